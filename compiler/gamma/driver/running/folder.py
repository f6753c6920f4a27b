"""The output folder over a run's life: one run at a time, nothing stale,
and earlier results never lost to a run that fails.

- ``OutputLock``: an exclusive lock (``DIR/.gamma-run.lock``) for the run;
  a second ``gammac run`` on the same folder is refused, so whatever
  temporary files the folder holds at start are stale (left by a killed run)
  and ``remove_stale_temporaries`` deletes them.
- ``set_aside``: once the new run is set up, the earlier run's files move to
  ``DIR/.previous-run/``.  A run that fails puts them back (``restore``); a
  run that completes, or is interrupted after at least one iteration (its
  folder then holds complete iterations and ``"completed": false``), drops
  them (``drop``).  After a crash (``kill -9``) the next run decides by what
  the folder holds (``recover``).
"""

from __future__ import annotations

import errno
import os
import re
import shutil
from pathlib import Path

LOCK_NAME = ".gamma-run.lock"
PREVIOUS = ".previous-run"
#: Folders of DIR that hold a run's files (export/ has one folder per object).
FOLDERS = ("maps", "renders", "renders/false_colour", "export")
_ITERATION_FILE = re.compile(r"^iter_(\d{4,})")
_RUN_FILES = ("summary.json", "renders/sequence.gif", "renders/sequence.mp4", "renders/strip.png")
#: Temporary names of atomic_write (".NAME.XXXXXXXX") and of the MP4 writer.
_TEMPORARY = re.compile(r"^\.(iter_\d{4,}.*|summary\.json|sequence\.(gif|mp4)|strip\.png|sequence)\..+")


class FolderError(Exception):
    """A one-line problem with the output folder."""


class OutputLock:
    def __init__(self, out: Path):
        self.out = out
        self.file = None

    def __enter__(self) -> "OutputLock":
        import fcntl

        try:
            self.file = open(self.out / LOCK_NAME, "a")
            fcntl.flock(self.file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            if self.file is not None:
                self.file.close()
                self.file = None
            if err.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise FolderError(f"another gammac run is writing to '{self.out}'; wait for it "
                                  "or choose another --out") from None
            raise FolderError(f"cannot write to '{self.out}': {err.strerror or err}") from None
        return self

    def __exit__(self, *exc) -> None:
        if self.file is not None:
            # removed while still held, so the folder keeps no trace of the run's lock
            (self.out / LOCK_NAME).unlink(missing_ok=True)
            self.file.close()     # releases the lock
            self.file = None


def _folders(out: Path) -> list[Path]:
    found = [out] + [out / f for f in FOLDERS]
    export = out / "export"
    if export.is_dir():
        found += [p for p in export.iterdir() if p.is_dir()]
    return [f for f in found if f.is_dir()]


def remove_stale_temporaries(out: Path) -> int:
    """Delete temporary files a killed run left behind (call under the lock)."""
    removed = 0
    for folder in _folders(out):
        for path in folder.iterdir():
            if _TEMPORARY.match(path.name) and path.is_file():
                path.unlink(missing_ok=True)
                removed += 1
    return removed


def run_files(out: Path, after: int = 0):
    """A run's files in ``out`` (relative paths); with ``after``, only the
    iteration files of iterations beyond it and the whole-run files."""
    for folder in _folders(out):
        for path in folder.iterdir():
            m = _ITERATION_FILE.match(path.name)
            if m and path.is_file() and int(m.group(1)) > after:
                yield path.relative_to(out)
    for name in _RUN_FILES:
        if (out / name).is_file():
            yield Path(name)


def _move(src_root: Path, dst_root: Path, relative: list[Path]) -> None:
    for rel in relative:
        target = dst_root / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(src_root / rel, target)


def set_aside(out: Path) -> None:
    """Move the earlier run's files to DIR/.previous-run/."""
    previous = out / PREVIOUS
    if previous.exists():
        shutil.rmtree(previous)
    _move(out, previous, list(run_files(out)))


def restore(out: Path) -> None:
    """Undo ``set_aside``: the failed run's files go, the earlier ones come back."""
    previous = out / PREVIOUS
    for rel in list(run_files(out)):
        (out / rel).unlink(missing_ok=True)
    if previous.is_dir():
        _move(previous, out, list(run_files(previous)))
        shutil.rmtree(previous, ignore_errors=True)


def drop(out: Path) -> None:
    shutil.rmtree(out / PREVIOUS, ignore_errors=True)


def recover(out: Path) -> None:
    """After a run that was killed: keep its iterations if it completed any
    (its summary.json exists), else bring the earlier run's files back."""
    if (out / PREVIOUS).is_dir():
        if (out / "summary.json").is_file():
            drop(out)
        else:
            restore(out)


def discard_after(out: Path, iteration: int) -> None:
    """Delete iteration files beyond ``iteration`` and the sequences (for --resume)."""
    for rel in list(run_files(out, after=iteration)):
        if rel != Path("summary.json"):
            (out / rel).unlink(missing_ok=True)
