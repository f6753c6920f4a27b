"""Compiled kernels against the reference interpreter.

Random well-typed rule bodies (seeded, so failures reproduce) are compiled
with llvmlite and run through ctypes on random inputs; the interpreter runs
the same AST.  Results must agree bit for bit (both are float32, in source
order, no fast-math); the only latitude is a NaN's payload.
"""

import ctypes
import random

import numpy as np
import pytest

from gamma import abi
from gamma.backends.jit import JitKernels
from gamma.frontend.checker import check
from gamma.backends.interp import Context, run_kernel
from gamma.frontend.parser import parse


_CTYPE = {"float": ctypes.c_float, "int32_t": ctypes.c_int32, "uint32_t": ctypes.c_uint32}


class GammaContext(ctypes.Structure):
    """Built from abi.CONTEXT_FIELDS, like the C header and the LLVM type."""

    _fields_ = [(name, _CTYPE[t] * n if n > 1 else _CTYPE[t]) for name, t, n in abi.CONTEXT_FIELDS]


def set_key(ctx, key: int) -> None:
    ctx.random_key[0], ctx.random_key[1] = key & 0xFFFFFFFF, key >> 32


FLOAT_P = ctypes.POINTER(ctypes.c_float)
TRANSPORT = ctypes.CFUNCTYPE(ctypes.c_int32, FLOAT_P, FLOAT_P, FLOAT_P, ctypes.POINTER(GammaContext))
UPDATE = ctypes.CFUNCTYPE(ctypes.c_int32, FLOAT_P, ctypes.POINTER(GammaContext))

HEADER = """
ton T { motion straight = 0.5 carry a = 1, b = 2 }
surface S { reflectance straight = 0.25 property p = 0, q = 1 }
source src = environment(sphere) emits T count 10
"""


def random_expr(rng, names, depth=0):
    pick = rng.random()
    if depth > 3 or pick < 0.3:
        if rng.random() < 0.4:
            return repr(round(rng.uniform(-4, 4), rng.choice([0, 1, 3])))
        return rng.choice(names)
    if pick < 0.75:
        op = rng.choice("+-*/")
        return f"({random_expr(rng, names, depth + 1)} {op} {random_expr(rng, names, depth + 1)})"
    if pick < 0.85:
        return f"-{random_expr(rng, names, depth + 1)}"
    fn = rng.choice(["min", "max", "clamp", "random"])
    if fn == "random":
        return "random()"
    n = 3 if fn == "clamp" else rng.choice([2, 3])
    return f"{fn}({', '.join(random_expr(rng, names, depth + 1) for _ in range(n))})"


def random_effect(rng):
    reads_t = ["t.a", "t.b", "s.p", "s.q", "s.reflectance.straight", "iteration", "interactions",
               "height", "position.x", "normal.y", "direction.z"]
    reads_u = ["s.p", "s.q", "s.reflectance.straight", "s.reflectance.flow", "iteration",
               "height", "position.z", "normal.x"]
    hit = [f"{rng.choice(['t.a', 't.b'])} {rng.choice(['=', '+=', '-=', '*='])} {random_expr(rng, reads_t)}"
           if rng.random() < 0.5 else
           f"{rng.choice(['s.p', 's.q'])} {rng.choice(['+=', '-='])} {random_expr(rng, reads_t)}"
           for _ in range(rng.randint(1, 5))]
    upd = [f"{rng.choice(['s.p', 's.q', 's.reflectance.straight'])} {rng.choice(['=', '+=', '-=', '*='])} "
           f"{random_expr(rng, reads_u)}" for _ in range(rng.randint(1, 5))]
    return (HEADER + "on hit(t: T, s: S) {\n  " + "\n  ".join(hit) + "\n}\n"
            + "update(s: S) {\n  " + "\n  ".join(upd) + "\n}\n")


def same(x, y):
    x, y = np.asarray(x, np.float32), np.asarray(y, np.float32)
    both_nan = np.isnan(x) & np.isnan(y)
    return bool(np.all(both_nan | (x.view(np.uint32) == y.view(np.uint32))))


def ptr(a):
    return a.ctypes.data_as(FLOAT_P)


