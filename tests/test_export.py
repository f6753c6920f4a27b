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
    colours = accessor_array(gltf, prim.attributes.COLOR_0, blob)
    uvs = accessor_array(gltf, prim.attributes.TEXCOORD_0, blob)
    indices = accessor_array(gltf, prim.indices, blob)
    assert len(positions) == len(patina) == len(colours) == len(uvs)
    assert indices.max() < len(positions) and len(indices) % 3 == 0
    acc = gltf.accessors[prim.attributes._PATINA]
    assert acc.min[0] == pytest.approx(float(patina.min())) and acc.max[0] == pytest.approx(float(patina.max()))
    assert patina.max() > 0 and np.all((colours >= 0) & (colours <= 1))
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
