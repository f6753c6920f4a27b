"""What a run writes: PLY maps, false-colour PNG renders, summary.json.

Pure encoders (bytes in memory) plus ``write_json``; every file is written
with ``gamma.files.atomic_write``, so an interrupted run never leaves a
half-written file.  Nothing here touches the simulation.  PNG files are
encoded by the runtime (``encode_pngs``: Pillow's bytes, several pictures
at a time on the runtime's threads with the GIL released); Pillow draws.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ...files import atomic_write


def ply_parts(columns: dict[str, np.ndarray], comments: list[str] = ()) -> tuple[bytes, np.ndarray]:
    """A binary little-endian PLY point cloud, one float32 property per column,
    as (header, table): written one after the other (``atomic_write`` takes
    the pair), the 4.4 MB table of a 100,000-surfel map is not copied twice
    more into one bytes object on the writer's thread."""
    names = list(columns)
    n = len(next(iter(columns.values())))
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {ascii(c)[1:-1]}" for c in comments]  # PLY headers are ASCII
    header.append(f"element vertex {n}")
    header += [f"property float {name}" for name in names]
    header.append("end_header")
    table = np.empty((n, len(names)), dtype="<f4")
    for j, name in enumerate(names):
        table[:, j] = columns[name]
    return ("\n".join(header) + "\n").encode("ascii"), table


