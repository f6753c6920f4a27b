"""Writing a file so that it is either complete or absent.

``atomic_write`` writes to a temporary name in the same folder, then renames
it into place: an interrupted run, a full disk or two processes sharing a
kernel cache never leave a half-written file.  Every file the package writes
(run outputs, the kernel cache, ``gammac fmt --write``) goes through it.
"""

from __future__ import annotations

import os
import tempfile
import threading
from pathlib import Path

_umask_lock = threading.Lock()


def _umask() -> int:
    # os.umask can only be read by setting it: the lock keeps a writer thread
    # from seeing the temporary 0 another thread set.
    with _umask_lock:
        mask = os.umask(0)
        os.umask(mask)
    return mask


def atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
