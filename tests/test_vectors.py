"""Vectors in rules (SPEC §10-12): literals, arithmetic, components, lets,
``dot``/``cross``/``length``/``normalize``, ``mix`` of vectors and the ``up``
context value.

Compiled kernels are run against the reference interpreter on random
bodies and random inputs (IEEE special values included) and must agree bit
for bit; type misuse gives a typed error at its position; end to end, a rule
keyed on ``dot(normal, up)`` deposits on up-facing faces only, whichever way
the scene's ``down`` points.
"""

import ctypes
import random

import numpy as np
import pytest

from gamma.backends.interp import Context, run_appearance, run_kernel
from gamma.backends.jit import JitKernels
from gamma.frontend.checker import check
from gamma.frontend.diagnostics import GammaError
from gamma.frontend.parser import parse
from gamma.ir.builtins import ref_cross, ref_dot, ref_length, ref_normalize
from test_kernels import HEADER, TRANSPORT, UPDATE, GammaContext, assert_hit_and_update_agree, ptr, same, set_key

f32 = np.float32
SPECIAL = [0.0, -0.0, 1.0, -1.0, 0.5, 1e-42, 3.4e38, float("inf"), float("-inf"), float("nan"), 123.25]

VECTORS_T = ["position", "normal", "direction", "up", "(t.a, t.b, s.p)", "(1, -2, 0.5)"]
NUMBERS_T = ["t.a", "t.b", "s.p", "s.q", "height", "normal.y", "up.z", "2", "0.25"]
VECTORS_U = ["position", "normal", "up", "(s.p, s.q, 3)"]
NUMBERS_U = ["s.p", "s.q", "height", "iteration", "position.x", "1.5"]


def vector_expr(rng, vectors, numbers, depth=0):
    """A random vector-valued expression using every vector operation."""
    if depth > 2 or rng.random() < 0.25:
        return rng.choice(vectors)
    sub = lambda: vector_expr(rng, vectors, numbers, depth + 1)
    num = lambda: number_expr(rng, vectors, numbers, depth + 1)
    return rng.choice([
        lambda: f"({sub()} + {sub()})",
        lambda: f"({sub()} - {sub()})",
        lambda: f"({sub()} * {num()})",
        lambda: f"({num()} * {sub()})",
        lambda: f"({sub()} / {num()})",
        lambda: f"-{sub()}",
        lambda: f"cross({sub()}, {sub()})",
        lambda: f"normalize({sub()})",
        lambda: f"mix({sub()}, {sub()}, {num()})",
        lambda: f"({num()}, {num()}, {num()})",
    ])()


def number_expr(rng, vectors, numbers, depth=0):
    """A random number-valued expression reading vectors."""
    if depth > 2 or rng.random() < 0.3:
        return rng.choice(numbers)
    vec = lambda: vector_expr(rng, vectors, numbers, depth + 1)
    return rng.choice([
        lambda: f"dot({vec()}, {vec()})",
        lambda: f"length({vec()})",
        lambda: f"{vec()}.{rng.choice('xyz')}" if not vec().isidentifier() else f"({vec()}).x",
        lambda: f"cross({vec()}, {vec()}).{rng.choice('xyz')}",
        lambda: f"({vec()}).{rng.choice('xyz')}",
        lambda: f"noise({vec()})",
        lambda: f"fbm({vec()}, {rng.randint(1, 8)})",
        lambda: f"({rng.choice(numbers)} + {number_expr(rng, vectors, numbers, depth + 1)})",
    ])()


def random_vector_effect(rng):
    hit, upd = [], []
    for i in range(rng.randint(1, 4)):
        if rng.random() < 0.4:
            hit.append(f"let v{i} = {vector_expr(rng, VECTORS_T, NUMBERS_T)}")
            hit.append(f"t.a += v{i}.{rng.choice('xyz')} + dot(v{i}, up)")
        target = rng.choice(["t.a = ", "t.b += ", "s.p += ", "s.q -= "])
        hit.append(target + number_expr(rng, VECTORS_T, NUMBERS_T))
    for i in range(rng.randint(1, 3)):
        if rng.random() < 0.4:
            upd.append(f"let w{i} = {vector_expr(rng, VECTORS_U, NUMBERS_U)}")
            upd.append(f"s.q = length(w{i})")
        upd.append(rng.choice(["s.p = ", "s.q += "]) + number_expr(rng, VECTORS_U, NUMBERS_U))
    return (HEADER + "on hit(t: T, s: S) {\n  " + "\n  ".join(hit) + "\n}\n"
            + "update(s: S) {\n  " + "\n  ".join(upd) + "\n}\n")


