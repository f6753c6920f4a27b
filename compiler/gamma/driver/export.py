"""Baking and export: the weathered scene as files artists open elsewhere.

- ``bake``: for a mesh with texture coordinates, every texel of a square
  texture is mapped back to its point on the surface (triangles rasterised
  in UV space), where the runtime gives the smoothed surfel row and the
  appearance colour (``Simulation.bake_points``, the renderer's own code).
  Empty texels next to filled ones are filled from their neighbours a few
  times over ("seam bleeding"), so mip-mapping shows no dark seams.
- ``write_glb``: glTF 2.0 binary with positions, normals, texture
  coordinates, one float attribute per surface property (``_PROPERTYNAME``,
  the glTF convention for application-specific attributes) and the
  appearance colour: as the material's base-colour texture when baked, else
  per vertex (``COLOR_0``) — never both, since viewers multiply them.

Every object of the scene (``pieces``: OBJ object, else group, else mesh
file) is exported on its own.  Objects without texture coordinates get a
cell atlas (``cell_atlas``: two triangles per square cell); it only places
texels: texture() lookups in appearance blocks still see the mesh's own
coordinates (none: (0, 0)), as in the renders.
"""

from __future__ import annotations

import io
import json
import struct
from dataclasses import dataclass

import numpy as np

BLEED_PASSES = 8


@dataclass
class Piece:
    """One object of the scene, exported on its own."""

    name: str
    triangles: np.ndarray        # the scene's triangle numbers (for the runtime)
    vertices: np.ndarray         # float32 (n, 3), this object's only
    faces: np.ndarray            # (m, 3) indices into vertices
    own_uvs: np.ndarray | None   # the mesh's texture coordinates (m, 3, 2), for texture() lookups
    layout: np.ndarray           # (m, 3, 2) where each triangle lies in the baked textures


def pieces(scene, size: int = 1024) -> list[Piece]:
    """The scene split into its objects, each with a texture layout: the mesh's
    own coordinates, else a cell atlas for a ``size``² texture."""
    mesh = scene.mesh
    verts = np.asarray(mesh.vertices(), np.float32)
    tris = np.asarray(mesh.triangles(), np.int64)
    uvs = np.asarray(mesh.triangle_uvs(), np.float32) if mesh.has_uvs else None
    out = []
    for k, name in enumerate(scene.object_names):
        ids = np.flatnonzero(scene.triangle_object == k)
        if not len(ids):
            continue
        used, faces = np.unique(tris[ids], return_inverse=True)
        faces = faces.reshape(-1, 3)
        has_uv = getattr(scene, "triangle_has_uv", None)
        own = uvs[ids] if uvs is not None and (has_uv is None or has_uv[ids].all()) else None
        layout = own if own is not None else cell_atlas(len(faces), size)
        out.append(Piece(name, ids, verts[used], faces, own, layout))
    return out


