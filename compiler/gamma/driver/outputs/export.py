"""Baking and export: the weathered scene as texture sets and files that
artists open elsewhere (SPEC §16.3, "export").

- ``pieces``: the scene split into its objects (OBJ object, else group,
  else mesh file; the regions of each surface after a shape change).
- ``layout``: one object welded for export.  With the mesh's own texture
  coordinates, a vertex per distinct (position, uv, shading normal); without
  them, charts that keep neighbouring triangles together (``atlas.py``,
  xatlas), welded inside each chart.  Normals are the renders' shading
  normals (``--shading``/``--crease``), so Blender shows what ``gammac
  render`` draws.
- ``bake_texture_set``: every texel of the layout mapped back to its point
  on the surface, where the runtime gives the smoothed surfel row and the
  appearance block's look (``Simulation.bake_points``, the renderer's own
  code): base colour, occlusion-roughness-metallic, displacement (height),
  the tangent-space normal map derived from it (combined with the asset's
  own normal map) and every property.  Empty texels around the charts are
  filled from the same chart (dilation), so filtering and mip-maps never
  mix two charts.
- ``write_glb``: glTF 2.0 binary of all objects: per object a node and a
  mesh named after it, a primitive and a material per surface (named after
  the surface), metallic-roughness, normal and occlusion textures, and one
  float attribute per property (``_NAME``).
"""

from __future__ import annotations

import io
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..running.budget import available_memory

BLEED_PASSES = 8
#: Texels come to the baker in tiles of BAKE_TILE x BAKE_TILE: nearby on the
#: surface, so runs of them share a neighbour search (kBakeBlock in baker.h).
BAKE_TILE = 8
#: Texels of a band's own rows, baked in one call of the runtime with its
#: margins (its rows are W floats each).
BAKE_CHUNK = 1 << 20
#: The texture set's images: file suffix -> what it holds (SPEC §16.3).
CHANNELS = {"BaseColor": "base colour, sRGB", "ORM": "occlusion (R), roughness (G), metallic (B)",
            "Normal": "tangent-space normal map (OpenGL: +Y up)", "Height": "displacement, 16-bit"}


@dataclass
class Piece:
    """One object of the scene, exported on its own."""

    name: str
    triangles: np.ndarray        # the scene's triangle numbers (for the runtime)
    vertices: np.ndarray         # float32 (n, 3), this object's only
    faces: np.ndarray            # (m, 3) indices into vertices
    own_uvs: np.ndarray | None   # the mesh's texture coordinates (m, 3, 2), for texture() lookups
    tile: int | None = None      # UDIM tile (1001 + u + 10 v) of an object whose uvs span several


def udim_tiles(own_uvs: np.ndarray) -> np.ndarray:
    """The UDIM tile of each triangle (its uv centre's unit square: 1001 + u
    + 10 v, u in 0..9), for texture coordinates that span several tiles."""
    centre = np.asarray(own_uvs, np.float64).mean(axis=1)
    u = np.clip(np.floor(centre[:, 0]), 0, 9).astype(np.int64)
    v = np.maximum(np.floor(centre[:, 1]), 0).astype(np.int64)
    return 1001 + u + 10 * v


def pieces(scene) -> list[Piece]:
    """The scene split into its objects (``scene.object_names``), and an
    object whose texture coordinates span several UDIM tiles into one piece
    per tile (its textures are that tile's)."""
    mesh = scene.mesh
    verts = np.asarray(mesh.vertices(), np.float32)
    tris = np.asarray(mesh.triangles(), np.int64)
    uvs = np.asarray(mesh.triangle_uvs(), np.float32) if mesh.has_uvs else None
    has_uv = getattr(scene, "triangle_has_uv", None)
    out = []
    for k, name in enumerate(scene.object_names):
        ids = np.flatnonzero(scene.triangle_object == k)
        if not len(ids):
            continue
        used, faces = np.unique(tris[ids], return_inverse=True)
        own = uvs[ids] if uvs is not None and (has_uv is None or has_uv[ids].all()) else None
        tiles = udim_tiles(own) if own is not None else None
        if tiles is None or len(np.unique(tiles)) == 1:
            out.append(Piece(name, ids, verts[used], faces.reshape(-1, 3), own))
            continue
        for tile in np.unique(tiles):
            mine = ids[tiles == tile]
            used, faces = np.unique(tris[mine], return_inverse=True)
            out.append(Piece(name, mine, verts[used], faces.reshape(-1, 3), uvs[mine], int(tile)))
    return out


def layout_uvs(piece: Piece) -> np.ndarray | None:
    """The piece's own uvs as its textures lay them out: a UDIM tile's moved
    to the unit square (texture() lookups still see the mesh's own)."""
    if piece.own_uvs is None or piece.tile is None:
        return piece.own_uvs
    u, v = (piece.tile - 1001) % 10, (piece.tile - 1001) // 10
    return (piece.own_uvs - np.array([u, v], np.float32)).astype(np.float32)


@dataclass
class Layout:
    """One object welded for export."""

    piece: Piece
    positions: np.ndarray        # float32 (k, 3)
    normals: np.ndarray          # float32 (k, 3) unit shading normals
    uvs: np.ndarray              # float32 (k, 2) in the baked textures (v up)
    faces: np.ndarray            # int64 (m, 3), the piece's triangle order
    chart: np.ndarray | None     # int32 (m,) chart per triangle (atlas), None for the mesh's own uvs
    size: int                    # the textures' width and height

    _raster: tuple | None = None

    @property
    def corner_uvs(self) -> np.ndarray:
        return self.uvs[self.faces]

    def texels(self) -> tuple:
        """``rasterise_uv`` of the layout (texel, triangle, barycentrics),
        made once: every iteration exported bakes the same texels."""
        if self._raster is None:
            self._raster = rasterise_uv(self.corner_uvs, self.size)
        return self._raster

    def charts(self) -> np.ndarray | None:
        """The chart of each texel (size, size), -1 in the gutters; None for the mesh's own uvs."""
        if self.chart is None:
            return None
        texels, tris, _ = self.texels()
        charts = np.full(self.size * self.size, -1, np.int32)
        charts[texels] = self.chart[tris]
        return charts.reshape(self.size, self.size)


