"""Blender's side of a run: hand the selected objects to ``gammac`` as a glb
(Blender's own glTF exporter, modifiers applied, world space) and put the
results back into the same objects.

What a weathered object gets (``apply_results``):
- its mesh replaced by the weathered one (the mesh as the run saw it, so
  with its modifiers applied: they are switched off), with the run's texture
  coordinates, smooth normals and every property as a float point attribute
  named after it.  The object keeps its own mesh (``ORIGINAL``) and the
  names of the modifiers it switched off, so a second run starts from the
  object as the user made it, and ``restore`` puts it back;
- per surface a material whose Principled BSDF reads the baked texture set
  (base colour, roughness and metallic from the ORM map, the tangent-space
  normal map), the images packed into the .blend;
- for a shape-change effect, on request, the change as a shape key over the
  shape it had (the basis is each weathered vertex moved back onto the
  original surface, so it works even where the run re-tiled the mesh).

A second run replaces what the first one added (materials, images, meshes
tagged ``gamma``) instead of piling up copies.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import uuid
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector
from mathutils.bvhtree import BVHTree

from .glb import Part, read_parts
from .job import GammaError

#: Custom property marking what a run made (materials, images, meshes) and, on an object, the run.
TAG = "gamma"
#: An object's own mesh, kept while it shows a weathered one.
ORIGINAL = "gamma_original_mesh"
#: The modifiers a run switched off (the weathered mesh has them applied).
SWITCHED_OFF = "gamma_switched_off"
#: The object's material slots' links (DATA or OBJECT) as the user had them.
SLOT_LINKS = "gamma_slot_links"
#: Where the add-on keeps each object's last run (its maps), for "continue from the last run".
RUNS = Path(tempfile.gettempdir()) / "gamma-blender-runs"


# ---- hand-over ----------------------------------------------------------------------

def mesh_objects(objects) -> list:
    """The mesh objects among ``objects``; an error naming any without faces."""
    meshes = [o for o in objects if o.type == "MESH"]
    if not meshes:
        raise GammaError("select one or more mesh objects to weather")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for obj in meshes:
        if len(obj.evaluated_get(depsgraph).data.polygons) == 0:
            raise GammaError(f"'{obj.name}' has no faces: gamma weathers surfaces")
    names = [o.name for o in meshes]
    if len(set(names)) != len(names):
        raise GammaError("two selected objects share a name")
    return meshes


class AsMade:
    """Within ``with AsMade(objects):`` each weathered object shows its own
    mesh and modifiers again, as the user made it (the hand-over and the
    shape key's basis start from that, not from an earlier run's result)."""

    def __init__(self, objects):
        self.swapped = [(o, o.data) for o in objects if o.get(ORIGINAL) is not None]

    def __enter__(self):
        for obj, _ in self.swapped:
            obj.data = obj[ORIGINAL]
            _switch(obj, True)
            for slot, link in zip(obj.material_slots, obj.get(SLOT_LINKS, ())):
                slot.link = link
        return self

    def __exit__(self, *exc):
        for obj, weathered in self.swapped:
            obj.data = weathered
            _switch(obj, False)
            for slot in obj.material_slots:
                slot.link = "DATA"
        return False


def _switch(obj, on: bool) -> None:
    for name in obj.get(SWITCHED_OFF, ()):
        modifier = obj.modifiers.get(name)
        if modifier is not None:
            modifier.show_viewport = modifier.show_render = on


def world_triangles(obj) -> tuple[np.ndarray, np.ndarray]:
    """The object's evaluated mesh (modifiers applied) in world space:
    (vertices (V, 3), triangles (T, 3))."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        mesh.calc_loop_triangles()
        co = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", co)
        tris = np.empty(len(mesh.loop_triangles) * 3, np.int32)
        mesh.loop_triangles.foreach_get("vertices", tris)
    finally:
        evaluated.to_mesh_clear()
    m = np.array(obj.matrix_world, dtype=np.float64)
    world = co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    return world, tris.reshape(-1, 3)


