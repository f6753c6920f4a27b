"""Analytic scenes with known answers, run end to end through ``gammac run``.

Point source at the centre of a closed sphere, the paper's patina parameters
(k_s = 1, Delta_s = 0.5): nothing can escape; the first impact always
reflects, the second reflects with probability 1/2, the third always settles,
so the mean number of interactions is 1 + 1 + 1/2 = 2.5; and every settled
gamma-ton deposits exactly 0.05 of patina.
"""

import json

import pytest

from conftest import run_gammac
from meshes import icosphere, write_obj

PATINA_IN_SPHERE = """
ton Weather { motion straight = 1.0  carry patina = 1.0 }
surface Copper { reflectance straight = 0.5  property patina = 0.0 }
source leak = point(0, 0, 0) emits Weather count 100000
on settle(t: Weather, s: Copper) { s.patina += 0.05 * t.patina }
"""


@pytest.fixture(scope="module")
def sphere_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("sphere")
    write_obj(d / "sphere.obj", *icosphere(3, radius=2.0))
    (d / "patina.gamma").write_text(PATINA_IN_SPHERE)
    r = run_gammac("run", d / "patina.gamma", "--scene", d / "sphere.obj", "--surfels", 5000,
                   "--iterations", 2, "--threads", 2, "--quiet", "--out", d / "out")
    assert r.returncode == 0, r.stderr
    return json.loads((d / "out" / "summary.json").read_text())


def test_no_gamma_ton_escapes_a_closed_sphere(sphere_run):
    for it in sphere_run["iterations"]:
        assert it["emitted"] == 100000
        assert it["escaped"] == 0 and it["capped"] == 0
        assert it["settled"] == it["emitted"]


def test_mean_interactions_is_two_and_a_half(sphere_run):
    for it in sphere_run["iterations"]:
        mean = it["interactions"] / it["emitted"]
        assert abs(mean - 2.5) < 0.02, mean   # sigma = 0.5 / sqrt(1e5) = 0.0016


def test_deposited_patina_is_conserved(sphere_run):
    settled = 0
    for it in sphere_run["iterations"]:
        settled += it["settled"]
        total = it["property_sums"]["patina"]
        # float32 accumulation per surfel: relative rounding well below 1e-5
        assert total == pytest.approx(0.05 * settled, rel=1e-5)


def test_interaction_bound_caps_runaway_gamma_tons(tmp_path):
    write_obj(tmp_path / "sphere.obj", *icosphere(2))
    (tmp_path / "mirror.gamma").write_text(PATINA_IN_SPHERE.replace("straight = 0.5", "straight = 0.0"))
    r = run_gammac("run", tmp_path / "mirror.gamma", "--scene", tmp_path / "sphere.obj",
                   "--surfels", 1000, "--iterations", 1, "--tons", 500,
                   "--max-interactions", 7, "--quiet", "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    it = json.loads((tmp_path / "out" / "summary.json").read_text())["iterations"][0]
    assert it["capped"] == 500 and it["settled"] == 0
    assert it["interactions"] == 500 * 7
    assert it["property_sums"]["patina"] == 0
