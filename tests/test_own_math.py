"""The project's own math (SPEC §11, "Own math"): the runtime extension
imports no transcendental function from the C library, the compiled kernels
call the runtime's functions and none of the C library's, and the reference
interpreter calls the very same functions."""

import math
import shutil
import subprocess

import pytest

from gamma import _runtime, ownmath
from gamma.backends.jit import JitKernels, compile_ir
from gamma.frontend.checker import check
from gamma.frontend.parser import parse
from test_kernels import HEADER

#: the C library's transcendental functions, float and double (and long double)
LIBM = {base + suffix
        for base in ("sin", "cos", "tan", "sincos", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh",
                     "exp", "exp2", "expm1", "exp10", "log", "log2", "log10", "log1p", "pow", "cbrt", "hypot",
                     "erf", "erfc", "lgamma", "tgamma")
        for suffix in ("", "f", "l")}


def undefined_symbols(path):
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("nm (binutils) is not installed")
    out = subprocess.run([nm, "-D", "--undefined-only", path], check=True, capture_output=True, text=True).stdout
    return {line.split()[-1].split("@")[0] for line in out.splitlines() if line.strip()}


def test_runtime_extension_imports_no_transcendental_function_from_libm():
    names = undefined_symbols(_runtime.__file__)
    assert names, "nm found no undefined symbols at all"
    assert sorted(names & LIBM) == []


def test_kernels_call_the_runtimes_own_math_and_no_libm():
    source = HEADER + """
on hit(t: T, s: S) { s.p += exp(t.a) + log(s.q) + pow(t.b, 0.5) }
"""
    effect = check(parse(source, "own.gamma"))
    kernels = JitKernels(effect, cache=None)
    text = str(compile_ir(kernels.ir_text))
    for symbol in ("gamma_expf", "gamma_logf", "gamma_powf"):
        assert f"@{symbol}(" in text
    called = {name for name in LIBM if f"@{name}(" in text or f"@llvm.{name}." in text}
    assert called == set()


def test_interpreter_calls_the_same_functions_as_the_runtime():
    # the addresses the JIT binds are the extension's own exports
    assert set(ownmath.addresses()) >= {symbol for symbol, _ in ownmath.FUNCTIONS.values()}
    expf, logf, powf = (ownmath.function(s) for s in ("gamma_expf", "gamma_logf", "gamma_powf"))
    assert expf(0.0) == 1.0 and logf(1.0) == 0.0 and powf(2.0, 10.0) == 1024.0
    assert logf(0.0) == -math.inf and math.isnan(logf(-1.0))
    assert powf(float("nan"), 0.0) == 1.0 and powf(1.0, float("nan")) == 1.0
    # correctly rounded where glibc's and numpy's agree on the exact answer
    assert expf(1.0) == pytest.approx(math.e, rel=6e-8)


def test_a_cached_shared_object_of_kernels_finds_the_own_math(tmp_path):
    """The effect cache links kernels into a shared object with the own math
    undefined; loaded, it resolves to the extension and computes what the JIT does."""
    import ctypes

    from gamma.backends.effect_cache import SharedKernels
    from gamma.backends.jit import position_independent_object
    from test_kernels import TRANSPORT, GammaContext

    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler")
    effect = check(parse(HEADER + "on hit(t: T, s: S) { s.p += exp(t.a) + log(s.q) + pow(t.b, 0.5) }", "c.gamma"))
    jit = JitKernels(effect, cache=None)
    (tmp_path / "k.o").write_bytes(position_independent_object(jit.ir_text))
    subprocess.run([compiler, "-shared", "-o", str(tmp_path / "k.so"), str(tmp_path / "k.o")], check=True)
    assert {"gamma_expf", "gamma_logf", "gamma_powf"} <= undefined_symbols(str(tmp_path / "k.so"))
    symbol = effect.kernels[0].symbol
    shared = SharedKernels(tmp_path / "k.so", [symbol], jit.ir_text, ())
    results = []
    for address in (jit.address[symbol], shared.address[symbol]):
        ton = (ctypes.c_float * 8)(0.7, 3.0)
        surf = (ctypes.c_float * 8)(0.25, 0.0, 0.0, 5.0, 2.5)  # p at slot 3, q at slot 4
        delta = (ctypes.c_float * 8)()
        TRANSPORT(address)(ton, surf, delta, ctypes.byref(GammaContext()))
        results.append(list(delta))
    assert results[0] == results[1] and results[0] != [0.0] * 8
