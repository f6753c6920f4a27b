"""Scenes: what ``--scene`` names, assembled into one mesh whose every triangle
is bound to a surface of the effect.

``--scene`` is a mesh file (OBJ, PLY), a glTF 2.0 scene (``.gltf``, ``.glb``:
one part per node, transforms applied, see ``gltf.py``) or a JSON scene file
listing several meshes with transforms (format in language/SPEC.md, "Scenes").  Triangles are
bound to surfaces by assignment rules ``PATTERN=SURFACE``: a pattern (shell
wildcards) matches a triangle when it matches its OBJ object, group or
material name or its mesh's file name without extension (for glTF: its node,
mesh or material name).  Rules from the
command line (``--assign``) come first, in the order given, then the rules of
the scene file's mesh entry, then the effect's own ``assign`` declarations;
the first rule that matches wins.  ``--assign SURFACE`` alone means
``*=SURFACE``.  An effect with a single surface needs no rule at all.
"""

from __future__ import annotations

import fnmatch
import sys
import json
import math
from dataclasses import field
from pathlib import Path

import numpy as np

from ...ir.effect import Effect
from .budget import scene_size_problem
from ...files import file_problem
from ...records import Record, record


class SceneError(Exception):
    """A one-line, user-facing problem with the scene or its assignment."""


@record
class Scene(Record):
    mesh: object                   # gamma._runtime.Mesh (all parts, transformed)
    triangle_surface: np.ndarray   # int32 surface index per triangle
    down: tuple[float, float, float]
    bounds: tuple[tuple[float, ...], tuple[float, ...]]
    triangles_per_surface: dict[str, int]
    triangle_object: np.ndarray = None    # int32 index into object_names per triangle
    object_names: list = None             # OBJ object, else group, else the mesh file's name
    triangle_has_uv: np.ndarray = None    # bool per triangle: its part has texture coordinates
    triangle_flat: np.ndarray = None      # bool per triangle: its part renders flat ("shading": "flat")
    triangle_material: np.ndarray = None  # int32 per triangle: index into materials, -1 none
    materials: list = None                # gltf.Material per material
    #: attribute(): {name as the file has it: (float32 per vertex, bool per vertex: the part has it)},
    #: read only when the effect asks for attributes (vertex_attributes.py)
    vertex_attributes: dict = None
    part_attribute_names: dict = None     # part name -> the attribute names it has (for messages)

    @property
    def diagonal(self) -> float:
        lo, hi = (np.asarray(b, float) for b in self.bounds)
        return float(np.linalg.norm(hi - lo))


def parse_assign(items: list[str], effect: Effect) -> list[tuple[str, str]]:
    rules = []
    for item in items:
        pattern, _, surface = item.rpartition("=")
        pattern = pattern or "*"
        if surface not in effect.surfaces:
            raise SceneError(f"--assign {item}: no surface '{surface}' in {effect.path} "
                             f"(surfaces: {', '.join(effect.surfaces) or 'none'})")
        rules.append((pattern, surface))
    return rules


