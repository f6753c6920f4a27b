"""A simulation taken over by another effect (``Simulation.reconfigure``,
what `gammac watch` does on a save): the same results as a fresh run, the
surfel setup skipped, and refused (then built afresh) when the surfels
cannot stay."""

import tempfile

import numpy as np
import pytest

from conftest import ROOT
from gamma.driver.events import CallbackWriter, IterationUpdated, SetupDone
from gamma.driver.runner import RunOptions, run, runtime_module
from gamma.driver.scene import load_scene
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
    from gamma.driver.runner import build_config

    eff = effect(PATINA)
    bad = build_config(runtime_module(), eff, JitKernels(eff),
                       RunOptions(scene="b", out="", surfels=5000, seed=9), scene.bounds, scene.down)
    bad.triangle_surface = scene.triangle_surface
    before = np.asarray(first["sim"].rows()).copy()
    with pytest.raises((ValueError, RuntimeError), match="reconfigure: another surfel count or seed"):
        first["sim"].reconfigure(bad)
    assert np.array_equal(np.asarray(first["sim"].rows()), before)