def weld(vertex: np.ndarray, uvs: np.ndarray, normals: np.ndarray):
    """One vertex per distinct (vertex, uv, normal) of the corners: (vertex
    per new vertex, uv per new vertex, normal per new vertex, triangles)."""
    keys = np.column_stack([vertex.reshape(-1, 1).astype(np.float64),
                            uvs.reshape(-1, 2).astype(np.float64), normals.reshape(-1, 3).astype(np.float64)])
    unique, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return (unique[:, 0].astype(np.int64), unique[:, 1:3].astype(np.float32),
            normals.reshape(-1, 3)[first].astype(np.float32), inverse.reshape(-1, 3))


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    corner = vertices.astype(np.float64)[faces]
    n = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return (n / np.where(length > 0, length, 1)).astype(np.float32)


def layout(piece: Piece, corner_normals: np.ndarray | None, size: int) -> Layout:
    """``piece`` welded for a ``size``² texture set.  ``corner_normals``: the
    renders' shading normals of the scene's triangles (m, 3, 3), None: flat."""
    corners = (corner_normals[piece.triangles].astype(np.float32) if corner_normals is not None
               else np.repeat(face_normals(piece.vertices, piece.faces)[:, None, :], 3, axis=1))
    if piece.own_uvs is not None:
        source, uvs, normals, faces = weld(piece.faces, layout_uvs(piece), corners)
        return Layout(piece, piece.vertices[source], normals, uvs, faces, None, size)
    from .atlas import chart_atlas

    atlas = chart_atlas(piece.vertices, piece.faces, size, corner_normals=corners)
    return Layout(piece, piece.vertices[atlas.source], atlas.normals, atlas.uvs, atlas.faces,
                  atlas.chart, size)


def vertex_normals(positions: np.ndarray, tris: np.ndarray) -> np.ndarray:
    a, b, c = positions[tris[:, 0]], positions[tris[:, 1]], positions[tris[:, 2]]
    face = np.cross(b - a, c - a)                      # area-weighted
    normals = np.zeros_like(positions)
    for k in range(3):
        np.add.at(normals, tris[:, k], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.where(length > 0, length, 1)).astype(np.float32)


def vertex_looks(sim, lay: Layout, iteration: int, threads: int, cancel=None):
    """At the layout's vertices: (rows, looks, scene triangle per vertex).
    ``cancel``: a CancelToken that stops the bake (runtime Cancelled)."""
    local = np.zeros(len(lay.positions), np.int64)     # a triangle each vertex belongs to
    local[lay.faces.reshape(-1)] = np.repeat(np.arange(len(lay.faces)), 3)
    owner = lay.piece.triangles[local].astype(np.int32)
    lookup = np.zeros((len(lay.positions), 2), np.float32)
    if lay.piece.own_uvs is not None:                  # texture() sees the mesh's coordinates
        lookup[lay.faces.reshape(-1)] = lay.piece.own_uvs.reshape(-1, 2)
    rows, look = sim.bake_points(lay.positions, lay.normals, owner, lookup, iteration, threads, cancel=cancel)
    return np.asarray(rows), np.asarray(look), owner


def rasterise_uv(corner_uvs: np.ndarray, size: int, rows: tuple | None = None, tile: int = 1):
    """Texels covered by triangles in UV space: (texel index, triangle, barycentrics).

    Texel (i, j) has its centre at u = (j + 0.5)/size, v = 1 - (i + 0.5)/size; a
    texel inside several triangles goes to the lowest-numbered one.  ``rows``
    = (first, end): only the texels of those rows (the same ones the whole
    texture has there).  ``tile`` > 1: the texels come tile by tile (tile x
    tile texels), else in increasing order.  The runtime's loop (gamma/uv_raster.h)."""
    from ..running.common import runtime_module

    first, end = rows if rows is not None else (0, size)
    uvs = np.ascontiguousarray(np.asarray(corner_uvs, np.float64).reshape(-1, 3, 2))
    texels, tris, bary = runtime_module().rasterise_uv(uvs, size, first, end, tile)
    return np.asarray(texels), np.asarray(tris), np.asarray(bary)


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


@dataclass
class TextureSet:
    """One object's baked images (row 0 = the top of the image), float32."""

    size: int
    base_color: np.ndarray           # (s, s, 3) display values
    orm: np.ndarray                  # (s, s, 3) occlusion, roughness, metallic
    normal: np.ndarray               # (s, s, 3) unit tangent-space normals
    height: np.ndarray               # (s, s) displacement, scene units
    properties: dict = field(default_factory=dict)   # name -> (s, s)


def surface_frames(lay: Layout) -> tuple[np.ndarray, np.ndarray]:
    """Per triangle the surface's change per unit of u and of v (m, 3) each."""
    p = lay.positions.astype(np.float64)[lay.faces]
    t = lay.corner_uvs.astype(np.float64)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    det = np.where(np.abs(det) > 1e-20, det, 1e-20)
    pu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) / det[:, None]
    pv = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) / det[:, None]
    return pu, pv


