"""Baking and export: the weathered scene as files artists open elsewhere.

- ``bake``: for a mesh with texture coordinates, every texel of a square
  texture is mapped back to its point on the surface (triangles rasterised
  in UV space), where the runtime gives the smoothed surfel row and the
  appearance colour (``Simulation.bake_points``, the renderer's own code).
  Empty texels next to filled ones are filled from their neighbours a few
  times over ("seam bleeding"), so mip-mapping shows no dark seams.
- ``write_glb``: glTF 2.0 binary with positions, normals, texture
  coordinates, the appearance colour per vertex (``COLOR_0``), one float
  attribute per surface property (``_PROPERTYNAME``, the glTF convention
  for application-specific attributes) and, when baked, the colour texture
  as the material's base colour.

Meshes without texture coordinates are exported with per-vertex data only
(generating an atlas, e.g. with xatlas, is not part of this version).
"""

from __future__ import annotations

import io
import json
import struct

import numpy as np

BLEED_PASSES = 8


def weld(mesh):
    """One glTF vertex per distinct (mesh vertex, uv) pair: returns
    (vertex index per new vertex, uv per new vertex or None, triangles)."""
    tris = np.asarray(mesh.triangles(), np.int64)
    if not mesh.has_uvs:
        return np.arange(mesh.num_vertices), None, tris
    uvs = np.asarray(mesh.triangle_uvs(), np.float32).reshape(-1, 2)
    corners = np.column_stack([tris.reshape(-1).astype(np.float64), uvs.astype(np.float64)])
    keys, inverse = np.unique(corners, axis=0, return_inverse=True)
    return keys[:, 0].astype(np.int64), keys[:, 1:].astype(np.float32), inverse.reshape(-1, 3)


def vertex_normals(positions: np.ndarray, tris: np.ndarray) -> np.ndarray:
    a, b, c = positions[tris[:, 0]], positions[tris[:, 1]], positions[tris[:, 2]]
    face = np.cross(b - a, c - a)                      # area-weighted
    normals = np.zeros_like(positions)
    for k in range(3):
        np.add.at(normals, tris[:, k], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.where(length > 0, length, 1)).astype(np.float32)


def vertex_data(sim, mesh, iteration: int, threads: int):
    """Welded vertices with positions, normals, uvs, rows and colours."""
    source, uvs, tris = weld(mesh)
    verts = np.asarray(mesh.vertices(), np.float32)
    positions = verts[source]
    normals = vertex_normals(positions.astype(np.float64), tris)
    owner = np.zeros(len(positions), np.int32)         # a triangle each vertex belongs to
    owner[tris.reshape(-1)] = np.repeat(np.arange(len(tris), dtype=np.int32), 3)
    point_uvs = uvs if uvs is not None else np.zeros((len(positions), 2), np.float32)
    rows, rgb = sim.bake_points(positions, normals, owner, point_uvs, iteration, threads)
    return positions, normals, uvs, tris.astype(np.uint32), rows, rgb, owner


def rasterise_uv(mesh, size: int):
    """Texels covered by triangles in UV space: (texel index, triangle, barycentrics)."""
    uvs = np.asarray(mesh.triangle_uvs(), np.float64)
    texel_idx, tri_idx, bary = [], [], []
    for t, corner in enumerate(uvs):
        # texel (i, j) has its centre at u = (j + 0.5)/size, v = 1 - (i + 0.5)/size
        x, y = corner[:, 0] * size - 0.5, (1 - corner[:, 1]) * size - 0.5
        j0, j1 = int(np.floor(x.min())), int(np.ceil(x.max()))
        i0, i1 = int(np.floor(y.min())), int(np.ceil(y.max()))
        jj, ii = np.meshgrid(np.arange(max(j0, 0), min(j1, size - 1) + 1),
                             np.arange(max(i0, 0), min(i1, size - 1) + 1))
        if jj.size == 0:
            continue
        px, py = jj.reshape(-1).astype(float), ii.reshape(-1).astype(float)
        (xa, xb, xc), (ya, yb, yc) = x, y
        det = (yb - yc) * (xa - xc) + (xc - xb) * (ya - yc)
        if abs(det) < 1e-18:
            continue
        l1 = ((yb - yc) * (px - xc) + (xc - xb) * (py - yc)) / det
        l2 = ((yc - ya) * (px - xc) + (xa - xc) * (py - yc)) / det
        l3 = 1 - l1 - l2
        inside = (l1 >= -1e-9) & (l2 >= -1e-9) & (l3 >= -1e-9)
        if not inside.any():
            continue
        texel_idx.append((ii.reshape(-1) * size + jj.reshape(-1))[inside])
        tri_idx.append(np.full(int(inside.sum()), t, np.int32))
        bary.append(np.column_stack([l1, l2, l3])[inside])
    if not texel_idx:
        return np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 3))
    texels, first = np.unique(np.concatenate(texel_idx), return_index=True)  # one triangle per texel
    return texels, np.concatenate(tri_idx)[first], np.concatenate(bary)[first]


def bleed(image: np.ndarray, filled: np.ndarray, passes: int = BLEED_PASSES) -> np.ndarray:
    """Fill empty texels from the mean of their filled 4-neighbours, ``passes`` rings deep."""
    image, filled = image.copy(), filled.copy()
    for _ in range(passes):
        total = np.zeros_like(image, dtype=np.float64)
        count = np.zeros(filled.shape, np.float64)
        for axis, shift in ((0, 1), (0, -1), (1, 1), (1, -1)):
            moved = np.roll(filled, shift, axis=axis)
            total += np.roll(image, shift, axis=axis) * moved[..., None]
            count += moved
        grow = ~filled & (count > 0)
        if not grow.any():
            break
        image[grow] = (total[grow] / count[grow][:, None]).astype(image.dtype)
        filled = filled | grow
    return image