def write_handover(objects, path: Path) -> None:
    """The objects as one glb by Blender's glTF exporter: +Y up, world
    transforms, modifiers applied, UVs, normals and materials."""
    view_layer = bpy.context.view_layer
    selected = [o for o in view_layer.objects if o.select_get()]
    active = view_layer.objects.active
    try:
        for o in selected:
            o.select_set(False)
        for o in objects:
            o.select_set(True)
        view_layer.update()
        bpy.ops.export_scene.gltf(
            filepath=str(path), export_format="GLB", use_selection=True, export_apply=True,
            export_yup=True, export_texcoords=True, export_normals=True, export_materials="EXPORT",
            export_animations=False, export_skins=False, export_morph=False, export_cameras=False,
            export_lights=False, export_extras=False)
    finally:
        for o in objects:
            o.select_set(False)
        for o in selected:
            o.select_set(True)
        view_layer.objects.active = active
    if not path.is_file():
        raise GammaError("Blender's glTF exporter wrote nothing")


# ---- results ------------------------------------------------------------------------

def _to_blender(v: np.ndarray) -> np.ndarray:
    """glTF axes (+Y up) to Blender's (+Z up)."""
    return np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1).astype(np.float64)


def _sidecars(export: Path) -> dict:
    """Each exported part's texture set: {part name: (folder, sidecar)}, the
    last iteration's.  Folders are the names made file-safe, so the sidecar's
    own "object" says whose it is."""
    found = {}
    for path in sorted(export.glob("*/*.json")):
        try:
            sidecar = json.loads(path.read_text())
        except ValueError:
            continue
        name = sidecar.get("object")
        if name is None:
            continue
        if sidecar.get("udim") is not None:
            raise GammaError(f"'{name}': its UVs span several UDIM tiles, which the add-on does not read yet; "
                             "keep the UVs in 0..1")
        if name not in found or found[name][1]["iteration"] < sidecar["iteration"]:
            found[name] = (path.parent, sidecar)
    return found


def _image(folder: Path, entry: dict, name: str, colour_space: str):
    image = bpy.data.images.load(str(folder / entry["file"]), check_existing=False)
    image.name = name
    image.colorspace_settings.name = colour_space
    image.pack()
    image[TAG] = name             # the name it should have once an earlier run's image is gone
    return image


def build_material(name: str, folder: Path, sidecar: dict, part: str):
    """A material whose Principled BSDF reads the part's texture set."""
    images = sidecar["images"]
    mat = bpy.data.materials.new(name)
    mat[TAG] = True
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")

    def texture(channel: str, colour_space: str, y: float):
        node = nodes.new("ShaderNodeTexImage")
        node.image = _image(folder, images[channel], f"{part}_{channel}", colour_space)
        node.location = (-700, y)
        node.label = channel
        return node

    base = texture("BaseColor", "sRGB", 300)
    links.new(base.outputs["Color"], bsdf.inputs["Base Color"])
    orm = texture("ORM", "Non-Color", 0)
    split = nodes.new("ShaderNodeSeparateColor")
    split.location = (-400, 0)
    links.new(orm.outputs["Color"], split.inputs["Color"])
    links.new(split.outputs["Green"], bsdf.inputs["Roughness"])
    links.new(split.outputs["Blue"], bsdf.inputs["Metallic"])
    normal = texture("Normal", "Non-Color", -300)
    normal_map = nodes.new("ShaderNodeNormalMap")
    normal_map.location = (-400, -300)
    normal_map.uv_map = "UVMap"
    links.new(normal.outputs["Color"], normal_map.inputs["Color"])
    links.new(normal_map.outputs["Normal"], bsdf.inputs["Normal"])
    return mat


def _weld(part: Part) -> tuple[np.ndarray, np.ndarray]:
    """(index of each glTF vertex's welded vertex, first glTF vertex of each
    welded one): gamma splits vertices at chart seams and creases; Blender
    keeps UVs and normals per corner, so the mesh stays connected."""
    _, first, inverse = np.unique(part.positions, axis=0, return_index=True, return_inverse=True)
    return inverse.reshape(-1), first


