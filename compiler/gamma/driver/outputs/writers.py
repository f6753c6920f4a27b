"""The standard outputs of ``gammac run``, each a ``Writer`` (see ``events.py``).

    MapWriter            maps/iter_NNNN.ply per iteration
    SummaryWriter        summary.json, rewritten after every iteration
    FalseColourWriter    renders[/false_colour]/iter_NNNN.png of one property, one scale
    AppearanceWriter     renders/iter_NNNN.png as the appearance blocks paint it,
                         then sequence.gif, sequence.mp4, strip.png
    MeshWriter           meshes/iter_NNNN.ply when the shape changes (SPEC §19)
    ExportWriter         export/: the scene's glb, per object its texture set, OBJ and sidecar
    ProgressWriter       the progress bar on stderr

``standard_writers`` picks them for a run's options, in the order above (the
order the files were always written in).  Each handler asks the simulation
for what it needs on the loop's thread and hands encoding and writing to
``run.behind``.  These writers own the output layout of ``DIR``; they never
change the simulation.
"""

from __future__ import annotations

import copy
import io
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from ... import abi
from ...version import version
from ...files import atomic_write
from ..running.camera import sun_direction
from ..running.events import IterationUpdated, RunFinished, Writer
from .outputs import mesh_ply_bytes, ply_parts, write_json


def _timed_on_loop(kind: str):
    """A handler whose time on the loop's thread counts under ``kind`` (events.Timings)."""
    def wrap(handler):
        def timed(self, event):
            with event.run.behind.timings.timed(kind):
                handler(self, event)
        timed.__doc__, timed.__name__ = handler.__doc__, handler.__name__
        return timed
    return wrap


class MapWriter(Writer):
    """maps/iter_NNNN.ply: position, normal, surface, every property, the reflectance."""

    def on_iteration_updated(self, event: IterationUpdated) -> None:
        run, it = event.run, event.iteration
        columns = dict(run.static_columns, **event.properties)
        for j, name in enumerate(abi.REFLECTANCE_SLOTS):
            columns[f"reflectance_{name}"] = event.rows[:, j]
        comments = [f"gamma {version()}", f"effect {Path(run.effect.path).name}", f"iteration {it}"]
        run.behind.timed("maps", _write_ply, run.out / "maps" / f"iter_{it:04d}.ply", columns, comments)


def _write_final_summary(run, summary: dict) -> None:
    summary["nonfinite"] = copy.deepcopy(run.summary["nonfinite"])   # with the last renders' reports
    add_output_times(run, summary)
    write_json(run.out / "summary.json", summary)


#: Timings kinds that are not outputs (events.WriteQueue).
WAITING = "waiting for the writer"


def add_output_times(run, summary: dict) -> None:
    """What the outputs cost (every job before this one is done): seconds per
    kind of output, on any thread (busy time: behind the loop it overlaps the
    trace), the loop's waits for the writer, and the wall time from the end of
    the loop to now (what a user waits for once the last iteration is traced)."""
    import time

    seconds = run.behind.timings.snapshot()
    summary["writer_wait_seconds"] = seconds.pop(WAITING, 0.0)
    summary["output_seconds"] = seconds
    if run.loop_ended is not None:
        summary["finish_seconds"] = time.perf_counter() - run.loop_ended


def _write_ply(path: Path, columns: dict, comments: list[str]) -> None:
    atomic_write(path, ply_parts(columns, comments))


class SummaryWriter(Writer):
    """summary.json as it stands after each iteration (a snapshot: the loop goes on)."""

    def on_iteration_updated(self, event: IterationUpdated) -> None:
        event.run.behind.timed("summary", write_json, event.run.out / "summary.json",
                               copy.deepcopy(event.run.summary))


class CompletionWriter(Writer):
    """summary.json once more, after every other output of the run has been
    queued: its ``"completed": true`` means the folder holds the whole run."""

    def on_run_finished(self, event: RunFinished) -> None:
        event.run.behind(_write_final_summary, event.run, copy.deepcopy(event.run.summary))


