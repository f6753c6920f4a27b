"""Baking and export: the texture set and the glTF round-trip through an
independent reader (pygltflib) and the Khronos validator, baked textures
hold the surface values at the right places, the look's outputs reach the
ORM and normal maps with the values an analytic scene gives."""

import json

import numpy as np
import pygltflib
import pytest
from PIL import Image

from conftest import ROOT, run_gammac
from gamma.backends.jit import JitKernels
from gamma.frontend.checker import load
from gamma.driver.outputs.export import bake_texture_set, layout, Piece, PropertySlots, rasterise_uv
from gamma.driver.running.runner import RunOptions, build_config, runtime_module

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


def image_of(gltf, blob, texture_index):
    import io

    view = gltf.bufferViews[gltf.images[gltf.textures[texture_index].source].bufferView]
    return Image.open(io.BytesIO(blob[view.byteOffset:view.byteOffset + view.byteLength]))


def test_only_the_last_iteration_is_exported_by_default(exported):
    assert sorted(p.name for p in (exported / "export").glob("*.glb")) == ["spot_0002.glb"]
    assert not list((exported / "export" / "spot").glob("*_0001*"))


def test_gltf_round_trips_with_a_pbr_texture_set_and_attributes(exported):
    gltf = pygltflib.GLTF2().load(str(exported / "export" / "spot_0002.glb"))
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
    material = gltf.materials[prim.material]
    assert material.name == "Copper"                             # the effect's surface
    pbr = material.pbrMetallicRoughness
    assert pbr.metallicRoughnessTexture.index == material.occlusionTexture.index   # one ORM image
    names = {gltf.images[gltf.textures[t].source].name for t in
             (pbr.baseColorTexture.index, pbr.metallicRoughnessTexture.index, material.normalTexture.index)}
    assert names == {"spot_BaseColor_0002", "spot_ORM_0002", "spot_Normal_0002"}
    orm = np.asarray(image_of(gltf, blob, pbr.metallicRoughnessTexture.index).convert("RGB"), np.float64) / 255
    # patina-spot: roughness 0.35 under the glaze, 0.9 under a full crust; no metal; no occlusion set
    covered = orm[..., 1] > 0
    assert orm[covered, 0].min() == 1.0 and orm[covered, 2].max() == 0.0
    assert 0.34 < np.percentile(orm[covered, 1], 1) and orm[covered, 1].max() <= 0.91
    assert np.percentile(orm[covered, 1], 99) > 0.4              # some patina roughened the glaze
    side = json.loads((exported / "export" / "spot" / "spot_0002.json").read_text())
    grey = Image.open(exported / "export" / "spot" / side["properties"]["patina"]["file"])
    assert grey.mode == "I;16" and grey.size == (256, 256)
    summary = json.loads((exported / "summary.json").read_text())
    assert [side["properties"]["patina"]["min"], side["properties"]["patina"]["max"]] == summary["ranges"]["patina"]
    assert gltf.extras["gamma"]["properties"]["patina"] == {"min": summary["ranges"]["patina"][0],
                                                           "max": summary["ranges"]["patina"][1]}


def test_gltf_names_and_generator(exported):
    from gamma import __version__

    gltf = pygltflib.GLTF2().load(str(exported / "export" / "spot_0002.glb"))
    assert gltf.asset.generator == f"gamma {__version__}"
    assert [n.name for n in gltf.nodes] == ["spot"] and gltf.meshes[0].name == "spot"
    assert gltf.scenes[0].name == "spot"


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
    files = sorted((exported / "export").glob("*.glb"))
    assert files
    broken = files[0].parent / "broken.glb"
    data = files[0].read_bytes()
    broken.write_bytes(data[:len(data) - 1024])        # a cut-off binary chunk: the validator must say so
    *reports, cut = khronos_validator(files + [broken])
    for report in reports:
        errors = [m for m in report["messages"] if m["severity"] == 0]
        assert report["errors"] == 0, (report["file"], errors)
    assert cut["errors"] > 0
    broken.unlink()


