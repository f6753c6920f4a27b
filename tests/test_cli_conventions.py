"""Command-line conventions: one version everywhere, defaults in --help,
negative vectors, --look-at/--up, unknown --param listing the valid ones,
--param RECIPE.NAME reaching imported recipes."""

import json
import re
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, run_gammac
from gamma import __version__
from gamma.frontend.checker import load
from gamma.cli import _join_negative_vectors, _parser
from gamma.driver.running.camera import CameraError, auto_camera, choose_camera

CMAKE_VERSION = re.search(r"project\(gamma_runtime VERSION ([0-9.]+)",
                          (ROOT / "CMakeLists.txt").read_text()).group(1)


def test_one_version_everywhere():
    import gamma._runtime as rt

    assert __version__ == version("gamma-weathering") == CMAKE_VERSION == rt.RUNTIME_VERSION
    r = run_gammac("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"gammac {CMAKE_VERSION}"


def test_help_shows_defaults_and_exit_status():
    r = run_gammac("run", "--help")
    assert r.returncode == 0
    text = " ".join(r.stdout.split())
    for option, default in (("--iterations", "10"), ("--surfels", "100000"), ("--seed", "1"),
                            ("--size", "512"), ("--fov", "30.0"), ("--bake-size", "1024")):
        assert re.search(re.escape(option) + r" \S+ .*?\(default: " + re.escape(default) + r"\)", text), option
    assert "(default: -0.6,0.35,1)" in text
    assert "Exit status" in " ".join(run_gammac("--help").stdout.split())


def test_negative_vectors_need_no_equals_sign():
    argv = _join_negative_vectors(["run", "e.gamma", "--scene", "m.obj", "--out", "o",
                                   "--view", "-0.6,0.2,1", "--down", "-1,-2,-3", "--up", "0,1,0",
                                   "--look-at", "-1.5,0,2"])
    args = _parser().parse_args(argv)
    assert args.view == (-0.6, 0.2, 1.0) and args.down == (-1.0, -2.0, -3.0)
    assert args.look_at == (-1.5, 0.0, 2.0) and args.up == (0.0, 1.0, 0.0)
    # an option after a vector option is left alone
    assert _join_negative_vectors(["--view", "--quiet"]) == ["--view", "--quiet"]


BOUNDS = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))


def test_look_at_moves_the_target_and_keeps_the_view_direction():
    base = auto_camera(BOUNDS)
    eye, target, up, fov = choose_camera(BOUNDS, (0, -1, 0), look_at=(0.5, 0.2, 0.0))
    assert target == (0.5, 0.2, 0.0)
    assert np.allclose(np.subtract(eye, target), np.subtract(base[0], base[1]))
    eye2, target2, *_ = choose_camera(BOUNDS, (0, -1, 0), eye=(0, 0, 5), look_at=(1, 0, 0))
    assert eye2 == (0, 0, 5) and target2 == (1, 0, 0)


def test_up_vector_is_used_and_checked():
    _, _, up, _ = choose_camera(BOUNDS, (0, -1, 0), up=(0, 0, 2))
    assert np.allclose(up, (0, 0, 1))
    with pytest.raises(CameraError, match="--up must not point along the viewing direction"):
        choose_camera(BOUNDS, (0, -1, 0), eye=(0, 5, 0), up=(0, 1, 0))
    with pytest.raises(CameraError, match="--eye must not be the point the camera looks at"):
        choose_camera(BOUNDS, (0, -1, 0), eye=(1, 1, 1), look_at=(1, 1, 1))


def test_camera_options_change_the_render(tmp_path, bumpy_obj):
    effect = ROOT / "examples" / "patina.gamma"
    common = ["--scene", bumpy_obj, "--surfels", 3000, "--tons", 20000, "--iterations", 1, "--size", 48, "--quiet"]
    a = run_gammac("run", effect, *common, "--out", tmp_path / "a", "--view", "-0.6,0.2,1")
    b = run_gammac("run", effect, *common, "--out", tmp_path / "b", "--view", "-0.6,0.2,1",
                   "--look-at", "0.4,0,0", "--up", "1,1,0")
    assert a.returncode == 0, a.stderr
    assert b.returncode == 0, b.stderr
    one = (tmp_path / "a" / "renders" / "iter_0001.png").read_bytes()
    two = (tmp_path / "b" / "renders" / "iter_0001.png").read_bytes()
    assert one != two
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["versions"]["gamma"] == CMAKE_VERSION


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_unknown_param_lists_the_valid_ones(tmp_path):
    main = write(tmp_path / "m.gamma", "param rate = 0.05\nparam tons = 10\nimport \"patina.gamma\"\n")
    r = run_gammac("check", main, "--param", "rat=1")
    assert r.returncode == 2
    assert "--param rat: m.gamma has no parameter 'rat' (did you mean 'rate'?); its parameters: rate, tons" in r.stderr
    r = run_gammac("check", main, "--param", "patina.speed=1")
    assert r.returncode == 2
    assert "--param patina.speed: patina.gamma has no parameter 'speed'; its parameters: rate, intensity, tons, trap" in r.stderr
    r = run_gammac("check", main, "--param", "rust.rate=1")
    assert r.returncode == 2 and "m.gamma imports no recipe 'rust' (imported: patina)" in r.stderr


def test_param_reaches_imported_recipes(tmp_path):
    main = write(tmp_path / "m.gamma", "import \"patina.gamma\" (rate = 0.2)\n")
    effect = load(str(main), {"patina.tons": 1234, "patina.rate": 0.7})
    assert effect.sources[0].count == 1234                    # the recipe's own default replaced
    settle = next(k for k in effect.kernels if k.event == "settle")
    assert settle.bodies[0][0].value.left.value == pytest.approx(0.7)   # the command line wins over the import
    r = run_gammac("check", main, "--param", "patina.trap=0.25")
    assert r.returncode == 0, r.stderr
    assert load(str(main), {"patina.trap": 0.25}).surfaces["Copper"].initial_row[0] == 0.25
