"""The cache of false-colour views (gamma/driver/caches/view_cache.py): a run whose
setup the cache holds reads its view back instead of casting it, and writes
the same files; a damaged view is refused and cast again; the bytes of a view
are checked when read back; a view is keyed by everything it depends on."""

import os
import struct
import types

import numpy as np
import pytest

from conftest import ROOT
from test_prefetch import folder_hash

from gamma import _runtime as rt
from gamma import compile
from gamma.driver.running import runner
from gamma.driver.caches import view_cache

BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"
PATINA = ROOT / "examples" / "patina.gamma"


def run(tmp_path, name, effect=PATINA, **options):
    opts = runner.RunOptions(scene=str(BUNNY), out=str(tmp_path / name), iterations=2, surfels=3000,
                             tons=20000, width=48, height=40, progress=False, **options)
    runner.run(compile(str(effect)), opts)
    return tmp_path / name


@pytest.fixture
def spied(tmp_path, monkeypatch):
    """GAMMA_CACHE_DIR set; what view_cache.load gave and store was given, per run."""
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path / "cache"))
    seen = {"loaded": [], "stored": []}
    load, store = view_cache.load, view_cache.store

    def spy_load(path, width, height, surfels):
        view = load(path, width, height, surfels)
        seen["loaded"].append(view is not None)
        return view

    def spy_store(path, view):
        seen["stored"].append(path is not None)
        store(path, view)

    monkeypatch.setattr(view_cache, "load", spy_load)
    monkeypatch.setattr(view_cache, "store", spy_store)
    return seen


def views(tmp_path):
    from gamma.driver.caches import setup_cache

    setup_cache.wait()
    return sorted((tmp_path / "cache").glob("view-*.bin"))


def test_a_second_run_reads_its_view_and_writes_the_same_files(tmp_path, monkeypatch, spied):
    first = run(tmp_path, "first")
    assert spied == {"loaded": [False], "stored": [True]} and len(views(tmp_path)) == 1
    second = run(tmp_path, "second")
    assert spied == {"loaded": [False, True], "stored": [True]}
    assert folder_hash(second) == folder_hash(first)
    monkeypatch.setenv("GAMMA_CACHE_DIR", "off")
    off = run(tmp_path, "off")
    assert spied == {"loaded": [False, True], "stored": [True, False]}     # nothing read, nothing kept
    assert folder_hash(off) == folder_hash(first)


