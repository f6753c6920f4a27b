"""The output contract of ``gammac run`` (maps, renders, summary)."""

import json

import numpy as np
import pytest
from PIL import Image

from conftest import ROOT, run_gammac
from gamma.driver.outputs import read_ply


@pytest.fixture(scope="module")
def patina_run(tmp_path_factory, bumpy_obj):
    out = tmp_path_factory.mktemp("patina") / "out"
    r = run_gammac("run", ROOT / "examples" / "patina.gamma", "--scene", bumpy_obj,
                   "--surfels", 8000, "--tons", 40000, "--iterations", 3, "--size", 200,
                   "--seed", 3, "--out", out)
    assert r.returncode == 0, r.stderr
    return out, r


def test_maps_are_ply_point_clouds_with_every_column(patina_run):
    out, _ = patina_run
    for i in (1, 2, 3):
        cols = read_ply(out / "maps" / f"iter_{i:04d}.ply")
        assert list(cols) == ["x", "y", "z", "nx", "ny", "nz", "surface", "patina", "reflectance_straight",
                              "reflectance_parabolic", "reflectance_flow"]
        assert len(cols["x"]) == 8000
        n = np.stack([cols["nx"], cols["ny"], cols["nz"]], 1)
        assert np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-5)
        assert np.all(cols["reflectance_straight"] == np.float32(0.5))


def test_patina_grows_and_matches_the_summary(patina_run):
    out, _ = patina_run
    summary = json.loads((out / "summary.json").read_text())
    sums = [it["property_sums"]["patina"] for it in summary["iterations"]]
    assert sums[0] > 0 and sums[0] < sums[1] < sums[2]
    last = read_ply(out / "maps" / "iter_0003.ply")["patina"]
    assert float(np.sum(last, dtype=np.float64)) == pytest.approx(sums[2], rel=1e-9)
    for key in ("surfels", "triangles", "threads", "seed", "versions"):
        assert key in summary
    assert summary["surfels"] == 8000 and summary["seed"] == 3
    for it in summary["iterations"]:
        assert it["emitted"] == 40000
        assert it["emitted"] == it["settled"] + it["escaped"] + it["capped"]
        assert it["trace_seconds"] > 0 and it["update_seconds"] >= 0


def test_one_render_per_iteration_with_colour_bar(patina_run):
    out, _ = patina_run
    for i in (1, 2, 3):
        img = Image.open(out / "renders" / f"iter_{i:04d}.png")
        assert img.size[1] == 200 and img.size[0] > 200   # picture plus the colour bar
        pixels = np.asarray(img.convert("RGB")).astype(int)
        assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 50   # not blank


def test_a_rerun_replaces_the_earlier_run(tmp_path, bumpy_obj):
    for iterations in (3, 1):
        r = run_gammac("run", ROOT / "examples" / "patina.gamma", "--scene", bumpy_obj, "--surfels", 500,
                       "--tons", 1000, "--iterations", iterations, "--size", 32, "--quiet",
                       "--out", tmp_path)
        assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "maps").iterdir()) == ["iter_0001.ply"]
    assert sorted(p.name for p in (tmp_path / "renders").iterdir() if p.is_file()) == ["iter_0001.png"]


def test_no_temporary_files_left(patina_run):
    out, _ = patina_run
    leftovers = [p for p in out.rglob("*") if p.name.startswith(".")]
    assert leftovers == []


def test_progress_is_shown(patina_run):
    _, r = patina_run
    assert "3/3" in r.stderr and "γ-tons/s" in r.stderr


def test_non_finite_results_are_reported_once_and_kept_out_of_the_maps(tmp_path, bumpy_obj):
    (tmp_path / "nan.gamma").write_text(
        "ton T { motion straight = 0.5 carry a = 1 }\nsurface S { property p = 0, q = 0 }\n"
        "source s = environment(sphere) emits T count 5000\n"
        "on settle(t: T, s: S) {\n    s.p += t.a\n    s.q += t.a / (s.p - s.p)\n}\n")
    r = run_gammac("run", tmp_path / "nan.gamma", "--scene", bumpy_obj, "--surfels", 500,
                   "--iterations", 2, "--size", 32, "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    warnings = [line for line in r.stderr.splitlines() if "NaN or infinity" in line]
    assert len(warnings) == 1 and "nan.gamma:6:5" in warnings[0]
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    settled = sum(it["settled"] for it in summary["iterations"])
    assert summary["nonfinite"] == [{"where": str(tmp_path / "nan.gamma") + ":6:5",
                                     "rule": "on settle(T, S)", "count": settled,
                                     "first_iteration": 1}]
    cols = read_ply(tmp_path / "o" / "maps" / "iter_0002.ply")
    assert np.all(np.isfinite(cols["q"])) and np.all(cols["q"] == 0) and cols["p"].sum() > 0


def test_appearance_renders_sequence_and_false_colour(tmp_path):
    """An effect with an appearance block: textured pictures per iteration,
    an animated GIF, a strip, and the false colour beside them."""
    from meshes import write_obj

    verts = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1], [0, 1, 0]], float)
    faces = [(0, 2, 1), (0, 3, 2), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)]
    lines = [f"v {x} {y} {z}" for x, y, z in verts] + ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1", "vt 0.5 0.5"]
    lines += [f"f {a + 1}/{[1, 2, 3, 4, 5][a]} {b + 1}/{[1, 2, 3, 4, 5][b]} {c + 1}/{[1, 2, 3, 4, 5][c]}"
              for a, b, c in faces]
    (tmp_path / "pyramid.obj").write_text("\n".join(lines) + "\n")
    Image.new("RGB", (4, 4), (200, 40, 40)).save(tmp_path / "red.png")
    (tmp_path / "look.gamma").write_text(
        "ton T { motion straight = 0.5 carry a = 1 }\nsurface S { property p = 0 }\n"
        "source s = environment(sphere) emits T count 20000\non settle(t: T, s: S) { s.p += 0.01 * t.a }\n"
        'appearance(s: S) {\n    color = mix(texture("red.png"), rgb(0, 0.5, 1), clamp(s.p, 0, 1))\n}\n')
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "look.gamma", "--scene", tmp_path / "pyramid.obj", "--surfels", 2000,
                   "--iterations", 3, "--size", 64, "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    for i in (1, 2, 3):
        assert Image.open(out / "renders" / f"iter_{i:04d}.png").size == (64, 64)
        assert (out / "renders" / "false_colour" / f"iter_{i:04d}.png").is_file()
    gif = Image.open(out / "renders" / "sequence.gif")
    assert gif.n_frames == 3
    import imageio.v2 as imageio

    video = imageio.get_reader(out / "renders" / "sequence.mp4")
    assert video.count_frames() == 3 and video.get_data(0).shape == (64, 64, 3)
    mp4 = (out / "renders" / "sequence.mp4").read_bytes()
    assert 0 < mp4.index(b"moov") < mp4.index(b"mdat")     # +faststart: the index first, so it streams
    assert Image.open(out / "renders" / "strip.png").size == (64 * 3, 64)
    pixels = np.asarray(Image.open(out / "renders" / "iter_0001.png").convert("RGB")).reshape(-1, 3).astype(int)
    assert np.any(pixels[:, 0] > pixels[:, 2] + 40)     # the red texture shows somewhere
    assert json.loads((out / "summary.json").read_text())["appearance"] is True
