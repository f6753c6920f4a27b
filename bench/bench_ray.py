"""Benchmark: tracing on Ray workers (``gammac run --ray``) against a local
trace, and what distribution moves per iteration.

    .venv/bin/python bench/bench_ray.py [--tons 1000000] [--iterations 5] [--record]

Patina on the bunny (100k surfels).  In one process: the local tracer at 1
and 2 threads (the baseline), and a local Ray with 2 CPUs tracing the same
iterations with 1 worker (one task at a time) and with 2 workers, each
configuration its iterations in a block, as a run does.  Every configuration traces the same iterations
from the same start, and the rows after each are checked to be
bit-identical to the local run's.  Reported per iteration: seconds (median
of iterations 2 on; the worker processes' builds of their simulation, in
whichever iteration Ray first gave them a task, reported apart but included), the
driver's merge, bytes moved (surfel state sent to the workers, chunk deltas
returned, the job sent once), and the cost of distribution as the ratio of
Ray's time to the local time at the same parallelism.
``--record`` appends the table to bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
from report import ROOT, SCENE, cpu_name, load_average, report

from gamma.backends.jit import JitKernels
from gamma.driver.distributed import cluster, distributed
from gamma.driver.running.runner import RunOptions, build_config, runtime_module
from gamma.driver.running.scene import load_scene
from gamma.frontend.checker import load



def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tons", type=int, default=1_000_000)
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--iterations", type=int, default=5)
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
        local = {f"local, {n} thread{'s' * (n > 1)}": simulation(n) for n in (1, 2)}
        remote = {}
        job = None
        for workers in (1, 2):
            sim = simulation(2)
            # one job for both: a worker keeps the simulation it built for it
            job = job or distributed.make_job(rt, effect, kernels, opts, scene, sim, build_config)
            remote[f"Ray, {workers} worker{'s' * (workers > 1)}"] = distributed.RayTracer(sim, job, conn,
                                                                                          workers=workers)
        times = {name: [] for name in [*local, *remote]}
        moved = {name: [] for name in remote}
        merges = {name: [] for name in remote}
        reference = []
        # Each configuration traces its iterations in a block, as a run does:
        # interleaving the two Ray tracers (tasks of 2 CPUs and of 1) made Ray
        # replace worker processes, which then built their simulation again
        # in every iteration, which a run never sees.
        for name, sim in local.items():
            for it in range(1, args.iterations + 1):
                times[name].append(sim.trace(it)["trace_seconds"])
                if name == "local, 1 thread":
                    reference.append(sim.rows().copy())
        for name, tracer in remote.items():
            for it in range(1, args.iterations + 1):
                stats = tracer.trace(it)
                if not np.array_equal(tracer.sim.rows(), reference[it - 1]):
                    raise SystemExit(f"{name}: iteration {it} differs from the local run")
                times[name].append(stats["trace_seconds"])
                merges[name].append(stats["merge_seconds"])
                moved[name].append(stats["bytes_moved"])
        # Medians of iterations 2 on.  On Ray a worker process builds its
        # simulation when it first gets a task, which Ray gives it when it
        # first needs it (not only in iteration 1): those builds (and the
        # start of a worker process, which is not counted in them) stay in.
        results = {}
        for name, values in times.items():
            extra = None
            if name in remote:
                setups = (sum(m["worker_setups"] for m in moved[name]),
                          sum(m["worker_setup_seconds"] for m in moved[name]),
                          [i + 1 for i, m in enumerate(moved[name]) if m["worker_setups"]])
                extra = (moved[name], setups, statistics.median(merges[name]))
            results[name] = (statistics.median(values[1:] or values), extra)
    base1 = results["local, 1 thread"][0]
    base2 = results["local, 2 threads"][0]
    rows = []
    for name, (seconds, extra) in results.items():
        baseline = base1 if name.endswith(("1 thread", "1 worker")) else base2
        if extra is None:
            rows.append(f"| {name} | {seconds:.3f} | | | | | | {seconds / baseline:.2f} |")
            continue
        moved, (setups, setup_seconds, with_setup), merge = extra
        state = moved[-1]["state"] / 1e6
        deltas = statistics.median(m["deltas"] for m in moved) / 1e6
        job = moved[0]["job"] / 1e6
        where = f"{setup_seconds:.1f} s in iteration {', '.join(map(str, with_setup))}" if setups else "none"
        rows.append(f"| {name} | {seconds:.3f} | {merge:.3f} | {setups} ({where}) | "
                    f"{state:.2f} | {deltas:.2f} | {job:.2f} | {seconds / baseline:.2f} |")
    header = ("| tracing | s per iteration (median) | of it, driver merge s | worker setups | "
              "state sent MB | deltas back MB | job MB (once) | time / local at same parallelism |\n"
              "|---|---|---|---|---|---|---|---|")
    info = (f"patina on the bunny {scene.mesh.num_triangles:,} triangles, {args.surfels:,} surfels, "
            f"{args.tons:,} γ-tons per iteration, {args.iterations} iterations, rows bit-identical to the "
            f"local run checked every iteration; local Ray start-up {start_seconds:.1f} s; "
            f"{cpu_name()}, {os.cpu_count()} cores, load average {load_before:.1f} before, "
            f"{load_average():.1f} after (other engineers share the machine)")
    report("tracing on Ray", info, header, rows, args.record)


if __name__ == "__main__":
    main()
