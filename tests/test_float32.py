"""The checker's float32 constant folding without numpy (gamma.ir.float32)
against numpy's float32, bit for bit; and ``gammac check`` not importing
numpy (its start-up time, issue 14)."""

import math
import struct
import subprocess
import sys

import numpy as np

from gamma.ir.float32 import f32, fold


def bits(x: float) -> int:
    return struct.unpack("<Q", struct.pack("<d", x))[0]


def same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or bits(a) == bits(b)


SPECIAL = [0.0, -0.0, 1.0, -1.0, 0.1, 1 / 3, 3.4028234663852886e38, 3.4028235e38, 3.40282357e38, 1e39, -1e39,
           1e-45, 1.4e-45, 7e-46, 1e-40, 1.1754943508222875e-38, math.inf, -math.inf, math.nan, 1e99, -1e300,
           16777217.0, 0.30000000000000004, 2.0 ** -149, 2.0 ** -150, 3 * 2.0 ** -151]


def numbers():
    rng = np.random.default_rng(5)
    values = list(SPECIAL)
    values += list(rng.standard_normal(300) * 10.0 ** rng.integers(-40, 40, 300))
    values += list(rng.uniform(-4, 4, 200))
    return [float(v) for v in values]


def test_rounding_matches_numpy():
    with np.errstate(all="ignore"):
        for v in numbers():
            assert same(f32(v), float(np.float32(v))), v


def test_operations_match_numpy():
    values = numbers()
    rng = np.random.default_rng(6)
    pairs = [(a, b) for a in SPECIAL for b in SPECIAL]
    pairs += [(values[i], values[j]) for i, j in rng.integers(0, len(values), (3000, 2))]
    with np.errstate(all="ignore"):
        for a, b in pairs:
            x, y = np.float32(a), np.float32(b)
            for op, want in (("+", x + y), ("-", x - y), ("*", x * y), ("/", x / y)):
                assert same(fold(op, a, b), float(want)), (op, a, b)


def test_check_does_not_import_numpy(tmp_path):
    effect = tmp_path / "e.gamma"
    effect.write_text("param k = 1e-3 * 2 / 3\nton T { motion straight = 1 carry x = 1 }\n"
                      "surface S { property wet = 0 }\nsource s = environment(sphere) emits T count 10\n"
                      "on hit(t: T, s: S) { s.wet += t.x * k + 0.1 }\n")
    code = ("import sys; from gamma.cli import main; rc = main(['check', sys.argv[1]]); "
            "print('numpy' in sys.modules, rc)")
    out = subprocess.run([sys.executable, "-c", code, str(effect)], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "0"], out.stdout + out.stderr