def test_obj_and_mtl_reference_the_texture_set(exported):
    folder = exported / "export" / "spot"
    obj = (folder / "spot_0002.obj").read_text()
    assert "mtllib spot_0002.mtl" in obj and "\nvt " in obj and "\no spot\n" in obj and "usemtl Copper" in obj
    mtl = (folder / "spot_0002.mtl").read_text()
    assert "newmtl Copper" in mtl and "map_Kd spot_BaseColor_0002.png" in mtl and "norm spot_Normal_0002.png" in mtl
    assert Image.open(folder / "spot_BaseColor_0002.png").size == (256, 256)


def _simulation(effect_path, mesh_path, surfels=40000):
    rt = runtime_module()
    effect = load(str(effect_path))
    kernels = JitKernels(effect)
    mesh = rt.Mesh.load(str(mesh_path))
    cfg = build_config(rt, effect, kernels, RunOptions(scene="", out="", surfels=surfels, threads=2),
                       mesh.bounds, (0.0, -1.0, 0.0))
    return effect, mesh, rt.Simulation(mesh, cfg), kernels


def _slots(mesh, **slots):
    """PropertySlots baking each named property from the same row slot on every surface."""
    return PropertySlots(list(slots), np.array([list(slots.values())] * 4, np.int32).reshape(4, len(slots)),
                         np.zeros(mesh.num_triangles, np.int32))


def _piece(mesh):
    corner_uvs = np.asarray(mesh.triangle_uvs()) if mesh.has_uvs else None
    return Piece("mesh", np.arange(mesh.num_triangles), np.asarray(mesh.vertices()),
                 np.asarray(mesh.triangles(), np.int64), corner_uvs)


def test_baked_texels_hold_the_values_of_their_surface_points():
    """Set a property to a known smooth field (the x coordinate); every baked
    texel must hold (nearly) the x of the surface point it maps to."""
    effect, mesh, sim, kernels = _simulation(ROOT / "examples" / "patina-spot.gamma", SPOT)
    rows = sim.rows()
    rows[:, 3] = sim.surfel_positions()[:, 0]
    sim.set_rows(rows)
    size = 128
    lay = layout(_piece(mesh), None, size)
    ts = bake_texture_set(sim, lay, 1, 2, _slots(mesh, patina=3))
    texels, tris, bary = rasterise_uv(np.asarray(mesh.triangle_uvs()), size)
    assert len(texels) > 0.3 * size * size
    verts = np.asarray(mesh.vertices(), np.float64)
    x = np.einsum("kc,kc->k", bary, verts[np.asarray(mesh.triangles())[tris]][:, :, 0])
    baked = ts.properties["patina"].reshape(-1)[texels]
    spacing = np.sqrt(0.57 / 40000)            # Spot's area / surfels, roughly
    assert np.median(np.abs(baked - x)) < spacing
    assert np.percentile(np.abs(baked - x), 99) < 4 * spacing


PLANE_LOOK = """
ton T { motion straight = 1.0 }
surface S { reflectance straight = 0.0  property p = 0.0 }
source sky = environment(sphere) emits T count 1000
on settle(t: T, s: S) { s.p += 1 }
appearance(s: S) {
    roughness = 0.25
    metallic = 1
    occlusion = 0.5
    displacement = 0.1 * position.x
}
"""


