"""Benchmark: one erosion iteration of the Stanford bunny (trace, update,
displacement, re-tiling, surfel re-sampling and transfer, rebuild) against a
paint-only iteration (trace + update of the patina effect, same surfels and
gamma-ton count), in one process.

    .venv/bin/python bench/bench_erosion.py [--surfels 100000] [--tons 300000] [--record]

The erosion effect is examples/erosion.gamma with the whole bunny as
Sandstone.  Its first iteration is set up but not timed (the shape step has
nothing to compare against before the first trace); iterations 2.. are
timed and the best is reported, split by phase.  The ratio erosion / paint
measured in the same run is the figure to compare (rates swing on this
shared machine).  ``--record`` appends the table to bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from report import cpu_name, report

from gamma.backends.jit import JitKernels
from gamma.frontend.checker import load
from gamma.driver.runner import RunOptions, build_config, runtime_module

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "examples" / "scenes" / "stanford-bunny.obj"


def iteration(sim, it: int) -> dict:
    t0 = time.perf_counter()
    traced = sim.trace(it)
    updated = sim.update(it)
    shaped = sim.shape(it)
    total = time.perf_counter() - t0
    return {"total": total, "trace": traced["trace_seconds"], "update": updated["seconds"],
            "displace": shaped["displace_seconds"], "retile": shaped["retile_seconds"],
            "resample": shaped["resample_seconds"], "rebuild": shaped["rebuild_seconds"],
            "changed": shaped["changed"], "triangles": shaped["geometry"]["triangles"],
            "min_angle": shaped["geometry"]["min_angle_deg"], "emitted": traced["emitted"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--tons", type=int, default=300_000)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()

    rt = runtime_module()
    mesh = rt.Mesh.load(str(SCENE))
    opts = RunOptions(scene=str(SCENE), out="", surfels=args.surfels, tons=args.tons, threads=args.threads)

    erosion = load(str(ROOT / "examples" / "erosion.gamma"))
    ek = JitKernels(erosion)
    sim = rt.Simulation(mesh, build_config(rt, erosion, ek, opts, mesh.bounds, (0.0, -1.0, 0.0)))
    runs = [iteration(sim, it) for it in range(1, args.iterations + 1)]
    best = min(runs[1:] or runs, key=lambda r: r["total"])

    paint = load(str(ROOT / "examples" / "patina.gamma"))
    pk = JitKernels(paint)
    psim = rt.Simulation(mesh, build_config(rt, paint, pk, opts, mesh.bounds, (0.0, -1.0, 0.0)))
    paint_runs = []
    for it in range(1, args.iterations + 1):
        t0 = time.perf_counter()
        psim.trace(it)
        psim.update(it)
        paint_runs.append(time.perf_counter() - t0)
    paint_best = min(paint_runs)

    header = ("| iteration | total s | trace | update | displace | re-tile | re-sample + transfer | rebuild "
              "| paint-only s | ratio |\n|---|---|---|---|---|---|---|---|---|---|")
    row = (f"| erosion | {best['total']:.3f} | {best['trace']:.3f} | {best['update']:.3f} | "
           f"{best['displace']:.3f} | {best['retile']:.3f} | {best['resample']:.3f} | {best['rebuild']:.3f} | "
           f"{paint_best:.3f} | {best['total'] / paint_best:.2f} |")
    info = (f"bunny {mesh.num_triangles:,} triangles re-tiled to {best['triangles']:,} "
            f"(min angle {best['min_angle']:.1f}°), {args.surfels:,} surfels, {best['emitted']:,} γ-tons "
            f"per iteration, {args.threads} threads, best of iterations 2..{args.iterations}, "
            f"{cpu_name()}, {os.cpu_count()} cores")
    report("erosion iteration on the bunny", info, header, [row], args.record)


if __name__ == "__main__":
    main()
