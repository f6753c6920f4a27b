"""The USD export (gamma.driver.outputs.usd_export) on scenes built by hand: a quad
with one material and a triangle strip with two, written as one-frame and
three-frame stages next to real PNGs.  usd-core's compliance checker must
pass them (and fail a stage whose texture is missing); pxr reads back the
prims, subsets, bindings, the UsdPreviewSurface network, primvars and time
samples; Blender's USD importer must feed its Principled BSDF from the
images."""

import io
import shutil

import numpy as np
import pytest
from PIL import Image

from clients import blender_script, usd_check, usd_summary
from gamma.driver.outputs.export import ExportPart
from gamma.driver.outputs.usd_export import write_usd

from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade    # usd-core: a test dependency (make test installs it)

ITERATIONS = (10, 20, 30)
CHANNELS = ("BaseColor", "ORM", "Normal")


def png(value: float) -> bytes:
    out = io.BytesIO()
    Image.fromarray(np.full((4, 4, 3), int(value * 255), np.uint8)).save(out, "PNG")
    return out.getvalue()


def quad(iteration: int) -> ExportPart:
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    return ExportPart("old bunny", p, np.tile(np.float32([0, 0, 1]), (4, 1)), p[:, :2].copy(),
                      np.array([[0, 1, 2], [0, 2, 3]], np.uint32), [("Copper", np.array([0, 1]))],
                      {"patina": np.arange(4, dtype=np.float32) + iteration}, {})


def strip(iteration: int, shift: float = 0.0, extra: bool = False) -> ExportPart:
    """Three triangles (four with ``extra``: a changed topology), Stone on
    0 and 2, Moss on 1 (and 3)."""
    p = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1], [0, 2, 1], [1, 2, 1]], np.float32)
    p[:, 0] += shift
    tris = [[0, 1, 2], [1, 3, 2], [2, 3, 4]] + ([[3, 5, 4]] if extra else [])
    n = 6 if extra else 5
    moss = [1, 3] if extra else [1]
    return ExportPart("strip", p[:n], np.tile(np.float32([0, 0, 1]), (n, 1)), p[:n, :2] / 2,
                      np.array(tris, np.uint32), [("Stone", np.array([0, 2])), ("Moss", np.array(moss))],
                      {"patina": np.full(n, iteration / 10, np.float32),
                       "grime": np.linspace(0, 1, n).astype(np.float32)}, {})


def textures(folder, parts, iteration):
    """Write the parts' PNGs under ``folder``; the files dict write_usd takes."""
    files = {}
    for part in parts:
        sub = part.name.replace(" ", "_")
        (folder / sub).mkdir(parents=True, exist_ok=True)
        files[part.name] = {}
        for k, channel in enumerate(CHANNELS):
            name = f"{sub}/{sub}_{channel}_{iteration:04d}.png"
            (folder / name).write_bytes(png((k + 1) * iteration / 100))
            files[part.name][channel] = name
    return files


def frames_of(folder, moving=False):
    out = []
    for k, it in enumerate(ITERATIONS):
        parts = [quad(it), strip(it, shift=0.5 * k if moving else 0.0, extra=moving and k == 2)]
        if moving and k == 1:
            parts = parts[1:]                   # the quad is gone at iteration 20
        out.append((it, parts, textures(folder, parts, it)))
    return out


@pytest.fixture(scope="module")
def stages(tmp_path_factory):
    folder = tmp_path_factory.mktemp("usd")
    frames = frames_of(folder)
    write_usd(folder / "one.usda", frames[:1], "weathered scene")
    write_usd(folder / "three.usdc", frames, "weathered scene")
    moving = tmp_path_factory.mktemp("usd_moving")
    write_usd(moving / "moving.usda", frames_of(moving, moving=True), "weathered scene", moving=True)
    return {"one": folder / "one.usda", "three": folder / "three.usdc", "moving": moving / "moving.usda"}


def texture_of(surface: UsdShade.Shader, name: str):
    """(texture shader, output name) connected to the PreviewSurface input."""
    source, output, _ = surface.GetInput(name).GetConnectedSource()
    return UsdShade.Shader(source.GetPrim()), output


@pytest.mark.parametrize("which", ["one", "three", "moving"])
def test_stages_pass_the_compliance_checker(stages, which):
    assert usd_check(stages[which]) == []


