"""Smooth shading of renders (SPEC §16, "Shading"): a coarse sphere renders
without facets, `--shading flat` and a scene file's `"shading": "flat"` keep
them, and `gammac render DIR` re-renders with the run's shading."""

import json

import numpy as np
from PIL import Image

from conftest import run_gammac
from meshes import icosphere, write_obj

EFFECT = """
ton Drop { motion straight = 1.0 }
surface Ball { property a = 0.5 }
source sky = environment(sphere) emits Drop count 1000
update(s: Ball) { s.a += 0 }
"""


def render(tmp_path, name, scene, *extra):
    out = tmp_path / name
    r = run_gammac("run", tmp_path / "e.gamma", "--scene", scene, "--surfels", 2000, "--iterations", 1,
                   "--size", 128, "--quiet", "--out", out, *extra)
    assert r.returncode == 0, r.stderr
    return out


def roughness(png) -> float:
    """Mean |Laplacian| of the grey picture inside the sphere's central disc:
    facet edges are jumps of the shade, a smooth sphere has none."""
    a = np.asarray(Image.open(png).convert("L"), float)[:, :128]
    lap = np.abs(a[1:-1, 2:] + a[1:-1, :-2] + a[2:, 1:-1] + a[:-2, 1:-1] - 4 * a[1:-1, 1:-1])
    y, x = np.mgrid[1:127, 1:127]
    inside = (x - 64) ** 2 + (y - 64) ** 2 < 30 ** 2
    return float(lap[inside].mean())


def test_smooth_shading_removes_facets_and_flat_keeps_them(tmp_path):
    (tmp_path / "e.gamma").write_text(EFFECT)
    ball = write_obj(tmp_path / "ball.obj", *icosphere(2))
    smooth = render(tmp_path, "smooth", ball)
    flat = render(tmp_path, "flat", ball, "--shading", "flat")
    zero_crease = render(tmp_path, "zero", ball, "--crease", 0)
    png = "renders/iter_0001.png"
    assert roughness(smooth / png) < 0.4 * roughness(flat / png), (roughness(smooth / png), roughness(flat / png))
    assert (zero_crease / png).read_bytes() == (flat / png).read_bytes()
    # a scene file can mark a mesh flat
    (tmp_path / "scene.json").write_text(json.dumps({"meshes": [{"file": "ball.obj", "shading": "flat"}]}))
    marked = render(tmp_path, "marked", tmp_path / "scene.json")
    assert (marked / png).read_bytes() == (flat / png).read_bytes()
    # gammac render DIR re-renders with the run's shading
    r = run_gammac("render", flat, "--size", 128, "--show", "a", "--output", tmp_path / "again.png")
    assert r.returncode == 0, r.stderr
    r = run_gammac("render", flat, "--size", 128, "--show", "a", "--shading", "smooth",
                   "--output", tmp_path / "smooth-again.png")
    assert r.returncode == 0, r.stderr
    assert roughness(tmp_path / "smooth-again.png") < 0.4 * roughness(tmp_path / "again.png")


def test_bad_shading_is_refused(tmp_path):
    (tmp_path / "e.gamma").write_text(EFFECT)
    write_obj(tmp_path / "ball.obj", *icosphere(1))
    (tmp_path / "scene.json").write_text(json.dumps({"meshes": [{"file": "ball.obj", "shading": "glossy"}]}))
    r = run_gammac("run", tmp_path / "e.gamma", "--scene", tmp_path / "scene.json", "--out", tmp_path / "o")
    assert r.returncode != 0 and 'meshes[0].shading must be "smooth" or "flat", not "glossy"' in r.stderr
    r = run_gammac("run", tmp_path / "e.gamma", "--scene", tmp_path / "ball.obj", "--crease", "200",
                   "--out", tmp_path / "o")
    assert r.returncode == 2 and "not an angle from 0 to 180 degrees" in r.stderr