def contexts(rng):
    """A compiled-side and an interpreter-side context with the same random values."""
    pick = lambda n: np.where(rng.random(n) < 0.2, rng.choice(SPECIAL, n),
                              rng.standard_normal(n) * 10.0 ** rng.integers(-2, 3, n)).astype(np.float32)
    vec = pick(13)
    it, n = int(rng.integers(1, 50)), int(rng.integers(1, 10))
    c3 = lambda a: (ctypes.c_float * 3)(*a)
    ctx = GammaContext(iteration=it, interactions=n, height=float(vec[12]), position=c3(vec[0:3]),
                       normal=c3(vec[3:6]), direction=c3(vec[6:9]), up=c3(vec[9:12]))
    key = int(rng.integers(0, 2**63))
    set_key(ctx, key)
    ictx = Context(iteration=it, interactions=n, height=vec[12], position=vec[0:3], normal=vec[3:6],
                   direction=vec[6:9], up=vec[9:12], random_key=key)
    return ctx, ictx, pick


@pytest.mark.parametrize("seed", range(12))
def test_random_vector_bodies_agree_bit_for_bit(seed):
    rng = random.Random(seed)
    text = random_vector_effect(rng)
    effect = check(parse(text, "vectors.gamma"))
    jit = JitKernels(effect)
    hit_k = next(k for k in effect.kernels if k.event == "hit")
    upd_k = next(k for k in effect.kernels if k.event == "update")
    hit_fn, upd_fn = TRANSPORT(jit.address[hit_k.symbol]), UPDATE(jit.address[upd_k.symbol])
    nrng = np.random.default_rng(seed)
    for _ in range(60):
        ctx, ictx, pick = contexts(nrng)
        ton, surf = pick(2), pick(effect.row_width)
        assert_hit_and_update_agree(hit_fn, upd_fn, hit_k, upd_k, ton, surf, ctx, ictx, text)


@pytest.mark.parametrize("builtin", ["dot", "cross", "length", "normalize", "component", "literal",
                                     "arith", "neg", "mix"])
def test_each_vector_operation_agrees_and_means_what_spec_says(builtin):
    """One body per operation, on random inputs: compiled == interpreter, and both equal
    the formula of SPEC §10/§11 written out here in numpy."""
    body = {
        "dot": "t.a = dot(position, normal)",
        "cross": "let c = cross(position, normal)\n t.a = c.x\n t.b = c.y\n s.p += c.z",
        "length": "t.a = length(position)",
        "normalize": "let c = normalize(position)\n t.a = c.x\n t.b = c.y\n s.p += c.z",
        "component": "t.a = (position + normal).y\n t.b = position.z",
        "literal": "let c = (t.a, t.b * 2, -t.a)\n t.a = c.z\n t.b = c.y",
        "arith": "let c = (position - normal) * t.a + normal / t.b\n t.a = c.x\n t.b = c.z",
        "neg": "t.a = (-position).x\n t.b = (-normal).z",
        "mix": "t.a = mix(position, normal, t.b).y",
    }[builtin]
    effect = check(parse(HEADER + f"on hit(t: T, s: S) {{\n {body}\n}}\n", "one.gamma"))
    kernel = effect.kernels[0]
    jit = JitKernels(effect)          # owns the machine code: kept alive while fn is called
    fn = TRANSPORT(jit.address[kernel.symbol])
    rng = np.random.default_rng(7)
    for _ in range(300):
        ctx, ictx, pick = contexts(rng)
        ton, surf = pick(2), pick(effect.row_width)
        ton_c, delta_c = ton.copy(), np.zeros_like(surf)
        fn(ptr(ton_c), ptr(surf), ptr(delta_c), ctypes.byref(ctx))
        ton_i, delta_i = ton.copy(), np.zeros_like(surf)
        run_kernel(kernel, ton_i, surf.copy(), delta_i, ictx)
        assert same(ton_c, ton_i) and same(delta_c, delta_i)
        p, n = tuple(ictx.position), tuple(ictx.normal)

        def stored(got, want, old=(ton[0], ton[1])):
            """As stored: a NaN or infinite result leaves the old value (SPEC §13.11)."""
            return same(got, [w if np.isfinite(w) else o for w, o in zip(want, old)])

        with np.errstate(all="ignore"):
            if builtin == "dot":
                assert stored([ton_c[0]], [f32(f32(f32(p[0] * n[0]) + f32(p[1] * n[1])) + f32(p[2] * n[2]))])
            elif builtin == "cross":
                want = (f32(p[1] * n[2]) - f32(p[2] * n[1]), f32(p[2] * n[0]) - f32(p[0] * n[2]),
                        f32(p[0] * n[1]) - f32(p[1] * n[0]))
                assert stored(ton_c, want[:2]) and stored([delta_c[3]], [f32(0) + want[2]], old=[0])
            elif builtin == "length":
                assert stored([ton_c[0]], [np.sqrt(ref_dot(p, p))])
            elif builtin == "normalize":
                length = ref_length(p)
                want = [f32(0)] * 3 if length == 0 else [f32(c / length) for c in p]
                assert stored(ton_c, want[:2]) and stored([delta_c[3]], [f32(0) + want[2]], old=[0])
            elif builtin == "mix":
                assert stored([ton_c[0]], [f32(p[1] + f32(f32(n[1] - p[1]) * ton[1]))])