class FalseColourWriter(Writer):
    """One false-colour PNG per iteration of ``property``, all on the scale of
    the whole run, so they are drawn once the run is finished (non-finite
    values, which a rule can produce, are left out of the scale)."""

    def __init__(self, property: str, folder: Path):
        self.property, self.folder = property, folder
        self.history: list[np.ndarray] = []
        # per iteration: value_range of its values, worked out behind the loop (UNMEASURED
        # until then; the last iteration's and any the writer has not reached are worked
        # out once the loop is done)
        self.ranges: list = []
        self.casting = None             # the view's rays being cast (a background.Outcome), if they are

    def on_setup_done(self, event) -> None:
        # a resumed run: the earlier iterations' values, from their maps
        from .outputs import read_ply

        run = event.run
        for it in range(1, run.first_iteration):
            self.history.append(read_ply(run.out / "maps" / f"iter_{it:04d}.ply")[self.property])
            self.ranges.append(UNMEASURED)
        # An effect that never changes the shape has its final geometry now: the rays of every
        # picture are cast beside the loop (no GIL; on the cores its serial stretches leave),
        # not after it, where a user waits for the pictures.
        from ..running.common import shape_changes

        if not shape_changes(run.effect):
            self.casting = self._cast(run, keep=True)

    #: Largest picture whose rays are kept for every iteration's picture
    #: (a FalseColourView holds ~100 bytes per pixel); a larger one casts them
    #: again per picture.
    VIEW_PIXELS = 1 << 20

    def _cast(self, run, keep: bool = False):
        """The view's rays cast on a thread of their own (an Outcome), or None for
        a picture too large to keep them.  ``keep``: the geometry never
        changes, so the view is read from the cache of views if it holds it
        (view_cache.py), and kept there once cast if not."""
        if run.opts.width * run.opts.height > self.VIEW_PIXELS:
            return None
        from ... import background

        return background.start(run.behind.timings.call, "renders", _view, run, keep, name="gamma-view-rays")

    def on_iteration_updated(self, event: IterationUpdated) -> None:
        self.history.append(event.properties[self.property].copy())
        self.ranges.append(UNMEASURED)
        if event.iteration < event.run.opts.iterations:
            # while the next iteration is traced, not after the loop where a user waits
            event.run.behind.timed("renders", self._measure, len(self.history) - 1)

    def _measure(self, k: int) -> None:
        self.ranges[k] = value_range(self.history[k])

    def on_run_finished(self, event: RunFinished) -> None:
        from .outputs import FalseColourCanvas

        run, shown = event.run, self.property
        eye, target, up, fov = run.camera
        width, height = run.opts.width, run.opts.height
        # the geometry no longer changes: the rays of every picture are cast once (if they were
        # not since the setup), and the pictures are coloured behind the loop, in the runtime
        # (threads, no GIL); the rays are cast (no GIL) while the scale and the frame are worked
        # out here
        casting, self.casting = self.casting or self._cast(run), None
        try:
            ranges = [value_range(h) if r is UNMEASURED else r for h, r in zip(self.history, self.ranges)]
            found = [r for r in ranges if r is not None]
            vmax = max((high for high, _ in found), default=1.0)
            vmin = min(0.0, min((low for _, low in found), default=0.0))
            if vmax <= vmin:
                vmax = vmin + 1.0
            # one frame (colour bar, ticks) for every picture of the run
            canvas = FalseColourCanvas(width, height, vmin, vmax, shown)
        except BaseException:
            if casting is not None:
                casting.exception()     # waited for: the simulation must outlive the rays it casts
            raise
        view = None
        if casting is not None:
            view = run.call(casting.result)
        pictures = []
        for it, values in enumerate(self.history, start=1):
            values = np.ascontiguousarray(np.nan_to_num(values, nan=vmin, posinf=vmax, neginf=vmin), np.float32)
            path, title = self.folder / f"iter_{it:04d}.png", f"{shown}, iteration {it}"
            if view is not None:
                pictures.append((path, title, values))
                continue
            with run.behind.timings.timed("renders"):
                value, shade = run.call(run.sim.render, values, eye, target, up, fov, width, height, run.threads,
                                        cancel=run.cancel)
            run.behind.timed("renders", _write_false_colour, path, canvas, value, shade, title)
        if pictures:
            run.behind.timed("renders", _write_false_colour_views, pictures, canvas, view, vmin, vmax, run.threads)