def cell_atlas(triangles: int, size: int) -> np.ndarray:
    """Texture coordinates per triangle corner (m, 3, 2): two triangles per
    square cell of a grid over the texture (one in each half, a texel of
    gutter around each), every triangle the same shape in the texture.

    A chart atlas (xatlas) keeps neighbours together but takes minutes on a
    100k-triangle mesh; the weathering varies on the scale of the surfels,
    which are about as many as the triangles, so a few texels per triangle
    hold what there is to see.  Cells are whole texels wide, so a texel
    never straddles two cells."""
    cells = max(1, (triangles + 1) // 2)
    grid = int(np.ceil(np.sqrt(cells)))
    width = size // grid if size >= grid else size / grid   # texels per cell side
    if width < 4:
        import sys

        print(f"gammac: warning: a {size}² texture gives each of the {triangles:,} triangles of an "
              f"object without texture coordinates under 2 texels; try --bake-size {grid * 4}",
              file=sys.stderr)
    k = np.arange(triangles)
    cell = k // 2
    x0 = (cell % grid) * width
    y0 = (cell // grid) * width
    first = (k % 2 == 0)                               # the upper-left half, else the lower-right
    # corners in texel units inside the cell (y down): a texel of gutter at the
    # cell's sides, half a texel on each side of the diagonal
    pad = 1.0 if width >= 4 else 0.0
    gap = 0.5 if width >= 2 else 0.0                   # too small a texture: a cell's texel to its first
    far, near = width - pad, pad + gap
    a = np.where(first[:, None], [pad, pad], [far, far])
    b = np.where(first[:, None], [width - near, pad], [near, far])
    c = np.where(first[:, None], [pad, width - near], [far, near])
    corners = np.stack([a, b, c], axis=1) + np.stack([x0, y0], axis=1)[:, None, :]
    u = corners[..., 0] / size
    v = 1.0 - corners[..., 1] / size                   # texture v runs up
    return np.stack([u, v], axis=-1).astype(np.float32)


def weld(piece: Piece):
    """One glTF vertex per distinct (vertex, uv) pair: returns
    (vertex index per new vertex, uv per new vertex, triangles)."""
    uvs = np.asarray(piece.layout, np.float32).reshape(-1, 2)
    corners = np.column_stack([piece.faces.reshape(-1).astype(np.float64), uvs.astype(np.float64)])
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


def vertex_data(sim, piece: Piece, iteration: int, threads: int):
    """Welded vertices: positions, normals, uvs, triangles, rows, colours and
    the scene triangle each vertex was evaluated on."""
    source, uvs, tris = weld(piece)
    positions = piece.vertices[source]
    normals = vertex_normals(positions.astype(np.float64), tris)
    local = np.zeros(len(positions), np.int64)         # a triangle each vertex belongs to
    local[tris.reshape(-1)] = np.repeat(np.arange(len(tris)), 3)
    owner = piece.triangles[local].astype(np.int32)
    if piece.own_uvs is not None:                      # texture() sees the mesh's coordinates
        corner = np.zeros((len(positions), 2), np.float32)
        corner[tris.reshape(-1)] = piece.own_uvs.reshape(-1, 2)
        lookup = corner
    else:
        lookup = np.zeros((len(positions), 2), np.float32)
    rows, rgb = sim.bake_points(positions, normals, owner, lookup, iteration, threads)
    return positions, normals, uvs, tris.astype(np.uint32), rows, rgb, owner


def rasterise_uv(corner_uvs: np.ndarray, size: int, chunk: int = 1 << 22):
    """Texels covered by triangles in UV space: (texel index, triangle, barycentrics).

    Texel (i, j) has its centre at u = (j + 0.5)/size, v = 1 - (i + 0.5)/size; a
    texel inside several triangles goes to the lowest-numbered one.  Vectorised
    over all triangles: every texel of every triangle's bounding box is tested
    at once (in chunks of about ``chunk`` candidates)."""
    uvs = np.asarray(corner_uvs, np.float64).reshape(-1, 3, 2)
    x = uvs[:, :, 0] * size - 0.5
    y = (1 - uvs[:, :, 1]) * size - 0.5
    j0 = np.clip(np.floor(x.min(axis=1)), 0, size - 1).astype(np.int64)
    j1 = np.clip(np.ceil(x.max(axis=1)), 0, size - 1).astype(np.int64)
    i0 = np.clip(np.floor(y.min(axis=1)), 0, size - 1).astype(np.int64)
    i1 = np.clip(np.ceil(y.max(axis=1)), 0, size - 1).astype(np.int64)
    (xa, xb, xc), (ya, yb, yc) = x.T, y.T
    det = (yb - yc) * (xa - xc) + (xc - xb) * (ya - yc)
    width, height = j1 - j0 + 1, i1 - i0 + 1
    count = np.where(np.abs(det) < 1e-18, 0, width * height)
    texel_idx, tri_idx, bary = [], [], []
    ends = np.cumsum(count)
    first = 0
    while first < len(count):
        # triangles [first, last) give at most about `chunk` candidate texels
        start_total = ends[first] - count[first]
        last = int(np.searchsorted(ends, start_total + chunk, side="right"))
        last = max(last, first + 1)
        tris = np.arange(first, last)
        n = count[tris]
        t = np.repeat(tris, n)
        k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)   # position inside the box
        jj = j0[t] + k % width[t]
        ii = i0[t] + k // width[t]
        px, py = jj.astype(np.float64), ii.astype(np.float64)
        l1 = ((yb[t] - yc[t]) * (px - xc[t]) + (xc[t] - xb[t]) * (py - yc[t])) / det[t]
        l2 = ((yc[t] - ya[t]) * (px - xc[t]) + (xa[t] - xc[t]) * (py - yc[t])) / det[t]
        l3 = 1 - l1 - l2
        inside = (l1 >= -1e-9) & (l2 >= -1e-9) & (l3 >= -1e-9)
        texel_idx.append((ii * size + jj)[inside])
        tri_idx.append(t[inside].astype(np.int32))
        bary.append(np.column_stack([l1, l2, l3])[inside])
        first = last
    if not texel_idx or not sum(len(a) for a in texel_idx):
        return np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 3))
    texels, first_hit = np.unique(np.concatenate(texel_idx), return_index=True)  # one triangle per texel
    return texels, np.concatenate(tri_idx)[first_hit], np.concatenate(bary)[first_hit]


def bleed(image: np.ndarray, filled: np.ndarray, passes: int = BLEED_PASSES) -> np.ndarray:
    """Fill empty texels from the mean of their filled 4-neighbours, ``passes`` rings deep."""
    image, filled = image.copy(), filled.copy()
    for _ in range(passes):
        total = np.zeros_like(image, dtype=np.float32)
        count = np.zeros(filled.shape, np.float32)
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


