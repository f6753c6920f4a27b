"""Multi-part scenes, several surfaces, sources and windows, end to end."""

import json

import numpy as np
import pytest

from conftest import ROOT, run_gammac
from gamma.driver.outputs.outputs import read_ply
from meshes import icosphere

TWO_SURFACES = """
ton Drop { motion straight = 0.5  carry wet = 1.0 }
surface Stone { reflectance straight = 0.5  property damp = 0.0 }
surface Metal { reflectance straight = 0.5  property rust = 0.0, damp = 0.0 }
source sky = environment(sphere) emits Drop count 20000
on hit(t: Drop, s: Stone) { s.damp += 1 }
on hit(t: Drop, s: Metal) { s.rust += 1 }
"""


def two_part_obj(path):
    """Object 'ball' (a sphere) resting on object 'slab' (a square)."""
    v, f = icosphere(2, radius=0.5)
    lines = ["o ball"] + [f"v {x:.6f} {y + 0.5:.6f} {z:.6f}" for x, y, z in v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    n = len(v)
    lines += ["o slab", "v -2 0 -2", "v 2 0 -2", "v 2 0 2", "v -2 0 2",
              f"f {n + 1} {n + 3} {n + 2}", f"f {n + 1} {n + 4} {n + 3}"]
    path.write_text("\n".join(lines) + "\n")
    return path


def run_two(tmp_path, *extra):
    (tmp_path / "two.gamma").write_text(TWO_SURFACES)
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "two.gamma", "--surfels", 3000, "--iterations", 1, "--quiet",
                   "--size", 32, "--out", out, *extra)
    assert r.returncode == 0, r.stderr
    return read_ply(out / "maps" / "iter_0001.ply"), json.loads((out / "summary.json").read_text())


def test_parts_bind_by_object_name_first_match_wins(tmp_path):
    scene = two_part_obj(tmp_path / "scene.obj")
    cols, summary = run_two(tmp_path, "--scene", scene, "--assign", "ball=Metal", "--assign", "*=Stone")
    metal = cols["surface"] == 1
    assert summary["surfaces"]["Metal"]["triangles"] == 320
    assert summary["surfaces"]["Stone"]["triangles"] == 2
    assert metal.any() and (~metal).any()
    assert np.all(cols["y"][metal] > -1e-4)             # metal surfels are on the ball
    assert np.all(np.abs(cols["y"][~metal]) < 1e-4)     # stone surfels on the slab
    # rules fire only for their (ton, surface) pair
    assert cols["rust"][metal].sum() > 0 and cols["rust"][~metal].sum() == 0
    assert cols["damp"][~metal].sum() > 0 and cols["damp"][metal].sum() == 0


def test_json_scene_with_transforms(tmp_path):
    two_part_obj(tmp_path / "scene.obj")
    (tmp_path / "scene.json").write_text(json.dumps({"down": [0, 0, -1], "meshes": [
        {"file": "scene.obj", "rotate": [90, 0, 0], "scale": 2, "translate": [10, 0, 0],
         "assign": {"ball": "Metal", "*": "Stone"}}]}))
    cols, summary = run_two(tmp_path, "--scene", tmp_path / "scene.json")
    assert summary["down"] == [0, 0, -1]
    assert cols["x"].min() > 10 - 4 - 1e-3 and cols["x"].max() < 10 + 4 + 1e-3   # scaled, moved
    slab = cols["surface"] == 0
    assert np.all(np.abs(cols["z"][slab]) < 1e-3)        # y-up slab rotated into z = 0


def test_source_window_and_split(tmp_path, box_obj):
    (tmp_path / "w.gamma").write_text(
        "ton T { motion straight = 0 carry a = 1 }\nsurface S { property p = 0 }\n"
        "source early = environment(hemisphere) emits T count 300 until 2\n"
        "source late = point(relative(0.5, 0.5, 0.5)) emits T count 100 from 3\n"
        "on settle(t: T, s: S) { s.p += t.a }\n")
    r = run_gammac("run", tmp_path / "w.gamma", "--scene", box_obj, "--surfels", 200, "--iterations", 4,
                   "--tons", 1000, "--quiet", "--size", 32, "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    emitted = [it["emitted"] for it in json.loads((tmp_path / "o" / "summary.json").read_text())["iterations"]]
    assert emitted == [750, 750, 250, 250]     # --tons split 3:1, each source only in its window


@pytest.fixture(scope="module")
def stain_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("stain")
    scene = d / "staircase.obj"
    assert run_gammac_script(ROOT / "examples" / "scenes" / "make_staircase.py", scene) == 0
    r = run_gammac("run", ROOT / "examples" / "stain-bleeding.gamma", "--scene", scene,
                   "--assign", "chain=Iron", "--assign", "*=Cement", "--surfels", 30000,
                   "--iterations", 6, "--tons", 150000, "--size", 64, "--quiet", "--out", d / "out")
    assert r.returncode == 0, r.stderr
    return read_ply(d / "out" / "maps" / "iter_0006.ply"), json.loads((d / "out" / "summary.json").read_text())


def run_gammac_script(script, *args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, str(script), *map(str, args)], capture_output=True).returncode


def test_stain_bleeding_puts_rust_below_the_chain(stain_run):
    cols, summary = stain_run
    it = summary["iterations"][-1]
    assert it["bounces"] > 0 and it["flow_steps"] > 0 and it["drips"] > 0
    cement = cols["surface"] == 1
    rust = cols["rust"]
    assert rust[~cement].sum() > 0                        # the chain rusted
    stained = cement & (rust > 0)
    assert stained.any()
    # rust on cement lies around and below the chain (x = -0.3, z = 0.75), not spread evenly
    xz = np.stack([cols["x"][stained], cols["z"][stained]], 1)
    weights = rust[stained]
    centre = (xz * weights[:, None]).sum(0) / weights.sum()
    assert abs(centre[0] + 0.3) < 0.25 and abs(centre[1] - 0.75) < 0.35


def test_assign_declarations_in_the_effect_come_last(tmp_path):
    scene = two_part_obj(tmp_path / "scene.obj")
    (tmp_path / "two.gamma").write_text(TWO_SURFACES + 'assign "ball" = Metal\nassign "*" = Stone\n')
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "two.gamma", "--scene", scene, "--surfels", 2000, "--iterations", 1,
                   "--quiet", "--size", 32, "--out", out)
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["surfaces"]["Metal"]["triangles"] == 320
    # the command line wins over the file
    r = run_gammac("run", tmp_path / "two.gamma", "--scene", scene, "--surfels", 2000, "--iterations", 1,
                   "--quiet", "--size", 32, "--out", out, "--assign", "Stone")
    assert json.loads((out / "summary.json").read_text())["surfaces"]["Metal"]["triangles"] == 0
