"""Fit the ROS / OpenCV distortion models to an exact radial camera model.

ROS tools understand CameraInfo's ``equidistant`` (OpenCV fisheye, Kannala-Brandt k1..k4) and
``plumb_bob`` models, not the paper's G_w. Both are linear in their coefficients once the focal
length is fixed, so the coefficients that minimise the *maximum* pixel error over every off-axis
angle the image contains are the solution of a small linear programme (a Chebyshev fit).

The programme is solved by the discrete Remez exchange (numpy only): the columns, odd powers of
theta (or of tan theta), form a Haar system on theta > 0, so the minimax solution levels the
error with alternating signs on m + 1 of the samples, and exchanging one sample at a time
reaches those samples in a few iterations. It gives the linear programme's vertex to rounding,
and keeps scipy.optimize (half a second to import) off the node's path to its first CameraInfo.
scipy's ``linprog`` is the fallback if the exchange does not converge, least squares if that fails.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .models import KannalaBrandtCamera, PlumbBobCamera, RadialCamera

FIT_SAMPLES = 2000
FIT_WARNING_PX = 0.5
"""A fit whose ``max_error_px`` exceeds this many pixels is reported (CLI and node warn)."""


@dataclass
class DistortionFit:
    """Coefficients for a ROS distortion model and how well they reproduce the exact model."""

    distortion_model: str
    D: np.ndarray
    max_error_px: float
    """Largest image distance between the fitted and the exact model over the whole image."""
    camera: object
    """The fitted camera (KannalaBrandtCamera or PlumbBobCamera) with the same K."""


CONVERGED = 1e-12
"""The exchange stops when no sample's error exceeds the levelled error by this fraction."""


def _remez(A: np.ndarray, b: np.ndarray, iterations: int = 200):
    """x minimising max |A x - b| by the discrete Remez (single-point) exchange, or None if it
    does not converge (module docstring). Rows with an all-zero A and b (theta = 0) carry no
    error and are never references."""
    n, m = A.shape
    if not np.any(np.abs(b) > 1e-15):  # the exact model is the ROS model's own (a pinhole): D = 0
        return np.zeros(m)
    scale = np.max(np.abs(A), axis=0)
    if not np.all(scale > 0):
        return None
    A = A / scale  # unit columns: the powers of theta differ by orders of magnitude
    candidates = np.flatnonzero(np.any(A != 0, axis=1) | (b != 0))
    if len(candidates) < m + 1:
        return None
    # Every column vanishes at theta = 0, so near it the error is ~0 whatever x is: a reference
    # sample there makes the levelled system singular to rounding (level ~1e-18, its sign noise),
    # and the exchange then cycles between two references. The first reference is spread over
    # (0, max] (k / (m + 1) of the way, k = 1..m+1): the alternation points of these fits lie
    # there.
    ref = candidates[np.round(np.arange(1, m + 2) * (len(candidates) - 1) / (m + 1)).astype(int)]
    signs = (-1.0) ** np.arange(m + 1)
    # What rounding leaves of a residual: b - A x cancels terms of the size of b, so a levelled
    # error below this is as good as zero, and two errors closer than this are equal.
    noise = 1e-12 * float(np.max(np.abs(b)))
    best_level = -1.0
    for _ in range(iterations):
        try:
            solution = np.linalg.solve(np.c_[A[ref], signs], b[ref])
        except np.linalg.LinAlgError:
            return None
        x, level = solution[:m], abs(solution[m])
        if not np.all(np.isfinite(solution)):
            return None
        r = b - A @ x
        j = int(np.argmax(np.abs(r)))
        if abs(r[j]) <= level * (1 + CONVERGED) + noise:
            return x / scale
        if j in ref:  # the levelled system is solved only to rounding: that is convergence
            return x / scale if abs(r[j]) <= level * (1 + 1e-6) + noise else None
        # The levelled error of an exchange never decreases (de la Vallee Poussin); a decrease
        # beyond rounding means the exchange is lost in rounding: give up, the caller falls back.
        if level < best_level - noise:
            return None
        best_level = max(best_level, level)
        s = np.sign(r[j])
        ref_signs = np.sign(r[ref])
        k = int(np.searchsorted(ref, j))
        if k == 0:
            if ref_signs[0] == s:
                ref = np.r_[j, ref[1:]]
            else:
                ref = np.r_[j, ref[:-1]]
        elif k == len(ref):
            if ref_signs[-1] == s:
                ref = np.r_[ref[:-1], j]
            else:
                ref = np.r_[ref[1:], j]
        else:
            i = k - 1 if ref_signs[k - 1] == s else k
            ref = ref.copy()
            ref[i] = j
        if len(np.unique(ref)) != m + 1:
            return None
    return None


def _chebyshev_fit(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x minimising max |A x - b| (module docstring)."""
    x = _remez(A, b)
    if x is not None:
        return x
    from scipy.optimize import linprog  # only if the exchange fails: half a second to import
    n, m = A.shape
    ones = np.ones((n, 1))
    result = linprog(np.r_[np.zeros(m), 1.0],
                     A_ub=np.block([[A, -ones], [-A, -ones]]), b_ub=np.r_[b, -b],
                     bounds=[(None, None)] * (m + 1), method='highs')
    if result.status == 0:
        return result.x[:m]
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _angles(camera: RadialCamera, samples: int) -> np.ndarray:
    return np.linspace(0.0, camera.max_field_angle(), samples)


def fit_kannala_brandt(camera: RadialCamera, samples: int = FIT_SAMPLES) -> DistortionFit:
    """k1..k4 with theta_d(theta) = theta (1 + k1 theta^2 + ... + k4 theta^8) ~ the exact model,
    for theta from 0 to the farthest image corner."""
    theta = _angles(camera, samples)
    target = camera.theta_d(theta)
    A = np.stack([theta ** 3, theta ** 5, theta ** 7, theta ** 9], axis=1)
    D = _chebyshev_fit(A, target - theta)
    error = camera.f * float(np.max(np.abs(A @ D - (target - theta))))
    fitted = KannalaBrandtCamera(camera.f, camera.f, camera.cx, camera.cy, camera.width,
                                 camera.height, D)
    return DistortionFit('equidistant', D, error, fitted)


def fit_plumb_bob(camera: RadialCamera, samples: int = FIT_SAMPLES) -> DistortionFit:
    """k1, k2, k3 (p1 = p2 = 0) of OpenCV's radial model ~ the exact model, over the image.

    Good for narrow lenses only: a polynomial in the pinhole radius tan(theta) cannot follow a
    fisheye towards 90 degrees, which the reported error shows.

    A camera with fx != fy whose ``theta_d`` is per normalised radius (a refined Kannala-Brandt
    camera) is fitted the same way, with its own fx, fy, and the error in pixels of the larger.
    """
    theta = _angles(camera, samples)
    r = np.tan(theta)
    target = camera.theta_d(theta)
    A = np.stack([r ** 3, r ** 5, r ** 7], axis=1)
    k = _chebyshev_fit(A, target - r)
    error = max(camera.fx, camera.fy) * float(np.max(np.abs(A @ k - (target - r))))
    D = np.array([k[0], k[1], 0.0, 0.0, k[2]])
    fitted = PlumbBobCamera(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height, D)
    return DistortionFit('plumb_bob', D, error, fitted)


DISTORTION_FITS = {'equidistant': fit_kannala_brandt, 'plumb_bob': fit_plumb_bob}
