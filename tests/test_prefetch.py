"""gammac run reads its mesh file ahead, and samples its surfels, while it
reads and checks the effect (gamma/driver/running/prefetch.py): the mesh read ahead
is the one reading the file later gives, a file changed in between is read
again, the surfels sampled ahead give the setup's own state and the same
output files, and errors stay where they were."""

import hashlib
import os
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest

from conftest import ROOT, run_gammac
from gamma import _runtime as rt
from gamma.driver.running import prefetch

BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"


@pytest.fixture(autouse=True)
def no_setup_cache(monkeypatch):
    """The surfels are sampled here, never taken from the session's setup
    cache (test_setup_cache.py tests that)."""
    monkeypatch.setenv("GAMMA_CACHE_DIR", "off")


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
    prefetch._pending[str(path)].mesh.result()
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


def config(mesh, surfels=2000, seed=3):
    cfg = rt.Config()
    cfg.surfels, cfg.seed, cfg.threads, cfg.row_width = surfels, seed, 2, 4
    cfg.surface_rows = [[0.0, 0.0, 0.0, 1.0]]
    return cfg


def state(sim):
    return [np.asarray(a) for a in (sim.surfel_positions(), sim.surfel_normals(), sim.surfel_surfaces(),
                                    sim.rows())]


def test_the_surfels_sampled_ahead_are_the_setups_own(monkeypatch):
    monkeypatch.setattr(prefetch, "_surfaces", None)
    prefetch.expect(2)                  # known before the sampling ends: no setup made ahead
    prefetch.start(str(BUNNY), 2000, 3, 1)
    mesh = prefetch.take(BUNNY)
    sample = prefetch.sample_for(mesh, 2000, 3)
    assert isinstance(sample, rt.SurfelSample)
    assert sample.ok and sample.matches(mesh, 2000, 3)
    assert prefetch.sample_for(mesh, 2000, 3) is None        # handed out once
    with_sample = rt.Simulation(mesh, config(mesh), sample)
    assert "sample_ahead" in with_sample.setup_seconds        # it was taken ...
    assert "ahead" not in with_sample.setup_seconds and not with_sample.setup_made_ahead
    assert not sample.ok
    plain = rt.Simulation(mesh, config(mesh))
    assert "sample_ahead" not in plain.setup_seconds
    for a, b in zip(state(with_sample), state(plain)):        # ... and it is what the setup samples
        assert np.array_equal(a, b)


def test_the_setup_made_ahead_is_the_setups_own(monkeypatch):
    monkeypatch.setattr(prefetch, "_surfaces", None)        # the effect not known yet: one surface assumed
    prefetch.start(str(BUNNY), 2000, 3, 1)
    mesh = prefetch.take(BUNNY)
    made = prefetch.sample_for(mesh, 2000, 3)
    assert isinstance(made, rt.SetupSnapshot) and made.made_ahead and made.prepared
    assert made.matches(mesh, 2000, 3) and not made.matches(mesh, 2000, 4)
    taken = rt.Simulation(mesh, config(mesh), None, made)
    assert taken.from_snapshot == "setup" and taken.setup_made_ahead and made.taken
    assert {"ahead", "sample_ahead"} <= set(taken.setup_seconds)
    plain = rt.Simulation(mesh, config(mesh))
    for a, b in zip(state(taken), state(plain)):
        assert np.array_equal(a, b)
    assert np.array_equal(np.asarray(taken.setup_snapshot()), np.asarray(plain.setup_snapshot()))


def test_surfels_sampled_for_another_count_or_seed_are_not_used():
    prefetch.start(str(BUNNY), 2000, 3, 2)
    mesh = prefetch.take(BUNNY)
    assert prefetch.sample_for(mesh, 2000, 4) is None
    sample = rt.SurfelSample(mesh, 1999, 3, 2)
    sim = rt.Simulation(mesh, config(mesh), sample)
    assert "sample_ahead" not in sim.setup_seconds and sample.ok
    # a mesh nobody read ahead
    assert prefetch.sample_for(rt.Mesh.load(str(BUNNY)), 2000, 3) is None


def test_a_sample_that_failed_leaves_the_error_to_the_setup(tmp_path):
    path = tmp_path / "tri.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    mesh = rt.Mesh.load(str(path))
    failed = rt.SurfelSample(mesh, 0, 1, 1)                   # no exception here
    assert not failed.ok and not failed.matches(mesh, 0, 1)
    cfg = config(mesh, surfels=0)
    errors = []
    for ahead in (None, failed):
        try:
            rt.Simulation(mesh, cfg, ahead)
        except ValueError as err:
            errors.append(str(err))
    assert len(errors) == 2 and errors[0] == errors[1] and "surfels" in errors[0]


def test_surfels_are_sampled_ahead_only_for_options_the_run_accepts():
    assert prefetch.worth_sampling(100_000, 1, 0)
    assert not prefetch.worth_sampling(0, 1, 0)
    assert not prefetch.worth_sampling(20_000_001, 1, 0)
    assert not prefetch.worth_sampling(1000, 2**63, 0)
    assert not prefetch.worth_sampling(1000, 1, 257)
    prefetch.start(str(BUNNY), 20_000_001, 1, 2)
    mesh = prefetch.take(BUNNY)
    assert mesh is not None and prefetch.sample_for(mesh, 20_000_001, 1) is None


NO_SAMPLE = textwrap.dedent("""
    import sys
    from gamma.driver.running import prefetch
    prefetch.worth_sampling = lambda *args: False
    sys.argv = ["gammac", *sys.argv[1:]]
    from gamma.cli import entry
    entry()
""")


