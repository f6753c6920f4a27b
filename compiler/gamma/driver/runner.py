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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import abi, __version__
from ..frontend.ast import Pos
from ..backends.jit import JitKernels
from ..ir.effect import Effect, Length, Source
from ..frontend.diagnostics import Diagnostic, GammaError


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
    started: float | None = None  # time.perf_counter() when gammac started (start-up time)


def runtime_module():
    """``gamma._runtime``, checked against ``abi`` (version and binding)."""
    from .. import _runtime as rt

    problems = abi.check_runtime(rt)
    if problems:
        raise RunError(f"the runtime does not match the compiler ({'; '.join(problems)}); "
                       "reinstall the package")
    return rt


#: Defaults for ton types that do not say, as fractions of the scene diagonal.
DEFAULT_BOUNCE = Length(0.02, relative=True)
DEFAULT_STEP = Length(0.005, relative=True)
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
    args = {"first_iteration": src.first, "last_iteration": src.last}
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
        cfg.add_ton_type(*ton.motion, ton.initial, bounce, step)
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
    for surface in effect.surfaces.values():
        for slot, rate, _ in surface.shape.values():
            cfg.add_shape_rate(surface.index, slot, rate)
    for name in mass_properties(effect):
        cfg.add_mass_property([s.properties.get(name, -1) for s in effect.surfaces.values()],
                              [t.carry.get(name, -1) for t in effect.tons.values()])
    return cfg


def mass_properties(effect: Effect) -> list[str]:
    """Properties whose pick-up is accounted (SPEC §19): a name that is both a
    surface property and an attribute some ton type carries."""
    carried = {name for t in effect.tons.values() for name in t.carry}
    names = []
    for s in effect.surfaces.values():
        names += [n for n in s.properties if n in carried and n not in names]
    return names


def shape_changes(effect: Effect) -> bool:
    return any(s.shape for s in effect.surfaces.values())


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


OUTPUT_FOLDERS = ("maps", "renders", "renders/false_colour", "export", "meshes")


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




def run(effect: Effect, opts: RunOptions, writers: list | tuple = ()) -> dict:
    """Simulate ``effect`` with ``opts``; the standard outputs, then ``writers``,
    receive the run's events (``events.py``).  Returns the summary."""
    from .events import IterationTraced, IterationUpdated, RunFinished, SetupDone, publish
    from .writers import standard_writers

    session = start(effect, opts)
    subscribers = standard_writers(session) + list(writers)
    try:
        with session.behind:   # leaving it waits for the writers' queued jobs
            publish(subscribers, SetupDone(session))
            for it in range(1, opts.iterations + 1):
                traced = session.trace(it)
                publish(subscribers, IterationTraced(session, it, traced))
                rows, props, record = session.update(it, traced)
                publish(subscribers, IterationUpdated(session, it, rows, props, record))
            publish(subscribers, RunFinished(session, session.summary))
    except OSError as err:
        raise RunError(f"cannot write to '{session.out}': {err.strerror or err}") from None
    return session.summary


@dataclass
class Run:
    """One run's state, shared by the loop and its writers.  Writers read it;
    only the loop advances ``sim`` (and only on the loop's thread)."""

    effect: Effect
    opts: RunOptions
    out: Path
    rt: object                     # gamma._runtime
    scene: object                  # scene.Scene
    kernels: JitKernels            # owns the machine code ``sim`` calls: keep alive
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

    def trace(self, it: int) -> dict:
        """Trace iteration ``it``'s gamma-tons; the runtime's statistics."""
        return self.sim.trace(it)

    def update(self, it: int, traced: dict) -> tuple[np.ndarray, dict, dict]:
        """Run the update rules; (rows, property columns, summary record)."""
        updated = self.sim.update(it)
        self.nonfinite.add(it, traced["nonfinite"], updated["nonfinite"])
        rows = self.sim.rows()
        props = property_columns(self.effect, rows, self.surfel_surface)
        record = {k: traced[k] for k in abi.STATISTICS if k in traced}
        record["property_sums"] = {name: float(np.sum(col, dtype=np.float64))
                                   for name, col in props.items()}
        record["trace_seconds"] = traced["trace_seconds"]
        record["update_seconds"] = updated["seconds"]
        names = mass_properties(self.effect)
        if names:
            record["mass"] = {name: books for name, books in zip(names, traced["mass"])}
        if self.shapes:
            shaped = self.sim.shape(it)
            record["geometry"] = shaped["geometry"]
            record["shape"] = {k: v for k, v in shaped.items() if k != "geometry"}
            for key, count in (("clamped_vertices", "was cut to the per-iteration bound"),
                               ("inversion_limited", "was shortened so that no triangle turns over")):
                if shaped[key]:
                    print(f"\ngammac: warning: {self.shape_where}: the displacement of {shaped[key]} "
                          f"vertices {count} in iteration {it}", file=sys.stderr)
            if shaped["changed"]:
                rows = self.sim.rows()
                self.refresh_surfels()
                props = property_columns(self.effect, rows, self.surfel_surface)
                record["property_sums"] = {name: float(np.sum(col, dtype=np.float64))
                                           for name, col in props.items()}
        self.summary["iterations"].append(record)
        return rows, props, record

    def refresh_surfels(self) -> None:
        """Surfel positions, normals and surfaces after the shape changed."""
        self.surfel_surface = np.asarray(self.sim.surfel_surfaces())
        self.static_columns = static_columns(self.sim, self.surfel_surface)

    def export_scene(self):
        """The scene as export sees it: the deformed mesh as one object once the
        shape has changed, else the loaded scene."""
        if not self.shapes:
            return self.scene
        from types import SimpleNamespace

        vertices, triangles = self.sim.mesh_arrays()
        mesh = self.rt.Mesh.from_arrays(vertices, triangles)
        return SimpleNamespace(mesh=mesh, object_names=[Path(self.opts.scene).stem],
                               triangle_object=np.zeros(len(triangles), np.int64),
                               triangle_surface=np.asarray(self.sim.triangle_surfaces()))


