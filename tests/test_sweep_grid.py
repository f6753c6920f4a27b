"""gammac sweep and run --ray without Ray: grid syntax, cell names and
commands, overlap with run options, and the message when the optional extra
is missing."""

import sys

import pytest

from gamma import cli
from gamma.driver.distributed.sweep import Axis, SweepError, check_overlap, parse_grid, plan_cells


def test_grid_values_and_ranges():
    assert parse_grid("rate=0.05,0.1,0.2") == Axis("rate", ["0.05", "0.1", "0.2"])
    assert parse_grid("seed=1..4") == Axis("seed", ["1", "2", "3", "4"])
    assert parse_grid("seed=1..2,7").values == ["1", "2", "7"]
    assert parse_grid("max-interactions=5").name == "max_interactions"


@pytest.mark.parametrize("text, message", [
    ("rate", "expected NAME=V1,V2"),
    ("rate=", "expected NAME=V1,V2"),
    ("1x=2", "expected NAME=V1,V2"),
    ("rate=0.1,abc", "'abc' is not a number"),
    ("rate=0.1,nan", "'nan' is not a number"),
    ("seed=3..1", "is empty"),
    ("seed=1..x", "not a range of whole numbers"),
    ("seed=1.5", "--seed takes whole numbers"),
    ("rate=0.1,0.10", "the value 0.10 is given twice"),
    ("seed=0..20000", "more than 10,000 values"),
])
def test_bad_grids_are_named(text, message):
    with pytest.raises(SweepError, match=message):
        parse_grid(text)


def _options(*argv):
    """The RunOptions and --param pairs of a ``gammac sweep`` command line."""
    from gamma.options import from_args

    args = cli._parser().parse_args(["sweep", "e.gamma", "--scene", "m.obj", "--out", "o", "--grid", "seed=1",
                                     *argv])
    return from_args(args), args.param


def test_cells_are_every_combination_as_options_and_gammac_run_commands(tmp_path):
    base, params = _options("--surfels", "500")
    cells = plan_cells("e.gamma", params, base, [parse_grid("rate=0.1,0.2"), parse_grid("seed=1..3")],
                       threads=1)
    assert [c.name for c in cells] == [f"rate={r}_seed={s}" for r in ("0.1", "0.2") for s in (1, 2, 3)]
    last = cells[-1]
    assert last.parameters() == {"rate": 0.2, "seed": 3}
    assert last.opts.seed == 3 and last.opts.surfels == 500 and last.opts.threads == 1
    assert not last.opts.progress and last.params == [("rate", 0.2)]
    assert last.argv[:2] == ["run", str((tmp_path.cwd() / "e.gamma").resolve())]
    assert last.argv[-2:] == ["--param", "rate=0.2"]
    assert "--surfels" in last.argv and "--quiet" in last.argv and "--seed" in last.argv
    # the command recorded is the same run
    again = cli._parser().parse_args([*last.argv, "--out", "o"])
    from gamma.options import from_args

    assert from_args(again) == last.opts and again.param == last.params


def test_a_swept_name_may_not_also_be_a_run_option():
    base, params = _options("--seed", "4", "--param", "rate=0.3")
    with pytest.raises(SweepError, match="--seed is given and also swept"):
        check_overlap([parse_grid("seed=1..2")], base, params)
    with pytest.raises(SweepError, match="--param rate=0.3 is given and also swept"):
        check_overlap([parse_grid("rate=0.1")], base, params)
    check_overlap([parse_grid("other=0.1"), parse_grid("surfels=10")], base, params)


def test_run_options_are_passed_on_exactly():
    from gamma.options import command_line, from_args

    base, _ = _options("--param", "k=0.1", "--view", "1,0.7,0.9", "--surfels", "123", "--export",
                       "--assign", "a=B", "--threads", "2", "--size", "64", "--crease", "0.1")
    again = cli._parser().parse_args(["run", "e.gamma", "--scene", "m.obj", "--out", "o", *command_line(base)])
    assert from_args(again) == base
    assert (base.width, base.height, base.threads) == (64, 64, 2)


