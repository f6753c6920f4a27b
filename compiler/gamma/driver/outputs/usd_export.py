"""The weathered scene as OpenUSD (SPEC §16.3, ``export --format usd``).

One stage (``.usda`` text, ``.usdc``/``.usd`` binary) holding every exported
iteration: ``/SCENE`` (the default prim, an Xform) with a ``UsdGeom.Mesh``
per object and ``/SCENE/Materials`` with a ``UsdShade.Material`` per surface
of each object: a UsdPreviewSurface fed by the object's texture set (base
colour, occlusion-roughness-metallic, tangent-space normal map) through
UsdUVTexture shaders reading the ``st`` primvar.  Every property is a float
vertex primvar ``primvars:NAME``.

Several iterations become time samples (time code = iteration): the
textures' ``inputs:file`` and the property primvars change per iteration,
so the weathering plays as an animation (their default value is the last
iteration's file, for readers that ignore time samples, like Blender's
importer); with ``moving`` (a shape change)
the points, normals, texture coordinates and extent too, and the topology
and the material subsets when they change.  One iteration: default values
only.

The textures are not written here: ``files`` names the PNGs the exporter
wrote, relative to the stage's folder.  ``pxr`` (usd-core) is imported
only when a stage is written.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from typing import TYPE_CHECKING

if TYPE_CHECKING:    # export.py calls this module: at run time it is a parameter's type only
    from .export import ExportPart

#: The texture set's images a material reads (the rest are for other tools).
MATERIAL_CHANNELS = ("BaseColor", "ORM", "Normal")
#: Frames per second of the animation (one frame per exported iteration).
TIME_CODES_PER_SECOND = 4
#: Primvar names a property may not take (they mean something to every client).
RESERVED_PRIMVARS = {"st", "normals", "displayColor", "displayOpacity", "velocities", "accelerations",
                     "widths", "ids"}
SUFFIXES = (".usda", ".usdc", ".usd")


def identifier(name: str, fallback: str = "object") -> str:
    """``name`` as a USD prim or property name (ASCII identifier)."""
    text = re.sub(r"[^A-Za-z0-9_]", "_", str(name))
    if not text.strip("_"):
        text = fallback
    return "_" + text if text[0].isdigit() else text


def unique(name: str, taken: set) -> str:
    out, k = name, 1
    while out in taken:
        out, k = f"{name}_{k}", k + 1
    taken.add(out)
    return out


def asset_path(relative: str) -> str:
    """A texture file relative to the stage's folder as an asset path that
    resolves against the stage's layer (``./`` prefix: not a search path)."""
    text = str(relative).replace(os.sep, "/")
    if text.startswith(("./", "../", "/")) or re.match(r"^[A-Za-z]:/", text):
        return text
    return "./" + text


def primvar_reader_varname_type():
    """The type of UsdPrimvarReader's ``inputs:varname`` in this usd-core's
    shader registry (string in usd-core 26, token in some older ones): the
    compliance checker wants the registry's."""
    from pxr import Sdf

    try:
        from pxr import Sdr

        node = Sdr.Registry().GetShaderNodeByIdentifier("UsdPrimvarReader_float2")
        kind = node.GetShaderInput("varname").GetTypeAsSdfType()
        kind = kind.GetSdfType() if hasattr(kind, "GetSdfType") else kind[0]
        if kind in (Sdf.ValueTypeNames.String, Sdf.ValueTypeNames.Token):
            return kind
    except Exception:       # no registry entry: the UsdPreviewSurface spec's own type
        pass
    return Sdf.ValueTypeNames.String