def test_normalize_of_the_zero_vector_is_the_zero_vector():
    zero = (f32(0), f32(-0.0), f32(0))
    assert ref_normalize(zero) == (0, 0, 0)
    assert ref_cross((f32(1), f32(0), f32(0)), (f32(0), f32(1), f32(0))) == (0, 0, 1)
    effect = check(parse(HEADER + "on hit(t: T, s: S) {\n let z = normalize((0, -0, 0))\n"
                         " t.a = z.x + z.y + z.z\n t.b = length(normalize(position))\n}\n", "z.gamma"))
    kernel = effect.kernels[0]
    jit = JitKernels(effect)          # owns the machine code: kept alive while fn is called
    fn = TRANSPORT(jit.address[kernel.symbol])
    ctx = GammaContext(position=(ctypes.c_float * 3)(3, 4, 0))
    ton = np.array([5, 5], np.float32)
    assert fn(ptr(ton), ptr(np.zeros(5, np.float32)), ptr(np.zeros(5, np.float32)), ctypes.byref(ctx)) == 0
    assert ton[0] == 0 and ton[1] == 1


def test_up_is_the_scene_up_in_every_rule_kind():
    text = (HEADER + "on hit(t: T, s: S) { t.a = up.x + 2 * up.y + 4 * up.z }\n"
            "update(s: S) { s.p = dot(up, (1, 10, 100)) }\n"
            "appearance(s: S) { color = rgb(up.x, up.y, up.z) }\n")
    effect = check(parse(text, "up.gamma"))
    ictx = Context(up=(0, 0, 1))
    hit = next(k for k in effect.kernels if k.event == "hit")
    ton = np.zeros(2, np.float32)
    run_kernel(hit, ton, np.zeros(5, np.float32), np.zeros(5, np.float32), ictx)
    assert ton[0] == 4
    upd = next(k for k in effect.kernels if k.event == "update")
    surf = np.zeros(5, np.float32)
    run_kernel(upd, None, surf, None, ictx)
    assert surf[3] == 100
    look, _ = run_appearance(next(k for k in effect.kernels if k.event == "appearance"), surf, [0.7] * 3, ictx)
    rgb = look[:3]
    assert list(rgb) == [0, 0, 1]


# ---- type misuse: a clear error at the position of the offending expression -------------

ERRORS = [
    ("s.p += normal", "2:normal: error: expected a number here, but this is a vector"),
    ("s.p += dot(normal, 1)", "2:1): error: expected a vector here, but this is a number"),
    ("s.p += length(2)", "2:2): error: expected a vector here, but this is a number"),
    ("s.p += normal * position", "2:normal: error: '*' cannot combine a vector and a vector; use dot() or cross()"),
    ("s.p += (normal + 1).x", "2:normal + 1: error: '+' cannot combine a vector and a number"),
    ("s.p += (1, 2).x", "2:(1, 2): error: a vector has 3 components (x, y, z), not 2"),
    ("s.p += normal.w", "2:normal.w: error: 'normal' is a vector; its components are normal.x, normal.y and normal.z"),
    ("s.p += cross(normal, up).w", "2:w: error: a vector has the components x, y and z, not 'w'"),
    ("s.p += (t.a + 1).x", "2:(t.a: error: this is a number and has no fields; only a vector has components"),
    ("let k = 2\n s.p += k.x", "3:k.x: error: 'k' is a number and has no fields; only a vector has components"),
    ("if normal > 0 { s.p += 1 }", "2:normal: error: expected a number here, but this is a vector"),
    ("if up { s.p += 1 }", "2:up: error: expected a truth value (a comparison) here, but this is a vector"),
    ("s.p += mix(normal, 1, 0.5).x", "2:1,: error: expected a vector here, but this is a number"),
    ("s.p += noise(1)", "2:1): error: expected a vector here, but this is a number"),
    ("s.p += fbm(position, 9)", "2:9): error: the octaves of fbm() must be a constant whole number from 1 to 8, not 9"),
    ("s.p += fbm(position, t.a)", "2:t.a: error: the octaves of fbm() must be a constant whole number from 1 to 8"),
    ("s.p += fbm(position, 2.5)", "2:2.5: error: the octaves of fbm() must be a constant whole number from 1 to 8, not 2.5"),
    ("let up = 1\n s.p += up", "2:up: error: 'up' is already a name here; choose another"),
]


