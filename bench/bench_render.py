"""Benchmark: a 512 x 512 appearance render of the Stanford bunny with
100,000 surfels on 1 and 2 threads (goal, issue 5: under 1 s on 2 cores),
and baking a 1024 x 1024 texture of Spot (goal: under 2 s).

    .venv/bin/python bench/bench_render.py [--record]
"""

from __future__ import annotations

import argparse
import time

from report import LOOK_EFFECT, ROOT, SCENE, cpu_name, report
from gamma.backends.jit import JitKernels
from gamma.frontend.checker import check
from gamma.frontend.parser import parse
from gamma.driver.running.camera import auto_camera, sun_direction
from gamma.driver.running.runner import RunOptions, build_config, runtime_module



def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--record", action="store_true")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    rt = runtime_module()
    effect = check(parse(LOOK_EFFECT, "bench.gamma"))
    kernels = JitKernels(effect)
    mesh = rt.Mesh.load(str(SCENE))
    cfg = build_config(rt, effect, kernels, RunOptions(scene="", out="", threads=2), mesh.bounds,
                       (0.0, -1.0, 0.0))
    sim = rt.Simulation(mesh, cfg)
    sim.trace(1)
    camera = auto_camera(mesh.bounds)
    eye, target, up, fov = camera
    rows = []
    for samples, ao in ((1, 4), (4, 8)):
        for threads in (1, 2):
            best = float("inf")
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                sim.render_appearance(eye, target, up, fov, 512, 512, threads, samples,
                                      sun_direction(camera), ao, 1)
                best = min(best, time.perf_counter() - t0)
            rows.append(f"| {samples} | {ao} | {threads} | {best:.3f} |")
    # Baking: a 1024 x 1024 texture of Spot (issue 5 goal: under 2 s).
    import numpy as np

    from gamma.driver.outputs.export import Piece, bake_texture_set, layout

    spot_mesh = rt.Mesh.load(str(ROOT / "examples" / "scenes" / "spot.obj"))
    spot_cfg = build_config(rt, effect, kernels, RunOptions(scene="", out="", surfels=100_000, threads=2),
                            spot_mesh.bounds, (0.0, -1.0, 0.0))
    spot = rt.Simulation(spot_mesh, spot_cfg)
    corner_uvs = np.asarray(spot_mesh.triangle_uvs())
    piece = Piece("spot", np.arange(spot_mesh.num_triangles), np.asarray(spot_mesh.vertices()),
                  np.asarray(spot_mesh.triangles(), np.int64), corner_uvs)
    spot_layout = layout(piece, np.asarray(spot.corner_normals()), 1024)
    best_bake = float("inf")
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        bake_texture_set(spot, spot_layout, 1, 2, lambda rows, tris: {"patina": rows[:, 3]})
        best_bake = min(best_bake, time.perf_counter() - t0)
    rows.append(f"| texture set 1024² (Spot, 100k surfels) | | 2 | {best_bake:.3f} |")
    info = (f"bunny {mesh.num_triangles:,} triangles, {sim.num_surfels:,} surfels, 512x512, "
            f"best of {args.repeats}, {cpu_name()}; goals: render under 1 s, bake under 2 s on 2 cores")
    header = "| samples/pixel | AO rays/sample | threads | seconds |\n|---|---|---|---|"
    report("appearance render and bake", info, header, rows, args.record)


if __name__ == "__main__":
    main()
