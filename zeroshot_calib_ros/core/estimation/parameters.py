"""Parameter layouts: the vector a solver moves <-> the camera the terms evaluate.

A layout has ``names``, ``camera(x)``, ``x_from(camera)`` and ``steps(x)`` (finite-difference
steps per parameter, in the parameter's unit). The terms never see the vector, only the camera.

- ``KannalaBrandtLayout``: the refined camera, ROS ``equidistant`` with fx = fy = f:
  x = (f, cx, cy, d1..dn), k_j = base_k_j + d_j for j <= n, the others the base's. ``order`` n
  (0..4) is the number of shape parameters the evidence is allowed to move; n = 0 keeps the base
  (zero-shot) shape and moves only f and the principal point. Deviations from the zero-shot shape,
  not absolute k's, so that every order starts from the zero-shot camera itself.
- ``ZeroShotLayout``: the zero-shot model (the paper's law rho with a = w f, continued past 90
  degrees as ``WideFovCamera`` does), x = (f, a, cx, cy, d1..d4): the law's two parameters, the
  principal point, and a polynomial deviation of the law theta (d1 theta^2 + ... + d4 theta^8)
  that a ``ShapePrior`` keeps small (real lenses follow no single one-parameter law). Used for
  the zero-shot camera's error bar.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ..lens.models import KannalaBrandtCamera, RadialCamera
from ..lens.projections import FisheyeProjection
from ..lens.wide_fov import psi

KB_TERMS = 4


class TabulatedKannalaBrandtCamera(KannalaBrandtCamera):
    """A KannalaBrandtCamera whose inverse starts from a table of theta_d on [0, theta_max] and
    polishes with three Newton steps: the same rays (checked to 1e-12 like the parent's; points
    that do not converge fall back to the parent's bracketed Newton) at a fifth of the cost,
    which matters when a solver unprojects thousands of line points per evaluation."""

    TABLE = 1024

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._theta = np.linspace(0.0, self.theta_max, self.TABLE)
        self._theta_d = self.theta_d(self._theta)

    def theta_from_theta_d(self, theta_d, iterations: int = 60):
        theta_d = np.asarray(theta_d, dtype=float)
        top = self._theta[-1]
        theta = np.interp(theta_d, self._theta_d, self._theta)
        k1, k2, k3, k4 = self.D
        with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
            for _ in range(3):
                # theta_d and its derivative (the parent's two polynomials, term for term) sharing theta^2
                t2 = theta * theta
                value = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
                slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
                theta = np.clip(theta - (value - theta_d) / slope, 0.0, top)
            ok = (theta_d >= 0) & (np.abs(self.theta_d(theta) - theta_d) <= 1e-12 * np.maximum(1.0, theta_d))
        out = np.where(ok, theta, np.nan)
        retry = ~ok & np.isfinite(theta_d) & (theta_d >= 0) & (theta_d <= self._theta_d[-1] * (1 + 1e-12))
        if np.any(retry):
            out[retry] = super().theta_from_theta_d(theta_d[retry], iterations)
        return out

    def plain(self) -> KannalaBrandtCamera:
        return KannalaBrandtCamera(self.fx, self.fy, self.cx, self.cy, self.width, self.height, self.D)


def deviation_steps(theta_max: float, order: int) -> np.ndarray:
    """Steps of d_1..d_order (coefficients of theta^3 .. theta^(2 order + 1)) that each move
    theta_d at ``theta_max`` by 1e-7 theta_max."""
    theta_max = max(float(theta_max), 1e-3)
    return 1e-7 / theta_max ** (2 * np.arange(1, order + 1))


class KannalaBrandtLayout:
    """x = (f, cx, cy, d1..dn) -> KannalaBrandtCamera with k = base.D + (d, 0...)."""

    def __init__(self, base: KannalaBrandtCamera, order: int = KB_TERMS, width: Optional[int] = None,
                 height: Optional[int] = None):
        if not 0 <= order <= KB_TERMS:
            raise ValueError(f'order = {order} is invalid: allowed: 0 to {KB_TERMS}')
        self.base = base
        self.base_D = np.asarray(base.D, dtype=float).copy()
        self.order = int(order)
        self.width = int(width if width is not None else base.width)
        self.height = int(height if height is not None else base.height)
        self.names = ('f', 'cx', 'cy') + tuple(f'd{j + 1}' for j in range(self.order))
        self.theta_max = float(base.max_field_angle()) if np.isfinite(base.max_field_angle()) else 1.0

    def camera(self, x) -> KannalaBrandtCamera:
        x = np.asarray(x, dtype=float)
        D = self.base_D.copy()
        D[:self.order] += x[3:3 + self.order]
        return TabulatedKannalaBrandtCamera(x[0], x[0], x[1], x[2], self.width, self.height, D)

    def x_from(self, camera: KannalaBrandtCamera) -> np.ndarray:
        """The vector of ``camera`` (its k beyond ``order`` are dropped: the base's are used)."""
        f = 0.5 * (camera.fx + camera.fy)
        d = np.asarray(camera.D, dtype=float)[:self.order] - self.base_D[:self.order]
        return np.r_[f, camera.cx, camera.cy, d]

    def steps(self, x) -> np.ndarray:
        """Finite-difference steps: 1e-6 f for f and the principal point; for d_j a step that
        moves theta_d at the field's edge by 1e-7 theta_max (a fixed step in k_j would vanish
        below rounding on a narrow lens, where theta_max^9 is 1e-8)."""
        x = np.asarray(x, dtype=float)
        return np.r_[1e-6 * x[0], 1e-6 * x[0], 1e-6 * x[0], deviation_steps(self.theta_max, self.order)]

    def with_order(self, order: int) -> 'KannalaBrandtLayout':
        return KannalaBrandtLayout(self.base, order, self.width, self.height)


class LawCamera(RadialCamera):
    """theta_d(theta) = rho(psi(theta, a)) / a + theta (d1 theta^2 + ... + d4 theta^8): a fisheye
    law continued in angle space (``core/lens/wide_fov.py``) plus a polynomial deviation. a -> 0
    is the pinhole tan(theta). Inverted numerically on the branch where theta_d rises."""

    SAMPLES = 4001

    def __init__(self, f, a, cx, cy, width, height, law: FisheyeProjection, deviation=(0, 0, 0, 0)):
        super().__init__(f, cx, cy, width, height)
        self.a = float(a)
        self.law = law
        self.deviation = np.asarray(deviation, dtype=float)
        theta = np.linspace(0.0, math.pi, self.SAMPLES)
        with np.errstate(invalid='ignore', over='ignore'):
            values = self.theta_d(theta)
        rising = np.isfinite(values) & np.r_[True, np.diff(values) > 0]
        stop = np.nonzero(~rising)[0]
        last = (stop[0] - 1) if stop.size else len(theta) - 1
        self.theta_lim = float(theta[max(last, 0)])
        self.theta_d_lim = float(values[max(last, 0)])

    def theta_d(self, theta):
        theta = np.asarray(theta, dtype=float)
        t2 = theta * theta
        d1, d2, d3, d4 = self.deviation
        extra = theta * t2 * (d1 + t2 * (d2 + t2 * (d3 + t2 * d4)))
        with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
            if abs(self.a) < 1e-9:
                base = np.where(theta < math.pi / 2, np.tan(np.minimum(theta, math.pi / 2 - 1e-12)), np.nan)
            else:
                base = self.law.rho(psi(theta, self.a)) / self.a
        return base + extra

    def theta_from_theta_d(self, theta_d):
        theta_d = np.asarray(theta_d, dtype=float)
        lo = np.zeros_like(theta_d)
        hi = np.full_like(theta_d, self.theta_lim)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            with np.errstate(invalid='ignore'):
                below = self.theta_d(mid) < theta_d
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        with np.errstate(invalid='ignore'):
            ok = (theta_d >= 0) & (theta_d <= self.theta_d_lim)
        return np.where(ok, 0.5 * (lo + hi), np.nan)


def law_of(camera) -> FisheyeProjection:
    """The fisheye law of a ZeroShotCamera / WideFovCamera (the wide model's law inside)."""
    projection = camera.projection
    return getattr(projection, 'law', projection)


class ZeroShotLayout:
    """x = (f, a, cx, cy, d1..d4) -> LawCamera (module docstring). ``a_floor``: a pinhole
    solution (a = 0) is linearised at this small a instead, where the law is still smooth."""

    def __init__(self, law: FisheyeProjection, width: int, height: int, theta_max: float = 1.0):
        self.law = law
        self.width, self.height = int(width), int(height)
        self.theta_max = float(theta_max)
        self.names = ('f', 'a', 'cx', 'cy', 'd1', 'd2', 'd3', 'd4')

    def camera(self, x) -> LawCamera:
        x = np.asarray(x, dtype=float)
        return LawCamera(x[0], x[1], x[2], x[3], self.width, self.height, self.law, x[4:8])

    def x_from_zero_shot(self, camera, a_floor: float = 1e-3) -> np.ndarray:
        return np.r_[camera.f, max(camera.a, a_floor), camera.cx, camera.cy, np.zeros(4)]

    def steps(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return np.r_[1e-6 * x[0], 1e-6 * max(abs(x[1]), 1e-3), 1e-6 * x[0], 1e-6 * x[0],
                     deviation_steps(self.theta_max, 4)]
