"""Benchmark: compiling a 200-line effect, cold (no kernel cache) and warm.

    .venv/bin/python bench/bench_compile.py [--record]

Goals: compiling under 0.5 s cold (issue 4); `gammac check` of the same
effect under 0.3 s, its whole process (interpreter start-up, imports, parse,
check) timed from outside (issue 14).  Each measurement runs in a fresh
process so nothing is cached in memory; the 'cold' runs use
GAMMA_CACHE_DIR=off (no kernel cache, no lark cache).  The grammar's LALR
tables are built with the package (gamma/frontend/lalr_tables.py), so even a
cold process only loads them: that is what a user's first `gammac check`
after installing does.
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

from report import report


MEASURE = """
import json, time
t0 = time.perf_counter()
from gamma.frontend.checker import load
from gamma.backends.jit import JitKernels
t1 = time.perf_counter()
effect = load({path!r})
t2 = time.perf_counter()
jit = JitKernels(effect)
t3 = time.perf_counter()
print(json.dumps({{"import": t1 - t0, "check": t2 - t1, "jit": t3 - t2, "cached": jit.from_cache,
                  "kernels": len(effect.kernels)}}))
"""


def effect_text() -> str:
    """A 200-line effect: 2 ton types, 6 surfaces, lets, ifs, built-ins, random()."""
    lines = ["ton Rain {", "    motion parabolic = 0.8, flow = 0.2", "    carry humidity = 1.0, rust = 0.0, dirt = 0.0", "}",
             "ton Seed {", "    motion straight = 0.2", "    carry moss = 1.0", "}"]
    for i in range(6):
        lines += [f"surface S{i} {{", "    reflectance parabolic = 0.4, flow = 0.05",
                  "    property humidity = 0.0, rust = 0.0, dirt = 0.0, moss = 0.0", "}"]
    lines += ["source rain = directional(down) emits Rain count 1000",
              "source seeds = environment(hemisphere) emits Seed count 100 until 1"]
    i = 0
    while len(lines) + 10 <= 200:
        s = f"S{i % 6}"
        lines += [f"on hit(t: Rain, s: {s}) {{", f"    let w = clamp(t.humidity * {0.1 + i * 0.01:.2f}, 0, 1)",
                  "    if s.moss > 0.5 and height < 1 {", "        s.humidity += w * 0.5", "    } else {",
                  "        s.humidity += w", "    }", f"    t.rust += s.rust * {0.02 + i * 0.001:.3f}",
                  "    s.dirt += smoothstep(0, 1, t.dirt) * 0.1 + random() * 0.01", "}"]
        i += 1
    while len(lines) < 200:
        lines.append(f"update(s: S{len(lines) % 6}) {{ s.rust *= 0.99 }}")
    return "\n".join(lines) + "\n"


def measure(path: Path, cache: str) -> dict:
    env = dict(os.environ, GAMMA_CACHE_DIR=cache)
    out = subprocess.run([sys.executable, "-c", MEASURE.format(path=str(path))], env=env,
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def check_process(path: Path, cache: str) -> float:
    """Wall time of a whole `gammac check` process."""
    env = dict(os.environ, GAMMA_CACHE_DIR=cache)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "gamma.cli", "check", str(path)], env=env,
                   capture_output=True, check=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--record", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.gamma"
        path.write_text(effect_text())
        cold = min((measure(path, "off") for _ in range(args.repeats)), key=lambda r: r["check"] + r["jit"])
        measure(path, tmp)                       # fill the cache
        warm = min((measure(path, tmp) for _ in range(args.repeats)), key=lambda r: r["check"] + r["jit"])
        check_cold = min(check_process(path, "off") for _ in range(args.repeats))
        check_warm = min(check_process(path, tmp) for _ in range(args.repeats))
    assert warm["cached"] and not cold["cached"]
    header = "| case | import s | check s | codegen+JIT s | check+JIT s |\n|---|---|---|---|---|"
    rows = [f"| {name} | {r['import']:.3f} | {r['check']:.3f} | {r['jit']:.3f} | {r['check'] + r['jit']:.3f} |"
            for name, r in (("cold (no cache)", cold), ("warm (cache hit)", warm))]
    rows += [f"| `gammac check`, whole process, {name} | | | | {s:.3f} |"
             for name, s in (("no caches (prebuilt LALR tables)", check_cold), ("caches on", check_warm))]
    load = os.getloadavg()[0]
    info = (f"200-line effect, {cold['kernels']} kernels, best of {args.repeats} fresh processes; "
            f"goals: compiling under 0.5 s cold, `gammac check` under 0.3 s; load average {load:.1f}")
    report("compiling a 200-line effect", info, header, rows, args.record)


if __name__ == "__main__":
    main()
