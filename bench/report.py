"""What every benchmark shares: the machine's name and how a table is
printed and, with --record, appended to bench/RESULTS.md."""

from __future__ import annotations

import datetime
import os
import platform
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
#: The repository, and the mesh most benchmarks run on.
ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "examples" / "scenes" / "stanford-bunny.obj"

#: examples/patina.gamma with an appearance block (the render and export
#: benchmarks draw the look, not a false-colour property).
LOOK_EFFECT = """
ton Weather { motion straight = 1.0  carry patina = 1.0 }
surface Copper { reflectance straight = 0.5  property patina = 0.0 }
source air = environment(sphere) emits Weather count 1000000
on settle(t: Weather, s: Copper) { s.patina += 0.05 * t.patina }
appearance(s: Copper) {
    color = mix(rgb(0.55, 0.35, 0.2), rgb(0.27, 0.58, 0.5), smoothstep(0, 0.5, s.patina))
}
"""

# As gammac does (cli.entry): numpy's OpenBLAS without its thread pool, whose
# threads woke beside the tracer in the benchmarks' own processes (each bench
# imports this module before numpy).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def load_average() -> float:
    """The 1-minute load average (other engineers share these 2 cores)."""
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def report(title: str, info: str, header: str, rows: list[str], record: bool) -> None:
    """Print a markdown table; with ``record`` also append it to RESULTS.md."""
    table = "\n".join(rows)
    print(info)
    print(header)
    print(table)
    if record:
        with open(RESULTS, "a", encoding="utf-8") as out:
            out.write(f"\n### {datetime.date.today()} — {title}\n{info}\n\n{header}\n{table}\n")
