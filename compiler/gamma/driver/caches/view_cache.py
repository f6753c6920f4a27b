"""False-colour views kept in the cache folder beside the setup they were
cast on, so that a run set up from the setup cache does not cast them again.

A false-colour picture's rays (``FalseColourView``: per pixel whether the
ray hit, its 8 nearest surfels and their weights, the shade) depend only on
the setup (mesh, surfel count, seed: the setup cache's file name, which
holds the runtime's build), the mesh itself (its vertices and triangles,
hashed: the setup's name only fingerprints them), Embree (a shared library
the runtime's build does not name), the binding of triangles to surfaces
(which surfels a pixel may take), the shading (flat parts, crease angle) and
the camera and picture size: the key covers all of them.  Casting them
(mostly the 8-nearest search) took CPU beside the loop of every run;
reading them back takes a small part of that.

Only views of runs whose shape never changes are kept (the writer casts
those from the setup on).  A file is the view's bytes
(``FalseColourView.to_bytes``: every size, count, index, weight and shade
checked when read back) followed by their CRC-32 and a mark, as the setup
cache's files are; one that is damaged, cut short or of another surfel count
is removed and cast again.  Views count towards the setup cache's limit,
live only as long as their setup's file, and at most the most recent few of
each setup are kept (setup_cache.trim).  Nothing here raises: a view not
kept or not read only costs time.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from ... import background
from . import setup_cache

#: The mark after the view's bytes and their CRC-32 (setup_cache.write_with_trailer).
MARK = b"GMFV"


def path_for(run) -> Path | None:
    """The cache file of ``run``'s false-colour view, or None (the cache off,
    or a runtime that does not name its setups)."""
    try:
        from ... import _runtime

        setup = setup_cache.path_for(run.scene.mesh, run.opts.surfels, run.opts.seed)
        if setup is None:
            return None
        mesh = run.scene.mesh
        eye, target, up, fov = run.camera
        key = hashlib.sha256(b"false-colour view 1")
        key.update(str(getattr(_runtime, "EMBREE_VERSION", "")).encode())
        key.update(np.ascontiguousarray(mesh.vertices(), np.float32).tobytes())
        key.update(np.ascontiguousarray(mesh.triangles(), np.int32).tobytes())
        key.update(np.ascontiguousarray(run.scene.triangle_surface, np.int32).tobytes())
        flat = run.scene.triangle_flat
        key.update(b"flat" + (np.ascontiguousarray(flat, np.uint8).tobytes() if flat is not None else b"none"))
        camera = [*map(float, eye), *map(float, target), *map(float, up), float(fov)]
        key.update(repr((run.opts.shading, float(run.opts.crease), camera, run.opts.width,
                         run.opts.height)).encode())
    except Exception:  # noqa: BLE001 - see the module's docstring
        return None
    stem = setup.name.removeprefix("setup-").removesuffix(".bin")
    return setup.parent / f"{setup_cache.VIEW_PREFIX}{stem}-{key.hexdigest()[:32]}.bin"


def load(path: Path | None, width: int, height: int, surfels: int):
    """The view kept at ``path``, or None (none kept, or one that is not a
    whole view of this size and surfel count: then it is removed)."""
    if path is None:
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None
    from ... import _runtime

    try:
        body = setup_cache.body_of(data, MARK)
        if body is None:
            raise ValueError("damaged or cut short")
        view = _runtime.FalseColourView.from_bytes(bytes(body))
        if (view.width, view.height, view.surfels) != (width, height, surfels):
            raise ValueError("another size or surfel count")
    except Exception:  # noqa: BLE001 - whatever the bytes (MemoryError included), cast again
        setup_cache.unlink_quietly(path)
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
        if data.nbytes > setup_cache.limit_bytes() // 2:
            return                      # as a setup that large is not kept
        setup_cache.write_with_trailer(path, data, MARK)
    except Exception:  # noqa: BLE001 - an unwritable cache only costs time
        pass