#: Rows of the texture baked at once (about BAKE_CHUNK texels), each with a
#: margin of HALO rows on both sides: the gutter filling reaches
#: BLEED_PASSES rows, the normal map's slope one more, and the normal map's
#: own filling BLEED_PASSES more, so a band's own rows come out exactly as
#: the whole texture's would, in memory bounded by the band.
HALO = 2 * BLEED_PASSES + 1


@dataclass
class PropertySlots:
    """Where each exported property lies in the surfels' rows: ``names``
    (P), ``slots`` (surfaces, P) int32, the row slot of each property on
    each surface (-1: that surface has none, baked as 0), and
    ``surface_of_triangle``, the surface of each scene triangle."""
    names: list
    slots: np.ndarray
    surface_of_triangle: np.ndarray


def property_slots(effect, surface_of_triangle: np.ndarray, present=None) -> PropertySlots:
    """The effect's properties as ``property_columns`` names them (surface by
    surface, first seen first), of the surfaces in ``present`` (default: all)."""
    surfaces = [s for s in effect.surfaces.values() if present is None or s.index in present]
    names = list(dict.fromkeys(name for s in surfaces for name in s.properties))
    slots = np.full((max((s.index for s in effect.surfaces.values()), default=-1) + 1, len(names)), -1, np.int32)
    for s in surfaces:
        for name, slot in s.properties.items():
            slots[s.index, names.index(name)] = slot
    return PropertySlots(names, slots, np.ascontiguousarray(surface_of_triangle, np.int32))


