"""Benchmark: exporting the Stanford bunny (no texture coordinates) at 100,000
surfels after one iteration of patina: the chart atlas (xatlas), the 1024²
texture set (base colour, ORM, normal, height, the property), the scene glb
and the OBJ (goal, texture-set issue: at most 10 s).  The baseline measured
in the same run is one simulation iteration of the same scene (1M γ-tons).

    .venv/bin/python bench/bench_export.py [--record]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from report import LOOK_EFFECT, SCENE, cpu_name, report
from gamma.backends.jit import JitKernels
from gamma.frontend.checker import check
from gamma.driver.outputs.export import Exporter, layout, pieces
from gamma.frontend.parser import parse
from gamma.driver.running.runner import RunOptions, build_config, runtime_module
from gamma.driver.running.scene import load_scene



def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--record", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    rt = runtime_module()
    effect = check(parse(LOOK_EFFECT, "bench.gamma"))
    kernels = JitKernels(effect)
    scene = load_scene(rt, str(SCENE), effect, [])
    opts = RunOptions(scene=str(SCENE), out="", threads=args.threads, surfels=100_000)
    cfg = build_config(rt, effect, kernels, opts, scene.bounds, scene.down)
    cfg.triangle_surface = scene.triangle_surface
    sim = rt.Simulation(scene.mesh, cfg)
    t0 = time.perf_counter()
    sim.trace(1)
    sim.update(1)
    iteration = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        from gamma.driver.running.events import WriteQueue

        class Run:   # what Exporter reads of a run
            shapes = False

            def export_scene(self):
                return self.scene

        run = Run()
        run.sim, run.scene, run.effect, run.threads, run.out = sim, scene, effect, args.threads, Path(tmp)
        run.opts = opts
        import numpy as np

        corner = np.asarray(sim.corner_normals())
        t0 = time.perf_counter()
        parts = [layout(piece, corner, 1024) for piece in pieces(scene)]
        atlas = time.perf_counter() - t0
        t0 = time.perf_counter()
        Exporter(run, 1024, None, {}).write(1)      # its own atlas again: what gammac run pays
        total = time.perf_counter() - t0
        assert len(list(Path(tmp).glob("export/*_0001.glb"))) == 1 and len(parts) == 1
    rows = [f"| {scene.mesh.num_triangles:,} | {atlas:.2f} | {total:.2f} | {iteration:.2f} | "
            f"{total / iteration:.1f} |"]
    report("export of the bunny without UVs (texture-set issue)",
           f"{cpu_name()}, {args.threads} threads; bunny, 100,000 surfels, 1024² textures, one iteration "
           "of 1M patina γ-tons as the baseline",
           "| triangles | atlas s | export s (atlas, texture set, glb, OBJ, PNGs) | one iteration s | "
           "export / iteration |\n|---|---|---|---|---|", rows, args.record)


if __name__ == "__main__":
    main()
