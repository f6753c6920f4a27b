"""Benchmark: end-to-end wall time of ``gammac run`` against the trace + update
time of the same run.

    .venv/bin/python bench/bench_endtoend.py [--iterations 5] [--tons 1000000] [--record]

Runs ``gammac run examples/patina.gamma`` on the Stanford bunny (100,000
surfels, 1M gamma-tons per iteration, default outputs: renders, maps,
summary.json) in a fresh process, timing the whole process from outside
(start-up, compilation, setup, the loop and every output written), and reads
the run's own trace and update times from its summary.json.  The ratio
wall / (trace + update) is the figure: 1.0 would mean everything but the
simulation itself is free.  Best of ``--repeats`` (by ratio).
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

from report import cpu_name, load_average, report

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "examples" / "scenes" / "stanford-bunny.obj"
GAMMAC = Path(sys.executable).parent / "gammac"


def one_run(args, out: Path) -> dict:
    cmd = [str(GAMMAC), "run", str(ROOT / "examples" / "patina.gamma"), "--scene", str(SCENE),
           "--surfels", str(args.surfels), "--tons", str(args.tons), "--iterations", str(args.iterations),
           "--threads", str(args.threads), "--out", str(out)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    summary = json.loads((out / "summary.json").read_text())
    iters = summary["iterations"]
    trace = sum(r["trace_seconds"] for r in iters)
    update = sum(r["update_seconds"] for r in iters)
    return {"wall": wall, "trace_update": trace + update, "setup": summary.get("setup_seconds", float("nan")),
            "startup": summary.get("startup_seconds", float("nan")),
            "compile": summary.get("compile_seconds", float("nan"))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=5)
    ap.add_argument("--tons", type=int, default=1_000_000)
    ap.add_argument("--surfels", type=int, default=100_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()

    load_before = load_average()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.repeats):
            runs.append(one_run(args, Path(tmp) / f"run{rep}"))
    best = min(runs, key=lambda r: r["wall"] / r["trace_update"])
    n = args.iterations
    header = ("| s/iteration end-to-end | trace + update s/iteration | ratio | start-up s | compile s | setup s |\n"
              "|---|---|---|---|---|---|")
    row = (f"| {best['wall'] / n:.3f} | {best['trace_update'] / n:.3f} | "
           f"{best['wall'] / best['trace_update']:.2f}× | {best['startup']:.2f} | {best['compile']:.2f} | "
           f"{best['setup']:.2f} |")
    info = (f"`gammac run examples/patina.gamma`, bunny, {args.surfels:,} surfels, {args.tons:,} γ-tons/iteration, "
            f"{n} iterations, {args.threads} threads, default outputs; wall time of the whole process "
            f"(start-up, compile, setup, outputs) / the run's own trace + update time; best of {args.repeats} "
            f"by ratio; {cpu_name()}, {os.cpu_count()} cores, load average {load_before:.1f} → "
            f"{load_average():.1f}")
    report("end-to-end gammac run (patina, bunny)", info, header, [row], args.record)


if __name__ == "__main__":
    main()