#: A FalseColourWriter.ranges entry not worked out yet.
UNMEASURED = object()


def value_range(values: np.ndarray) -> tuple[float, float] | None:
    """(99.5th percentile, least) of the finite ``values`` (one iteration's),
    or None if none is finite: the run's scale is the largest percentile and
    the least value (or 0) of its iterations."""
    finite = values[np.isfinite(values)]
    if not finite.size:
        return None
    return percentile_995(finite), float(finite.min())


def percentile_995(finite: np.ndarray) -> float:
    """``float(np.percentile(finite, 99.5))`` of a non-empty 1-D float32
    array, bit for bit (its "linear" method: the two order statistics around
    (n - 1) * 0.995 found by a partition, and numpy's ``_lerp`` of them in
    float32, the weight a weak Python float), without ``np.percentile``:
    that imports numpy's masked arrays (through ``np.unique``) in every run
    with pictures.  tests/test_outputs.py compares the two (the
    same bits as numpy 2.4.1 and later, whose weak-``q`` arithmetic this is;
    earlier numpy rounded the float32 case otherwise)."""
    n = finite.size
    at = (n - 1) * (99.5 / 100)
    lo = int(np.floor(at))
    if at >= n - 1:
        return float(finite.max())
    below, above = np.partition(finite, (lo, lo + 1))[lo:lo + 2]
    gamma = at - lo
    diff = above - below
    if gamma >= 0.5:
        return float(above - diff * np.float32(1 - gamma))
    return float(below + diff * np.float32(gamma))


def _view(run, keep: bool):
    """``run``'s false-colour view: from the cache of views (``keep``), or cast
    (and then kept, with ``keep``)."""
    from ..caches import view_cache

    eye, target, up, fov = run.camera
    width, height = run.opts.width, run.opts.height
    path = view_cache.path_for(run) if keep else None
    view = view_cache.load(path, width, height, run.sim.num_surfels) if path is not None else None
    if view is None:
        view = run.sim.false_colour_view(eye, target, up, fov, width, height, run.threads, cancel=run.cancel)
        view_cache.store(path, view)
    return view


def _write_false_colour(path: Path, canvas, value, shade, title) -> None:
    atomic_write(path, canvas.png(value, shade, title))


def _write_false_colour_views(items: list, canvas, view, vmin, vmax, threads: int) -> None:
    """The pictures of ``items`` [(path, title, values)]: coloured in the
    runtime, titled here (Pillow), encoded in the runtime ``threads`` at a
    time (no GIL), then written in order."""
    from .outputs import PNG_COMPRESS_LEVEL, encode_pngs

    titled = [canvas.titled(view.picture(values, vmin, vmax, canvas.background, threads), title)
              for _, title, values in items]
    for (path, _, _), data in zip(items, encode_pngs(titled, PNG_COMPRESS_LEVEL, threads)):
        atomic_write(path, data)


class AppearanceWriter(Writer):
    """The scene as its appearance blocks paint it (sun, sky, ambient occlusion),
    per iteration; at the end the sequence as GIF, MP4 and a strip."""

    def __init__(self):
        self.frames: list = []

    def on_setup_done(self, event) -> None:
        # a resumed run: the earlier iterations' pictures, for the sequence
        from PIL import Image

        for it in range(1, event.run.first_iteration):
            with Image.open(event.run.out / "renders" / f"iter_{it:04d}.png") as picture:
                self.frames.append(picture.convert("RGB"))

    def on_iteration_updated(self, event: IterationUpdated) -> None:
        from PIL import Image

        run, it = event.run, event.iteration
        eye, target, up, fov = run.camera
        opts = run.opts
        with run.behind.timings.timed("renders"):
            image = run.call(run.sim.render_appearance, eye, target, up, fov, opts.width, opts.height,
                             run.threads, opts.samples, sun_direction(run.camera), opts.ao_samples, it,
                             cancel=run.cancel)
        run.nonfinite.add_appearance(it, run.sim.last_render_stats()["nonfinite"])
        rgb = np.clip(np.asarray(image)[..., :3], 0.0, 1.0)
        pixels = (rgb * 255 + 0.5).astype(np.uint8)
        self.frames.append(Image.fromarray(pixels))
        run.behind.timed("renders", _write_png, run.out / "renders" / f"iter_{it:04d}.png", pixels)

    def on_run_finished(self, event: RunFinished) -> None:
        if self.frames:
            event.run.behind.timed("sequence", write_sequence, list(self.frames), event.run.out / "renders")


