"""Evidence terms: one class per kind of evidence, each an unwhitened residual with its own sigma.

Interface (also met by ``core.lines.straightness.StraightnessTerm``): ``name``,
``residuals(camera)`` -> 1-D array in the term's unit, ``sigma`` (scalar or per residual, same
unit), ``loss`` (None = least squares, or 'soft_l1' / 'cauchy'), ``loss_scale`` (in sigmas) and
``group`` (residuals per robust unit). ``Problem`` divides by sigma and applies the loss.

- ``FovTerm``: the spec sheet's FOVs as soft priors: predicted minus given, in degrees, sigma =
  the tolerance (default 1 degree: a spec sheet's rounding and its unit-to-unit spread). The FOV
  is the spec's: edge-to-edge through the principal point (hfov from (0, cy) to (W, cy), vfov
  from (cx, 0) to (cx, H), dfov from (0, 0) to (W, H)), measured through the optical axis when the
  two edge rays' off-axis angles add up to more than 180 degrees
  (``wide_fov.fields_of_view_through_axis``); ``circle``: across the image circle's horizontal
  diameter, centred on the image, at the principal point's row.
- ``PrincipalPointPrior``: (cx, cy) near the image centre, sigma in pixels. Default
  ``PRINCIPAL_POINT_SIGMA`` of the image width: on the 770 wide square-pixel profiles of
  ../shared/data/lens_profiles_dev.csv the offset from the centre has a standard deviation of
  1.1 % of the width per axis (p90 of |offset| 1.6 %, largest 7.6 %).
- ``ShapePrior``: the distortion shape near a reference shape (zero-shot's): residuals
  (theta_d(t_j) - ref(t_j)) / t_j at ``samples`` angles up to the largest field angle, sigma
  chosen so that the prior bounds the RMS relative deviation over the field by
  ``sigma_relative``. Default ``SHAPE_SIGMA``: the same 770 profiles deviate from the zero-shot
  shape (h+v+d) by a median 0.5 %, p90 1.4 %, largest 5.3 % (RMS over the field), which is the
  prior of the zero-shot camera's own error bar. The refinement uses four times that
  (``refine.REFINE_SHAPE_SIGMA``, 2 %): the tail is long, and at 0.5 % the prior held the shape
  of the lenses in it away from what their lines showed (median error 1.35 px instead of 0.57
  on 60 lenses, tolerance 0.5 degree, measured while choosing); at 2 % it only holds the shape
  where no line reaches.
- ``ImageCircleTerm``: the image circle measured in the images (``core.lines.image_region``):
  its centre is the principal point (sigma: the measurement's, and a floor
  ``CIRCLE_CENTRE_SIGMA`` of the width for a field stop centred on the axis only to mechanical
  tolerances), and, with the spec's circle FOV, the FOV the camera sees across the measured
  circle (in degrees, sigma: the FOV tolerance and the radius measurement turned into degrees).
  It replaces the ``FovTerm``'s ``circle`` (the same statement, with the measured diameter about
  the measured centre).
"""
from __future__ import annotations

import math
from typing import Dict, Optional

import numpy as np

from ..lens.models import angle_between
from ..lens.wide_fov import fields_of_view_through_axis
from ..zeroshot.spec import FOV_TOLERANCE_DEG as _SPEC_FOV_TOLERANCE_DEG
from ..zeroshot.spec import CameraSpec

PRINCIPAL_POINT_SIGMA = 0.011
"""Prior standard deviation of each principal-point coordinate, as a fraction of the width."""

SHAPE_SIGMA = 0.005
"""Prior RMS relative deviation of theta_d from the reference shape over the field."""

FOV_TOLERANCE_DEG = _SPEC_FOV_TOLERANCE_DEG
"""Default standard deviation of a spec FOV (degrees); defined with the spec (zeroshot/spec.py),
where the consistency warnings use it too."""

CIRCLE_CENTRE_SIGMA = 0.002
"""Floor of the image circle's centre as a measurement of the principal point, as a fraction of
the width (4 px at 1920): a lens's field stop is centred on its axis to mechanical tolerances."""

INVALID_FOV_DEG = 90.0
"""Residual of a FOV whose edge pixel has no ray under the camera."""


