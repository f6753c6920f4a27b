"""A simulation taken over by another effect (``Simulation.reconfigure``,
what `gammac watch` does on a save): the same results as a fresh run, the
surfel setup skipped, and refused (then built afresh) when the surfels
cannot stay."""

import tempfile

import numpy as np
import pytest

from conftest import ROOT
from gamma.driver.running.events import CallbackWriter, IterationUpdated, SetupDone
from gamma.driver.running.runner import RunOptions, run, runtime_module
from gamma.driver.running.scene import load_scene
from gamma.frontend.checker import check
from gamma.frontend.parser import parse

PATINA = (ROOT / "examples" / "patina.gamma").read_text()
# another effect on the same surface: another rate, another property (another row width), a bounce
OTHER = PATINA.replace("surface Copper {", "surface Copper {\n    property grime = 0.0") + """
on settle(t: Weather, s: Copper) { s.grime += 0.5 * random() }
"""


def effect(text):
    return check(parse(text, str(ROOT / "examples" / "x.gamma")))


def go(eff, scene, reuse=None, **options):
    opts = RunOptions(scene="bunny", out=tempfile.mkdtemp(), **{
        "surfels": 5000, "tons": 20000, "iterations": 2, "threads": 2, "progress": False, **options})
    got = {}
    writers = [CallbackWriter(lambda e: got.__setitem__("sim", e.run.sim), events=(SetupDone,)),
               CallbackWriter(lambda e: got.__setitem__("rows", np.asarray(e.rows).copy()),
                              events=(IterationUpdated,))]
    run(eff, opts, writers, scene=scene, standard=False, reuse=reuse)
    return got


@pytest.fixture(scope="module")
def scene():
    return load_scene(runtime_module(), str(ROOT / "examples" / "scenes" / "stanford-bunny.obj"),
                      effect(PATINA), [], None)


def test_another_effect_on_kept_surfels_equals_a_fresh_run(scene):
    first = go(effect(PATINA), scene)
    other = effect(OTHER)
    reused = go(other, scene, reuse=first["sim"])
    fresh = go(other, scene)
    assert reused["sim"] is first["sim"]                       # taken over, not rebuilt
    assert reused["rows"].shape == fresh["rows"].shape != first["rows"].shape
    assert np.array_equal(reused["rows"], fresh["rows"])
    back = go(effect(PATINA), scene, reuse=reused["sim"])     # and back again
    assert np.array_equal(back["rows"], first["rows"])


def test_surfels_that_cannot_stay_are_built_afresh(scene):
    first = go(effect(PATINA), scene)
    for options in ({"seed": 2}, {"surfels": 4000}):
        reused = go(effect(PATINA), scene, reuse=first["sim"], **options)
        fresh = go(effect(PATINA), scene, **options)
        assert reused["sim"] is not first["sim"]
        assert np.array_equal(reused["rows"], fresh["rows"])
    # the refusal itself, through the binding: nothing changed
    from gamma.backends.jit import JitKernels
    from gamma.driver.running.runner import build_config

    eff = effect(PATINA)
    bad = build_config(runtime_module(), eff, JitKernels(eff),
                       RunOptions(scene="b", out="", surfels=5000, seed=9), scene.bounds, scene.down)
    bad.triangle_surface = scene.triangle_surface
    before = np.asarray(first["sim"].rows()).copy()
    with pytest.raises((ValueError, RuntimeError), match="reconfigure: another surfel count or seed"):
        first["sim"].reconfigure(bad)
    assert np.array_equal(np.asarray(first["sim"].rows()), before)


