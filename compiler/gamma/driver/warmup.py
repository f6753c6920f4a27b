"""What a run's outputs will import, imported while the runtime builds the
simulation.

``Simulation(mesh, config)`` releases the GIL for its whole setup (a second or
so per 100,000 surfels), and parts of it leave a core idle; the main thread
only waits.  ``prepare_outputs`` starts a daemon thread that imports, during
that wait, what the writers would otherwise import on the loop's thread or
after the last iteration: tqdm, Pillow's image plugins and FreeType, numpy's
masked arrays (which ``np.percentile`` pulls in).  It only warms caches:
nothing it does changes an output, and a failure here is ignored (the writer
that needs the module imports it again and reports the error there, as it
always did).
"""

from __future__ import annotations

import threading


def prepare_outputs(progress: bool, pictures: bool, picture_height: int) -> threading.Thread:
    """Start the warm-up thread (daemon) and return it (joining is optional)."""
    thread = threading.Thread(target=_warm, args=(progress, pictures, picture_height),
                              name="gamma-warmup", daemon=True)
    thread.start()
    return thread


def _warm(progress: bool, pictures: bool, picture_height: int) -> None:
    try:
        if progress:
            import tqdm  # noqa: F401  (writers.ProgressWriter)
        if pictures:
            import numpy.ma  # noqa: F401  (np.percentile -> np.unique -> np.ma.is_masked)
            from PIL import Image, ImageDraw, ImageFont, PngImagePlugin  # noqa: F401

            Image.preinit()     # the plugins the first save() would import
            ImageFont.load_default(size=max(11, picture_height // 40)).getbbox("0")
    except Exception:  # noqa: BLE001 - a cache warmed or not; the writers report real errors
        pass
