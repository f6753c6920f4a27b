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
class GltfPart:
    node: str
    mesh: str
    material: str | None
    vertices: np.ndarray               # float32 (n, 3), world space
    faces: np.ndarray                  # int32 (m, 3)
    uvs: np.ndarray | None             # float32 (m, 3, 2), OBJ convention (v up), or None
    base_colour: np.ndarray | None     # float32 (h, w, 3) display values, or None
    base_factor: tuple[float, float, float] = (1.0, 1.0, 1.0)
    has_material: bool = False


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
            image, factor = _base_colour(material)
        except GltfError as err:
            raise GltfError(f"glTF '{path}', node '{node}': {err}") from None
        parts.append(GltfPart(str(node), str(geometry_name), getattr(material, "name", None),
                              world.astype(np.float32), faces.astype(np.int32), uvs, image, factor,
                              material is not None))
    if not parts:
        raise GltfError(f"glTF '{path}' has no triangle mesh")
    return parts


def _base_colour(material):
    """(texture as float32 [h, w, 3] or None, RGB factor) of a glTF material."""
    if material is None:
        return None, (1.0, 1.0, 1.0)
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        image = getattr(material, "image", None)      # trimesh's SimpleMaterial
    factor = getattr(material, "baseColorFactor", None)
    rgb = (1.0, 1.0, 1.0)
    if factor is not None:
        f = np.asarray(factor, float).reshape(-1)
        scale = 255.0 if f.dtype.kind in "iu" or f.max() > 1.0 else 1.0
        rgb = tuple(float(c) / scale for c in f[:3])
    if image is not None:
        width, height = image.size
        if width * height > MAX_TEXTURE_PIXELS:
            raise GltfError(f"a base-colour texture of {width} x {height} pixels is larger than "
                            f"{MAX_TEXTURE_SIDE} x {MAX_TEXTURE_SIDE}")
        try:
            image = np.asarray(image.convert("RGB"), np.float32) / 255.0
        except (OSError, ValueError) as err:
            raise GltfError(f"a base-colour texture cannot be decoded ({err})") from None
    return image, rgb


#: The largest base-colour texture read (as for texture() in effects, SPEC §8a;
#: MAX_TEXTURE_SIDE lives in gltf_check.py, which checks the image headers).
MAX_TEXTURE_PIXELS = MAX_TEXTURE_SIDE * MAX_TEXTURE_SIDE
