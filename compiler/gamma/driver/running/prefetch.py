"""The mesh file of ``gammac run --scene FILE`` read, and its surfels sampled,
while the command starts up.

Reading a mesh and sampling its surfels are among the longest steps of a
run's start, and the command needs neither until it has imported the
compiler and read and checked the effect, all on one core.  ``start`` reads the file on a background thread from the moment the
command line is parsed (``Mesh.load`` releases the GIL) and then samples the
surfels on it (``SurfelSample``: the sampling needs only the mesh, the surfel
count and the seed, not the effect), and then makes the rest of the setup
for every triangle on one surface (``SetupSnapshot.make_ahead``; not once
the effect is known to have another number of surfaces: ``expect``), unless
the setup cache keeps this
mesh's setup (setup_cache.py): then that is read and prepared instead, and
``sample_for`` hands out the ``SetupSnapshot``.  The read, the cache file's
name, its reading and checking and the preparing are one runtime call
(``_runtime.read_mesh_ahead``), which holds no GIL while gammac imports.
``scene._load_mesh`` ``take``s the mesh
instead of reading the file again, and the runner hands ``sample_for(mesh,
...)`` to the ``Simulation``, which uses the surfels only if they are the
ones it would sample itself (same mesh, count and seed: checked in the
runtime), so the outputs are the same bit for bit.

Only a plain OBJ or PLY file named on the command line is read ahead (a scene
file or glTF is assembled from parts by ``scene.py``).  The mesh is used only
if the file is still the one that was read (same size, modification time and
inode); otherwise, or if reading it ahead failed for any reason, ``take``
returns None and the file is read again where it always was, so every error
is reported there, in the same words and in the same order relative to the
effect's errors.  A sampling that fails only means the setup samples again
(and reports the error there); surfels are sampled ahead only when the count
is within ``--surfels``' limits and their memory is a small part of what the
machine has free (a run too large for it is refused by the runner, as before,
not by an allocation here).
"""

from __future__ import annotations

import atexit
import os
import threading

from ... import background

#: Extensions the runtime's own readers parse (no OpenMesh, no global state).
SUFFIXES = (".obj", ".ply")

_lock = threading.Lock()
_pending: dict[str, "_Read"] = {}
_handed: list["_Read"] = []      # reads whose mesh ``take`` handed out, their samples not yet
#: Stops the samplings started here (gamma/cancel.h): at the interpreter's
#: exit, and when the run that waits for one is interrupted.
_cancel = None


class _Read:
    """One file read ahead: ``mesh``, a ``background.Outcome`` of the Mesh (or
    None), and once it is set, ``sampled``, an Outcome of its SurfelSample or
    SetupSnapshot (None: none)."""

    def __init__(self, path: str, read_mesh_ahead, surfels: int | None, seed: int, threads: int):
        self.path = path
        self.signature = None
        self.sampled: background.Outcome | None = None
        if surfels is not None and not worth_sampling(surfels, seed, threads):
            surfels = None
        # The cache's folder found here, on the main thread, which imports gamma.files
        # anyway: the thread goes straight into the runtime.
        from ...files import cache_dir

        folder = cache_dir() if surfels is not None else None
        self.mesh = background.start(self._work, read_mesh_ahead, surfels, seed, threads,
                                     str(folder) if folder is not None else "", name="gamma-mesh-read")

    def _work(self, read_mesh_ahead, surfels, seed, threads, folder):
        # The read, the setup cache's file named, read, checked and prepared: one
        # runtime call, without the GIL, which several calls from here would each
        # have to wait for while gammac imports (setup_cache.h).
        try:
            mesh, signature, snapshot = read_mesh_ahead(self.path, folder, surfels or 0,
                                                        seed if surfels is not None else 0, threads)
        except Exception:  # noqa: BLE001 - read again (and reported) by scene.py
            return None
        if mesh is None:                 # a directory, a FIFO, missing, unreadable, changed: reported later
            return None
        self.signature = signature
        if snapshot is not None:
            self.sampled = background.Outcome.of(snapshot)
        elif surfels is not None:
            # Sampling takes longer: on a thread of its own, so the mesh is handed out before it ends.
            self.sampled = background.start(_sample, mesh, surfels, seed, threads, name="gamma-surfel-sample")
        return mesh


@atexit.register
def _forget() -> None:
    """At the interpreter's exit: the samplings still running are stopped, and
    the reads and samples nobody took waited for and dropped (the runtime's
    objects are freed before it)."""
    if _cancel is not None:
        _cancel.cancel()
    with _lock:
        reads = list(_pending.values()) + _handed
        _pending.clear()
        _handed.clear()
    for read in reads:
        read.mesh.exception()
        if read.sampled is not None:
            read.sampled.exception()
    # (the calls of reads dropped before, a file changed since it was read, are
    # waited for by background's own handler, which runs after this one)


