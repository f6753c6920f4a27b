"""Checks on the files a user names (effect, mesh, scene, texture) before
they are opened: a directory, a FIFO or a device is refused with a one-line
reason instead of an OS error or a read that never returns."""

from __future__ import annotations

import stat
from pathlib import Path


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