def bake_texture_set(sim, lay: Layout, iteration: int, threads: int, columns: PropertySlots, normal_map=None,
                     band: int | None = None, as_bytes: bool = False, cancel=None) -> TextureSet:
    """The layout's texture set, baked in bands of ``band`` rows (default:
    about BAKE_CHUNK texels).  ``columns``: the properties to bake, one map
    each; ``normal_map(lookup_uvs, scene_triangles)``, when given, the
    asset's own tangent-space normals there ((k, 3), or None where it has
    none).  ``as_bytes``: the base colour, ORM and normal map (as (n + 1) /
    2) as the 8-bit values their PNGs hold (``to_bytes``), a quarter of the
    memory of floats.  ``cancel``: a CancelToken that stops the bake between
    blocks of texels."""
    size = lay.size
    band = band or max(16, BAKE_CHUNK // size)
    rgb = np.uint8 if as_bytes else np.float32
    ts = TextureSet(size, np.zeros((size, size, 3), rgb), np.zeros((size, size, 3), rgb),
                    np.zeros((size, size, 3), rgb), np.zeros((size, size), np.float32))
    for name in columns.names:
        ts.properties[name] = np.zeros((size, size), np.float32)
    put = to_bytes if as_bytes else (lambda image: image)
    corner_uvs = lay.corner_uvs
    from ..running.common import runtime_module

    stride = runtime_module().LATTICE_STRIDE
    for first in range(0, size, band):
        end = min(size, first + band)
        top, bottom = max(0, first - HALO), min(size, end + HALO)
        # and the lattice rows around them (the runtime's bake_texels: aligned to the whole texture)
        top, bottom = top - top % stride, min(size, (bottom - 1) // stride * stride + stride + 1)
        texels, tris, bary = rasterise_uv(corner_uvs, size, rows=(top, bottom), tile=BAKE_TILE)
        images = _bake_band(sim, lay, iteration, threads, columns, normal_map,
                            texels - top * size, tris, bary, (bottom - top, size), top, cancel)
        keep = slice(first - top, end - top)
        ts.base_color[first:end], ts.orm[first:end] = put(images[0][keep]), put(images[1][keep])
        ts.normal[first:end] = to_bytes((images[2][keep] + 1.0) * 0.5) if as_bytes else images[2][keep]
        ts.height[first:end] = images[3][keep]
        for k, name in enumerate(columns.names):
            ts.properties[name][first:end] = images[4][keep, :, k]
    return ts


def _bake_band(sim, lay: Layout, iteration: int, threads: int, columns: PropertySlots, normal_map, texels, tris,
               bary, shape: tuple, top: int, cancel=None):
    """The images of a band of rows (``shape``, from row ``top`` of the
    texture; ``texels`` numbered in it): (base colour, ORM, normal, height,
    properties (h, w, P)).  The runtime bakes the band in one call, every
    channel but the normal map in one stack (base colour 0-2, ORM 3-5,
    height 6, then the properties), filled into the gutters at once:
    texels between lattice points near enough on the surface take their
    rows from them (gamma/baker.h)."""
    piece = lay.piece
    corners = np.ascontiguousarray(lay.faces, np.int32)
    scene_triangle = np.ascontiguousarray(piece.triangles, np.int32)
    lookup_uvs = None if piece.own_uvs is None else np.ascontiguousarray(piece.own_uvs, np.float32)
    tris = np.ascontiguousarray(tris, np.int32)
    stack = np.asarray(sim.bake_texels(lay.positions, lay.normals, corners, lookup_uvs, scene_triangle, tris,
                                       np.ascontiguousarray(bary), columns.surface_of_triangle, columns.slots,
                                       iteration, threads, cancel=cancel, texels=texels, band_width=shape[1],
                                       band_rows=shape[0], first_row=top))
    own = None
    if normal_map is not None:
        own = np.zeros((len(texels), 3), np.float32)
        for first in range(0, len(texels), BAKE_CHUNK):
            part = slice(first, first + BAKE_CHUNK)
            t = tris[part]
            lookup = np.einsum("kc,kcd->kd", bary[part], lookup_uvs.astype(np.float64)[t]).astype(np.float32)
            mine = normal_map(lookup, scene_triangle[t])
            if mine is not None:
                own[part] = mine
    charts = None if lay.chart is None else np.ascontiguousarray(lay.chart[tris], np.int32)
    image, filled = fill(stack, texels, shape, charts, threads, with_charts=True)
    del stack
    height = image[..., 6]
    if own is None and filled is not None and not np.any(height):
        # flat everywhere: the texels the filling reaches hold (0, 0, 1), exactly what filling it gives
        normal = np.zeros(shape + (3,), np.float32)
        normal[..., 2] = filled >= 0
    else:
        normal = fill(tangent_normals(lay, height, texels, tris, own), texels, shape, charts, threads)
    return image[..., 0:3], image[..., 3:6], normal, height, image[..., 7:]


def sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``image`` (h, w, C; row 0 at the top) at texture coordinates (k, 2),
    v up, bilinear with wrap-around: the runtime's sample_texture."""
    h, w = image.shape[:2]
    u = np.mod(np.nan_to_num(uv[:, 0].astype(np.float64)), 1.0)
    v = np.mod(np.nan_to_num(uv[:, 1].astype(np.float64)), 1.0)
    x, y = u * w - 0.5, (1.0 - v) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64) % w, y0.astype(np.int64) % h
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    top = image[y0, x0] + fx * (image[y0, x1] - image[y0, x0])
    bottom = image[y1, x0] + fx * (image[y1, x1] - image[y1, x0])
    return (top + fy * (bottom - top)).astype(np.float32)


def fill(values: np.ndarray, texels: np.ndarray, shape: tuple, charts: np.ndarray | None,
         threads: int = 0, with_charts: bool = False):
    """A (rows, columns, C) image (``shape``) with ``values`` at ``texels``,
    its gutters filled from the same chart (``charts``: the chart of each
    texel of ``texels``; None: from any neighbour).  With charts, the
    runtime's ``fill_charts`` (atlas.dilate's rings) on ``threads`` threads.
    ``with_charts``: (the image, the chart each texel holds after the
    filling, -1: none; None without charts)."""
    values = np.asarray(values, np.float32)
    channels = values.shape[1] if values.ndim == 2 else 1
    values = values.reshape(len(texels), channels)
    if charts is not None:
        from ..running.common import runtime_module

        return runtime_module().fill_charts(values, texels, shape[0], shape[1], charts, BLEED_PASSES, threads,
                                            with_charts=with_charts)
    image = np.zeros((shape[0] * shape[1], channels), np.float32)
    image[texels] = values
    image = image.reshape(shape[0], shape[1], -1)
    covered = np.zeros(shape[0] * shape[1], bool)
    covered[texels] = True
    image = bleed(image, covered.reshape(shape))
    return (image, None) if with_charts else image


def tangent_normals(lay: Layout, height: np.ndarray, texels, tris, own_normals) -> np.ndarray:
    """Unit tangent-space normals (k, 3) at the covered texels: the surface
    bent by the slope of the displacement, over the asset's own normal map
    (``own_normals``, tangent space, or None: flat).  The tangent follows +u,
    the bitangent +v (the image's up), as glTF and Blender read them."""
    size, columns = lay.size, height.shape[1]
    k = len(texels)
    flat = np.zeros((k, 3), np.float32)
    flat[:, 2] = 1.0
    base = flat if own_normals is None else own_normals
    if not np.any(height):
        return base
    # slope per texel (rows run down the image, v up), then per unit of u and v
    dy, dx = np.gradient(height.astype(np.float64))
    i, j = texels // columns, texels % columns
    dh_du, dh_dv = dx[i, j] * size, -dy[i, j] * size
    pu, pv = surface_frames(lay)
    pu, pv = pu[tris], pv[tris]
    # the surface gradient g (in the plane of pu, pv) with g.pu = dh/du and g.pv = dh/dv
    a11, a12, a22 = (pu * pu).sum(1), (pu * pv).sum(1), (pv * pv).sum(1)
    det = a11 * a22 - a12 * a12
    det = np.where(np.abs(det) > 1e-30, det, np.inf)
    cu = (a22 * dh_du - a12 * dh_dv) / det
    cv = (a11 * dh_dv - a12 * dh_du) / det
    g = pu * cu[:, None] + pv * cv[:, None]
    # the tangent frame: T along +u, B along +v, N = T x B's side of the surface
    normal = np.cross(pu, pv)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    tangent = pu / np.maximum(np.linalg.norm(pu, axis=1, keepdims=True), 1e-30)
    bitangent = np.cross(normal, tangent)
    bent = np.column_stack([-(g * tangent).sum(1), -(g * bitangent).sum(1), np.ones(k)])
    bent /= np.linalg.norm(bent, axis=1, keepdims=True)
    if own_normals is None:
        return bent.astype(np.float32)
    # reoriented normal mapping (Barré-Brisebois and Hill): the slope's bend on top of the asset's detail
    t = base.astype(np.float64) + np.array([0.0, 0.0, 1.0])
    u = bent * np.array([-1.0, -1.0, 1.0])
    r = t * (t * u).sum(1, keepdims=True) / t[:, 2:3] - u
    return (r / np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-30)).astype(np.float32)


def png_bytes(pixels: np.ndarray) -> bytes:
    """A uint8 image (grey, RGB or RGBA) as a PNG."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(pixels).save(out, format="PNG")
    return out.getvalue()


#: zlib level and strategy (Z_RLE) of the 16-bit maps: much faster to write
#: than Pillow's default (level 6, Z_DEFAULT_STRATEGY) for files a little
#: larger: a property's low bits are noise that matching strings do not find
#: (bench/RESULTS.md).
PNG16_LEVEL = 3
PNG16_STRATEGY = 3


def png16(values: np.ndarray, span: tuple[float, float] | None = None) -> tuple[bytes, float, float]:
    """A property as a 16-bit grey PNG, 0..65535 spanning [low, high] (returned):
    ``span``, else the values' own range."""
    if span is not None:
        low, high = (float(span[0]), float(span[1]))
    else:
        finite = values[np.isfinite(values)]
        low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    return png16_encode(grey16(values, low, high)), low, high


