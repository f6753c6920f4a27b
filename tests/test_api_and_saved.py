"""The Python API (``import gamma``), its README example, and saved results
reused by ``gammac render DIR`` / ``gammac export DIR`` without simulating."""

import json
import os
import subprocess
import sys

import numpy as np
import pygltflib
import pytest
from PIL import Image

import gamma
from conftest import ROOT, run_gammac

PATINA = (ROOT / "examples" / "patina.gamma").read_text()


def test_readme_example_runs_as_written(tmp_path):
    text = (ROOT / "README.md").read_text()
    start = text.index("```python", text.index("## Python API")) + len("```python")
    code = text[start:text.index("```", start)]
    (tmp_path / "example.py").write_text(code)
    r = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=600, env=dict(os.environ))
    assert r.returncode == 0, r.stderr
    assert "iteration 3/3" in r.stdout and "(256, 256)" in r.stdout


def test_compile_from_string_and_path_with_overrides(tmp_path):
    from_string = gamma.compile(source=PATINA.replace("count 4000000", "count 1000"))
    assert from_string.sources[0].count == 1000
    path = tmp_path / "e.gamma"
    path.write_text('import "patina.gamma"\n')
    effect = gamma.compile(path, params={"patina.tons": 777})
    assert effect.sources[0].count == 777
    with pytest.raises(gamma.GammaError):
        gamma.compile(source="ton T { motion straight = 2 }")
    with pytest.raises(TypeError):
        gamma.compile()


def test_run_on_arrays_matches_the_command_line(tmp_path):
    """The same mesh as arrays and as a file, the same seed: the same surfels and values.

    The vertices are float32 first, so the OBJ text (9 significant digits)
    gives back exactly the same numbers: the splat's weights depend on
    positions to the last bit."""
    from meshes import bumpy_sphere, write_obj

    effect = gamma.compile(ROOT / "examples" / "patina.gamma")
    verts, faces = bumpy_sphere()
    verts = verts.astype(np.float32)
    bumpy_obj = write_obj(tmp_path / "bumpy.obj", verts, faces)
    seen = []
    result = gamma.run(effect, vertices=verts, faces=faces, iterations=2, surfels=3000, tons=30000,
                       threads=2, progress=lambda it, total, record: seen.append((it, total, record["emitted"])))
    assert seen == [(1, 2, 30000), (2, 2, 30000)]
    r = run_gammac("run", ROOT / "examples" / "patina.gamma", "--scene", bumpy_obj, "--surfels", 3000,
                   "--tons", 30000, "--iterations", 2, "--threads", 2, "--size", 32, "--quiet",
                   "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    from gamma.driver.outputs.outputs import read_ply

    saved = read_ply(tmp_path / "out" / "maps" / "iter_0002.ply")
    assert np.array_equal(result.surfel_positions[:, 0], saved["x"])
    assert np.array_equal(result.properties["patina"], saved["patina"])
    assert len(result.history) == 2 and result.summary["iterations"][1]["emitted"] == 30000
    per_vertex = result.vertex_properties()["patina"]
    assert per_vertex.shape == (len(verts),) and per_vertex.max() > 0
    assert result.vertex_colours().shape == (len(verts), 3)
    baked = result.bake(128)["mesh"]
    assert baked["color"].shape == (128, 128, 3) and baked["patina"].shape == (128, 128)
    assert baked["patina"].max() > 0
    low, high = result.summary["ranges"]["patina"]
    all_values = np.concatenate([h["patina"] for h in result.history])
    assert (low, high) == (float(all_values.min()), float(all_values.max()))


LOOK = """\
ton T { motion straight = 0.5 carry a = 1 }
surface S { property p = 0 }
source s = environment(sphere) emits T count 20000
on settle(t: T, s: S) { s.p += 0.02 * t.a }
appearance(s: S) { color = mix(rgb(0.8, 0.5, 0.3), rgb(0.2, 0.6, 0.5), clamp(s.p, 0, 1)) }
"""


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory, bumpy_obj):
    folder = tmp_path_factory.mktemp("saved")
    (folder / "look.gamma").write_text(LOOK)
    out = folder / "out"
    r = run_gammac("run", folder / "look.gamma", "--scene", bumpy_obj, "--surfels", 3000, "--iterations", 3,
                   "--size", 48, "--samples", 1, "--ao", 2, "--export", "all", "--bake-size", 64, "--quiet",
                   "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def test_render_from_saved_maps_equals_the_runs_picture(saved_run, tmp_path):
    target = tmp_path / "again.png"
    r = run_gammac("render", saved_run, "--iteration", 2, "--size", 48, "--samples", 1, "--ao", 2,
                   "-o", target)
    assert r.returncode == 0, r.stderr
    again = np.asarray(Image.open(target))
    original = np.asarray(Image.open(saved_run / "renders" / "iter_0002.png"))
    assert np.array_equal(again, original)
    # a new camera: a different picture, no simulation
    r = run_gammac("render", saved_run, "--view", "1,0.2,-1", "--size", 48, "--show", "p")
    assert r.returncode == 0, r.stderr
    assert (saved_run / "renders" / "view_iter_0003_p.png").is_file()
    assert json.loads((saved_run / "summary.json").read_text())["iterations"].__len__() == 3


def test_export_from_saved_maps_matches_the_runs_export(saved_run):
    ranges = json.loads((saved_run / "summary.json").read_text())["ranges"]
    export = saved_run / "export"
    during = {p.name: p.read_bytes() for p in [*export.glob("*.glb"), *(export / "bumpy").iterdir()]}
    r = run_gammac("export", saved_run, "--all", "--bake-size", 64)
    assert r.returncode == 0, r.stderr
    after = {p.name: p.read_bytes() for p in [*export.glob("*.glb"), *(export / "bumpy").iterdir()]}
    assert set(after) == set(during) and len(during) == 3 * (1 + 7 + 1)   # glb; 5 images, obj, mtl, json; p
    assert after == during                                               # the same bytes, file for file
    for it in (1, 2, 3):
        gltf = pygltflib.GLTF2().load(str(export / f"bumpy_{it:04d}.glb"))
        props = gltf.extras["gamma"]["properties"]["p"]
        assert (props["min"], props["max"]) == tuple(ranges["p"])    # one range for the whole run


def test_saved_results_errors(tmp_path, saved_run):
    r = run_gammac("render", tmp_path)
    assert r.returncode == 1 and "holds no run (no summary.json)" in r.stderr
    r = run_gammac("export", saved_run, "--iteration", 9)
    assert r.returncode == 1 and "no map of iteration 9" in r.stderr
