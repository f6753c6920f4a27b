"""Saved results reused: ``gammac render DIR`` and ``gammac export DIR``.

A run's folder holds, per iteration, every surfel's row (``maps/iter_NNNN.ply``)
and in ``summary.json`` what placed the surfels (effect, scene, assignment,
surfel count, seed).  ``reopen`` rebuilds the simulation with the same
surfels (placement is deterministic: same mesh, count and seed, same
surfels), checks they are the saved ones, and loads an iteration's rows into
it; pictures and textures then come from the runtime as in the run, with no
γ-ton traced.

A run whose shape changes (SPEC §13.12) re-tiles its mesh and moves or
re-samples its surfels, so no placement from the scene gives them again:
for an iteration after the first shape step that moved the geometry, the
simulation is rebuilt on the deformed mesh the run saved
(``meshes/iter_NNNN.ply``) with the saved map's surfels (``shaped_simulation``;
both in ``reload.py``).
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from ...options import RunOptions
from ..running.common import RunError
from ..running.reload import load_iteration
from ..running.runner import start


def reopen(folder: str | Path, view=None, eye=None, look_at=None, up=None, fov: float = 30.0,
           threads: int = 0, shading: str | None = None, crease: float | None = None, stop=None):
    """(run session, summary, the iterations saved) of the run in ``folder``;
    shading and crease (None: the run's) as ``gammac run`` takes them.
    ``stop``: the command's Interruptions (its token stops the set-up, the
    renders and the bakes)."""
    from ...frontend.checker import load

    folder = Path(folder)
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
        options = summary["options"]
    except FileNotFoundError:
        raise RunError(f"'{folder}' holds no run (no summary.json)") from None
    except (OSError, ValueError, KeyError) as err:
        raise RunError(f"cannot read '{folder / 'summary.json'}': {err}") from None
    saved = sorted(int(p.stem[5:]) for p in (folder / "maps").glob("iter_[0-9][0-9][0-9][0-9].ply"))
    if not saved:
        raise RunError(f"'{folder}' holds no maps (maps/iter_NNNN.ply)")
    effect_path = Path(summary["effect"])
    if not effect_path.is_file():
        raise RunError(f"the run's effect '{effect_path}' is not there any more (paths are relative "
                       "to the folder gammac run was started in)")
    effect = load(str(effect_path), options.get("params") or {})
    opts = RunOptions(scene=summary["scene"], out="", assign=options.get("assign", []),
                      down=tuple(options["down"]) if options.get("down") else None,
                      view=view, eye=eye, look_at=look_at, up=up, fov=fov,
                      surfels=options["surfels"], seed=options["seed"], tons=options.get("tons"),
                      threads=threads, max_interactions=options.get("max_interactions", 100),
                      iterations=max(saved), progress=False,
                      shading=shading or options.get("shading", "smooth"),
                      crease=crease if crease is not None else options.get("crease", 60.0))
    import tempfile

    scratch = tempfile.TemporaryDirectory(prefix="gamma-saved-")   # start() wants a folder of its own
    session = start(effect, replace(opts, out=scratch.name), stop)
    session.lock.__exit__()
    session.scratch = scratch
    session.saved_summary = summary
    return session, summary, saved


def run_ranges(summary: dict, folder: Path, saved: list[int], names) -> dict:
    """The run's value range per property: summary.json's, else from the maps."""
    from .outputs import read_ply

    ranges = {k: tuple(v) for k, v in (summary.get("ranges") or {}).items()}
    missing = [n for n in names if n not in ranges]
    for it in saved if missing else ():
        columns = read_ply(folder / "maps" / f"iter_{it:04d}.ply")
        for name in missing:
            values = columns[name][np.isfinite(columns[name])]
            if values.size:
                low, high = ranges.get(name, (np.inf, -np.inf))
                ranges[name] = (min(low, float(values.min())), max(high, float(values.max())))
    return ranges


def render_saved(folder, iteration: int | None, show: str | None, output: str | None, size: int,
                 samples: int, ao: int, stop=None, **camera) -> Path:
    """One picture of a saved iteration: the appearance, or ``show`` in false
    colour on the run's range.  Returns the file written."""
    import io

    from PIL import Image

    from ...files import atomic_write
    from ..running.camera import sun_direction
    from .outputs import false_colour_png

    folder = Path(folder)
    session, summary, saved = reopen(folder, stop=stop, **camera)
    it = iteration or saved[-1]
    load_iteration(session, folder, it)
    sim, (eye, target, up, fov) = session.sim, session.camera
    names = sorted({n for s in session.effect.surfaces.values() for n in s.properties})
    if show is not None and show not in names:
        raise RunError(f"--show {show}: the effect has no such property ({', '.join(names) or 'none'})")
    if show is None and not session.looks:
        show = session.shown
    suffix = f"_{show}" if show else ""
    target_path = Path(output) if output else folder / "renders" / f"view_iter_{it:04d}{suffix}.png"
    if show:
        low, high = run_ranges(summary, folder, saved, [show]).get(show, (0.0, 1.0))
        low = min(0.0, low)      # as the run's own renders: the scale starts at 0 or below
        if high <= low:
            high = low + 1.0
        values = np.ascontiguousarray(np.nan_to_num(_column(session, show), nan=low, posinf=high,
                                                    neginf=low), np.float32)
        value, shade = sim.render(values, eye, target, up, fov, size, size, session.threads, cancel=session.cancel)
        data = false_colour_png(value, shade, low, high, show, f"{show}, iteration {it}")
    else:
        image = sim.render_appearance(eye, target, up, fov, size, size, session.threads, samples,
                                      sun_direction(session.camera), ao, it, cancel=session.cancel)
        rgb = np.clip(np.asarray(image)[..., :3], 0.0, 1.0)
        buffer = io.BytesIO()
        Image.fromarray((rgb * 255 + 0.5).astype(np.uint8)).save(buffer, format="PNG")
        data = buffer.getvalue()
    atomic_write(target_path, data)
    return target_path


