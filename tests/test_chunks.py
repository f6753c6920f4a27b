"""The runtime's trace in pieces (what gammac run --ray distributes):
tracing chunk ranges against the same rows and merging every chunk in chunk
order equals trace() bit for bit, however the chunks are split: the rows
(deposits spread by the splat kernel, weighted by source strength), the
counters and the mass books of the carried properties."""

import numpy as np
import pytest

from gamma.backends.jit import JitKernels
from gamma.driver.running.runner import RunOptions, build_config, runtime_module
from gamma.driver.running.scene import load_scene
from gamma.frontend.checker import check
from gamma.frontend.parser import parse

EFFECT = """
ton Weather { motion straight = 1.0  carry patina = 1.0, grime = 0.0 }
surface Copper { reflectance straight = 0.5  property patina = 0.0, grime = 0.5 }
source air = environment(sphere) emits Weather count 4000
source drip = point(0, 1, 0) emits Weather count 1500 strength 0.5
on hit(t: Weather, s: Copper) {
    t.grime += 0.1 * s.grime * random()
    s.grime -= 0.01 * s.grime
}
on settle(t: Weather, s: Copper) { s.patina += 0.05 * t.patina + 0.01 * t.grime }
update(s: Copper) { s.grime = max(s.grime, 0) + 0.001 * random() }
"""


def simulations_of(text: str, scene_path, seed: int):
    """(runtime, kernels, make(threads) -> a Simulation of ``text`` on the scene)."""
    rt = runtime_module()
    effect = check(parse(text, "chunks.gamma"))
    kernels = JitKernels(effect)
    scene = load_scene(rt, str(scene_path), effect, [], None)

    def make(threads):
        opts = RunOptions(scene=str(scene_path), out="", surfels=3000, seed=seed, threads=threads)
        cfg = build_config(rt, effect, kernels, opts, scene.bounds, scene.down)
        cfg.triangle_surface = scene.triangle_surface
        return rt.Simulation(scene.mesh, cfg)

    return rt, kernels, make


@pytest.fixture(scope="module")
def simulations(bumpy_obj):
    return simulations_of(EFFECT, bumpy_obj, 9)


#: Spores from a point, then from the moss they grew (a surface source weighted by moss and random()).
SPREADING = """
ton Spore { motion straight = 0.5  carry seed = 1.0 }
surface Stone { reflectance straight = 0.3  property moss = 0.0 }
source start = point(0, 1, 0) emits Spore count 2000
source spread = surface(Stone, emission = cosine, weight = s.moss * (0.5 + random())) emits Spore count 3000
on settle(t: Spore, s: Stone) { s.moss += 0.1 * t.seed }
"""


