"""The real-client harness (tests/clients.py) on files made here: a glb built
by hand with the features our exporter writes or may write, one made by
Blender's own glTF exporter, and USD stages written with pxr.  The
assertions also pin what Blender 4.5's glTF importer does with each feature,
the facts the exporter's design rests on."""

import io
from pathlib import Path
import json
import struct
import time

import numpy as np
import pytest
from PIL import Image

from clients import (BlenderImportError, blender_import, blender_import_many, blender_render, blender_script,
                     has_bpy, has_usd, usd_check, usd_summary)

# The clients are test dependencies (make test installs them): a machine without them fails here.
needs_bpy = pytest.mark.usefixtures("bpy_installed")
needs_usd = pytest.mark.usefixtures("usd_installed")


@pytest.fixture(scope="session")
def bpy_installed():
    assert has_bpy(), "bpy (Blender 4.5 as a module) is not installed: make test installs it"


@pytest.fixture(scope="session")
def usd_installed():
    assert has_usd(), "usd-core is not installed: make test installs it"


# --------------------------------------------------------------------------- a glb by hand

def png_bytes(rgb, size=(8, 8)) -> bytes:
    """A PNG: one colour, or an (h, w, 3) uint8 array."""
    if isinstance(rgb, np.ndarray):
        image = Image.fromarray(rgb.astype(np.uint8), "RGB")
    else:
        image = Image.new("RGB", size, tuple(int(c) for c in rgb))
    out = io.BytesIO()
    image.save(out, "PNG")
    return out.getvalue()


def curved_patch(n=5):
    """An n x n vertex patch of z = 0.3 (x^2 + y^2) (glTF +Y up: the patch is
    in x/z, height y) with smooth normals and UVs: 2 (n-1)^2 triangles."""
    u = np.linspace(-1, 1, n)
    x, z = np.meshgrid(u, u, indexing="xy")
    y = 0.3 * (x ** 2 + z ** 2)
    positions = np.column_stack([x.ravel(), y.ravel(), z.ravel()]).astype(np.float32)
    normals = np.column_stack([-0.6 * x.ravel(), np.ones(n * n), -0.6 * z.ravel()])
    normals = (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)
    uvs = np.column_stack([(x.ravel() + 1) / 2, (z.ravel() + 1) / 2]).astype(np.float32)
    tris = []
    for j in range(n - 1):
        for i in range(n - 1):
            a, b, c, d = j * n + i, j * n + i + 1, (j + 1) * n + i, (j + 1) * n + i + 1
            tris += [(a, c, b), (b, c, d)]       # counter-clockwise seen from +y
    return positions, normals, uvs, np.array(tris, np.uint32)