def _edge_fov(camera, start, end) -> float:
    """Degrees between the rays of two pixels, through the axis when their off-axis angles add
    up to more than 180 degrees (``fields_of_view_through_axis``)."""
    rays = camera.unproject(np.array([start, end], dtype=float))
    off_axis = np.arctan2(np.linalg.norm(rays[:, :2], axis=-1), rays[:, 2])
    angle = float(angle_between(rays[0], rays[1]))
    if off_axis[0] + off_axis[1] > math.pi:
        angle = 2.0 * math.pi - angle
    return math.degrees(angle)


def spec_fovs(spec: CameraSpec) -> Dict[str, float]:
    """The FOVs a spec gives, 'circle' included (degrees)."""
    fovs = dict(spec.given())
    if getattr(spec, 'circle_fov', None) is not None:
        fovs['circle'] = spec.circle_fov
    return fovs


class FovTerm:
    """The spec's FOVs as priors with a tolerance (module docstring)."""

    name = 'fov'
    group = 1
    loss = None
    loss_scale = 1.0

    def __init__(self, fovs: Dict[str, float], width: int, height: int, tolerance_deg: float = FOV_TOLERANCE_DEG,
                 circle_diameter: Optional[float] = None):
        if not fovs:
            raise ValueError('no FOV given: a FOV term needs at least one')
        if not tolerance_deg > 0 or not math.isfinite(tolerance_deg):
            raise ValueError(f'fov_tolerance_deg = {tolerance_deg!r} is invalid: allowed: degrees, greater than 0')
        if 'circle' in fovs and circle_diameter is None:
            raise ValueError('a circle FOV needs circle_diameter')
        self.fovs = dict(fovs)
        self.keys = tuple(self.fovs)
        self.given = np.array([self.fovs[k] for k in self.keys])
        self.width, self.height = int(width), int(height)
        self.circle_diameter = circle_diameter
        self.sigma = float(tolerance_deg)

    @classmethod
    def from_spec(cls, spec: CameraSpec, tolerance_deg: float = FOV_TOLERANCE_DEG, width=None, height=None,
                  leave_out=()):
        """The spec's FOVs; at another image size of the same aspect (binned images) the angles
        are the same and the circle's diameter scales. ``leave_out``: FOV names another term
        states (the circle, by ``ImageCircleTerm``); None when no FOV is left."""
        width = spec.width if width is None else width
        height = spec.height if height is None else height
        circle = getattr(spec, 'circle_diameter', None)
        if circle is not None:
            circle = circle * width / spec.width
        fovs = {k: v for k, v in spec_fovs(spec).items() if k not in leave_out}
        if not fovs:
            return None
        return cls(fovs, width, height, tolerance_deg, circle if 'circle' in fovs else None)

    def predicted(self, camera) -> Dict[str, float]:
        out = {}
        if any(k in self.fovs for k in ('hfov', 'vfov', 'dfov')):
            out.update(fields_of_view_through_axis(camera))
        if 'circle' in self.fovs:
            r = self.circle_diameter / 2.0
            cx = self.width / 2.0
            out['circle'] = _edge_fov(camera, (cx - r, camera.cy), (cx + r, camera.cy))
        return {k: out[k] for k in self.keys}

    def residuals(self, camera) -> np.ndarray:
        predicted = self.predicted(camera)
        r = np.array([predicted[k] for k in self.keys]) - self.given
        return np.where(np.isfinite(r), r, INVALID_FOV_DEG)


class PrincipalPointPrior:
    """(cx, cy) - (W/2, H/2), sigma pixels (default ``PRINCIPAL_POINT_SIGMA`` x width)."""

    name = 'principal_point'
    group = 1
    loss = None
    loss_scale = 1.0

    def __init__(self, width: int, height: int, sigma_px: Optional[float] = None):
        self.centre = np.array([width / 2.0, height / 2.0])
        self.sigma = float(PRINCIPAL_POINT_SIGMA * width if sigma_px is None else sigma_px)

    def residuals(self, camera) -> np.ndarray:
        return np.array([camera.cx, camera.cy]) - self.centre