def grey16(values: np.ndarray, low: float, high: float) -> np.ndarray:
    """``values`` as 16-bit grey levels, 0..65535 spanning [low, high]
    (clamped; NaN as 0), with one float temporary."""
    scale = 65535.0 / (high - low) if high > low else 0.0
    scaled = np.subtract(values, low, dtype=np.float32)
    np.multiply(scaled, scale, out=scaled)
    np.nan_to_num(scaled, copy=False)
    np.clip(scaled, 0, 65535, out=scaled)
    return scaled.astype(np.uint16)


def png16_encode(grey: np.ndarray) -> bytes:
    """A uint16 image as a 16-bit grey PNG (Pillow releases the GIL while it compresses)."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(grey).save(out, format="PNG", compress_level=PNG16_LEVEL,  # uint16 -> 16-bit grey
                               compress_type=PNG16_STRATEGY)
    return out.getvalue()




def to_bytes(image: np.ndarray) -> np.ndarray:
    """A float image in [0, 1] as 8-bit values (x * 255 + 0.5, clamped);
    finite input (the runtime clamps the look, normals are unit)."""
    scaled = np.multiply(image, 255, dtype=np.float32)
    np.add(scaled, 0.5, out=scaled)
    np.clip(scaled, 0, 255, out=scaled)
    return scaled.astype(np.uint8)


def encode_rgb8(images: list, threads: int) -> list[bytes]:
    """8-bit PNGs of RGB images (uint8, or floats in [0, 1]), encoded by the
    runtime on ``threads`` threads without the GIL (as Pillow's default level
    writes them)."""
    from .outputs import PILLOW_DEFAULT_LEVEL
    from ..running.common import runtime_module

    pictures = [np.ascontiguousarray(im if im.dtype == np.uint8 else to_bytes(im)) for im in images]
    return list(runtime_module().encode_pngs(pictures, PILLOW_DEFAULT_LEVEL, threads))


def exr32(values: np.ndarray) -> bytes:
    """A single-channel 32-bit float OpenEXR image (channel Y, ZIP), as bytes."""
    import os
    import tempfile

    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    fd, path = tempfile.mkstemp(suffix=".exr")
    os.close(fd)
    try:    # the binding writes to a path only
        OpenEXR.File(header, {"Y": np.ascontiguousarray(values, np.float32)}).write(path)
        with open(path, "rb") as f:
            return f.read()
    finally:
        os.unlink(path)




def _glb(doc: dict, binary: bytes) -> bytes:
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(text), 0x4E4F534A) + text
            + struct.pack("<II", len(binary), 0x004E4942) + binary)


@dataclass
class ExportPart:
    """One object as the glTF (and OBJ, USD) writers take it."""

    name: str
    positions: np.ndarray            # float32 (k, 3)
    normals: np.ndarray              # float32 (k, 3)
    uvs: np.ndarray                  # float32 (k, 2), v up
    triangles: np.ndarray            # uint32 (m, 3)
    primitives: list                 # (material name, triangle numbers) per surface
    attributes: dict                 # property -> float32 (k,)
    images: dict                     # "BaseColor", "ORM", "Normal" -> (image name, PNG bytes)


def write_glb(parts: list[ExportPart], scene_name: str, extras: dict | None = None) -> bytes:
    """glTF 2.0 binary of the exported objects: a node and a mesh per
    object, a primitive per surface with its material (base colour,
    metallic-roughness, normal and occlusion textures), every property as a
    float vertex attribute ``_NAME``."""
    from ...version import version

    chunks, views, accessors = [], [], []
    images, textures, materials, meshes, nodes = [], [], [], [], []
    size = [0]

    def add(data: bytes, target: int | None = None) -> int:
        view = {"buffer": 0, "byteOffset": size[0], "byteLength": len(data)}
        chunks.append(data + b"\0" * (-len(data) % 4))
        size[0] += len(chunks[-1])
        if target is not None:
            view["target"] = target
        views.append(view)
        return len(views) - 1

    def accessor(array: np.ndarray, kind: str, component: int, target: int, bounds=False) -> int:
        view = add(np.ascontiguousarray(array).tobytes(), target)
        acc = {"bufferView": view, "componentType": component, "count": int(len(array)), "type": kind}
        if bounds and len(array):
            acc["min"] = [float(v) for v in np.atleast_1d(array.min(axis=0))]
            acc["max"] = [float(v) for v in np.atleast_1d(array.max(axis=0))]
        accessors.append(acc)
        return len(accessors) - 1

    FLOAT, UINT = 5126, 5125
    ARRAY, ELEMENTS = 34962, 34963
    for part in parts:
        attrs = {"POSITION": accessor(part.positions.astype(np.float32), "VEC3", FLOAT, ARRAY, bounds=True),
                 "NORMAL": accessor(part.normals.astype(np.float32), "VEC3", FLOAT, ARRAY),
                 # glTF's v runs downward from the top of the image
                 "TEXCOORD_0": accessor(np.column_stack([part.uvs[:, 0], 1.0 - part.uvs[:, 1]]).astype(np.float32),
                                        "VEC2", FLOAT, ARRAY)}
        for name, values in part.attributes.items():
            attrs["_" + name.upper()] = accessor(values.astype(np.float32).reshape(-1, 1), "SCALAR", FLOAT,
                                                 ARRAY, bounds=True)
        texture_of = {}
        for channel, (name, png) in part.images.items():
            images.append({"name": name, "bufferView": add(png), "mimeType": "image/png"})
            textures.append({"sampler": 0, "source": len(images) - 1, "name": name})
            texture_of[channel] = len(textures) - 1
        primitives = []
        for material, faces in part.primitives:
            pbr = {"metallicFactor": 1.0, "roughnessFactor": 1.0}
            entry = {"name": material, "pbrMetallicRoughness": pbr}
            if "BaseColor" in texture_of:
                pbr["baseColorTexture"] = {"index": texture_of["BaseColor"]}
            if "ORM" in texture_of:
                pbr["metallicRoughnessTexture"] = {"index": texture_of["ORM"]}
                entry["occlusionTexture"] = {"index": texture_of["ORM"]}
            if "Normal" in texture_of:
                entry["normalTexture"] = {"index": texture_of["Normal"]}
            materials.append(entry)
            indices = accessor(part.triangles[faces].astype(np.uint32).reshape(-1), "SCALAR", UINT, ELEMENTS)
            primitives.append({"attributes": attrs, "indices": indices, "material": len(materials) - 1})
        meshes.append({"name": part.name, "primitives": primitives})
        nodes.append({"name": part.name, "mesh": len(meshes) - 1})
    doc = {"asset": {"version": "2.0", "generator": f"gamma {version()}"}, "scene": 0,
           "scenes": [{"name": scene_name, "nodes": list(range(len(nodes)))}], "nodes": nodes,
           "meshes": meshes, "materials": materials, "accessors": accessors}
    if images:
        doc["images"], doc["textures"] = images, textures
        doc["samplers"] = [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}]
    if extras:
        doc["extras"] = extras
    doc["bufferViews"] = views
    binary = b"".join(chunks)
    doc["buffers"] = [{"byteLength": len(binary)}]
    return _glb(doc, binary)


def write_obj(part: ExportPart, mtl_file: str) -> bytes:
    """Wavefront OBJ of one exported object (indices shared by v, vt and vn:
    its welded vertices), a ``usemtl`` per surface.  Lines are formatted by
    one %-operation per block (not one per line)."""

    def block(template: str, rows: np.ndarray) -> str:
        rows = np.asarray(rows)
        return (template * len(rows)) % tuple(rows.reshape(-1).tolist()) if len(rows) else ""

    text = [f"# exported by gamma\nmtllib {mtl_file}\no {part.name}\n",
            block("v %.7g %.7g %.7g\n", part.positions), block("vn %.7g %.7g %.7g\n", part.normals),
            block("vt %.7g %.7g\n", part.uvs)]
    corners = np.asarray(part.triangles, np.int64) + 1
    for material, faces in part.primitives:
        text.append(f"usemtl {material}\n")
        text.append(block("f %d/%d/%d %d/%d/%d %d/%d/%d\n", np.repeat(corners[faces], 3, axis=1)))
    return "".join(text).encode("utf-8")


def write_mtl(part: ExportPart, files: dict) -> bytes:
    """The OBJ's materials: the base colour map and the normal map (``norm``,
    which Blender's OBJ importer reads); roughness and metallic are in the
    glTF's ORM texture."""
    text = ["# exported by gamma\n"]
    for material, _ in part.primitives:
        text.append(f"newmtl {material}\nKd 1 1 1\n")
        if "BaseColor" in files:
            text.append(f"map_Kd {files['BaseColor']}\n")
        if "Normal" in files:
            text.append(f"norm {files['Normal']}\n")
    return "".join(text).encode("utf-8")