def write_glb(path, *, attributes=None, names=True, occlusion=True, extensions=True):
    """A glb with one node/mesh/material, textured base colour, a packed ORM
    texture (occlusion R, roughness G, metallic B), a normal map, an emissive
    texture with KHR_materials_emissive_strength, KHR_materials_ior and
    KHR_texture_transform, COLOR_0, and ``attributes`` (name -> (n, k) float32
    array, default one ``_PATINA``) as custom vertex attributes."""
    positions, normals, uvs, tris = curved_patch()
    count = len(positions)
    colours = np.tile(np.float32([0.2, 0.6, 0.4, 1.0]), (count, 1))
    if attributes is None:
        attributes = {"_PATINA": (positions[:, 0:1] + 1) / 2}     # 0 .. 1 along x
    blob = bytearray()
    views, accessors = [], []

    def add_view(data: bytes, target=None):
        while len(blob) % 4:
            blob.append(0)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data),
                      **({"target": target} if target else {})})
        blob.extend(data)
        return len(views) - 1

    def add_accessor(array, kind, component=5126, target=34962, normalized=False):
        array = np.ascontiguousarray(array)
        view = add_view(array.tobytes(), target)
        acc = {"bufferView": view, "componentType": component, "count": len(array), "type": kind}
        if normalized:
            acc["normalized"] = True
        if component == 5126:
            flat = array.reshape(len(array), -1)
            acc["min"], acc["max"] = flat.min(0).tolist(), flat.max(0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    kinds = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
    prim_attrs = {"POSITION": add_accessor(positions, "VEC3"), "NORMAL": add_accessor(normals, "VEC3"),
                  "TEXCOORD_0": add_accessor(uvs, "VEC2"), "COLOR_0": add_accessor(colours, "VEC4")}
    for name, values in attributes.items():
        values = np.asarray(values)
        values = values.reshape(count, -1)
        if values.dtype == np.uint16:
            prim_attrs[name] = add_accessor(values, kinds[values.shape[1]], 5123, normalized=True)
        else:
            prim_attrs[name] = add_accessor(values.astype(np.float32), kinds[values.shape[1]])
    indices = add_accessor(tris.reshape(-1), "SCALAR", 5125, 34963)
    pictures = {"base_img": png_bytes((200, 120, 60)), "orm_img": png_bytes((255, 128, 64)),
                "normal_img": png_bytes((128, 128, 255)), "emissive_img": png_bytes((10, 200, 10))}
    images = []
    for name, data in pictures.items():
        images.append({"bufferView": add_view(data), "mimeType": "image/png", **({"name": name} if names else {})})
    textures = [{"source": i, "sampler": 0} for i in range(len(images))]
    pbr = {"baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"scale": [2, 2]}}
                                if extensions else {}},
           "metallicRoughnessTexture": {"index": 1}, "metallicFactor": 1.0, "roughnessFactor": 1.0}
    material = {"pbrMetallicRoughness": pbr, "normalTexture": {"index": 2, "scale": 0.5},
                "emissiveTexture": {"index": 3}, "emissiveFactor": [1, 1, 1]}
    if names:
        material["name"] = "gamma_bronze"
    if occlusion:
        material["occlusionTexture"] = {"index": 1, "strength": 0.8}
    used = ["KHR_texture_transform", "KHR_materials_emissive_strength", "KHR_materials_ior"]
    if extensions:
        material["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0},
                                  "KHR_materials_ior": {"ior": 1.2}}
    gltf = {
        "asset": {"version": "2.0", "generator": "gamma test_clients"},
        "scene": 0,
        "scenes": [{"nodes": [0], "extras": {"gamma": {"iteration": 3}}}],
        "nodes": [{"mesh": 0, **({"name": "gamma_node", "extras": {"surfels": 1234}} if names else {})}],
        "meshes": [{"primitives": [{"attributes": prim_attrs, "indices": indices, "material": 0}],
                    **({"name": "gamma_mesh"} if names else {})}],
        "materials": [material],
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}],
        "textures": textures, "images": images,
        "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": len(blob)}],
        **({"extensionsUsed": used} if extensions else {}),
    }
    while len(blob) % 4:
        blob.append(0)
    gltf["buffers"][0]["byteLength"] = len(blob)
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    data = struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(text), 0x4E4F534A) + text \
        + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
    path.write_bytes(data)
    return path


# --------------------------------------------------------------------------- a glb by Blender's exporter

#: Runs in a bpy child (clients.blender_script): a UV sphere, some faces smooth,
#: a Principled BSDF fed by image textures (Base Color; Roughness and Metallic
#: through Separate Color; Normal through Normal Map), a custom float attribute,
#: exported by Blender's own glTF exporter.
EXPORT_SCENE = r'''
import bmesh
import numpy as np
from pathlib import Path

folder = Path(args["folder"])
mesh = bpy.data.meshes.new("WeatheredMesh")
bm = bmesh.new()
bm.loops.layers.uv.new("UVMap")
bmesh.ops.create_uvsphere(bm, u_segments=16, v_segments=8, radius=1.0, calc_uvs=True)
bm.to_mesh(mesh)
bm.free()
# Smooth: the faces above z = 0.3 (the upper tri band and the quad bands below it).
smooth = [p.center.z > 0.3 for p in mesh.polygons]
mesh.polygons.foreach_set("use_smooth", smooth)
triangles = np.array([len(p.vertices) - 2 for p in mesh.polygons])
result["smooth_faces"] = int(sum(smooth))
result["polygons"] = len(mesh.polygons)
result["expected_smooth_fraction"] = float(triangles[np.array(smooth)].sum() / triangles.sum())
patina = mesh.attributes.new("_PATINA", "FLOAT", "POINT")
patina.data.foreach_set("value", [(v.co.z + 1) / 2 for v in mesh.vertices])

def image(name, rgb, colorspace):
    img = bpy.data.images.new(name, 16, 16)
    img.pixels.foreach_set(np.tile([*rgb, 1.0], 16 * 16).astype(np.float32))
    img.filepath_raw = str(folder / f"{name}.png")
    img.file_format = "PNG"
    img.save()
    img.colorspace_settings.name = colorspace
    return img

mat = bpy.data.materials.new("Bronze")
mat.use_nodes = True
nodes, links = mat.node_tree.nodes, mat.node_tree.links
bsdf = nodes["Principled BSDF"]
base = nodes.new("ShaderNodeTexImage")
base.image = image("bronze_base", (0.6, 0.35, 0.2), "sRGB")
links.new(base.outputs["Color"], bsdf.inputs["Base Color"])
orm = nodes.new("ShaderNodeTexImage")
orm.image = image("bronze_orm", (1.0, 0.4, 0.9), "Non-Color")
split = nodes.new("ShaderNodeSeparateColor")
links.new(orm.outputs["Color"], split.inputs["Color"])
links.new(split.outputs["Green"], bsdf.inputs["Roughness"])
links.new(split.outputs["Blue"], bsdf.inputs["Metallic"])
normal = nodes.new("ShaderNodeTexImage")
normal.image = image("bronze_normal", (0.5, 0.5, 1.0), "Non-Color")
normal_map = nodes.new("ShaderNodeNormalMap")
links.new(normal.outputs["Color"], normal_map.inputs["Color"])
links.new(normal_map.outputs["Normal"], bsdf.inputs["Normal"])
mesh.materials.append(mat)

obj = bpy.data.objects.new("Weathered", mesh)
bpy.context.scene.collection.objects.link(obj)
out = str(folder / "blender_export.glb")
bpy.ops.export_scene.gltf(filepath=out, export_format="GLB", export_attributes=True)
result["glb"] = out
'''


