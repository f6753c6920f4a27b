"""The user's files: checked before they are read, written so that each is
either complete or absent.

``file_problem`` refuses a directory, a FIFO or a device with a one-line
reason instead of an OS error or a read that never returns.
``atomic_write`` writes to a temporary name in the same folder, then renames
it into place: an interrupted run, a full disk or two processes sharing a
kernel cache never leave a half-written file.  Every file the package writes
(run outputs, the kernel and setup caches, ``gammac fmt --write``) goes
through it.  ``cache_dir`` is where those caches live.
"""

from __future__ import annotations

import os
import stat
import tempfile
import threading
from pathlib import Path

_umask_lock = threading.Lock()


def file_problem(path: Path | str) -> str | None:
    """Why ``path`` cannot be read as a file, or None when it can be opened."""
    try:
        mode = Path(path).stat().st_mode
    except FileNotFoundError:
        return "file not found"
    except (OSError, ValueError) as err:
        return getattr(err, "strerror", None) or str(err)
    if stat.S_ISDIR(mode):
        return "is a directory"
    if not stat.S_ISREG(mode):
        return "not a regular file (a pipe or a device)"
    return None


def _umask() -> int:
    # os.umask can only be read by setting it: the lock keeps a writer thread
    # from seeing the temporary 0 another thread set.
    with _umask_lock:
        mask = os.umask(0)
        os.umask(mask)
    return mask


def cache_dir() -> Path | None:
    """Where compiled kernels and setups are kept: $GAMMA_CACHE_DIR, else
    ~/.cache/gamma ($XDG_CACHE_HOME respected); GAMMA_CACHE_DIR=off disables
    the caches."""
    configured = os.environ.get("GAMMA_CACHE_DIR")
    if configured == "off":
        return None
    if configured:
        return Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "gamma"


def atomic_write(path: Path, data, mode: int | None = None) -> None:
    """Write ``data`` (bytes, a tuple of buffers written one after the
    other, or a callable given the open binary file, which writes it) to
    ``path``; the file gets ``mode`` (default: 0666 less the umask)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            if callable(data):
                data(f)
            else:
                for part in data if isinstance(data, tuple) else (data,):
                    f.write(part)
        os.chmod(tmp, (0o666 & ~_umask()) if mode is None else mode)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
