"""What a run may ask for, checked before anything is allocated: the memory a
run will need (stated when large, refused when the machine lacks it), the
scene sizes the tracer handles, and how far from the scene a source or the
camera may be.  The limits are stated in language/SPEC.md §15 and §16.1;
each option's own range is declared with it (``gamma.options``).
"""

from __future__ import annotations

import math

#: Scene sizes (bounding-box diagonal, scene units) at which the tracer gives
#: the same result as at unit scale.  Measured: the bunny gives identical
#: counts from 2.5e-7 to 2.5e11 units and loses hits outside (float
#: intersection tests underflow or overflow); the limits keep a margin.
MIN_SCENE_DIAGONAL = 1e-5
MAX_SCENE_DIAGONAL = 1e10

#: A point or spot source, and the camera, must lie within this many scene
#: diagonals of the scene's centre (Embree refuses rays starting beyond
#: ~1.8e18, and nothing that far can be meant).
MAX_DISTANCE_IN_DIAGONALS = 1000.0

#: Memory of a run, calibrated on `gammac run` (peak resident size): a fixed
#: part (Python, LLVM, Embree), per surfel (surfel arrays, k-d trees, the
#: per-iteration map and its PLY bytes), per float of a surfel's row, per
#: surfel and iteration when a false-colour history is kept, and per γ-ton
#: record of a tracing pass.
BASE_BYTES = 160 << 20
BYTES_PER_SURFEL = 700
BYTES_PER_ROW_FLOAT = 16
BYTES_PER_HISTORY_VALUE = 4
#: A tracing pass keeps, until it sums them, a log per chunk of 1024 γ-tons
#: (~160 bytes) and a record per surface write (surfel index and one float
#: per property; one per γ-ton is counted).  It sums them every batch of
#: chunks (runtime Config.trace_batch_chunks: max(64, 8 × threads) chunks),
#: so only one batch's logs are held, whatever the number of γ-tons.
BYTES_PER_TON_CHUNK = 160
BYTES_PER_TON_RECORD_FIXED = 4
CHUNK_TONS = 1024


def batch_tons(threads: int) -> int:
    """γ-tons of one batch of chunks (the runtime's default batch)."""
    import os

    threads = threads if threads > 0 else (os.cpu_count() or 1)
    return max(64, 8 * threads) * CHUNK_TONS
#: Above this, `run` says how much memory it will need before it starts.
ANNOUNCE_BYTES = 2 << 30


def run_memory(surfels: int, row_width: int, iterations: int, history: bool, tons: int = 0,
               threads: int = 0) -> int:
    """Bytes a run is expected to need at its peak (``tons``: γ-tons of the
    largest tracing pass; its logs are held one batch at a time)."""
    per_surfel = BYTES_PER_SURFEL + BYTES_PER_ROW_FLOAT * row_width
    if history:
        per_surfel += BYTES_PER_HISTORY_VALUE * iterations
    per_ton = BYTES_PER_TON_CHUNK / 1024 + BYTES_PER_TON_RECORD_FIXED + 4 * max(0, row_width - 3)
    return int(BASE_BYTES + surfels * per_surfel + min(tons, batch_tons(threads)) * per_ton)


def available_memory() -> int | None:
    """Memory the system can give without swapping (Linux), else None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def gigabytes(n: int) -> str:
    return f"{n / (1 << 30):.1f} GB"


def memory_problem(need: int, available: int | None) -> str | None:
    if available is not None and need > available:
        return (f"this run needs about {gigabytes(need)} of memory and {gigabytes(available)} are "
                "available; use fewer --surfels, or fewer --iterations with a false-colour --show")
    return None


def scene_size_problem(diagonal: float) -> str | None:
    if not (MIN_SCENE_DIAGONAL <= diagonal <= MAX_SCENE_DIAGONAL) or not math.isfinite(diagonal):
        return (f"the scene's size (bounding-box diagonal {diagonal:.3g}) is outside what the tracer "
                f"handles exactly ({MIN_SCENE_DIAGONAL:g} to {MAX_SCENE_DIAGONAL:g} scene units); "
                "scale it (a scene file's \"scale\")")
    return None


def distance_problem(what: str, point, centre, diagonal: float) -> str | None:
    """A position too far from the scene to trace from."""
    offset = math.dist(tuple(map(float, point)), tuple(map(float, centre)))
    limit = MAX_DISTANCE_IN_DIAGONALS * diagonal
    if not math.isfinite(offset) or offset > limit:
        shown = ", ".join(f"{float(c):g}" for c in point)
        return (f"{what} at ({shown}) is {offset:.3g} scene units from the scene's centre; "
                f"it must be within {MAX_DISTANCE_IN_DIAGONALS:g} scene diagonals ({limit:.3g})")
    return None