# --------------------------------------------------------------------------- USD stages by pxr

def write_usd_stage(folder, *, default_prim=True, texture_name="patina.png", name="stage.usda", animated=False):
    """A Z-up stage: /World/Patch, a mesh bound to /World/Looks/Bronze, a
    UsdPreviewSurface whose diffuseColor comes from a UsdUVTexture reading
    ``texture_name`` (a real PNG next to the stage unless it is the missing
    one), roughness from its green channel, through a primvar reader of "st"."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "patina.png").write_bytes(png_bytes((90, 160, 120)))
    path = folder / name
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Scope.Define(stage, "/World/Looks")
    if default_prim:
        stage.SetDefaultPrim(world.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, "/World/Patch")
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    mesh.CreatePointsAttr(points)
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateExtentAttr([(0, 0, 0), (1, 1, 0)])
    if animated:
        stage.SetStartTimeCode(1)
        stage.SetEndTimeCode(3)
        for t in (1, 2, 3):
            mesh.GetPointsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(x, y, 0.1 * t) for x, y, _ in points]), t)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    material = UsdShade.Material.Define(stage, "/World/Looks/Bronze")
    surface = UsdShade.Shader.Define(stage, "/World/Looks/Bronze/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, "/World/Looks/Bronze/StReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    texture = UsdShade.Shader.Define(stage, "/World/Looks/Bronze/PatinaTexture")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./{texture_name}")
    texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    rgb = texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    green = texture.CreateOutput("g", Sdf.ValueTypeNames.Float)
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).ConnectToSource(green)
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(1.0)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    stage.GetRootLayer().Save()
    return path


# --------------------------------------------------------------------------- Blender

@pytest.fixture(scope="module")
def glbs(tmp_path_factory):
    """The glbs Blender imports, all in one child (bpy takes ~1.7 s to start):
    hand-made ones and one written by Blender's own exporter."""
    assert has_bpy(), "bpy (Blender 4.5 as a module) is not installed: make test installs it"
    folder = tmp_path_factory.mktemp("glbs")
    patch = curved_patch()[0]
    n = len(patch)
    start = time.perf_counter()
    exported = blender_script(EXPORT_SCENE, folder=str(folder))
    export_seconds = time.perf_counter() - start
    files = {
        "hand": write_glb(folder / "hand.glb"),
        "unnamed": write_glb(folder / "unnamed.glb", names=False, extensions=False,
                             attributes={"PATINA": (patch[:, :1] + 1) / 2,          # no leading "_"
                                         "_MASK16": np.full((n, 1), 30000, np.uint16)}),
        "two_scalars": write_glb(folder / "two_scalars.glb",
                                 attributes={"_PATINA": (patch[:, :1] + 1) / 2, "_RUST": np.full((n, 1), 0.25)}),
        "blender": Path(exported["glb"]),
    }
    truncated = folder / "truncated.glb"
    truncated.write_bytes(files["hand"].read_bytes()[:200])
    start = time.perf_counter()
    reports = blender_import_many([*files.values(), truncated], errors="return")
    import_seconds = time.perf_counter() - start
    print(f"blender export child {export_seconds:.2f} s; {len(reports)} imports in one child "
          f"{import_seconds:.2f} s (import bpy {reports[0]['import_bpy_seconds']:.2f} s, "
          f"imports {', '.join(format(r['seconds'], '.2f') for r in reports)} s)")
    return {"exported": exported, "folder": folder, **dict(zip([*files, "truncated"], reports))}