def test_one_frame_stage_holds_the_scene(stages):
    summary = usd_summary(stages["one"])
    assert summary["default_prim"] == "/weathered_scene"
    assert summary["up_axis"] == "Y" and summary["meters_per_unit"] == 1.0
    assert not summary["has_time_code_range"]
    prims = dict(summary["prims"])
    assert prims["/weathered_scene"] == "Xform"
    assert prims["/weathered_scene/old_bunny"] == "Mesh" and prims["/weathered_scene/strip"] == "Mesh"
    assert prims["/weathered_scene/strip/Stone"] == "GeomSubset"
    assert {p for p, t in summary["prims"] if t == "Material"} == {
        f"/weathered_scene/Materials/{m}" for m in ("Copper", "Stone", "Moss")}
    for material, part in (("Copper", "old_bunny"), ("Stone", "strip"), ("Moss", "strip")):
        entry = summary["materials"][f"/weathered_scene/Materials/{material}"]
        assert entry["shader_id"] == "UsdPreviewSurface"
        inputs = entry["inputs"]
        for name, channel, output in (("diffuseColor", "BaseColor", "rgb"), ("roughness", "ORM", "g"),
                                      ("metallic", "ORM", "b"), ("occlusion", "ORM", "r"),
                                      ("normal", "Normal", "rgb")):
            assert inputs[name]["connected"] and inputs[name]["source_id"] == "UsdUVTexture"
            assert inputs[name]["output"] == output, name
            assert inputs[name]["file"] == f"./{part}/{part}_{channel}_0010.png", name
            assert inputs[name]["resolved"], name

    stage = Usd.Stage.Open(str(stages["one"]))
    bunny = UsdGeom.Mesh(stage.GetPrimAtPath("/weathered_scene/old_bunny"))
    assert bunny.GetPrim().GetDisplayName() == "old bunny"
    built = quad(10)
    assert np.array_equal(np.array(bunny.GetPointsAttr().Get()), built.positions)
    assert np.array_equal(np.array(bunny.GetNormalsAttr().Get()), built.normals)
    assert bunny.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    assert list(bunny.GetFaceVertexCountsAttr().Get()) == [3, 3]
    assert list(bunny.GetFaceVertexIndicesAttr().Get()) == built.triangles.reshape(-1).tolist()
    assert bunny.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert np.allclose(np.array(bunny.GetExtentAttr().Get()), [[0, 0, 0], [1, 1, 0]])
    primvars = UsdGeom.PrimvarsAPI(bunny)
    st = primvars.GetPrimvar("st")
    assert st.GetTypeName() == Sdf.ValueTypeNames.TexCoord2fArray and st.GetInterpolation() == "vertex"
    assert np.array_equal(np.array(st.Get()), built.uvs)
    patina = primvars.GetPrimvar("patina")
    assert patina.GetTypeName() == Sdf.ValueTypeNames.FloatArray and patina.GetInterpolation() == "vertex"
    assert np.array_equal(np.array(patina.Get()), [10, 11, 12, 13])
    # one material: bound to the mesh itself, no subsets
    assert UsdShade.MaterialBindingAPI(bunny).ComputeBoundMaterial()[0].GetPath() == \
        "/weathered_scene/Materials/Copper"
    assert not UsdGeom.Subset.GetAllGeomSubsets(bunny)
    # two materials: a materialBind subset each
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/weathered_scene/strip"))
    assert mesh.GetPrim().GetDisplayName() == ""                 # its name was already valid
    assert np.array_equal(np.array(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("grime").Get()),
                          strip(10).attributes["grime"])
    subsets = {s.GetPrim().GetName(): s for s in UsdShade.MaterialBindingAPI(mesh).GetMaterialBindSubsets()}
    assert set(subsets) == {"Stone", "Moss"}
    assert list(subsets["Stone"].GetIndicesAttr().Get()) == [0, 2]
    assert list(subsets["Moss"].GetIndicesAttr().Get()) == [1]
    for name, subset in subsets.items():
        assert subset.GetElementTypeAttr().Get() == UsdGeom.Tokens.face
        assert subset.GetFamilyNameAttr().Get() == "materialBind"
        bound = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0]
        assert bound.GetPath() == f"/weathered_scene/Materials/{name}"
    assert UsdGeom.Subset.GetFamilyType(mesh, "materialBind") == UsdGeom.Tokens.nonOverlapping
    # the normal map's decoding, colour spaces, the st reader
    surface = UsdShade.Material(stage.GetPrimAtPath("/weathered_scene/Materials/Stone")).ComputeSurfaceSource()[0]
    normal, _ = texture_of(surface, "normal")
    assert normal.GetInput("scale").Get() == Gf.Vec4f(2, 2, 2, 1)
    assert normal.GetInput("bias").Get() == Gf.Vec4f(-1, -1, -1, 0)
    assert normal.GetInput("sourceColorSpace").Get() == "raw"
    base, _ = texture_of(surface, "diffuseColor")
    assert base.GetInput("sourceColorSpace").Get() == "sRGB"
    reader, _ = texture_of(base, "st")
    assert reader.GetShaderId() == "UsdPrimvarReader_float2" and reader.GetInput("varname").Get() == "st"
    # one frame: no time samples anywhere
    sampled = [a.GetPath() for p in stage.Traverse() for a in p.GetAttributes() if a.GetNumTimeSamples()]
    assert sampled == []


