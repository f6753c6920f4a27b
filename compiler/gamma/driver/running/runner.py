"""``gammac run``: set a run up and iterate it.

``Run.start`` turns a checked ``Effect`` plus options into the runtime's
``Config`` and ``Simulation`` (with ``scene.py``, which assembles the mesh);
``run`` iterates (trace, update) and publishes the loop's events to writers
(``events.py``, ``writers.py``).  This module writes no file itself: every
output is a writer, so adding one never touches the loop.
"""

from __future__ import annotations

import math
import re
import sys
import time
from dataclasses import field
from pathlib import Path

import numpy as np

from ... import abi
from ...version import version
from . import budget
from ...frontend.ast import Pos
from ...ir.effect import Effect
from ...frontend.diagnostics import Diagnostic, GammaError
from ...options import LIMITS, RunOptions, limit_problem
from ...records import Record, record
from .common import RunError, cpu_count, property_columns, runtime_module, shape_changes
from .config import build_config, load_textures, mass_properties, set_materials


def check_limits(opts: "RunOptions") -> None:
    problem = limit_problem(opts)
    if problem:
        raise RunError(problem)


def run_camera(scene, opts: "RunOptions"):
    """The camera of a run's options (--view, --eye, --look-at, --up, --fov)."""
    from .camera import CameraError, choose_camera

    try:
        return choose_camera(scene.bounds, scene.down, opts.view, opts.eye, opts.look_at, opts.up, opts.fov)
    except CameraError as err:
        raise RunError(str(err)) from None


OUTPUT_FOLDERS = ("maps", "renders", "renders/false_colour", "export", "meshes")


def prepare_output(out: Path) -> None:
    """Create the folders up front, so an unwritable --out fails before any work."""
    try:
        for sub in OUTPUT_FOLDERS:
            (out / sub).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RunError(f"cannot write to '{out}': {err.strerror or err}") from None


def _remove_empty_folders(out: Path) -> None:
    for sub in sorted((p for p in out.rglob("*") if p.is_dir()), key=lambda p: len(p.parts), reverse=True):
        try:
            sub.rmdir()
        except OSError:
            pass
    try:
        out.rmdir()
    except OSError:
        pass


def run(effect: Effect, opts: RunOptions, writers: list | tuple = (), scene=None,
        standard: bool = True, reuse=None) -> dict:
    """Simulate ``effect`` with ``opts``; the standard outputs, then ``writers``,
    receive the run's events (``events.py``).  Returns the summary.

    SIGINT and SIGTERM stop the run within a fraction of a second
    (``interrupt.py``): the iterations completed so far stay written, with
    ``"completed": false`` (before the first: the earlier run's files stay),
    and ``RunInterrupted`` is raised.  The runtime pass that was running (the
    set-up, a trace, a render) stops at its next check of the run's cancel
    token; an update or shape step that had started ends first.  A run that fails
    puts the earlier run's files back (``folder.py``).  ``scene`` (a
    ``scene.Scene``) replaces ``opts.scene``; ``standard=False`` leaves the
    standard outputs out (the Python API, the viewer).  ``reuse``: the
    simulation of an earlier run on the same ``scene``, taken over with the
    new effect when its surfels can stay (``Simulation.reconfigure``), which
    saves the surfel setup; the results are the same either way."""
    from . import folder
    from .events import IterationTraced, IterationUpdated, RunFinished, SetupDone, publish
    from .interrupt import Interrupted, Interruptions
    from ..outputs.writers import standard_writers

    with Interruptions() as stop:
        try:
            session = start(effect, opts, stop, scene, reuse, warm_outputs=standard)
        except Interrupted as sig:
            # before the earlier run's files were set aside (start's runtime calls all are)
            raise RunInterrupted(f"interrupted by {sig.name} before the first iteration; "
                                 "the earlier results are kept", sig.status) from None
        subscribers = (standard_writers(session) if standard else []) + list(writers)
        done = session.first_iteration - 1
        books = None        # (iteration, what its update adds to the summary besides its record)
        try:
            with session.behind:   # leaving it waits for the writers' queued jobs
                publish(subscribers, SetupDone(session))
                loop_started = time.perf_counter()
                for it in range(session.first_iteration, opts.iterations + 1):
                    traced = stop.call(session.trace, it)
                    publish(subscribers, IterationTraced(session, it, traced))
                    books = it, session.books()
                    rows, props, record = stop.call(session.update, it, traced)
                    publish(subscribers, IterationUpdated(session, it, rows, props, record))
                    done = it
                    stop.check()
                session.loop_ended = time.perf_counter()
                # the iterations with their outputs' work on the loop's thread
                session.summary["loop_seconds"] = session.loop_ended - loop_started
                session.summary["completed"] = True
                publish(subscribers, RunFinished(session, session.summary))
            folder.drop(session.out)
        except Interrupted as sig:
            # the books before an update of the iteration dropped (it ended after the signal)
            dropped = books[1] if books is not None and books[0] == done + 1 else None
            _interrupted(session, sig, done, dropped)     # raises RunInterrupted
        except BaseException as err:
            if not opts.resume:
                folder.restore(session.out)      # the earlier run's files come back
            if isinstance(err, OSError):
                raise RunError(f"cannot write to '{session.out}': {err.strerror or err}") from None
            raise
        finally:
            session.lock.__exit__()
            if session.tracer is not None:
                session.tracer.close()
    return session.summary