def only(mapping):
    assert len(mapping) == 1, list(mapping)
    return next(iter(mapping.values()))


def source(material, name):
    """The one image texture feeding a Principled BSDF input."""
    entry = material["bsdf"][name]
    assert entry["linked"], (name, entry)
    assert len(entry["sources"]) == 1, (name, entry["sources"])
    return entry["sources"][0]


def test_handmade_glb_keeps_names_extras_and_attributes(glbs):
    r = glbs["hand"]
    assert r["messages"] == [], r["messages"]
    [obj] = r["objects"]
    assert (obj["name"], obj["type"], obj["data"], obj["materials"]) == ("gamma_node", "MESH", "gamma_mesh",
                                                                         ["gamma_bronze"])
    assert obj["custom_properties"] == {"surfels": 1234}                # node extras -> object properties
    assert r["scene_extras"] == {"gamma": {"iteration": 3}}             # scene extras -> scene properties
    # glTF +Y up becomes Blender's +Z up: the patch's height (glTF y) is Blender z.
    assert obj["bounds"] == [[-1.0, -1.0, 0.0], [1.0, 1.0, pytest.approx(0.6)]]
    mesh = r["meshes"]["gamma_mesh"]
    assert (mesh["vertices"], mesh["polygons"]) == (25, 32)
    assert mesh["smooth_fraction"] == mesh["shaded_smooth_fraction"] == 1.0   # NORMALs bend away from faces
    attrs = {a["name"]: a for a in mesh["attributes"]}
    # A custom attribute keeps its name, leading underscore included, on the points.
    assert (attrs["_PATINA"]["domain"], attrs["_PATINA"]["data_type"]) == ("POINT", "FLOAT")
    assert attrs["_PATINA"]["min"] == [0.0] and attrs["_PATINA"]["max"] == [1.0]
    # COLOR_0 becomes the 8-bit corner colour attribute "Color" (sRGB-encoded bytes).
    assert mesh["color_attributes"] == ["Color"] and mesh["render_color"] == "Color"
    assert (attrs["Color"]["domain"], attrs["Color"]["data_type"]) == ("CORNER", "BYTE_COLOR")
    assert attrs["Color"]["mean"] == pytest.approx([0.2, 0.6, 0.4, 1.0], abs=0.005)
    assert mesh["uv_layers"] == ["UVMap"]
    assert {i["name"] for i in r["images"]} == {"base_img", "orm_img", "normal_img", "emissive_img"}
    assert all(i["packed"] and i["size"] == [8, 8] for i in r["images"])


def test_handmade_glb_material_in_blender(glbs):
    r = glbs["hand"]
    mat = r["materials"]["gamma_bronze"]
    base = source(mat, "Base Color")
    assert (base["image"], base["colorspace"]) == ("base_img", "sRGB")
    # COLOR_0 multiplies the base colour: a Mix node between the texture and the BSDF.
    assert base["path"][0] == "ShaderNodeMix.Result"
    assert mat["bsdf"]["Base Color"]["attributes"][0]["node"] == "ShaderNodeVertexColor"
    # metallicRoughnessTexture: one Non-Color image, G -> Roughness, B -> Metallic via Separate Color.
    rough, metal = source(mat, "Roughness"), source(mat, "Metallic")
    assert (rough["image"], rough["colorspace"], rough["channel"]) == ("orm_img", "Non-Color", "Color.Green")
    assert (metal["image"], metal["colorspace"], metal["channel"]) == ("orm_img", "Non-Color", "Color.Blue")
    assert rough["path"][0] == "ShaderNodeSeparateColor.Green"
    normal = source(mat, "Normal")
    assert (normal["image"], normal["colorspace"]) == ("normal_img", "Non-Color")
    assert normal["path"][0] == "ShaderNodeNormalMap.Normal"
    emission = source(mat, "Emission Color")
    assert (emission["image"], emission["colorspace"]) == ("emissive_img", "sRGB")
    assert mat["bsdf"]["Emission Strength"]["default"] == 4.0          # KHR_materials_emissive_strength
    assert mat["bsdf"]["IOR"]["default"] == pytest.approx(1.2)         # KHR_materials_ior
    assert not mat["bsdf"]["Alpha"]["linked"]
    assert "ShaderNodeMapping" in mat["nodes"]                         # KHR_texture_transform
    # occlusionTexture: not a BSDF input; a second node of the same image, its
    # red channel into the "glTF Material Output" group's Occlusion (kept for re-export only).
    to_occlusion = [chain for t in mat["textures"] for chain in t["to"]
                    if chain[-1] == "ShaderNodeGroup(glTF Material Output).Occlusion"]
    assert len(to_occlusion) == 1 and "ShaderNodeSeparateColor.Color->Red" in to_occlusion[0]
    assert [t["image"] for t in mat["textures"] if t["to"] and t["to"][0] in to_occlusion] == ["orm_img"]


