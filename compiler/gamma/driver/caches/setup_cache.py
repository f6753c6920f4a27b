"""The setup cache: a run's surfels, triangle lookup and splat kernel kept on
disk, so that the next run on the same mesh, with the same surfel count and
seed, skips most of its setup (SPEC §16.1).

The setup is a run's longest step before the first trace, and an artist
runs one effect after another on the same mesh.  ``Simulation.setup_snapshot`` gives the setup as
bytes (runtime/include/gamma/setup_snapshot.h); they are kept in
``cache_dir()`` as ``setup-BUILD-MESH-COUNT-SEED.bin``: BUILD the runtime
build (the linker's build ID of its module, ``_runtime.RUNTIME_BUILD``), MESH
the mesh's fingerprint (CRC-32s of its vertices, triangles and bounds, with
their counts), then the surfel count and the seed.  The runtime makes the
name (``_runtime.setup_cache_name``), so that ``gammac run`` can read the
file on its read-ahead thread in one call without the GIL
(``_runtime.read_mesh_ahead``, prefetch.py).  The binding of
triangles to surfaces, which comes from the effect, is inside the file: a
run with another binding takes only the surfels, and stores its own setup.
A file is the snapshot followed by its CRC-32 and a mark; one that is
damaged or cut short is never used (and is removed; one of another build
has another name, and goes when the cache is trimmed), and
the runtime takes a snapshot only when the mesh, count, seed and binding
are exactly its own, so a run set up from the cache is the same, bit for
bit, as one set up from scratch.  ``GAMMA_CACHE_DIR=off`` turns it off
together with the kernel cache.

Files are written behind the run (``store``) and ``wait`` is called before
the process ends.  The folder's setup files are kept under ``LIMIT_BYTES``
together (``$GAMMA_SETUP_CACHE_MB``), the least recently used removed first;
a snapshot larger than half of that, or than ``STORE_MAX_BYTES`` (it is held
in memory until written), is not kept.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

from ... import background
from ...files import cache_dir, cache_write

#: Trailer after the snapshot: CRC-32 of the snapshot, then this mark (the
#: runtime's SetupSnapshot.load_cached checks both).
MARK = b"GMSC"
TRAILER = struct.Struct("<I4s")
#: Default bound on the setup files kept together, in bytes.
LIMIT_BYTES = 1 << 30
#: Largest snapshot kept (it is held in memory while it is written).
STORE_MAX_BYTES = 256 << 20

_writes = background.Pending()


def limit_bytes() -> int:
    configured = os.environ.get("GAMMA_SETUP_CACHE_MB")
    try:
        return max(0, int(float(configured) * (1 << 20))) if configured else LIMIT_BYTES
    except (ValueError, OverflowError):         # not a number, inf, nan
        return LIMIT_BYTES


def path_for(mesh, surfels: int, seed: int) -> Path | None:
    """The cache file of a setup of ``surfels`` surfels on ``mesh`` with
    ``seed``, or None when the cache is off (or the runtime does not know
    its build)."""
    folder = cache_dir()
    if folder is None:
        return None
    from ... import _runtime

    name = _runtime.setup_cache_name(mesh, int(surfels), int(seed))
    return folder / name if name else None


def load(mesh, surfels: int, seed: int):
    """The SetupSnapshot kept for this mesh, count and seed, or None (none
    kept, the cache off, or a file that is not whole: then it is removed;
    one that cannot be read is left alone).  Never raises."""
    folder = cache_dir()
    if folder is None:
        return None
    from ... import _runtime

    try:
        # read straight into the runtime's arrays, its checksum checked, a file
        # refused removed and a file taken marked recently used: all there
        return _runtime.SetupSnapshot.load_cached(str(folder), mesh, int(surfels), int(seed))
    except (TypeError, ValueError, OverflowError):  # a count or seed the runtime cannot take
        return None


def store(sim, mesh, surfels: int, seed: int, behind: bool = False) -> None:
    """Keep ``sim``'s setup (just made, not taken from the cache) for the
    next run, written on a thread of their own.  The bytes are taken now,
    or with ``behind`` on that thread too: only for a simulation whose
    shape no rule changes (the runtime's reconfigure waits for it): taking
    them (a copy of the whole setup) was the last step between the setup and
    the first trace.  Never raises: a setup not kept only costs
    the next run time."""
    try:
        path = path_for(mesh, surfels, seed)
        # held in memory until written: a large one (1.6M surfels on a 1M-triangle
        # mesh: ~0.8 GB) is not kept, so a run's peak stays what it was
        if path is None or sim.setup_snapshot_bytes > min(limit_bytes() // 2, STORE_MAX_BYTES):
            return
        if behind:
            outcome = background.start(_take_and_write, sim, path, name="gamma-setup-cache")
        else:
            outcome = background.start(_write, path, sim.setup_snapshot(), name="gamma-setup-cache")
    except Exception:  # noqa: BLE001 - see above
        return
    _writes.add(outcome)


def _take_and_write(sim, path: Path) -> None:
    """``sim``'s setup written to the cache file as the runtime makes it
    (straight to the file, without the GIL: no 39 MB copy of the bunny's
    setup in memory first), then its trailer."""
    def write(f) -> None:
        f.flush()                       # nothing buffered yet: the runtime writes to the descriptor
        crc = sim.write_setup_snapshot(f.fileno())
        f.write(TRAILER.pack(crc, MARK))

    try:
        cache_write(path, write)
        trim(path.parent, keep=path)
    except Exception:  # noqa: BLE001 - a setup not kept only costs the next run time
        pass


def _write(path: Path, data) -> None:
    try:
        write_with_trailer(path, data, MARK)
    except OSError:
        pass                            # an unwritable cache only costs time


def write_with_trailer(path: Path, data, mark: bytes) -> None:
    """``data`` then its CRC-32 and ``mark`` written to ``path`` (atomically),
    then the folder trimmed (this file kept)."""
    cache_write(path, (memoryview(data), TRAILER.pack(zlib.crc32(memoryview(data)), mark)))
    trim(path.parent, keep=path)


def body_of(data: bytes, mark: bytes) -> memoryview | None:
    """What ``write_with_trailer`` wrote, or None if the trailer is not
    ``mark`` or the CRC-32 differs (a file damaged or cut short)."""
    if len(data) < TRAILER.size:
        return None
    body = memoryview(data)[:-TRAILER.size]
    crc, found = TRAILER.unpack(data[-TRAILER.size:])
    return body if found == mark and crc == zlib.crc32(body) else None


#: A temporary file of a write older than this was left by a process that
#: died while writing it (a write takes well under a second).
STALE_TEMPORARY_SECONDS = 3600


def keep_behind(outcome) -> None:
    """A cache write started elsewhere (view_cache.py) that ``wait`` waits for too."""
    _writes.add(outcome)


#: A setup's false-colour views (view_cache.py: ``view-STEM-KEY.bin``, STEM
#: the setup file's name between ``setup-`` and ``.bin``) count towards the
#: limit with the setups, live only as long as their setup's file, and the
#: most recently used VIEWS_PER_SETUP of each are kept.
VIEW_PREFIX = "view-"
VIEWS_PER_SETUP = 4


def trim(folder: Path, keep: Path) -> None:
    """Remove the least recently used setup and view files until the rest
    fit the limit (a setup's views with it), the views of setups not kept
    and all but the most recent views of each, and the temporary files of
    writes that never finished.  ``keep`` (the file just written) stays."""
    import time

    files = []                          # (mtime, size, path, setup stem or None)
    for entry in os.scandir(folder):
        try:
            st = entry.stat()
        except OSError:
            continue
        name = entry.name
        if name.startswith((".setup-", "." + VIEW_PREFIX)) and time.time() - st.st_mtime > STALE_TEMPORARY_SECONDS:
            unlink_quietly(entry.path)
        elif name.startswith("setup-") and name.endswith(".bin"):
            files.append((st.st_mtime_ns, st.st_size, Path(entry.path), None))
        elif name.startswith(VIEW_PREFIX) and name.endswith(".bin"):
            stem = name[len(VIEW_PREFIX):-len(".bin")].rsplit("-", 1)[0]
            files.append((st.st_mtime_ns, st.st_size, Path(entry.path), stem))
    setups = {path.name for _, _, path, stem in files if stem is None}
    seen: dict[str, int] = {}
    gone = set()
    for _, _, path, stem in sorted(files, key=lambda f: f[0], reverse=True):   # the most recent first
        if stem is None or path == keep:
            continue
        seen[stem] = count = seen.get(stem, 0) + 1
        if f"setup-{stem}.bin" not in setups or count > VIEWS_PER_SETUP:
            gone.add(path)
    total = sum(size for _, size, path, _ in files if path not in gone)
    for _, size, path, stem in sorted(files, key=lambda f: f[0]):              # the least recent first
        if total <= limit_bytes():
            break
        if path == keep or path in gone:
            continue
        gone.add(path)
        total -= size
        if stem is None:                # its views go with it
            for _, view_size, view, view_stem in files:
                if view_stem is not None and f"setup-{view_stem}.bin" == path.name and view not in gone \
                        and view != keep:
                    gone.add(view)
                    total -= view_size
    for path in gone:
        unlink_quietly(path)


def unlink_quietly(path) -> bool:
    """Remove ``path``; whether it was (another process may be trimming too)."""
    try:
        os.unlink(path)
        return True
    except OSError:
        return False


def wait() -> None:
    """Wait for the setups being written (before the process ends)."""
    _writes.wait()
