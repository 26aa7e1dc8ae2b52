"""The zoom of a refined camera: what straight lines cannot see, taken from the spec's FOVs.

The zoom of the rays r -> (s x, s y, z) maps planes through the centre to planes through the
centre, so every straight line stays straight under it (``uncertainty.zoom_field``): lines fix a
camera's shape up to a zoom, and only the FOVs fix the zoom. ``rezoom`` composes the refined
camera with the zoom that fits the FOV statements best.

Each FOV statement is evidence of the zoom only as far as the camera's shape is known at that
FOV's edge. Where the lines reach, the shape is theirs; beyond them (past a vignetted image
circle, past the last line of a room) it is the shape prior's extrapolation, and a zoom fitted to
a FOV there trades that extrapolation's error for a zoom error everywhere. On the line
benchmark's views through an image circle (``benchmarks/line_refinement.py --nuisances all``),
a 4:3 action camera's lines reach 34 degrees off-axis, its hfov / vfov / dfov edges lie at 52 /
39 / 66 degrees and the circle's FOV at 37: the zoom fitted to all four statements put the
refined camera 3.1 px (at 1920 wide) from the truth inside the circle, against zero-shot's 2.1
px, though only 0.2 px of it was off the zoom; weighed by the shape's own uncertainty at each
edge (``statement_shape_covariance``: 1.3, 0.1, 9.4 and 0.05 degrees there), 1.8 px. Over the 60
lenses the fitted cameras went from 0.80 / 2.10 px (median / p90) to 0.35 / 0.93 px.
"""
from __future__ import annotations

import math
from typing import List, Optional, Sequence

import numpy as np

from ..lens.models import KannalaBrandtCamera
from .problem import Problem
from .terms import FovTerm, ImageCircleTerm
from .uncertainty import GRID, pixel_jacobian, rotation_fields, systematic_covariance, zoom_field

REZOOM_MISFIT_PX = 0.05
"""Largest radius error (px) of the Kannala-Brandt refit of a re-zoomed camera: the line noise
floor (``fit.MIN_SIGMA_PX``); a zoom of 1 % costs ~0.03 px."""
ZOOM_BOUNDS = (0.9, 1.1)
"""The zooms ``rezoom`` searches: the lines' fit already holds the FOVs within their tolerance."""
ZOOM_STEP = 1e-4


def zoomed_camera(camera: KannalaBrandtCamera, s: float, samples: int = 256):
    """(camera, misfit_px): ``camera`` composed with the zoom s of its rays, as a Kannala-Brandt
    camera again (f and k1..k4 refitted to the zoomed radius function by linear least squares over
    ``samples`` angles up to its largest field angle; the principal point kept), and the largest
    radius error of that refit; (None, inf) when the zoomed rays leave the camera's field."""
    top = camera.max_field_angle()
    top = min(top if math.isfinite(top) else camera.theta_max, camera.theta_max)
    theta = np.linspace(0.0, top, samples)[1:]
    basis = np.stack([theta ** (2 * j + 1) for j in range(5)], axis=1)
    inner = np.arctan2(s * np.sin(theta), np.cos(theta))
    if not np.all(inner <= camera.theta_max):
        return None, math.inf
    radius = camera.fx * camera.theta_d(inner)
    a = np.linalg.lstsq(basis, radius, rcond=None)[0]
    if not a[0] > 0:
        return None, math.inf
    fitted = KannalaBrandtCamera(a[0], a[0], camera.cx, camera.cy, camera.width, camera.height, a[1:] / a[0])
    return fitted, float(np.max(np.abs(basis @ a - radius)))


def _statements(terms: Sequence, camera):
    """(residuals, sigmas) of the terms that state the zoom, stacked."""
    r = np.concatenate([np.atleast_1d(t.residuals(camera)) for t in terms])
    sigma = np.concatenate([np.broadcast_to(np.asarray(t.sigma, dtype=float), np.shape(np.atleast_1d(
        t.residuals(camera)))) for t in terms])
    return r, sigma


class _CircleCentre:
    """An ``ImageCircleTerm`` without its FOV: the measured centre only."""

    name = 'image_circle_centre'
    group = 1
    loss = None
    loss_scale = 1.0

    def __init__(self, term: ImageCircleTerm):
        self.term = term
        self.sigma = np.asarray(term.sigma, dtype=float)[:2]

    def residuals(self, camera) -> np.ndarray:
        return np.asarray(self.term.residuals(camera), dtype=float)[:2]


