"""gammac run keeps its setup (surfels, triangle lookup, splat kernel) in the
setup cache and the next run on the same mesh, count and seed takes it
(gamma/driver/caches/setup_cache.py): the files written are the same either way,
a damaged file is never used, another seed is set up again, and the cache
stays under its limit."""

import json
import os
import struct
import subprocess
import sys
import textwrap
import zlib

import numpy as np

from conftest import ROOT
from test_prefetch import folder_hash

from gamma import _runtime as rt
from gamma.driver.running import prefetch
from gamma.driver.caches import setup_cache

BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"


def run(tmp_path, cache, name, *extra, env=None, script=None):
    """gammac run (patina, bunny, 3000 surfels) with the cache folder ``cache``
    ("off": none), or ``script`` run with gammac's arguments: its output
    folder and what its setup took from the cache."""
    out = tmp_path / name
    args = ["run", ROOT / "examples" / "patina.gamma", "--scene", BUNNY, "--surfels", "3000", "--tons", "20000",
            "--iterations", "2", "--threads", "2", "--quiet", "--out", out, *extra]
    command = ["-c", script] if script else ["-m", "gamma.cli"]
    r = subprocess.run([sys.executable, *command, *map(str, args)], capture_output=True, text=True,
                       timeout=600, env=dict(os.environ, GAMMA_CACHE_DIR=str(cache), **(env or {})))
    assert r.returncode == 0, r.stderr
    return out, json.loads((out / "summary.json").read_text())["setup_from_cache"]


def kept(cache):
    return sorted(cache.glob("setup-*.bin"))


def test_a_second_run_takes_its_setup_from_the_cache_and_writes_the_same_files(tmp_path):
    cache = tmp_path / "cache"
    first, took = run(tmp_path, cache, "first")
    assert took == "nothing" and len(kept(cache)) == 1
    second, took = run(tmp_path, cache, "second")
    assert took == "setup"
    assert folder_hash(first) == folder_hash(second)
    # the cache off: nothing kept, nothing taken, the same files
    off, took = run(tmp_path, "off", "off")
    assert took == "nothing"
    assert folder_hash(off) == folder_hash(first)


