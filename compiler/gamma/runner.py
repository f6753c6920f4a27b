"""``gammac run``: compile an effect, hand its kernels to the C++ runtime,
iterate (trace, merge, update) and write the outputs.

This module (with ``scene.py``, which assembles the mesh) is what talks to
``gamma._runtime``: it turns a checked ``Effect`` plus command-line options
into the runtime's ``Config`` and the run's outputs.
"""

from __future__ import annotations

import io
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import abi, __version__
from .ast import Pos
from .backend import JitKernels
from .checker import Effect, Length, Source
from .diagnostics import Diagnostic, GammaError
from .outputs import atomic_write, false_colour_png, ply_bytes, write_json


class RunError(Exception):
    """A one-line, user-facing error (bad mesh, bad option value)."""


@dataclass
class RunOptions:
    scene: str
    out: str
    assign: list[str] = field(default_factory=list)   # PATTERN=SURFACE or SURFACE
    down: tuple[float, float, float] | None = None    # None: the scene file's, else -y
    view: tuple[float, float, float] | None = None    # camera direction from the scene's centre
    eye: tuple[float, float, float] | None = None     # camera position (overrides view)
    fov: float = 30.0                                 # vertical field of view, degrees
    iterations: int = 10
    surfels: int = 100_000
    tons: int | None = None
    seed: int = 1
    threads: int = 0              # 0 = all cores
    max_interactions: int = 100
    show: str | None = None       # property rendered in false colour
    width: int = 512
    height: int = 512
    export: bool = False        # glTF / OBJ (+ baked textures) per iteration
    bake_size: int = 1024       # baked texture width and height
    samples: int = 4            # camera rays per pixel (appearance renders)
    ao_samples: int = 8         # ambient-occlusion rays per hit
    progress: bool = True


def runtime_module():
    from . import _runtime as rt

    if rt.ABI_VERSION != abi.ABI_VERSION:
        raise RunError(f"runtime ABI {rt.ABI_VERSION} does not match compiler ABI "
                       f"{abi.ABI_VERSION}; reinstall the package")
    return rt


#: Defaults for ton types that do not say, as fractions of the scene diagonal.
DEFAULT_BOUNCE = Length(0.02, relative=True)
DEFAULT_STEP = Length(0.005, relative=True)
DEFAULT_DRIP_DEGREES = 10.0  # SPEC §4: water clings to walls and slight overhangs
#: Upper bounds on options, so a typo cannot ask for terabytes.
LIMITS = {"--iterations": (1, 1_000_000), "--surfels": (1, 20_000_000),
          "--threads": (0, 256), "--tons": (0, 10**12), "--max-interactions": (1, 10**6),
          "--size": (16, 8192), "--seed": (0, 2**63 - 1), "--samples": (1, 64), "--ao": (0, 256),
          "--bake-size": (8, 8192)}


def check_limits(opts: "RunOptions") -> None:
    values = {"--iterations": opts.iterations, "--surfels": opts.surfels, "--threads": opts.threads,
              "--tons": opts.tons or 0, "--max-interactions": opts.max_interactions,
              "--size": min(opts.width, opts.height), "--seed": opts.seed,
              "--samples": opts.samples, "--ao": opts.ao_samples, "--bake-size": opts.bake_size}
    for name, value in values.items():
        low, high = LIMITS[name]
        if not low <= value <= high:
            raise RunError(f"{name} must be between {low} and {high:,}, not {value}")


def split_counts(counts: list[int], total: int) -> list[int]:
    """Split ``total`` in proportion to ``counts`` (largest remainder; sums exactly)."""
    whole = sum(counts)
    exact = [total * c / whole for c in counts]
    out = [int(math.floor(x)) for x in exact]
    order = sorted(range(len(counts)), key=lambda i: (out[i] - exact[i], i))
    for i in order[: total - sum(out)]:
        out[i] += 1
    return out


def _direction(value, down) -> tuple[float, float, float]:
    if value == "down":
        return tuple(down)
    if value == "up":
        return tuple(-c for c in down)
    return tuple(value)