def _direct(fn, *args, **kwargs):
    return fn(*args, **kwargs)


class RunInterrupted(Exception):
    """The run stopped at a signal; its folder holds its complete iterations
    (or the earlier run's files).  ``status``: 128 + the signal's number."""

    def __init__(self, message: str, status: int):
        super().__init__(message)
        self.status = status

    @property
    def signal_name(self) -> str:
        from .interrupt import SIGNAL_NAMES

        number = self.status - 128
        return next((name for sig, name in SIGNAL_NAMES.items() if sig == number), f"signal {number}")


def _interrupted(session: "Run", sig, done: int, dropped_books):
    """Finish the folder of an interrupted run: complete iterations only (the
    queued writes are done: leaving ``behind`` waited for them), summary.json
    with ``"completed": false``; keep the earlier run's files if none is.
    ``dropped_books``: ``Run.books`` before the update of the iteration
    dropped, or None if none started."""
    from . import folder
    from ...files import atomic_write

    summary = dict(session.summary)
    summary["completed"] = False
    summary["interrupted"] = sig.name
    summary["iterations"] = summary["iterations"][:done]
    if dropped_books is not None:
        ranges, summary["nonfinite"] = dropped_books
        if ranges is None:
            summary.pop("ranges", None)
        else:
            summary["ranges"] = ranges
    out = session.out
    if done == 0 and not session.opts.resume:
        folder.restore(out)
        kept = "the earlier results are kept"
    else:
        folder.discard_after(out, done)
        atomic_write(out / "summary.json", (__import__("json").dumps(summary, indent=2) + "\n").encode())
        folder.drop(out)
        kept = (f"'{out}' holds iterations 1 to {done} of {session.opts.iterations} "
                f"(summary.json: \"completed\": false); add --resume to continue")
    raise RunInterrupted(f"interrupted by {sig.name} during iteration {done + 1}; {kept}", sig.status)


