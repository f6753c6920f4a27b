"""Benchmark: patina gamma-tons/s on the Stanford bunny against Embree's raw
ray-cast rate on the same scene, in one process.

    .venv/bin/python bench/bench_patina.py [--tons 1000000] [--record]

For each thread count the tracer runs the patina effect (k_s = 1,
Delta_s = 0.5) and then Embree casts the same number of rays the tracer cast,
drawn like the environment source, with no surfel lookup and no kernels: the
ceiling.  Rates swing on this shared machine, so the ratio measured in the
same run is the figure to compare.  ``--record`` appends the table to
bench/RESULTS.md.
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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tons", type=int, default=1_000_000)
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()

    rt = runtime_module()
    effect = load(str(ROOT / "examples" / "patina.gamma"))
    kernels = JitKernels(effect)
    mesh = rt.Mesh.load(str(SCENE))
    rows = []
    for threads in (1, 2):
        opts = RunOptions(scene=str(SCENE), out="", surfels=args.surfels, tons=args.tons,
                          threads=threads)
        cfg = build_config(rt, effect, kernels, opts, mesh.bounds, (0.0, -1.0, 0.0))
        t0 = time.perf_counter()
        sim = rt.Simulation(mesh, cfg)
        setup = time.perf_counter() - t0
        best = None
        for rep in range(args.repeats):
            stats = sim.trace(rep + 1)
            if best is None or stats["trace_seconds"] < best["trace_seconds"]:
                best = stats
        raw = min((sim.raw_raycast(best["rays"], threads, 12345) for _ in range(args.repeats)),
                  key=lambda r: r["seconds"])
        tons_rate = best["emitted"] / best["trace_seconds"]
        ray_rate = best["rays"] / best["trace_seconds"]
        raw_rate = raw["rays"] / raw["seconds"]
        rows.append((threads, tons_rate, ray_rate, raw_rate, ray_rate / raw_rate, setup))
    header = ("| threads | γ-tons/s | tracer rays/s | raw Embree rays/s | ratio | setup s |\n"
              "|---|---|---|---|---|---|")
    table = "\n".join(f"| {t} | {a:,.0f} | {b:,.0f} | {c:,.0f} | {d:.0%} | {s:.2f} |"
                      for t, a, b, c, d, s in rows)
    info = (f"bunny {mesh.num_triangles:,} triangles, {args.surfels:,} surfels, "
            f"{args.tons:,} γ-tons per trace (best of {args.repeats}), "
            f"{cpu_name()}, {os.cpu_count()} cores")
    report("patina on the bunny", info, header, table.split("\n"), args.record)


if __name__ == "__main__":
    main()
