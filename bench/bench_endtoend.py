"""Benchmark: end-to-end wall time of ``gammac run`` against the trace + update
time of the same run.

    .venv/bin/python bench/bench_endtoend.py [--iterations 5] [--tons 1000000] [--record]

Runs ``gammac run examples/patina.gamma`` on the Stanford bunny (100,000
surfels, 1M gamma-tons per iteration, default outputs: renders, maps,
summary.json) in a fresh process, timing the whole process from outside
(start-up, compilation, setup, the loop and every output written), and reads
the run's own trace and update times from its summary.json.  The ratio
wall / (trace + update) is the figure: 1.0 would mean everything but the
simulation itself is free.  The median of ``--repeats`` runs (by ratio; the
range beside), and the median wall time against the quietest trace + update
of all the bench's runs (work behind the loop lengthens a run's own trace +
update, which would flatter its ratio); the median run's wall
time is split by the clocks summary.json reports (start-up, scene, compile,
setup, the loop, after the loop; the remainder is the interpreter's start and
the process's exit), with the outputs' busy time by kind.  ``gammac run``
samples the surfels while it starts up (driver/running/prefetch.py): "setup" is then
what is left of the setup once those are taken (including any wait for them),
and the sampling's own time is reported beside, overlapping the start-up.

Four kinds of run are reported, each repeat in a cache folder of its own
(GAMMA_CACHE_DIR): the first run of the effect on the mesh (the effect
checked, the kernels compiled, the setup made), a run of an effect run before
on a new mesh or surfel count (the effect and its kernels from the effect
cache, the setup made), the same run again (effect, kernels and setup from
the caches: backends/effect_cache.py, driver/caches/setup_cache.py), and the effect
edited (a constant changed, the look-development loop: checked and compiled
again, the setup from the setup cache).

A second table gives the floor of the two kinds that make the setup: what any
such run must spend outside its loop however its work were arranged on the
cores, measured in the same bench run in fresh processes: the import of the
libraries the run needs (a first run: numpy, Pillow, lark, llvmlite with its
native target, the runtime; a new mesh: numpy, Pillow, the runtime), the
mesh read and setup's CPU (at 1 thread, the least CPU it takes), and the
pictures after the loop (the run's own).  With the imports and the setup
packed perfectly on the cores, the time before the first trace is at least
max((imports + setup CPU) / cores, setup wall at ``--threads``, imports).
The floor leaves out everything else a run does: its own modules, the
parse, check and compile, the caches written for the next run, page faults
beyond the setup's own, the process's exit.  It is a lower bound for this
architecture (Python with these libraries, this setup), not a target.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from report import ROOT, SCENE, cpu_name, load_average, report

GAMMAC = Path(sys.executable).parent / "gammac"


def one_run(args, out: Path, cache: Path, effect: Path = ROOT / "examples" / "patina.gamma") -> dict:
    cmd = [str(GAMMAC), "run", str(effect), "--scene", str(SCENE),
           "--surfels", str(args.surfels), "--tons", str(args.tons), "--iterations", str(args.iterations),
           "--threads", str(args.threads), "--out", str(out)]
    env = dict(os.environ, GAMMA_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    wall = time.perf_counter() - t0
    summary = json.loads((out / "summary.json").read_text())
    iters = summary["iterations"]
    trace = sum(r["trace_seconds"] for r in iters)
    update = sum(r["update_seconds"] for r in iters)
    nan = float("nan")
    run = {"wall": wall, "trace_update": trace + update, "setup": summary.get("setup_seconds", nan),
           "startup": summary.get("startup_seconds", nan), "compile": summary.get("compile_seconds", nan),
           "scene": summary.get("scene_seconds", nan), "start": summary.get("start_seconds", nan),
           "loop": summary.get("loop_seconds", nan), "finish": summary.get("finish_seconds", nan),
           "outputs": summary.get("output_seconds", {}), "wait": summary.get("writer_wait_seconds", nan),
           # the surfels sampled while gammac started up (prefetch.py), when the setup took them
           "sample_ahead": summary.get("setup_phases", {}).get("sample_ahead"),
           # and the rest of the setup made after them, for one surface (SetupSnapshot.make_ahead)
           "ahead": summary.get("setup_phases", {}).get("ahead"),
           "from_cache": summary.get("setup_from_cache"), "kernels_from": summary.get("kernels_from")}
    # where the wall time went, in the order it is spent (summary.json's own clocks):
    # start-up (imports, parse, check) | scene | compile | setup | the rest of start
    # (output folder, camera, ...) | the loop's trace + update | the loop's other work
    # (writers' handlers, waits for the writer) | after the loop (false-colour renders,
    # the writer's last jobs) | outside (interpreter start, process exit)
    run["start_other"] = run["start"] - run["scene"] - run["compile"] - run["setup"]
    run["loop_other"] = run["loop"] - run["trace_update"]
    run["outside"] = wall - run["startup"] - run["start"] - run["loop"] - run["finish"]
    return run


#: The libraries each kind of run imports, as Python statements (gamma.launch sets
#: OPENBLAS_NUM_THREADS=1 before numpy's import; the floor's processes do too).
FLOOR_IMPORTS = {
    "first run (nothing cached)": "import numpy, PIL.Image, lark, llvmlite.binding as llvm, gamma._runtime; "
                                  "llvm.initialize_native_target(); llvm.initialize_native_asmprinter()",
    "effect cached, setup made": "import numpy, PIL.Image, gamma._runtime",
}


def setup_cpu(surfels: int, threads: int) -> dict:
    """The mesh read and the setup of the bench's run in this process
    (called in a child): wall and process CPU seconds."""
    from gamma.backends.jit import JitKernels
    from gamma.driver.running.runner import RunOptions, build_config, runtime_module
    from gamma.frontend.checker import load

    rt = runtime_module()
    effect = load(str(ROOT / "examples" / "patina.gamma"))
    kernels = JitKernels(effect, cache=None)
    t0, c0 = time.perf_counter(), time.process_time()
    mesh = rt.Mesh.load(str(SCENE))
    opts = RunOptions(scene=str(SCENE), out="", surfels=surfels, tons=1000, threads=threads)
    sim = rt.Simulation(mesh, build_config(rt, effect, kernels, opts, mesh.bounds, (0.0, -1.0, 0.0)))
    return {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0, "surfels": sim.num_surfels}


def floor_parts(args) -> dict:
    """The floor's parts, each the least of three fresh processes."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    parts = {}
    for kind, statement in FLOOR_IMPORTS.items():
        walls = []
        for _ in range(3):
            # from before the process starts to the end of its imports (its exit left out)
            t0 = time.time()
            out = subprocess.run([sys.executable, "-c", statement + "; import time; print(repr(time.time()))"],
                                 check=True, env=env, capture_output=True, text=True).stdout
            walls.append(float(out.strip().splitlines()[-1]) - t0)
        parts[kind] = min(walls)
    for threads in sorted({1, args.threads or os.cpu_count() or 1}):
        runs = [json.loads(subprocess.run([sys.executable, __file__, "--setup-cpu", f"{args.surfels},{threads}"],
                                          check=True, capture_output=True, text=True, env=env).stdout)
                for _ in range(3)]
        parts[f"setup {threads}"] = {"wall": min(r["wall"] for r in runs), "cpu": min(r["cpu"] for r in runs)}
    return parts


