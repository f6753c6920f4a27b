"""Resolution-independent amounts (SPEC §13.2): with a source's `strength`,
`--surfels` and the γ-ton count change the noise, not the look.  The mean of
a property over a region agrees within a few per cent between 50k and 200k
surfels and between N and 4N γ-tons, and the noise falls with more γ-tons."""

import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, run_gammac
from gamma.driver.outputs.outputs import read_ply

EFFECT = """
ton Rain {
    motion parabolic = 0.8, flow = 0.2
    carry water = 1.0
    bounce 0.3
    step 0.02
}

surface Wall {
    reflectance parabolic = 0.4, flow = 0.05
    property wet = 0.0
}

surface Ground {
    reflectance parabolic = 0.4, flow = 0.05
    property wet = 0.0
}

assign "wall" = Wall
assign "ground" = Ground

source rain = directional(down) emits Rain count 40000 strength 1

on hit(t: Rain, s: *) {
    s.wet += 0.1 * t.water
}
"""


@pytest.fixture(scope="module")
def courtyard(tmp_path_factory):
    d = tmp_path_factory.mktemp("resolution")
    scene = d / "courtyard.obj"
    subprocess.run([sys.executable, str(ROOT / "examples" / "scenes" / "make_courtyard.py"), str(scene)],
                   check=True, capture_output=True)
    (d / "wet.gamma").write_text(EFFECT)
    return d, scene


def regions(m):
    wall = m["surface"] == 0
    return {
        "ground": (~wall) & (m["z"] > 0.6) & (np.abs(m["x"]) < 1.2),    # rain falls on it evenly
        "splash": wall & (m["nz"] > 0.9) & (m["y"] < 0.25),            # only splashes reach it
    }


def run(courtyard, surfels, tons):
    d, scene = courtyard
    out = d / f"out_{surfels}_{tons}"
    r = run_gammac("run", d / "wet.gamma", "--scene", scene, "--out", out, "--surfels", surfels,
                   "--tons", tons, "--iterations", 1, "--size", 16, "--samples", 1, "--ao", 0,
                   "--quiet", "--threads", 2)
    assert r.returncode == 0, r.stderr
    m = read_ply(out / "maps" / "iter_0001.ply")
    return {name: (m["wet"][mask].astype(np.float64), m["x"][mask], m["z"][mask])
            for name, mask in regions(m).items()}


def noise(values, x, z, cell=0.1):
    """Relative spread of a region's values about their 10 cm cell means: the
    noise, without the region's real (smooth) variation."""
    keys = np.floor(x / cell).astype(np.int64) * 100003 + np.floor(z / cell).astype(np.int64)
    _, inverse = np.unique(keys, return_inverse=True)
    means = np.bincount(inverse, values) / np.bincount(inverse)
    return np.sqrt(np.mean((values - means[inverse]) ** 2)) / values.mean()


def test_means_do_not_depend_on_surfels_or_gamma_tons(courtyard):
    base = run(courtyard, 50000, 40000)
    fine = run(courtyard, 200000, 40000)
    many = run(courtyard, 50000, 160000)
    for name in ("ground", "splash"):
        mean = base[name][0].mean()
        assert mean > 0, name
        assert fine[name][0].mean() == pytest.approx(mean, rel=0.05), name
        assert many[name][0].mean() == pytest.approx(mean, rel=0.05), name
    # Four times the gamma-tons: about half the noise (1/sqrt(4)).
    assert noise(*many["ground"]) < 0.65 * noise(*base["ground"])


def test_without_strength_amounts_are_per_gamma_ton(courtyard):
    """The behaviour kept for analytic work: no strength, every gamma-ton
    weighs 1, so four times the gamma-tons give four times the water."""
    d, scene = courtyard
    (d / "plain.gamma").write_text(EFFECT.replace(" strength 1", ""))
    sums = []
    for tons in (10000, 40000):
        out = d / f"plain_{tons}"
        r = run_gammac("run", d / "plain.gamma", "--scene", scene, "--out", out, "--surfels", 20000,
                       "--tons", tons, "--iterations", 1, "--size", 16, "--samples", 1, "--ao", 0, "--quiet")
        assert r.returncode == 0, r.stderr
        sums.append(read_ply(out / "maps" / "iter_0001.ply")["wet"].astype(np.float64).sum())
    assert sums[1] == pytest.approx(4 * sums[0], rel=0.05)
