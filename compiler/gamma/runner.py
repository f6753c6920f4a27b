"""``gammac run``: compile an effect, hand its kernels to the C++ runtime,
iterate (trace, merge, update) and write the outputs.

This module is the only one that talks to ``gamma._runtime``; it turns a
checked ``Effect`` plus command-line options into the runtime's ``Config``.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import abi, __version__
from .ast import Pos
from .backend import JitKernels
from .checker import Effect
from .diagnostics import Diagnostic, GammaError
from .outputs import atomic_write, false_colour_png, ply_bytes, write_json


class RunError(Exception):
    """A one-line, user-facing error (bad mesh, bad option value)."""


@dataclass
class RunOptions:
    scene: str
    out: str
    assign: str | None = None
    iterations: int = 10
    surfels: int = 100_000
    tons: int | None = None
    seed: int = 1
    threads: int = 0              # 0 = all cores
    max_interactions: int = 100
    show: str | None = None       # property rendered in false colour
    width: int = 512
    height: int = 512
    progress: bool = True


def runtime_module():
    from . import _runtime as rt

    if rt.ABI_VERSION != abi.ABI_VERSION:
        raise RunError(f"runtime ABI {rt.ABI_VERSION} does not match compiler ABI "
                       f"{abi.ABI_VERSION}; reinstall the package")
    return rt


def refuse_untraced_motion(effect: Effect) -> None:
    """This runtime traces straight motion and settling only."""
    diags = []
    for ton in effect.tons.values():
        for init in ton.decl.motion:
            if init.name in ("parabolic", "flow") and ton.motion[abi.REFLECTANCE_SLOTS.index(init.name)] > 0:
                diags.append(Diagnostic(init.pos, f"{init.name} motion is not traced by this "
                                        "version of the runtime (straight motion and settling only)"))
    if not effect.sources:
        diags.append(Diagnostic(Pos(1, 1), "the effect declares no source, so no gamma-ton would be traced"))
    if diags:
        raise GammaError(effect.path, effect.source, diags)


def split_counts(counts: list[int], total: int) -> list[int]:
    """Split ``total`` in proportion to ``counts`` (largest remainder; sums exactly)."""
    whole = sum(counts)
    exact = [total * c / whole for c in counts]
    out = [int(math.floor(x)) for x in exact]
    order = sorted(range(len(counts)), key=lambda i: (out[i] - exact[i], i))
    for i in order[: total - sum(out)]:
        out[i] += 1
    return out


def pick_surface(effect: Effect, name: str | None):
    if name is None:
        if len(effect.surfaces) == 1:
            return next(iter(effect.surfaces.values()))
        raise RunError("the effect declares several surfaces; choose one with --assign "
                       f"({', '.join(effect.surfaces)})")
    if name not in effect.surfaces:
        raise RunError(f"--assign {name}: no such surface in {effect.path} "
                       f"(surfaces: {', '.join(effect.surfaces) or 'none'})")
    return effect.surfaces[name]


def build_config(rt, effect: Effect, kernels: JitKernels, opts: RunOptions):
    cfg = rt.Config()
    cfg.surfels = opts.surfels
    cfg.seed = opts.seed
    cfg.threads = opts.threads or _cpu_count()
    cfg.max_interactions = opts.max_interactions
    cfg.row_width = effect.row_width
    cfg.surface_rows = [s.initial_row + [0.0] * (effect.row_width - len(s.initial_row))
                        for s in effect.surfaces.values()]
    for ton in effect.tons.values():
        cfg.add_ton_type(*ton.motion, ton.initial)
    counts = [s.count for s in effect.sources]
    if opts.tons is not None:
        counts = split_counts(counts, opts.tons)
    for src, count in zip(effect.sources, counts):
        cfg.add_source(src.kind, src.ton, count, src.position)
    for k in effect.transport_kernels():
        cfg.set_transport(abi.EVENTS[k.event], k.ton.index, k.surface.index,
                          kernels.address[k.symbol], k.writes_surface)
    for k in effect.update_kernels():
        cfg.set_update(k.surface.index, kernels.address[k.symbol])
    return cfg


def auto_camera(bounds, fov_deg: float = 30.0):
    """Eye, target and up framing the scene's bounding box from front-left-above (+z front, +y up)."""
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    centre = (lo + hi) / 2
    radius = np.linalg.norm(hi - lo) / 2
    direction = np.array([-0.6, 0.35, 1.0])
    direction /= np.linalg.norm(direction)
    distance = radius / math.sin(math.radians(fov_deg) / 2) * 1.02
    return tuple(centre + direction * distance), tuple(centre), (0.0, 1.0, 0.0), fov_deg


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


