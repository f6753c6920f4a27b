"""The runtime keeps the compiled kernels alive: a Config built from a
JitKernels holds it, and a Simulation holds its config, so a caller that
drops its own handle to the kernels cannot leave the runtime calling into
freed machine code (the kernels go when the last holder goes)."""

import gc
import weakref

import numpy as np

import gamma
from gamma.backends.jit import JitKernels
from gamma.driver.running.runner import RunOptions, build_config, runtime_module

EFFECT = """
ton Drop { carry wet = 1 }
surface Ground { property wet = 0 }
source rain = directional(down) emits Drop count 2000
on settle(t: Drop, s: Ground) { s.wet += t.wet }
"""


def plane():
    rt = runtime_module()
    vertices = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float32)
    return rt, rt.Mesh.from_arrays(vertices, np.array([[0, 2, 1], [0, 3, 2]], np.int32))


def test_a_simulation_keeps_its_kernels_alive(tmp_path):
    effect = gamma.compile(source=EFFECT)
    rt, mesh = plane()
    kernels = JitKernels(effect, cache=None)
    alive = weakref.ref(kernels)
    opts = RunOptions(scene="<plane>", out=str(tmp_path), surfels=500, threads=1)
    cfg = build_config(rt, effect, kernels, opts, ([-1, 0, -1], [1, 0, 1]), (0, -1, 0))
    assert cfg.code_owner is kernels
    sim = rt.Simulation(mesh, cfg)
    del kernels, cfg
    gc.collect()
    assert alive() is not None                 # the simulation still needs the machine code
    stats = sim.trace(1)
    sim.update(1)
    assert stats["settled"] == 2000
    wet = sim.rows()[:, -1]
    assert abs(float(wet.sum()) - 2000) < 1e-2  # every drop's settle kernel ran and deposited
    del sim
    gc.collect()
    assert alive() is None                     # and nothing keeps it once the simulation is gone


def test_reconfigure_lets_go_of_the_previous_kernels(tmp_path):
    effect = gamma.compile(source=EFFECT)
    rt, mesh = plane()
    opts = RunOptions(scene="<plane>", out=str(tmp_path), surfels=500, threads=1)
    bounds = ([-1, 0, -1], [1, 0, 1])
    first = JitKernels(effect, cache=None)
    first_alive = weakref.ref(first)
    sim = rt.Simulation(mesh, build_config(rt, effect, first, opts, bounds, (0, -1, 0)))
    second = JitKernels(effect, cache=None)
    sim.reconfigure(build_config(rt, effect, second, opts, bounds, (0, -1, 0)))
    del first, second
    gc.collect()
    assert first_alive() is None
    assert sim.trace(1)["settled"] == 2000