def test_three_frames_animate_textures_and_properties(stages):
    stage = Usd.Stage.Open(str(stages["three"]))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (10, 30)
    assert stage.GetTimeCodesPerSecond() == 4
    surface = UsdShade.Material(stage.GetPrimAtPath("/weathered_scene/Materials/Moss")).ComputeSurfaceSource()[0]
    for name, channel in (("diffuseColor", "BaseColor"), ("roughness", "ORM"), ("normal", "Normal")):
        file = texture_of(surface, name)[0].GetInput("file")
        assert file.GetAttr().GetTimeSamples() == list(ITERATIONS)
        for it in ITERATIONS:
            asset = file.Get(Usd.TimeCode(it))
            assert asset.path == f"./strip/strip_{channel}_{it:04d}.png" and asset.resolvedPath
        assert file.Get().path.endswith("_0030.png")        # the default: the last state (Blender reads it)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/weathered_scene/strip"))
    patina = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("patina")
    assert patina.GetAttr().GetTimeSamples() == list(ITERATIONS)
    for it in ITERATIONS:
        assert np.allclose(patina.Get(Usd.TimeCode(it)), it / 10)
    # the shape does not move: geometry is not sampled
    for attr in (mesh.GetPointsAttr(), mesh.GetNormalsAttr(), mesh.GetFaceVertexIndicesAttr(),
                 mesh.GetExtentAttr(), UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").GetAttr()):
        assert attr.GetNumTimeSamples() == 0 and attr.HasValue(), attr.GetPath()
    assert usd_summary(stages["three"])["animated_points"] is False


def test_moving_shapes_sample_geometry_topology_and_subsets(stages):
    summary = usd_summary(stages["moving"])
    assert summary["animated_points"] is True
    stage = Usd.Stage.Open(str(stages["moving"]))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/weathered_scene/strip"))
    assert mesh.GetPointsAttr().GetTimeSamples() == list(ITERATIONS)
    for k, it in enumerate(ITERATIONS):
        t = Usd.TimeCode(it)
        built = strip(it, shift=0.5 * k, extra=k == 2)
        assert np.array_equal(np.array(mesh.GetPointsAttr().Get(t)), built.positions)
        assert np.allclose(np.array(mesh.GetExtentAttr().Get(t))[:, 0], [0.5 * k, 0.5 * k + 1])
        assert list(mesh.GetFaceVertexIndicesAttr().Get(t)) == built.triangles.reshape(-1).tolist()
        assert len(mesh.GetFaceVertexCountsAttr().Get(t)) == len(built.triangles)
        assert len(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Get(t)) == len(built.positions)
        moss = UsdGeom.Subset(stage.GetPrimAtPath("/weathered_scene/strip/Moss"))
        assert list(moss.GetIndicesAttr().Get(t)) == ([1, 3] if k == 2 else [1])
    # the quad is missing at iteration 20: hidden there, geometry fixed (its topology never changes)
    bunny = UsdGeom.Mesh(stage.GetPrimAtPath("/weathered_scene/old_bunny"))
    assert [bunny.GetVisibilityAttr().Get(Usd.TimeCode(it)) for it in ITERATIONS] == \
        ["inherited", "invisible", "inherited"]
    assert bunny.GetFaceVertexIndicesAttr().GetNumTimeSamples() == 0


def test_a_missing_texture_fails_the_checker(tmp_path):
    frames = frames_of(tmp_path)
    write_usd(tmp_path / "scene.usda", frames, "scene")
    assert usd_check(tmp_path / "scene.usda") == []
    late = tmp_path / "strip" / "strip_BaseColor_0030.png"          # a later time sample's file
    shutil.move(late, tmp_path / "aside.png")
    problems = usd_check(tmp_path / "scene.usda")
    assert any("strip_BaseColor_0030.png" in p and "unresolvable" in p for p in problems), problems
    shutil.move(tmp_path / "aside.png", late)
    (tmp_path / "old_bunny" / "old_bunny_Normal_0010.png").unlink()   # the first normal map
    problems = usd_check(tmp_path / "scene.usda")
    assert any("old_bunny_Normal_0010.png" in p and "NormalMapTextureChecker" in p for p in problems), problems


def test_names_are_made_valid_and_shared_surfaces_split(tmp_path):
    a, b = quad(10), quad(10)
    a.name, b.name = "3 rocks", "Materials"          # a digit first; the materials scope's own name
    b.primitives = [("Copper", np.array([0, 1]))]
    write_usd(tmp_path / "s.usd", [(10, [a, b], textures(tmp_path, [a, b], 10))], "my-scene!")
    assert usd_check(tmp_path / "s.usd") == []
    stage = Usd.Stage.Open(str(tmp_path / "s.usd"))
    assert (tmp_path / "s.usd").read_bytes()[:8] == b"PXR-USDC"      # .usd: the binary (crate) form
    assert str(stage.GetDefaultPrim().GetPath()) == "/my_scene_"
    assert stage.GetDefaultPrim().GetDisplayName() == "my-scene!"
    meshes = {p.GetName(): p.GetDisplayName() for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)}
    assert meshes == {"_3_rocks": "3 rocks", "Materials_1": "Materials"}
    materials = sorted(p.GetName() for p in stage.Traverse() if p.IsA(UsdShade.Material))
    assert materials == ["Copper_3_rocks", "Copper_Materials"]