def test_prepared_points_bake_like_bake_points(scene):
    """The viewer's bake (neighbours found once) gives bake_points' results, bit for bit,
    for every iteration and after the simulation is taken over by another effect."""
    first = go(effect(PATINA), scene)
    sim = first["sim"]
    rng = np.random.default_rng(3)
    tris = np.asarray(scene.mesh.triangles())
    verts = np.asarray(scene.mesh.vertices())
    owner = rng.integers(0, len(tris), 3000).astype(np.int32)
    bary = rng.dirichlet([1, 1, 1], 3000)
    positions = np.einsum("kc,kcd->kd", bary, verts[tris[owner]]).astype(np.float32)
    normals = np.tile(np.float32([0, 1, 0]), (3000, 1))
    uvs = rng.random((3000, 2)).astype(np.float32)
    sim.prepare_points(positions, normals, owner, uvs, 2)
    assert sim.num_prepared_points == 3000
    for it in (1, 2):
        rows_a, rgb_a = sim.bake_points(positions, normals, owner, uvs, it, 2)
        rows_b, rgb_b = sim.bake_prepared(it, 2)
        assert np.array_equal(rows_a, rows_b) and np.array_equal(rgb_a, rgb_b)
    go(effect(OTHER), scene, reuse=sim)
    rows_a, rgb_a = sim.bake_points(positions, normals, owner, uvs, 2, 1)
    rows_b, rgb_b = sim.bake_prepared(2, 2)
    assert rows_b.shape[1] == sim.row_width and np.array_equal(rows_a, rows_b) and np.array_equal(rgb_a, rgb_b)


def test_cancel_stops_a_trace_and_leaves_the_rows(scene):
    """A CancelToken cancelled from another thread stops the tracing pass
    before its end; the rows are untouched and a trace with a fresh token
    runs normally."""
    import threading
    import time

    from gamma.backends.jit import JitKernels
    from gamma.driver.running.runner import build_config

    eff = effect(PATINA)
    kernels = JitKernels(eff)              # alive as long as the simulation traces
    cfg = build_config(runtime_module(), eff, kernels, RunOptions(scene="b", out="", surfels=5000, tons=20000,
                                                                 threads=2), scene.bounds, scene.down)
    cfg.triangle_surface = scene.triangle_surface
    sim = runtime_module().Simulation(scene.mesh, cfg)
    sim.trace(1)
    before = np.asarray(sim.rows()).copy()
    rt = runtime_module()
    stopped = rt.CancelToken()
    stopped.cancel()                                # before: the trace stops at once
    with pytest.raises(rt.Cancelled, match="^cancelled:"):
        sim.trace(2, cancel=stopped)
    assert np.array_equal(np.asarray(sim.rows()), before)
    sim.trace(2, cancel=rt.CancelToken())
    assert not np.array_equal(np.asarray(sim.rows()), before)
    token = rt.CancelToken()
    timer = threading.Timer(0.3, token.cancel)      # from another thread, while traces run
    timer.start()
    t0 = time.perf_counter()
    with pytest.raises(rt.Cancelled, match="^cancelled:"):
        for it in range(3, 100000):
            sim.trace(it, cancel=token)
    assert time.perf_counter() - t0 < 30


def test_texel_runs_bake_like_one_point_at_a_time(scene):
    """bake_points shares one neighbour search among each run of nearby
    texels (SceneIndex::smooth_block); the viewer's prepared points search
    one point at a time.  On a whole texture's texels (dense runs along the
    rows, jumping between charts) the two agree bit for bit, at 1 and 2 threads."""
    from gamma.driver.outputs.export import layout, pieces

    first = go(effect(PATINA), scene)
    sim = first["sim"]
    lay = layout(pieces(scene)[0], np.asarray(sim.corner_normals()), 512)
    texels, tris, bary = lay.texels()
    positions = np.einsum("kc,kcd->kd", bary, lay.positions.astype(np.float64)[lay.faces[tris]]).astype(np.float32)
    normals = np.einsum("kc,kcd->kd", bary, lay.normals.astype(np.float64)[lay.faces[tris]]).astype(np.float32)
    owner = lay.piece.triangles[tris].astype(np.int32)
    uvs = np.zeros((len(texels), 2), np.float32)
    assert len(texels) > 30_000
    sim.prepare_points(positions, normals, owner, uvs, 2)
    want_rows, want_look = sim.bake_prepared(1, 2)
    for threads in (1, 2):
        rows, look = sim.bake_points(positions, normals, owner, uvs, 1, threads)
        assert np.array_equal(rows, want_rows) and np.array_equal(look, want_look)