@record
class Run(Record):
    """One run's state, shared by the loop and its writers.  Writers read it;
    only the loop advances ``sim`` (and only on the loop's thread)."""

    effect: Effect
    opts: RunOptions
    out: Path
    rt: object                     # gamma._runtime
    scene: object                  # scene.Scene
    kernels: object                # owns the machine code ``sim`` calls (JitKernels, SharedKernels): keep alive
    sim: object                    # gamma._runtime.Simulation
    camera: tuple                  # eye, target, up, fov (camera.auto_camera)
    threads: int
    shown: str | None              # the property rendered in false colour
    looks: bool                    # the effect has appearance blocks
    surfel_surface: np.ndarray     # surface index per surfel
    static_columns: dict           # x y z nx ny nz surface per surfel
    summary: dict                  # what summary.json holds (grows per iteration)
    nonfinite: "NonFiniteReport"
    behind: object                 # events.WriteQueue: jobs run in order behind the loop
    shapes: bool = False           # some surface's shape follows a property
    shape_where: str = ""          # FILE:LINE:COL of the first `shape` entry (for warnings)
    shape_warned: set = field(default_factory=set)  # the shape limits already warned of
    first_iteration: int = 1       # 1, or where --resume continues
    lock: object = None            # folder.OutputLock, held for the run
    call: object = _direct         # call(fn, *args): a long runtime call, Interrupted by a signal
    cancel: object = None          # the run's CancelToken (interrupt.py), handed to every long runtime pass
    tracer: object = None          # distributed.RayTracer with --ray / --ray-address
    input_values: object = None    # float32 (surfels, inputs): mask() and attribute() (scene_inputs.py)
    loop_ended: float | None = None  # time.perf_counter() when the last iteration was done

    def trace(self, it: int) -> dict:
        """Trace iteration ``it``'s gamma-tons; the runtime's statistics."""
        if self.tracer is not None:
            return self.tracer.trace(it)
        return self.sim.trace(it, cancel=self.cancel)

    def books(self) -> tuple:
        """A copy of what ``update`` adds to the summary besides its record (the
        value ranges, the non-finite counts): what an interrupted run writes
        when it drops the iteration whose update ended after the signal (or
        still runs)."""
        ranges = self.summary.get("ranges")
        return (None if ranges is None else {name: list(bounds) for name, bounds in ranges.items()},
                [dict(entry) for entry in self.nonfinite.entries])

    def update(self, it: int, traced: dict) -> tuple[np.ndarray, dict, dict]:
        """Run the update rules; (rows, property columns, summary record)."""
        updated = self.sim.update(it, cancel=self.cancel)
        self.nonfinite.add(it, traced["nonfinite"], updated["nonfinite"])
        rows = self.sim.rows()
        props = property_columns(self.effect, rows, self.surfel_surface)
        record = {k: traced[k] for k in abi.STATISTICS if k in traced}
        record["property_sums"] = {name: float(np.sum(col, dtype=np.float64))
                                   for name, col in props.items()}
        record["trace_seconds"] = traced["trace_seconds"]
        record["update_seconds"] = updated["seconds"]
        if "bytes_moved" in traced:
            record["ray"] = traced["bytes_moved"]
        names = mass_properties(self.effect)
        if names:
            record["mass"] = {name: books for name, books in zip(names, traced["mass"])}
        if self.shapes:
            shaped = self.sim.shape(it, cancel=self.cancel)
            record["geometry"] = shaped["geometry"]
            record["shape"] = {k: v for k, v in shaped.items() if k != "geometry"}
            for key, count in (("clamped_vertices", "was cut to the per-iteration bound"),
                               ("clearance_limited", "was shortened so that no part wears through and no gap "
                                                     "closes (SPEC §13.12)"),
                               ("inversion_limited", "was shortened so that no triangle turns over")):
                # once per kind: a limit that holds in one step usually holds in every
                # later one, and thirty lines would hide every other message
                if shaped[key] and key not in self.shape_warned:
                    self.shape_warned.add(key)
                    print(f"\ngammac: warning: {self.shape_where}: the displacement of {shaped[key]} "
                          f"vertices {count} in iteration {it} (not warned again; summary.json's "
                          f"shape.{key} counts them in every iteration)", file=sys.stderr)
            if shaped["changed"]:
                rows = self.sim.rows()
                self.refresh_surfels()
                props = property_columns(self.effect, rows, self.surfel_surface)
                record["property_sums"] = {name: float(np.sum(col, dtype=np.float64))
                                           for name, col in props.items()}
        self.summary["iterations"].append(record)
        # one value range per property over the whole run so far (finite values, the
        # surfels of surfaces that have the property), so iterations compare
        ranges = self.summary.setdefault("ranges", {})
        for surface in self.effect.surfaces.values():
            mine = self.surfel_surface == surface.index
            for name, slot in surface.properties.items():
                values = rows[mine, slot]
                values = values[np.isfinite(values)]
                if values.size:
                    low, high = ranges.get(name, (math.inf, -math.inf))
                    ranges[name] = [min(low, float(values.min())), max(high, float(values.max()))]
        return rows, props, record

    def refresh_surfels(self) -> None:
        """Surfel positions, normals and surfaces after the shape changed."""
        self.surfel_surface = np.asarray(self.sim.surfel_surfaces())
        self.static_columns = static_columns(self.sim, self.surfel_surface)

    def export_scene(self):
        """The scene as export sees it: the loaded scene, or, once the shape
        may have changed, the deformed mesh with an object per surface, named
        after the scene's object that held the surface (the surface's name
        when several did)."""
        if not self.shapes:
            return self.scene
        from types import SimpleNamespace

        vertices, triangles = self.sim.mesh_arrays()
        mesh = self.rt.Mesh.from_arrays(vertices, triangles)
        surfaces = np.asarray(self.sim.triangle_surfaces())
        loaded = self.scene
        names, number = [], np.zeros(len(surfaces), np.int64)
        for s in np.unique(surfaces):
            held = np.unique(loaded.triangle_object[loaded.triangle_surface == s])
            names.append(loaded.object_names[int(held[0])] if len(held) == 1 else list(self.effect.surfaces)[s])
            number[surfaces == s] = len(names) - 1
        return SimpleNamespace(mesh=mesh, object_names=names, triangle_object=number,
                               triangle_surface=surfaces)