def test_unnamed_glb_and_dropped_attributes(glbs):
    r = glbs["unnamed"]
    [obj] = r["objects"]
    assert (obj["name"], obj["data"], obj["materials"]) == ("Mesh_0", "Mesh_0", ["Material_0"])
    assert sorted(i["name"] for i in r["images"]) == ["Image_0", "Image_1", "Image_2", "Image_3"]
    names = {a["name"] for a in only(r["meshes"])["attributes"]}
    # Not imported, without a word: a name without "_" and a normalized UNSIGNED_SHORT scalar.
    assert "PATINA" not in names and "_MASK16" not in names
    assert r["messages"] == []


def test_two_custom_scalars_keep_their_values(glbs):
    attrs = {a["name"]: a for a in only(glbs["two_scalars"]["meshes"])["attributes"]}
    assert attrs["_PATINA"]["max"] == [1.0] and attrs["_RUST"]["min"] == attrs["_RUST"]["max"] == [0.25]


def test_truncated_glb_error_is_reported(glbs):
    r = glbs["truncated"]
    assert "error" in r and "objects" not in r
    assert "RuntimeError" in r["error"], r["error"]


def test_mixed_width_custom_attributes_break_blender_import_by_hash_seed(tmp_path, monkeypatch):
    """Blender 4.5's importer walks custom attributes in set order (string hash,
    so per process) while their arrays are in file order: a SCALAR and a VEC3
    custom attribute together fail for some PYTHONHASHSEEDs.  The error must
    reach us as a BlenderImportError naming the numpy error."""
    assert has_bpy(), "bpy (Blender 4.5 as a module) is not installed: make test installs it"
    patch = curved_patch()[0]
    path = write_glb(tmp_path / "mixed.glb", attributes={"_PATINA": (patch[:, :1] + 1) / 2, "_FLOW": patch * 2})
    outcomes = {}
    for seed in ("0", "1"):
        monkeypatch.setenv("PYTHONHASHSEED", seed)
        try:
            report = blender_import(path)
            attrs = {a["name"]: a for a in only(report["meshes"])["attributes"]}
            # VEC3 custom attributes are not turned to Blender's axes (positions are).
            assert attrs["_FLOW"]["data_type"] == "FLOAT_VECTOR"
            assert attrs["_FLOW"]["max"] == pytest.approx([2.0, 1.2, 2.0])
            outcomes[seed] = "ok"
        except BlenderImportError as e:
            assert "ValueError" in str(e).splitlines()[0], str(e)[:2000]
            assert str(path) in str(e).splitlines()[0]
            outcomes[seed] = "error"
    assert outcomes == {"0": "ok", "1": "error"}


