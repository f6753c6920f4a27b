"""gammac sweep on a local Ray (loopback, shared by the session): every cell
equals, byte for byte, the same gammac run on one machine; reruns skip
finished cells; a failing cell is reported and the others go on; a worker
killed mid-cell is retried with the same result."""

import json
from pathlib import Path

import pytest
from PIL import Image

from gamma import cli
from gamma.driver.distributed.sweep import parse_grid, sweep

EFFECT = """
param rate = 0.05
ton Weather { motion straight = 1.0  carry patina = 1.0 }
surface Copper { reflectance straight = 0.5  property patina = 0.0 }
source air = environment(sphere) emits Weather count 6000
on settle(t: Weather, s: Copper) { s.patina += rate * t.patina }
"""
RUN = ["--surfels", "2000", "--iterations", "2", "--size", "64"]


def outputs(folder: Path) -> dict:
    """Every file a run wrote except summary.json (which holds timings)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != "summary.json"}


def local_run(tmp_path, box_obj, out, *extra) -> Path:
    code = cli.main(["run", str(tmp_path / "e.gamma"), "--scene", str(box_obj), *RUN, "--quiet",
                     "--out", str(out), *extra])
    assert code == 0
    return out


@pytest.fixture
def effect(tmp_path):
    (tmp_path / "e.gamma").write_text(EFFECT)
    return tmp_path / "e.gamma"


def test_cells_equal_local_runs_and_rerun_skips_them(ray_local, tmp_path, effect, box_obj, capsys):
    out = tmp_path / "sweep"
    argv = ["sweep", str(effect), "--scene", str(box_obj), "--grid", "rate=0.05,0.2", "--grid", "seed=1..2",
            *RUN, "--out", str(out)]
    assert cli.main(argv) == 0
    index = json.loads((out / "index.json").read_text())
    assert [c["name"] for c in index["cells"]] == ["rate=0.05_seed=1", "rate=0.05_seed=2",
                                                   "rate=0.2_seed=1", "rate=0.2_seed=2"]
    assert index["grid"] == {"rate": ["0.05", "0.2"], "seed": ["1", "2"]}
    for cell in index["cells"]:
        assert cell["status"] == "ok" and cell["error"] is None
        rate, seed = cell["parameters"]["rate"], cell["parameters"]["seed"]
        local = local_run(tmp_path, box_obj, tmp_path / f"local-{rate}-{seed}",
                          "--param", f"rate={rate}", "--seed", str(seed))
        mine = outputs(out / cell["folder"])
        assert mine == outputs(local), cell["name"]
        assert "maps/iter_0002.ply" in mine and "renders/iter_0002.png" in mine
        summary = json.loads((local / "summary.json").read_text())
        assert cell["summary"]["property_sums"] == summary["iterations"][-1]["property_sums"]
        assert cell["summary"]["emitted"] == 6000
        assert cell["command"].startswith("gammac run ") and f"--seed {seed}" in cell["command"]
    sums = [c["summary"]["property_sums"]["patina"] for c in index["cells"]]
    assert sums[2] == pytest.approx(4 * sums[0], rel=1e-5)   # rate 0.2 deposits 4x rate 0.05
    assert sums[0] != sums[1]                                # another seed, another result
    err = capsys.readouterr().err
    assert "4/4 cells" in err and "ETA" in err
    with Image.open(out / "contact-sheet.png") as sheet:
        assert sheet.width > 2 * 240 and sheet.height > 2 * 64        # a 2 x 2 grid of tiles
    # A rerun runs nothing: every cell is kept as it was.
    before = {p: p.stat().st_mtime_ns for p in (out / "cells").rglob("*.ply")}
    assert cli.main(argv) == 0
    assert "4 of 4 cells finished earlier; running 0" in capsys.readouterr().err
    assert before == {p: p.stat().st_mtime_ns for p in (out / "cells").rglob("*.ply")}


def test_a_failing_cell_is_reported_and_the_others_finish(ray_local, tmp_path, effect, box_obj, capsys):
    out = tmp_path / "sweep"
    argv = ["sweep", str(effect), "--scene", str(box_obj), "--grid", "surfels=0,1000", "--iterations", "1",
            "--size", "32", "--out", str(out)]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert "cell surfels=0 failed" in err and "--surfels must be between 1 and" in err
    assert "1 cell failed: surfels=0" in err
    cells = {c["name"]: c for c in json.loads((out / "index.json").read_text())["cells"]}
    assert cells["surfels=0"]["status"] == "failed" and cells["surfels=0"]["parameters"] == {"surfels": 0}
    assert "--surfels must be between" in cells["surfels=0"]["error"]
    assert not (out / "cells" / "surfels=0").exists()
    assert cells["surfels=1000"]["status"] == "ok"
    assert (out / "cells" / "surfels=1000" / "maps" / "iter_0001.ply").is_file()
    # The rerun tries the failed cell again, not the finished one.
    assert cli.main(argv) == 1
    assert "1 of 2 cells finished earlier; running 1" in capsys.readouterr().err


def test_a_worker_killed_mid_cell_is_retried_with_the_same_result(ray_local, tmp_path, effect, box_obj):
    marker = tmp_path / "crashed"
    from gamma.options import from_args

    args = cli._parser().parse_args(["sweep", str(effect), "--scene", str(box_obj), "--grid", "seed=3", *RUN,
                                     "--out", str(tmp_path / "sweep")])
    cells = sweep(str(effect), [], from_args(args), [parse_grid("seed=3")], progress=False,
                  _crash_marker=str(marker))
    assert marker.exists()                 # the first attempt's worker did die
    assert [c.status for c in cells] == ["ok"]
    local = local_run(tmp_path, box_obj, tmp_path / "local", "--seed", "3")
    assert outputs(tmp_path / "sweep" / "cells" / "seed=3") == outputs(local)