def bake(sim, piece: Piece, size: int, iteration: int, threads: int):
    """Colour float32[size, size, 3] (seams bled), and for the covered texels:
    their flat indices, their scene triangles and their smoothed rows (k, W)."""
    texels, tris, bary = rasterise_uv(piece.layout, size)
    corner = piece.vertices.astype(np.float64)[piece.faces[tris]]      # (k, 3, 3)
    positions = np.einsum("kc,kcd->kd", bary, corner).astype(np.float32)
    face = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    normals = (face / np.linalg.norm(face, axis=1, keepdims=True)).astype(np.float32)
    if piece.own_uvs is not None:
        lookup = np.einsum("kc,kcd->kd", bary, np.asarray(piece.own_uvs, np.float64)[tris])
    else:
        lookup = np.zeros((len(tris), 2))
    scene_tris = piece.triangles[tris].astype(np.int32)
    rows, rgb = sim.bake_points(positions, normals, scene_tris, lookup.astype(np.float32),
                                iteration, threads)
    return texture_from_texels(rgb, texels, size), texels, scene_tris, rows


def texture_from_texels(values: np.ndarray, texels: np.ndarray, size: int) -> np.ndarray:
    """A (size, size, C) image with ``values`` at ``texels`` and bled seams."""
    values = np.asarray(values, np.float32)
    values = values.reshape(len(texels), -1) if len(texels) else values.reshape(0, max(1, values.shape[-1] if values.ndim > 1 else 1))
    image = np.zeros((size * size, values.shape[1]), np.float32)
    covered = np.zeros(size * size, bool)
    image[texels], covered[texels] = values, True
    return bleed(image.reshape(size, size, -1), covered.reshape(size, size))


def png8(rgb: np.ndarray) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)).save(out, format="PNG")
    return out.getvalue()


def png16(values: np.ndarray, span: tuple[float, float] | None = None) -> tuple[bytes, float, float]:
    """A property as a 16-bit grey PNG, 0..65535 spanning [low, high] (returned):
    ``span``, else the values' own range."""
    from PIL import Image

    finite = values[np.isfinite(values)]
    if span is not None:
        low, high = (float(span[0]), float(span[1]))
    else:
        low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    scale = 65535.0 / (high - low) if high > low else 0.0
    grey = np.clip(np.nan_to_num((values - low) * scale), 0, 65535).astype(np.uint16)
    out = io.BytesIO()
    Image.fromarray(grey).save(out, format="PNG")  # uint16 -> 16-bit grey
    return out.getvalue(), low, high


def write_glb(positions, normals, uvs, triangles, colours, attributes: dict,
              texture_png: bytes | None = None, extras: dict | None = None, name: str = "gamma") -> bytes:
    """glTF 2.0 binary (.glb) of one triangle mesh, its node and mesh named
    ``name``.  The appearance colour goes in the base-colour texture when there
    is one, else per vertex (``COLOR_0``): never both, since a viewer multiplies
    the two."""
    from .. import __version__

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
             "NORMAL": accessor(normals.astype(np.float32), "VEC3", FLOAT, ARRAY)}
    if texture_png is None:
        attrs["COLOR_0"] = accessor(np.clip(colours, 0, 1).astype(np.float32), "VEC3", FLOAT, ARRAY)
    if uvs is not None:
        # glTF's v runs downward from the top of the image
        flipped = np.column_stack([uvs[:, 0], 1.0 - uvs[:, 1]]).astype(np.float32)
        attrs["TEXCOORD_0"] = accessor(flipped, "VEC2", FLOAT, ARRAY)
    for attribute, values in attributes.items():
        attrs["_" + attribute.upper()] = accessor(values.astype(np.float32).reshape(-1, 1), "SCALAR",
                                             FLOAT, ARRAY, bounds=True)
    indices = accessor(triangles.astype(np.uint32).reshape(-1), "SCALAR", UINT, ELEMENTS)
    material = {"name": "weathered", "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 0.8}}
    doc = {"asset": {"version": "2.0", "generator": f"gamma {__version__}"}, "scene": 0,
           "scenes": [{"name": name, "nodes": [0]}], "nodes": [{"name": name, "mesh": 0}],
           "meshes": [{"name": name, "primitives": [{"attributes": attrs, "indices": indices, "material": 0}]}],
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
    """Wavefront OBJ of the welded mesh (indices shared by v, vt and vn).
    Lines are formatted by one %-operation per block (not one per line)."""

    def block(template: str, rows: np.ndarray) -> str:
        rows = np.asarray(rows)
        return (template * len(rows)) % tuple(rows.reshape(-1).tolist()) if len(rows) else ""

    head = "# exported by gamma\n"
    if material_name:
        head += f"mtllib {material_name}.mtl\nusemtl {material_name}\n"
    corners = np.asarray(triangles, np.int64) + 1
    text = [head, block("v %.7g %.7g %.7g\n", positions), block("vn %.7g %.7g %.7g\n", normals)]
    if uvs is not None:
        text.append(block("vt %.7g %.7g\n", uvs))
        text.append(block("f %d/%d/%d %d/%d/%d %d/%d/%d\n", np.repeat(corners, 3, axis=1)))
    else:
        text.append(block("f %d//%d %d//%d %d//%d\n", np.repeat(corners, 2, axis=1)))
    return "".join(text).encode("ascii")
