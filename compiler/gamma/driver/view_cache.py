"""False-colour views kept in the cache folder beside the setup they were
cast on, so that a run set up from the setup cache does not cast them again.

A false-colour picture's rays (``FalseColourView``: per pixel whether the
ray hit, its 8 nearest surfels and their weights, the shade) depend only on
the setup (mesh, surfel count, seed: the setup cache's file name, which
holds the runtime's build), the binding of triangles to surfaces (which
surfels a pixel may take), the shading (flat parts, crease angle) and the
camera and picture size.  Casting them cost ~80 ms of CPU for a 512 x 512
picture of the bunny at 100,000 surfels (most of it the 8-nearest search),
beside the loop of every run; reading them back, ~11 MB, a few.

Only views of runs whose shape never changes are kept (the writer casts
those from the setup on).  A file is the view's bytes
(``FalseColourView.to_bytes``, every count and index checked when read back)
followed by their CRC-32 and a mark, as the setup cache's files are; one that
is damaged or cut short is removed and cast again.  A view lives as long as
its setup's file does, the most recent few of each setup (setup_cache.trim).
Nothing here raises: a view not kept or not read only costs time.
"""

from __future__ import annotations

import hashlib
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..files import atomic_write
from . import background, setup_cache

#: Trailer after the view's bytes: their CRC-32, then this mark.
MARK = b"GMFV"
TRAILER = struct.Struct("<I4s")
PREFIX = "view-"


def path_for(run) -> Path | None:
    """The cache file of ``run``'s false-colour view, or None (the cache off,
    or a runtime that does not name its setups)."""
    try:
        setup = setup_cache.path_for(run.scene.mesh, run.opts.surfels, run.opts.seed)
    except Exception:  # noqa: BLE001 - see the module's docstring
        return None
    if setup is None:
        return None
    eye, target, up, fov = run.camera
    key = hashlib.sha256(b"false-colour view 1")
    key.update(np.ascontiguousarray(run.scene.triangle_surface, np.int32).tobytes())
    flat = run.scene.triangle_flat
    key.update(b"flat" + (np.ascontiguousarray(flat, np.uint8).tobytes() if flat is not None else b"none"))
    camera = [*map(float, eye), *map(float, target), *map(float, up), float(fov)]
    key.update(repr((run.opts.shading, float(run.opts.crease), camera, run.opts.width, run.opts.height)).encode())
    stem = setup.name.removeprefix("setup-").removesuffix(".bin")
    return setup.parent / f"{PREFIX}{stem}-{key.hexdigest()[:16]}.bin"


def load(path: Path | None, width: int, height: int):
    """The view kept at ``path``, or None (none kept, or one that is not a
    whole view of this size: then it is removed)."""
    if path is None:
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None
    from .. import _runtime

    body, trailer = data[:-TRAILER.size], data[-TRAILER.size:]
    try:
        crc, mark = TRAILER.unpack(trailer)
        if mark != MARK or crc != zlib.crc32(body):
            raise ValueError("damaged")
        view = _runtime.FalseColourView.from_bytes(body)
        if (view.width, view.height) != (width, height):
            raise ValueError("another size")
    except (struct.error, ValueError):
        try:
            path.unlink()
        except OSError:
            pass
        return None
    try:
        os.utime(path)                  # recently used: trimmed last
    except OSError:
        pass
    return view


def store(path: Path | None, view) -> None:
    """Keep ``view`` at ``path``, written on a thread of its own (waited for
    before gammac exits, as the setup cache's writes are)."""
    if path is not None:
        setup_cache.keep_behind(background.start(_write, path, view, name="gamma-view-cache"))


def _write(path: Path, view) -> None:
    try:
        data = view.to_bytes()
        atomic_write(path, (memoryview(data), TRAILER.pack(zlib.crc32(memoryview(data)), MARK)))
        setup_cache.trim(path.parent, keep=path)
    except (OSError, ValueError):
        pass                            # an unwritable cache only costs time
