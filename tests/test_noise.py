"""Procedural noise (SPEC §11, "Noise"): ``noise(p)`` and ``fbm(p, octaves)``.

Compiled kernels agree bit for bit with the reference interpreter (which
follows SPEC's algorithm step by step) on random points, special values
included; the values lie in [0, 1], are 0.5 at whole-number points, vary
smoothly and do not depend on the seed, the thread count or the iteration,
so a pattern in an update rule or an appearance block stays put.
"""

import ctypes

import numpy as np
import pytest

from gamma.backends.interp import Context, run_appearance, run_kernel
from gamma.backends.jit import JitKernels
from gamma.frontend.checker import check
from gamma.frontend.parser import parse
from gamma.ir.builtins import MAX_OCTAVES, _ref_fbm, _ref_noise
from test_kernels import HEADER, UPDATE, GammaContext, ptr, same

f32 = np.float32

BODY = "update(s: S) {\n  s.p = noise(position)\n" + "".join(
    f"  s.reflectance.{['straight', 'parabolic', 'flow'][i % 3]} = fbm(position, {i + 1})\n" for i in range(3)) + "}\n"


def _compiled(body: str):
    effect = check(parse(HEADER + body, "noise.gamma"))
    kernel = next(k for k in effect.kernels if k.event == "update")
    jit = JitKernels(effect)
    return effect, kernel, jit, UPDATE(jit.address[kernel.symbol])


def _points(rng, n):
    special = [0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 1e-30, 2.0**21, -(2.0**21) - 0.25, 1e9, -3e38,
               float("inf"), float("-inf"), float("nan")]
    pts = rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-2, 4, (n, 1))
    mask = rng.random((n, 3)) < 0.1
    pts[mask] = rng.choice(special, int(mask.sum()))
    return pts.astype(np.float32)


@pytest.mark.parametrize("octaves", range(1, MAX_OCTAVES + 1))
def test_noise_and_fbm_compiled_equal_the_interpreter(octaves):
    body = (f"update(s: S) {{\n  s.p = noise(position * 3.5 + normal)\n  s.q = fbm(position, {octaves})\n"
            f"  s.reflectance.flow = fbm((position.z, -position.x, position.y + 0.5), {octaves})\n}}\n")
    effect, kernel, jit, fn = _compiled(body)
    rng = np.random.default_rng(octaves)
    for p in _points(rng, 400):
        n = rng.standard_normal(3).astype(np.float32)
        surf = np.full(effect.row_width, 7, np.float32)
        surf_c, surf_i = surf.copy(), surf.copy()
        bad_c = fn(ptr(surf_c), ctypes.byref(GammaContext(position=(ctypes.c_float * 3)(*p),
                                                             normal=(ctypes.c_float * 3)(*n))))
        bad_i = run_kernel(kernel, None, surf_i, None, Context(position=p, normal=n))
        assert same(surf_c, surf_i) and bad_c == bad_i, (p, surf_c, surf_i)


def test_noise_range_lattice_and_smoothness():
    rng = np.random.default_rng(3)
    pts = (rng.random((3000, 3)) * 200 - 100).astype(np.float32)
    values = np.array([_ref_noise(None, None, [tuple(p)]) for p in pts])
    assert values.min() >= 0 and values.max() <= 1
    # spread: a pattern, not a constant (SPEC: within [0, 1], mean 0.5)
    assert abs(values.mean() - 0.5) < 0.01 and 0.1 < values.std() < 0.25
    assert values.min() < 0.1 and values.max() > 0.9
    for p in [(0, 0, 0), (3, -7, 12), (-100, 5, 2**20)]:
        assert _ref_noise(None, None, [tuple(f32(c) for c in p)]) == f32(0.5)
    # smooth: a step of 1e-3 changes the value by at most a few 1e-3
    steps = [abs(_ref_noise(None, None, [tuple(p)]) - _ref_noise(None, None, [tuple(p + f32(1e-3))]))
             for p in pts[:500]]
    assert max(steps) < 5e-3
    # fbm(p, 1) is noise(p); more octaves stay in [0, 1]
    for p in pts[:200]:
        assert _ref_fbm(None, None, [tuple(p), f32(1)]) == _ref_noise(None, None, [tuple(p)])
        assert 0 <= _ref_fbm(None, None, [tuple(p), f32(MAX_OCTAVES)]) <= 1
    # a non-finite component makes the signed value NaN, which the final clamp turns into 0
    assert _ref_noise(None, None, [(f32("nan"), f32(0), f32(0))]) == 0
    assert _ref_noise(None, None, [(f32(0), f32("-inf"), f32(0))]) == 0