def _column(session, name: str) -> np.ndarray:
    from ..running.common import property_columns

    rows = np.asarray(session.sim.rows())
    return property_columns(session.effect, rows, session.surfel_surface)[name]


def export_saved(folder, iterations: list[int] | None, bake_size: int | None, threads: int = 0,
                 progress: bool = False, texel_density: float | None = None, usd: bool = False,
                 preset: str = "gltf", float_maps: bool = False, stop=None) -> list[int]:
    """The export (SPEC §16.3) of saved iterations (the last by default),
    every 16-bit property map on the run's range, and with ``usd`` an
    OpenUSD stage of them.  Returns the iterations.  ``stop``: as for reopen."""
    from .export import Exporter

    if usd:
        import importlib.util

        if importlib.util.find_spec("pxr") is None:
            raise RunError("--format usd needs usd-core (pip install 'gamma-weathering[usd]')")

    folder = Path(folder)
    session, summary, saved = reopen(folder, threads=threads, stop=stop)
    chosen = iterations or [saved[-1]]
    for it in chosen:
        if it not in saved:
            raise RunError(f"no map of iteration {it} in '{folder}' (saved: {saved[0]}..{saved[-1]})")
    names = sorted({n for s in session.effect.surfaces.values() for n in s.properties})
    session.out = folder
    exporter = Exporter(session, bake_size, texel_density, run_ranges(summary, folder, saved, names), preset,
                        float_maps)
    if usd:
        exporter.keep_for_usd()
    from .progress import progress as shown

    for it in shown(chosen, unit=" iteration", file=sys.stderr, disable=not progress, desc="export"):
        load_iteration(session, folder, it)
        exporter.write(it)
    if usd:
        exporter.finish_usd()
    return chosen