def _number(value) -> bool:
    """A JSON number: true and false are not (Python's bool is an int)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _vector(value, n: int, where: str) -> np.ndarray:
    if (not isinstance(value, list) or len(value) != n
            or not all(_number(v) and math.isfinite(v) for v in value)):
        raise SceneError(f"{where} must be a list of {n} finite numbers")
    return np.asarray(value, dtype=float)


def _rotation(degrees: np.ndarray) -> np.ndarray:
    """Rotation about x, then y, then z (degrees, right-handed)."""
    ax, ay, az = np.radians(degrees)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _load_mesh(rt, path: Path):
    problem = file_problem(path)
    if problem:
        raise SceneError(f"cannot read mesh '{path}': {problem}")
    from . import prefetch

    mesh = prefetch.take(path)          # read ahead by gammac run (prefetch.py)
    if mesh is not None:
        return mesh
    try:
        return rt.Mesh.load(str(path))
    except (ValueError, RuntimeError) as err:
        raise SceneError(str(err)) from None


@record
class _Part(Record):
    mesh: object
    stem: str
    rules: list[tuple[str, str]]
    vertices: np.ndarray | None = None   # transformed (None: untransformed single mesh)
    names: tuple = ()                    # more names --assign patterns match (glTF mesh, material)
    flat: bool = False                   # rendered with flat shading (a scene file's "shading": "flat")
    material: tuple | None = None        # glTF base colour: (RGB factor, float32 image [h, w, 3] or None)
    source: Path | None = None           # the OBJ or PLY file (its vertex attributes are read from it)
    attributes: dict | None = None       # a glTF part's vertex attributes (name -> float32 per vertex)


def _file_parts(rt, path: Path, rules=()) -> list[_Part]:
    """The parts of one mesh file: one, or one per node of a glTF scene."""
    from .gltf import GltfError, is_gltf, read_gltf

    if not is_gltf(path):
        return [_Part(_load_mesh(rt, path), path.stem, list(rules), source=path)]
    if not path.is_file():
        what = "is a directory" if path.is_dir() else "file not found"
        raise SceneError(f"cannot read mesh '{path}': {what}")
    try:
        pieces = read_gltf(path)
    except GltfError as err:
        raise SceneError(str(err)) from None
    parts = []
    for piece in pieces:
        try:
            mesh = rt.Mesh.from_arrays(piece.vertices, piece.faces, piece.uvs)
        except (ValueError, RuntimeError) as err:
            raise SceneError(f"glTF '{path}', node '{piece.node}': {err}") from None
        names = tuple(n for n in (piece.mesh, piece.material, path.stem) if n)
        parts.append(_Part(mesh, piece.node, list(rules), np.asarray(mesh.vertices(), float), names,
                           material=piece.look, attributes=piece.attributes))
    return parts


#: A scene file is a small object; one larger than this is not one.
MAX_SCENE_BYTES = 16 << 20


def _read_scene_file(rt, path: Path, effect: Effect):
    problem = file_problem(path)
    if problem:
        raise SceneError(f"cannot read scene '{path}': {problem}")
    try:
        if path.stat().st_size > MAX_SCENE_BYTES:
            raise SceneError(f"cannot read scene '{path}': larger than {MAX_SCENE_BYTES >> 20} MB, "
                             "so not a scene file")
        spec = json.loads(path.read_text(encoding="utf-8"))
    except RecursionError:
        raise SceneError(f"cannot read scene '{path}': nested too deeply to be a scene file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise SceneError(f"cannot read scene '{path}': {err}") from None
    if not isinstance(spec, dict) or not isinstance(spec.get("meshes"), list) or not spec["meshes"]:
        raise SceneError(f"scene '{path}' must be an object with a non-empty list \"meshes\"")
    unknown = set(spec) - {"meshes", "down"}
    if unknown:
        raise SceneError(f"scene '{path}': unknown key '{sorted(unknown)[0]}' (keys: meshes, down)")
    down = tuple(_vector(spec["down"], 3, f"scene '{path}': down")) if "down" in spec else None
    parts = []
    for i, entry in enumerate(spec["meshes"]):
        where = f"scene '{path}': meshes[{i}]"
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise SceneError(f"{where} must be an object with a \"file\"")
        unknown = set(entry) - {"file", "translate", "rotate", "scale", "assign", "shading"}
        if unknown:
            raise SceneError(f"{where}: unknown key '{sorted(unknown)[0]}' "
                             "(keys: file, translate, rotate, scale, assign, shading)")
        shading = entry.get("shading", "smooth")
        if shading not in ("smooth", "flat"):
            raise SceneError(f"{where}.shading must be \"smooth\" or \"flat\", not {json.dumps(shading)}")
        scale = entry.get("scale", 1.0)
        if _number(scale):
            scale = [scale] * 3
        scale = _vector(scale, 3, f"{where}.scale")
        if np.any(scale == 0):
            raise SceneError(f"{where}.scale must not be zero")
        rotate = _vector(entry.get("rotate", [0, 0, 0]), 3, f"{where}.rotate")
        translate = _vector(entry.get("translate", [0, 0, 0]), 3, f"{where}.translate")
        assign = entry.get("assign", {})
        if not isinstance(assign, dict) or not all(isinstance(v, str) for v in assign.values()):
            raise SceneError(f"{where}.assign must map patterns to surface names")
        rules = []
        for pattern, surface in assign.items():
            if surface not in effect.surfaces:
                raise SceneError(f"{where}.assign: no surface '{surface}' in {effect.path}")
            rules.append((pattern, surface))
        for part in _file_parts(rt, path.parent / entry["file"], rules):
            verts = part.vertices if part.vertices is not None else np.asarray(part.mesh.vertices(), float)
            part.vertices = (verts * scale) @ _rotation(rotate).T + translate
            part.flat = shading == "flat"
            parts.append(part)
    return parts, down


@record
class _RuleUse(Record):
    """Which rules won some triangles, and for the others that matched some,
    the rule that beat them (its index, the name it matched)."""
    won: set = field(default_factory=set)
    beaten: dict = field(default_factory=dict)


def _bind(part: _Part, rules: list[tuple[str, str]], effect: Effect, use: _RuleUse | None = None) -> np.ndarray:
    """Surface index per triangle of one part; -1 where no rule matches."""
    m = part.mesh.num_triangles
    names = list(part.mesh.part_names())
    if m == 0:
        return np.zeros(0, np.int32)
    labels = np.stack([np.asarray(a, np.int64) for a in part.mesh.triangle_labels()], axis=1)
    keys, inverse = unique_rows(labels)
    chosen = np.full(len(keys), -1, np.int32)
    for k, key in enumerate(keys):
        candidates = [part.stem, *part.names] + [names[i] for i in key if i >= 0]
        winner = None
        for r, (pattern, surface) in enumerate(rules):
            matched = next((c for c in candidates if fnmatch.fnmatchcase(c, pattern)), None)
            if matched is None:
                continue
            if winner is None:
                winner = (r, matched)
                chosen[k] = effect.surfaces[surface].index
                if use is None:
                    break
                use.won.add(r)
            else:
                use.beaten.setdefault(r, winner)
    unbound = [k for k in range(len(keys)) if chosen[k] < 0]
    if unbound:
        described = []
        for k in unbound[:3]:
            kinds = ("object", "group", "material")
            named = [f"{kind} '{names[i]}'" for kind, i in zip(kinds, keys[k]) if i >= 0]
            described.append(" ".join(named) or "unnamed triangles")
        more = f" (and {len(unbound) - 3} more)" if len(unbound) > 3 else ""
        raise SceneError(f"no surface for {', '.join(described)}{more} of '{part.stem}': "
                         "add --assign PATTERN=SURFACE")
    return chosen[inverse.reshape(-1)]


def unique_rows(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(labels, axis=0, return_inverse=True)`` for int64 labels >= -1
    (object, group, material per triangle), sorted the same way: the rows as
    one mixed-radix number each, which sorts as the rows do, so a 1-D unique
    (a plain sort) does the work; ``np.unique`` with ``axis=0`` sorts rows as
    records, about 50 times slower on the bunny."""
    shifted = labels + 1
    bases = shifted.max(axis=0) + 1 if len(labels) else np.ones(labels.shape[1], np.int64)
    if labels.min(initial=0) < -1 or float(np.prod(bases.astype(float))) >= 2.0 ** 62:
        keys, inverse = np.unique(labels, axis=0, return_inverse=True)
        return keys, inverse.reshape(-1)
    number = np.zeros(len(labels), np.int64)
    for j in range(labels.shape[1]):
        number = number * bases[j] + shifted[:, j]
    values, inverse = np.unique(number, return_inverse=True)
    keys = np.empty((len(values), labels.shape[1]), np.int64)
    for j in range(labels.shape[1] - 1, -1, -1):
        keys[:, j] = values % bases[j] - 1
        values = values // bases[j]
    return keys, inverse.reshape(-1)