def folder_hash(folder):
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*")):
        if path.is_file() and path.name != "summary.json":
            digest.update(str(path.relative_to(folder)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def test_gammac_run_takes_the_surfels_sampled_ahead_and_writes_the_same_files(tmp_path):
    import json

    args = ["run", ROOT / "examples" / "patina.gamma", "--scene", BUNNY, "--surfels", "3000", "--tons", "20000",
            "--iterations", "2", "--threads", "2", "--quiet"]
    ahead = run_gammac(*args, "--out", tmp_path / "ahead")
    assert ahead.returncode == 0, ahead.stderr
    plain = subprocess.run([sys.executable, "-c", NO_SAMPLE, *map(str, args), "--out", str(tmp_path / "plain")],
                           capture_output=True, text=True, timeout=600)
    assert plain.returncode == 0, plain.stderr
    assert "sample_ahead" in json.loads((tmp_path / "ahead" / "summary.json").read_text())["setup_phases"]
    assert "sample_ahead" not in json.loads((tmp_path / "plain" / "summary.json").read_text())["setup_phases"]
    assert len(list((tmp_path / "ahead" / "renders").glob("iter_*.png"))) == 2
    assert folder_hash(tmp_path / "ahead") == folder_hash(tmp_path / "plain")


NO_AHEAD = NO_SAMPLE.replace("prefetch.worth_sampling = lambda *args: False",
                            "prefetch.AHEAD_MAX_SURFELS = 0")


def summary_of(folder):
    import json

    return json.loads((folder / "summary.json").read_text())


def test_a_setup_made_ahead_for_one_surface_is_taken_whole_and_writes_the_same_files(tmp_path):
    args = ["run", ROOT / "examples" / "patina.gamma", "--scene", BUNNY, "--surfels", "3000", "--tons", "20000",
            "--iterations", "2", "--threads", "2", "--quiet"]
    ahead = run_gammac(*args, "--out", tmp_path / "ahead")
    assert ahead.returncode == 0, ahead.stderr
    sampled = subprocess.run([sys.executable, "-c", NO_AHEAD, *map(str, args), "--out", str(tmp_path / "sampled")],
                             capture_output=True, text=True, timeout=600)
    assert sampled.returncode == 0, sampled.stderr
    made = summary_of(tmp_path / "ahead")
    assert "ahead" in made["setup_phases"] and "sample_ahead" in made["setup_phases"]
    assert made["setup_from_cache"] == "nothing"            # made here, not read from the cache
    only_sampled = summary_of(tmp_path / "sampled")
    assert "ahead" not in only_sampled["setup_phases"] and "sample_ahead" in only_sampled["setup_phases"]
    assert folder_hash(tmp_path / "ahead") == folder_hash(tmp_path / "sampled")


def test_two_surfaces_take_only_the_surfels_of_a_setup_made_ahead_and_write_the_same_files(tmp_path):
    args = ["run", ROOT / "examples" / "stain-bleeding.gamma", "--scene", ROOT / "examples" / "scenes" /
            "staircase.obj", "--assign", "chain=Iron", "--assign", "*=Cement", "--surfels", "4000",
            "--tons", "20000", "--iterations", "2", "--threads", "2", "--quiet"]
    outs = {}
    for name, script in (("default", None), ("sampled", NO_AHEAD), ("plain", NO_SAMPLE)):
        out = tmp_path / name
        r = (run_gammac(*args, "--out", out) if script is None else
             subprocess.run([sys.executable, "-c", script, *map(str, args), "--out", str(out)],
                            capture_output=True, text=True, timeout=600))
        assert r.returncode == 0, r.stderr
        outs[name] = out
    default = summary_of(outs["default"])
    assert "ahead" not in default["setup_phases"] and default["setup_from_cache"] == "nothing"
    assert folder_hash(outs["default"]) == folder_hash(outs["sampled"]) == folder_hash(outs["plain"])


def test_an_effect_error_comes_first_while_the_surfels_are_sampled(tmp_path):
    (tmp_path / "bad.gamma").write_text("surface S { reflectance straight = 0.5 }\nbogus\n")
    r = run_gammac("run", tmp_path / "bad.gamma", "--scene", BUNNY, "--surfels", "400000", "--quiet",
                   "--out", tmp_path / "out")
    assert r.returncode == 1
    assert "bad.gamma:2:" in r.stderr
    assert "Traceback" not in r.stderr and "leaked" not in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


EXITS = textwrap.dedent("""
    import sys
    from gamma.driver.running import prefetch
    prefetch.start(sys.argv[1], 400000, 1, 2)
    assert prefetch.take(sys.argv[1]) is not None
    sys.exit(0)                      # the interpreter's own exit, the sampling still running
""")


def test_a_process_that_exits_while_the_surfels_are_sampled_exits_cleanly():
    r = subprocess.run([sys.executable, "-c", EXITS, str(BUNNY)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "leaked" not in r.stderr, r.stderr


BEFORE_FRONT_END = textwrap.dedent("""
    import sys
    from gamma.driver.running import prefetch
    seen = []
    prefetch.start = lambda *args: seen.append(sorted(m for m in sys.modules
                                                      if m.startswith(("gamma.frontend", "numpy", "lark"))))
    from gamma.cli import main
    main(["run", "missing.gamma", "--scene", "missing.obj", "--out", "out"])
    print(seen)
""")


def test_the_mesh_read_starts_before_the_front_end_is_imported(tmp_path):
    r = subprocess.run([sys.executable, "-c", BEFORE_FRONT_END], capture_output=True, text=True, timeout=600,
                       cwd=tmp_path)
    assert r.stdout.strip() == "[[]]", (r.stdout, r.stderr)
