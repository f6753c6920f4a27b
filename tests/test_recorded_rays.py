"""record_rays (what bench_tracer.py casts as Embree's baseline) keeps every
ray the trace casts, in every motion mode: emission, reflections, parabola
chords and flow probes."""

import pytest

from conftest import ROOT
from gamma.backends.jit import JitKernels
from gamma.driver.running.runner import RunOptions, build_config
from gamma.driver.running.scene import load_scene
from gamma.frontend.checker import load

SCENE = ROOT / "examples" / "scenes" / "stanford-bunny.obj"
MOTION = {
    "straight": "motion straight = 1.0",
    "parabolic": "motion parabolic = 1.0\n    bounce 0.01",
    "flow": "motion flow = 1.0\n    step 0.002",
    "mixed": "motion straight = 0.3, parabolic = 0.3, flow = 0.3\n    bounce 0.01\n    step 0.002",
}


@pytest.mark.parametrize("mode", sorted(MOTION))
def test_recorded_rays_are_the_rays_the_trace_casts(rt, tmp_path, mode):
    path = tmp_path / "e.gamma"
    path.write_text(f"""
ton Weather {{
    {MOTION[mode]}
    carry patina = 1.0
}}
surface Copper {{
    reflectance straight = 0.2, parabolic = 0.2, flow = 0.05
    property patina = 0.0
}}
source air = environment(sphere) emits Weather count 20000
on settle(t: Weather, s: Copper) {{
    s.patina += 0.05 * t.patina
}}
""")
    effect = load(str(path))
    scene = load_scene(rt, str(SCENE), effect, [])
    opts = RunOptions(scene=str(SCENE), out="", surfels=5000, tons=20000, threads=2)
    kernels = JitKernels(effect)   # the config points into its machine code: keep it alive
    sim = rt.Simulation(scene.mesh, build_config(rt, effect, kernels, opts, scene.bounds, (0.0, -1.0, 0.0)))
    recorded = sim.record_rays(1)
    stats = sim.trace(1)
    assert stats["rays"] > 20000
    assert len(recorded) == stats["rays"]