def plane_with_uvs(path, n=8, u_span=1):
    """A unit square in the x-z plane (normal +y), u = u_span * x and v = 1 - z (+v runs along -z)."""
    lines = []
    for i in range(n + 1):
        for j in range(n + 1):
            x, z = j / n, i / n
            lines.append(f"v {x} 0 {z}\nvt {u_span * x} {1 - z}")
    for i in range(n):
        for j in range(n):
            a = i * (n + 1) + j + 1
            b, c, d = a + 1, a + n + 2, a + n + 1
            lines.append(f"f {a}/{a} {d}/{d} {c}/{c}\nf {a}/{a} {c}/{c} {b}/{b}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_the_looks_outputs_reach_the_orm_and_normal_maps(tmp_path):
    """roughness 0.25, metallic 1, occlusion 0.5 everywhere; a displacement
    rising 0.1 per unit of x, with u = x: the tangent-space normal is
    (-0.1, 0, 1) normalised, the height map rises left to right."""
    (tmp_path / "look.gamma").write_text(PLANE_LOOK)
    effect, mesh, sim, kernels = _simulation(tmp_path / "look.gamma", plane_with_uvs(tmp_path / "plane.obj"), 4000)
    size = 64
    lay = layout(_piece(mesh), None, size)
    ts = bake_texture_set(sim, lay, 1, 2, _slots(mesh))
    assert np.allclose(ts.orm[..., 0], 0.5) and np.allclose(ts.orm[..., 1], 0.25) and np.allclose(ts.orm[..., 2], 1)
    want = np.array([-0.1, 0.0, 1.0]) / np.sqrt(1.01)
    inner = ts.normal[4:-4, 4:-4].reshape(-1, 3)     # away from the border's one-sided slopes
    assert np.abs(inner - want).max() < 1e-3, inner[:3]
    assert np.allclose(ts.height[size // 2], (np.arange(size) + 0.5) / size * 0.1, atol=2e-3)


def test_mesh_without_uvs_gets_a_chart_atlas(tmp_path, bumpy_obj):
    out = tmp_path / "out"
    r = run_gammac("run", ROOT / "examples" / "patina.gamma", "--scene", bumpy_obj, "--surfels", 3000,
                   "--tons", 50000, "--iterations", 1, "--size", 32, "--bake-size", 128, "--export",
                   "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    gltf = pygltflib.GLTF2().load(str(out / "export" / "bumpy_0001.glb"))
    prim = gltf.meshes[0].primitives[0]
    blob = gltf.binary_blob()
    uvs = accessor_array(gltf, prim.attributes.TEXCOORD_0, blob)
    positions = accessor_array(gltf, prim.attributes.POSITION, blob)
    assert uvs.min() >= 0 and uvs.max() <= 1 and len(gltf.images) == 3
    distinct = len(np.unique(positions, axis=0))
    assert len(positions) <= 1.5 * distinct         # welded inside charts, not 3 vertices a triangle
    patina = np.asarray(Image.open(out / "export" / "bumpy" / "bumpy_patina_0001.png"), np.float64)
    assert patina.max() > 0                    # the baked map holds the deposit


def test_each_object_is_a_node_with_a_material_per_surface(tmp_path):
    from test_scenes import TWO_SURFACES, two_part_obj

    scene = two_part_obj(tmp_path / "scene.obj")
    (tmp_path / "two.gamma").write_text(TWO_SURFACES)
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "two.gamma", "--scene", scene, "--assign", "ball=Metal",
                   "--assign", "*=Stone", "--surfels", 2000, "--iterations", 2, "--size", 32,
                   "--bake-size", 64, "--export", "all", "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (out / "export").iterdir()) == ["ball", "scene_0001.glb", "scene_0002.glb", "slab"]
    gltf = pygltflib.GLTF2().load(str(out / "export" / "scene_0002.glb"))
    assert [n.name for n in gltf.nodes] == ["ball", "slab"]
    ball, slab = gltf.meshes
    assert gltf.accessors[ball.primitives[0].indices].count == 320 * 3
    assert gltf.accessors[slab.primitives[0].indices].count == 2 * 3
    assert gltf.materials[ball.primitives[0].material].name == "Metal"
    assert gltf.materials[slab.primitives[0].material].name == "Stone"
    rust = gltf.accessors[ball.primitives[0].attributes._RUST]
    assert rust.max[0] > 0                          # the ball is Metal and rusted
    # one range per property for the whole run: both iterations' masks share it
    first = json.loads((out / "export" / "slab" / "slab_0001.json").read_text())
    second = json.loads((out / "export" / "slab" / "slab_0002.json").read_text())
    assert first["properties"]["damp"]["max"] == second["properties"]["damp"]["max"] > 0
    a = np.asarray(Image.open(out / "export" / "slab" / "slab_damp_0001.png"), np.float64)
    b = np.asarray(Image.open(out / "export" / "slab" / "slab_damp_0002.png"), np.float64)
    assert a.mean() < b.mean()                      # damp grows; a mask scaled per iteration would not show it


@pytest.mark.parametrize("size", ["0", "-3", "16385"])
def test_a_bake_size_out_of_range_is_a_usage_error(tmp_path, size):
    r = run_gammac("export", tmp_path, "--bake-size", size)
    assert r.returncode == 2 and "--bake-size" in r.stderr and "Traceback" not in r.stderr


def test_a_bake_larger_than_memory_allows_is_refused_before_the_run(monkeypatch):
    """The estimate is checked against the memory available before the first
    iteration (ExportWriter.on_setup_done), and the refusal gives both."""
    from types import SimpleNamespace

    from gamma.driver.outputs import export
    from gamma.driver.running.runner import RunError
    from gamma.driver.outputs.writers import ExportWriter

    effect = load(str(ROOT / "examples" / "patina.gamma"))
    run = SimpleNamespace(effect=effect)
    monkeypatch.setattr(export, "available_memory", lambda: 8 << 30)
    ExportWriter(4096).on_setup_done(SimpleNamespace(run=run))         # ~0.9 GiB: made
    with pytest.raises(RunError) as refused:
        ExportWriter(16384).on_setup_done(SimpleNamespace(run=run))    # ~10 GiB: refused
    need = export.bake_memory(16384, effect.row_width, 1) / 2**30
    assert f"about {need:.1f} GiB" in str(refused.value) and "8.0 GiB is available" in str(refused.value)
    assert 9 < need < 12


def test_uv_rasteriser_matches_a_texel_by_texel_reference():
    """Every texel centre inside a triangle is found, once, with the first
    triangle that covers it and that triangle's barycentrics."""
    from gamma.driver.outputs.export import rasterise_uv

    rng = np.random.default_rng(3)
    size = 40
    corners = rng.random((60, 1, 2)) * 0.8 + rng.random((60, 3, 2)) * 0.25
    texels, tris, bary = rasterise_uv(corners, size)
    for rows in ((0, 13), (13, 14), (14, size)):      # bands of rows find the same texels there
        part = rasterise_uv(corners, size, rows=rows)
        inside = (texels >= rows[0] * size) & (texels < rows[1] * size)
        assert np.array_equal(part[0], texels[inside]) and np.array_equal(part[1], tris[inside])
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


def test_blender_imports_the_export_as_an_artist_needs_it(exported, tmp_path, bumpy_obj):
    """Blender 4.5 (the bpy wheel) imports the glb of a mesh with UVs (Spot)
    and of one without (an atlas): objects and materials named after the
    scene's parts and the effect's surfaces, the Principled BSDF's Base
    Color, Roughness, Metallic and Normal each fed by an image, smooth
    shading, the property as a mesh attribute."""
    from clients import blender_import_many

    out = tmp_path / "out"
    r = run_gammac("run", ROOT / "stdlib" / "rust.gamma", "--scene", bumpy_obj, "--surfels", 3000,
                   "--tons", 50000, "--iterations", 2, "--size", 32, "--bake-size", 256, "--export",
                   "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    spot, bumpy = blender_import_many([exported / "export" / "spot_0002.glb", out / "export" / "bumpy_0002.glb"])
    for report, name, material, prop in ((spot, "spot", "Copper", "_PATINA"), (bumpy, "bumpy", "Iron", "_RUST")):
        (obj,) = report["objects"]
        assert obj["name"] == name and obj["materials"] == [material]
        mesh = report["meshes"][obj["data"]]
        assert mesh["shaded_smooth_fraction"] > 0.9, mesh["shaded_smooth_fraction"]
        assert prop in {a["name"] for a in mesh["attributes"]}
        bsdf = report["materials"][material]["bsdf"]
        fed = {socket: bsdf[socket]["sources"][0]["image"] for socket in ("Base Color", "Roughness", "Metallic", "Normal")
               if bsdf[socket]["linked"] and bsdf[socket]["sources"]}
        assert fed == {"Base Color": f"{name}_BaseColor_0002", "Roughness": f"{name}_ORM_0002",
                       "Metallic": f"{name}_ORM_0002", "Normal": f"{name}_Normal_0002"}, fed
        assert bsdf["Roughness"]["sources"][0]["channel"] == "Color.Green"
        assert bsdf["Metallic"]["sources"][0]["channel"] == "Color.Blue"
        assert bsdf["Normal"]["sources"][0]["colorspace"] == "Non-Color"


def test_presets_pack_the_texture_set_for_each_engine(exported):
    """--preset unity adds HDRP's mask map (metallic, occlusion, detail,
    smoothness = 1 - roughness) and unreal a DirectX normal map (green
    flipped), beside glTF's ORM and OpenGL normal map; --float-maps writes
    the height and the properties as 32-bit EXR holding the values."""
    import OpenEXR

    folder = exported / "export" / "spot"
    r = run_gammac("export", exported, "--bake-size", 256, "--preset", "unity", "--float-maps", "--quiet")
    assert r.returncode == 0, r.stderr
    orm = np.asarray(Image.open(folder / "spot_ORM_0002.png").convert("RGB"), np.int64)
    mask = np.asarray(Image.open(folder / "spot_MaskMap_0002.png"), np.int64)
    assert mask.shape == (256, 256, 4)
    assert np.abs(mask[..., 0] - orm[..., 2]).max() <= 1 and np.abs(mask[..., 1] - orm[..., 0]).max() <= 1
    assert (mask[..., 2] == 255).all() and np.abs(mask[..., 3] - (255 - orm[..., 1])).max() <= 1
    side = json.loads((folder / "spot_0002.json").read_text())
    patina = OpenEXR.File(str(folder / side["properties"]["patina"]["file"])).channels()["Y"].pixels
    assert patina.dtype == np.float32 and patina.shape == (256, 256)
    assert 0 < patina.max() <= side["properties"]["patina"]["max"] + 1e-6   # the values, not a scale
    r = run_gammac("export", exported, "--bake-size", 256, "--preset", "unreal", "--quiet")
    assert r.returncode == 0, r.stderr
    gl = np.asarray(Image.open(folder / "spot_Normal_0002.png").convert("RGB"), np.int64)
    dx = np.asarray(Image.open(folder / "spot_NormalDX_0002.png").convert("RGB"), np.int64)
    assert np.abs(dx[..., 1] - (255 - gl[..., 1])).max() <= 1 and np.array_equal(dx[..., 0], gl[..., 0])


def test_the_assets_own_normal_map_is_kept(tmp_path):
    """A glTF part with a normal map, weathered by a block that sets no
    displacement: the exported normal map is the asset's, texel for texel."""
    import trimesh
    from trimesh.visual.material import PBRMaterial

    size = 64
    j, i = np.meshgrid(np.arange(size), np.arange(size))
    bumps = np.stack([0.5 + 0.3 * np.sin(j / 5.0), 0.5 + 0.3 * np.cos(i / 7.0), np.full(j.shape, 0.9)], -1)
    normal_image = Image.fromarray((bumps * 255 + 0.5).astype(np.uint8))
    plane = plane_with_uvs(tmp_path / "plane.obj")
    mesh = trimesh.load(str(plane), process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.visual.uv, material=PBRMaterial(
        name="painted", baseColorFactor=[200, 200, 200, 255], normalTexture=normal_image))
    glb = tmp_path / "plane.glb"
    mesh.export(str(glb))
    (tmp_path / "look.gamma").write_text(PLANE_LOOK.replace("    displacement = 0.1 * position.x\n", ""))
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "look.gamma", "--scene", glb, "--surfels", 2000, "--iterations", 1,
                   "--size", 32, "--export", "--bake-size", size, "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    (normal_file,) = (out / "export").glob("*/*_Normal_0001.png")
    got = np.asarray(Image.open(normal_file).convert("RGB"), np.float64) / 255
    want = np.asarray(normal_image, np.float64) / 255
    n = want * 2 - 1
    want = (n / np.linalg.norm(n, axis=-1, keepdims=True) + 1) / 2      # stored unit length
    inner = (slice(2, -2), slice(2, -2))
    assert np.abs(got[inner] - want[inner]).max() < 3 / 255


def test_a_texture_set_baked_in_bands_is_the_whole_textures(tmp_path, bumpy_obj):
    """Bands of rows with their margins (export.HALO) give every image of the
    texture set exactly as one bake of the whole texture does: the chart
    atlas's gutters, the displacement's normal map and the properties."""
    (tmp_path / "look.gamma").write_text(PLANE_LOOK.replace("0.1 * position.x", "0.05 * s.p + 0.02 * position.y"))
    effect, mesh, sim, kernels = _simulation(tmp_path / "look.gamma", bumpy_obj, 3000)
    rows = sim.rows()
    rows[:, 3] = np.sin(7 * sim.surfel_positions()[:, 0]) + 1      # a smooth field over the surface
    sim.set_rows(rows)
    size = 128
    lay = layout(_piece(mesh), np.asarray(sim.corner_normals()), size)
    assert lay.chart is not None
    columns = _slots(mesh, p=3)
    whole = bake_texture_set(sim, lay, 1, 2, columns, band=size)
    banded = bake_texture_set(sim, lay, 1, 2, columns, band=7)
    assert np.abs(whole.height).max() > 0 and whole.properties["p"].max() > 0
    for name in ("base_color", "orm", "normal", "height"):
        assert np.array_equal(getattr(whole, name), getattr(banded, name)), name
    assert np.array_equal(whole.properties["p"], banded.properties["p"])


UDIM_LOOK = """
ton T { motion straight = 1.0 }
surface S { reflectance straight = 0.0  property p = 0.0 }
source sky = environment(sphere) emits T count 1000
on settle(t: T, s: S) { s.p += 1 }
appearance(s: S) { color = rgb(uv.u / 2, 0.2, 0.2) }
"""


def test_uvs_spanning_udim_tiles_get_a_texture_set_per_tile(tmp_path):
    """A plane whose u runs 0..2 spans tiles 1001 and 1002: a node and a
    texture set per tile (NAME_CHANNEL_NNNN.1001.png), each tile's uvs moved
    to the unit square for its textures while texture() and uv still see
    the mesh's own (the colour's red is u / 2: below 0.5 in 1001, above in 1002)."""
    plane_with_uvs(tmp_path / "tiles.obj", u_span=2)
    (tmp_path / "look.gamma").write_text(UDIM_LOOK)
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "look.gamma", "--scene", tmp_path / "tiles.obj", "--surfels", 2000,
                   "--iterations", 1, "--size", 32, "--export", "--bake-size", 64, "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    gltf = pygltflib.GLTF2().load(str(out / "export" / "tiles_0001.glb"))
    assert [node.name for node in gltf.nodes] == ["tiles.1001", "tiles.1002"]
    reds = {}
    for tile in (1001, 1002):
        image = np.asarray(Image.open(out / "export" / "tiles" / f"tiles_BaseColor_0001.{tile}.png").convert("RGB"),
                           np.float64) / 255
        covered = image[8:-8, 8:-8, 0]
        reds[tile] = (covered.min(), covered.max())
        side = json.loads((out / "export" / "tiles" / f"tiles_0001.{tile}.json").read_text())
        assert side["udim"] == tile
    assert reds[1001][1] <= 0.5 + 2 / 255 and reds[1002][0] >= 0.5 - 2 / 255
    assert reds[1001][0] < 0.1 and reds[1002][1] > 0.9
    blob = gltf.binary_blob()
    for mesh in gltf.meshes:
        uvs = accessor_array(gltf, mesh.primitives[0].attributes.TEXCOORD_0, blob)
        assert uvs.min() >= 0 and uvs.max() <= 1          # each tile's textures in the unit square
    (report,) = khronos_validator([out / "export" / "tiles_0001.glb"])
    assert report["errors"] == 0


def test_gammac_export_format_usd_writes_a_compliant_stage(tmp_path, bumpy_obj):
    """gammac export DIR --all --format usd: one stage, the iterations as time
    samples of the texture files, which usd-core's compliance checker passes."""
    from clients import usd_check, usd_summary

    out = tmp_path / "out"
    r = run_gammac("run", ROOT / "stdlib" / "patina.gamma", "--scene", bumpy_obj, "--surfels", 2000,
                   "--iterations", 2, "--size", 32, "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    r = run_gammac("export", out, "--all", "--format", "usd", "--bake-size", 64, "--quiet")
    assert r.returncode == 0, r.stderr
    stage = out / "export" / "bumpy.usdc"
    assert usd_check(stage) == []
    summary = usd_summary(stage)
    assert (summary["start_time_code"], summary["end_time_code"]) == (1.0, 2.0)
    assert "bumpy_BaseColor_0002.png" in json.dumps(summary)


def _bake_both(sim, mesh, lay, size):
    """bake_texels over the whole texture with its lattice and without: (texels, exact channels, lattice
    channels, the x of each texel's point); channel 7 is row slot 3 (channels: base colour, ORM, height,
    then the property)."""
    texels, tris, bary = rasterise_uv(lay.corner_uvs, size, tile=8)
    piece = lay.piece
    slots = _slots(mesh, p=3)
    args = (lay.positions, lay.normals, np.ascontiguousarray(lay.faces, np.int32),
            None if piece.own_uvs is None else np.ascontiguousarray(piece.own_uvs, np.float32),
            np.ascontiguousarray(piece.triangles, np.int32), np.ascontiguousarray(tris, np.int32),
            np.ascontiguousarray(bary), slots.surface_of_triangle, slots.slots, 1, 2)
    exact = np.asarray(sim.bake_texels(*args))
    lattice = np.asarray(sim.bake_texels(*args, texels=texels, band_width=size, band_rows=size, first_row=0))
    x = np.einsum("kc,kc->k", bary, lay.positions[lay.faces[tris]][:, :, 0].astype(np.float64))
    return texels, exact, lattice, x


def test_texels_between_lattice_points_are_as_faithful_as_their_own_smoothing():
    """A bake fine enough for the lattice (Spot at 1024², 2000 surfels: texels
    about a sixteenth of a surfel spacing apart): lattice points are smoothed
    exactly as without it, most other texels are interpolated, and against
    the analytic field the surfels sample the interpolated bake errs no more
    than the texel-by-texel smoothing does."""
    effect, mesh, sim, kernels = _simulation(ROOT / "examples" / "patina-spot.gamma", SPOT, 2000)
    rows = sim.rows()
    rows[:, 3] = np.sin(20 * sim.surfel_positions()[:, 0]) + 1
    sim.set_rows(rows)
    size = 1024
    lay = layout(_piece(mesh), None, size)
    texels, exact, lattice, x = _bake_both(sim, mesh, lay, size)
    on_lattice = (texels // size % 4 == 0) & (texels % size % 4 == 0)
    assert np.array_equal(exact[on_lattice], lattice[on_lattice])
    interpolated = exact[:, 7] != lattice[:, 7]
    assert interpolated.mean() > 0.7
    truth = np.sin(20 * x) + 1
    e_exact, e_lattice = np.abs(exact[:, 7] - truth), np.abs(lattice[:, 7] - truth)
    assert e_lattice.mean() <= 1.01 * e_exact.mean()
    assert np.percentile(e_lattice, 99) <= 1.01 * np.percentile(e_exact, 99)
    # the looks follow the rows: on the whole, the colours are the exact bake's
    assert np.abs(lattice[:, :3] - exact[:, :3]).mean() < 0.01


def test_a_coarse_bake_takes_no_lattice():
    """Texels about a surfel spacing apart (Spot at 64², 20,000 surfels) are
    too far apart to interpolate: every one is smoothed itself."""
    effect, mesh, sim, kernels = _simulation(ROOT / "examples" / "patina-spot.gamma", SPOT, 20000)
    size = 64
    lay = layout(_piece(mesh), None, size)
    texels, exact, lattice, x = _bake_both(sim, mesh, lay, size)
    assert np.array_equal(exact, lattice)


def test_bands_of_a_texture_baked_on_the_lattice_are_the_whole_textures(tmp_path, bumpy_obj):
    """As test_a_texture_set_baked_in_bands_is_the_whole_textures, with few
    surfels, so that most texels take the lattice: the lattice is aligned to
    the whole texture, whatever the bands."""
    (tmp_path / "look.gamma").write_text(PLANE_LOOK.replace("0.1 * position.x", "0.05 * s.p + 0.02 * position.y"))
    effect, mesh, sim, kernels = _simulation(tmp_path / "look.gamma", bumpy_obj, 200)
    rows = sim.rows()
    rows[:, 3] = np.sin(7 * sim.surfel_positions()[:, 0]) + 1
    sim.set_rows(rows)
    size = 256
    lay = layout(_piece(mesh), np.asarray(sim.corner_normals()), size)
    columns = _slots(mesh, p=3)
    whole = bake_texture_set(sim, lay, 1, 2, columns, band=size)
    banded = bake_texture_set(sim, lay, 1, 2, columns, band=9)
    for name in ("base_color", "orm", "normal", "height"):
        assert np.array_equal(getattr(whole, name), getattr(banded, name)), name
    assert np.array_equal(whole.properties["p"], banded.properties["p"])
    texels, exact, lattice, x = _bake_both(sim, mesh, lay, size)
    assert (exact[:, 7] != lattice[:, 7]).mean() > 0.5          # the lattice was taken
