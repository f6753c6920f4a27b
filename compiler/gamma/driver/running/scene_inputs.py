"""What surfels read from the scene at setup (SPEC §12a): ``mask("file")``,
an image's luminance at the surfel's texture coordinates, and
``attribute("NAME")``, a vertex attribute interpolated at the surfel.

Each is one column of every surfel's row, after the properties
(``ir.effect.Input``), written once when the simulation is set up, so
tracing reads it like a property.  ``check`` refuses, with the call's file,
line and column, a mask on a part without texture coordinates and an
attribute that no part has.  Masks are read at full precision: 8- and
16-bit PNG, grey or colour (16-bit PNGs by pypng: Pillow, under imageio,
reads 16-bit colour as 8 bits), anything else imageio reads, OpenEXR.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Luminance of linear-weighted RGB (Rec. 709), applied to the stored values.
LUMINANCE = (0.2126, 0.7152, 0.0722)


class MaskError(Exception):
    pass


def _exr(path: Path) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        channels = f.channels()
        for key in ("Y", "y", "L"):
            if key in channels:
                return np.asarray(channels[key].pixels, np.float32)
        if "RGB" in channels or "RGBA" in channels:
            rgb = np.asarray(channels["RGB" if "RGB" in channels else "RGBA"].pixels, np.float32)
            return rgb[..., :3]
        if all(c in channels for c in "RGB"):
            return np.stack([np.asarray(channels[c].pixels, np.float32) for c in "RGB"], axis=-1)
        first = next(iter(channels.values()))
        return np.asarray(first.pixels, np.float32)


def _png16(path: Path) -> np.ndarray | None:
    """A 16-bit PNG's samples (uint16, height x width x channels), or None for another PNG."""
    with open(path, "rb") as f:
        head = f.read(26)
    if head[:8] != b"\x89PNG\r\n\x1a\n" or head[24] != 16:
        return None
    import png

    width, height, rows, info = png.Reader(filename=str(path)).asDirect()
    image = np.vstack([np.asarray(row, np.uint16) for row in rows])
    return image.reshape(height, width, info["planes"])


