"""The mesh file of ``gammac run --scene FILE`` read while the command starts up.

Reading the bunny's OBJ takes the runtime ~0.1 s; the command spends longer
than that importing the compiler, reading and checking the effect, all on one
core.  ``start`` reads the file on a background thread from the moment the
command line is parsed (``Mesh.load`` releases the GIL), and
``scene._load_mesh`` ``take``s the mesh instead of reading the file again.

Only a plain OBJ or PLY file named on the command line is read ahead (a scene
file or glTF is assembled from parts by ``scene.py``).  The result is the one
reading the file later would give: the mesh is used only if the file is still
the one that was read (same size, modification time and inode); otherwise, or
if reading it ahead failed for any reason, ``take`` returns None and the file
is read again where it always was, so every error is reported there, in the
same words and in the same order relative to the effect's errors.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

#: Extensions the runtime's own readers parse (no OpenMesh, no global state).
SUFFIXES = (".obj", ".ply")

_lock = threading.Lock()
_pending: dict[str, "_Read"] = {}


class _Read:
    def __init__(self, path: str):
        self.path = path
        self.signature = None
        self.mesh = None
        self.thread = threading.Thread(target=self._work, name="gamma-mesh-read", daemon=True)

    def _work(self) -> None:
        try:
            from ..files import file_problem

            if file_problem(self.path):      # a directory, a FIFO, missing: reported later
                return
            signature = _signature(self.path)
            from .. import _runtime

            mesh = _runtime.Mesh.load(self.path)
            if _signature(self.path) == signature:
                self.signature, self.mesh = signature, mesh
        except Exception:  # noqa: BLE001 - read again (and reported) by scene.py
            pass


def _signature(path: str):
    st = os.stat(path)
    return st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev


def _key(path) -> str:
    return str(Path(path))


def start(path: str) -> None:
    """Begin reading the mesh file ``path`` (if it is one read ahead)."""
    if Path(path).suffix.lower() not in SUFFIXES:
        return
    read = _Read(path)
    with _lock:
        if _key(path) in _pending:
            return
        _pending[_key(path)] = read
    read.thread.start()


def take(path: Path | str):
    """The mesh read ahead from ``path`` (waiting for it), or None: then read
    the file as usual.  Each read is handed out once."""
    with _lock:
        read = _pending.pop(_key(path), None)
    if read is None:
        return None
    read.thread.join()
    try:
        if read.mesh is not None and _signature(read.path) == read.signature:
            return read.mesh
    except OSError:
        pass
    return None