def static_columns(sim, surfel_surface: np.ndarray) -> dict:
    """x y z nx ny nz surface per surfel."""
    pos, nrm = sim.surfel_positions(), sim.surfel_normals()
    static = {axis: pos[:, j] for j, axis in enumerate("xyz")}
    static.update({axis: nrm[:, j] for j, axis in enumerate(("nx", "ny", "nz"))})
    static["surface"] = surfel_surface.astype(np.float32)
    return static


def start(effect: Effect, opts: RunOptions, stop=None, scene=None, reuse=None, warm_outputs: bool = False) -> Run:
    """Check the options, load the scene, compile, build the simulation and
    set the earlier run's files aside; every user error is raised before any output.
    ``warm_outputs``: the standard outputs will be written (see ``warmup.py``)."""
    from .scene import SceneError, load_scene

    entered = time.perf_counter()
    check_limits(opts)
    if (opts.ray or opts.ray_address) and shape_changes(effect):
        where = next((w for s in effect.surfaces.values() for _, _, w in s.shape.values()), "")
        raise RunError(f"--ray{'-address' if opts.ray_address else ''}: {where}: an effect that changes "
                       "the shape of the scene cannot be traced on Ray (the workers keep the scene as it "
                       "was loaded, the shape step re-tiles it); run it without Ray")
    if not effect.sources:
        raise GammaError(effect.path, effect.source, [Diagnostic(
            Pos(1, 1), "the effect declares no source, so no gamma-ton would be traced")])
    rt = runtime_module()
    t0 = time.perf_counter()
    try:
        scene = scene or load_scene(rt, opts.scene, effect, opts.assign, opts.down)
    except SceneError as err:
        raise RunError(str(err)) from None
    scene_seconds = time.perf_counter() - t0
    _check_scene_inputs(effect, scene)
    mesh = scene.mesh
    if mesh.degenerate_dropped:
        print(f"gammac: warning: {mesh.degenerate_dropped} degenerate triangles of "
              f"'{opts.scene}' ignored", file=sys.stderr)
    present = [s for s in effect.surfaces.values() if scene.triangles_per_surface[s.name]]
    shown = opts.show or next((n for s in present for n in s.properties), None)
    if shown is not None and not any(shown in s.properties for s in present):
        raise RunError(f"--show {shown}: no surface of the scene has that property "
                       f"({', '.join(sorted({n for s in present for n in s.properties})) or 'none'})")
    if opts.eye is not None:
        centre = (np.asarray(scene.bounds[0], float) + np.asarray(scene.bounds[1], float)) / 2
        problem = budget.distance_problem("--eye", opts.eye, centre, scene.diagonal)
        if problem:
            raise RunError(problem)
    tons = opts.tons if opts.tons is not None else sum(src.count for src in effect.sources)
    need = budget.run_memory(opts.surfels, effect.row_width, opts.iterations, history=shown is not None,
                             tons=tons, threads=opts.threads)
    problem = budget.memory_problem(need, budget.available_memory())
    if problem:
        raise RunError(problem)
    if need > budget.ANNOUNCE_BYTES:
        print(f"gammac: note: this run needs about {budget.gigabytes(need)} of memory", file=sys.stderr)
    looks = bool(effect.appearance_kernels())
    textures = load_textures(effect) if looks else None     # before any long setup
    init = _init_state(opts)             # a missing or mismatched --init is refused before any work
    out = Path(opts.out)
    created = not out.exists()
    prepare_output(out)
    from . import folder

    call = stop.call if stop is not None else _direct
    cancel = stop.token if stop is not None else None
    lock = folder.OutputLock(out)
    try:
        lock.__enter__()
    except folder.FolderError as err:
        raise RunError(str(err)) from None
    try:
        session = _start_locked(effect, opts, rt, scene, shown, looks, textures, out, call, cancel, entered, reuse,
                                warm_outputs, init)
    except BaseException:
        lock.__exit__()
        if created:
            _remove_empty_folders(out)      # a run refused at its start leaves no empty --out behind
        raise
    session.lock = lock
    # reading the mesh and binding its triangles to surfaces; all of start (scene,
    # compile, setup, the earlier run's files set aside)
    session.summary["scene_seconds"] = scene_seconds
    session.summary["start_seconds"] = time.perf_counter() - entered
    return session