def test_a_damaged_or_cut_file_is_not_used_and_is_replaced(tmp_path):
    cache = tmp_path / "cache"
    first, _ = run(tmp_path, cache, "first")
    (path,) = kept(cache)
    data = bytearray(path.read_bytes())
    for damage in ("flip", "cut"):
        if damage == "flip":
            data[len(data) // 2] ^= 0x40          # a value inside: only the checksum sees it
            path.write_bytes(bytes(data))
        else:
            path.write_bytes(bytes(data[:len(data) // 3]))
        out, took = run(tmp_path, cache, damage)
        assert took == "nothing", damage
        assert folder_hash(out) == folder_hash(first)
        assert kept(cache) == [path]
        data = bytearray(path.read_bytes())        # written again, whole
    again, took = run(tmp_path, cache, "again")
    assert took == "setup"
    assert folder_hash(again) == folder_hash(first)


def test_another_seed_is_set_up_again_and_kept_beside(tmp_path):
    cache = tmp_path / "cache"
    run(tmp_path, cache, "one")
    _, took = run(tmp_path, cache, "two", "--seed", "2")
    assert took == "nothing"
    assert len(kept(cache)) == 2


def test_the_cache_keeps_under_its_limit_the_most_recent_first(tmp_path):
    cache = tmp_path / "cache"
    # pictures of 16 x 16: their false-colour views, which count towards the limit too
    # (view_cache.py), are a few kB beside setups of ~1 MB
    run(tmp_path, cache, "one", "--size", "16", "--seed", "1")
    size = kept(cache)[0].stat().st_size
    limit_mb = 2.5 * size / (1 << 20)               # room for two
    run(tmp_path, cache, "two", "--size", "16", "--seed", "2", env={"GAMMA_SETUP_CACHE_MB": str(limit_mb)})
    first_two = kept(cache)
    assert len(first_two) == 2
    _, took = run(tmp_path, cache, "one-again", "--size", "16", "--seed", "1",
                  env={"GAMMA_SETUP_CACHE_MB": str(limit_mb)})
    assert took == "setup"                          # used now: the most recent
    run(tmp_path, cache, "three", "--size", "16", "--seed", "3",
        env={"GAMMA_SETUP_CACHE_MB": str(limit_mb)})
    assert len(kept(cache)) == 2
    assert sum(p.stat().st_size for p in [*kept(cache), *cache.glob("view-*.bin")]) <= limit_mb * (1 << 20)
    _, took = run(tmp_path, cache, "one-last", "--size", "16", "--seed", "1",
                  env={"GAMMA_SETUP_CACHE_MB": str(limit_mb)})
    assert took == "setup"                          # seed 2's, the least recently used, went
    # a snapshot larger than half the limit is not kept
    small = tmp_path / "small"
    run(tmp_path, small, "tiny-limit", "--size", "16",
        env={"GAMMA_SETUP_CACHE_MB": str(1.5 * size / (1 << 20))})
    assert kept(small) == []


def test_load_never_raises_and_removes_what_it_cannot_use(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path))
    mesh = rt.Mesh.load(str(BUNNY))
    path = setup_cache.path_for(mesh, 3000, 1)
    for garbage in (b"", b"xy", b"\0" * 64 + setup_cache.MARK, os.urandom(5000)):
        path.write_bytes(garbage)
        assert setup_cache.load(mesh, 3000, 1) is None
        assert not path.exists()
    # a whole file whose checksum fits but whose snapshot is not one (the runtime refuses it)
    body = np.frombuffer(os.urandom(4096), np.uint8)
    path.write_bytes(body.tobytes() + setup_cache.TRAILER.pack(zlib.crc32(body), setup_cache.MARK))
    assert setup_cache.load(mesh, 3000, 1) is None and not path.exists()
    monkeypatch.setenv("GAMMA_CACHE_DIR", "off")
    assert setup_cache.path_for(mesh, 3000, 1) is None and setup_cache.load(mesh, 3000, 1) is None


def test_the_key_follows_the_mesh_count_and_seed(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path))
    mesh = rt.Mesh.load(str(BUNNY))
    v, t = np.asarray(mesh.vertices()).copy(), np.asarray(mesh.triangles())
    v[5, 1] += 1e-4
    moved = rt.Mesh.from_arrays(v, t)
    paths = {setup_cache.path_for(mesh, 3000, 1), setup_cache.path_for(mesh, 3001, 1),
             setup_cache.path_for(mesh, 3000, 2), setup_cache.path_for(moved, 3000, 1)}
    assert len(paths) == 4
    assert setup_cache.path_for(rt.Mesh.load(str(BUNNY)), 3000, 1) == setup_cache.path_for(mesh, 3000, 1)


def build_id(module_file):
    """The linker's build ID in the module file (its NT_GNU_BUILD_ID note), as hex."""
    data = open(module_file, "rb").read()
    note = struct.pack("<III4s", 4, 20, 3, b"GNU\0")    # name size, 20 bytes of SHA-1, NT_GNU_BUILD_ID
    at = data.index(note) + len(note)
    assert data.count(note) == 1
    return data[at:at + 20].hex()


def test_the_name_is_the_runtime_build_the_mesh_count_and_seed(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path))
    mesh = rt.Mesh.load(str(BUNNY))
    assert rt.RUNTIME_BUILD == build_id(rt.__file__)            # the build, not the version string
    assert setup_cache.path_for(mesh, 3000, 1) == tmp_path / f"setup-{rt.RUNTIME_BUILD}-{mesh.fingerprint()}-3000-1.bin"
    assert rt.setup_cache_name(mesh, 3000, 2**63 - 1).endswith(f"-3000-{2**63 - 1}.bin")


def config_for(mesh, surfels=3000, seed=1):
    cfg = rt.Config()
    cfg.surfels, cfg.seed, cfg.threads, cfg.row_width = surfels, seed, 2, 4
    cfg.surface_rows = [[0.0, 0.0, 0.0, 1.0]]
    return cfg


def setup_state(sim):
    return [np.asarray(a) for a in (sim.surfel_positions(), sim.surfel_normals(), sim.surfel_surfaces(),
                                    sim.corner_normals(), sim.setup_snapshot())]


def keep_setup(mesh, surfels=3000, seed=1):
    sim = rt.Simulation(mesh, config_for(mesh, surfels, seed))
    setup_cache.store(sim, mesh, surfels, seed)
    setup_cache.wait()
    return sim


def test_the_read_ahead_gives_the_cached_setup_prepared_and_the_same_setup(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path))
    fresh = keep_setup(rt.Mesh.load(str(BUNNY)))
    prefetch.start(str(BUNNY), 3000, 1, 2)
    mesh = prefetch.take(BUNNY)
    snapshot = prefetch.sample_for(mesh, 3000, 1)
    assert isinstance(snapshot, rt.SetupSnapshot) and snapshot.prepared and not snapshot.made_ahead  # the cache's
    sim = rt.Simulation(mesh, config_for(mesh), None, snapshot)
    assert sim.from_snapshot == "setup" and snapshot.taken
    # the runner's own load (nothing read ahead) gives the same setup, unprepared
    loaded = setup_cache.load(mesh, 3000, 1)
    assert loaded is not None and not loaded.prepared
    from_loaded = rt.Simulation(mesh, config_for(mesh), None, loaded)
    assert from_loaded.from_snapshot == "setup"
    for a, b, c in zip(setup_state(sim), setup_state(from_loaded), setup_state(fresh)):
        assert np.array_equal(a, b) and np.array_equal(a, c)


