"""Layered runs (SPEC §16.1 --init): ``gammac run B --init DIR_A`` and
``gamma.run(..., init=...)`` start B from A's final surfels.

Dust only accumulates and its deposits do not depend on the surface's state,
so a run of 3 iterations started from A's final state must hold A's dust
plus what the same 3 iterations deposit alone, surfel for surfel."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import ROOT, run_gammac

import gamma
from gamma.driver.outputs.outputs import read_ply

DUST = str(ROOT / "stdlib" / "dust.gamma")
TEAPOT = str(ROOT / "examples" / "scenes" / "teapot.obj")
BUNNY = str(ROOT / "examples" / "scenes" / "stanford-bunny.obj")
COMMON = ["--scene", TEAPOT, "--surfels", "8000", "--quiet", "--size", "32", "--samples", "1", "--ao", "0"]

#: B: the dust recipe with a property A does not have.
DUST_AND_GRIME = (ROOT / "stdlib" / "dust.gamma").read_text().replace(
    "surface Marble {", "surface Marble {\n    property grime = 0.25", 1)


def last_map(folder, iteration):
    return read_ply(folder / "maps" / f"iter_{iteration:04d}.ply")


@pytest.fixture(scope="module")
def run_a(tmp_path_factory):
    out = tmp_path_factory.mktemp("layered") / "A"
    r = run_gammac("run", DUST, *COMMON, "--iterations", "2", "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def test_an_init_run_holds_a_s_amounts_plus_its_own_deposits(run_a, tmp_path):
    b, alone = tmp_path / "B", tmp_path / "alone"
    for out, extra in ((b, ["--init", run_a]), (alone, [])):
        r = run_gammac("run", DUST, *COMMON, "--iterations", "3", "--out", out, *extra)
        assert r.returncode == 0, r.stderr
    a_dust = last_map(run_a, 2)["dust"].astype(np.float64)
    b_dust = last_map(b, 3)["dust"].astype(np.float64)
    alone_dust = last_map(alone, 3)["dust"].astype(np.float64)
    assert a_dust.sum() > 0 and alone_dust.sum() > 0
    expected = a_dust + alone_dust
    assert abs(b_dust.sum() - expected.sum()) <= 0.01 * expected.sum()
    assert np.allclose(b_dust, expected, rtol=1e-5, atol=1e-6), np.abs(b_dust - expected).max()
    summary = json.loads((b / "summary.json").read_text())
    assert summary["init"] == {"from": f"run folder '{run_a}'", "iteration": 2, "taken": {"Marble": ["dust"]}}
    # the first iteration of B already holds A's dust: nothing was reset before it
    assert last_map(b, 1)["dust"].sum() > a_dust.sum()


def test_properties_a_lacks_start_at_b_s_initial_values(run_a, tmp_path):
    effect = tmp_path / "dust-grime.gamma"
    effect.write_text(DUST_AND_GRIME)
    r = run_gammac("run", effect, *COMMON, "--iterations", "1", "--out", tmp_path / "B", "--init", run_a)
    assert r.returncode == 0, r.stderr
    b = last_map(tmp_path / "B", 1)
    assert np.all(b["grime"] == np.float32(0.25)), "grime: B's initial value, A has none"
    assert b["dust"].sum() > last_map(run_a, 2)["dust"].sum()


@pytest.mark.parametrize("change, message", [
    (["--surfels", "8001"], "--surfels: A had 8000, this run 8001"),
    (["--seed", "7"], "--seed: A had 1, this run 7"),
    (["--scene", BUNNY], "scene: A ran on"),
])
def test_an_init_of_another_scene_count_or_seed_is_refused_with_what_differs(run_a, tmp_path, change, message):
    out = tmp_path / "B"
    r = run_gammac("run", DUST, *COMMON, "--iterations", "1", "--out", out, "--init", run_a, *change)
    assert r.returncode == 1, r.stderr
    assert "is not a run of this scene, surfel count and seed" in r.stderr and message in r.stderr, r.stderr
    assert not out.exists(), "a refused run writes nothing"


def test_an_init_folder_without_a_run_is_refused(tmp_path):
    r = run_gammac("run", DUST, *COMMON, "--out", tmp_path / "B", "--init", tmp_path / "nothing")
    assert r.returncode == 1 and "holds no run (no summary.json)" in r.stderr, r.stderr


def test_the_python_api_takes_a_result_or_a_folder(run_a):
    effect = gamma.compile(DUST)
    options = dict(surfels=8000, seed=1, iterations=3)
    first = gamma.run(effect, TEAPOT, iterations=2, surfels=8000)
    from_result = gamma.run(effect, TEAPOT, init=first, **options)
    from_folder = gamma.run(effect, TEAPOT, init=str(run_a), **options)
    assert np.array_equal(first.properties["dust"], last_map(run_a, 2)["dust"])
    assert np.array_equal(from_result.properties["dust"], from_folder.properties["dust"])
    with pytest.raises(gamma.RunError, match="--seed: A had 1, this run 2"):
        gamma.run(effect, TEAPOT, init=first, surfels=8000, seed=2, iterations=1)