def test_blender_exporter_round_trip(glbs):
    built, r = glbs["exported"], glbs["blender"]
    assert r["messages"] == [], r["messages"]
    [obj] = r["objects"]
    assert (obj["name"], obj["data"], obj["materials"]) == ("Weathered", "WeatheredMesh", ["Bronze"])
    mesh = r["meshes"]["WeatheredMesh"]
    assert mesh["polygons"] == 224          # 16 x 8 UV sphere: 96 quads (2 triangles each) + 32 triangles
    expected = built["expected_smooth_fraction"]
    assert 0 < expected < 1 and expected == pytest.approx(80 / 224)
    # The faces built smooth are shaded smooth again, exactly.
    assert mesh["shaded_smooth_fraction"] == pytest.approx(expected)
    # The Smooth flag is guessed from NORMALs with a 1e-7 tolerance: float32
    # round-off flags a few flat faces smooth (their custom normals keep them flat).
    assert expected <= mesh["smooth_fraction"] <= expected + 0.1
    attrs = {a["name"]: a for a in mesh["attributes"]}
    assert attrs["_PATINA"]["min"] == [0.0] and attrs["_PATINA"]["max"] == [1.0]
    mat = r["materials"]["Bronze"]
    base = source(mat, "Base Color")
    assert (base["image"], base["colorspace"], base["path"]) == ("bronze_base", "sRGB", ["ShaderNodeTexImage.Color"])
    rough, metal = source(mat, "Roughness"), source(mat, "Metallic")
    assert (rough["image"], rough["channel"], rough["colorspace"]) == ("bronze_orm", "Color.Green", "Non-Color")
    assert (metal["image"], metal["channel"]) == ("bronze_orm", "Color.Blue")
    normal = source(mat, "Normal")
    assert (normal["image"], normal["colorspace"], normal["path"][0]) == ("bronze_normal", "Non-Color",
                                                                          "ShaderNodeNormalMap.Normal")
    assert sorted(i["name"] for i in r["images"]) == ["bronze_base", "bronze_normal", "bronze_orm"]


def test_blender_render_of_the_handmade_glb(glbs, tmp_path):
    out = blender_render(glbs["folder"] / "hand.glb", tmp_path / "hand.png", size=96, samples=8)
    print(f"render child {out['seconds']:.2f} s (Cycles {out['render_seconds']:.2f} s)")
    image = np.asarray(Image.open(out["png"]).convert("RGB"), float)
    assert image.shape == (96, 96, 3)
    sky = 255 * np.where(np.array([0.55, 0.65, 0.8]) <= 0.0031308, 12.92 * np.array([0.55, 0.65, 0.8]),
                         1.055 * np.array([0.55, 0.65, 0.8]) ** (1 / 2.4) - 0.055)
    assert np.abs(image[2, 2] - sky).max() < 6                         # the corner is the world colour
    centre = image[40:56, 40:56].reshape(-1, 3).mean(0)
    assert centre[1] > centre[0] + 40 and centre[1] > centre[2] + 40   # the green emissive patch


# --------------------------------------------------------------------------- USD

@needs_usd
def test_usd_stage_passes_and_is_summarised(tmp_path):
    good = write_usd_stage(tmp_path)
    start = time.perf_counter()
    assert usd_check(good) == []
    print(f"usd_check child {time.perf_counter() - start:.2f} s")
    s = usd_summary(good)
    assert s["default_prim"] == "/World" and s["up_axis"] == "Z"
    assert ["/World/Patch", "Mesh"] in s["prims"] and ["/World/Looks/Bronze", "Material"] in s["prims"]
    inputs = s["materials"]["/World/Looks/Bronze"]["inputs"]
    assert inputs["diffuseColor"]["connected"] and inputs["diffuseColor"]["file"] == "./patina.png"
    assert (inputs["diffuseColor"]["source_id"], inputs["diffuseColor"]["output"]) == ("UsdUVTexture", "rgb")
    assert inputs["roughness"]["output"] == "g"
    assert not inputs["metallic"]["connected"] and inputs["metallic"]["value"] == 1.0
    assert "normal" not in inputs and "occlusion" not in inputs
    assert not s["animated_points"] and not s["has_time_code_range"]
    animated = usd_summary(write_usd_stage(tmp_path, animated=True, name="animated.usda"))
    assert (animated["start_time_code"], animated["end_time_code"]) == (1.0, 3.0)
    assert animated["points_time_samples"] == {"/World/Patch": 3} and animated["animated_points"]


@needs_usd
def test_usdz_package_passes(tmp_path):
    from pxr import UsdUtils

    good = write_usd_stage(tmp_path)
    usdz = tmp_path / "stage.usdz"
    assert UsdUtils.CreateNewUsdzPackage(str(good), str(usdz))
    assert usd_check(usdz) == []


@needs_usd
@pytest.mark.parametrize("engine", ["auto", "validation"])
def test_usd_checker_flags_broken_stages(tmp_path, engine):
    no_default = write_usd_stage(tmp_path, default_prim=False, name="no_default.usda")
    missing = write_usd_stage(tmp_path, texture_name="missing.png", name="missing.usda")
    assert any("defaultPrim" in p for p in usd_check(no_default, engine=engine)), usd_check(no_default, engine=engine)
    problems = usd_check(missing, engine=engine)
    assert any("missing.png" in p for p in problems), problems