def _write_png(path: Path, picture) -> None:
    """``picture`` as Pillow's ``save(format="PNG")`` writes it, encoded without the GIL."""
    from .outputs import PILLOW_DEFAULT_LEVEL, encode_pngs

    atomic_write(path, encode_pngs([picture], PILLOW_DEFAULT_LEVEL)[0])


def write_sequence(frames: list, folder: Path) -> None:
    """The iterations as an animated GIF, an MP4 and a strip of (at most 5)
    of them.  The MP4 (an ffmpeg process fed the frames) and the strip (its
    PNG encoded without the GIL) are made on threads of their own while the
    GIF is made here (Pillow holds the GIL for it): the three took their sum
    one after the other, after the loop.  All three are written, or have
    failed, when this returns; the first error (GIF, MP4, strip) is raised."""
    from ... import background

    others = [background.start(write_mp4, frames, folder / "sequence.mp4", name="gamma-mp4"),
              background.start(write_strip, frames, folder / "strip.png", name="gamma-strip")]
    try:
        buffer = io.BytesIO()
        frames[0].save(buffer, format="GIF", save_all=True, append_images=frames[1:], duration=400, loop=0)
        atomic_write(folder / "sequence.gif", buffer.getvalue())
    finally:
        background.wait(others)
    for made in others:
        made.result()


def write_strip(frames: list, path: Path) -> None:
    """Up to 5 of the frames side by side (the first, the last, evenly between), each labelled."""
    from PIL import Image, ImageDraw

    chosen = sorted({round(i * (len(frames) - 1) / 4) for i in range(5)}) if len(frames) > 1 else [0]
    w, h = frames[0].size
    strip = Image.new("RGB", (w * len(chosen), h), (255, 255, 255))
    draw = ImageDraw.Draw(strip)
    for slot, index in enumerate(chosen):
        strip.paste(frames[index], (slot * w, 0))
        draw.text((slot * w + 8, 8), f"iteration {index + 1}", fill=(0, 0, 0))
    _write_png(path, strip)


def write_mp4(frames: list, path: Path, fps: int = 4) -> None:
    """H.264 video (imageio-ffmpeg), via a temporary file renamed into place."""
    import imageio.v2 as imageio

    fd, tmp = tempfile.mkstemp(prefix=".sequence.", suffix=".mp4", dir=path.parent)
    os.close(fd)
    try:
        # yuv420p needs even sizes: pad by one pixel where needed
        w, h = frames[0].size
        pad = ((0, h % 2), (0, w % 2), (0, 0))
        with imageio.get_writer(tmp, fps=fps, codec="libx264", macro_block_size=1,
                                ffmpeg_log_level="error", pixelformat="yuv420p",
                                # the index (moov atom) first, so a browser can start playing at once
                                output_params=["-movflags", "+faststart"]) as writer:
            for frame in frames:
                writer.append_data(np.pad(np.asarray(frame.convert("RGB")), pad, mode="edge"))
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