class ShapePrior:
    """theta_d near ``reference.theta_d`` (module docstring); ``theta_max`` radians: the field
    the prior spans (the reference's largest field angle)."""

    name = 'shape'
    group = 1
    loss = None
    loss_scale = 1.0

    def __init__(self, reference, theta_max: float, sigma_relative: float = SHAPE_SIGMA, samples: int = 8,
                 radius: bool = False):
        self.theta = np.linspace(theta_max / samples, theta_max, samples)
        self.radius = bool(radius)
        self.f_reference = float(reference.fx) if radius else 1.0
        with np.errstate(invalid='ignore'):
            self.reference = np.asarray(reference.theta_d(self.theta), dtype=float)
        self.sigma_relative = float(sigma_relative)
        self.sigma = self.sigma_relative * math.sqrt(samples)

    def residuals(self, camera) -> np.ndarray:
        """(theta_d(t) - ref(t)) / t; with ``radius``, of the image radius f theta_d(t) relative
        to the reference's: (f theta_d(t) - f_ref ref(t)) / (f_ref t)."""
        scale = camera.fx / self.f_reference if self.radius else 1.0
        with np.errstate(invalid='ignore', over='ignore'):
            r = (scale * np.asarray(camera.theta_d(self.theta), dtype=float) - self.reference) / self.theta
        return np.where(np.isfinite(r), r, 1.0)


class ImageCircleTerm:
    """The image circle measured in the images as evidence (module docstring): residuals
    (cx - measured cx, cy - measured cy) in px, and, with ``circle_fov``, the FOV across the
    measured circle under the camera minus ``circle_fov`` in degrees."""

    name = 'image_circle'
    group = 1
    loss = None
    loss_scale = 1.0

    def __init__(self, cx: float, cy: float, radius: float, centre_sigma_px: float, radius_sigma_px: float,
                 width: int, circle_fov: Optional[float] = None, tolerance_deg: float = FOV_TOLERANCE_DEG,
                 reference=None):
        if not (radius > 0 and centre_sigma_px > 0 and radius_sigma_px >= 0):
            raise ValueError(f'image circle radius {radius!r} and sigmas ({centre_sigma_px!r}, '
                             f'{radius_sigma_px!r}) px are invalid: allowed: greater than 0')
        self.centre = np.array([float(cx), float(cy)])
        self.radius = float(radius)
        self.circle_fov = None if circle_fov is None else float(circle_fov)
        centre_sigma = math.hypot(centre_sigma_px, CIRCLE_CENTRE_SIGMA * width)
        sigma = [centre_sigma, centre_sigma]
        if self.circle_fov is not None:
            # the radius's uncertainty in degrees across the circle: 2 x dtheta/dr x sigma_r
            # (dtheta/dr of the reference camera, zero-shot's, at the circle)
            per_px = 0.0
            if reference is not None and radius_sigma_px > 0:
                a, b = self._angle_deg(reference, self.radius - 0.5), self._angle_deg(reference, self.radius + 0.5)
                per_px = abs(b - a) if math.isfinite(a) and math.isfinite(b) else 0.0
            sigma.append(math.hypot(tolerance_deg, per_px * radius_sigma_px))
        self.sigma = np.array(sigma)

    @staticmethod
    def _angle_deg(camera, radius: float) -> float:
        """Degrees across a circle of ``radius`` px about the principal point under ``camera``:
        twice the off-axis angle of its rays (a radial camera)."""
        ray = camera.unproject(np.array([[camera.cx + radius, camera.cy]], dtype=float))[0]
        return 2.0 * math.degrees(math.atan2(math.hypot(ray[0], ray[1]), ray[2]))

    def fov_deg(self, camera) -> float:
        """The FOV ``camera`` sees across the measured circle (degrees)."""
        return self._angle_deg(camera, self.radius)

    def residuals(self, camera) -> np.ndarray:
        r = [camera.cx - self.centre[0], camera.cy - self.centre[1]]
        if self.circle_fov is not None:
            d = self.fov_deg(camera) - self.circle_fov
            r.append(d if math.isfinite(d) else INVALID_FOV_DEG)
        return np.array(r, dtype=float)