def assert_hit_and_update_agree(hit_fn, upd_fn, hit_k, upd_k, ton, surf, ctx, ictx, text) -> None:
    """The compiled hit and update kernels (``hit_fn``, ``upd_fn``) and the
    interpreter's (``hit_k``, ``upd_k``) on the same gamma-ton and surfel rows
    and contexts: the same rows written bit for bit, the same status."""
    ton_c, delta_c = ton.copy(), np.zeros_like(surf)
    bad_c = hit_fn(ptr(ton_c), ptr(surf), ptr(delta_c), ctypes.byref(ctx))
    ton_i, delta_i = ton.copy(), np.zeros_like(surf)
    bad_i = run_kernel(hit_k, ton_i, surf.copy(), delta_i, ictx)
    assert same(ton_c, ton_i) and same(delta_c, delta_i) and bad_c == bad_i, (text, ton, surf)
    surf_c, surf_i = surf.copy(), surf.copy()
    bad_c = upd_fn(ptr(surf_c), ctypes.byref(ctx))
    bad_i = run_kernel(upd_k, None, surf_i, None, ictx)
    assert same(surf_c, surf_i) and bad_c == bad_i, (text, surf)


@pytest.mark.parametrize("seed", range(40))
def test_compiled_matches_interpreter(seed):
    rng = random.Random(seed)
    text = random_effect(rng)
    effect = check(parse(text, f"random{seed}.gamma"))
    jit = JitKernels(effect)
    hit = next(k for k in effect.kernels if k.event == "hit")
    upd = next(k for k in effect.kernels if k.event == "update")
    hit_fn = TRANSPORT(jit.address[hit.symbol])
    upd_fn = UPDATE(jit.address[upd.symbol])
    data = np.random.default_rng(seed)
    for trial in range(100):
        scale = 10.0 ** data.integers(-3, 4)
        ton = (data.standard_normal(2) * scale).astype(np.float32)
        surf = (data.standard_normal(effect.row_width) * scale).astype(np.float32)
        it, n = int(data.integers(1, 50)), int(data.integers(1, 10))
        vec = data.standard_normal((4, 3)).astype(np.float32)
        key = int(data.integers(0, 2**63)) * 2 + 1
        ctx = GammaContext(iteration=it, interactions=n, height=float(vec[3, 0]),
                           position=(ctypes.c_float * 3)(*vec[0]), normal=(ctypes.c_float * 3)(*vec[1]),
                           direction=(ctypes.c_float * 3)(*vec[2]))
        set_key(ctx, key)
        ictx = Context(iteration=it, interactions=n, height=vec[3, 0], position=vec[0],
                       normal=vec[1], direction=vec[2], random_key=key)

        ton_c, delta_c = ton.copy(), np.zeros_like(surf)
        bad_c = hit_fn(ptr(ton_c), ptr(surf), ptr(delta_c), ctypes.byref(ctx))
        ton_i, delta_i = ton.copy(), np.zeros_like(surf)
        bad_i = run_kernel(hit, ton_i, surf.copy(), delta_i, ictx)
        assert same(ton_c, ton_i) and same(delta_c, delta_i), (text, trial, ton, surf)
        assert bad_c == bad_i, (text, bad_c, bad_i)

        surf_c, surf_i = surf.copy(), surf.copy()
        bad_c = upd_fn(ptr(surf_c), ctypes.byref(ctx))
        bad_i = run_kernel(upd, None, surf_i, None, ictx)
        assert same(surf_c, surf_i) and bad_c == bad_i, (text, trial, surf)


def test_transport_never_writes_its_read_only_row():
    effect = check(parse(HEADER + "on hit(t: T, s: S) { s.p += 1  t.a = s.p }", "x.gamma"))
    jit = JitKernels(effect)
    fn = TRANSPORT(jit.address[effect.kernels[0].symbol])
    ton = np.zeros(2, np.float32)
    surf = np.array([0.25, 0, 0, 5, 1], np.float32)
    delta = np.zeros(5, np.float32)
    fn(ptr(ton), ptr(surf), ptr(delta), ctypes.byref(GammaContext()))
    assert list(surf) == [0.25, 0, 0, 5, 1]          # start-of-iteration state untouched
    assert list(delta) == [0, 0, 0, 1, 0]             # the write became a delta
    assert ton[0] == 5                                # reads see the start-of-iteration value


def test_random_is_a_function_of_key_and_site():
    effect = check(parse(HEADER + "on hit(t: T, s: S) { t.a = random()  t.b = random() }", "r.gamma"))
    jit = JitKernels(effect)          # keeps the code alive while fn is used
    fn = TRANSPORT(jit.address[effect.kernels[0].symbol])
    values = []
    for key in (1, 1, 2):
        ctx, ton = GammaContext(), np.zeros(2, np.float32)
        set_key(ctx, key)
        fn(ptr(ton), ptr(np.zeros(4, np.float32)), ptr(np.zeros(4, np.float32)), ctypes.byref(ctx))
        values.append(tuple(ton))
        assert tuple(ton) == (np.float32(abi.random_value(key, 0)), np.float32(abi.random_value(key, 1)))
    assert values[0] == values[1] and values[0] != values[2] and values[0][0] != values[0][1]
    assert all(0 <= v < 1 for v in values[0] + values[2])


