"""The ``gammac`` command starts reading a run's mesh, and sampling its
surfels, before it parses its command line (gamma/launch.py), but only when
the four options the read needs can be told for certain from ``sys.argv``;
the outputs are those of ``python -m gamma.cli``, which does not."""

import hashlib
import os
import subprocess
import sys
import textwrap

import pytest

from conftest import ROOT
from gamma.launch import read_options

BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"


@pytest.mark.parametrize("argv, expected", [
    (["run", "e.gamma", "--scene", "m.obj"], ("m.obj", 100_000, 1, 0)),
    (["run", "e.gamma", "--scene=m.obj", "--surfels=2000", "--seed", "7", "--threads", "2"], ("m.obj", 2000, 7, 2)),
    (["run", "--surfels", "5", "--scene", "a.obj", "e.gamma", "--surfels", "6"], ("a.obj", 6, 1, 0)),  # the last wins
    (["run", "e.gamma", "--scene", "m.obj", "--show", "rust", "--size", "64", "--param", "x=--seed"],
     ("m.obj", 100_000, 1, 0)),
    (["run", "e.gamma", "--scene", "m.obj", "--", "--seed", "3"], ("m.obj", 100_000, 1, 0)),
])
def test_the_options_are_read_from_an_unambiguous_command_line(argv, expected):
    assert read_options(argv) == expected


@pytest.mark.parametrize("argv", [
    [],
    ["check", "e.gamma", "--scene", "m.obj"],                 # another command
    ["--version", "run", "--scene", "m.obj"],
    ["run", "e.gamma"],                                       # no scene
    ["run", "e.gamma", "--scene"],                            # a value missing
    ["run", "e.gamma", "--scene", "m.obj", "--surf", "2000"],  # argparse expands an abbreviation
    ["run", "e.gamma", "--sc", "m.obj"],
    ["run", "e.gamma", "--scene", "m.obj", "--th=1"],
    ["run", "e.gamma", "--scene", "m.obj", "--surfels", "2e3"],   # argparse reports these
    ["run", "e.gamma", "--scene", "m.obj", "--seed", "-1"],
    ["run", "e.gamma", "--scene", "m.obj", "--threads", "٣"],
])
def test_nothing_is_read_ahead_when_argparse_might_read_it_otherwise(argv):
    assert read_options(argv) is None


# gammac's entry point with cli.entry replaced: what prefetch holds by then
PROBE = textwrap.dedent("""
    import sys
    import gamma.cli
    from gamma.driver.running import prefetch
    gamma.cli.entry = lambda: print(sorted(prefetch._pending))
    from gamma.launch import main
    main()
""")


def test_the_read_starts_before_the_command_line_is_parsed(tmp_path):
    env = dict(os.environ, GAMMA_CACHE_DIR="off")
    args = ["run", "e.gamma", "--scene", str(BUNNY), "--surfels", "2000", "--out", str(tmp_path)]
    r = subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == repr([str(BUNNY)])
    r = subprocess.run([sys.executable, "-c", PROBE, *args[:-2], "--surf", "2000"], capture_output=True, text=True,
                       timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def _outputs(out):
    return {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and p.name != "summary.json"}


def test_a_run_started_by_gammac_gives_the_outputs_of_one_started_by_the_cli(tmp_path, box_obj):
    env = dict(os.environ, GAMMA_CACHE_DIR="off", PYTHONUNBUFFERED="1")
    common = ["run", str(ROOT / "examples" / "patina.gamma"), "--iterations", "2", "--tons", "3000",
              "--size", "48", "--threads", "2", "--quiet"]
    runs = {
        "gammac": [sys.executable, "-c", "from gamma.launch import main; main()", *common, "--scene", str(box_obj),
                   "--surfels", "3000"],
        # the options abbreviated: nothing read ahead by launch.py
        "abbreviated": [sys.executable, "-c", "from gamma.launch import main; main()", *common,
                        "--scen", str(box_obj), "--surf", "3000"],
        "cli": [sys.executable, "-m", "gamma.cli", *common, "--scene", str(box_obj), "--surfels", "3000"],
    }
    outputs = {}
    for name, cmd in runs.items():
        out = tmp_path / name
        r = subprocess.run([*cmd, "--out", str(out)], capture_output=True, text=True, timeout=600, env=env)
        assert r.returncode == 0, r.stderr
        outputs[name] = _outputs(out)
    assert outputs["gammac"] and any(k.startswith("maps/") for k in outputs["gammac"])
    assert outputs["gammac"] == outputs["cli"] == outputs["abbreviated"]


def test_the_defaults_read_ahead_are_the_command_lines():
    from gamma import cli
    from gamma.options import EARLY

    args = cli._parser().parse_args(["run", "e.gamma", "--scene", "m.obj", "--out", "o"])
    assert {name: getattr(args, name.removeprefix("--")) for name in ("--surfels", "--seed", "--threads")} == \
        {name: default for name, default in EARLY.items() if name != "--scene"}


@pytest.mark.parametrize("argv, status", [(["run", "e.gamma", "--scene", "m.obj"], 2),   # no --out
                                          (["--version"], 0), (["run", "--help"], 0)])
def test_argparse_exits_are_returned_so_that_gammac_leaves_without_waiting(argv, status, capsys):
    """cli.main returns argparse's exit status instead of raising SystemExit
    from inside argparse: cli.entry then leaves through cli._leave, and the
    interpreter's exit stops the sampling launch.py started ahead (prefetch's
    atexit handler cancels its token) instead of waiting for it whole."""
    from gamma import cli

    assert cli.main(argv) == status


# A read whose file changed after it was read is dropped by take(); the
# interpreter's exit still waits for its sampling (else nanobind reports the
# runtime's objects as leaked).
DROPPED = textwrap.dedent("""
    import os, shutil, sys
    from gamma.driver.running import prefetch
    path = sys.argv[1]
    shutil.copy(sys.argv[2], path)
    prefetch.start(path, 20000, 1, 1)
    prefetch._pending[path].mesh.result()
    os.utime(path, ns=(1, 1))
    assert prefetch.take(path) is None
    sys.exit(0)
""")


def test_a_dropped_read_is_waited_for_at_exit(tmp_path):
    r = subprocess.run([sys.executable, "-c", DROPPED, str(tmp_path / "bunny.obj"), str(BUNNY)],
                       capture_output=True, text=True, timeout=300, env=dict(os.environ, GAMMA_CACHE_DIR="off"))
    assert r.returncode == 0, r.stderr
    assert "leaked" not in r.stderr
