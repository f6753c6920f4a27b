"""Compiled kernels are cached on disk and reused; the cache key follows the code."""

import ctypes

import numpy as np

from gamma.backends.jit import JitKernels
from gamma.frontend.checker import check
from gamma.frontend.parser import parse
from test_kernels import HEADER, TRANSPORT, GammaContext, ptr

RULE = "on hit(t: T, s: S) { t.a = t.a * {k} + s.p  s.q += exp(t.b) }"


def run(jit, effect):
    fn = TRANSPORT(jit.address[effect.kernels[0].symbol])
    ton, delta = np.array([2, 0.5], np.float32), np.zeros(5, np.float32)
    fn(ptr(ton), ptr(np.array([0, 0, 0, 3, 1], np.float32)), ptr(delta), ctypes.byref(GammaContext()))
    return ton.tolist(), delta.tolist()


def test_second_compile_comes_from_the_cache(tmp_path):
    effect = check(parse(HEADER + RULE.replace("{k}", "0.5"), "c.gamma"))
    first = JitKernels(effect, cache=tmp_path)
    assert not first.from_cache and len(list(tmp_path.glob("*.o"))) == 1
    second = JitKernels(effect, cache=tmp_path)
    assert second.from_cache
    assert run(first, effect) == run(second, effect) == ([4.0, 0.5], [0, 0, 0, 0, float(np.float32(np.exp(np.float32(0.5))))])


def test_a_changed_effect_is_compiled_again(tmp_path):
    for k in ("0.5", "0.25"):
        effect = check(parse(HEADER + RULE.replace("{k}", k), "c.gamma"))
        assert not JitKernels(effect, cache=tmp_path).from_cache
    assert len(list(tmp_path.glob("*.o"))) == 2


def test_cache_can_be_off(tmp_path):
    effect = check(parse(HEADER + RULE.replace("{k}", "1"), "c.gamma"))
    assert not JitKernels(effect, cache=None).from_cache
    assert not JitKernels(effect, cache=None).from_cache