def test_the_read_ahead_refuses_what_it_cannot_use_and_never_raises(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path))
    keep_setup(rt.Mesh.load(str(BUNNY)))
    (path,) = kept(tmp_path)
    whole = path.read_bytes()
    for damaged in (whole[:len(whole) // 2], whole[:100] + bytes([whole[100] ^ 1]) + whole[101:]):
        path.write_bytes(damaged)
        mesh, signature, snapshot = rt.read_mesh_ahead(str(BUNNY), str(tmp_path), 3000, 1, 2)
        assert mesh is not None and snapshot is None and not path.exists()
        assert signature == prefetch._signature(str(BUNNY))
    # a count or seed with none kept, the cache off (no folder), no count: the mesh only
    path.write_bytes(whole)
    for folder, surfels, seed in ((str(tmp_path), 3000, 2), (str(tmp_path), 2999, 1), ("", 3000, 1),
                                  (str(tmp_path), 0, 1)):
        mesh, _, snapshot = rt.read_mesh_ahead(str(BUNNY), folder, surfels, seed, 2)
        assert mesh is not None and snapshot is None
    assert path.read_bytes() == whole
    # files it cannot read as a mesh: nothing (read again, and reported, by scene.py)
    (tmp_path / "garbage.obj").write_text("v 0 0 0\nf 1 2 3 4 5\n")
    os.mkfifo(tmp_path / "pipe.obj")
    for bad in ("garbage.obj", "pipe.obj", "missing.obj", "."):
        assert rt.read_mesh_ahead(str(tmp_path / bad), str(tmp_path), 3000, 1, 2) == (None, None, None)
    # prefetch: the mesh read ahead, the setup refused, the surfels sampled instead (and, for
    # one surface, the rest of the setup made ahead: not the cache's)
    path.write_bytes(whole[:-1])
    prefetch.start(str(BUNNY), 3000, 1, 2)
    mesh = prefetch.take(BUNNY)
    sample = prefetch.sample_for(mesh, 3000, 1)
    assert not path.exists()
    assert (sample.made_ahead if isinstance(sample, rt.SetupSnapshot)
            else isinstance(sample, rt.SurfelSample) and sample.ok)


NO_PREFETCH = textwrap.dedent("""
    import sys
    from gamma.driver.running import prefetch
    prefetch.worth_sampling = lambda *args: False     # nothing read ahead: the runner loads the cache itself
    sys.argv = ["gammac", *sys.argv[1:]]
    from gamma.cli import entry
    entry()
""")

SLOW_WRITE = textwrap.dedent("""
    import sys, time
    from gamma.driver.running import prefetch
    from gamma.driver.caches import setup_cache
    write = setup_cache._write
    def slow(*args):
        time.sleep(1.5)                               # still writing when the run is done
        write(*args)
    setup_cache._write = slow
    sys.argv = ["gammac", *sys.argv[1:]]
    from gamma.cli import entry
    entry()
""")


def test_a_setup_loaded_without_the_prefetch_is_the_same(tmp_path):
    cache = tmp_path / "cache"
    first, _ = run(tmp_path, cache, "first")
    out, took = run(tmp_path, cache, "unprepared", script=NO_PREFETCH)
    assert took == "setup"
    assert folder_hash(out) == folder_hash(first)


def test_the_setup_is_written_whole_before_gammac_exits(tmp_path):
    cache = tmp_path / "cache"
    run(tmp_path, cache, "slow", script=SLOW_WRITE)
    assert len(kept(cache)) == 1 and not list(cache.glob(".setup-*"))
    _, took = run(tmp_path, cache, "next")
    assert took == "setup"


def test_an_unwritable_cache_or_a_bad_limit_only_costs_time(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    first, took = run(tmp_path, blocker / "cache", "unwritable")
    assert took == "nothing"
    for bad in ("inf", "nan", "lots", "-5"):
        out, took = run(tmp_path, tmp_path / f"cache-{bad}", f"limit-{bad}", env={"GAMMA_SETUP_CACHE_MB": bad})
        assert took == "nothing"
        assert folder_hash(out) == folder_hash(first)
    # not a number: the default limit, so the setup was kept
    assert len(kept(tmp_path / "cache-lots")) == 1 and len(kept(tmp_path / "cache-inf")) == 1
    assert kept(tmp_path / "cache--5") == []          # a limit of nothing keeps nothing


def test_stale_temporary_files_are_removed_and_fresh_ones_kept(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    stale, fresh = cache / ".setup-dead.bin.abc", cache / ".setup-writing.bin.def"
    for path in (stale, fresh):
        path.write_bytes(b"partial")
    old = stale.stat().st_mtime - setup_cache.STALE_TEMPORARY_SECONDS - 10
    os.utime(stale, (old, old))
    run(tmp_path, cache, "one")
    assert not stale.exists() and fresh.exists()


def test_a_setup_taken_behind_the_run_is_the_same_file(tmp_path, monkeypatch):
    mesh = rt.Mesh.load(str(BUNNY))
    sim = rt.Simulation(mesh, config_for(mesh))
    files = {}
    for behind in (False, True):
        monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path / str(behind)))
        setup_cache.store(sim, mesh, 3000, 1, behind=behind)
        setup_cache.wait()
        (files[behind],) = kept(tmp_path / str(behind))
    assert files[True].name == files[False].name
    assert files[True].read_bytes() == files[False].read_bytes()


def test_the_runner_takes_the_setup_behind_the_loop_only_when_nothing_changes_the_shape(tmp_path, monkeypatch):
    from gamma import compile
    from gamma.driver.running import runner

    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path / "cache"))
    seen = []
    monkeypatch.setattr(setup_cache, "store", lambda sim, mesh, surfels, seed, behind=False: seen.append(behind))
    # patina, then patina whose surface follows its property (SPEC: shape)
    moving = tmp_path / "moving.gamma"
    moving.write_text((ROOT / "examples" / "patina.gamma").read_text().replace(
        "property patina = 0.0", "property patina = 0.0\n    shape patina = 0.001"))
    for effect in (ROOT / "examples" / "patina.gamma", moving):
        opts = runner.RunOptions(scene=str(BUNNY), out=str(tmp_path / effect.stem), iterations=1, surfels=2000,
                                 tons=2000, width=16, height=16, progress=False)
        runner.run(compile(str(effect)), opts)
    assert seen == [True, False]       # a surface that moves: its setup is taken before the loop
