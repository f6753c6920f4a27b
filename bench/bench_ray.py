"""Benchmark: tracing on Ray workers (``gammac run --ray``) against a local
trace, and what distribution moves per iteration.

    .venv/bin/python bench/bench_ray.py [--tons 1000000] [--iterations 3] [--record]

Patina on the bunny (100k surfels).  In one process: the local tracer at 1
and 2 threads (the baseline), then a local Ray with 2 CPUs tracing the same
iterations with 1 worker (one task at a time) and with 2 workers.  Every
configuration traces the same iterations from the same start, and the rows
after each are checked to be bit-identical to the local run's.  Reported per
iteration: seconds (median), bytes moved (surfel state sent to the workers,
chunk deltas returned, the job sent once), and the cost of distribution as
the ratio of Ray's time to the local time at the same parallelism.
``--record`` appends the table to bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np
from report import cpu_name, load_average, report

from gamma.backends.jit import JitKernels
from gamma.driver import cluster, distributed
from gamma.driver.runner import RunOptions, build_config, runtime_module
from gamma.driver.scene import load_scene
from gamma.frontend.checker import load

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "examples" / "scenes" / "stanford-bunny.obj"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tons", type=int, default=1_000_000)
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()

    rt = runtime_module()
    effect = load(str(ROOT / "examples" / "patina.gamma"))
    kernels = JitKernels(effect)
    opts = RunOptions(scene=str(SCENE), out="", surfels=args.surfels, tons=args.tons, threads=1)
    scene = load_scene(rt, str(SCENE), effect, [], None)

    def simulation(threads: int):
        opts.threads = threads
        cfg = build_config(rt, effect, kernels, opts, scene.bounds, scene.down)
        cfg.triangle_surface = scene.triangle_surface
        return rt.Simulation(scene.mesh, cfg)

    load_before = load_average()
    # Ray first: its start-up is what fails on an overloaded machine.
    t0 = time.perf_counter()
    with cluster.connect(num_cpus=2) as conn:
        start_seconds = time.perf_counter() - t0
        results, reference = {}, []
        for threads in (1, 2):
            sim = simulation(threads)
            times = []
            for it in range(1, args.iterations + 1):
                times.append(sim.trace(it)["trace_seconds"])
                if threads == 1:
                    reference.append(sim.rows().copy())
            results[f"local, {threads} thread{'s' * (threads > 1)}"] = (statistics.median(times), None)
        for workers in (1, 2):
            sim = simulation(2)
            job = distributed.make_job(rt, effect, kernels, opts, scene, sim, build_config)
            tracer = distributed.RayTracer(sim, job, conn, workers=workers)
            times, moved, merges = [], [], []
            for it in range(1, args.iterations + 1):
                stats = tracer.trace(it)
                if not np.array_equal(sim.rows(), reference[it - 1]):
                    raise SystemExit(f"Ray with {workers} worker(s): iteration {it} differs from the local run")
                times.append(stats["trace_seconds"])
                merges.append(stats["merge_seconds"])
                moved.append(stats["bytes_moved"])
            # the first iteration also builds the simulation on each worker
            first = times[0]
            results[f"Ray, {workers} worker{'s' * (workers > 1)}"] = (statistics.median(times[1:] or times),
                                                                      (moved, first, statistics.median(merges)))
    base1 = results["local, 1 thread"][0]
    base2 = results["local, 2 threads"][0]
    rows = []
    for name, (seconds, extra) in results.items():
        baseline = base1 if name.endswith(("1 thread", "1 worker")) else base2
        if extra is None:
            rows.append(f"| {name} | {seconds:.3f} | | | | | {seconds / baseline:.2f} |")
            continue
        moved, first, merge = extra
        state = moved[-1]["state"] / 1e6
        deltas = statistics.median(m["deltas"] for m in moved) / 1e6
        job = moved[0]["job"] / 1e6
        rows.append(f"| {name} | {seconds:.3f} (first {first:.2f}) | {merge:.3f} | {state:.2f} | {deltas:.2f} | "
                    f"{job:.2f} | {seconds / baseline:.2f} |")
    header = ("| tracing | s per iteration (median) | of it, driver merge s | state sent MB | deltas back MB | "
              "job MB (once) | time / local at same parallelism |\n|---|---|---|---|---|---|---|")
    info = (f"patina on the bunny {scene.mesh.num_triangles:,} triangles, {args.surfels:,} surfels, "
            f"{args.tons:,} γ-tons per iteration, {args.iterations} iterations, rows bit-identical to the "
            f"local run checked every iteration; local Ray start-up {start_seconds:.1f} s; "
            f"{cpu_name()}, {os.cpu_count()} cores, load average {load_before:.1f} before, "
            f"{load_average():.1f} after (other engineers share the machine)")
    report("tracing on Ray", info, header, rows, args.record)


if __name__ == "__main__":
    main()