def mesh_ply_bytes(vertex_columns: dict[str, np.ndarray], triangles: np.ndarray,
                   comments: list[str] = ()) -> bytes:
    """A binary little-endian PLY triangle mesh: float32 vertex properties
    (x y z nx ny nz, then any others) and faces as uchar-counted int lists."""
    names = list(vertex_columns)
    n = len(next(iter(vertex_columns.values())))
    tris = np.asarray(triangles, np.int64).reshape(-1, 3)
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {ascii(c)[1:-1]}" for c in comments]
    header.append(f"element vertex {n}")
    header += [f"property float {name}" for name in names]
    header += [f"element face {len(tris)}", "property list uchar int vertex_indices", "end_header"]
    table = np.empty((n, len(names)), dtype="<f4")
    for j, name in enumerate(names):
        table[:, j] = vertex_columns[name]
    faces = np.empty(len(tris), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"] = 3
    faces["v"] = tris
    return ("\n".join(header) + "\n").encode("ascii") + table.tobytes() + faces.tobytes()


def _ply_header(data: bytes) -> tuple[list[str], dict[str, int], int]:
    """The header of a PLY this module wrote: the float properties' names,
    each element's count, and where the body starts."""
    names, counts, end = [], {}, 0
    while True:
        nl = data.index(b"\n", end)
        parts = data[end:nl].decode("ascii").split()
        end = nl + 1
        if parts == ["end_header"]:
            return names, counts, end
        if parts[:1] == ["element"]:
            counts[parts[1]] = int(parts[2])
        elif parts[:2] == ["property", "float"]:
            names.append(parts[2])


def read_mesh_ply(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Read back a PLY written by ``mesh_ply_bytes``: (vertex columns, triangles)."""
    data = Path(path).read_bytes()
    names, counts, end = _ply_header(data)
    n, m = counts.get("vertex", 0), counts.get("face", 0)
    size = n * len(names) * 4
    table = np.frombuffer(data[end:end + size], dtype="<f4").reshape(n, len(names))
    faces = np.frombuffer(data[end + size:], dtype=[("n", "u1"), ("v", "<i4", (3,))], count=m)
    return {name: table[:, j].copy() for j, name in enumerate(names)}, faces["v"].astype(np.int64)


def read_ply(path: Path) -> dict[str, np.ndarray]:
    """Read back a PLY written by ``ply_parts`` (tests and tools)."""
    data = Path(path).read_bytes()
    names, counts, end = _ply_header(data)
    n = counts.get("vertex", 0)
    table = np.frombuffer(data[end:], dtype="<f4").reshape(n, len(names))
    return {name: table[:, j].copy() for j, name in enumerate(names)}


# ---- false colour -------------------------------------------------------------

# Polynomial fit of matplotlib's viridis (Matt Zucker's CC0 fit), evaluated
# with Horner's rule; keeps numpy the only dependency for colour mapping.
_VIRIDIS = np.array([
    [0.2777273272234177, 0.005407344544966578, 0.3340998053353061],
    [0.1050930431085774, 1.404613529898575, 1.384590162594685],
    [-0.3308618287255563, 0.214847559468213, 0.09509516302823659],
    [-4.634230498983486, -5.799100973351585, -19.33244095627987],
    [6.228269936347081, 14.17993336680509, 56.69055260068105],
    [4.776384997670288, -13.74514537774601, -65.35303263337234],
    [-5.435455855934631, 4.645852612178535, 26.3124352495832],
])


def viridis(t: np.ndarray) -> np.ndarray:
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)[..., None]
    rgb = _VIRIDIS[6]
    for c in _VIRIDIS[5::-1]:
        rgb = c + t * rgb
    return np.clip(rgb, 0.0, 1.0)


#: zlib level of the false-colour PNGs: 1 encodes in half the time of
#: Pillow's default 6 (the pictures are drawn after the loop, where a user
#: waits for them) for files ~20 % larger.
PNG_COMPRESS_LEVEL = 1
#: Pillow's own level when save() is given none (zlib's default, 6).
PILLOW_DEFAULT_LEVEL = -1


def encode_pngs(pictures: list, level: int, threads: int = 1) -> list[bytes]:
    """The PNG files of ``pictures`` (uint8 [h, w, 3] arrays, or RGB Pillow
    images), byte for byte what Pillow's ``save(format="PNG",
    compress_level=level)`` writes, encoded ``threads`` at a time in the
    runtime without the GIL (Pillow's encoder holds it for the whole picture)."""
    from ... import _runtime

    arrays = [np.ascontiguousarray(np.asarray(p, dtype=np.uint8)) for p in pictures]
    return _runtime.encode_pngs(arrays, level, threads)


def canvas_font(height: int):
    """The font of a false-colour picture ``height`` pixels high: Pillow's
    default font, scaled (its bitmap font where Pillow lacks FreeType); a new
    one each time (a FreeType face is not shared between threads, and
    loading one is cheap beside drawing)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=max(11, height // 40))
    except TypeError:  # Pillow without FreeType
        return ImageFont.load_default()


def false_colour_png(value: np.ndarray, shade: np.ndarray, vmin: float, vmax: float,
                     label: str, title: str) -> bytes:
    """Shaded false-colour image of ``value`` (NaN = background) with a colour bar."""
    h, w = value.shape
    return FalseColourCanvas(w, h, vmin, vmax, label).png(value, shade, title)


class FalseColourCanvas:
    """The frame every false-colour picture of one scale shares (background
    gradient, colour bar, tick labels), drawn once; ``png`` adds one picture.
    A run's renders all have the same size and scale, so only the picture and
    its title are drawn per iteration (the bytes are those of drawing
    everything each time)."""

    BAR_WIDTH = 150

    def __init__(self, width: int, height: int, vmin: float, vmax: float, label: str):
        from PIL import Image, ImageDraw

        w, h = width, height
        self.width, self.height, self.vmin = w, h, vmin
        self.span = span = vmax - vmin if vmax > vmin else 1.0
        # the gradient is the same along a row: each row's byte worked out once, then repeated
        # (the bytes of scaling every pixel: value * 1.0 is value, so the float64 steps are the same)
        shade = (np.linspace(0.97, 0.85, h) * 255 + 0.5).astype(np.uint8)
        self.background = np.ascontiguousarray(np.broadcast_to(shade[:, None, None], (h, w, 3)))
        canvas = Image.new("RGB", (w + self.BAR_WIDTH, h), (255, 255, 255))
        draw = ImageDraw.Draw(canvas)
        self.font = font = canvas_font(h)
        top, bottom = int(h * 0.12), int(h * 0.88)
        x0 = w + 20
        ramp = viridis(np.linspace(1.0, 0.0, bottom - top))
        bar = Image.fromarray((np.repeat(ramp[:, None, :], 24, axis=1) * 255 + 0.5).astype(np.uint8))
        canvas.paste(bar, (x0, top))
        draw.rectangle([x0 - 1, top - 1, x0 + 24, bottom], outline=(0, 0, 0))
        for k in range(5):
            frac = k / 4
            y = bottom - frac * (bottom - top)
            draw.line([x0 + 24, y, x0 + 30, y], fill=(0, 0, 0))
            draw.text((x0 + 34, y), f"{vmin + frac * span:.3g}", fill=(0, 0, 0), font=font, anchor="lm")
        draw.text((x0 - 4, top - 10), label, fill=(0, 0, 0), font=font, anchor="lb")
        self.frame = canvas   # everything right of the picture (nothing is drawn over it)
        self._frame_pixels = np.asarray(canvas)[:, w:]

    def picture(self, value: np.ndarray, shade: np.ndarray) -> np.ndarray:
        """uint8 [h, w, 3]: the shaded colours where ``value`` is a number, the
        background where it is NaN."""
        hit = ~np.isnan(value)
        # float32 arithmetic as numpy does it on the whole image (the bounds are weak scalars)
        t = (value[hit] - self.vmin) / self.span
        rgb = viridis(t) * shade[hit][:, None]
        out = self.background.copy()
        out[hit] = (rgb * 255 + 0.5).astype(np.uint8)
        return out

    #: Where a title is written (its top left corner).
    TITLE_AT = (10, 10)

    def titled(self, picture: np.ndarray, title: str) -> np.ndarray:
        """uint8 [h, w + BAR_WIDTH, 3]: ``picture`` (uint8 [h, w, 3]) at the
        top left of the frame, ``title`` written over it.  The two are put
        side by side in numpy and Pillow writes the title on the few rows it
        covers only: its glyphs land on whole pixels (the corner is whole), so
        the bytes are those of writing it on the whole canvas, without copying
        the whole picture through Pillow (five pictures after a run's loop,
        where a user waits).  (``textbbox`` of a bitmap font, Pillow
        without FreeType, needs Pillow 9.2: pyproject.toml asks for it.)"""
        from PIL import Image, ImageDraw

        h, w = self.height, self.width
        out = np.empty((h, w + self.BAR_WIDTH, 3), np.uint8)
        out[:, :w] = picture
        out[:, w:] = self._frame_pixels
        x, y = self.TITLE_AT
        left, top, right, bottom = ImageDraw.Draw(self.frame).textbbox((x, y), title, font=self.font)
        # a pixel's margin around the box Pillow reports (antialiasing at its edges), on the canvas
        x0, y0 = max(0, min(x, left) - 1), max(0, min(y, top) - 1)
        x1, y1 = min(w + self.BAR_WIDTH, right + 1), min(h, bottom + 1)
        if x1 > x0 and y1 > y0:
            part = Image.fromarray(out[y0:y1, x0:x1])
            ImageDraw.Draw(part).text((x - x0, y - y0), title, fill=(0, 0, 0), font=self.font)
            out[y0:y1, x0:x1] = np.asarray(part)
        return out

    def png(self, value: np.ndarray, shade: np.ndarray, title: str, picture: np.ndarray | None = None) -> bytes:
        """The PNG of one picture (``picture``: ``self.picture(value, shade)`` made elsewhere)."""
        picture = self.picture(value, shade) if picture is None else picture
        return encode_pngs([self.titled(picture, title)], PNG_COMPRESS_LEVEL)[0]


def _finite_or_text(obj):
    """JSON has no NaN/Infinity: non-finite floats are written as strings."""
    if isinstance(obj, float) and not np.isfinite(obj):
        return str(obj)
    if isinstance(obj, dict):
        return {k: _finite_or_text(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite_or_text(v) for v in obj]
    return obj


def write_json(path: Path, obj) -> None:
    text = json.dumps(_finite_or_text(obj), indent=2, allow_nan=False, ensure_ascii=False)
    atomic_write(path, (text + "\n").encode("utf-8"))
