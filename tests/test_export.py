"""Baking and export: the glTF round-trips through an independent reader,
and baked textures hold the surface values at the right places."""

import json

import numpy as np
import pygltflib
import pytest
from PIL import Image

from conftest import ROOT, run_gammac
from gamma.backends.jit import JitKernels
from gamma.frontend.checker import load
from gamma.driver.export import bake
from gamma.driver.runner import RunOptions, build_config, runtime_module

SPOT = ROOT / "examples" / "scenes" / "spot.obj"


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "out"
    r = run_gammac("run", ROOT / "examples" / "patina-spot.gamma", "--scene", SPOT, "--surfels", 20000,
                   "--tons", 400000, "--iterations", 2, "--size", 64, "--bake-size", 256, "--export",
                   "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def accessor_array(gltf, index, blob):
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc.type]
    dtype = {5126: np.float32, 5125: np.uint32}[acc.componentType]
    return np.frombuffer(blob[view.byteOffset:view.byteOffset + view.byteLength], dtype).reshape(acc.count, width)


def test_gltf_round_trips_with_texture_and_attributes(exported):
    path = exported / "export" / "spot" / "iter_0002.glb"
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    prim = gltf.meshes[0].primitives[0]
    positions = accessor_array(gltf, prim.attributes.POSITION, blob)
    patina = accessor_array(gltf, prim.attributes._PATINA, blob)
    assert prim.attributes.COLOR_0 is None      # the colour is in the texture: never twice
    uvs = accessor_array(gltf, prim.attributes.TEXCOORD_0, blob)
    indices = accessor_array(gltf, prim.indices, blob)
    assert len(positions) == len(patina) == len(uvs)
    assert indices.max() < len(positions) and len(indices) % 3 == 0
    acc = gltf.accessors[prim.attributes._PATINA]
    assert acc.min[0] == pytest.approx(float(patina.min())) and acc.max[0] == pytest.approx(float(patina.max()))
    assert patina.max() > 0
    import gamma._runtime as rt

    source = np.asarray(rt.Mesh.load(str(SPOT)).triangle_uvs()).reshape(-1, 2)
    back = np.column_stack([uvs[:, 0], 1 - uvs[:, 1]])          # glTF's v runs downward
    assert np.allclose(np.unique(back, axis=0), np.unique(source.astype(np.float32), axis=0), atol=1e-6)
    assert len(gltf.images) == 1 and gltf.materials[0].pbrMetallicRoughness.baseColorTexture.index == 0
    image_view = gltf.bufferViews[gltf.images[0].bufferView]
    png = blob[image_view.byteOffset:image_view.byteOffset + image_view.byteLength]
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    props = gltf.extras["gamma"]["properties"]["patina"]
    grey = Image.open(exported / "export" / "spot" / props["texture"])
    assert grey.mode == "I;16" and grey.size == (256, 256)


def test_gltf_names_and_generator(exported):
    from gamma import __version__

    gltf = pygltflib.GLTF2().load(str(exported / "export" / "spot" / "iter_0001.glb"))
    assert gltf.asset.generator == f"gamma {__version__}"
    assert [n.name for n in gltf.nodes] == ["spot"] and gltf.meshes[0].name == "spot"


def test_untextured_glb_has_vertex_colours_only():
    from gamma.driver.export import write_glb

    tri = np.array([[0, 1, 2]], np.uint32)
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    data = write_glb(pos, np.tile([0, 0, 1], (3, 1)).astype(np.float32), None, tri,
                     np.full((3, 3), 0.5, np.float32), {}, None, None, name="part")
    gltf = pygltflib.GLTF2.load_from_bytes(data)
    prim = gltf.meshes[0].primitives[0]
    assert prim.attributes.COLOR_0 is not None
    assert gltf.materials[0].pbrMetallicRoughness.baseColorTexture is None