def write_usd(path: Path, frames: list, scene_name: str, moving: bool = False) -> None:
    """Write the stage ``path`` (``.usda``, ``.usdc`` or ``.usd``).

    ``frames``: ``(iteration, parts, files)`` per exported iteration, in
    order, where ``parts`` are the iteration's ``ExportPart`` and
    ``files[part.name][channel]`` the PNG of that channel ("BaseColor",
    "ORM", "Normal") relative to ``path``'s folder.  ``moving``: the shape
    changes between iterations (geometry is time-sampled); otherwise every
    frame must have the first frame's vertices and triangles."""
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise ValueError(f"{path}: a USD stage is .usda, .usdc or .usd, not {path.suffix or 'no suffix'!r}")
    if not frames:
        raise ValueError("write_usd: no frames to write")
    iterations = [int(f[0]) for f in frames]
    if sorted(set(iterations)) != iterations:
        raise ValueError(f"write_usd: the iterations must be increasing, not {iterations}")
    stage = _Stage(path, frames, scene_name, moving)
    for name in stage.part_names:
        stage.write_mesh(name)
    stage.save(path)


class _Stage:
    """One stage being written: its names, its materials and its meshes."""

    def __init__(self, path: Path, frames: list, scene_name: str, moving: bool):
        from pxr import Sdf, Usd, UsdGeom, Vt

        from ...version import version

        self.frames, self.moving = frames, moving
        self.iterations = [int(f[0]) for f in frames]
        self.animated = len(frames) > 1
        self._names(scene_name)
        fmt = Sdf.FileFormat.FindByExtension(path.suffix.lstrip(".").lower())
        self.layer = Sdf.Layer.CreateAnonymous(path.stem, fmt)
        stage = self.stage = Usd.Stage.Open(self.layer)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        self.layer.documentation = f"exported by gamma {version()}"
        self.layer.customLayerData = {"gamma": {"iterations": Vt.IntArray(self.iterations),
                                                "scene": str(scene_name)}}
        if self.animated:
            stage.SetStartTimeCode(self.iterations[0])
            stage.SetEndTimeCode(self.iterations[-1])
            stage.SetTimeCodesPerSecond(TIME_CODES_PER_SECOND)
            stage.SetFramesPerSecond(TIME_CODES_PER_SECOND)
        root = UsdGeom.Xform.Define(stage, f"/{self.root_name}").GetPrim()
        stage.SetDefaultPrim(root)
        if self.root_name != scene_name:
            root.SetDisplayName(str(scene_name))
        UsdGeom.Scope.Define(stage, f"/{self.root_name}/Materials")
        self.varname_type = primvar_reader_varname_type()
        self.textures: dict = {}     # (object, surface) -> {channel: UsdShade.Shader}

    def _names(self, scene_name: str) -> None:
        """Prim names: the root, a mesh per object (in the order they first
        appear) and a material per (object, surface), named after the surface
        unless two objects share it."""
        self.root_name = identifier(scene_name, "scene")
        self.part_names: list[str] = []
        for _, parts, _ in self.frames:
            for part in parts:
                if part.name not in self.part_names:
                    self.part_names.append(part.name)
        taken = {"Materials"}
        self.mesh_name = {name: unique(identifier(name), taken) for name in self.part_names}
        self.surfaces_of: dict[str, list[str]] = {name: [] for name in self.part_names}
        users: dict[str, set] = {}
        for _, parts, _ in self.frames:
            for part in parts:
                for material, _faces in part.primitives:
                    if material not in self.surfaces_of[part.name]:
                        self.surfaces_of[part.name].append(material)
                    users.setdefault(material, set()).add(part.name)
        taken = set()
        self.material_name = {}
        for name in self.part_names:
            for material in self.surfaces_of[name]:
                base = material if len(users[material]) == 1 else f"{material}_{name}"
                self.material_name[name, material] = (unique(identifier(base, "material"), taken), base)

    def at(self, iteration: int):
        from pxr import Usd

        return Usd.TimeCode(iteration) if self.animated else Usd.TimeCode.Default()

    def define_material(self, part_name: str, material: str, channels):
        """A UsdPreviewSurface reading the texture set's ``channels``."""
        from pxr import Sdf, UsdShade

        prim_name, shown = self.material_name[part_name, material]
        mat = UsdShade.Material.Define(self.stage, f"/{self.root_name}/Materials/{prim_name}")
        if prim_name != shown:
            mat.GetPrim().SetDisplayName(shown)
        base = mat.GetPath()
        surface = UsdShade.Shader.Define(self.stage, base.AppendChild("PreviewSurface"))
        surface.CreateIdAttr("UsdPreviewSurface")
        mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
        reader = UsdShade.Shader.Define(self.stage, base.AppendChild("stReader"))
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", self.varname_type).Set("st")
        st = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        self.textures[part_name, material] = {channel: self._texture(base, channel, st, surface)
                                              for channel in channels}
        if "ORM" not in channels:       # glTF's defaults without the texture: rough, metal
            surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
            surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(1.0)
        return mat

    def _texture(self, base, channel: str, st, surface):
        """A UsdUVTexture of ``channel`` connected to the surface's inputs."""
        from pxr import Gf, Sdf, UsdShade

        tex = UsdShade.Shader.Define(self.stage, base.AppendChild(channel))
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset)
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st)
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB" if channel == "BaseColor" else "raw")
        if channel == "BaseColor":
            rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
            surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
        elif channel == "ORM":
            for name, output in (("occlusion", "r"), ("roughness", "g"), ("metallic", "b")):
                out = tex.CreateOutput(output, Sdf.ValueTypeNames.Float)
                surface.CreateInput(name, Sdf.ValueTypeNames.Float).ConnectToSource(out)
        elif channel == "Normal":
            tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
            tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
            rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
            surface.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(rgb)
        return tex

    def _bind(self, name: str, prim, channels) -> dict:
        """The object's materials bound to its mesh (one) or to face subsets
        (several); returns the subsets by material."""
        from pxr import UsdGeom, UsdShade, Vt

        materials = {m: self.define_material(name, m, channels) for m in self.surfaces_of[name]}
        binding = UsdShade.MaterialBindingAPI.Apply(prim)
        if len(materials) == 1:
            binding.Bind(next(iter(materials.values())))
            return {}
        subsets = {}
        for material, mat in materials.items():
            subset = binding.CreateMaterialBindSubset(self.material_name[name, material][0], Vt.IntArray(),
                                                      UsdGeom.Tokens.face)
            UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mat)
            subsets[material] = subset
        return subsets

    def write_mesh(self, name: str) -> None:
        """One object: its mesh, materials, primvars and their samples."""
        from pxr import Sdf, UsdGeom

        present = [(it, next(p for p in parts if p.name == name), files.get(name, {}))
                   for it, parts, files in self.frames if any(p.name == name for p in parts)]
        channels = [c for c in MATERIAL_CHANNELS if any(c in f for _, _, f in present)]
        mesh = UsdGeom.Mesh.Define(self.stage, f"/{self.root_name}/{self.mesh_name[name]}")
        prim = mesh.GetPrim()
        if self.mesh_name[name] != name:
            prim.SetDisplayName(name)
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        subsets = self._bind(name, prim, channels)
        prop_names, taken = {}, set(RESERVED_PRIMVARS)
        for _, part, _ in present:
            for prop in part.attributes:
                if prop not in prop_names:
                    prop_names[prop] = unique(identifier(prop, "property"), taken)
        pv = UsdGeom.PrimvarsAPI(prim)
        samples = _MeshSamples(mesh, subsets, pv)
        samples.props = {prop: pv.CreatePrimvar(n, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
                         for prop, n in prop_names.items()}
        self._sample(name, present, samples)

    def _sample(self, name: str, present: list, samples: "_MeshSamples") -> None:
        """The mesh's values: defaults for what never changes, time samples
        for the rest (geometry only when ``moving``)."""
        from pxr import Sdf, Usd, UsdGeom

        first = present[0][1]
        if not self.moving:
            for it, part, _ in present[1:]:
                if (part.positions.shape != first.positions.shape
                        or not np.array_equal(part.positions, first.positions)
                        or not np.array_equal(part.triangles, first.triangles)):
                    raise ValueError(f"write_usd: '{name}' changes its vertices or triangles at iteration "
                                     f"{it}; pass moving=True")
        topology_changes = any(not np.array_equal(part.triangles, first.triangles) for _, part, _ in present)
        subsets_change = topology_changes or not all(_same_faces(part, first) for _, part, _ in present)
        default = Usd.TimeCode.Default()
        if not self.moving or not self.animated:
            samples.geometry(first, default)
        if not topology_changes:
            samples.topology(first, default)
        if not subsets_change:
            samples.faces(first, default)
        for it, part, files in present:
            time = self.at(it)
            if self.moving and self.animated:
                samples.geometry(part, time)
            if topology_changes:
                samples.topology(part, time)
            if subsets_change:
                samples.faces(part, time)
            samples.properties(part, time)
            for material in self.surfaces_of[name]:
                for channel, tex in self.textures[name, material].items():
                    if channel in files:
                        tex.GetInput("file").Set(Sdf.AssetPath(asset_path(files[channel])), time)
        if self.animated:        # readers that ignore time samples (Blender's importer) see the last state
            for material in self.surfaces_of[name]:
                for channel, tex in self.textures[name, material].items():
                    last = [f[channel] for _, _, f in present if channel in f]
                    if last:
                        tex.GetInput("file").Set(Sdf.AssetPath(asset_path(last[-1])))
        shown = {it for it, _, _ in present}
        if self.animated and len(shown) < len(self.frames):      # an object that comes and goes
            visible = samples.mesh.CreateVisibilityAttr()
            for it in self.iterations:
                visible.Set(UsdGeom.Tokens.inherited if it in shown else UsdGeom.Tokens.invisible,
                            Usd.TimeCode(it))

    def save(self, path: Path) -> None:
        """The stage to ``path``, through a temporary file renamed into place."""
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
        try:
            if not self.layer.Export(str(temporary)):
                raise OSError(f"usd-core could not write {temporary}")
            os.replace(temporary, path)
        finally:
            if temporary.exists():
                temporary.unlink()


def _same_faces(a: ExportPart, b: ExportPart) -> bool:
    return ([m for m, _ in a.primitives] == [m for m, _ in b.primitives]
            and all(np.array_equal(f, g) for (_, f), (_, g) in zip(a.primitives, b.primitives)))


class _MeshSamples:
    """The attributes of one mesh and how a part's values are set on them."""

    def __init__(self, mesh, subsets: dict, pv):
        from pxr import Sdf, UsdGeom

        self.mesh, self.subsets = mesh, subsets
        self.points = mesh.CreatePointsAttr()
        self.normals = mesh.CreateNormalsAttr()
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        self.extent = mesh.CreateExtentAttr()
        self.counts, self.indices = mesh.CreateFaceVertexCountsAttr(), mesh.CreateFaceVertexIndicesAttr()
        self.st = pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        self.props: dict = {}

    def geometry(self, part: ExportPart, time) -> None:
        from pxr import UsdGeom, Vt

        p = np.ascontiguousarray(part.positions, np.float32).reshape(-1, 3)
        self.points.Set(Vt.Vec3fArray.FromNumpy(p), time)
        self.normals.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(part.normals, np.float32).reshape(-1, 3)),
                         time)
        self.extent.Set(UsdGeom.Mesh.ComputeExtent(self.points.Get(time)), time)
        self.st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(part.uvs, np.float32).reshape(-1, 2)), time)

    def topology(self, part: ExportPart, time) -> None:
        from pxr import Vt

        tris = np.ascontiguousarray(part.triangles, np.int32).reshape(-1, 3)
        self.counts.Set(Vt.IntArray.FromNumpy(np.full(len(tris), 3, np.int32)), time)
        self.indices.Set(Vt.IntArray.FromNumpy(tris.reshape(-1)), time)

    def faces(self, part: ExportPart, time) -> None:
        from pxr import Vt

        own = {m: f for m, f in part.primitives}
        for material, subset in self.subsets.items():
            ids = np.sort(np.asarray(own.get(material, []), np.int32).reshape(-1))
            subset.GetIndicesAttr().Set(Vt.IntArray.FromNumpy(ids), time)

    def properties(self, part: ExportPart, time) -> None:
        from pxr import Vt

        for prop, primvar in self.props.items():
            if prop in part.attributes:
                values = np.ascontiguousarray(part.attributes[prop], np.float32).reshape(-1)
                primvar.Set(Vt.FloatArray.FromNumpy(values), time)