def _warn_shadowed(cli_rules: list[tuple[str, str]], use: _RuleUse) -> None:
    """A ``--assign`` rule that names some triangles but is beaten to every
    one of them by an earlier rule is a mistake a user does not see (the
    classic: ``arch=...`` also matches every part of ``arch.obj`` through the
    file name); say so, naming the rule that won."""
    for r, (pattern, surface) in enumerate(cli_rules):
        if r in use.won or r not in use.beaten:
            continue
        w, name = use.beaten[r]
        earlier = f"{cli_rules[w][0]}={cli_rules[w][1]}" if w < len(cli_rules) else "an earlier rule"
        print(f"gammac: warning: --assign {pattern}={surface} is never used: the triangles it matches "
              f"are taken by {earlier}, which matches the name '{name}'; give the narrower rule first",
              file=sys.stderr)


def arrays_scene(rt, vertices, faces, uvs, effect: Effect, assign: list[str], down=None,
                 name: str = "mesh") -> Scene:
    """A scene of one mesh given as arrays: vertices (n, 3), faces (m, 3) and
    optionally texture coordinates per vertex (n, 2) or per corner (m, 3, 2)."""
    verts = np.asarray(vertices, np.float32)
    tris = np.asarray(faces, np.int32)
    corner_uvs = None
    if uvs is not None:
        uvs = np.asarray(uvs, np.float32)
        corner_uvs = uvs[tris] if uvs.ndim == 2 else uvs
    try:
        mesh = rt.Mesh.from_arrays(verts, tris, corner_uvs)
    except (ValueError, RuntimeError, TypeError) as err:
        raise SceneError(str(err)) from None
    return load_scene(rt, name, effect, assign, down, parts=[_Part(mesh, name, [])])