def static_columns(sim, surfel_surface: np.ndarray) -> dict:
    """x y z nx ny nz surface per surfel."""
    pos, nrm = sim.surfel_positions(), sim.surfel_normals()
    static = {axis: pos[:, j] for j, axis in enumerate("xyz")}
    static.update({axis: nrm[:, j] for j, axis in enumerate(("nx", "ny", "nz"))})
    static["surface"] = surfel_surface.astype(np.float32)
    return static


def start(effect: Effect, opts: RunOptions) -> Run:
    """Check the options, load the scene, compile, build the simulation and
    clear an earlier run's files; every user error is raised before any output."""
    from .camera import DEFAULT_VIEW, CameraError, auto_camera
    from .events import WriteQueue
    from .scene import SceneError, load_scene

    entered = time.perf_counter()
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
    t0 = time.perf_counter()
    kernels = JitKernels(effect)
    compile_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        cfg = build_config(rt, effect, kernels, opts, scene.bounds, scene.down)
        cfg.triangle_surface = scene.triangle_surface
        sim = rt.Simulation(mesh, cfg)
    except (ValueError, TypeError, RuntimeError) as err:
        message = str(err).removeprefix("config: ")
        names = list(effect.surfaces)
        # The runtime knows surfaces by index: name them.
        message = re.sub(r"^surface (\d+) ", lambda m: f"surface {names[int(m[1])]} "
                         if int(m[1]) < len(names) else m[0], message)
        raise RunError(message) from None
    setup_seconds = time.perf_counter() - t0
    looks = bool(effect.appearance_kernels())
    if looks:
        sim.set_textures(load_textures(effect))
    try:
        camera = auto_camera(scene.bounds, opts.view or DEFAULT_VIEW, scene.down, opts.fov)
    except CameraError as err:
        raise RunError(str(err)) from None
    if opts.eye is not None:
        _, target, up, fov = camera
        if np.allclose(opts.eye, target):
            raise RunError("--eye must not be the centre of the scene, which the camera looks at")
        camera = (tuple(opts.eye), target, up, fov)
    clear_earlier_run(out)

    surfel_surface = np.asarray(sim.surfel_surfaces())
    static = static_columns(sim, surfel_surface)
    threads = min(opts.threads or _cpu_count(), LIMITS["--threads"][1])
    summary = {
        "effect": str(effect.path), "scene": str(opts.scene),
        "surfaces": {name: {"triangles": count, "surfels": int(np.sum(surfel_surface == s.index))}
                     for (name, count), s in zip(scene.triangles_per_surface.items(),
                                                 effect.surfaces.values())},
        "surfels": sim.num_surfels, "triangles": mesh.num_triangles, "threads": threads,
        "seed": opts.seed, "down": list(scene.down), "setup_seconds": setup_seconds,
        # start-up: gammac's imports, reading and checking the effect;
        # compile: code generation and JIT of the kernels (or the cache)
        "startup_seconds": None if opts.started is None else entered - opts.started,
        "compile_seconds": compile_seconds,
        "setup_phases": dict(getattr(sim, "setup_seconds", {})),
        "versions": {"gamma": __version__, "abi": abi.ABI_VERSION,
                     "llvm": ".".join(map(str, llvm_version())),
                     "runtime": getattr(rt, "RUNTIME_VERSION", None),
                     "embree": getattr(rt, "EMBREE_VERSION", None)},
        "rendered": shown,
        "appearance": looks,
        "iterations": [],
    }
    report = NonFiniteReport(effect, opts.progress)
    summary["nonfinite"] = report.entries
    shapes = shape_changes(effect)
    where = next((w for s in effect.surfaces.values() for _, _, w in s.shape.values()), "")
    if shapes:
        summary["geometry"] = sim.geometry()
    return Run(effect, opts, out, rt, scene, kernels, sim, camera, threads, shown, looks,
               surfel_surface, static, summary, report, WriteQueue(), shapes, where)


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


def llvm_version():
    import llvmlite.binding

    return llvmlite.binding.llvm_version_info


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
