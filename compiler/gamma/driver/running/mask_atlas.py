"""Masks painted on parts without texture coordinates (SPEC §12a).

A mask is read at texture coordinates, which a mesh without UVs does not
have.  ``gammac watch`` therefore lays a new mask out in the scene's own
chart atlas (``atlas.chart_atlas``, the one the export makes), and the PNG
says so in a text chunk, ``gamma-atlas``: the atlas's version, its size and
a fingerprint of the triangles it covers (the scene's triangles without
UVs, as assembled).  When an effect reads such a mask, those triangles get
the atlas's coordinates (``with_atlas``), so surfels, appearance blocks and
the page all read the same texels.  A mask laid out for other triangles (the
mesh changed) is refused rather than read at the wrong places.

- ``layout``: the record a mask file carries, or None;
- ``with_atlas``: the scene's mesh with atlas coordinates on its bare triangles;
- ``create``: a black mask laid out in the scene's atlas;
- ``texel_points``: the scene point under each texel of the atlas, for the
  page's brush, which paints in space so strokes cross chart seams.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

KEY = "gamma-atlas"
VERSION = 1
#: A new mask's size in texels (square), as `gammac watch` creates it.
DEFAULT_SIZE = 1024

_cache: dict = {}   # (fingerprint, size) -> corner uvs (k, 3, 2) of the bare triangles


class LayoutError(Exception):
    pass


def layout(path: str | Path) -> dict | None:
    """The atlas record of a mask file (``version``, ``size``, ``mesh``), or None."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            text = getattr(image, "text", {}).get(KEY)
            size = image.size
    except (OSError, ValueError, Image.DecompressionBombError):
        return None
    if text is None:
        return None
    try:
        record = json.loads(text)
        record = {"version": int(record["version"]), "size": int(record["size"]), "mesh": str(record["mesh"])}
    except (ValueError, KeyError, TypeError):
        raise LayoutError(f"mask '{Path(path).name}' has a broken {KEY} record") from None
    if record["version"] != VERSION or size != (record["size"], record["size"]):
        raise LayoutError(f"mask '{Path(path).name}' is laid out in an atlas this gammac does not make "
                          f"(version {record['version']}, {size[0]}x{size[1]} texels)")
    return record


def fingerprint(vertices, triangles, bare) -> str:
    """Of the corners of the triangles without texture coordinates."""
    corners = np.asarray(vertices, np.float32)[np.asarray(triangles, np.int64)[np.asarray(bare, bool)]]
    return hashlib.sha256(np.ascontiguousarray(corners).tobytes()).hexdigest()[:20]


def _bare_uvs(vertices, triangles, bare, size: int) -> np.ndarray:
    from ..outputs.atlas import chart_atlas

    key = (fingerprint(vertices, triangles, bare), size)
    if key not in _cache:
        tris = np.asarray(triangles, np.int64)[bare]
        used, local = np.unique(tris, return_inverse=True)
        atlas = chart_atlas(np.asarray(vertices, np.float32)[used], local.reshape(-1, 3), size)
        _cache.clear()       # one scene at a time: a watch session, a run
        _cache[key] = atlas.uvs[atlas.faces].astype(np.float32)
    return _cache[key]


def _record(vertices, triangles, bare, size: int) -> str:
    return json.dumps({"version": VERSION, "size": size, "mesh": fingerprint(vertices, triangles, bare)})


def atlas_masks(effect) -> dict:
    """{path: record} of the masks the effect reads that are laid out in an atlas."""
    found = {}
    for path in sorted({use[3] for use in effect.mask_uses}):
        record = layout(path)
        if record is not None:
            found[path] = record
    return found


