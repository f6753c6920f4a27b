"""glTF 2.0 scenes in (``.gltf``, ``.glb``), read with trimesh.

Every node that draws a mesh becomes one part: its vertices in world space
(the node's full transform applied), its triangles, its texture coordinates
per triangle corner (when the primitive has ``TEXCOORD_0``) and its
material's base colour (texture as float RGB in [0, 1], and factor).  The
part answers to its node name, its mesh name and its material name in
``--assign`` patterns.  The file is checked first (``gltf_check.py``), so
a malformed one is a one-line error naming it, never a trimesh exception.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .gltf_check import MAX_TEXTURE_SIDE, GltfError, check_gltf

GLTF_SUFFIXES = (".gltf", ".glb")


@dataclass
class Material:
    """A glTF part's material as the renders and exports use it: base colour
    (factor times texture), roughness and metallic (factors times the
    metallic-roughness texture's green and blue), and its normal map."""

    name: str | None
    base_factor: tuple[float, float, float] = (1.0, 1.0, 1.0)
    base_colour: np.ndarray | None = None      # float32 (h, w, 3) display values
    roughness: float = 1.0                     # glTF's defaults
    metallic: float = 1.0
    rough_metal: np.ndarray | None = None      # float32 (h, w, 3): roughness in G, metallic in B
    normal_map: np.ndarray | None = None       # float32 (h, w, 3): tangent-space normals as stored


@dataclass
class GltfPart:
    node: str
    mesh: str
    material: str | None
    vertices: np.ndarray               # float32 (n, 3), world space
    faces: np.ndarray                  # int32 (m, 3)
    uvs: np.ndarray | None             # float32 (m, 3, 2), OBJ convention (v up), or None
    look: Material | None = None       # None: the part has no material
    attributes: dict = None            # vertex attributes: "_WET" as "WET", COLOR_0 as "COLOR_0.r" ... (float32)


def is_gltf(path: str | Path) -> bool:
    return Path(path).suffix.lower() in GLTF_SUFFIXES


def read_gltf(path: str | Path) -> list[GltfPart]:
    import trimesh

    path = Path(path)
    check_gltf(path)
    try:
        scene = trimesh.load(str(path), force="scene", process=False)
    except Exception as err:   # trimesh raises many kinds for a bad file
        raise GltfError(f"cannot read glTF '{path}': {err or type(err).__name__}") from None
    with np.errstate(all="ignore"):    # a non-finite vertex is refused by Mesh.from_arrays, by number
        return _parts(path, scene, trimesh)


def _parts(path: Path, scene, trimesh) -> list[GltfPart]:
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        geometry = scene.geometry[geometry_name]
        if not isinstance(geometry, trimesh.Trimesh) or len(geometry.faces) == 0:
            continue                                   # points and lines: nothing to weather
        verts = np.asarray(geometry.vertices, np.float64)
        world = verts @ np.asarray(transform[:3, :3], np.float64).T + np.asarray(transform[:3, 3], np.float64)
        faces = np.asarray(geometry.faces, np.int64)
        if np.linalg.det(np.asarray(transform[:3, :3], float)) < 0:
            faces = faces[:, ::-1]                     # a mirroring transform flips the winding back
        visual = geometry.visual
        uv = getattr(visual, "uv", None)
        uvs = np.asarray(uv, np.float32)[faces] if uv is not None and len(uv) == len(verts) else None
        material = getattr(visual, "material", None)
        try:
            look = _material(material) if material is not None else None
        except GltfError as err:
            raise GltfError(f"glTF '{path}', node '{node}': {err}") from None
        parts.append(GltfPart(str(node), str(geometry_name), getattr(material, "name", None),
                              world.astype(np.float32), faces.astype(np.int32), uvs, look,
                              _vertex_attributes(geometry, len(verts))))
    if not parts:
        raise GltfError(f"glTF '{path}' has no triangle mesh")
    return parts


def _vertex_attributes(geometry, count: int) -> dict:
    """A primitive's per-vertex attributes for attribute() (SPEC §12a):
    application-specific ones (``_WET``: "WET") and COLOR_0 by channel."""
    found = {}
    for name, values in getattr(geometry, "vertex_attributes", {}).items():
        values = np.asarray(values, np.float32)
        if len(values) != count:
            continue
        if values.ndim == 1 or values.shape[1] == 1:
            found[name.lstrip("_")] = values.reshape(-1)
        else:
            for c in range(values.shape[1]):
                found[f"{name.lstrip('_')}.{'xyzw'[c] if c < 4 else c}"] = values[:, c]
    visual = geometry.visual
    colours = visual.vertex_colors if getattr(visual, "kind", None) == "vertex" else None
    if colours is not None and len(colours) == count:
        colours = np.asarray(colours, np.float32) / 255.0
        for c, channel in enumerate("rgba"[:colours.shape[1]]):
            found[f"COLOR_0.{channel}"] = colours[:, c]
    return found


def _material(material) -> Material:
    """A trimesh material (PBRMaterial, or SimpleMaterial for old files) as a Material."""
    factor = getattr(material, "baseColorFactor", None)
    rgb = (1.0, 1.0, 1.0)
    if factor is not None:
        f = np.asarray(factor, float).reshape(-1)
        scale = 255.0 if f.dtype.kind in "iu" or f.max() > 1.0 else 1.0
        rgb = tuple(float(c) / scale for c in f[:3])
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        image = getattr(material, "image", None)      # trimesh's SimpleMaterial
    look = Material(getattr(material, "name", None), rgb, _image(image, "base-colour"))
    for name in ("roughness", "metallic"):
        value = getattr(material, f"{name}Factor", None)
        if value is not None:
            if not (np.isfinite(value) and 0.0 <= float(value) <= 1.0):
                raise GltfError(f"its {name}Factor {value} is outside [0, 1]")
            setattr(look, name, float(value))
    look.rough_metal = _image(getattr(material, "metallicRoughnessTexture", None), "metallic-roughness")
    look.normal_map = _image(getattr(material, "normalTexture", None), "normal")
    return look


def _image(image, what: str) -> np.ndarray | None:
    """A material's PIL image as float32 (h, w, 3) in [0, 1], checked for size."""
    if image is None:
        return None
    width, height = image.size
    if width * height > MAX_TEXTURE_PIXELS:
        raise GltfError(f"a {what} texture of {width} x {height} pixels is larger than "
                        f"{MAX_TEXTURE_SIDE} x {MAX_TEXTURE_SIDE}")
    try:
        return np.asarray(image.convert("RGB"), np.float32) / 255.0
    except (OSError, ValueError) as err:
        raise GltfError(f"a {what} texture cannot be decoded ({err})") from None


#: The largest base-colour texture read (as for texture() in effects, SPEC §8a;
#: MAX_TEXTURE_SIDE lives in gltf_check.py, which checks the image headers).
MAX_TEXTURE_PIXELS = MAX_TEXTURE_SIDE * MAX_TEXTURE_SIDE