def _start_locked(effect, opts, rt, scene, shown, looks, textures, out, call, cancel, entered, reuse=None,
                  warm_outputs=False, init=None) -> Run:
    """The rest of ``start``, with the output folder locked."""
    from . import folder
    from .events import WriteQueue

    mesh = scene.mesh
    folder.remove_stale_temporaries(out)
    folder.recover(out)
    from ...backends.effect_cache import SharedKernels, kernels_for

    t0 = time.perf_counter()
    kernels = call(kernels_for, effect)
    compile_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        cfg = build_config(rt, effect, kernels, opts, scene.bounds, scene.down)
        cfg.triangle_surface = scene.triangle_surface
        sim = None
        if reuse is not None:
            try:
                call(reuse.reconfigure, cfg)    # waits for a setup still being taken for the cache
                sim = reuse
            except (ValueError, RuntimeError):
                sim = None              # another surfel set is needed: build it
        if sim is None:
            if warm_outputs:
                from .warmup import prepare_outputs

                prepare_outputs(shown is not None or looks, bool(looks), opts.height)
            sim = call(_simulation, rt, mesh, cfg, not shape_changes(effect), cancel)
    except (ValueError, TypeError, RuntimeError) as err:
        message = str(err).removeprefix("config: ")
        names = list(effect.surfaces)
        # The runtime knows surfaces by index: name them.
        message = re.sub(r"^surface (\d+) ", lambda m: f"surface {names[int(m[1])]} "
                         if int(m[1]) < len(names) else m[0], message)
        raise RunError(message) from None
    setup_seconds = time.perf_counter() - t0
    flat = scene.triangle_flat
    sim.set_shading(flat.astype(np.int32) if flat is not None and flat.any() else None,
                    0.0 if opts.shading == "flat" else float(opts.crease))
    if scene.materials:
        set_materials(sim, scene.triangle_material, scene.materials)
    if looks:
        sim.set_textures(textures)
    camera = run_camera(scene, opts)
    tracer = None
    if opts.ray or opts.ray_address:
        from ..distributed import distributed
        from ..distributed.cluster import RayUnavailable

        try:
            tracer = distributed.start(rt, effect, kernels, opts, scene, sim, build_config)
        except RayUnavailable as err:
            raise RunError(str(err)) from None
    from . import scene_inputs

    input_values = scene_inputs.columns(effect, scene, sim)
    scene_inputs.write(sim, effect, input_values)
    try:
        layered_rows = _layered_rows(effect, opts, sim, init)     # before the earlier results are set aside
        key, earlier, first = _resume_or_set_aside(effect, opts, scene, kernels, sim, out)
    except BaseException:
        if tracer is not None:
            tracer.close()
        raise
    if layered_rows is not None and first == 1:
        sim.set_rows(layered_rows[0])
    elif first > 1:
        scene_inputs.write(sim, effect, input_values)     # the maps do not hold them

    surfel_surface = np.asarray(sim.surfel_surfaces())
    static = static_columns(sim, surfel_surface)
    threads = min(opts.threads or cpu_count(), LIMITS["--threads"][1])
    summary = {
        "effect": str(effect.path), "scene": str(opts.scene),
        "surfaces": {name: {"triangles": count, "surfels": int(np.sum(surfel_surface == s.index)),
                            "properties": list(s.properties)}
                     for (name, count), s in zip(scene.triangles_per_surface.items(),
                                                 effect.surfaces.values())},
        "surfels": sim.num_surfels, "triangles": mesh.num_triangles, "threads": threads,
        "seed": opts.seed, "down": list(scene.down), "setup_seconds": setup_seconds,
        # start-up: gammac's imports, reading and checking the effect;
        # compile: code generation and JIT of the kernels (or the cache)
        "startup_seconds": None if opts.started is None else entered - opts.started,
        "compile_seconds": compile_seconds,
        "scene_seconds": None,         # filled in by start()
        "start_seconds": None,
        "setup_phases": dict(getattr(sim, "setup_seconds", {})),
        # what the setup took from the setup cache (setup_cache.py): "setup", "surfels" or "nothing"
        "setup_from_cache": "nothing" if getattr(sim, "setup_made_ahead", False)
                            else getattr(sim, "from_snapshot", "nothing"),
        # where the kernels came from: "compiled", "kernel cache" (machine code, linked by the JIT)
        # or "effect cache" (the checked effect and a shared object: backends/effect_cache.py)
        "kernels_from": ("effect cache" if isinstance(kernels, SharedKernels)
                         else "kernel cache" if kernels.from_cache else "compiled"),
        "versions": {"gamma": version(), "abi": abi.ABI_VERSION,
                     "llvm": ".".join(map(str, kernels.llvm_version)),
                     "runtime": getattr(rt, "RUNTIME_VERSION", None),
                     "embree": getattr(rt, "EMBREE_VERSION", None)},
        "rendered": shown,
        "appearance": looks,
        "requested_iterations": opts.iterations,
        "completed": False,            # true once the last iteration's outputs are written
        "run_key": key,                # what --resume checks (resume.py)
        # what `gammac render DIR` and `gammac export DIR` need to rebuild the surfels
        "options": {"params": dict(effect.overrides), "assign": list(opts.assign),
                    "down": list(opts.down) if opts.down is not None else None,
                    "surfels": opts.surfels, "seed": opts.seed, "tons": opts.tons,
                    "iterations": opts.iterations, "max_interactions": opts.max_interactions,
                    "shading": opts.shading, "crease": opts.crease},
        "iterations": [],
    }
    if layered_rows is not None:
        summary["init"] = layered_rows[1]
    if tracer is not None:
        summary["ray"] = {"address": opts.ray_address or "local", "workers": tracer.workers,
                          "job_bytes": tracer.job_bytes}
    report = NonFiniteReport(effect, opts.progress)
    summary["nonfinite"] = report.entries
    if earlier is not None:
        summary["iterations"] = earlier["iterations"][:first - 1]
        summary["resumed_at"] = first
        if earlier.get("ranges") is not None:     # over the whole run, the earlier iterations too
            summary["ranges"] = {name: list(bounds) for name, bounds in earlier["ranges"].items()}
        for entry in earlier.get("nonfinite", []):
            report.by_key[(entry["where"], entry["rule"])] = entry
            report.entries.append(entry)
    shapes = shape_changes(effect)
    where = next((w for s in effect.surfaces.values() for _, _, w in s.shape.values()), "")
    if shapes:
        summary["geometry"] = sim.geometry()
    session = Run(effect, opts, out, rt, scene, kernels, sim, camera, threads, shown, looks,
                  surfel_surface, static, summary, report, WriteQueue(), shapes, where, tracer=tracer)
    session.first_iteration = first
    session.call = call
    session.cancel = cancel
    session.input_values = input_values
    return session


