"""The checker's float32 constant folding (gamma.ir.float32, numpy-free so
that `gammac check` starts fast) rounds exactly as numpy's float32 does, and
`gammac check` indeed runs without importing numpy."""

import math
import random
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from gamma.ir.float32 import arith_f32, round_f32

SPECIAL = [0.0, -0.0, 1.0, -1.0, 0.1, 1e-45, 1.4e-45, 7e-46, 1e-40, -1e-40, 1.1754942e-38,
           3.4028235e38, 3.4028236e38, 3.40282357e38, 3.4028237e38, 1e39, -1e39, 1e300, -1e300,
           math.inf, -math.inf, math.nan, 16777217.0, 0.5 + 2 ** -25, 1 + 2 ** -24, 1 + 3 * 2 ** -25]


def same(a: float, b) -> bool:
    b = float(b)
    return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))


def samples(n=4000):
    rng = random.Random(7)
    values = list(SPECIAL)
    for _ in range(n):
        values.append(rng.uniform(-1, 1) * 10.0 ** rng.randint(-46, 40))
    return values


def test_rounding_matches_numpy():
    with np.errstate(over="ignore"):
        for x in samples():
            assert same(round_f32(x), np.float32(x)), x


@pytest.mark.parametrize("op", ["+", "-", "*", "/"])
def test_operations_match_numpy(op):
    rng = random.Random(op)
    values = samples(600)
    ufunc = {"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide}[op]
    with np.errstate(all="ignore"):
        for a in SPECIAL + values[:200]:
            for b in SPECIAL + [rng.choice(values) for _ in range(20)]:
                want = ufunc(np.float32(a), np.float32(b))
                assert same(arith_f32(op, a, b), want), (a, op, b)


def test_check_does_not_import_numpy(tmp_path):
    effect = tmp_path / "e.gamma"
    effect.write_text("param k = 1e-3 * 2 / 3\nton T { carry a = k }\nsurface S { property a = 0 }\n"
                      "source s = directional(down) emits T count 10\n"
                      "on settle(t: T, s: S) { s.a += t.a * fbm(position * 2, 3) + noise(normal) }\n")
    code = ("import sys\nfrom gamma.cli import main\nrc = main(['check', sys.argv[1]])\n"
            "assert 'numpy' not in sys.modules, 'gammac check imported numpy'\nsys.exit(rc)\n")
    r = subprocess.run([sys.executable, "-c", code, str(effect)], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr


def test_compiling_kernels_does_not_import_numpy(tmp_path):
    # codegen folds constant operations with arith_f32 too; numpy's import
    # (a third of a cold compile) is left to whoever needs arrays.
    effect = tmp_path / "e.gamma"
    effect.write_text("ton T { carry a = 1 }\nsurface S { property a = 0 }\n"
                      "source s = directional(down) emits T count 10\n"
                      "on settle(t: T, s: S) { s.a += t.a * (0.1 + 0.2) * smoothstep(0, 1, height) / 3 }\n")
    code = ("import os, sys\nos.environ['GAMMA_CACHE_DIR'] = 'off'\n"
            "from gamma.frontend.checker import load\nfrom gamma.backends.jit import JitKernels\n"
            "jit = JitKernels(load(sys.argv[1]))\nassert not jit.from_cache\n"
            "assert 'numpy' not in sys.modules, 'compiling imported numpy'\n")
    r = subprocess.run([sys.executable, "-c", code, str(effect)], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