def piece_label(piece: Piece) -> str:
    """The name an exported piece's node has: the object's, with its UDIM tile."""
    return piece.name if piece.tile is None else f"{piece.name}.{piece.tile}"


def safe_name(name: str) -> str:
    """A part's name as a file name."""
    import re

    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "object"


def texel_size(piece: Piece, lay_uvs: np.ndarray, density: float) -> int:
    """The texture size that gives ``density`` texels per scene unit on the
    piece, given its corner uvs (m, 3, 2): sqrt(surface area / uv area)."""
    p = piece.vertices.astype(np.float64)[piece.faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    t = lay_uvs.astype(np.float64)
    uv_area = 0.5 * np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                           - (t[:, 2, 0] - t[:, 0, 0]) * (t[:, 1, 1] - t[:, 0, 1])).sum()
    side = density * np.sqrt(area / max(uv_area, 1e-12))
    return int(min(max(4 * np.ceil(side / 4), 16), MAX_BAKE_SIZE))


#: The largest texture side baked (--bake-size, or what --texel-density asks for).
MAX_BAKE_SIZE = 16384
#: What a bake holds at its peak, measured on the stain scene at 4096² (1.15
#: GiB for the whole gammac process, bench/RESULTS.md): per texel the 8-bit
#: base colour, ORM and normal map, the float height and their PNGs being
#: made; per texel and property its float image and its 16-bit (or EXR)
#: copy; and a band's working set (its texels with their margins: points,
#: lattice, looks, rows and images), whatever the size.
BYTES_PER_TEXEL = 32
BYTES_PER_TEXEL_AND_PROPERTY = 8
BAND_BYTES = 300 << 20
#: The runtime's own per texel of a band: point, normal, uv, triangle,
#: lattice corners and weights, looks.
BAND_BYTES_PER_TEXEL = 96


