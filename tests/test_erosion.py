"""Shape change (SPEC §5 `shape`, §13.12): the erosion example end to end,
the mass books on every example, determinism with re-tiling, errors."""

import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, run_gammac

ARCH_ARGS = ("--assign", "ground=Ground", "--assign", "arch=Sandstone")


@pytest.fixture(scope="module")
def arch_obj(tmp_path_factory):
    path = tmp_path_factory.mktemp("arch") / "arch.obj"
    r = subprocess.run([sys.executable, str(ROOT / "examples" / "scenes" / "make_arch.py"), str(path)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return path


def balance(books):
    left = books["removed"] + books["emitted"] + books["created"]
    right = books["deposited"] + books["escaped"] + books["dropped"] + books["in_flight"]
    return left, right


@pytest.fixture(scope="module")
def erosion_run(arch_obj, tmp_path_factory):
    out = tmp_path_factory.mktemp("erosion") / "out"
    r = run_gammac("run", ROOT / "examples" / "erosion.gamma", "--scene", arch_obj, *ARCH_ARGS,
                   "--surfels", 12000, "--tons", 60000, "--iterations", 3, "--threads", 2, "--quiet",
                   "--out", out)
    assert r.returncode == 0, r.stderr
    (out / "stderr.txt").write_text(r.stderr)
    return out


def test_each_shape_limit_is_warned_once_and_counted_in_every_iteration(erosion_run):
    # The arch stands on the ground plate, so deposition under and beside its
    # foot is held back by the clearance limit in every iteration (SPEC §13.12).
    summary = json.loads((erosion_run / "summary.json").read_text())
    stderr = (erosion_run / "stderr.txt").read_text()
    limited = [record["shape"]["clearance_limited"] for record in summary["iterations"]]
    assert sum(1 for n in limited if n) >= 2
    warnings = [line for line in stderr.splitlines() if "no part wears through" in line]
    first = next(it for it, n in enumerate(limited, 1) if n)
    assert len(warnings) == 1
    assert warnings[0].startswith("gammac: warning: ") and "erosion.gamma:" in warnings[0]
    assert f"of {limited[first - 1]} vertices" in warnings[0] and f"in iteration {first} " in warnings[0]
    assert "shape.clearance_limited" in warnings[0]


def test_erosion_writes_meshes_geometry_and_balanced_books(erosion_run):
    from gamma.driver.outputs.outputs import read_mesh_ply

    summary = json.loads((erosion_run / "summary.json").read_text())
    first = summary["geometry"]
    assert first["closed"] is False          # the ground plate is open
    assert summary["iterations"][0]["shape"]["retiled"] is True     # the input's tiling is re-tiled first
    for it, record in enumerate(summary["iterations"], 1):
        g = record["geometry"]
        assert g["triangles"] > 0 and g["area"] > 0
        assert g["min_angle_deg"] >= 15.0
        # the bound's own measure: corners not between two boundary or seam edges
        assert g["min_free_angle_deg"] >= max(15.0, g["min_angle_deg"])
        books = record["mass"]["stone"]
        assert books["removed"] > 0 and books["deposited"] > 0
        assert books["emitted"] == 0 and books["dropped"] == 0 and books["in_flight"] == 0
        assert abs(books["created"]) <= 1e-5 * books["removed"]     # pick-up only moves stone
        left, right = balance(books)
        assert right == pytest.approx(left, rel=1e-9)
        assert books["removed"] == pytest.approx(books["deposited"] + books["escaped"], rel=1e-5)
        columns, tris = read_mesh_ply(erosion_run / "meshes" / f"iter_{it:04d}.ply")
        assert len(tris) == g["triangles"]
        assert set(columns) >= {"x", "y", "z", "nx", "ny", "nz", "stone"}
        assert np.all(np.isfinite(columns["x"]))
        assert tris.max() < len(columns["x"])
    # The stone lost on the arch is what the surfels lost: the property sum fell
    # where the wind hit and rose where sand settled.
    columns, _ = read_mesh_ply(erosion_run / "meshes" / "iter_0003.ply")
    assert columns["stone"].min() < 0 < columns["stone"].max()


def test_erosion_is_bit_identical_at_one_and_two_threads(arch_obj, tmp_path):
    outs = {}
    for threads in (1, 2):
        out = tmp_path / f"t{threads}"
        r = run_gammac("run", ROOT / "examples" / "erosion.gamma", "--scene", arch_obj, *ARCH_ARGS,
                       "--surfels", 6000, "--tons", 20000, "--iterations", 2, "--threads", threads,
                       "--quiet", "--out", out)
        assert r.returncode == 0, r.stderr
        outs[threads] = [(out / sub / f"iter_{i:04d}.ply").read_bytes()
                         for sub in ("meshes", "maps") for i in (1, 2)]
    assert outs[1] == outs[2]
    assert outs[1][0] != outs[1][1]      # the mesh really changed


EXAMPLES = [
    ("patina.gamma", "stanford-bunny.obj", ()),
    ("stain-bleeding.gamma", "staircase.obj", ("--assign", "chain=Iron", "--assign", "*=Cement")),
]


@pytest.mark.parametrize("effect,scene,extra", EXAMPLES)
def test_mass_books_balance_on_the_examples(effect, scene, extra, tmp_path):
    out = tmp_path / "out"
    r = run_gammac("run", ROOT / "examples" / effect, "--scene", ROOT / "examples" / "scenes" / scene,
                   *extra, "--surfels", 8000, "--tons", 20000, "--iterations", 2, "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    for record in summary["iterations"]:
        for name, books in record.get("mass", {}).items():
            left, right = balance(books)
            assert right == pytest.approx(left, rel=1e-9, abs=1e-9), name


def test_shape_of_an_unknown_property_is_an_error(tmp_path, box_obj):
    (tmp_path / "e.gamma").write_text(
        "ton T { motion straight = 1 }\n"
        "surface S { property worn = 0\n  shape wron = -0.01 }\n"
        "source s = environment(sphere) emits T count 10\n")
    r = run_gammac("run", tmp_path / "e.gamma", "--scene", box_obj, "--out", tmp_path / "o")
    assert r.returncode != 0
    assert "3:9" in r.stderr and "shape follows 'wron', which is not a property of S" in r.stderr
    assert "did you mean 'worn'" in r.stderr
