"""``gammac watch``: run an effect, then run it again whenever the effect
file or a file it imports is saved, and show each result in the browser.

Each save is answered twice: first a preview (the same iterations with a
fraction of the γ-tons, chosen in the page), published as soon as it is
done, then the full-quality run, published when it completes.  A save
during a run cancels it: the runtime pass under way stops at its next chunk
(the run's CancelToken).  The scene is read once per
effect whose surfaces or assignment rules change; the kernels of an
unchanged effect come from the compiler's cache.
"""

from __future__ import annotations

import os
import struct
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import abi
from ..frontend.checker import UsageError
from ..frontend.diagnostics import GammaError
from ..driver.running.events import Writer
from ..driver.running.runner import RunError, property_columns, run_camera, runtime_module
from ..options import RunOptions
from .server import ViewerState, serve


class Superseded(Exception):
    """The files changed (or the preview level did) while a run was going on."""


@dataclass
class ViewerMesh:
    """The scene as the page draws it: vertices welded per (vertex, uv), each
    with the scene triangle its values are evaluated on."""

    positions: np.ndarray   # float32 (n, 3)
    normals: np.ndarray     # float32 (n, 3)
    triangles: np.ndarray   # uint32 (m, 3)
    owner: np.ndarray       # int32 (n,) scene triangle per vertex
    uvs: np.ndarray         # float32 (n, 2) texture coordinates for texture() lookups

    def to_bytes(self) -> bytes:
        n, m = len(self.positions), len(self.triangles)
        return (struct.pack("<II", n, m) + self.positions.astype("<f4").tobytes()
                + self.normals.astype("<f4").tobytes() + self.triangles.astype("<u4").tobytes()
                + self.uvs.astype("<f4").tobytes())


def viewer_mesh(mesh) -> ViewerMesh:
    from ..driver.outputs.export import vertex_normals

    verts = np.asarray(mesh.vertices(), np.float32)
    tris = np.asarray(mesh.triangles(), np.int64)
    if mesh.has_uvs:
        uvs = np.asarray(mesh.triangle_uvs(), np.float32).reshape(-1, 2)
        corners = np.column_stack([tris.reshape(-1).astype(np.float64), uvs.astype(np.float64)])
        keys, inverse = np.unique(corners, axis=0, return_inverse=True)
        source, vertex_uvs = keys[:, 0].astype(np.int64), keys[:, 1:].astype(np.float32)
        faces = inverse.reshape(-1, 3)
    else:
        source, faces = np.arange(len(verts)), tris
        vertex_uvs = np.zeros((len(verts), 2), np.float32)
    positions = verts[source]
    normals = vertex_normals(positions.astype(np.float64), faces)
    owner = np.zeros(len(positions), np.int32)
    owner[faces.reshape(-1)] = np.repeat(np.arange(len(faces), dtype=np.int32), 3)
    return ViewerMesh(positions, normals, faces.astype(np.uint32), owner, vertex_uvs)


