"""gammac run reads its mesh file ahead, while it reads and checks the effect
(gamma/driver/prefetch.py): the mesh read ahead is the one reading the file
later gives, a file changed in between is read again, and errors stay where
they were."""

import os
import threading

import numpy as np

from conftest import ROOT, run_gammac
from gamma import _runtime as rt
from gamma.driver import prefetch

BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"


def arrays(mesh):
    return np.asarray(mesh.vertices()), np.asarray(mesh.triangles())


def test_the_mesh_read_ahead_is_the_mesh_of_the_file():
    prefetch.start(str(BUNNY))
    ahead = prefetch.take(BUNNY)
    assert ahead is not None
    direct = rt.Mesh.load(str(BUNNY))
    for a, b in zip(arrays(ahead), arrays(direct)):
        assert np.array_equal(a, b)
    assert ahead.bounds == direct.bounds
    assert prefetch.take(BUNNY) is None          # handed out once


def test_a_file_changed_after_it_was_read_ahead_is_read_again(tmp_path):
    path = tmp_path / "tri.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    prefetch.start(str(path))
    prefetch._pending[str(path)].thread.join()
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n")
    assert prefetch.take(path) is None


def test_only_regular_obj_and_ply_files_are_read_ahead(tmp_path):
    os.mkfifo(tmp_path / "pipe.obj")
    prefetch.start(str(tmp_path / "pipe.obj"))   # must not block on the FIFO
    assert prefetch.take(tmp_path / "pipe.obj") is None
    prefetch.start(str(tmp_path / "scene.json"))
    assert str(tmp_path / "scene.json") not in prefetch._pending
    assert not [t for t in threading.enumerate() if t.name == "gamma-mesh-read"]


def test_an_effect_error_comes_before_a_mesh_error(tmp_path):
    (tmp_path / "bad.gamma").write_text("surface S { reflectance straight = 0.5 }\nbogus\n")
    (tmp_path / "garbage.obj").write_text("v 0 0 0\nf 1 2 3 4 5\n")
    r = run_gammac("run", tmp_path / "bad.gamma", "--scene", tmp_path / "garbage.obj", "--quiet",
                   "--out", tmp_path / "out")
    assert r.returncode == 1
    assert "bad.gamma:2:" in r.stderr and "garbage.obj" not in r.stderr
    assert not (tmp_path / "out").exists()