def _simulation(rt, mesh, cfg, shape_static: bool = False, cancel=None):
    """``Simulation(mesh, cfg)``, with the setup cache's snapshot for it or
    the surfels ``gammac run`` sampled on ``mesh`` while it started up
    (prefetch.py, setup_cache.py: used only if they are this setup's); a
    setup not taken whole from the cache is kept there for the next run
    (taken from the simulation behind the loop when ``shape_static``: no
    rule of the effect changes the shape).  ``cancel``: the run's CancelToken."""
    from . import prefetch
    from ..caches import setup_cache

    ahead = prefetch.sample_for(mesh, cfg.surfels, cfg.seed, cancel)
    snapshot = None
    if isinstance(ahead, rt.SetupSnapshot):
        snapshot, ahead = ahead, None
    elif ahead is None:                 # nothing read ahead (a scene file, a glTF, ...)
        snapshot = setup_cache.load(mesh, cfg.surfels, cfg.seed)
    sim = rt.Simulation(mesh, cfg, ahead, snapshot, cancel=cancel)
    if sim.from_snapshot != "setup" or sim.setup_made_ahead:
        setup_cache.store(sim, mesh, cfg.surfels, cfg.seed, behind=shape_static)
    return sim


def _check_scene_inputs(effect, scene) -> None:
    """mask() and attribute() against this scene: errors stop the run, with
    the calls' file:line:col; warnings are printed (scene_inputs.py)."""
    if not effect.inputs and not effect.mask_uses:
        return
    from ...frontend.diagnostics import GammaError, render
    from .scene_inputs import problems

    found = problems(effect, scene)
    errors = [d for d in found if d.severity == "error"]
    if errors:
        raise GammaError(effect.path, effect.source, errors)
    if found:
        print(render(found, effect.path, effect.source), file=sys.stderr)


