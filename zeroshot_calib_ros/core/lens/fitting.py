"""Fit the ROS / OpenCV distortion models to an exact radial camera model.

ROS tools understand CameraInfo's ``equidistant`` (OpenCV fisheye, Kannala-Brandt k1..k4) and
``plumb_bob`` models, not the paper's G_w. Both are linear in their coefficients once the focal
length is fixed, so the coefficients that minimise the *maximum* pixel error over every off-axis
angle the image contains are the solution of a small linear programme (a Chebyshev fit); least
squares is the fallback if the programme fails.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

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


def _chebyshev_fit(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x minimising max |A x - b| (linear programme over x and the bound t)."""
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
    """
    theta = _angles(camera, samples)
    r = np.tan(theta)
    target = camera.theta_d(theta)
    A = np.stack([r ** 3, r ** 5, r ** 7], axis=1)
    k = _chebyshev_fit(A, target - r)
    error = camera.f * float(np.max(np.abs(A @ k - (target - r))))
    D = np.array([k[0], k[1], 0.0, 0.0, k[2]])
    fitted = PlumbBobCamera(camera.f, camera.f, camera.cx, camera.cy, camera.width, camera.height, D)
    return DistortionFit('plumb_bob', D, error, fitted)


DISTORTION_FITS = {'equidistant': fit_kannala_brandt, 'plumb_bob': fit_plumb_bob}