@pytest.mark.parametrize("damage", ["flip", "cut", "trailer"])
def test_a_damaged_view_is_removed_and_cast_again(tmp_path, spied, damage):
    first = run(tmp_path, "first")
    (path,) = views(tmp_path)
    data = bytearray(path.read_bytes())
    if damage == "flip":
        data[len(data) // 2] ^= 0x10
    elif damage == "cut":
        data = data[:len(data) // 3]
    else:
        data[-1] ^= 0xFF
    path.write_bytes(bytes(data))
    again = run(tmp_path, "again")
    assert spied["loaded"] == [False, False] and spied["stored"] == [True, True]
    assert folder_hash(again) == folder_hash(first)
    (kept,) = views(tmp_path)
    assert kept.read_bytes() != bytes(data)                 # cast again and kept whole


def test_a_whole_view_of_another_surfel_count_or_unreadable_bytes_cost_only_a_cast(tmp_path, spied):
    first = run(tmp_path, "first")
    (path,) = views(tmp_path)
    _, other = cast_view(48, 40)                              # 2000 surfels, not the run's 3000
    from gamma.driver.caches import setup_cache

    for data in (bytes(other.to_bytes()),
                 struct.pack("<4sIiiQII Q", b"GMFV", 1, 2147418113, 1718039348, 3000, 8, 0, 0) + b"\0" * 4):
        setup_cache.write_with_trailer(path, data, view_cache.MARK)   # whole, its checksum right
        again = run(tmp_path, "again")
        assert spied["loaded"][-1] is False and spied["stored"][-1] is True
        assert folder_hash(again) == folder_hash(first)
        assert view_cache.load(path, 48, 40, 3000) is not None        # cast again and kept
    assert view_cache.load(path, 48, 40, 2999) is None and not path.exists()   # refused: removed


def test_a_shape_that_changes_keeps_no_view(tmp_path, spied):
    moving = tmp_path / "moving.gamma"
    moving.write_text(PATINA.read_text().replace("property patina = 0.0",
                                                 "property patina = 0.0\n    shape patina = 0.001"))
    run(tmp_path, "moving", effect=moving)
    assert spied == {"loaded": [], "stored": [False]} and views(tmp_path) == []


def cast_view(width=40, height=30):
    mesh = rt.Mesh.load(str(BUNNY))
    cfg = rt.Config()
    cfg.surfels, cfg.seed, cfg.threads, cfg.row_width = 2000, 1, 2, 4
    cfg.surface_rows = [[0.0, 0.0, 0.0, 1.0]]
    sim = rt.Simulation(mesh, cfg)
    lo, hi = (np.asarray(b, float) for b in mesh.bounds)
    centre = (lo + hi) / 2
    eye = centre + np.array([0.0, 0.0, 2.5 * np.linalg.norm(hi - lo)])
    return sim, sim.false_colour_view(tuple(eye), tuple(centre), (0.0, 1.0, 0.0), 40.0, width, height, 2)


def test_a_view_read_back_gives_the_same_pictures():
    sim, view = cast_view()
    data = view.to_bytes()
    back = rt.FalseColourView.from_bytes(bytes(data))
    assert (back.width, back.height) == (view.width, view.height)
    assert np.array_equal(back.to_bytes(), data)
    values = np.random.default_rng(1).random(sim.num_surfels, dtype=np.float32)
    assert np.array_equal(back.values(values), view.values(values), equal_nan=True)
    assert np.array_equal(back.shade(), view.shade(), equal_nan=True)
    background = np.zeros((view.height, view.width, 3), np.uint8)
    assert np.array_equal(back.picture(values, 0.0, 1.0, background, 2), view.picture(values, 0.0, 1.0, background, 2))
    hit = ~np.isnan(view.shade())
    assert 0 < hit.sum() < hit.size                          # the bunny and the background both in the picture


def test_bytes_that_are_not_a_whole_view_are_refused():
    _, view = cast_view()
    data = bytes(view.to_bytes())
    header = struct.Struct("<4sIiiQII Q")
    magic, version, width, height, surfels, k, _, entries = header.unpack_from(data)
    assert (magic, version, width, height, k) == (b"GMFV", 1, 40, 30, 8) and entries > 0
    npx = width * height
    first_index = header.size + npx * 5                       # after count and shade
    bad = {
        "magic": b"XXXX" + data[4:],
        "cut": data[:-1],
        "longer": data + b"\0",
        "index": data[:first_index] + struct.pack("<I", surfels) + data[first_index + 4:],
        "count": data[:header.size] + bytes([9]) + data[header.size + 1:],
        "empty": b"",
        # sizes whose products wrap around 2^64: 44 bytes claiming ~3.7e18 pixels
        "wrapping": header.pack(b"GMFV", 1, 2147418113, 1718039348, 1000, 8, 0, 0) + b"\0" * 4,
        "entries": header.pack(b"GMFV", 1, width, height, surfels, k, 0, 2**61) + data[header.size:],
    }
    # a hit pixel's weight or shade out of [0, 1] (a picture's bytes come from them)
    count = data[header.size:header.size + npx]
    hit = next(px for px in range(npx) if count[px] != 0xFF)
    shade_at = header.size + npx + 4 * hit
    bad["shade"] = data[:shade_at] + struct.pack("<f", float("inf")) + data[shade_at + 4:]
    first_weight = first_index + 4 * entries
    bad["weight"] = data[:first_weight] + struct.pack("<d", -0.5) + data[first_weight + 8:]
    for what, blob in bad.items():
        with pytest.raises(ValueError):
            rt.FalseColourView.from_bytes(blob)
            pytest.fail(what)


def test_the_key_follows_what_the_view_depends_on(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path))
    mesh = rt.Mesh.load(str(BUNNY))
    triangles = mesh.num_triangles
    scene = types.SimpleNamespace(mesh=mesh, triangle_surface=np.zeros(triangles, np.int32), triangle_flat=None)
    opts = runner.RunOptions(scene=str(BUNNY), out=str(tmp_path))
    camera = ((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0)

    def key(scene=scene, opts=opts, camera=camera):
        return view_cache.path_for(types.SimpleNamespace(scene=scene, opts=opts, camera=camera)).name

    base = key()
    assert base.startswith("view-") and base == key()
    two = np.zeros(triangles, np.int32)
    two[: triangles // 2] = 1
    flat = np.zeros(triangles, bool)
    flat[0] = True
    others = [key(scene=types.SimpleNamespace(mesh=mesh, triangle_surface=two, triangle_flat=None)),
              key(scene=types.SimpleNamespace(mesh=mesh, triangle_surface=scene.triangle_surface, triangle_flat=flat)),
              key(camera=((0.0, 0.0, 3.5),) + camera[1:]),
              key(camera=camera[:3] + (41.0,))]
    for change in ({"surfels": 5000}, {"seed": 2}, {"width": 256}, {"height": 256}, {"crease": 30.0},
                   {"shading": "flat"}):
        others.append(key(opts=runner.RunOptions(scene=str(BUNNY), out=str(tmp_path), **change)))
    assert len({base, *others}) == len(others) + 1
    monkeypatch.setenv("GAMMA_CACHE_DIR", "off")
    assert view_cache.path_for(types.SimpleNamespace(scene=scene, opts=opts, camera=camera)) is None
    assert view_cache.load(None, 1, 1, 1) is None


def test_views_live_as_long_as_their_setup_the_most_recent_few_under_the_limit(tmp_path, monkeypatch):
    from gamma.driver.caches import setup_cache

    monkeypatch.setenv("GAMMA_SETUP_CACHE_MB", "100")
    setups = {stem: tmp_path / f"setup-{stem}.bin" for stem in ("aaa-100-1", "bbb-100-1")}
    for k, path in enumerate(setups.values()):
        path.write_bytes(b"s" * 300_000)
        os.utime(path, ns=(k * 10**9, k * 10**9))           # aaa's the least recently used
    for k in range(6):
        for stem in setups:
            view = tmp_path / f"view-{stem}-{k:032x}.bin"
            view.write_bytes(b"v" * 100_000)
            os.utime(view, ns=(k * 10**9, k * 10**9))
    orphan = tmp_path / f"view-ccc-100-1-{0:032x}.bin"        # its setup is not kept
    orphan.write_bytes(b"v")
    setup_cache.trim(tmp_path, keep=setups["bbb-100-1"])
    assert sorted(p.name for p in tmp_path.glob("setup-*")) == ["setup-aaa-100-1.bin", "setup-bbb-100-1.bin"]
    assert sorted(p.name for p in tmp_path.glob("view-*")) == [f"view-{stem}-{k:032x}.bin"
                                                             for stem in setups for k in (2, 3, 4, 5)]
    # views count towards the limit: over it, the least recently used go first, a setup's views with it
    monkeypatch.setenv("GAMMA_SETUP_CACHE_MB", str(1_000_000 / (1 << 20)))
    setup_cache.trim(tmp_path, keep=setups["bbb-100-1"])
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == ["setup-bbb-100-1.bin"] + [f"view-bbb-100-1-{k:032x}.bin" for k in (2, 3, 4, 5)], left
    assert sum(p.stat().st_size for p in tmp_path.iterdir()) <= 1_000_000