class Watcher:
    """The watch loop; ``stop`` (a threading.Event) ends it."""

    CANCEL_POLL = 0.02   # seconds between looks at the files while a run traces

    def __init__(self, path: str, overrides: dict, opts: RunOptions, state: ViewerState,
                 stop: threading.Event | None = None, poll: float = 0.05, log=None):
        self.path, self.overrides, self.opts, self.state = path, overrides, opts, state
        self.stop = stop or threading.Event()
        self.poll = poll
        self.log = log or (lambda text: print(text, file=sys.stderr, flush=True))
        self.files = [path]
        self.stamps: dict[str, float | None] = {}
        self.generation = 0
        self.scene_key = None
        self.scene = None
        self.sim = None            # the last run's simulation, whose surfels a save can keep
        self.mesh = None
        import tempfile

        self.scratch = tempfile.TemporaryDirectory(prefix="gamma-watch-")   # the runs' folder (nothing kept)

    # -- files --

    def _stamp(self) -> dict:
        out = {}
        for f in self.files:
            try:
                st = os.stat(f)
                out[f] = (st.st_mtime_ns, st.st_size)
            except OSError:
                out[f] = None
        return out

    def changed(self) -> bool:
        return self._stamp() != self.stamps

    def _check(self) -> None:
        if self.stop.is_set() or self.changed() or self.state.preview_changed.is_set():
            raise Superseded

    # -- the loop --

    def run_forever(self) -> None:
        while not self.stop.is_set():
            self.stamps = self._stamp()
            self.state.preview_changed.clear()
            self.generation += 1
            try:
                self.once()
            except Superseded:
                continue
            while not self.stop.is_set() and not self.changed() and not self.state.preview_changed.is_set():
                self.stop.wait(self.poll)

    def once(self) -> None:
        from ..frontend.checker import check
        from ..frontend.parser import parse

        started = time.perf_counter()
        # the generation changes with the result, so the page never takes the old one for the new
        self.state.publish(status="running", progress="compiling")
        missing: list = []
        try:
            source = Path(self.path).read_text(encoding="utf-8")
            effect = check(parse(source, self.path), self.overrides, missing_masks=missing)
            if missing:
                self._make_masks(effect, missing)
        except (GammaError, UsageError, OSError, UnicodeDecodeError, RunError) as err:
            self._fail(err)
            return
        self._check()
        masks = sorted({path for _, _, _, path in effect.mask_uses})
        # the effect, its imports, and the images it reads: saving any of them (a mask
        # painted in the page too) runs the effect again
        self.files = [self.path] + [str(Path(f)) for f in effect.files if Path(f) != Path(self.path)] \
            + masks + [p for p in effect.textures if p not in masks]
        from ..driver.running.mask_atlas import LayoutError, atlas_masks

        try:
            atlas = frozenset(atlas_masks(effect))
        except LayoutError:
            atlas = frozenset()       # reported by the run
        self.state.set_masks(masks, atlas, self._texel_points)
        self.stamps.update({f: s for f, s in self._stamp().items() if f not in self.stamps})
        try:
            fraction = self.state.preview
            if fraction < 1.0:
                self.simulate(effect, fraction, started)
            self.simulate(effect, 1.0, started)
        except (RunError, GammaError) as err:
            self._fail(err)

    def _make_masks(self, effect, paths: list) -> None:
        """The masks the effect reads that are not there yet, black: in the
        scene's atlas if parts of the scene have no texture coordinates."""
        from ..driver.running.mask_atlas import DEFAULT_SIZE, create
        from ..driver.running.scene import SceneError, load_scene

        try:
            scene = load_scene(runtime_module(), self.opts.scene, effect, self.opts.assign, self.opts.down)
        except SceneError as err:
            raise RunError(str(err)) from None
        bare = not np.asarray(scene.triangle_has_uv, bool).all()
        for path in paths:
            create(path, scene.mesh.vertices(), scene.mesh.triangles(), scene.triangle_has_uv)
            where = " in the scene's atlas (parts have no texture coordinates)" if bare else ""
            self.log(f"gammac: made {Path(path).name}, a black {DEFAULT_SIZE}x{DEFAULT_SIZE} mask{where}: "
                     "paint it in the page")

    def _texel_points(self, path):
        """Scene points of an atlas mask's texels (for the page's brush), for the scene on show."""
        from ..driver.running.mask_atlas import texel_points
        from PIL import Image

        scene = self.scene
        if scene is None or not scene.mesh.has_uvs:
            return None
        with Image.open(path) as image:
            size = image.size[0]
        key = (id(scene), str(path), size)
        if getattr(self, "_points_key", None) != key:
            self._points = texel_points(scene.mesh, scene.triangle_has_uv, size)
            self._points_key = key
        return self._points

    def _fail(self, err) -> None:
        # An editor writing the file in place (truncate, then write) can be
        # read half-written: a file that changed since it was read is read
        # again instead of reported.
        self._check()
        if isinstance(err, GammaError):
            text = err.render()
            n = len(err.diagnostics)
            where = [{"file": str(d.file.path if d.file else err.path), "line": d.pos.line, "col": d.pos.col,
                      "message": d.message} for d in err.diagnostics]
            text += f"\n{n} error{'s' if n != 1 else ''} in {err.path}"
        else:
            text, where = f"gammac: error: {err}", []
        self.log(text)
        self.state.publish(status="error", generation=self.generation, frames=[],
                           error={"text": text, "diagnostics": where}, progress=None)

    def simulate(self, effect, fraction: float, started: float) -> None:
        """One run on the driver's loop (``driver.runner``), the viewer a writer on it."""
        from ..driver.running.runner import run
        from ..driver.running.scene import SceneError, load_scene

        opts = self.opts
        from ..driver.running.mask_atlas import LayoutError, atlas_masks

        try:   # the atlas masks' records: they give parts without UVs their coordinates
            layouts = tuple(sorted((p, r["mesh"], r["size"]) for p, r in atlas_masks(effect).items()))
        except LayoutError as err:
            raise RunError(str(err)) from None
        key = (tuple(effect.surfaces), tuple(effect.assign), layouts)
        if self.scene_key != key:
            try:
                self.scene = load_scene(runtime_module(), opts.scene, effect, opts.assign, opts.down)
            except SceneError as err:
                raise RunError(str(err)) from None
            self.scene_key = key
            self.sim = None                  # surfels of another scene
            self.mesh = viewer_mesh(self.scene.mesh)
            self._publish_mesh(run_camera(self.scene, opts))
        total = opts.tons if opts.tons is not None else sum(s.count for s in effect.sources)
        tons = max(1, round(total * fraction)) if fraction < 1.0 else total
        quality = "final" if fraction >= 1.0 else "preview"
        writer = ViewerWriter(self, self.mesh, quality)
        t0 = time.perf_counter()
        finished = threading.Event()
        monitor = threading.Thread(target=self._cancel_when_stale, args=(writer, finished), daemon=True)
        monitor.start()
        try:
            run(effect, replace(opts, tons=tons, out=self.scratch.name, progress=False), [writer],
                scene=self.scene, standard=False, reuse=self.sim)
        except runtime_module().Cancelled:
            raise Superseded from None
        finally:
            finished.set()
            monitor.join()
        session = writer.session
        self.sim = session.sim             # the next save keeps its surfels when it can
        setup_seconds = writer.setup_seconds - t0            # compilation (or the cache) and surfels
        run_seconds = time.perf_counter() - writer.setup_seconds
        info = {"surfels": int(session.sim.num_surfels), "triangles": int(self.scene.mesh.num_triangles),
                "tons_per_iteration": int(tons), "setup_seconds": setup_seconds, "run_seconds": run_seconds,
                "seconds_since_save": time.perf_counter() - started, "records": writer.records}
        done = quality == "final"
        self.state.publish(frames=writer.frames, status="ready" if done else "running", quality=quality,
                           error=None, generation=self.generation, properties=writer.properties(),
                           appearance=session.looks, run=info, progress=None if done else "refining")
        self.log(f"gammac watch: {quality} result {self.generation} "
                 f"({info['seconds_since_save']:.2f} s after the change, {tons:,} γ-tons per iteration)")

    def _cancel_when_stale(self, writer: "ViewerWriter", finished: threading.Event) -> None:
        """Stops the runtime pass running now (the run's CancelToken) as soon as
        a file is saved (or the page asks for another preview), instead of at
        the iteration's end: with millions of γ-tons an iteration takes seconds."""
        while not finished.wait(self.CANCEL_POLL):
            if self.stop.is_set() or self.changed() or self.state.preview_changed.is_set():
                session = getattr(writer, "session", None)
                if session is not None:      # before the setup is done, on_setup_done stops the run
                    session.cancel.cancel()
                    return

    def _publish_mesh(self, camera) -> None:
        self.state.publish(mesh_bytes=self.mesh.to_bytes(), frames=[],
                           mesh={"version": self.generation, "vertices": len(self.mesh.positions),
                                 "triangles": len(self.mesh.triangles), "has_uvs": bool(self.scene.mesh.has_uvs)},
                           camera={"eye": [float(c) for c in camera[0]], "target": [float(c) for c in camera[1]],
                                   "up": [float(c) for c in camera[2]], "fov": float(camera[3])})