def test_chunks_merged_in_order_equal_trace_with_a_surface_source(bumpy_obj):
    """The weights are worked out from the same rows wherever a chunk is traced."""
    rt, _, make = simulations_of(SPREADING, bumpy_obj, 5)
    whole, pieces = make(2), make(1)
    # iteration 1: no moss yet, so the surface source is silent; then it spreads
    assert pieces.num_chunks(1) == -(-2000 // rt.CHUNK_SIZE)
    for it in (1, 2, 3):
        expected = whole.trace(it)
        whole.update(it)
        n = pieces.num_chunks(it)
        got = pieces.merge_chunks(it, pieces.trace_chunks(it, 0, n))
        pieces.update(it)
        assert got["emitted"] == expected["emitted"] and got["silent"] == expected["silent"]
        assert np.array_equal(pieces.rows(), whole.rows()), f"iteration {it}"
    assert expected["silent"] == 0 and expected["emitted"] == 5000


COUNTERS = ("emitted", "settled", "escaped", "missed", "capped", "interactions", "rays", "bounces", "flow_steps",
            "drips", "segments")


@pytest.mark.parametrize("splits", [[(0, 6)], [(0, 1), (1, 6)], [(0, 3), (3, 4), (4, 6)],
                                    [(i, i + 1) for i in range(6)]])
def test_chunks_merged_in_order_equal_trace(simulations, splits):
    rt, _, make = simulations
    whole, pieces = make(2), make(1)
    assert pieces.num_chunks(1) == 6 == -(-5500 // rt.CHUNK_SIZE)
    for it in (1, 2, 3):
        expected = whole.trace(it)
        whole.update(it)
        before = pieces.rows().copy()
        chunks = [c for a, b in splits for c in pieces.trace_chunks(it, a, b)]
        assert np.array_equal(pieces.rows(), before)          # tracing leaves the rows alone
        assert len(chunks) == 6 and all(s.dtype == np.uint32 and d.shape == (len(s), 2) for s, d, _ in chunks)
        got = pieces.merge_chunks(it, chunks)
        pieces.update(it)
        assert {k: got[k] for k in COUNTERS} == {k: expected[k] for k in COUNTERS}
        # the books of patina and grime (carried and surface properties), doubles summed in chunk order
        assert len(expected["mass"]) == 2 and expected["mass"][0]["deposited"] > 0
        assert got["mass"] == expected["mass"]
        assert np.array_equal(pieces.rows(), whole.rows()), f"iteration {it}"


@pytest.mark.parametrize("batches", [[(0, 6)], [(0, 1), (1, 6)], [(i, i + 1) for i in range(6)]])
def test_chunks_merged_batch_by_batch_equal_trace(simulations, batches):
    """merge_begin / merge_add / merge_end: each batch added as soon as it is
    traced (what the Ray driver does, so it never holds a whole pass)."""
    _, _, make = simulations
    whole, pieces = make(2), make(1)
    for it in (1, 2):
        expected = whole.trace(it)
        whole.update(it)
        pieces.merge_begin(it)
        for a, b in batches:
            pieces.merge_add(pieces.trace_chunks(it, a, b))
        got = pieces.merge_end()
        pieces.update(it)
        assert {k: got[k] for k in COUNTERS} == {k: expected[k] for k in COUNTERS}
        assert got["mass"] == expected["mass"]
        assert 0 < got["log_records_peak"] <= expected["log_records_peak"]
        assert np.array_equal(pieces.rows(), whole.rows()), f"iteration {it}"


def test_batched_merge_refuses_batches_that_do_not_fit(simulations):
    _, _, make = simulations
    sim = make(1)
    before = sim.rows().copy()
    chunks = sim.trace_chunks(1, 0, 6)
    with pytest.raises(ValueError, match="no merge begun"):
        sim.merge_add(chunks[:2])
    sim.merge_begin(1)
    sim.merge_add(chunks[:4])
    with pytest.raises(ValueError, match="has 6 chunks, not 8 or more"):
        sim.merge_add(chunks[2:6])
    with pytest.raises(ValueError, match="abandoned"):
        sim.merge_end()
    sim.merge_begin(1)
    sim.merge_add(chunks[:5])
    with pytest.raises(ValueError, match="has 6 chunks, not 5"):
        sim.merge_end()
    assert np.array_equal(sim.rows(), before)
    sim.merge_begin(1)
    sim.merge_add(chunks[:3])
    sim.merge_add(chunks[3:])
    assert sim.merge_end()["emitted"] == 5500


def test_merge_refuses_chunks_that_do_not_fit(simulations):
    _, _, make = simulations
    sim = make(1)
    chunks = sim.trace_chunks(1, 0, 6)
    with pytest.raises(ValueError, match="has 6 chunks, not 5"):
        sim.merge_chunks(1, chunks[:5])
    surfels, deltas, stats = chunks[0]
    bad = [(np.full_like(surfels, 10**6), deltas, stats)] + chunks[1:]
    if len(surfels):
        with pytest.raises(ValueError, match="out of range"):
            sim.merge_chunks(1, bad)
    with pytest.raises(ValueError, match="not within the 6 chunks"):
        sim.trace_chunks(1, 4, 7)


def test_merge_spreads_the_deposits_with_the_splat_kernel(simulations):
    """The chunks hold each rule's deltas at the surfel it hit; the merge
    spreads them over neighbouring surfels (SPEC §13.2) as trace() does, so
    the rows differ from the deltas added where they were logged, while each
    column's total is kept."""
    _, _, make = simulations
    sim = make(1)
    before = sim.rows().copy()
    chunks = sim.trace_chunks(1, 0, sim.num_chunks(1))
    at_hits = before.astype(np.float64)
    for surfels, deltas, _ in chunks:
        np.add.at(at_hits[:, -2:], surfels.astype(np.int64), deltas)
    sim.merge_chunks(1, chunks)
    after = sim.rows().astype(np.float64)
    assert not np.allclose(after[:, -2:], at_hits[:, -2:], rtol=0, atol=1e-6)
    assert np.allclose(after[:, -2:].sum(axis=0), at_hits[:, -2:].sum(axis=0), rtol=1e-4)


#: Every motion, rules on hit, bounce, flow and settle, a measure, a carried
#: mass property and two sources of other strengths: what the batched tracer
#: reorders (casts, surfel lookups and paths ahead of the rules) all at work.
EVERY_MOTION = """
ton Drop { motion straight = 0.4, parabolic = 0.3, flow = 0.2  carry water = 1.0 }
surface Stone { reflectance straight = 0.1, parabolic = 0.05, flow = 0.02  property wet = 0.0, dirt = 0.2 }
source rain = environment(sphere) emits Drop count 5000
source leak = point(0, 1, 0) emits Drop count 2000 strength 2
on hit(t: Drop, s: Stone) { s.dirt += 0.01 * t.water * accessibility }
on bounce(t: Drop, s: Stone) { t.water -= 0.1 * t.water * random() }
on flow(t: Drop, s: Stone) { s.wet += 0.05 * t.water }
on settle(t: Drop, s: Stone) { s.wet += t.water }
update(s: Stone) { s.dirt = 0.9 * s.dirt }
"""


@pytest.mark.parametrize("threads", [1, 2])
def test_the_batched_tracer_gives_the_plain_one_at_a_time_tracers_logs(bumpy_obj, threads):
    """Tracer::run_chunks traces groups of gamma-tons phase by phase; the
    plain form follows each gamma-ton to its end before the next.  Their
    chunk logs are the same records, deltas and counters, bit for bit, over
    iterations whose rows the rules changed."""
    rt, _, make = simulations_of(EVERY_MOTION, bumpy_obj, 4)
    sim = make(threads)
    for it in (1, 2, 3):
        n = sim.num_chunks(it)
        batched = sim.trace_chunks(it, 0, n)
        plain = sim.trace_chunks(it, 0, n, one_at_a_time=True)
        assert len(batched) == len(plain) == n
        for (s_b, d_b, st_b), (s_p, d_p, st_p) in zip(batched, plain):
            assert np.array_equal(s_b, s_p) and np.array_equal(d_b, d_p)
            assert st_b == st_p
        assert sum(len(s) for s, _, _ in batched) > 1000 and sum(st["bounces"] for *_, st in batched) > 0
        sim.merge_chunks(it, batched)
        sim.update(it)
