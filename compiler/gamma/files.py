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


_unsafe_said: set = set()


def cache_dir() -> Path | None:
    """Where compiled kernels and setups are kept: $GAMMA_CACHE_DIR, else
    ~/.cache/gamma ($XDG_CACHE_HOME respected); GAMMA_CACHE_DIR=off disables
    the caches.  A folder that another user owns, or that others may write
    to, is not used (the caches load machine code from it): None, and a note
    on stderr once per folder."""
    configured = os.environ.get("GAMMA_CACHE_DIR")
    if configured == "off":
        return None
    if configured:
        folder = Path(configured)
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        folder = Path(base) / "gamma"
    problem = _unsafe(folder)
    if not problem:
        try:    # made private: entries are written 0600 (``cache_write``) in 0700 folders
            folder.mkdir(mode=CACHE_FOLDER_MODE, parents=True, exist_ok=True)
        except OSError:
            return None                 # cannot be made (read-only, a file there): no cache
    if problem:
        if str(folder) not in _unsafe_said:
            _unsafe_said.add(str(folder))
            import sys

            print(f"gammac: note: not using the cache folder '{folder}': {problem} "
                  "(it would load code from there); running without the cache", file=sys.stderr)
        return None
    return folder


def _unsafe(folder: Path) -> str:
    """Why code kept in ``folder`` could be someone else's ('' if it cannot)."""
    try:
        st = os.stat(folder)
    except OSError:
        return ""                       # made by this user when first written
    if st.st_uid != os.getuid():
        return "another user owns it"
    if st.st_mode & 0o022:
        return "other users can write to it"
    return ""


#: Modes of the caches' entries and folders: only their owner reads them.
CACHE_FILE_MODE = 0o600
CACHE_FOLDER_MODE = 0o700


def cache_write(path: Path, data) -> None:
    """``atomic_write`` of a cache entry: 0600, in a folder made 0700."""
    path.parent.mkdir(mode=CACHE_FOLDER_MODE, parents=True, exist_ok=True)
    atomic_write(path, data, CACHE_FILE_MODE)


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
