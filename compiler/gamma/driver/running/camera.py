"""Where the run's pictures are taken from: the camera framing the scene and
the sun's direction relative to it.  Pure geometry; knows nothing of the run."""

from __future__ import annotations

import math

from ...options import DEFAULT_VIEW


class CameraError(ValueError):
    """A camera option that cannot frame the scene."""


def auto_camera(bounds, view=DEFAULT_VIEW, down=(0.0, -1.0, 0.0), fov_deg: float = 30.0):
    """Eye, target and up framing the scene's bounding box; ``view`` points from
    the scene's centre toward the camera, "up" is against gravity."""
    import numpy as np

    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    centre = (lo + hi) / 2
    radius = np.linalg.norm(hi - lo) / 2
    direction = np.asarray(view, float)
    direction /= np.linalg.norm(direction)
    up = -np.asarray(down, float) / np.linalg.norm(down)
    if not 1.0 <= fov_deg <= 170.0:
        raise CameraError(f"--fov must be between 1 and 170 degrees, not {fov_deg:g}")
    if abs(float(np.dot(up, direction))) > 0.999:   # looking straight along gravity
        up = np.array([0.0, 0.0, -1.0]) if abs(up[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    distance = radius / math.sin(math.radians(fov_deg) / 2) * 1.02
    return tuple(centre + direction * distance), tuple(centre), tuple(up), fov_deg


def sun_direction(camera) -> tuple[float, float, float]:
    """Toward the sun: above the scene, over the camera's left shoulder."""
    import numpy as np

    eye, target, up, _ = (np.asarray(v, float) if i < 3 else v for i, v in enumerate(camera))
    view = eye - target
    view /= np.linalg.norm(view)
    left = np.cross(up, view)
    sun = 1.0 * up + 0.45 * view + 0.5 * left
    return tuple(sun / np.linalg.norm(sun))


def choose_camera(bounds, down, view=None, eye=None, look_at=None, up=None, fov_deg: float = 30.0):
    """The camera of the command-line options: ``view`` (or ``eye``) around
    ``look_at`` (default the scene's centre), ``up`` (default against gravity)."""
    import numpy as np

    eye0, target, up0, fov = auto_camera(bounds, view or DEFAULT_VIEW, down, fov_deg)
    if look_at is not None:     # the same view direction and distance, around the new target
        shift = np.asarray(look_at, float) - np.asarray(target, float)
        target = tuple(float(c) for c in look_at)
        eye0 = tuple(np.asarray(eye0, float) + shift)
    if eye is not None:
        eye0 = tuple(float(c) for c in eye)
    if np.allclose(eye0, target):
        raise CameraError("--eye must not be the point the camera looks at "
                          f"({', '.join(f'{c:g}' for c in target)})")
    if up is not None:
        forward = np.asarray(target, float) - np.asarray(eye0, float)
        up = np.asarray(up, float)
        if np.linalg.norm(np.cross(forward, up)) <= 1e-6 * np.linalg.norm(forward) * np.linalg.norm(up):
            raise CameraError("--up must not point along the viewing direction")
        up0 = tuple(up / np.linalg.norm(up))
    return tuple(eye0), tuple(target), tuple(up0), fov