def _init_state(opts):
    """``opts.init``'s final state (layered.py), its options checked against
    this run's; None without --init (or when resuming: the run's own maps count)."""
    if opts.init is None or opts.resume:
        return None
    from . import layered

    try:
        state = layered.final_state(opts.init)
        layered.check_options(state, opts)
    except layered.InitError as err:
        raise RunError(str(err)) from None
    return state


def _layered_rows(effect, opts, sim, init):
    """With --init: (the rows the run starts from, what they took from the
    earlier run), checked before anything is written; else None."""
    if init is None:
        return None
    from . import layered

    try:
        return layered.initial_rows(init, effect, opts, sim)
    except layered.InitError as err:
        raise RunError(str(err)) from None


def _resume_or_set_aside(effect, opts, scene, kernels, sim, out) -> tuple:
    """The run key; with --resume the earlier summary and the first iteration
    to run (the rows of the last complete one loaded), else the earlier run's
    files set aside: (key, earlier summary or None, first iteration)."""
    from . import folder, resume

    key = resume.run_key(kernels.ir_text, scene, opts)
    earlier, first = None, 1
    if opts.resume:
        if shape_changes(effect):
            raise RunError("--resume: an effect that changes the shape of the scene cannot be "
                           "resumed (its geometry is not in the maps); run it again")
        try:
            earlier, done = resume.load(out, key, opts.iterations)
            sim.set_rows(resume.rows_from_map(out / "maps" / f"iter_{done:04d}.ply", effect,
                                              np.asarray(sim.surfel_surfaces()), effect.row_width))
        except resume.ResumeError as err:
            raise RunError(str(err)) from None
        folder.discard_after(out, done)
        first = done + 1
    else:
        try:
            folder.set_aside(out)
        except OSError as err:
            raise RunError(f"cannot write to '{out}': {err.strerror or err}") from None
    return key, earlier, first


#: The event number NonFiniteReport files appearance kernels under (the
#: runtime reports them apart, by surface and statement).
APPEARANCE = -2


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
        self.kernels.update({(APPEARANCE, 0, k.surface.index): k for k in effect.appearance_kernels()})

    def add_appearance(self, iteration: int, items) -> None:
        """The (surface, statement, count) list of ``Simulation.last_render_stats``."""
        self.add(iteration, [(APPEARANCE, 0, surface, statement, count)
                             for surface, statement, count in items])

    def add(self, iteration: int, *lists) -> None:
        for items in lists:
            for event, ton, surface, statement, count in items:
                kernel = self.kernels.get((event, ton if event >= 0 else 0, surface))
                if kernel is None:
                    continue
                st = kernel.statement_at(statement)
                where = f"{st.origin}:{st.pos.line}:{st.pos.col}"
                key = (where, kernel.label)
                if key not in self.by_key:
                    entry = {"where": where, "rule": kernel.label, "count": 0, "first_iteration": iteration}
                    self.by_key[key] = entry
                    self.entries.append(entry)
                    print(f"\ngammac: warning: {where}: in {kernel.label}, "
                          f"'{st.target.text} {st.op} ...' gave NaN or infinity "
                          f"{count} times in iteration {iteration}; those results were not stored",
                          file=sys.stderr)
                self.by_key[key]["count"] += count