def statement_shape_covariance(problem: Problem, x, jacobian: np.ndarray, floor_px: float,
                               statements: Sequence, camera=None, circle_radius: Optional[float] = None,
                               circle_centre=None) -> Optional[np.ndarray]:
    """The covariance of the zoom ``statements``' residuals (``_statements``' order) that the
    uncertainty of the camera's shape alone puts on them: G Sigma' G^T, with G = d residuals / dx at
    ``x`` of ``problem``'s layout, and Sigma' the covariance of the lines and the priors without
    any FOV statement (``uncertainty.systematic_covariance`` of ``problem`` less its ``FovTerm``
    and the FOV of its ``ImageCircleTerm``; ``jacobian``: ``problem``'s at ``x``), less its zoom:
    Sigma' = P Sigma P^T, P = I - v w^T / (w v), v the parameters' motion under a zoom
    (``zoomed_camera``), w its share of a parameter change by the pixels (the zoom field's least
    squares coefficient over the grid, inside the circle when given). A shape known from the lines
    puts nothing on a FOV they reach; the shape prior's extrapolation beyond them puts its spread.
    None when that covariance does not exist (the lines and priors alone do not pin the shape)."""
    layout = problem.layout
    x = np.asarray(x, dtype=float)
    camera = layout.camera(x) if camera is None else camera
    rows, kept, start = [], [], 0
    for t in problem.terms:
        n = len(np.atleast_1d(t.residuals(camera)))
        if isinstance(t, ImageCircleTerm):
            rows += [start, start + 1]
            kept.append(_CircleCentre(t))
        elif not isinstance(t, FovTerm):
            rows += list(range(start, start + n))
            kept.append(t)
        start += n
    if start != len(jacobian):
        return None
    cov, _ = systematic_covariance(Problem(layout, kept), x, jacobian[rows], floor_px)
    if cov is None:
        return None
    zoomed, _ = zoomed_camera(camera, 1.0 + ZOOM_STEP)
    if zoomed is None:
        return None
    v = (layout.x_from(zoomed) - x) / ZOOM_STEP
    A, rays = pixel_jacobian(layout, x, GRID, True, circle_radius=circle_radius, circle_centre=circle_centre)
    if len(rays) == 0:
        return None
    Z = zoom_field(camera, rays)[:, 0]
    B = rotation_fields(camera, rays)
    Z = Z - B @ np.linalg.lstsq(B, Z, rcond=None)[0]
    ok = np.isfinite(Z)
    w = A[ok].T @ Z[ok] / float(Z[ok] @ Z[ok])
    if not abs(w @ v) > 0:
        return None
    P = np.eye(len(x)) - np.outer(v, w) / float(w @ v)
    cov = P @ cov @ P.T
    steps = layout.steps(x)
    base, _ = _statements(statements, camera)
    G = np.empty((len(base), len(x)))
    for j in range(len(x)):
        xp = x.copy()
        xp[j] += steps[j]
        G[:, j] = (_statements(statements, layout.camera(xp))[0] - base) / steps[j]
    C = G @ cov @ G.T
    return C if np.all(np.isfinite(C)) else None


def rezoom(camera: KannalaBrandtCamera, fov, samples: int = 256,
           shape_covariance: Optional[np.ndarray] = None) -> KannalaBrandtCamera:
    """``camera`` composed with the zoom of its rays r -> (s x, s y, z) that fits the FOVs best,
    as a Kannala-Brandt camera again (``zoomed_camera``; the principal point is kept).

    Best: least squares in the statements' covariance, their tolerances and, when given,
    ``shape_covariance`` (``statement_shape_covariance``: the camera's own shape uncertainty at
    each statement's edge). The zoom maps planes through the centre to planes through the centre,
    so every straight line stays straight under it: lines cannot tell the zoom, only the FOVs can
    (``uncertainty.zoom_field``). The joint fit still lets the lines pull it wherever
    Kannala-Brandt's four coefficients follow a zoom imperfectly, and what the pull then follows
    is the lines' small systematic errors, not the lens: on the line benchmark a rendered
    action camera came out with every FOV 0.45 degrees wide of its exact spec and 0.8 px worse
    than zero-shot, for lines straightened twice as well. Returns ``camera`` unchanged when the
    refit would misrepresent the zoomed camera (by more than ``REZOOM_MISFIT_PX``) or the FOVs
    gain nothing. ``fov``: a ``FovTerm`` or a list of terms that state the zoom (the FOVs, the
    measured image circle's FOV)."""
    from scipy.optimize import minimize_scalar
    terms: List = [t for t in (fov if isinstance(fov, (list, tuple)) else [fov]) if t is not None]
    if not terms:
        return camera
    _, sigma = _statements(terms, camera)
    weight = np.diag(1.0 / sigma ** 2)
    if shape_covariance is not None and shape_covariance.shape == (len(sigma), len(sigma)):
        weight = np.linalg.inv(np.diag(sigma ** 2) + shape_covariance)

    def chi2(cam):
        r, _ = _statements(terms, cam)
        return float(r @ weight @ r)

    def cost(s):
        fitted, _ = zoomed_camera(camera, s, samples)
        if fitted is None:
            return 1e12
        return chi2(fitted)

    before = chi2(camera)
    best = minimize_scalar(cost, bounds=ZOOM_BOUNDS, method='bounded', options={'xatol': 1e-7})
    fitted, misfit = zoomed_camera(camera, best.x, samples)
    if fitted is None or misfit > REZOOM_MISFIT_PX or not best.fun < before:
        return camera
    return fitted