def test_non_finite_results_are_not_stored_and_reported():
    effect = check(parse(HEADER + "on hit(t: T, s: S) { t.a = 1\n t.b = t.a / 0\n s.p += 0 * t.b\n t.a = 2 }",
                         "n.gamma"))
    kernel = effect.kernels[0]
    jit = JitKernels(effect)
    fn = TRANSPORT(jit.address[kernel.symbol])
    ton, delta = np.array([5, 7], np.float32), np.zeros(4, np.float32)
    bad = fn(ptr(ton), ptr(np.zeros(4, np.float32)), ptr(delta), ctypes.byref(GammaContext()))
    assert bad == 2                                   # the first statement giving inf
    assert list(ton) == [2, 7]                        # t.b kept its value; later statements ran
    assert kernel.statement_at(bad).target.text == "t.b"


APPEARANCE = ctypes.CFUNCTYPE(ctypes.c_int32, FLOAT_P, FLOAT_P, FLOAT_P, ctypes.POINTER(GammaContext))


def random_color(rng, depth=0):
    pick = rng.random()
    if depth > 2 or pick < 0.3:
        return rng.choice(['texture("a.png")', 'texture("b.png")', "rgb(s.p, 0.5, uv.u)",
                           "rgb(0.1, s.q, normal.y)", "color", "base_color()"])
    if pick < 0.5:
        return f"mix({random_color(rng, depth + 1)}, {random_color(rng, depth + 1)}, {random_expr(rng, ['s.p', 'uv.v', 'height'])})"
    if pick < 0.7:
        return f"({random_color(rng, depth + 1)} {rng.choice('+-')} {random_color(rng, depth + 1)})"
    if pick < 0.85:
        return f"({random_color(rng, depth + 1)} * {random_expr(rng, ['s.p', 'uv.u', 'position.x'])})"
    return f"-{random_color(rng, depth + 1)}"


@pytest.mark.parametrize("seed", range(20))
def test_appearance_matches_interpreter(tmp_path, seed):
    from PIL import Image

    from gamma.backends.interp import run_appearance

    for name in ("a.png", "b.png"):
        Image.new("RGB", (2, 2)).save(tmp_path / name)
    rng = random.Random(seed)

    def output():
        """An assignment to one of the look's outputs (SPEC §8a); the numbers
        may read the outputs assigned so far."""
        name = rng.choice(["color", "color", "roughness", "metallic", "displacement", "occlusion"])
        if name == "color":
            return f"color = {random_color(rng)}"
        return f"{name} = {random_expr(rng, ['s.p', 'uv.u', 'roughness', 'metallic', 'displacement'])}"

    body = "\n  ".join(output() if rng.random() < 0.7 else
                       f"if s.p < {rng.uniform(-1, 1):.2f} {{ {output()} }}"
                       for _ in range(rng.randint(1, 4)))
    path = tmp_path / "look.gamma"
    path.write_text(HEADER + f"appearance(s: S) {{\n  {body}\n}}\n")
    from gamma.frontend.checker import load

    effect = load(str(path))
    kernel = effect.appearance_kernels()[0]
    jit = JitKernels(effect)
    fn = APPEARANCE(jit.address[kernel.symbol])
    data = np.random.default_rng(seed)
    for _ in range(50):
        surf = (data.standard_normal(effect.row_width) * 2).astype(np.float32)
        textures = data.random(3 * len(effect.textures) + 3).astype(np.float32)   # + the base colour
        vec = data.standard_normal(9).astype(np.float32)
        ctx = GammaContext(height=float(vec[0]), position=(ctypes.c_float * 3)(*vec[1:4]),
                           normal=(ctypes.c_float * 3)(*vec[4:7]), uv=(ctypes.c_float * 2)(*vec[7:9]))
        ictx = Context(height=vec[0], position=vec[1:4], normal=vec[4:7])
        ictx.uv = vec[7:9]
        start = data.random(abi.APPEARANCE_WIDTH).astype(np.float32)    # the material's look there
        look = start.copy()
        bad_c = fn(ptr(surf), ptr(textures), ptr(look), ctypes.byref(ctx))
        want, bad_i = run_appearance(kernel, surf.copy(), textures, ictx, look=start)
        assert same(look, want) and bad_c == bad_i, (body, look, want)
