"""Benchmark: the texture set of the paper's Fig. 8 stain scene (four parts:
stairs, ground, wall, chain; no texture coordinates, so chart atlases) at
1024² and 4096², as `gammac export DIR --bake-size N` writes it from the
last iteration, against the baseline measured in the same run: `gammac run`
of the scene's 3 iterations (wall time of each command, peak resident size
of each child).  The texture-set issue asks for 4096² in at most 5x the run
and at most 1.5 GiB.

    .venv/bin/python bench/bench_texture_set.py [--record]
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from report import ROOT, cpu_name, report

GAMMAC = [sys.executable, "-m", "gamma.cli"]


def timed(args: list) -> tuple[float, float]:
    """(wall seconds, peak resident GiB) of one gammac command."""
    start = time.perf_counter()
    r = subprocess.run(GAMMAC + [str(a) for a in args], capture_output=True, text=True)
    wall = time.perf_counter() - start
    if r.returncode != 0:
        raise SystemExit(r.stderr)
    # the largest child so far: the commands run from the smallest to the largest
    return wall, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()
    scene = ROOT / "examples" / "scenes" / "staircase.obj"
    if not scene.is_file():
        subprocess.run([sys.executable, ROOT / "examples" / "scenes" / "make_staircase.py", scene], check=True)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "stain"
        run, run_peak = timed(["run", ROOT / "examples" / "stain-bleeding.gamma", "--scene", scene,
                               "--assign", "chain=Iron", "--assign", "*=Cement", "--iterations", 3,
                               "--quiet", "--out", out])
        rows = []
        for size in (1024, 4096):
            wall, peak = timed(["export", out, "--bake-size", size, "--quiet"])
            rows.append(f"| {size}² | {wall:.1f} | {peak:.2f} | {run:.1f} | {wall / run:.1f} |")
    report("texture set of the stain scene (texture-set issue)",
           f"{cpu_name()}, 2 threads; stain scene, 100,000 surfels, 3 iterations; goal at 4096²: "
           "export / run <= 5, peak <= 1.5 GiB",
           "| size | export s | peak GiB (largest child so far) | run s | export / run |\n|---|---|---|---|---|",
           rows, args.record)


if __name__ == "__main__":
    main()
