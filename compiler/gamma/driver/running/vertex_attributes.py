"""Per-vertex attributes of the scene's meshes, for ``attribute("NAME")``
(SPEC §12a): PLY vertex properties, glTF application-specific attributes
(``_WETNESS`` read as "WETNESS") and COLOR_0, OBJ vertex colours
(``v x y z r g b``).  Colours are read as ``COLOR_0.r`` ... ``COLOR_0.a``
in [0, 1], whatever the file's format.

Read only when the effect asks for an attribute: the files are read a second
time for it (the runtime's mesh readers keep positions, faces and texture
coordinates only), in the same vertex order (a test checks it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: PLY vertex properties that are geometry, not attributes.
_PLY_GEOMETRY = {"x", "y", "z", "nx", "ny", "nz", "u", "v", "s", "t", "texture_u", "texture_v"}
_PLY_COLOURS = {"red": "r", "green": "g", "blue": "b", "alpha": "a"}


def _obj_colours(path: Path, count: int) -> dict:
    """``v x y z r g b`` lines: COLOR_0.r/g/b (every vertex must have them)."""
    rows = []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.startswith("v ") or line.startswith("v\t"):
                rows.append(line.split()[1:])
    if len(rows) != count or not rows or any(len(r) != 6 for r in rows):
        return {}
    try:
        colours = np.asarray([r[3:] for r in rows], np.float64).astype(np.float32)
    except ValueError:
        return {}
    return {f"COLOR_0.{c}": colours[:, i] for i, c in enumerate("rgb")}


def _ply_properties(path: Path, count: int) -> dict:
    """Every vertex property of a PLY file but the geometry, as float32."""
    import trimesh

    try:
        mesh = trimesh.load(str(path), process=False)
        data = mesh.metadata["_ply_raw"]["vertex"]["data"]
    except Exception:       # a file the runtime read but trimesh cannot: no attributes, said by the checks
        return {}
    if not isinstance(data, dict):      # binary files: a structured array
        data = {name: data[name] for name in data.dtype.names}
    found = {}
    for name, values in data.items():
        values = np.asarray(values).reshape(len(values), -1)
        if name in _PLY_GEOMETRY or len(values) != count or values.shape[1] != 1:
            continue
        column = values[:, 0].astype(np.float32)
        found[name] = column
        if name in _PLY_COLOURS:
            scale = 255.0 if np.issubdtype(values.dtype, np.integer) else 1.0
            found[f"COLOR_0.{_PLY_COLOURS[name]}"] = (values[:, 0].astype(np.float64) / scale).astype(np.float32)
    return found


def part_attributes(part) -> dict:
    """{name: float32 per vertex of the part} for one scene part."""
    if part.attributes is not None:
        return part.attributes
    if part.source is None:
        return {}
    count = part.mesh.num_vertices
    suffix = part.source.suffix.lower()
    if suffix == ".obj":
        return _obj_colours(part.source, count)
    if suffix == ".ply":
        return _ply_properties(part.source, count)
    return {}


def scene_attributes(parts, num_vertices: int) -> tuple[dict, dict]:
    """Every part's attributes over the scene's vertices (parts in order,
    their vertices one after the other, as the scene's mesh has them):
    ({lower-case name: (values, present)}, {part name: [names]})."""
    table: dict = {}
    names_of: dict = {}
    base = 0
    for part in parts:
        count = part.mesh.num_vertices
        found = part_attributes(part)
        names_of[part.stem] = sorted(found)
        for name, values in found.items():
            key = name.lower()
            if key not in table:
                table[key] = (np.zeros(num_vertices, np.float32), np.zeros(num_vertices, bool))
            table[key][0][base:base + count] = values
            table[key][1][base:base + count] = True
        base += count
    return table, names_of


def at_surfels(values: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, surfel_triangle: np.ndarray,
               positions: np.ndarray) -> np.ndarray:
    """A per-vertex value interpolated (barycentric) at each surfel's position
    in its triangle."""
    tri = triangles[surfel_triangle]
    a, b, c = (vertices[tri[:, k]].astype(np.float64) for k in range(3))
    p = positions.astype(np.float64)
    e1, e2, d = b - a, c - a, p - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    d1, d2 = (d * e1).sum(1), (d * e2).sum(1)
    det = d11 * d22 - d12 * d12
    safe = np.where(det > 0, det, 1.0)
    v = np.clip(np.where(det > 0, (d22 * d1 - d12 * d2) / safe, 0.0), 0.0, 1.0)
    w = np.clip(np.where(det > 0, (d11 * d2 - d12 * d1) / safe, 0.0), 0.0, 1.0)
    total = v + w
    over = total > 1.0
    v, w = np.where(over, v / total, v), np.where(over, w / total, w)
    u = 1.0 - v - w
    f = values.astype(np.float64)
    return (u * f[tri[:, 0]] + v * f[tri[:, 1]] + w * f[tri[:, 2]]).astype(np.float32)