#: The appearance outputs a frame carries after the colour, one float per
#: vertex each, in this order (``displacement`` is not drawn).
FRAME_LOOK = ("roughness", "metallic", "occlusion")


class ViewerWriter(Writer):
    """The page's frames, one per iteration: the appearance (the look) and
    every property at the viewer mesh's vertices (the surfels' smoothed
    values), with each property's range over the run.  Stops the run
    (``Superseded``) as soon as the files change.

    A frame (``GET /api/frame``) is little-endian float32, for the n
    vertices of the viewer mesh: the appearance colour (3n: r, g, b per
    vertex, display values in [0, 1]), then roughness (n), metallic (n) and
    occlusion (n), each clamped to [0, 1] (SPEC §8a), then each property
    (n each, in the order of the state's ``properties``)."""

    def __init__(self, watcher: "Watcher", mesh: ViewerMesh, quality: str):
        self.watcher, self.mesh, self.quality = watcher, mesh, quality
        self.frames: list[bytes] = []
        self.records: list[dict] = []
        self.ranges: dict[str, tuple[float, float]] = {}
        self.names: list[str] = []

    def on_setup_done(self, event) -> None:
        self.session = event.run
        self.setup_seconds = time.perf_counter()
        self.watcher._check()

    def on_iteration_traced(self, event) -> None:
        self.watcher._check()

    def on_iteration_updated(self, event) -> None:
        run, it, mesh = event.run, event.iteration, self.mesh
        record = event.record
        self.records.append({k: record[k] for k in ("emitted", "settled", "escaped", "interactions",
                                                     "property_sums")})
        if run.sim.num_prepared_points != len(mesh.owner):   # once per set of surfels: kept over saves
            run.sim.prepare_points(mesh.positions, mesh.normals, mesh.owner, mesh.uvs, run.threads)
        rows, look = run.sim.bake_prepared(it, run.threads)
        look = np.asarray(look)
        at = abi.appearance_offsets()
        columns = property_columns(run.effect, np.asarray(rows), np.asarray(run.scene.triangle_surface)[mesh.owner])
        self.names = list(columns)
        parts = [np.asarray(look[:, at["color"]:at["color"] + 3], "<f4").reshape(-1)]
        parts += [np.clip(look[:, at[name]], 0.0, 1.0).astype("<f4") for name in FRAME_LOOK]
        for name, values in columns.items():
            finite = values[np.isfinite(values)]
            if finite.size:
                low, high = self.ranges.get(name, (np.inf, -np.inf))
                self.ranges[name] = (min(low, float(finite.min())), max(high, float(finite.max())))
            parts.append(np.asarray(values, "<f4"))
        self.frames.append(b"".join(p.tobytes() for p in parts))
        if self.quality == "final":
            self.watcher.state.publish(progress=f"refining: iteration {it}/{run.opts.iterations}")
        self.watcher._check()

    def properties(self) -> list[dict]:
        return [{"name": n, "min": self.ranges.get(n, (0.0, 1.0))[0], "max": self.ranges.get(n, (0.0, 1.0))[1]}
                for n in self.names]


def watch(path: str, overrides: dict, opts: RunOptions, port: int = 8000, preview: float = 0.25,
          stop: threading.Event | None = None, on_ready=None) -> int:
    """Serve the viewer and run the watch loop until ``stop`` is set (or ^C)."""
    state = ViewerState(path, opts.scene, preview)
    try:
        server = serve(state, port)
    except OSError as err:
        raise RunError(f"cannot serve on 127.0.0.1:{port}: {err.strerror or err}") from None
    url = f"http://127.0.0.1:{server.server_address[1]}/"
    print(f"gammac watch: viewer at {url} (Ctrl-C to stop)", file=sys.stderr, flush=True)
    if on_ready is not None:
        on_ready(url)
    watcher = Watcher(path, overrides, opts, state, stop)
    try:
        watcher.run_forever()
    finally:
        state.close()
        server.shutdown()
        server.server_close()
        watcher.scratch.cleanup()
    return 0