def build_mesh(part: Part, name: str, world_to_local: Matrix, property_names: list[str]):
    """A Blender mesh of a weathered part in the object's local space."""
    welded, first = _weld(part)
    m = np.array(world_to_local, dtype=np.float64)
    local = _to_blender(part.positions[first]) @ m[:3, :3].T + m[:3, 3]
    triangles = np.concatenate([p.triangles for p in part.primitives])
    mesh = bpy.data.meshes.new(name)
    mesh[TAG] = True
    mesh.from_pydata(local.tolist(), [], welded[triangles].tolist())
    corners = triangles.reshape(-1)              # from_pydata keeps the corners' order
    if part.uvs is not None:
        uv = part.uvs[corners].astype(np.float64)
        uv[:, 1] = 1.0 - uv[:, 1]
        mesh.uv_layers.new(name="UVMap").data.foreach_set("uv", uv.astype(np.float32).reshape(-1))
    material_index = np.concatenate([np.full(len(p.triangles), i, np.int32) for i, p in enumerate(part.primitives)])
    mesh.polygons.foreach_set("material_index", material_index)
    for attribute, values in part.attributes.items():
        name_of = {"_" + n.upper(): n for n in property_names}
        layer = mesh.attributes.new(name_of.get(attribute, attribute.lstrip("_").lower()), "FLOAT", "POINT")
        layer.data.foreach_set("value", values[first].astype(np.float32))
    mesh.validate(clean_customdata=False)
    mesh.update()
    if part.normals is not None:
        # a normal transforms by the inverse transpose of the object's world matrix
        world_normals = _to_blender(part.normals[corners])
        normals = world_normals @ np.array(world_to_local.inverted(), dtype=np.float64)[:3, :3]
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        mesh.shade_smooth()
        mesh.normals_split_custom_set(normals.tolist())
    return mesh


def add_shape_key(obj, original_world: tuple[np.ndarray, np.ndarray], effect: str) -> None:
    """The weathered shape as a shape key over its basis, the weathered
    vertices moved back to the nearest point of the shape the run started from."""
    vertices, triangles = original_world
    tree = BVHTree.FromPolygons([Vector(v) for v in vertices], triangles.tolist(), all_triangles=True)
    matrix, inverse = obj.matrix_world, obj.matrix_world.inverted()
    mesh = obj.data
    weathered = [v.co.copy() for v in mesh.vertices]
    for v, co in zip(mesh.vertices, weathered):
        nearest = tree.find_nearest(matrix @ co)[0]
        if nearest is not None:
            v.co = inverse @ nearest
    obj.shape_key_add(name="Basis", from_mix=False)
    key = obj.shape_key_add(name=f"gamma {effect}", from_mix=False)
    for point, co in zip(key.data, weathered):
        point.co = co
    key.value = 1.0


def _forget(mesh) -> None:
    """Remove a mesh an earlier run made, with its materials and images,
    once nothing uses them."""
    if mesh is None or not mesh.get(TAG) or mesh.users > 0:
        return
    materials = [m for m in mesh.materials if m is not None and m.get(TAG)]
    bpy.data.meshes.remove(mesh)
    for mat in materials:
        if mat.users > 0:
            continue
        images = [n.image for n in mat.node_tree.nodes if n.type == "TEX_IMAGE" and n.image] \
            if mat.node_tree else []
        bpy.data.materials.remove(mat)
        for image in images:
            if image.get(TAG) and image.users == 0:
                bpy.data.images.remove(image)


def _show_weathered(obj, mesh) -> None:
    """``obj`` shows ``mesh``; its own mesh is kept and its modifiers switched off."""
    shown = obj.data
    if obj.get(ORIGINAL) is None:
        obj[ORIGINAL] = shown
        obj[SWITCHED_OFF] = [m.name for m in obj.modifiers if m.show_viewport or m.show_render]
        obj[SLOT_LINKS] = [slot.link for slot in obj.material_slots]
    obj.data = mesh
    _switch(obj, False)
    _forget(shown)


def restore(obj) -> bool:
    """Put a weathered object back as the user made it (False: it was not weathered)."""
    original = obj.get(ORIGINAL)
    if original is None:
        return False
    shown = obj.data
    obj.data = original
    _switch(obj, True)
    for slot, link in zip(obj.material_slots, obj.get(SLOT_LINKS, ())):
        slot.link = link
    earlier = {(obj.get(TAG) or {}).get("run")}
    for key in (ORIGINAL, SWITCHED_OFF, SLOT_LINKS, TAG):
        if key in obj:
            del obj[key]
    _forget(shown)
    _forget_runs(earlier)
    return True


