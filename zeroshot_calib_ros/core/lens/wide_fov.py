"""The wide-FOV lens model: the paper's camera continued to 180 degrees and beyond (beyond the paper).

The paper's model (``ZeroShotCamera``) sends a ray theta off-axis through a pinhole of focal f
and then through the fisheye map G_w: r_d = G_w(f tan theta) = f rho(arctan(a tan theta)) / a,
a = w f. At theta = 90 degrees the pinhole radius is infinite, so that model stops there, and so
does every spec whose FOV reaches 180 degrees or whose image corners reach 90 degrees off-axis.

The same lens law written in angle space,

    r_d = f * theta_d(theta),   theta_d(theta) = rho(psi) / a,   psi = atan2(a sin theta, cos theta),

is *identical* to the paper's for theta < 90 degrees (tan psi = a tan theta) and continues
smoothly and monotonically up to theta = 180 degrees (psi runs from 0 to pi for any a > 0, and
rho is increasing on [0, pi] for the equidistant, equisolid and stereographic laws; orthographic
stops at 90 degrees and is not offered). a = 1 is the pure fisheye law (r = f theta for
equidistant), a -> 0 the pinhole. ``WideFovCamera`` is that camera: a ``ZeroShotCamera``
subclass (``RadialCamera`` interface: theta_d and its exact inverse), so fitting Kannala-Brandt
k1..k4 for ROS, rectification and calibration files work with it unchanged; its ``omega`` is the
paper's w = a / f (finite; equal to the paper's w* whenever the paper's model can represent the
spec, 0 in the pinhole limit).

A ray beyond the pair's angles is extrapolated by the law; a pixel beyond the law's largest
radius (theta = 180 degrees: r = f pi / a for equidistant, 2 f / a for equisolid) has no ray
(NaN), as outside a circular fisheye's image circle.

Fitting it to a spec sheet is ``core/zeroshot/wide_solver.py``.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from .models import CameraModel, ZeroShotCamera, angle_between, fov_edge_pixels
from .projections import PROJECTIONS, FisheyeProjection

WIDE = 'wide'
"""Projection choice of solve_zero_shot: the angle-space model, law chosen as described above."""

WIDE_LAWS = ('equidistant', 'equisolid', 'stereographic')
"""Fisheye laws rho that stay increasing up to 180 degrees (orthographic does not)."""


class WideProjection(FisheyeProjection):
    """A fisheye law continued in angle space; named 'wide-<law>' (rho, theta as the law's)."""

    def __init__(self, law: FisheyeProjection):
        if law.name not in WIDE_LAWS:
            raise ValueError(f"law = {law.name!r} is invalid: allowed: {', '.join(WIDE_LAWS)}")
        self.law = law
        self.name = f'{WIDE}-{law.name}'

    def rho(self, theta):
        return self.law.rho(theta)

    def theta(self, rho):
        return self.law.theta(rho)

    def dtheta_drho(self, rho):
        return self.law.dtheta_drho(rho)

    @property
    def rho_limit(self) -> float:
        """rho at 180 degrees: the largest normalised radius a ray reaches (inf: stereographic)."""
        with np.errstate(over='ignore'):
            value = float(self.law.rho(np.pi))
        return math.inf if not math.isfinite(value) or value > 1e15 else value

    def __repr__(self):
        return f'WideProjection({self.law!r})'


def wide_projection(name: str) -> WideProjection:
    """'equidistant' / 'wide-equidistant' -> WideProjection; ValueError naming the choices."""
    law = name[len(WIDE) + 1:] if name.startswith(WIDE + '-') else name
    if law not in WIDE_LAWS:
        raise ValueError(f"law = {name!r} is invalid: allowed: {', '.join(WIDE_LAWS)}")
    return WideProjection(PROJECTIONS[law])


def psi(theta, a):
    """The paper's pinhole angle arctan(a tan theta), continued through 90 degrees."""
    return np.arctan2(a * np.sin(theta), np.cos(theta))


def fields_of_view_through_axis(camera: CameraModel) -> dict:
    """Edge-to-edge FOVs in degrees through the principal point, as
    ``CameraModel.fields_of_view`` (hfov between the rays of (0, cy) and (W, cy), vfov between
    (cx, 0) and (cx, H), dfov between (0, 0) and (W, H)), except that when the two rays' off-axis
    angles add up to more than 180 degrees the angle is measured through the optical axis
    (360 degrees minus the plain angle between the rays): a 200-degree lens has hfov 200, not 160.
    Identical to ``fields_of_view`` below 180 degrees; NaN where a pixel has no ray."""
    rays = camera.unproject(fov_edge_pixels(camera.width, camera.height, camera.cx, camera.cy).reshape(-1, 2))
    off_axis = np.arctan2(np.linalg.norm(rays[:, :2], axis=-1), rays[:, 2])
    angle = angle_between(rays[0::2], rays[1::2])
    angle = np.where(off_axis[0::2] + off_axis[1::2] > np.pi, 2.0 * np.pi - angle, angle)
    angle = np.degrees(angle)
    return {'hfov': float(angle[0]), 'vfov': float(angle[1]), 'dfov': float(angle[2])}


class WideFovCamera(ZeroShotCamera):
    """The paper's camera continued in angle space up to 180 degrees off-axis (module docstring).

    ``projection`` is a ``WideProjection`` (a law name is accepted too). ``circle_radius``
    (px, optional): the image circle of a circular fisheye; pixels outside it are dark, so
    ``max_field_angle`` (the range a Kannala-Brandt fit covers) stops at the circle.
    """

    def __init__(self, f, cx, cy, width, height, omega=1.0, projection='equidistant',
                 circle_radius: Optional[float] = None):
        if not isinstance(projection, WideProjection):
            projection = wide_projection(projection if isinstance(projection, str) else projection.name)
        super().__init__(f, cx, cy, width, height, omega, projection)
        self.circle_radius = None if circle_radius is None else float(circle_radius)

    @property
    def law(self) -> FisheyeProjection:
        return self.projection.law

    def theta_d(self, theta):
        if self.omega == 0.0:
            return super().theta_d(theta)  # the pinhole limit: tan(theta), NaN from 90 degrees
        theta = np.asarray(theta, dtype=float)
        a = self.a
        with np.errstate(invalid='ignore'):
            valid = (theta >= 0.0) & (theta <= np.pi)
            return np.where(valid, self.law.rho(psi(theta, a)) / a, np.nan)

    def theta_from_theta_d(self, theta_d):
        if self.omega == 0.0:
            return super().theta_from_theta_d(theta_d)
        theta_d = np.asarray(theta_d, dtype=float)
        a = self.a
        rho = a * theta_d
        limit = self.projection.rho_limit
        with np.errstate(invalid='ignore', over='ignore'):
            valid = (rho >= 0.0) & (rho <= limit)
            psi = np.minimum(self.law.theta(np.where(valid, rho, 0.0)), np.pi)
            return np.where(valid, np.arctan2(np.sin(psi), a * np.cos(psi)), np.nan)

    def fields_of_view(self) -> dict:
        """Edge-to-edge FOVs, measured through the optical axis beyond 180 degrees
        (``fields_of_view_through_axis``)."""
        return fields_of_view_through_axis(self)

    def max_field_angle(self) -> float:
        """Largest off-axis angle (radians) of a pixel with a ray: the farthest image corner's,
        or the image circle's when the circle is smaller; at most just under 180 degrees."""
        radius = self.corner_radius()
        if self.circle_radius is not None:
            radius = min(radius, self.circle_radius)
        theta = float(self.theta_from_theta_d(radius / self.f))
        cap = np.nextafter(np.pi, 0.0) * (1 - 1e-9)
        return cap if not math.isfinite(theta) else min(theta, cap)

    def scaled(self, width, height):
        s = width / self.width
        return WideFovCamera(self.f * s, self.cx * s, self.cy * height / self.height, width, height,
                             self.omega / s, self.projection,
                             None if self.circle_radius is None else self.circle_radius * s)

    def __repr__(self):
        circle = '' if self.circle_radius is None else f', circle_radius={self.circle_radius:g}'
        return (f'WideFovCamera(f={self.f:.6g}, cx={self.cx:g}, cy={self.cy:g}, '
                f'omega={self.omega:.6g} (a={self.a:.6g}), law={self.law.name}, '
                f'size={self.width}x{self.height}{circle})')