def main() -> None:
    if len(sys.argv) == 3 and sys.argv[1] == "--setup-cpu":
        surfels, threads = map(int, sys.argv[2].split(","))
        print(json.dumps(setup_cpu(surfels, threads)))
        return
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=5)
    ap.add_argument("--tons", type=int, default=1_000_000)
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()

    load_before = load_average()
    # Kinds of run, each in a cache folder of its own per repeat: the
    # first run of the effect on the mesh (nothing cached: the effect checked,
    # the kernels compiled, the setup made); the effect run before but a new
    # mesh or surfel count (the effect and kernels from the effect cache, the
    # setup made); the same run again (effect, kernels and setup from the
    # caches: backends/effect_cache.py, driver/caches/setup_cache.py).
    # A fourth: the effect edited (a constant changed, as a user tuning a
    # look does) and run on the same mesh: its kernels compiled again, the
    # setup from the setup cache.
    kinds = {"first run (nothing cached)": [], "effect cached, setup made": [],
             "run again (effect and setup cached)": [], "effect edited, setup cached": []}
    patina = (ROOT / "examples" / "patina.gamma").read_text()
    if "0.05 * t.patina" not in patina:
        raise SystemExit("bench_endtoend: examples/patina.gamma no longer has the constant the edited run changes")
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.repeats):
            cache = Path(tmp) / f"cache{rep}"
            for k, runs in enumerate(kinds.values()):
                if k == 1:              # as for a new mesh: no setup, no pictures' rays (view_cache.py)
                    for kept in [*cache.glob("setup-*.bin"), *cache.glob("view-*.bin")]:
                        kept.unlink()
                effect = ROOT / "examples" / "patina.gamma"
                if k == 3:
                    effect = Path(tmp) / f"patina-edited{rep}.gamma"
                    effect.write_text(patina.replace("0.05 * t.patina", f"{0.05 + 0.001 * (rep + 1):.3f} * t.patina"))
                runs.append(one_run(args, Path(tmp) / f"run{rep}-{k}", cache, effect))
    expected = {"first run (nothing cached)": ("nothing", "compiled"),
                "effect cached, setup made": ("nothing", "effect cache"),
                "run again (effect and setup cached)": ("setup", "effect cache"),
                "effect edited, setup cached": ("setup", "compiled")}
    for kind, runs in kinds.items():
        took = {(r["from_cache"], r["kernels_from"]) for r in runs}
        if took != {expected[kind]}:
            raise SystemExit(f"bench_endtoend: the {kind!r} runs took (setup, kernels) {sorted(map(str, took))} "
                             f"from the caches, not {expected[kind]!r} (a setup too large to keep? no C compiler?)")
    # Work behind the loop (the outputs, the setup cache's write, the pictures' rays) shares the
    # cores with the trace and lengthens a run's own trace + update: the quietest trace + update
    # of every run of this bench is a second denominator that this cannot flatter.
    quietest = min(r["trace_update"] for runs in kinds.values() for r in runs)
    n = args.iterations
    header = ("| run | s/iteration end-to-end | trace + update s/iteration | ratio (median; min–max) "
              "| ratio to the quietest trace + update | start-up s | scene s | compile s "
              "| setup s | rest of start s | loop besides trace + update s | after the loop s "
              "| outside (interpreter start, exit) s |\n"
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows, notes = [], []
    for kind, runs in kinds.items():
        ratios = sorted(r["wall"] / r["trace_update"] for r in runs)
        median = runs[sorted(range(len(runs)), key=lambda i: runs[i]["wall"] / runs[i]["trace_update"])
                      [len(runs) // 2]]
        best = median
        walls = sorted(r["wall"] for r in runs)
        rows.append(f"| {kind} | {best['wall'] / n:.3f} | {best['trace_update'] / n:.3f} | "
                    f"{ratios[len(ratios) // 2]:.2f}× ({ratios[0]:.2f}–{ratios[-1]:.2f}) | "
                    f"{walls[len(walls) // 2] / quietest:.2f}× | {best['startup']:.2f} | {best['scene']:.2f} | "
                    f"{best['compile']:.2f} | {best['setup']:.2f} | {best['start_other']:.2f} | "
                    f"{best['loop_other']:.2f} | {best['finish']:.2f} | {best['outside']:.2f} |")
        ahead = ("surfels sampled during the start-up in " + f"{best['sample_ahead']:.2f} s"
                 if best["sample_ahead"] is not None else "")
        if best["ahead"] is not None:
            ahead += f", the rest of the setup made after them in {best['ahead']:.2f} s"
        busy = ", ".join(f"{kind} {seconds:.2f} s" for kind, seconds in sorted(best["outputs"].items()))
        notes.append(f"{kind}: kernels {best['kernels_from']}, setup took {best['from_cache']} from the setup cache"
                     + (f", {ahead}" if ahead else "") + f"; outputs' busy time {busy or 'not reported'}, "
                     f"the loop waited {best['wait']:.2f} s for the writer")
    info = (f"`gammac run examples/patina.gamma`, bunny, {args.surfels:,} surfels, {args.tons:,} γ-tons/iteration, "
            f"{n} iterations, {args.threads} threads, default outputs; wall time of the whole process "
            f"(start-up, compile, setup, outputs) / the run's own trace + update time, median of "
            f"{args.repeats} runs per kind (min–max beside), and the median wall time / the least trace + update "
            f"of all {len(kinds) * args.repeats} runs (quietest: {quietest / n:.3f} s/iteration); the median run's "
            f"seconds split by summary.json's clocks; "
            f"outputs' busy time is on any thread, overlapping the loop behind it; " + "; ".join(notes)
            + f"; {cpu_name()}, {os.cpu_count()} cores, load average {load_before:.1f} → {load_average():.1f}")
    report("end-to-end gammac run (patina, bunny)", info, header, rows, args.record)

    parts = floor_parts(args)
    threads = args.threads or os.cpu_count() or 1          # (--threads 0: all cores)
    cores = min(os.cpu_count() or 1, threads)
    setup_1, setup_t = parts["setup 1"], parts[f"setup {threads}"]
    header = ("| run | imports s | mesh + setup CPU s (1 thread) | setup wall s "
              f"({threads} threads) | after the loop s | floor outside the loop s | floor ratio "
              "(own trace + update; quietest) | measured outside trace + update s | above the floor s |\n"
              "|---|---|---|---|---|---|---|---|---|")
    rows = []
    for kind in FLOOR_IMPORTS:
        runs = kinds[kind]
        median = sorted(runs, key=lambda r: r["wall"] / r["trace_update"])[len(runs) // 2]
        before = max((parts[kind] + setup_1["cpu"]) / cores, setup_t["wall"], parts[kind])
        floor = before + median["finish"]
        outside = median["wall"] - median["trace_update"]
        rows.append(f"| {kind} | {parts[kind]:.3f} | {setup_1['cpu']:.3f} | {setup_t['wall']:.3f} | "
                    f"{median['finish']:.3f} | {floor:.3f} | {1 + floor / median['trace_update']:.2f}× "
                    f"({1 + floor / quietest:.2f}×) | {outside:.3f} | {outside - floor:.3f} |")
    info = ("the floor of a run that makes its setup: what it must spend outside its loop however its work "
            "were arranged on the cores (fresh processes, least of 3 each): the libraries' import (interpreter "
            f"start included, its exit not), the mesh read and setup's CPU at 1 thread, packed with the imports on {cores} "
            f"cores (the setup's wall at {threads} threads bounds it too), then the median run's own "
            "time after the loop; everything else the run does (its own modules, parse, check, compile, "
            "the caches written for the next run, further page faults, the loop's own work besides trace "
            "+ update, exit) is above the floor")
    report("end-to-end floor (patina, bunny)", info, header, rows, args.record)


if __name__ == "__main__":
    main()