class MeshWriter(Writer):
    """meshes/iter_NNNN.ply: the deformed mesh with per-vertex normals and
    every property (smoothed from the surfels at each vertex)."""

    @_timed_on_loop("meshes")
    def on_iteration_updated(self, event: IterationUpdated) -> None:
        from .export import vertex_normals
        from ..running.common import property_columns

        run, it = event.run, event.iteration
        vertices, triangles = run.sim.mesh_arrays()
        vertices = np.asarray(vertices, np.float32)
        triangles = np.asarray(triangles, np.int64)
        normals = vertex_normals(vertices.astype(np.float64), triangles)
        owner = np.zeros(len(vertices), np.int32)          # a triangle of each vertex
        owner[triangles.reshape(-1)] = np.repeat(np.arange(len(triangles), dtype=np.int32), 3)
        rows, _ = run.sim.bake_points(vertices, normals, owner, np.zeros((len(vertices), 2), np.float32),
                                      it, run.threads)
        surface = np.asarray(run.sim.triangle_surfaces())[owner]
        columns = {"x": vertices[:, 0], "y": vertices[:, 1], "z": vertices[:, 2],
                   "nx": normals[:, 0], "ny": normals[:, 1], "nz": normals[:, 2]}
        columns.update(property_columns(run.effect, rows, surface))
        comments = [f"gamma {version()}", f"effect {Path(run.effect.path).name}", f"iteration {it}"]
        run.behind.timed("meshes", _write_mesh, run.out / "meshes" / f"iter_{it:04d}.ply", columns, triangles,
                         comments)


def _write_mesh(path: Path, columns: dict, triangles, comments: list[str]) -> None:
    atomic_write(path, mesh_ply_bytes(columns, triangles, comments))


class ExportWriter(Writer):
    """The texture sets and scene files of ``--export`` (SPEC §16.3): the
    last iteration, or every one (``--export all``), written once the run is
    complete so that every property map spans the whole run's range."""

    def __init__(self, bake_size: int | None, which: str = "last", texel_density: float | None = None,
                 preset: str = "gltf", float_maps: bool = False):
        self.bake_size, self.which, self.texel_density, self.preset = bake_size, which, texel_density, preset
        self.float_maps = float_maps

    def on_setup_done(self, event) -> None:
        from .export import memory_problem
        from ..running.common import RunError

        run = event.run
        if self.bake_size and not self.texel_density:   # refused before the first iteration
            properties = len({n for s in run.effect.surfaces.values() for n in s.properties})
            problem = memory_problem(self.bake_size, run.effect.row_width, properties)
            if problem:
                raise RunError(f"--export: {problem}")

    @_timed_on_loop("export")
    def on_run_finished(self, event: RunFinished) -> None:
        from .export import Exporter

        run = event.run
        last = run.opts.iterations
        exporter = Exporter(run, self.bake_size, self.texel_density, run.summary.get("ranges") or {}, self.preset,
                            self.float_maps)
        if self.which == "all":
            from ..running.reload import load_iteration

            run.behind.drain()          # the maps of every iteration are on disk
            for it in range(1, last + 1):
                load_iteration(run, run.out, it)
                exporter.write(it)
        else:
            exporter.write(last)


class ProgressWriter(Writer):
    """A progress bar with the elapsed time and the time left on stderr
    (progress.py); ``--quiet`` leaves it out."""

    def __init__(self, total: int, what: str = "iteration"):
        from .progress import ProgressBar

        self.bar = ProgressBar(total, unit=f" {what}", file=sys.stderr)

    def on_iteration_updated(self, event: IterationUpdated) -> None:
        record = event.record
        # γ-tons that reached the surface: a source's misses cost one ray each
        # and would flatter the rate.
        hitting = record["emitted"] - record.get("missed", 0)
        rate = hitting / max(record["trace_seconds"], 1e-9)
        self.bar.set_postfix_str(f"{record['trace_seconds']:.2f} s trace, {rate / 1e3:.0f}k hitting γ-tons/s")
        self.bar.update(1)

    def on_run_finished(self, event) -> None:
        self.bar.close()


def standard_writers(run) -> list[Writer]:
    """The outputs ``gammac run`` writes for ``run.opts``, in writing order."""
    writers: list[Writer] = [MapWriter(), SummaryWriter()]
    if run.shapes:
        writers.append(MeshWriter())
    if run.shown is not None:
        folder = run.out / "renders" / ("false_colour" if run.looks else "")
        writers.append(FalseColourWriter(run.shown, folder))
    if run.looks:
        writers.append(AppearanceWriter())
    if run.opts.export:
        writers.append(ExportWriter(run.opts.bake_size, "all" if run.opts.export == "all" else "last",
                                    run.opts.texel_density, run.opts.preset, run.opts.float_maps))
    if run.opts.progress:
        writers.append(ProgressWriter(run.opts.iterations))
    writers.append(CompletionWriter())
    return writers