def load_mask(path: str | Path) -> np.ndarray:
    """The image's luminance, float32 (height, width), values in [0, 1] for
    integer images (8 or 16 bits as stored), as stored for float images."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".exr":
            image = _exr(path)
        elif (image := _png16(path)) is not None:
            pass
        else:
            import imageio.v3 as iio

            image = iio.imread(path)
    except Exception as err:   # a bad image: the libraries raise many kinds
        raise MaskError(f"cannot read mask '{path}': {err or type(err).__name__}") from None
    image = np.asarray(image)
    if image.ndim == 4:                 # an animation: its first frame
        image = image[0]
    if np.issubdtype(image.dtype, np.integer):
        image = image.astype(np.float64) / float(np.iinfo(image.dtype).max)
    image = image.astype(np.float64)
    if image.ndim == 3:
        if image.shape[2] >= 3:
            image = image[..., 0] * LUMINANCE[0] + image[..., 1] * LUMINANCE[1] + image[..., 2] * LUMINANCE[2]
        else:
            image = image[..., 0]       # grey, grey + alpha
    if image.ndim != 2 or image.size == 0:
        raise MaskError(f"cannot read mask '{path}': not an image")
    return image.astype(np.float32)


def sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples at texture coordinates (n, 2), as the runtime samples
    texture() (gamma/render.h ``sample_texture``): repeat, v up, pixel centres."""
    h, w = image.shape
    u = np.nan_to_num(uv[:, 0].astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    v = np.nan_to_num(uv[:, 1].astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    u, v = u - np.floor(u), v - np.floor(v)
    x, y = u * w - 0.5, (1.0 - v) * h - 0.5
    xf, yf = np.floor(x), np.floor(y)
    fx, fy = x - xf, y - yf
    x0, x1 = np.mod(xf.astype(np.int64), w), np.mod(xf.astype(np.int64) + 1, w)
    y0, y1 = np.mod(yf.astype(np.int64), h), np.mod(yf.astype(np.int64) + 1, h)
    img = image.astype(np.float64)
    a, b, d, e = img[y0, x0], img[y0, x1], img[y1, x0], img[y1, x1]
    top, bottom = a + fx * (b - a), d + fx * (e - d)
    return (top + fy * (bottom - top)).astype(np.float32)


def as_texture(path: str | Path) -> np.ndarray:
    """A mask as one of the renderer's textures (float32 [h, w, 3], the luminance in every channel)."""
    return np.repeat(load_mask(path)[..., None], 3, axis=2)


# ---- checks against the scene --------------------------------------------------------

def _surface_parts(scene, effect, surface: str, where: np.ndarray) -> list[str]:
    """Names of the objects with triangles of ``surface`` among ``where`` (bool per triangle)."""
    index = effect.surfaces[surface].index
    mine = (np.asarray(scene.triangle_surface) == index) & where
    objects = np.unique(np.asarray(scene.triangle_object)[mine]) if scene.triangle_object is not None else []
    return [scene.object_names[i] for i in objects]


def problems(effect, scene) -> list:
    """Diagnostics (errors and warnings, with the calls' positions) of the
    effect's mask() and attribute() calls on this scene."""
    from ...frontend.diagnostics import Diagnostic

    found = []
    if effect.mask_uses and scene.triangle_has_uv is not None:
        from .mask_atlas import LayoutError, layout

        bare = ~np.asarray(scene.triangle_has_uv, bool)
        for pos, file, surface, path in effect.mask_uses:
            try:
                if layout(path) is not None:
                    continue        # laid out in the scene's atlas (mask_atlas.py), checked with the scene
            except LayoutError as err:
                found.append(Diagnostic(pos, str(err), "error", file))
                continue
            parts = _surface_parts(scene, effect, surface, bare)
            if parts:
                found.append(Diagnostic(pos, f"mask() reads texture coordinates, and part "
                                        f"{', '.join(repr(p) for p in parts[:6])} (surface {surface}) has none; "
                                        "give it UVs, bind it to another surface, or paint the mask in "
                                        "gammac watch, which lays a new mask out in the scene's atlas "
                                        "(move this one away first)", "error", file))
    table = scene.vertex_attributes or {}
    for item in effect.inputs:
        if item.kind != "attribute":
            continue
        have = table.get(item.key.lower())
        for pos, file, surface, text in item.uses:
            if have is None:
                known = sorted({n for names in (scene.part_attribute_names or {}).values() for n in names})
                found.append(Diagnostic(pos, f"no part of the scene has a vertex attribute '{item.key}' "
                                        f"(they have: {', '.join(known[:12]) or 'none'})", "error", file))
                break
            lacking = _parts_lacking(scene, effect, surface, have[1])
            if lacking:
                found.append(Diagnostic(pos, f"{text}: part {', '.join(repr(p) for p in lacking[:6])} "
                                        f"(surface {surface}) has no vertex attribute '{item.key}': it reads 0 there",
                                        "warning", file))
    return found


def _parts_lacking(scene, effect, surface: str, present: np.ndarray) -> list[str]:
    tris = np.asarray(scene.mesh.triangles(), np.int64)
    without = ~present[tris].all(axis=1)
    return _surface_parts(scene, effect, surface, without)


# ---- the columns ---------------------------------------------------------------------

def columns(effect, scene, sim) -> np.ndarray:
    """Every surfel's value of every Input, float32 (surfels, inputs)."""
    n = sim.num_surfels
    out = np.zeros((n, len(effect.inputs)), np.float32)
    if not effect.inputs:
        return out
    uv = None
    tri = positions = None
    for k, item in enumerate(effect.inputs):
        if item.kind == "mask":
            if uv is None:
                uv = np.asarray(sim.surfel_measures()[3], np.float32)
                if len(uv) != n:
                    raise RuntimeError("mask(): the runtime measured no texture coordinates")
            try:
                out[:, k] = sample(load_mask(item.key), uv)
            except MaskError as err:
                from .common import RunError

                raise RunError(str(err)) from None
        else:
            values, _ = scene.vertex_attributes[item.key.lower()]
            if tri is None:
                tri = np.asarray(sim.surfel_triangles(), np.int64)
                positions = np.asarray(sim.surfel_positions(), np.float32)
                mesh_vertices = np.asarray(scene.mesh.vertices(), np.float32)
                mesh_triangles = np.asarray(scene.mesh.triangles(), np.int64)
            from .vertex_attributes import at_surfels

            out[:, k] = at_surfels(values, mesh_vertices, mesh_triangles, tri, positions)
    return out


def write(sim, effect, values: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray | None:
    """Put the inputs' columns into ``rows`` (or the simulation's own rows)."""
    if not effect.inputs:
        return rows
    slots = [item.slot for item in effect.inputs]
    own = rows is None
    if own:
        rows = np.array(sim.rows(), dtype=np.float32, copy=True)
    rows[:, slots] = values
    if own:
        sim.set_rows(np.ascontiguousarray(rows))
    return rows