def run(effect: Effect, opts: RunOptions) -> dict:
    refuse_untraced_motion(effect)
    surface = pick_surface(effect, opts.assign)
    shown = opts.show or next(iter(surface.properties), None)
    if shown is not None and shown not in surface.properties:
        raise RunError(f"--show {shown}: surface {surface.name} has no such property "
                       f"({', '.join(surface.properties) or 'none'})")
    for name, value, low in (("--iterations", opts.iterations, 1), ("--surfels", opts.surfels, 1),
                             ("--threads", opts.threads, 0), ("--tons", opts.tons or 0, 0),
                             ("--max-interactions", opts.max_interactions, 1),
                             ("--size", min(opts.width, opts.height), 16)):
        if value < low:
            raise RunError(f"{name} must be at least {low}, not {value}")
    rt = runtime_module()
    if not Path(opts.scene).is_file():
        raise RunError(f"cannot read mesh '{opts.scene}': file not found")
    try:
        mesh = rt.Mesh.load(opts.scene)
    except ValueError as err:
        raise RunError(str(err)) from None
    if mesh.degenerate_dropped:
        print(f"gammac: warning: {mesh.degenerate_dropped} degenerate triangles of "
              f"'{opts.scene}' ignored", file=sys.stderr)
    kernels = JitKernels(effect)
    cfg = build_config(rt, effect, kernels, opts)
    cfg.triangle_surface = np.full(mesh.num_triangles, surface.index, dtype=np.int32)
    t0 = time.perf_counter()
    try:
        sim = rt.Simulation(mesh, cfg)
    except ValueError as err:
        raise RunError(str(err)) from None
    setup_seconds = time.perf_counter() - t0

    out = Path(opts.out)
    columns_static = {}
    pos, nrm = sim.surfel_positions(), sim.surfel_normals()
    for j, axis in enumerate("xyz"):
        columns_static[axis] = pos[:, j]
    for j, axis in enumerate(("nx", "ny", "nz")):
        columns_static[axis] = nrm[:, j]
    # The runtime never uses more threads than there are cores (results do not
    # depend on it); the summary records what was actually used.
    threads = min(opts.threads or _cpu_count(), _cpu_count())
    summary = {
        "effect": str(effect.path), "scene": str(opts.scene), "surface": surface.name,
        "surfels": sim.num_surfels, "triangles": mesh.num_triangles, "threads": threads,
        "seed": opts.seed, "setup_seconds": setup_seconds,
        "versions": {"gamma": __version__, "abi": abi.ABI_VERSION,
                     "llvm": ".".join(map(str, __import__("llvmlite.binding").binding.llvm_version_info)),
                     "runtime": getattr(rt, "RUNTIME_VERSION", None)},
        "iterations": [],
    }
    history = []
    progress = Progress(opts.iterations, opts.progress)
    for it in range(1, opts.iterations + 1):
        stats = sim.trace(it)
        if stats["untraced"]:
            raise RunError(f"iteration {it}: {stats['untraced']} gamma-tons chose parabolic or flow "
                           "motion (an update rule made a reflectance negative?), which this "
                           "version does not trace")
        update_seconds = sim.update(it)
        rows = sim.rows()
        record = {k: stats[k] for k in ("emitted", "settled", "escaped", "capped", "interactions",
                                        "rays", "untraced")}
        record["property_sums"] = {name: float(np.sum(rows[:, slot], dtype=np.float64))
                                   for name, slot in surface.properties.items()}
        record["trace_seconds"] = stats["trace_seconds"]
        record["update_seconds"] = update_seconds
        summary["iterations"].append(record)
        columns = dict(columns_static)
        for name, slot in surface.properties.items():
            columns[name] = rows[:, slot]
        for j, name in enumerate(abi.REFLECTANCE_SLOTS):
            columns[f"reflectance_{name}"] = rows[:, j]
        atomic_write(out / "maps" / f"iter_{it:04d}.ply",
                     ply_bytes(columns, [f"gamma {__version__} iteration {it}",
                                         f"effect {Path(effect.path).name} surface {surface.name}"]))
        write_json(out / "summary.json", summary)
        if shown is not None:
            history.append(rows[:, surface.properties[shown]].copy())
        rate = stats["emitted"] / max(stats["trace_seconds"], 1e-9)
        progress.update(it, f"iterations  {stats['trace_seconds']:.2f} s trace  "
                            f"{rate / 1e3:.0f}k γ-tons/s")
    if shown is not None:
        render_history(sim, history, shown, out, opts, threads, mesh.bounds)
    return summary


def render_history(sim, history, shown, out: Path, opts: RunOptions, threads: int, bounds) -> None:
    """One false-colour PNG per iteration, all on the same colour scale."""
    vmax = max(float(np.percentile(h, 99.5)) for h in history)
    vmin = min(0.0, min(float(h.min()) for h in history))
    if vmax <= vmin:
        vmax = vmin + 1.0
    eye, target, up, fov = auto_camera(bounds)
    for it, values in enumerate(history, start=1):
        value, shade = sim.render(np.ascontiguousarray(values, dtype=np.float32), eye, target, up,
                                  fov, opts.width, opts.height, threads)
        png = false_colour_png(value, shade, vmin, vmax, shown, f"{shown}, iteration {it}")
        atomic_write(out / "renders" / f"iter_{it:04d}.png", png)


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