@pytest.mark.parametrize("body, message", ERRORS)
def test_type_misuse_is_a_positioned_error(body, message):
    """``message`` is LINE:at:TEXT: the column is where TEXT starts in the body's line."""
    line, at, rest = message.split(":", 2)
    body_line = body.split("\n")[int(line) - 2]
    indent = 2 if line == "2" else 1     # the body's first line follows a space
    message = f"{line}:{indent + body_line.index(at)}:{rest}"
    text = "on hit(t: T, s: S) {\n " + body + "\n}\n" + \
        "ton T { motion straight = 0.5 carry a = 1 }\nsurface S { property p = 0 }\n" \
        "source src = environment(sphere) emits T count 10\n"
    with pytest.raises(GammaError) as err:
        check(parse(text, "bad.gamma"))
    assert f"bad.gamma:{message}" in str(err.value), str(err.value)


def test_a_vector_let_and_components_in_appearance():
    text = (HEADER + "appearance(s: S) {\n let tint = (0.2, 0.4, 0.6) * 0.5 + up * 0.1\n"
            " color = rgb(tint.x, tint.y, (uv + tint).z) * (1 - uv.u)\n}\n"
            "on hit(t: T, s: S) { s.p += 1 }\nupdate(s: S) { s.q = 0 }\n")
    effect = check(parse(text, "look.gamma"))
    kernel = next(k for k in effect.kernels if k.event == "appearance")
    look, bad = run_appearance(kernel, np.zeros(5, np.float32), [0.7] * 3, Context(up=(0, 1, 0), uv=(0.5, 0.25)))
    rgb = look[:3]
    assert bad == 0
    want = np.array([f32(0.1) * f32(0.5), f32(f32(0.2) + f32(0.1)) * f32(0.5), f32(0.3) * f32(0.5)],
                    np.float32)
    assert np.allclose(rgb, want, rtol=1e-6)


# ---- end to end: dot(normal, up) deposits on up-facing faces only ----------------------------

DUST = """
ton Dust { carry grit = 1 }
surface Ground { property dust = 0 }
source sky = environment(sphere) emits Dust count 40000
on settle(t: Dust, s: Ground) {
    if dot(normal, up) > 0.9 { s.dust += t.grit }
}
"""


def _cube(lo=-1.0, hi=1.0):
    v = np.array([[x, y, z] for x in (lo, hi) for y in (lo, hi) for z in (lo, hi)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = []
    for a, b, c, d in quads:          # outward-facing triangles
        faces += [(a, b, c), (a, c, d)]
    return v, np.array(faces, np.int32)


@pytest.mark.parametrize("down", [(0, -1, 0), (0, 0, -1)])
def test_dust_settles_on_up_facing_faces_only(down):
    import gamma

    effect = gamma.compile(source=DUST, name="dust.gamma")
    verts, faces = _cube()
    result = gamma.run(effect, vertices=verts, faces=faces, iterations=1, surfels=6000, threads=2,
                       down=list(down))
    dust = result.properties["dust"]
    normals = result.surfel_normals
    facing = normals @ -np.asarray(down, np.float32)
    top = facing > 0.99
    # the cube's top face (one sixth of its area) and nothing else
    assert abs(top.mean() - 1 / 6) < 0.02
    # A hit runs the rule on the nearest surfel of its surface (SPEC §13.2): next to the
    # top's edges that can be a side's first row, and the deposit then spreads over the
    # splat kernel (2 sigma).  So a side holds dust only within 3 surfel spacings of the
    # top edge, and little of it; the bottom and the rest of the sides none.
    spacing = np.sqrt(24.0 / len(dust))
    height = result.surfel_positions @ -np.asarray(down, np.float32)
    side = ~top & (dust > 0)
    assert np.all(height[side] > 1 - 3 * spacing), height[side].min()
    assert dust[side].sum() < 0.04 * dust.sum()
    assert np.all(dust[facing < -0.5] == 0)
    assert (dust[top] > 0).mean() > 0.9
    # every gamma-ton settles at its first impact (no motion); under the sphere of
    # directions each face of the cube is hit by the same share: the top holds a sixth
    # of the settled grit (sigma about 1.5 %)
    settled = result.summary["iterations"][0]["settled"]
    assert float(dust.sum()) == pytest.approx(settled / 6, rel=0.06)