#: Surfel counts up to which the rest of the setup is made ahead too (above,
#: a setup made ahead for the wrong binding would be held, in memory, beside
#: the Simulation's own).
AHEAD_MAX_SURFELS = 500_000
#: The number of surfaces of the effect being run, once known (``expect``).
_surfaces: int | None = None


def expect(surfaces: int) -> None:
    """The effect has ``surfaces`` surfaces: a setup made ahead assumes one
    (every triangle on it), so with any other count none is made from now
    on (one being made is still handed out: the Simulation then takes only
    its surfels)."""
    global _surfaces
    _surfaces = surfaces


def _sample(mesh, surfels: int, seed: int, threads: int):
    """The surfels sampled, and then, unless the effect is known to have
    another number of surfaces than one, the rest of the setup made for
    every triangle on one surface (``SetupSnapshot.make_ahead``: what the
    Simulation would make for that binding, bit for bit; it takes it whole
    only when its binding is that one, else only the surfels).  The core
    gammac's start-up leaves idle makes most of the setup of a first run."""
    from ... import _runtime

    sample = _runtime.SurfelSample(mesh, surfels, seed, threads, cancel=_cancel)
    if not sample.ok or surfels > AHEAD_MAX_SURFELS or _surfaces not in (None, 1):
        return sample
    try:
        return _runtime.SetupSnapshot.make_ahead(mesh, sample, threads)
    except Exception:  # noqa: BLE001 - the Simulation sets up (and reports) as always
        return None


def _signature(path: str):
    st = os.stat(path)
    return st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev


def _key(path) -> str:
    from pathlib import Path

    return str(Path(path))


def worth_sampling(surfels: int, seed: int, threads: int) -> bool:
    """Whether ``surfels`` surfels are sampled ahead: the options within their
    limits (else the runner refuses the run), and the run's memory for them
    under a quarter of what is free."""
    from . import budget
    from ...options import LIMITS

    if not all(low <= value <= high for value, (low, high) in
               ((surfels, LIMITS["--surfels"]), (seed, LIMITS["--seed"]), (threads, LIMITS["--threads"]))):
        return False
    available = budget.available_memory()
    need = budget.run_memory(surfels, 0, 1, history=False)
    return need <= (available // 4 if available is not None else budget.BASE_BYTES + 100_000_000)


def start(path: str, surfels: int | None = None, seed: int = 1, threads: int = 0) -> None:
    """Begin reading the mesh file ``path`` (if it is one read ahead), then
    sample ``surfels`` surfels on it with ``seed`` (None: do not sample) on
    ``threads`` threads (0: all cores)."""
    if os.path.splitext(os.fspath(path))[1].lower() not in SUFFIXES:
        return
    try:
        # imported here, on the main thread, which imports it anyway (for the run)
        from ... import _runtime

        read_mesh_ahead = _runtime.read_mesh_ahead
    except Exception:  # noqa: BLE001 - a runtime that does not load is reported by the runner
        return
    global _cancel
    with _lock:
        if _cancel is None:
            _cancel = _runtime.CancelToken()
        if _key(path) in _pending:
            return
        _pending[_key(path)] = _Read(path, read_mesh_ahead, surfels, seed, threads)


def take(path: "os.PathLike | str"):
    """The mesh read ahead from ``path`` (waiting for it), or None: then read
    the file as usual.  Each read is handed out once."""
    with _lock:
        read = _pending.pop(_key(path), None)
    if read is None:
        return None
    mesh = read.mesh.result()
    try:
        if mesh is not None and _signature(read.path) == read.signature:
            with _lock:
                _handed.append(read)
            return mesh
    except OSError:
        pass
    return None


#: Seconds between looks at the run's token while a sampling is waited for.
CANCEL_STEP = 0.05


def sample_for(mesh, surfels: int, seed: int, cancel=None):
    """The surfels sampled ahead on ``mesh`` (a mesh ``take`` handed out), or
    the setup cache's snapshot for it, waiting for them, or None.  The
    Simulation checks that they fit.  Once ``cancel`` (the run's
    CancelToken) is cancelled, the samplings stop and None is returned."""
    with _lock:
        read = next((r for r in _handed if r.mesh.result() is mesh), None)
        if read is not None:
            _handed.remove(read)
    if read is None or read.sampled is None:
        return None
    while cancel is not None and not read.sampled.wait(CANCEL_STEP):
        if cancel.cancelled:
            _cancel.cancel()
            return None
    try:
        sample = read.sampled.result()
    except Exception:  # noqa: BLE001 - sampled again (and reported) by the Simulation
        return None
    return sample if sample is not None and sample.matches(mesh, surfels, seed) else None