def khronos_validator(paths):
    """Reports of the Khronos glTF validator (npm gltf-validator, in web/)."""
    import shutil
    import subprocess

    node = shutil.which("node")
    assert node, "node is needed for the glTF validator (make install installs it)"
    r = subprocess.run([node, str(ROOT / "tests" / "validate_gltf.cjs"), *map(str, paths)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def test_every_glb_passes_the_khronos_validator(exported):
    files = sorted((exported / "export").glob("*/*.glb"))
    assert files
    broken = files[0].parent.parent / "broken.glb"
    data = files[0].read_bytes()
    broken.write_bytes(data[:len(data) - 1024])        # a cut-off binary chunk: the validator must say so
    *reports, cut = khronos_validator(files + [broken])
    for report in reports:
        errors = [m for m in report["messages"] if m["severity"] == 0]
        assert report["errors"] == 0, (report["file"], errors)
    assert cut["errors"] > 0
    broken.unlink()


def test_obj_and_mtl_reference_the_baked_colour(exported):
    folder = exported / "export" / "spot"
    obj = (folder / "iter_0001.obj").read_text()
    assert "mtllib iter_0001.mtl" in obj and "\nvt " in obj
    assert "map_Kd iter_0001_color.png" in (folder / "iter_0001.mtl").read_text()
    assert Image.open(folder / "iter_0001_color.png").size == (256, 256)


def test_baked_texels_hold_the_values_of_their_surface_points():
    """Set a property to a known smooth field (the x coordinate); every baked
    texel must hold (nearly) the x of the surface point it maps to."""
    rt = runtime_module()
    effect = load(str(ROOT / "examples" / "patina-spot.gamma"))
    kernels = JitKernels(effect)
    mesh = rt.Mesh.load(str(SPOT))
    cfg = build_config(rt, effect, kernels, RunOptions(scene="", out="", surfels=40000, threads=2),
                       mesh.bounds, (0.0, -1.0, 0.0))
    sim = rt.Simulation(mesh, cfg)
    rows = sim.rows()
    rows[:, 3] = sim.surfel_positions()[:, 0]
    sim.set_rows(rows)
    from gamma.driver.export import rasterise_uv

    size = 128
    from gamma.driver.export import Piece

    corner_uvs = np.asarray(mesh.triangle_uvs())
    piece = Piece("spot", np.arange(mesh.num_triangles), np.asarray(mesh.vertices()),
                  np.asarray(mesh.triangles(), np.int64), corner_uvs, corner_uvs)
    _, texels, _, rows = bake(sim, piece, size, 1, 2)
    texels2, tris, bary = rasterise_uv(corner_uvs, size)
    assert np.array_equal(texels, texels2) and len(texels) > 0.3 * size * size
    verts = np.asarray(mesh.vertices(), np.float64)
    x = np.einsum("kc,kc->k", bary, verts[np.asarray(mesh.triangles())[tris]][:, :, 0])
    baked = rows[:, 3]
    spacing = np.sqrt(0.57 / 40000)            # Spot's area / surfels, roughly
    assert np.median(np.abs(baked - x)) < spacing
    assert np.percentile(np.abs(baked - x), 99) < 4 * spacing


def test_mesh_without_uvs_gets_an_atlas(tmp_path, bumpy_obj):
    out = tmp_path / "out"
    r = run_gammac("run", ROOT / "examples" / "patina.gamma", "--scene", bumpy_obj, "--surfels", 3000,
                   "--tons", 50000, "--iterations", 1, "--size", 32, "--bake-size", 128, "--export",
                   "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    gltf = pygltflib.GLTF2().load(str(out / "export" / "bumpy" / "iter_0001.glb"))
    prim = gltf.meshes[0].primitives[0]
    uvs = accessor_array(gltf, prim.attributes.TEXCOORD_0, gltf.binary_blob())
    assert uvs.min() >= 0 and uvs.max() <= 1 and len(gltf.images) == 1
    patina = np.asarray(Image.open(out / "export" / "bumpy" / "iter_0001_patina.png"), np.float64)
    assert patina.max() > 0                    # the baked map holds the deposit


def test_each_object_is_exported_on_its_own(tmp_path):
    from test_scenes import TWO_SURFACES, two_part_obj

    scene = two_part_obj(tmp_path / "scene.obj")
    (tmp_path / "two.gamma").write_text(TWO_SURFACES)
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "two.gamma", "--scene", scene, "--assign", "ball=Metal",
                   "--assign", "*=Stone", "--surfels", 2000, "--iterations", 1, "--size", 32,
                   "--bake-size", 64, "--export", "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (out / "export").iterdir()) == ["ball", "slab"]
    ball = pygltflib.GLTF2().load(str(out / "export" / "ball" / "iter_0001.glb"))
    slab = pygltflib.GLTF2().load(str(out / "export" / "slab" / "iter_0001.glb"))
    assert ball.accessors[ball.meshes[0].primitives[0].indices].count == 320 * 3
    assert slab.accessors[slab.meshes[0].primitives[0].indices].count == 2 * 3
    assert ball.extras["gamma"]["object"] == "ball"
    rust = ball.accessors[ball.meshes[0].primitives[0].attributes._RUST]
    assert rust.max[0] > 0                          # the ball is Metal and rusted
    assert (out / "export" / "slab" / "iter_0001_damp.png").is_file()


def test_uv_rasteriser_matches_a_texel_by_texel_reference():
    """Every texel centre inside a triangle is found, once, with the first
    triangle that covers it and that triangle's barycentrics."""
    from gamma.driver.export import rasterise_uv

    rng = np.random.default_rng(3)
    size = 40
    corners = rng.random((60, 1, 2)) * 0.8 + rng.random((60, 3, 2)) * 0.25
    texels, tris, bary = rasterise_uv(corners, size, chunk=500)     # small chunks: several passes
    j, i = np.meshgrid(np.arange(size), np.arange(size))
    centre = np.column_stack([(j.reshape(-1) + 0.5) / size, 1 - (i.reshape(-1) + 0.5) / size])
    owner = np.full(size * size, -1)
    for t in range(len(corners) - 1, -1, -1):          # the lowest-numbered triangle wins
        a, b, c = corners[t]
        m = np.column_stack([b - a, c - a])
        l23 = np.linalg.solve(m, (centre - a).T).T
        inside = (l23 >= -1e-9).all(axis=1) & (l23.sum(axis=1) <= 1 + 1e-9)
        owner[inside] = t
    assert np.array_equal(texels, np.flatnonzero(owner >= 0))
    assert np.array_equal(tris, owner[texels])
    back = np.einsum("kc,kcd->kd", bary, corners[tris])
    assert np.allclose(back, centre[texels], atol=1e-9)