def bake(sim, mesh, size: int, iteration: int, threads: int):
    """(colour float32[size, size, 3], rows float32[size, size, W], covered mask)."""
    texels, tris, bary = rasterise_uv(mesh, size)
    verts = np.asarray(mesh.vertices(), np.float64)
    corner = verts[np.asarray(mesh.triangles(), np.int64)[tris]]        # (k, 3, 3)
    positions = np.einsum("kc,kcd->kd", bary, corner).astype(np.float32)
    face = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    normals = (face / np.linalg.norm(face, axis=1, keepdims=True)).astype(np.float32)
    uv = np.einsum("kc,kcd->kd", bary, np.asarray(mesh.triangle_uvs(), np.float64)[tris]).astype(np.float32)
    rows, rgb = sim.bake_points(positions, normals, tris.astype(np.int32), uv, iteration, threads)
    width = rows.shape[1] if rows.ndim == 2 and rows.size else sim.row_width
    colour = np.zeros((size * size, 3), np.float32)
    values = np.zeros((size * size, width), np.float32)
    covered = np.zeros(size * size, bool)
    colour[texels], values[texels], covered[texels] = rgb, rows, True
    shape = (size, size)
    covered = covered.reshape(shape)
    return (bleed(colour.reshape(*shape, 3), covered), bleed(values.reshape(*shape, width), covered), covered)


def png8(rgb: np.ndarray) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)).save(out, format="PNG")
    return out.getvalue()


def png16(values: np.ndarray) -> tuple[bytes, float, float]:
    """A property as a 16-bit grey PNG, 0..65535 spanning [low, high] (returned)."""
    from PIL import Image

    finite = values[np.isfinite(values)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    scale = 65535.0 / (high - low) if high > low else 0.0
    grey = np.clip(np.nan_to_num((values - low) * scale), 0, 65535).astype(np.uint16)
    out = io.BytesIO()
    Image.fromarray(grey).save(out, format="PNG")  # uint16 -> 16-bit grey
    return out.getvalue(), low, high


def write_glb(positions, normals, uvs, triangles, colours, attributes: dict,
              texture_png: bytes | None = None, extras: dict | None = None) -> bytes:
    """glTF 2.0 binary (.glb) of one triangle mesh."""
    chunks, views, accessors = [], [], []

    def add(data: bytes, target: int | None = None) -> int:
        offset = sum(len(c) for c in chunks)
        chunks.append(data + b"\0" * (-len(data) % 4))
        view = {"buffer": 0, "byteOffset": offset, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        views.append(view)
        return len(views) - 1

    def accessor(array: np.ndarray, kind: str, component: int, target: int, bounds=False) -> int:
        view = add(np.ascontiguousarray(array).tobytes(), target)
        acc = {"bufferView": view, "componentType": component, "count": int(len(array)), "type": kind}
        if bounds:
            acc["min"] = [float(v) for v in array.min(axis=0)]
            acc["max"] = [float(v) for v in array.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    FLOAT, UINT = 5126, 5125
    ARRAY, ELEMENTS = 34962, 34963
    attrs = {"POSITION": accessor(positions.astype(np.float32), "VEC3", FLOAT, ARRAY, bounds=True),
             "NORMAL": accessor(normals.astype(np.float32), "VEC3", FLOAT, ARRAY),
             "COLOR_0": accessor(colours.astype(np.float32), "VEC3", FLOAT, ARRAY)}
    if uvs is not None:
        # glTF's v runs downward from the top of the image
        flipped = np.column_stack([uvs[:, 0], 1.0 - uvs[:, 1]]).astype(np.float32)
        attrs["TEXCOORD_0"] = accessor(flipped, "VEC2", FLOAT, ARRAY)
    for name, values in attributes.items():
        attrs["_" + name.upper()] = accessor(values.astype(np.float32).reshape(-1, 1), "SCALAR",
                                             FLOAT, ARRAY, bounds=True)
    indices = accessor(triangles.astype(np.uint32).reshape(-1), "SCALAR", UINT, ELEMENTS)
    material = {"name": "weathered", "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 0.8}}
    doc = {"asset": {"version": "2.0", "generator": "gamma"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": attrs, "indices": indices, "material": 0}]}],
           "materials": [material], "accessors": accessors}
    if texture_png is not None:
        doc["images"] = [{"bufferView": add(texture_png), "mimeType": "image/png"}]
        doc["samplers"] = [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]
        doc["textures"] = [{"sampler": 0, "source": 0}]
        material["pbrMetallicRoughness"]["baseColorTexture"] = {"index": 0}
    if extras:
        doc["extras"] = extras
    doc["bufferViews"] = views
    binary = b"".join(chunks)
    doc["buffers"] = [{"byteLength": len(binary)}]
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(text), 0x4E4F534A) + text
            + struct.pack("<II", len(binary), 0x004E4942) + binary)


def write_obj(positions, normals, uvs, triangles, material_name: str | None) -> bytes:
    """Wavefront OBJ of the welded mesh (indices shared by v, vt and vn)."""
    lines = ["# exported by gamma"]
    if material_name:
        lines += [f"mtllib {material_name}.mtl", f"usemtl {material_name}"]
    lines += [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in positions]
    lines += [f"vn {x:.7g} {y:.7g} {z:.7g}" for x, y, z in normals]
    if uvs is not None:
        lines += [f"vt {u:.7g} {v:.7g}" for u, v in uvs]
        lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in triangles + 1]
    else:
        lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in triangles + 1]
    return ("\n".join(lines) + "\n").encode("ascii")