def test_sweep_without_ray_says_how_to_install_it(tmp_path, monkeypatch, capsys):
    (tmp_path / "e.gamma").write_text("""
        ton T { motion straight = 1.0  carry p = 1.0 }
        surface S { property q = 0.0 }
        source a = environment(sphere) emits T count 10
        on settle(t: T, s: S) { s.q += t.p }
    """)
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    monkeypatch.setitem(sys.modules, "ray", None)     # import ray fails as if not installed
    code = cli.main(["sweep", str(tmp_path / "e.gamma"), "--scene", str(tmp_path / "m.obj"),
                     "--grid", "seed=1..2", "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 1
    err = capsys.readouterr().err
    assert "Ray is not installed" in err and "pip install '.[ray]'" in err


def test_sweep_checks_the_effect_before_starting(tmp_path, capsys):
    (tmp_path / "e.gamma").write_text("""
        ton T { motion straight = 1.0  carry p = 1.0 }
        surface S { property q = 0.0 }
        source a = environment(sphere) emits T count 10
        on settle(t: T, s: S) { s.q += t.p }
    """)
    code = cli.main(["sweep", str(tmp_path / "e.gamma"), "--scene", "nowhere.obj",
                     "--grid", "speed=1,2", "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 2
    assert "--grid speed: e.gamma has no parameter 'speed'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_run_on_ray_without_ray_says_how_to_install_it(tmp_path, monkeypatch, capsys):
    (tmp_path / "e.gamma").write_text("""
        ton T { motion straight = 1.0  carry p = 1.0 }
        surface S { property q = 0.0 }
        source a = environment(sphere) emits T count 10
        on settle(t: T, s: S) { s.q += t.p }
    """)
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    monkeypatch.setitem(sys.modules, "ray", None)     # import ray fails as if not installed
    code = cli.main(["run", str(tmp_path / "e.gamma"), "--scene", str(tmp_path / "m.obj"), "--surfels", "100",
                     "--iterations", "1", "--ray", "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 1
    err = capsys.readouterr().err
    assert "Ray is not installed" in err and "pip install '.[ray]'" in err
    assert not list((tmp_path / "out").rglob("iter_*"))


@pytest.mark.parametrize("where", [["--ray"], ["--ray-address", "127.0.0.1:1"]])
def test_run_on_ray_refuses_an_effect_that_changes_shape(tmp_path, capsys, where):
    """The workers keep the scene as loaded; the shape step re-tiles it. The
    refusal names the shape clause and comes before Ray is started or reached
    and before anything is written."""
    (tmp_path / "e.gamma").write_text(
        "ton T { motion straight = 1.0  carry worn = 1.0 }\n"
        "surface S { property worn = 0.0\n"
        "  shape worn = -0.01 }\n"
        "source a = environment(sphere) emits T count 10\n"
        "on settle(t: T, s: S) { s.worn += t.worn }\n")
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    code = cli.main(["run", str(tmp_path / "e.gamma"), "--scene", str(tmp_path / "m.obj"), "--surfels", "100",
                     "--iterations", "1", *where, "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 1
    err = capsys.readouterr().err
    assert f"{where[0]}: {tmp_path / 'e.gamma'}:3:9: an effect that changes the shape of the scene " \
           "cannot be traced on Ray" in err
    assert not (tmp_path / "out").exists()


class _FlakyRay:
    """Stands in for the ray module: init fails `failures` times (as Ray's
    fixed 30 s raylet wait does on a loaded machine), then succeeds."""

    def __init__(self, failures):
        self.failures, self.inits, self.shutdowns, self.up = failures, [], 0, False

    def is_initialized(self):
        return self.up

    def init(self, **kwargs):
        self.inits.append(kwargs)
        if len(self.inits) <= self.failures:
            raise Exception("Timed out after 30 seconds waiting for the raylet")
        self.up = True

    def shutdown(self):
        self.shutdowns += 1
        self.up = False


@pytest.mark.parametrize("failures, started", [(0, True), (2, True), (3, False)])
def test_a_local_ray_start_is_tried_three_times(monkeypatch, failures, started):
    from gamma.driver.distributed import cluster

    fake = _FlakyRay(failures)
    monkeypatch.setattr(cluster, "ray_module", lambda: fake)
    if started:
        connection = cluster.connect(num_cpus=2)
        assert connection.started and fake.up
        assert len(fake.inits) == failures + 1 and fake.shutdowns == failures   # each failed start cleaned up
        connection.close()
        assert not fake.up
    else:
        with pytest.raises(cluster.RayUnavailable, match="cannot start or reach a local Ray: Timed out"):
            cluster.connect(num_cpus=2)
        assert len(fake.inits) == 3 and fake.shutdowns == 3


def test_a_cluster_address_is_tried_once(monkeypatch):
    from gamma.driver.distributed import cluster

    fake = _FlakyRay(1)
    monkeypatch.setattr(cluster, "ray_module", lambda: fake)
    with pytest.raises(cluster.RayUnavailable, match="cannot start or reach the Ray cluster at '10.0.0.1:6379'"):
        cluster.connect("10.0.0.1:6379")
    assert [call["address"] for call in fake.inits] == ["10.0.0.1:6379"]
