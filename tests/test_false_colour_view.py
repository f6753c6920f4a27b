"""The false-colour pictures of a run: its rays cast once (FalseColourView)
and the pictures coloured in the runtime give the bytes of rendering and
colouring each picture on its own (Simulation.render + FalseColourCanvas)."""

import numpy as np
import pytest

import gamma
from gamma.driver.outputs.outputs import FalseColourCanvas

EFFECT = """
ton Weather { motion straight = 1.0  carry patina = 1.0 }
surface Copper { reflectance straight = 0.5  property patina = 0.0 }
source air = environment(sphere) emits Weather count 20000
on settle(t: Weather, s: Copper) { s.patina += 0.05 * t.patina }
"""


@pytest.fixture(scope="module")
def finished(bumpy_obj):
    effect = gamma.compile(source=EFFECT)
    return gamma.run(effect, bumpy_obj, iterations=2, surfels=4000, seed=5, threads=2)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("size", [(96, 80), (161, 203)])
def test_a_view_gives_what_render_gives(finished, threads, size):
    sim = finished.session.sim
    eye, target, up, fov = finished.session.camera
    width, height = size
    view = sim.false_colour_view(eye, target, up, fov, width, height, threads)
    assert (view.width, view.height) == size
    rng = np.random.default_rng(threads)
    for values in (finished.properties["patina"],
                   rng.normal(size=sim.num_surfels).astype(np.float32) * 1e3):
        value, shade = sim.render(np.ascontiguousarray(values, np.float32), eye, target, up, fov, width, height,
                                  threads)
        got = view.values(values)
        assert np.isnan(value).any() and not np.isnan(value).all()      # background and bunny both in view
        assert np.array_equal(got, value, equal_nan=True)
        assert np.array_equal(view.shade(), shade, equal_nan=True)


@pytest.mark.parametrize("threads", [1, 2])
def test_pictures_in_the_runtime_are_the_canvas_pictures(finished, threads):
    sim = finished.session.sim
    eye, target, up, fov = finished.session.camera
    width, height = 120, 100
    view = sim.false_colour_view(eye, target, up, fov, width, height, threads)
    patina = finished.properties["patina"].astype(np.float32)
    rng = np.random.default_rng(11)
    cases = [(patina, 0.0, float(np.percentile(patina, 99.5))),       # as a run scales it
             (patina, -0.3, 0.05),                                       # clipped at both ends
             (rng.normal(size=sim.num_surfels).astype(np.float32), -1.5, 2.25),
             (np.full(sim.num_surfels, 3e38, np.float32), 0.0, 1.0)]      # sums overflow to infinity
    for values, vmin, vmax in cases:
        canvas = FalseColourCanvas(width, height, vmin, vmax, "patina")
        value, shade = sim.render(values, eye, target, up, fov, width, height, threads)
        with np.errstate(over="ignore"):
            want = canvas.picture(value, shade)
        got = view.picture(values, vmin, vmax, canvas.background, threads)
        assert got.dtype == np.uint8 and got.shape == (height, width, 3)
        assert np.array_equal(got, want)
        assert canvas.png(None, None, "t", picture=got) == canvas.png(value, shade, "t")


def test_a_view_refuses_values_of_another_size(finished):
    sim = finished.session.sim
    eye, target, up, fov = finished.session.camera
    view = sim.false_colour_view(eye, target, up, fov, 32, 32, 1)
    background = np.zeros((32, 32, 3), np.uint8)
    with pytest.raises(ValueError, match="values must have shape"):
        view.values(np.zeros(sim.num_surfels + 1, np.float32))
    with pytest.raises(ValueError, match="values must have shape"):
        view.picture(np.zeros(3, np.float32), 0.0, 1.0, background, 1)
    with pytest.raises(ValueError, match="background"):
        view.picture(np.zeros(sim.num_surfels, np.float32), 0.0, 1.0, background[:5], 1)
    with pytest.raises(ValueError, match="vmax"):
        view.picture(np.zeros(sim.num_surfels, np.float32), 1.0, 1.0, background, 1)


def test_the_view_rays_are_cast_at_the_setup_when_the_shape_never_changes():
    """FalseColourWriter casts the pictures' rays beside the loop when the
    geometry is final from the setup on, and after the loop otherwise."""
    from pathlib import Path
    from types import SimpleNamespace

    from gamma.driver.outputs.writers import FalseColourWriter

    calls = []

    class Sim:
        def false_colour_view(self, *args, cancel=None):
            calls.append(args)
            return "view"

    class Timings:
        def call(self, kind, fn, *args):
            assert kind == "renders"
            return fn(*args)

    def run_of(shape, width=8):
        return SimpleNamespace(first_iteration=1, sim=Sim(), behind=SimpleNamespace(timings=Timings()),
                               camera=((0, 0, 1), (0, 0, 0), (0, 1, 0), 40.0), threads=2, cancel=None,
                               opts=SimpleNamespace(width=width, height=8),
                               effect=SimpleNamespace(surfaces={"S": SimpleNamespace(shape=shape)}))

    writer = FalseColourWriter("p", Path("unused"))
    writer.on_setup_done(SimpleNamespace(run=run_of(None)))
    assert writer.casting is not None and writer.casting.result() == "view"
    assert calls == [((0, 0, 1), (0, 0, 0), (0, 1, 0), 40.0, 8, 8, 2)]
    # the shape changes: the geometry is final only after the loop
    for run in (run_of(object()), run_of(None, width=FalseColourWriter.VIEW_PIXELS)):
        writer = FalseColourWriter("p", Path("unused"))
        writer.on_setup_done(SimpleNamespace(run=run))
        assert writer.casting is None
    assert len(calls) == 1