def _read_run(export: Path, objects) -> tuple[dict, dict]:
    """The last iteration's parts and texture sets, every one the objects need
    (read before any object is touched: a failure leaves them all as they were)."""
    scenes = sorted(export.glob("*.glb"))
    if not scenes:
        raise GammaError("the run exported nothing")
    parts = {p.name: p for p in read_parts(scenes[-1])}
    missing = [o.name for o in objects if o.name not in parts]
    if missing:
        raise GammaError(f"the run's export has no part named {', '.join(missing)} "
                         f"(it has {', '.join(sorted(parts))})")
    sidecars = _sidecars(export)
    missing = [o.name for o in objects if o.name not in sidecars]
    if missing:
        raise GammaError(f"the run exported no texture set for {', '.join(missing)}")
    return parts, sidecars


def _take_names(mesh, wanted_mesh: str, materials: dict) -> None:
    """The names a run's datablocks should have, now that the last run's are gone."""
    if wanted_mesh not in bpy.data.meshes:
        mesh.name = wanted_mesh
    for wanted, mat in materials.items():
        if wanted and wanted not in bpy.data.materials:
            mat.name = wanted
        for node in mat.node_tree.nodes:
            image = node.image if node.type == "TEX_IMAGE" else None
            if image is not None and image[TAG] not in bpy.data.images:
                image.name = image[TAG]


def _weather_object(obj, part: Part, folder: Path, sidecar: dict) -> tuple:
    """Show ``part`` in ``obj`` with its texture set: (mesh, materials by name, property names)."""
    properties = list(sidecar.get("properties", {}))
    own = obj.get(ORIGINAL) or obj.data
    wanted = f"{own.name} weathered"
    mesh = build_mesh(part, wanted, obj.matrix_world.inverted(), properties)
    materials = {}
    for prim in part.primitives:
        if prim.material not in materials:
            materials[prim.material] = build_material(prim.material or obj.name, folder, sidecar, obj.name)
    for mat in materials.values():
        mesh.materials.append(mat)
    _show_weathered(obj, mesh)
    for slot in obj.material_slots:
        slot.link = "DATA"
    _take_names(mesh, wanted, materials)
    return mesh, materials, properties


def keep_run(run: Path) -> Path:
    """Keep a finished run's maps and summary (not its pictures and texture
    sets, which are packed now) where a later run can start from them."""
    RUNS.mkdir(parents=True, exist_ok=True)
    kept = RUNS / uuid.uuid4().hex
    kept.mkdir()
    shutil.copy2(run / "summary.json", kept / "summary.json")
    maps = sorted((run / "maps").glob("iter_*.ply"))
    (kept / "maps").mkdir()
    if maps:
        shutil.copy2(maps[-1], kept / "maps" / maps[-1].name)
    return kept


def last_run(objects) -> str:
    """The run folder the objects' last run left (all of them weathered by that run)."""
    runs = {(o.get(TAG) or {}).get("run") for o in objects}
    if len(runs) != 1 or None in runs:
        raise GammaError("continue from the last run: the selected objects were not all weathered by one "
                         "earlier run; select the objects of that run, or run without continuing")
    run = runs.pop()
    if not (Path(run) / "summary.json").is_file():
        raise GammaError(f"continue from the last run: its maps are gone ({run}); run without continuing")
    return run


def _forget_runs(earlier: set) -> None:
    """Delete the kept runs among ``earlier`` that no object names any more
    (only those: other .blend files keep theirs in the same folder)."""
    named = {(o.get(TAG) or {}).get("run") for o in bpy.data.objects}
    for folder in earlier - named:
        if folder and Path(folder).parent == RUNS:
            shutil.rmtree(folder, ignore_errors=True)


def apply_results(objects, run: Path, effect: str, *, shape_key: bool = False,
                  originals: dict | None = None, kept: Path | None = None) -> dict:
    """Put the run in ``run`` (its ``export/``) into ``objects``; per object
    what it got: {name: {"properties": [...], "materials": [...], "vertices": N}}."""
    parts, sidecars = _read_run(run / "export", objects)
    earlier = {(o.get(TAG) or {}).get("run") for o in objects}
    done = {}
    for obj in objects:
        folder, sidecar = sidecars[obj.name]
        mesh, materials, properties = _weather_object(obj, parts[obj.name], folder, sidecar)
        if shape_key and originals and obj.name in originals:
            add_shape_key(obj, originals[obj.name], Path(effect).stem)
        obj[TAG] = {"effect": str(effect), "properties": properties, "run": str(kept) if kept else ""}
        done[obj.name] = {"properties": properties, "materials": [m.name for m in materials.values()],
                          "vertices": len(mesh.vertices)}
    _forget_runs(earlier)
    return done
