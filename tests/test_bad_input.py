"""Bad input ends with a non-zero exit, a one-line message and no traceback,
and leaves no half-written output behind."""

import pytest

from conftest import ROOT, run_gammac

PATINA = ROOT / "examples" / "patina.gamma"


def assert_one_line_error(result, *fragments):
    assert result.returncode == 1, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("gammac: error: ")
    for fragment in fragments:
        assert fragment in lines[0]


def run_on(tmp_path, mesh):
    return run_gammac("run", PATINA, "--scene", mesh, "--surfels", 100, "--tons", 100,
                      "--iterations", 1, "--quiet", "--out", tmp_path / "out")


def test_missing_mesh(tmp_path):
    r = run_on(tmp_path, tmp_path / "nowhere.obj")
    assert_one_line_error(r, "nowhere.obj", "not found")
    assert not (tmp_path / "out").exists()


def test_empty_mesh(tmp_path):
    (tmp_path / "empty.obj").write_text("")
    assert_one_line_error(run_on(tmp_path, tmp_path / "empty.obj"), "empty.obj")


def test_garbage_mesh(tmp_path):
    (tmp_path / "garbage.ply").write_bytes(bytes(range(256)) * 8)
    assert_one_line_error(run_on(tmp_path, tmp_path / "garbage.ply"), "garbage.ply")


def test_mesh_without_triangles(tmp_path):
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    assert_one_line_error(run_on(tmp_path, tmp_path / "points.obj"), "no triangles")


def test_nan_vertex(tmp_path):
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n")
    assert_one_line_error(run_on(tmp_path, tmp_path / "nan.obj"), "non-finite")


def test_only_degenerate_triangles(tmp_path):
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    assert_one_line_error(run_on(tmp_path, tmp_path / "flat.obj"), "degenerate")


def test_missing_effect(tmp_path, box_obj):
    r = run_gammac("run", tmp_path / "none.gamma", "--scene", box_obj, "--out", tmp_path / "o")
    assert_one_line_error(r, "none.gamma", "not found")


def test_binary_effect(tmp_path):
    (tmp_path / "bin.gamma").write_bytes(b"\xff\xfe\x00garbage\x80")
    assert_one_line_error(run_gammac("check", tmp_path / "bin.gamma"), "not UTF-8")


def test_malformed_effect_reports_diagnostics(tmp_path, box_obj):
    (tmp_path / "bad.gamma").write_text("ton T { motion straight = }\n")
    r = run_gammac("run", tmp_path / "bad.gamma", "--scene", box_obj, "--out", tmp_path / "o")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert r.stderr.startswith("bad.gamma:1:27: error: ") or ":1:27: error: " in r.stderr
    assert not (tmp_path / "o").exists()


def test_unwritable_output_folder(tmp_path, box_obj):
    (tmp_path / "file").write_text("not a folder")
    r = run_gammac("run", PATINA, "--scene", box_obj, "--surfels", 100, "--tons", 10,
                   "--out", tmp_path / "file" / "out")
    assert_one_line_error(r, "cannot write to")


@pytest.mark.parametrize("option,value", [("--surfels", "999999999999"), ("--seed", "99999999999999999999999"),
                                          ("--threads", "99999"), ("--size", "4")])
def test_out_of_range_options(tmp_path, box_obj, option, value):
    r = run_gammac("run", PATINA, "--scene", box_obj, option, value, "--out", tmp_path / "o")
    assert_one_line_error(r, option)


def test_directory_as_mesh(tmp_path):
    assert_one_line_error(run_on(tmp_path, tmp_path), "is a directory")


@pytest.mark.parametrize("args", [["--iterations", "x"], ["--surfels", "-3"], ["--bogus"], []])
def test_usage_errors_exit_2(tmp_path, box_obj, args):
    base = ["run", PATINA, "--scene", box_obj, "--out", tmp_path / "o"] if args else ["run"]
    r = run_gammac(*base, *args)
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_unknown_surface_assignment(tmp_path, box_obj):
    r = run_gammac("run", PATINA, "--scene", box_obj, "--assign", "Bronze",
                   "--out", tmp_path / "o")
    assert_one_line_error(r, "Bronze", "Copper")


def test_unassigned_parts(tmp_path, box_obj):
    two = ("ton T { motion straight = 1 carry a = 1 }\nsurface A { property p = 0 }\n"
           "surface B { property q = 0 }\nsource s = environment(sphere) emits T count 10\n"
           "on hit(t: T, s: A) { s.p += 1 }\non hit(t: T, s: B) { s.q += 1 }\n")
    (tmp_path / "two.gamma").write_text(two)
    r = run_gammac("run", tmp_path / "two.gamma", "--scene", box_obj, "--out", tmp_path / "o")
    assert_one_line_error(r, "no surface for", "--assign")


def test_a_failing_run_keeps_the_earlier_results(tmp_path, box_obj):
    out = tmp_path / "out"
    ok = run_gammac("run", PATINA, "--scene", box_obj, "--surfels", 200, "--tons", 1000, "--iterations", 1,
                    "--size", 32, "--quiet", "--out", out)
    assert ok.returncode == 0, ok.stderr
    before = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    for bad in (["--fov", "500"], ["--scene", tmp_path / "missing.obj"], ["--assign", "Nope"]):
        args = ["run", PATINA, "--scene", box_obj, "--surfels", 200, "--quiet", "--out", out] + bad
        r = run_gammac(*args)
        assert r.returncode == 1, r.stderr
        assert sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file()) == before
