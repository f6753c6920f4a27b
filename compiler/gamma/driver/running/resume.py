"""``gammac run --resume``: continue a run from its last complete iteration.

A run's state between iterations is its surfels' rows: surfel placement
depends only on the scene, ``--surfels`` and ``--seed``, and every random
number is keyed by (seed, iteration, γ-ton or surfel, draw) (SPEC §13.9).  The
map of the last complete iteration holds every row exactly (float32 columns:
the reflectance and each surface's properties), so loading it and tracing on
gives maps bit-identical to a run that was never interrupted.

``run_key`` fingerprints what the results depend on (the compiled IR, the
scene's geometry and binding, the options); ``--resume`` refuses a folder
whose summary.json carries another key.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from ... import abi
from ...version import version

#: Options that do not change the results (or are what --resume changes).
_NOT_IN_KEY = {"iterations", "threads", "progress", "resume", "out", "quiet", "started", "ray", "ray_address"}


def run_key(ir_text: str, scene, opts) -> str:
    h = hashlib.sha256()
    h.update(f"gamma {version()} abi {abi.ABI_VERSION}\0".encode())
    h.update(ir_text.encode("utf-8"))
    h.update(np.ascontiguousarray(scene.mesh.vertices(), dtype=np.float32).tobytes())
    h.update(np.ascontiguousarray(scene.mesh.triangles(), dtype=np.int32).tobytes())
    h.update(np.ascontiguousarray(scene.triangle_surface, dtype=np.int32).tobytes())
    options = {k: v for k, v in vars(opts).items() if k not in _NOT_IN_KEY}
    # a run folder by its path; a gamma.Result (the Python API) by what it is, not its address
    options["init"] = None if opts.init is None else str(opts.init) if isinstance(opts.init, (str, Path)) \
        else "result"
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    return h.hexdigest()


class ResumeError(Exception):
    pass


def load(out: Path, key: str, iterations: int) -> tuple[dict, int]:
    """The earlier summary and the number of its complete iterations."""
    path = out / "summary.json"
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ResumeError(f"--resume: '{out}' holds no run to resume (no summary.json)") from None
    except (OSError, ValueError) as err:
        raise ResumeError(f"--resume: cannot read '{path}': {err}") from None
    if not isinstance(summary, dict) or summary.get("run_key") != key:
        raise ResumeError(f"--resume: '{out}' holds a run of another effect, scene or options; "
                          "resume with the same command (only --iterations and --threads may change)")
    done = len(summary.get("iterations", []))
    while done > 0 and not (out / "maps" / f"iter_{done:04d}.ply").is_file():
        done -= 1
    if done == 0:
        raise ResumeError(f"--resume: '{out}' holds no complete iteration; run without --resume")
    if done >= iterations:
        raise ResumeError(f"--resume: '{out}' already holds {done} iterations; ask for more "
                          f"with --iterations (more than {done})")
    return summary, done


def rows_from_map(path: Path, effect, surfel_surface: np.ndarray, row_width: int) -> np.ndarray:
    """Every surfel's row as the map of one iteration recorded it."""
    from ..outputs.outputs import read_ply

    columns = read_ply(path)
    n = len(surfel_surface)
    if len(columns.get("x", ())) != n:
        raise ResumeError(f"--resume: '{path}' has {len(columns.get('x', ()))} surfels, "
                          f"the run has {n}")
    rows = np.zeros((n, row_width), np.float32)
    for j, name in enumerate(abi.REFLECTANCE_SLOTS):
        rows[:, j] = columns[f"reflectance_{name}"]
    for surface in effect.surfaces.values():
        mine = surfel_surface == surface.index
        for name, slot in surface.properties.items():
            rows[mine, slot] = columns[name][mine]
    return rows
