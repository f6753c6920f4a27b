"""Benchmark: exporting the Stanford bunny (no texture coordinates) at 100,000
surfels after one iteration of patina: glTF + OBJ + a 1024² baked colour and
property map (goal, issue 12: at most 10 s; it took 50-100 s with an xatlas
atlas and a per-triangle Python rasteriser).  The baseline measured in the
same run is one simulation iteration of the same scene (1M γ-tons).

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
from gamma.driver.export import pieces
from gamma.frontend.parser import parse
from gamma.driver.events import IterationUpdated
from gamma.driver.runner import RunOptions, build_config, runtime_module
from gamma.driver.writers import ExportWriter
from gamma.driver.scene import load_scene



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
        from gamma.driver.events import WriteQueue

        class Run:   # what ExportWriter reads of a run
            shapes = False

            def export_scene(self):
                return self.scene

        run = Run()
        run.sim, run.scene, run.effect, run.threads, run.out = sim, scene, effect, args.threads, Path(tmp)
        run.behind = WriteQueue()
        writer = ExportWriter(1024)
        rows = sim.rows()
        t0 = time.perf_counter()
        parts = pieces(scene, 1024)
        atlas = time.perf_counter() - t0
        t0 = time.perf_counter()
        with run.behind:
            writer.on_iteration_updated(IterationUpdated(run, 1, rows, {}, {}))
        total = time.perf_counter() - t0
        assert len(list(Path(tmp).glob("export/*/iter_0001.glb"))) == len(parts)
    rows = [f"| {scene.mesh.num_triangles:,} | {atlas:.2f} | {total:.2f} | {iteration:.2f} | "
            f"{total / iteration:.1f} |"]
    report("export of the bunny without UVs (issue 12)",
           f"{cpu_name()}, {args.threads} threads; bunny, 100,000 surfels, 1024² textures, one iteration "
           "of 1M patina γ-tons as the baseline",
           "| triangles | atlas s | export s (atlas, bake, glTF, OBJ, PNGs) | one iteration s | "
           "export / iteration |\n|---|---|---|---|---|", rows, args.record)


if __name__ == "__main__":
    main()