def load_scene(rt, path: str, effect: Effect, assign: list[str], down=None, parts=None) -> Scene:
    """The scene of ``path`` (or of ``parts`` already loaded, ``path`` then only names it)."""
    cli_rules = parse_assign(assign, effect)
    file_rules = list(effect.assign)       # the effect's own `assign` declarations come last
    if not cli_rules and not file_rules and len(effect.surfaces) == 1:
        file_rules = [("*", next(iter(effect.surfaces)))]
    scene_path = Path(path)
    if parts is not None:
        file_down = None
    elif scene_path.suffix.lower() == ".json":
        parts, file_down = _read_scene_file(rt, scene_path, effect)
    else:
        parts, file_down = _file_parts(rt, scene_path), None
    down = tuple(down) if down is not None else file_down or (0.0, -1.0, 0.0)
    if not any(down):
        raise SceneError("the down direction must not be the zero vector")
    use = _RuleUse()
    surface_of = [_bind(p, cli_rules + p.rules + file_rules, effect, use) for p in parts]
    _warn_shadowed(cli_rules, use)
    if len(parts) == 1 and parts[0].vertices is None:
        mesh = parts[0].mesh
    else:
        verts, tris, base = [], [], 0
        for p in parts:
            verts.append(p.vertices)
            tris.append(np.asarray(p.mesh.triangles(), np.int64) + base)
            base += len(p.vertices)
        # each part keeps its texture coordinates; those without get (0, 0), and a warning
        uvs = (np.concatenate([np.asarray(p.mesh.triangle_uvs(), np.float32) for p in parts])
               if any(p.mesh.has_uvs for p in parts) else None)
        bare = [p.stem for p in parts if not p.mesh.has_uvs]
        if uvs is not None and bare:
            import sys

            print(f"gammac: warning: {len(bare)} part{'s' if len(bare) != 1 else ''} of '{path}' "
                  f"without texture coordinates ({', '.join(bare[:8])}{', ...' if len(bare) > 8 else ''}): "
                  "texture() reads (0, 0) there and export makes them an atlas", file=sys.stderr)
        try:
            mesh = rt.Mesh.from_arrays(np.concatenate(verts).astype(np.float32),
                                       np.concatenate(tris).astype(np.int32), uvs)
        except (ValueError, RuntimeError) as err:
            raise SceneError(f"scene '{path}': {err}") from None
    surface = np.concatenate(surface_of).astype(np.int32)
    has_uv = np.concatenate([np.full(p.mesh.num_triangles, p.mesh.has_uvs) for p in parts])
    if effect.mask_uses:
        from .mask_atlas import LayoutError, with_atlas

        try:
            mesh = with_atlas(rt, mesh, has_uv, effect)
        except (LayoutError, ValueError, RuntimeError) as err:
            raise SceneError(f"scene '{path}': {err}") from None
    if len(surface) != mesh.num_triangles:
        # from_arrays drops triangles that became degenerate under the transform
        raise SceneError(f"scene '{path}': {len(surface) - mesh.num_triangles} triangles "
                         "became degenerate after scaling")
    counts = {name: int(np.sum(surface == s.index)) for name, s in effect.surfaces.items()}
    objects, names = _objects(parts)
    flat = np.concatenate([np.full(p.mesh.num_triangles, p.flat) for p in parts])
    materials = [p.material for p in parts if p.material is not None]
    numbered = iter(range(len(materials)))
    triangle_material = np.concatenate([np.full(p.mesh.num_triangles, -1 if p.material is None else next(numbered),
                                                 np.int32) for p in parts])
    scene = Scene(mesh, surface, down, mesh.bounds, counts, objects, names, has_uv, flat,
                  triangle_material, materials)
    if any(item.kind == "attribute" for item in effect.inputs):
        from .vertex_attributes import scene_attributes

        scene.vertex_attributes, scene.part_attribute_names = scene_attributes(parts, mesh.num_vertices)
    problem = scene_size_problem(scene.diagonal)
    if problem:
        raise SceneError(f"scene '{path}': {problem}")
    return scene


def _objects(parts: list[_Part]) -> tuple[np.ndarray, list[str]]:
    """Which object each triangle belongs to: its OBJ object, else its group,
    else its mesh file's name (prefixed by the file's name when several meshes)."""
    names: list[str] = []
    index: dict[str, int] = {}
    out = []
    for part in parts:
        labels = list(part.mesh.part_names())
        objs, groups, _ = (np.asarray(a, np.int64) for a in part.mesh.triangle_labels())
        chosen = np.where(objs >= 0, objs, groups)
        keys, inverse = np.unique(chosen, return_inverse=True)
        lut = []
        for key in keys:
            name = part.stem if key < 0 else labels[key]
            if len(parts) > 1 and key >= 0:
                name = f"{part.stem}.{name}"
            if name not in index:
                index[name] = len(names)
                names.append(name)
            lut.append(index[name])
        out.append(np.asarray(lut, np.int32)[inverse.reshape(-1)] if len(chosen) else np.zeros(0, np.int32))
    return np.concatenate(out), names
