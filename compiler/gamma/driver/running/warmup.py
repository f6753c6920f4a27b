"""What a run's outputs will import, imported while the runtime builds the
simulation.

``Simulation(mesh, config)`` releases the GIL for its whole setup (a second or
so per 100,000 surfels), and parts of it leave a core idle; the main thread
only waits.  ``prepare_outputs`` starts a daemon thread that imports, during
that wait, what the writers would otherwise import on the loop's thread or
after the last iteration: Pillow's drawing and FreeType, its image plugins
only for a run whose appearance sequence Pillow saves (a GIF).  Pillow's plugins are left out
otherwise: its PNGs are encoded in the runtime now, and a rerun (its setup
read from the cache) would spend the plugins' import beside the loop's first
trace.  It only warms caches:
nothing it does changes an output, and a failure here is ignored (the writer
that needs the module imports it again and reports the error there, as it
always did).
"""

from __future__ import annotations

import threading


def prepare_outputs(pictures: bool, sequence: bool, picture_height: int) -> threading.Thread:
    """Start the warm-up thread (daemon) and return it (joining is optional):
    ``pictures``, false-colour or appearance renders will be drawn;
    ``sequence``, Pillow will save the appearance sequence."""
    thread = threading.Thread(target=_warm, args=(pictures, sequence, picture_height),
                              name="gamma-warmup", daemon=True)
    thread.start()
    return thread


def _warm(pictures: bool, sequence: bool, picture_height: int) -> None:
    try:
        if pictures:
            from PIL import Image, ImageDraw, ImageFont  # noqa: F401

            ImageFont.load_default(size=max(11, picture_height // 40)).getbbox("0")
            if sequence:
                Image.preinit()     # the plugins the GIF's save() would import
    except Exception:  # noqa: BLE001 - a cache warmed or not; the writers report real errors
        pass