def test_octaves_are_decorrelated():
    """Each octave has its own salt: fbm with two octaves is not noise plus a copy of itself."""
    rng = np.random.default_rng(5)
    pts = (rng.random((2000, 3)) * 50).astype(np.float32)
    one = np.array([_ref_noise(None, None, [tuple(p)]) for p in pts])
    two = np.array([_ref_fbm(None, None, [tuple(p), f32(2)]) for p in pts])
    assert 0.6 < np.corrcoef(one, two)[0, 1] < 0.99


NOISE_EFFECT = """
ton Air { carry a = 1 }
surface Stone { property speckle = 0, grain = 0, dirt = 0 }
source sky = environment(sphere) emits Air count 2000
on settle(t: Air, s: Stone) { s.dirt += t.a }
update(s: Stone) {
    s.speckle = noise(position * 4)
    s.grain = fbm(position * 2 + up, 5)
}
appearance(s: Stone) {
    let n = noise(position * 6)
    color = rgb(n, fbm(position * 3, 3), 0.5)
}
"""


def _sphere_run(threads, seed, iterations):
    import gamma
    from meshes import icosphere

    verts, faces = icosphere(3, radius=1.5)
    effect = gamma.compile(source=NOISE_EFFECT, name="speckle.gamma")
    return gamma.run(effect, vertices=verts, faces=faces, iterations=iterations, surfels=3000,
                     threads=threads, seed=seed)


def test_noise_in_rules_is_keyed_by_position_only():
    """The same at 1 and 2 threads and in every iteration, and equal to the interpreter
    at each surfel's position whatever the seed (the seed places the surfels, the noise
    depends on the position only)."""
    a = _sphere_run(threads=1, seed=1, iterations=2)
    b = _sphere_run(threads=2, seed=1, iterations=1)
    for name in ("speckle", "grain"):
        assert np.array_equal(a.history[0][name], a.history[1][name])
        assert np.array_equal(a.properties[name], b.properties[name])
    c = _sphere_run(threads=2, seed=77, iterations=1)
    kernel = next(k for k in c.effect.kernels if k.event == "update")
    columns = {n: i for i, n in enumerate(c.effect.surfaces["Stone"].properties)}
    for i in range(0, len(c.surfel_positions), 101):
        row = np.zeros(c.effect.row_width, np.float32)
        run_kernel(kernel, None, row, None, Context(position=c.surfel_positions[i], up=(0, 1, 0)))
        assert c.properties["speckle"][i] == row[3 + columns["speckle"]]
    effect = a.effect
    kernel = next(k for k in effect.kernels if k.event == "update")
    columns = {n: i for i, n in enumerate(effect.surfaces["Stone"].properties)}
    positions = a.surfel_positions
    for i in range(0, len(positions), 97):
        row = np.zeros(effect.row_width, np.float32)
        run_kernel(kernel, None, row, None, Context(position=positions[i], up=(0, 1, 0)))
        assert a.properties["speckle"][i] == row[3 + columns["speckle"]]
        assert a.properties["grain"][i] == row[3 + columns["grain"]]
    assert 0.05 < np.std(a.properties["speckle"]) < 0.3


def test_noise_in_appearance_is_a_stable_pattern_on_the_surface():
    """Colours at the mesh's vertices: identical between iterations and thread counts
    (no per-pixel static), and equal to the interpreter's at the vertex."""
    a = _sphere_run(threads=2, seed=1, iterations=1)
    b = _sphere_run(threads=1, seed=1, iterations=2)
    ca, cb = a.vertex_colours(), b.vertex_colours()
    assert np.array_equal(ca, cb)
    assert np.std(ca[:, 0]) > 0.05        # a pattern, not a flat colour
    kernel = next(k for k in a.effect.kernels if k.event == "appearance")
    verts = a.vertices
    for i in range(0, len(verts), 37):
        look, _ = run_appearance(kernel, np.zeros(a.effect.row_width, np.float32), [0.7] * 3,
                                 Context(position=verts[i]))
        rgb = look[:3]
        assert np.allclose(ca[i], np.clip(rgb, 0, 1), atol=0), (ca[i], rgb)
