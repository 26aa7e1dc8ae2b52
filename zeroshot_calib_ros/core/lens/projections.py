"""Fisheye lens projections and the paper's radial distortion maps G_w (eqs. 13-19).

A fisheye lens maps the off-axis angle theta of a ray to the image radius r = f * rho(theta)
(eqs. 13-16). Seen through an ideal pinhole of the same focal length, the same ray lands at
r_u = f * tan(theta). Writing w = 1/f for the lens constant gives the paper's distortion map
between the undistorted (pinhole) radius r_u and the distorted radius r_d:

    G_w(r_u)    = rho(arctan(w * r_u)) / w          (eq. 18 for rho(theta) = theta)
    G_w^-1(r_d) = tan(rho^-1(w * r_d)) / w          (eq. 19)

Each projection is one small class with the same interface, so adding a lens law is adding a
class. Arrays in, arrays out (numpy broadcasting throughout).
"""
from __future__ import annotations

import numpy as np

HALF_PI = np.pi / 2.0


class FisheyeProjection:
    """A radial lens law r / f = rho(theta), for 0 <= theta <= pi/2."""

    name = ''

    def rho(self, theta):
        """Normalised image radius of a ray theta radians off-axis."""
        raise NotImplementedError

    def theta(self, rho):
        """Inverse of rho: off-axis angle of a normalised radius."""
        raise NotImplementedError

    def dtheta_drho(self, rho):
        """Derivative of theta(rho), for the paper's Newton iteration."""
        raise NotImplementedError

    @property
    def rho_max(self) -> float:
        """Normalised radius of a ray 90 degrees off-axis: beyond it, no pinhole ray exists."""
        return float(self.rho(HALF_PI))

    def distort_radius(self, r_u, omega):
        """G_w(r_u): pinhole radius -> distorted radius (pixels). G_0 is the identity."""
        r_u = np.asarray(r_u, dtype=float)
        if omega == 0.0:
            return r_u.copy()
        return self.rho(np.arctan(omega * r_u)) / omega

    def undistort_radius(self, r_d, omega):
        """G_w^-1(r_d): distorted radius -> pinhole radius; inf at and beyond rho_max / omega."""
        r_d = np.asarray(r_d, dtype=float)
        if omega == 0.0:
            return r_d.copy()
        rho = omega * r_d
        with np.errstate(invalid='ignore'):
            theta = self.theta(np.minimum(rho, self.rho_max))
            r_u = np.tan(theta) / omega
        return np.where(rho < self.rho_max, r_u, np.inf)

    def d_undistort_radius_domega(self, r_d, omega):
        """Partial derivative of G_w^-1(r_d) with respect to omega (omega > 0)."""
        rho = omega * r_d
        theta = self.theta(rho)
        sec2 = 1.0 / np.cos(theta) ** 2
        return (sec2 * self.dtheta_drho(rho) * rho - np.tan(theta)) / omega ** 2

    def __repr__(self):
        return f'{type(self).__name__}()'


class Equidistant(FisheyeProjection):
    """r = f * theta (eq. 14), the paper's default model."""

    name = 'equidistant'

    def rho(self, theta):
        return np.asarray(theta, dtype=float) * 1.0

    def theta(self, rho):
        return np.asarray(rho, dtype=float) * 1.0

    def dtheta_drho(self, rho):
        return np.ones_like(np.asarray(rho, dtype=float))


class Equisolid(FisheyeProjection):
    """r = 2 f sin(theta / 2) (eq. 15)."""

    name = 'equisolid'

    def rho(self, theta):
        return 2.0 * np.sin(np.asarray(theta, dtype=float) / 2.0)

    def theta(self, rho):
        return 2.0 * np.arcsin(np.asarray(rho, dtype=float) / 2.0)

    def dtheta_drho(self, rho):
        return 1.0 / np.sqrt(1.0 - (np.asarray(rho, dtype=float) / 2.0) ** 2)


class Stereographic(FisheyeProjection):
    """r = 2 f tan(theta / 2) (eq. 13)."""

    name = 'stereographic'

    def rho(self, theta):
        return 2.0 * np.tan(np.asarray(theta, dtype=float) / 2.0)

    def theta(self, rho):
        return 2.0 * np.arctan(np.asarray(rho, dtype=float) / 2.0)

    def dtheta_drho(self, rho):
        return 1.0 / (1.0 + (np.asarray(rho, dtype=float) / 2.0) ** 2)


class Orthographic(FisheyeProjection):
    """r = f sin(theta) (eq. 16)."""

    name = 'orthographic'

    def rho(self, theta):
        return np.sin(np.asarray(theta, dtype=float))

    def theta(self, rho):
        return np.arcsin(np.asarray(rho, dtype=float))

    def dtheta_drho(self, rho):
        return 1.0 / np.sqrt(1.0 - np.asarray(rho, dtype=float) ** 2)


PROJECTIONS = {p.name: p for p in (Equidistant(), Equisolid(), Stereographic(), Orthographic())}
"""Every fisheye projection by name; 'equidistant' is the paper's default."""


def get_projection(name: str) -> FisheyeProjection:
    """The projection called ``name``; ValueError naming the choices otherwise."""
    try:
        return PROJECTIONS[name]
    except KeyError:
        raise ValueError(f"projection = {name!r} is invalid: allowed: {', '.join(PROJECTIONS)}") from None
