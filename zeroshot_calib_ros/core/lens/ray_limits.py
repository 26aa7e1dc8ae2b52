"""Where a camera model stops giving rays inside its image: the largest off-axis angle on the image
border, how far towards an edge pixel unproject still gives rays, and what that rules out (a ROS
plumb_bob file of a lens that sees 90 degrees or more off-axis; FOVs read off a calibration whose
distortion turns back before the image edge)."""
from __future__ import annotations

import dataclasses
import math
from typing import Optional

import numpy as np


def edge_angle_deg(camera) -> float:
    """Largest off-axis angle (degrees) of the rays of the image border (nan: a border pixel with
    no ray)."""
    w, h = camera.width, camera.height
    t = np.linspace(0.0, 1.0, 33)
    border = np.concatenate([np.c_[t * w, 0 * t], np.c_[t * w, 0 * t + h], np.c_[0 * t, t * h], np.c_[0 * t + w, t * h]])
    rays = camera.unproject(border)
    with np.errstate(invalid='ignore'):
        angles = np.degrees(np.arctan2(np.linalg.norm(rays[:, :2], axis=-1), rays[:, 2]))
    return float(np.max(angles)) if np.all(np.isfinite(angles)) else math.nan


def ray_reach(camera, edge) -> float:
    """Distance (px) from the principal point towards the pixel ``edge`` up to which the camera
    still gives rays (bisection on where unproject turns NaN)."""
    centre = np.array([camera.cx, camera.cy])
    direction = np.asarray(edge, dtype=float) - centre
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if np.all(np.isfinite(camera.unproject(centre + mid * direction))):
            lo = mid
        else:
            hi = mid
    return lo * float(np.hypot(*direction))


def plumb_bob_refusal(camera, fit_error: float) -> Optional[str]:
    """Why a ROS plumb_bob model cannot represent ``camera`` (None when it can): plumb_bob projects
    through a pinhole, so a lens that sees 90 degrees or more off-axis inside the image (a FOV of
    180 or more), or a fit that gives no finite error, would be written as a wrong D."""
    angle = edge_angle_deg(camera)
    if math.isfinite(angle) and angle < 90.0 and math.isfinite(fit_error):
        return None
    seen = (f'sees {angle:.1f} degrees off-axis at the image edge' if math.isfinite(angle)
            else 'has image pixels without a ray')
    return (f'it {seen}, and plumb_bob projects through a pinhole (allowed: lenses below 90 degrees '
            'off-axis, a FOV below 180)')


@dataclasses.dataclass(frozen=True)
class MissingFov:
    """A field of view (hfov / vfov) a camera does not give: ``side`` is the image edge whose
    pixel has no ray ('left', 'right', 'top', 'bottom'; None when both have rays), ``reach_px``
    how far from the principal point towards it rays go, ``edge_distance_px`` how far it is."""

    fov: str
    value: float
    side: Optional[str] = None
    reach_px: Optional[float] = None
    edge_distance_px: Optional[float] = None


def missing_fov(camera, fovs: dict) -> Optional[MissingFov]:
    """The first of hfov, vfov in ``fovs`` (camera.fields_of_view()) that is not finite, with the
    edge pixel that has no ray (the lens curve turns back before the image edge); None when both
    are finite."""
    w, h, cx, cy = camera.width, camera.height, camera.cx, camera.cy
    edges = {'hfov': (((0, cy), 'left'), ((w, cy), 'right')), 'vfov': (((cx, 0), 'top'), ((cx, h), 'bottom'))}
    for key, pair in edges.items():
        if math.isfinite(fovs[key]):
            continue
        for edge, side in pair:
            if not np.all(np.isfinite(camera.unproject(np.asarray(edge, dtype=float)))):
                return MissingFov(key, fovs[key], side, ray_reach(camera, edge),
                                  math.hypot(edge[0] - cx, edge[1] - cy))
        return MissingFov(key, fovs[key])
    return None