def with_atlas(rt, mesh, has_uv, effect):
    """``mesh`` with the atlas's texture coordinates on its triangles without
    any, when the effect reads masks laid out in the scene's atlas (else
    ``mesh`` itself).  LayoutError when they were laid out for other triangles."""
    has_uv = np.asarray(has_uv, bool)
    masks = atlas_masks(effect)
    if not masks or has_uv.all():
        return mesh
    vertices = np.asarray(mesh.vertices(), np.float32)
    triangles = np.asarray(mesh.triangles(), np.int64)
    bare = ~has_uv
    mine = fingerprint(vertices, triangles, bare)
    sizes = sorted({r["size"] for r in masks.values()})
    for path, record in masks.items():
        if record["mesh"] != mine:
            raise LayoutError(f"mask '{Path(path).name}' was painted on another mesh's atlas (the scene's "
                              "triangles without texture coordinates have changed since): paint it again, "
                              "or move it away and let gammac watch make a new one")
    if len(sizes) > 1:
        raise LayoutError("the masks laid out in the scene's atlas must have one size, not "
                          + ", ".join(f"{s}x{s}" for s in sizes))
    uvs = (np.asarray(mesh.triangle_uvs(), np.float32).reshape(-1, 3, 2).copy() if mesh.has_uvs
           else np.zeros((len(triangles), 3, 2), np.float32))
    uvs[bare] = _bare_uvs(vertices, triangles, bare, sizes[0])
    return rt.Mesh.from_arrays(vertices, triangles.astype(np.int32), uvs)


def create(path: str | Path, vertices, triangles, has_uv, size: int = DEFAULT_SIZE) -> None:
    """A black 8-bit grey PNG, laid out in the atlas of the triangles without
    texture coordinates when there are some (a plain image otherwise),
    written whole or not at all."""
    import os
    import tempfile

    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    path = Path(path)
    bare = ~np.asarray(has_uv, bool)
    info = PngInfo()
    if bare.any():
        info.add_text(KEY, _record(vertices, triangles, bare, size))
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            Image.fromarray(np.zeros((size, size), np.uint8), "L").save(f, format="PNG", pnginfo=info)
        os.replace(temporary, path)
    except BaseException:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        raise


def keep_record(body: bytes, record_of: str | Path) -> bytes:
    """A PNG the page painted (``body``), carrying the atlas record of the
    file it replaces, when that file has one (a browser's PNG has no text)."""
    from io import BytesIO

    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    with Image.open(record_of) as old:
        text = getattr(old, "text", {}).get(KEY)
    if text is None:
        return body
    info = PngInfo()
    info.add_text(KEY, text)
    out = BytesIO()
    with Image.open(BytesIO(body)) as new:
        new.save(out, format="PNG", pnginfo=info)
    return out.getvalue()


def texel_points(mesh, has_uv, size: int) -> tuple[np.ndarray, float]:
    """float32 (size, size, 3): the scene point at each texel centre of the
    atlas of ``mesh``'s triangles without texture coordinates (NaN where no
    triangle is; gutters take their chart's nearest points), and the scene
    units per texel (the atlas's mean), so a brush of r texels is as wide on
    the mesh as in the image."""
    from ..outputs.atlas import dilate, texel_hits

    bare = np.flatnonzero(~np.asarray(has_uv, bool))
    vertices = np.asarray(mesh.vertices(), np.float64)
    triangles = np.asarray(mesh.triangles(), np.int64)[bare]
    uvs = np.asarray(mesh.triangle_uvs(), np.float64).reshape(-1, 3, 2)[bare]
    texels, tris, bary = texel_hits(uvs, size)
    corners = vertices[triangles]
    points = np.full((size * size, 3), np.nan, np.float32)
    points[texels] = np.einsum("kj,kjc->kc", bary, corners[tris])
    chart = np.full(size * size, -1, np.int32)
    chart[texels] = tris.astype(np.int32)   # a triangle is a chart here: gutters fill from one triangle
    filled = dilate(np.nan_to_num(points, nan=0.0).reshape(size, size, 3), chart.reshape(size, size), passes=2)
    # dilate fills two rings around the triangles; the rest stay NaN (no point there)
    reached = np.zeros(size * size, bool)
    reached[texels] = True
    ring = _grow(reached.reshape(size, size), 2)
    out = np.where(ring[..., None], filled, np.nan).astype(np.float32)
    area3 = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    e1, e2 = (uvs[:, 1] - uvs[:, 0]) * size, (uvs[:, 2] - uvs[:, 0]) * size
    area_t = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    per_texel = float(np.sqrt(area3.sum() / area_t.sum())) if area_t.sum() > 0 else 0.0
    return out, per_texel


def _grow(mask: np.ndarray, rings: int) -> np.ndarray:
    out = mask.copy()
    for _ in range(rings):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        grown[1:, 1:] |= out[:-1, :-1]
        grown[1:, :-1] |= out[:-1, 1:]
        grown[:-1, 1:] |= out[1:, :-1]
        grown[:-1, :-1] |= out[1:, 1:]
        out = grown
    return out
