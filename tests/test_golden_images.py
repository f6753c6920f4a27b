"""Golden images: an appearance render of a small scene against committed
references.  Tolerance: mean absolute difference <= 1/255 per channel and at
most 0.5 % of pixels differing by more than 16/255 (room for an Embree build
that rounds a hit differently; a real change of shading, texture lookup or
interpolation exceeds it).  Regenerate, after looking at the new pictures,
with GAMMA_REGENERATE_GOLDEN=1."""

import os
import shutil

import numpy as np
import pytest
from PIL import Image

from conftest import ROOT, run_gammac

GOLDEN = ROOT / "tests" / "golden"
EFFECT = """
ton Dust { motion straight = 1.0  carry d = 1.0 }
surface Stone { reflectance straight = 0.4  property dust = 0.0 }
source sky = environment(hemisphere) emits Dust count 40000
on settle(t: Dust, s: Stone) { s.dust += 0.02 * t.d }
appearance(s: Stone) {
    let stripes = 0.5 + 0.5 * floor(fract(position.x * 4) * 2)
    let dusty = clamp(s.dust, 0, 1)
    color = mix(rgb(0.8, 0.75, 0.6) * (0.7 + 0.3 * stripes), rgb(0.2, 0.15, 0.1), dusty)
    metallic = (1 - stripes) * 2 * (1 - dusty)   // bare metal stripes, dulled by the dust
    roughness = 0.25 + 0.7 * dusty
    displacement = 0.02 * dusty                  // its slope bends the shading normal
}
"""


@pytest.mark.parametrize("iteration", [1, 3])
def test_appearance_render_matches_golden(tmp_path, iteration):
    (tmp_path / "dust.gamma").write_text(EFFECT)
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "dust.gamma", "--scene", GOLDEN / "open_box.obj", "--surfels", 2000,
                   "--iterations", 3, "--seed", 4, "--size", 96, "--samples", 4, "--ao", 4,
                   "--view", "0.4,1,0.8", "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    got_path = out / "renders" / f"iter_{iteration:04d}.png"
    want_path = GOLDEN / f"appearance_iter{iteration}.png"
    if os.environ.get("GAMMA_REGENERATE_GOLDEN"):
        shutil.copy(got_path, want_path)
    got = np.asarray(Image.open(got_path).convert("RGB"), np.float64)
    want = np.asarray(Image.open(want_path).convert("RGB"), np.float64)
    diff = np.abs(got - want)
    assert diff.mean() <= 1.0, diff.mean()
    assert np.mean(diff.max(axis=2) > 16) <= 0.005, np.mean(diff.max(axis=2) > 16)