def source_arguments(src: Source, lo, hi, diagonal: float, down) -> dict:
    """The runtime's ``add_source`` keyword arguments, in scene units."""
    p = src.params
    args = {"first_iteration": src.first, "last_iteration": src.last, "strength": src.strength or 0.0}
    if "position" in p:
        args["position"] = p["position"].resolve(lo, hi)
    if "direction" in p:
        args["direction"] = _direction(p["direction"], down)
    if "normal" in p:
        args["direction"] = _direction(p["normal"], down)
    if "angle" in p:
        args["angle_deg"] = p["angle"]
        args["falloff"] = p["falloff"]
    if p.get("size") is not None:
        args["size"] = tuple(length.resolve(diagonal) for length in p["size"])
    if p.get("radius") is not None:
        args["radius"] = p["radius"].resolve(diagonal)
    if "emission" in p:
        args["emission"] = p["emission"]
    return args


def build_config(rt, effect: Effect, kernels: JitKernels, opts: "RunOptions", bounds, down):
    lo, hi = (np.asarray(b, float) for b in bounds)
    diagonal = float(np.linalg.norm(hi - lo))
    cfg = rt.Config()
    cfg.surfels = opts.surfels
    cfg.seed = opts.seed
    cfg.threads = opts.threads or _cpu_count()
    cfg.max_interactions = opts.max_interactions
    cfg.row_width = effect.row_width
    cfg.down = tuple(float(c) for c in down)
    cfg.surface_rows = [s.initial_row + [0.0] * (effect.row_width - len(s.initial_row))
                        for s in effect.surfaces.values()]
    for ton in effect.tons.values():
        bounce = (ton.bounce or DEFAULT_BOUNCE).resolve(diagonal)
        step = (ton.step or DEFAULT_STEP).resolve(diagonal)
        drip = DEFAULT_DRIP_DEGREES if ton.drip is None else ton.drip
        cfg.add_ton_type(*ton.motion, ton.initial, bounce, step, drip)
    counts = [s.count for s in effect.sources]
    if opts.tons is not None:
        counts = split_counts(counts, opts.tons)
    for src, count in zip(effect.sources, counts):
        cfg.add_source(src.kind, src.ton, count, **source_arguments(src, lo, hi, diagonal, down))
    for k in effect.transport_kernels():
        cfg.set_transport(abi.EVENTS[k.event], k.ton.index, k.surface.index,
                          kernels.address[k.symbol], k.writes_surface)
    for k in effect.update_kernels():
        cfg.set_update(k.surface.index, kernels.address[k.symbol])
    for k in effect.appearance_kernels():
        cfg.set_appearance(k.surface.index, kernels.address[k.symbol])
    return cfg


def load_textures(effect: Effect) -> list[np.ndarray]:
    """Every texture() image as float32 [H, W, 3] in [0, 1] (display values)."""
    from PIL import Image, UnidentifiedImageError

    images = []
    for path in effect.textures:
        try:
            with Image.open(path) as image:
                images.append(np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0)
        except (OSError, UnidentifiedImageError) as err:
            raise RunError(f"cannot read texture '{path}': {err}") from None
    return images


def sun_direction(camera) -> tuple[float, float, float]:
    """Toward the sun: above the scene, over the camera's left shoulder."""
    eye, target, up, _ = (np.asarray(v, float) if i < 3 else v for i, v in enumerate(camera))
    view = eye - target
    view /= np.linalg.norm(view)
    left = np.cross(up, view)
    sun = 1.0 * up + 0.45 * view + 0.5 * left
    return tuple(sun / np.linalg.norm(sun))


DEFAULT_VIEW = (-0.6, 0.35, 1.0)   # front-left-above for a +z-facing, y-up model