def test_bad_input_is_refused(tmp_path):
    frames = frames_of(tmp_path, moving=True)
    with pytest.raises(ValueError, match="moving=True"):
        write_usd(tmp_path / "s.usda", frames, "s")
    with pytest.raises(ValueError, match="usdz"):
        write_usd(tmp_path / "s.usdz", frames[:1], "s")
    with pytest.raises(ValueError, match="increasing"):
        write_usd(tmp_path / "s.usda", frames[::-1], "s", moving=True)


BLENDER_IMPORT = """
import sys, time
helpers = sys.modules["__main__"]        # tests/clients.py, the child's program
start = time.perf_counter()
bpy.ops.wm.usd_import(filepath=args["path"])
result["import_seconds"] = time.perf_counter() - start
result["objects"] = {o.name: [s.material.name if s.material else None for s in o.material_slots]
                     for o in bpy.data.objects if o.type == "MESH"}
result["materials"] = {m.name: helpers._material_report(m) for m in bpy.data.materials}
result["images"] = {i.name: i.colorspace_settings.name for i in bpy.data.images}
result["attributes"] = {m.name: sorted(a.name for a in m.attributes if not a.name.startswith(".")) for m in bpy.data.meshes}
"""


@pytest.mark.parametrize("which, iteration", [("one", 10), ("three", 30)])
def test_blender_feeds_the_principled_bsdf_from_the_images(stages, which, iteration):
    r = blender_script(BLENDER_IMPORT, path=str(stages[which]))
    print(f"Blender USD import of {which}: {r['import_seconds']:.3f} s (child {r['seconds']:.1f} s)")
    assert r["objects"] == {"old_bunny": ["Copper"], "strip": ["Stone", "Moss"]}
    assert {"patina", "st"} <= set(r["attributes"]["strip"]) and "grime" in r["attributes"]["strip"]
    for material, part in (("Copper", "old_bunny"), ("Stone", "strip"), ("Moss", "strip")):
        bsdf = r["materials"][material]["bsdf"]
        for name, channel, used in (("Base Color", "BaseColor", "Color"), ("Roughness", "ORM", "Color.Green"),
                                    ("Metallic", "ORM", "Color.Blue"), ("Normal", "Normal", "Color")):
            sources = bsdf[name]["sources"]
            assert [(s["image"], s["channel"]) for s in sources] == \
                [(f"{part}_{channel}_{iteration:04d}.png", used)], (material, name, sources)
        assert any("ShaderNodeNormalMap" in step for step in bsdf["Normal"]["sources"][0]["path"])
    assert r["images"][f"strip_BaseColor_{iteration:04d}.png"] == "sRGB"
    assert r["images"][f"strip_ORM_{iteration:04d}.png"] == "Non-Color"
    assert r["images"][f"strip_Normal_{iteration:04d}.png"] == "Non-Color"
