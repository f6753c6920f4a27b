"""What the driver's parts share below the run loop (``runner``): the
user-facing error of a run, the runtime checked against the compiler, and
an effect's per-property columns of surfel rows.  Imports no other driver
module, so that the writers, exporters and caches the runner uses can take
these without importing the runner.
"""

from __future__ import annotations

import numpy as np

from ... import abi
from ...ir.effect import Effect


class RunError(Exception):
    """A one-line, user-facing error (bad mesh, bad option value)."""


def runtime_module():
    """``gamma._runtime``, checked against ``abi`` (version and binding)."""
    from ... import _runtime as rt

    problems = abi.check_runtime(rt)
    if problems:
        raise RunError(f"the runtime does not match the compiler ({'; '.join(problems)}); "
                       "reinstall the package")
    return rt


def shape_changes(effect: Effect) -> bool:
    return any(s.shape for s in effect.surfaces.values())


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


def cpu_count() -> int:
    """The cores this process may run on."""
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