def auto_camera(bounds, view=DEFAULT_VIEW, down=(0.0, -1.0, 0.0), fov_deg: float = 30.0):
    """Eye, target and up framing the scene's bounding box; ``view`` points from
    the scene's centre toward the camera, "up" is against gravity."""
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    centre = (lo + hi) / 2
    radius = np.linalg.norm(hi - lo) / 2
    direction = np.asarray(view, float)
    direction /= np.linalg.norm(direction)
    up = -np.asarray(down, float) / np.linalg.norm(down)
    if not 1.0 <= fov_deg <= 170.0:
        raise RunError(f"--fov must be between 1 and 170 degrees, not {fov_deg:g}")
    if abs(float(np.dot(up, direction))) > 0.999:   # looking straight along gravity
        up = np.array([0.0, 0.0, -1.0]) if abs(up[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    distance = radius / math.sin(math.radians(fov_deg) / 2) * 1.02
    return tuple(centre + direction * distance), tuple(centre), tuple(up), fov_deg


class Progress:
    """A one-line progress bar on a terminal; a line per step otherwise."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, enabled
        self.tty = sys.stderr.isatty()

    def update(self, done: int, note: str) -> None:
        if not self.enabled:
            return
        width = 30
        filled = int(width * done / max(1, self.total))
        line = f"[{'#' * filled}{'.' * (width - filled)}] {done}/{self.total} {note}"
        if self.tty:
            sys.stderr.write("\r" + line.ljust(100)[:120])
            if done == self.total:
                sys.stderr.write("\n")
        else:
            sys.stderr.write(line + "\n")
        sys.stderr.flush()


def property_columns(effect: Effect, rows: np.ndarray, surfel_surface: np.ndarray) -> dict:
    """One column per property name of any surface; 0 where a surfel's surface lacks it."""
    columns: dict[str, np.ndarray] = {}
    for surface in effect.surfaces.values():
        mine = surfel_surface == surface.index
        if not mine.any():
            continue
        for name, slot in surface.properties.items():
            column = columns.setdefault(name, np.zeros(len(rows), np.float32))
            column[mine] = rows[mine, slot]
    return columns


OUTPUT_FOLDERS = ("maps", "renders", "renders/false_colour", "export")


def prepare_output(out: Path) -> None:
    """Create the folders up front, so an unwritable --out fails before any work."""
    try:
        for sub in OUTPUT_FOLDERS:
            (out / sub).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RunError(f"cannot write to '{out}': {err.strerror or err}") from None


def clear_earlier_run(out: Path) -> None:
    """Drop an earlier run's iteration files, so the folder describes one run.
    Called only once this run has been set up without error: a run that fails
    early leaves the earlier results alone."""
    try:
        for sub in OUTPUT_FOLDERS:
            for stale in (out / sub).glob("iter_[0-9][0-9][0-9][0-9]*"):
                stale.unlink()
        for stale in (out / "export").glob("*/iter_[0-9][0-9][0-9][0-9]*"):
            stale.unlink()
        for stale in ("sequence.gif", "sequence.mp4", "strip.png"):
            (out / "renders" / stale).unlink(missing_ok=True)
    except OSError as err:
        raise RunError(f"cannot write to '{out}': {err.strerror or err}") from None


STAT_KEYS = ("emitted", "settled", "escaped", "capped", "interactions", "rays",
             "bounces", "flow_steps", "drips", "segments")


def run(effect: Effect, opts: RunOptions) -> dict:
    from .scene import SceneError, load_scene

    check_limits(opts)
    if not effect.sources:
        raise GammaError(effect.path, effect.source, [Diagnostic(
            Pos(1, 1), "the effect declares no source, so no gamma-ton would be traced")])
    rt = runtime_module()
    try:
        scene = load_scene(rt, opts.scene, effect, opts.assign, opts.down)
    except SceneError as err:
        raise RunError(str(err)) from None
    mesh = scene.mesh
    if mesh.degenerate_dropped:
        print(f"gammac: warning: {mesh.degenerate_dropped} degenerate triangles of "
              f"'{opts.scene}' ignored", file=sys.stderr)
    present = [s for s in effect.surfaces.values() if scene.triangles_per_surface[s.name]]
    shown = opts.show or next((n for s in present for n in s.properties), None)
    if shown is not None and not any(shown in s.properties for s in present):
        raise RunError(f"--show {shown}: no surface of the scene has that property "
                       f"({', '.join(sorted({n for s in present for n in s.properties})) or 'none'})")
    out = Path(opts.out)
    prepare_output(out)
    kernels = JitKernels(effect)
    t0 = time.perf_counter()
    try:
        cfg = build_config(rt, effect, kernels, opts, scene.bounds, scene.down)
        cfg.triangle_surface = scene.triangle_surface
        sim = rt.Simulation(mesh, cfg)
    except (ValueError, TypeError, RuntimeError) as err:
        raise RunError(str(err).removeprefix("config: ")) from None
    setup_seconds = time.perf_counter() - t0
    looks = bool(effect.appearance_kernels())
    if looks:
        sim.set_textures(load_textures(effect))
    camera = auto_camera(scene.bounds, opts.view or DEFAULT_VIEW, scene.down, opts.fov)
    if opts.eye is not None:
        _, target, up, fov = camera
        if np.allclose(opts.eye, target):
            raise RunError("--eye must not be the centre of the scene, which the camera looks at")
        camera = (tuple(opts.eye), target, up, fov)
    frames = []
    pieces = None       # the scene's objects for --export, made on first use
    clear_earlier_run(out)

    surfel_surface = np.asarray(sim.surfel_surfaces())
    pos, nrm = sim.surfel_positions(), sim.surfel_normals()
    static = {axis: pos[:, j] for j, axis in enumerate("xyz")}
    static.update({axis: nrm[:, j] for j, axis in enumerate(("nx", "ny", "nz"))})
    static["surface"] = surfel_surface.astype(np.float32)
    threads = min(opts.threads or _cpu_count(), LIMITS["--threads"][1])
    summary = {
        "effect": str(effect.path), "scene": str(opts.scene),
        "surfaces": {name: {"triangles": count, "surfels": int(np.sum(surfel_surface == s.index))}
                     for (name, count), s in zip(scene.triangles_per_surface.items(),
                                                 effect.surfaces.values())},
        "surfels": sim.num_surfels, "triangles": mesh.num_triangles, "threads": threads,
        "seed": opts.seed, "down": list(scene.down), "setup_seconds": setup_seconds,
        "versions": {"gamma": __version__, "abi": abi.ABI_VERSION,
                     "llvm": ".".join(map(str, llvm_version())),
                     "runtime": getattr(rt, "RUNTIME_VERSION", None),
                     "embree": getattr(rt, "EMBREE_VERSION", None)},
        "rendered": shown,
        "appearance": bool(effect.appearance_kernels()),
        "iterations": [],
    }
    history = []
    report = NonFiniteReport(effect, opts.progress)
    summary["nonfinite"] = report.entries
    progress = Progress(opts.iterations, opts.progress)
    comments = [f"gamma {__version__}", f"effect {Path(effect.path).name}"]
    try:
        for it in range(1, opts.iterations + 1):
            stats = sim.trace(it)
            updated = sim.update(it)
            report.add(it, stats["nonfinite"], updated["nonfinite"])
            rows = sim.rows()
            props = property_columns(effect, rows, surfel_surface)
            record = {k: stats[k] for k in STAT_KEYS if k in stats}
            record["property_sums"] = {name: float(np.sum(col, dtype=np.float64))
                                       for name, col in props.items()}
            record["trace_seconds"] = stats["trace_seconds"]
            record["update_seconds"] = updated["seconds"]
            summary["iterations"].append(record)
            columns = dict(static, **props)
            for j, name in enumerate(abi.REFLECTANCE_SLOTS):
                columns[f"reflectance_{name}"] = rows[:, j]
            atomic_write(out / "maps" / f"iter_{it:04d}.ply",
                         ply_bytes(columns, comments + [f"iteration {it}"]))
            write_json(out / "summary.json", summary)
            if shown is not None:
                history.append(props[shown].copy())
            if looks:
                frames.append(render_appearance(sim, out, opts, threads, camera, it))
            if opts.export:
                if pieces is None:
                    from .export import pieces as split

                    pieces = split(scene)
                export_iteration(sim, scene, effect, out / "export", it, threads, opts.bake_size, pieces)
            rate = stats["emitted"] / max(stats["trace_seconds"], 1e-9)
            progress.update(it, f"iterations  {stats['trace_seconds']:.2f} s trace  "
                                f"{rate / 1e3:.0f}k γ-tons/s")
        if shown is not None:
            folder = out / "renders" / ("false_colour" if looks else "")
            render_history(sim, history, shown, folder, opts, threads, camera)
        if frames:
            write_sequence(frames, out / "renders")
    except OSError as err:
        raise RunError(f"cannot write to '{out}': {err.strerror or err}") from None
    return summary


class NonFiniteReport:
    """Statements whose result was NaN or infinite (the kernels skip such
    stores): each is reported once, on first sight, and counted in summary.json."""

    def __init__(self, effect: Effect, show: bool):
        self.effect, self.show = effect, show
        self.entries: list[dict] = []
        self.by_key: dict = {}
        self.kernels = {(abi.EVENTS[k.event], k.ton.index, k.surface.index): k
                        for k in effect.transport_kernels()}
        self.kernels.update({(-1, 0, k.surface.index): k for k in effect.update_kernels()})

    def add(self, iteration: int, *lists) -> None:
        for items in lists:
            for event, ton, surface, statement, count in items:
                kernel = self.kernels[(event, ton if event >= 0 else 0, surface)]
                scope, st = kernel.statement_at(statement)
                where = f"{scope.origin}:{st.target.pos.line}:{st.target.pos.col}"
                key = (where, kernel.label)
                if key not in self.by_key:
                    entry = {"where": where, "rule": kernel.label, "count": 0, "first_iteration": iteration}
                    self.by_key[key] = entry
                    self.entries.append(entry)
                    print(f"\ngammac: warning: {where}: in {kernel.label}, "
                          f"'{'.'.join(st.target.parts)} {st.op} ...' gave NaN or infinity "
                          f"{count} times in iteration {iteration}; those results were not stored",
                          file=sys.stderr)
                self.by_key[key]["count"] += count


def llvm_version():
    import llvmlite.binding

    return llvmlite.binding.llvm_version_info


def export_iteration(sim, scene, effect: Effect, folder: Path, it: int, threads: int, size: int,
                     pieces) -> None:
    """Per object, in folder/OBJECT/: iter_NNNN.glb, .obj + .mtl, the baked
    colour (8-bit PNG) and every property (16-bit PNG)."""
    from .export import bake, png16, png8, texture_from_texels, vertex_data, write_glb, write_obj

    stem = f"iter_{it:04d}"
    for piece in pieces:
        where = folder / _safe_name(piece.name)
        positions, normals, uvs, tris, rows, rgb, owner = vertex_data(sim, piece, it, threads)
        surfaces = np.asarray(scene.triangle_surface)[owner]
        attributes = property_columns(effect, rows, surfaces)
        extras = {"gamma": {"iteration": it, "object": piece.name, "properties": {}}}
        colour, texels, texel_tris, texel_rows = bake(sim, piece, size, it, threads)
        texture = png8(colour)
        atomic_write(where / f"{stem}_color.png", texture)
        texel_surfaces = np.asarray(scene.triangle_surface)[texel_tris]
        for name, column in property_columns(effect, texel_rows, texel_surfaces).items():
            data, low, high = png16(texture_from_texels(column, texels, size)[..., 0])
            atomic_write(where / f"{stem}_{name}.png", data)
            extras["gamma"]["properties"][name] = {"texture": f"{stem}_{name}.png", "min": low, "max": high}
        atomic_write(where / f"{stem}.mtl",
                     f"newmtl {stem}\nKd 1 1 1\nmap_Kd {stem}_color.png\n".encode("ascii"))
        atomic_write(where / f"{stem}.glb",
                     write_glb(positions, normals, uvs, tris, rgb, attributes, texture, extras))
        atomic_write(where / f"{stem}.obj", write_obj(positions, normals, uvs, tris, stem))


def _safe_name(name: str) -> str:
    """An object name as a folder name."""
    import re

    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "object"


def render_appearance(sim, out: Path, opts: RunOptions, threads: int, camera, iteration: int):
    """The scene as its appearance blocks paint it (sun, sky, ambient occlusion)."""
    from PIL import Image

    eye, target, up, fov = camera
    image = sim.render_appearance(eye, target, up, fov, opts.width, opts.height, threads,
                                  opts.samples, sun_direction(camera), opts.ao_samples, iteration)
    rgb = np.clip(np.asarray(image)[..., :3], 0.0, 1.0)
    picture = Image.fromarray((rgb * 255 + 0.5).astype(np.uint8))
    buffer = io.BytesIO()
    picture.save(buffer, format="PNG")
    atomic_write(out / "renders" / f"iter_{iteration:04d}.png", buffer.getvalue())
    return picture


def write_sequence(frames: list, folder: Path) -> None:
    """The iterations as an animated GIF, an MP4 and a strip of (at most 5) of them."""
    buffer = io.BytesIO()
    frames[0].save(buffer, format="GIF", save_all=True, append_images=frames[1:], duration=400, loop=0)
    atomic_write(folder / "sequence.gif", buffer.getvalue())
    write_mp4(frames, folder / "sequence.mp4")
    chosen = sorted({round(i * (len(frames) - 1) / 4) for i in range(5)}) if len(frames) > 1 else [0]
    from PIL import Image, ImageDraw

    w, h = frames[0].size
    strip = Image.new("RGB", (w * len(chosen), h), (255, 255, 255))
    draw = ImageDraw.Draw(strip)
    for slot, index in enumerate(chosen):
        strip.paste(frames[index], (slot * w, 0))
        draw.text((slot * w + 8, 8), f"iteration {index + 1}", fill=(0, 0, 0))
    buffer = io.BytesIO()
    strip.save(buffer, format="PNG")
    atomic_write(folder / "strip.png", buffer.getvalue())


def write_mp4(frames: list, path: Path, fps: int = 4) -> None:
    """H.264 video (imageio-ffmpeg), via a temporary file renamed into place."""
    import os
    import tempfile

    import imageio.v2 as imageio

    fd, tmp = tempfile.mkstemp(prefix=".sequence.", suffix=".mp4", dir=path.parent)
    os.close(fd)
    try:
        # yuv420p needs even sizes: pad by one pixel where needed
        w, h = frames[0].size
        pad = ((0, h % 2), (0, w % 2), (0, 0))
        with imageio.get_writer(tmp, fps=fps, codec="libx264", macro_block_size=1,
                                ffmpeg_log_level="error", pixelformat="yuv420p") as writer:
            for frame in frames:
                writer.append_data(np.pad(np.asarray(frame.convert("RGB")), pad, mode="edge"))
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def render_history(sim, history, shown, out: Path, opts: RunOptions, threads: int, camera) -> None:
    """One false-colour PNG per iteration, all on the same colour scale
    (non-finite values, which a rule can produce, are left out of the scale)."""
    finite = [h[np.isfinite(h)] for h in history]
    vmax = max((float(np.percentile(f, 99.5)) for f in finite if f.size), default=1.0)
    vmin = min(0.0, min((float(f.min()) for f in finite if f.size), default=0.0))
    if vmax <= vmin:
        vmax = vmin + 1.0
    eye, target, up, fov = camera
    for it, values in enumerate(history, start=1):
        values = np.nan_to_num(values, nan=vmin, posinf=vmax, neginf=vmin).astype(np.float32)
        value, shade = sim.render(np.ascontiguousarray(values), eye, target, up,
                                  fov, opts.width, opts.height, threads)
        png = false_colour_png(value, shade, vmin, vmax, shown, f"{shown}, iteration {it}")
        atomic_write(out / f"iter_{it:04d}.png", png)


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