def bake_memory(size: int, row_width: int, properties: int) -> int:
    """An estimate of the peak memory of baking one ``size``² texture set."""
    texels = size * size
    band = min(size, max(16, BAKE_CHUNK // size) + 2 * HALO + 8) * size
    return (texels * (BYTES_PER_TEXEL + BYTES_PER_TEXEL_AND_PROPERTY * properties) + BAND_BYTES
            + band * (4 * row_width + BAND_BYTES_PER_TEXEL))



def memory_problem(size: int, row_width: int, properties: int) -> str | None:
    """Why a ``size``² bake cannot be made here (its estimated peak memory
    is more than this machine has available), or None."""
    need, have = bake_memory(size, row_width, properties), available_memory()
    if have is None or need <= 0.8 * have:
        return None
    return (f"a {size:,}² texture set needs about {need / 2**30:.1f} GiB while baking and "
            f"{have / 2**30:.1f} GiB is available; choose a smaller --bake-size or --texel-density")


class Exporter:
    """Writes a run's export (SPEC §16.3) for one iteration at a time from
    the simulation's current state: ``export/SCENE_NNNN.glb`` and per object
    ``export/OBJECT/`` with its texture set, OBJ + MTL and a sidecar JSON.
    ``ranges``: property -> (low, high) over the whole run, which every
    16-bit property map spans."""

    def __init__(self, run, bake_size: int | None, texel_density: float | None, ranges: dict,
                 preset: str = "gltf", float_maps: bool = False):
        self.preset = preset
        self.float_maps = float_maps

        self.run, self.ranges = run, {k: tuple(v) for k, v in ranges.items()}
        self.bake_size, self.texel_density = bake_size or 1024, texel_density
        self.scene_name = safe_name(Path(run.opts.scene).stem)
        self.layouts = None
        self.usd_frames = None     # (iteration, parts, texture files) per iteration, for write_usd

    def keep_for_usd(self) -> None:
        """Keep what each write makes, for one USD stage of all of them (``finish_usd``)."""
        self.usd_frames = []

    def finish_usd(self) -> Path:
        """``export/SCENE.usdc``: the iterations written as time samples (SPEC §16.3)."""
        from .usd_export import write_usd

        path = self.run.out / "export" / f"{self.scene_name}.usdc"
        write_usd(path, self.usd_frames, self.scene_name, moving=bool(self.run.shapes))
        return path

    def _layouts(self) -> list[Layout]:
        run = self.run
        if self.layouts is None or run.shapes:       # a changing shape is laid out again
            scene = run.export_scene()
            self.triangle_surface = np.asarray(scene.triangle_surface)
            corner = np.asarray(run.sim.corner_normals())
            self.layouts = []
            properties = len({n for s in run.effect.surfaces.values() for n in s.properties})
            for piece in pieces(scene):
                size = self.bake_size
                lay = layout(piece, corner, size)
                if self.texel_density:
                    size = texel_size(piece, lay.corner_uvs, self.texel_density)
                    if size != lay.size:
                        lay = layout(piece, corner, size)
                problem = memory_problem(lay.size, run.effect.row_width, properties)
                if problem:
                    from ..running.common import RunError

                    raise RunError(f"cannot export '{piece.name}': {problem}")
                self.layouts.append(lay)
        return self.layouts

    def _normal_map(self, piece: Piece):
        """The asset's own normal maps at bake points of ``piece`` (a callable
        for bake_texture_set), or None when none of its materials has one."""
        scene = self.run.export_scene()
        materials = getattr(scene, "materials", None) or []
        triangle_material = getattr(scene, "triangle_material", None)
        if piece.own_uvs is None or triangle_material is None or not any(
                getattr(m, "normal_map", None) is not None for m in materials):
            return None

        def sample(lookup: np.ndarray, scene_tris: np.ndarray):
            out = np.zeros((len(lookup), 3), np.float32)
            out[:, 2] = 1.0
            which = triangle_material[scene_tris]
            for m, material in enumerate(materials):
                mine = np.flatnonzero(which == m)
                if len(mine) and material.normal_map is not None:
                    n = sample_bilinear(material.normal_map, lookup[mine]) * 2.0 - 1.0
                    out[mine] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            return out

        return sample

    def write(self, iteration: int) -> None:
        """Export ``iteration``: per part its texture set, OBJ, MTL and
        sidecar, then the glb.  A part's images are encoded on worker threads
        (the runtime's encoder and Pillow, without the GIL) while the next
        part bakes; its files are written once they are done."""
        from ...files import atomic_write
        from concurrent.futures import ThreadPoolExecutor

        run = self.run
        effect = run.effect
        surface_parts: dict = {}
        layouts = self._layouts()
        for lay in layouts:
            for s in np.unique(self.triangle_surface[lay.piece.triangles]):
                surface_parts.setdefault(int(s), []).append(piece_label(lay.piece))
        parts, stem, usd_files = [], f"{iteration:04d}", {}
        with ThreadPoolExecutor(2) as pool:
            pending = None
            for lay in layouts:
                finish = self._bake_part(lay, iteration, stem, surface_parts, pool)
                if pending is not None:
                    pending(parts, usd_files)
                pending = finish
            if pending is not None:
                pending(parts, usd_files)
        out = run.out / "export"
        extras = {"gamma": {"iteration": iteration, "effect": str(effect.path),
                            "properties": {p: {"min": lo, "max": hi} for p, (lo, hi) in self.ranges.items()}}}
        atomic_write(out / f"{self.scene_name}_{stem}.glb", write_glb(parts, self.scene_name, extras))
        if self.usd_frames is not None:
            for part in parts:
                part.images = {}          # the stage refers to the files: the PNG bytes are not kept
            self.usd_frames.append((iteration, parts, usd_files))

    def _bake_part(self, lay: Layout, iteration: int, stem: str, surface_parts: dict, pool):
        """Bake one part and set its images encoding on ``pool``; returns
        finish(parts, usd_files), which waits for them and writes the part's
        files.  Only what the files need is kept until then (the encoders'
        inputs; the texture set itself for a preset or float maps)."""
        from ...files import atomic_write
        from ..running.common import property_columns

        run = self.run
        effect, sim = run.effect, run.sim
        piece = lay.piece
        surfaces = self.triangle_surface[piece.triangles]
        columns = property_slots(effect, self.triangle_surface, set(np.unique(surfaces).tolist()))
        rows, _, owner = vertex_looks(sim, lay, iteration, run.threads, run.cancel)
        attributes = property_columns(effect, rows, self.triangle_surface[owner])
        ts = bake_texture_set(sim, lay, iteration, run.threads, columns, self._normal_map(piece),
                              as_bytes=True, cancel=run.cancel)
        reach = float(np.max(np.abs(ts.height))) if ts.height.size else 0.0
        spans = {prop: self.ranges.get(prop, (float(np.min(values)), float(np.max(values))))
                 for prop, values in ts.properties.items()}
        rgb = pool.submit(encode_rgb8, [ts.base_color, ts.orm, ts.normal], 1)
        grey = {}
        if not self.float_maps:
            grey["Height"] = pool.submit(png16, ts.height, (-reach, reach))
            for prop, values in ts.properties.items():
                grey[prop] = pool.submit(png16, values, spans[prop])
        keep = ts if (self.float_maps or self.preset in ("unity", "unreal")) else None
        properties = list(ts.properties)
        del ts

        def finish(parts: list, usd_files: dict) -> None:
            names = list(effect.surfaces)
            part_name = safe_name(piece.name)
            tile = "" if piece.tile is None else f".{piece.tile}"     # UDIM: NAME.1001.png
            folder = run.out / "export" / part_name
            files, sidecar = {}, {"iteration": iteration, "object": piece.name, "udim": piece.tile, "size": lay.size,
                                  "preset": self.preset, "images": {}, "properties": {}}

            def image(channel: str, data: bytes, **about) -> None:
                file = f"{part_name}_{channel}_{stem}{tile}.png"
                atomic_write(folder / file, data)
                files[channel] = file
                sidecar["images"][channel] = {"file": file, "holds": CHANNELS.get(channel, channel), **about}

            base, orm, normal = rgb.result()
            # glTF's ORM and OpenGL normal map always (the glb, the OBJ and the USD stage read
            # them); a preset adds its engine's own packing beside them
            image("BaseColor", base, colour_space="sRGB")
            image("ORM", orm, colour_space="linear")
            image("Normal", normal, colour_space="linear")
            if self.preset == "unity":      # HDRP's mask map: metallic, occlusion, detail mask, smoothness
                mask = np.stack([keep.orm[..., 2], keep.orm[..., 0], np.full_like(keep.orm[..., 0], 255),
                                 255 - keep.orm[..., 1]], axis=-1)
                image("MaskMap", png_bytes(mask), colour_space="linear",
                      holds="metallic (R), occlusion (G), detail mask (B), smoothness = 1 - roughness (A)")
            if self.preset == "unreal":     # DirectX convention: green points down the image
                flipped = keep.normal.copy()
                flipped[..., 1] = 255 - flipped[..., 1]
                image("NormalDX", encode_rgb8([flipped], run.threads)[0], colour_space="linear",
                      holds="tangent-space normal map (DirectX: +Y down), for Unreal")
            if self.float_maps:
                file = f"{part_name}_Height_{stem}{tile}.exr"
                atomic_write(folder / file, exr32(keep.height))
                sidecar["images"]["Height"] = {"file": file, "holds": CHANNELS["Height"], "min": -reach,
                                               "max": reach, "unit": "scene units along the normal (32-bit float)"}
            else:
                image("Height", grey["Height"].result()[0], min=-reach, max=reach,
                      unit="scene units along the normal (0 is mid-grey)")
            for prop in properties:
                low, high = spans[prop]
                if self.float_maps:
                    file = f"{part_name}_{prop}_{stem}{tile}.exr"
                    atomic_write(folder / file, exr32(keep.properties[prop]))
                    scale = "the values themselves (32-bit float); min..max over the whole run"
                else:
                    file = f"{part_name}_{prop}_{stem}{tile}.png"
                    atomic_write(folder / file, grey[prop].result()[0])
                    scale = "0..65535 spans min..max over the whole run"
                sidecar["properties"][prop] = {"file": file, "min": low, "max": high, "scale": scale}
            primitives = []
            for s in np.unique(surfaces):
                surface = names[int(s)]
                material = surface if len(surface_parts[int(s)]) == 1 else f"{surface}_{part_name}{tile}"
                primitives.append((material, np.flatnonzero(surfaces == s)))
            part = ExportPart(piece_label(piece), lay.positions, lay.normals, lay.uvs,
                              lay.faces.astype(np.uint32), primitives, attributes,
                              {"BaseColor": (f"{part_name}_BaseColor_{stem}{tile}", base),
                               "ORM": (f"{part_name}_ORM_{stem}{tile}", orm),
                               "Normal": (f"{part_name}_Normal_{stem}{tile}", normal)})
            parts.append(part)
            usd_files[part.name] = {channel: f"{part_name}/{file}" for channel, file in files.items()}
            atomic_write(folder / f"{part_name}_{stem}{tile}.obj", write_obj(part, f"{part_name}_{stem}{tile}.mtl"))
            atomic_write(folder / f"{part_name}_{stem}{tile}.mtl", write_mtl(part, files))
            atomic_write(folder / f"{part_name}_{stem}{tile}.json",
                         (json.dumps(sidecar, indent=1) + "\n").encode("utf-8"))

        return finish
