"""Layered runs: ``gammac run B.gamma ... --init DIR_A`` (and ``gamma.run(...,
init=result_or_dir)``) start B from run A's final surfel state.

Surfel placement depends only on the scene, ``--surfels`` and ``--seed``
(SPEC §13.2), so B, run on the same scene with the same count and seed, has
A's surfels; the surfels' positions are compared bit for bit to make sure.
A property of B starts at A's final value on the surfels whose surface has
the same name in both runs and has that property in A; everywhere else it
starts at B's declared initial value.  γ-reflectance always starts as B
declares it.  So rust and then rain streaks, or years of dirt and then one
cleaning, compose from recipes without a combined effect.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class InitError(Exception):
    """``--init`` refused: the message says what differs."""


@dataclass
class FinalState:
    """What B needs of A: its surfels and their final property values."""
    where: str                      # "run folder 'DIR'" or "the given result", for messages
    iteration: int                  # A's last complete iteration
    surfaces: list                  # A's surface names, by index
    surface_properties: dict | None # A's properties per surface name (None: every column, older runs)
    surfel_surface: np.ndarray      # A's surface index per surfel
    positions: np.ndarray           # (n, 3) float32
    columns: dict                   # property name -> float32 per surfel
    scene: str
    surfels: int                    # --surfels A asked for
    seed: int
    shape_change: bool


def _from_folder(folder: Path) -> FinalState:
    from ..outputs.outputs import read_ply

    where = f"run folder '{folder}'"
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InitError(f"--init: {where} holds no run (no summary.json)") from None
    except (OSError, ValueError) as err:
        raise InitError(f"--init: cannot read {folder / 'summary.json'}: {err}") from None
    done = len(summary.get("iterations", []))
    while done > 0 and not (folder / "maps" / f"iter_{done:04d}.ply").is_file():
        done -= 1
    if done == 0:
        raise InitError(f"--init: {where} holds no complete iteration")
    columns = read_ply(folder / "maps" / f"iter_{done:04d}.ply")
    surfaces = summary.get("surfaces", {})
    options = summary.get("options", {})
    known = {name: s["properties"] for name, s in surfaces.items() if "properties" in s}
    return FinalState(
        where=where, iteration=done, surfaces=list(surfaces),
        surface_properties=known if len(known) == len(surfaces) else None,
        surfel_surface=np.rint(columns.pop("surface")).astype(np.int64),
        positions=np.stack([columns.pop(c) for c in "xyz"], axis=1).astype(np.float32),
        columns={k: v for k, v in columns.items() if k not in ("nx", "ny", "nz")
                 and not k.startswith("reflectance_")},
        scene=str(summary.get("scene")), surfels=int(options.get("surfels", summary.get("surfels", 0))),
        seed=int(options.get("seed", summary.get("seed", 0))), shape_change="geometry" in summary)


def _from_result(result) -> FinalState:
    from .common import property_columns

    session = result.session
    rows = np.asarray(session.sim.rows())
    surfel_surface = np.asarray(session.surfel_surface, dtype=np.int64)
    effect = result.effect
    return FinalState(
        where="the given result", iteration=result.iterations, surfaces=list(effect.surfaces),
        surface_properties={name: list(s.properties) for name, s in effect.surfaces.items()},
        surfel_surface=surfel_surface, positions=np.asarray(session.sim.surfel_positions(), np.float32),
        columns=property_columns(effect, rows, surfel_surface),
        scene=str(session.opts.scene), surfels=session.opts.surfels, seed=session.opts.seed,
        shape_change=bool(session.shapes))


def final_state(init) -> FinalState:
    """A's final state from a run folder (str or Path) or a ``gamma.Result``."""
    if isinstance(init, FinalState):
        return init
    if isinstance(init, (str, Path)):
        return _from_folder(Path(init))
    if hasattr(init, "session") and hasattr(init, "effect"):
        return _from_result(init)
    raise TypeError(f"init must be a run folder or a gamma.Result, not {type(init).__name__}")


def check_options(a: FinalState, opts) -> None:
    """Refuse, before any work, an A of another scene, surfel count or seed."""
    if a.shape_change:
        raise InitError(f"--init: {a.where} changed the scene's shape; starting from a shape-change "
                        "run's last mesh is not supported yet")
    differs = _differences(a, opts, None)
    if differs:
        raise InitError(f"--init: {a.where} is not a run of this scene, surfel count and seed: "
                        + "; ".join(differs))


def _differences(a: FinalState, opts, count: int | None) -> list[str]:
    found = []
    if Path(a.scene).name != Path(str(opts.scene)).name:
        found.append(f"scene: A ran on '{a.scene}', this run on '{opts.scene}'")
    if a.surfels != opts.surfels:
        found.append(f"--surfels: A had {a.surfels}, this run {opts.surfels}")
    if a.seed != opts.seed:
        found.append(f"--seed: A had {a.seed}, this run {opts.seed}")
    if not found and count is not None and len(a.positions) != count:
        found.append(f"surfels: A has {len(a.positions)}, this run {count} (another scene?)")
    return found


def initial_rows(a: FinalState, effect, opts, sim) -> tuple[np.ndarray, dict]:
    """B's starting rows (its declared ones with A's values where surface and
    property names match) and what was taken, for summary.json."""
    check_options(a, opts)
    positions = np.asarray(sim.surfel_positions(), np.float32)
    differs = _differences(a, opts, len(positions))
    if not differs and not np.array_equal(positions, a.positions):
        differs.append("the surfels are not in the same places (another mesh with the same name?)")
    if differs:
        raise InitError(f"--init: {a.where} is not a run of this scene, surfel count and seed: "
                        + "; ".join(differs))
    rows = np.array(sim.rows(), dtype=np.float32, copy=True)
    surfel_surface = np.asarray(sim.surfel_surfaces(), dtype=np.int64)
    taken = {}
    for surface in effect.surfaces.values():
        if surface.name not in a.surfaces:
            continue
        theirs = a.surfaces.index(surface.name)
        mine = (surfel_surface == surface.index) & (a.surfel_surface == theirs)
        had = a.surface_properties.get(surface.name, ()) if a.surface_properties is not None else a.columns
        for name, slot in surface.properties.items():
            if name in had and name in a.columns and mine.any():
                rows[mine, slot] = a.columns[name][mine]
                taken.setdefault(surface.name, []).append(name)
    return rows, {"from": a.where, "iteration": a.iteration, "taken": taken}
