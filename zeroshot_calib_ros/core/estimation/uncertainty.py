"""Uncertainty after a fit: the covariance of the parameters, and what it means in pixels.

Covariance. At the solution x* of a problem, J the whitened (robust-corrected) Jacobian, the
Laplace approximation of the posterior is N(x*, (J^T J)^-1) (GTSAM's marginals, colmap's
covariance). It is computed after column scaling, by SVD; when the evidence and the priors do
not determine every parameter (relative singular value below ``RANK_TOLERANCE``) there is no
covariance: ``None`` with the reason, never a wrong number.

In pixels. For each pixel u_i of a 33 x 19 grid spanning the image (the lens benchmark's grid),
its ray r_i under the solution is held fixed and the pixel Jacobian A_i = d project(x; r_i) / dx
taken. The error a user meets after the best rotation of the camera (what the benchmark measures
and what any pose estimate absorbs) is the part of the displacement field outside the span of
the three rotation fields B = d project(R(w) r_i) / dw, so A is projected off B first. The
reported number is sqrt(trace(A' Sigma A'^T) / N): the RMS over the image of the 1-sigma pixel
displacement, in the image's pixels.

Zero-shot. ``zero_shot_uncertainty`` linearises the zero-shot model itself: the paper's law with
its two parameters (f, a = w f) continued past 90 degrees, the principal point and a polynomial
deviation of the law (``parameters.ZeroShotLayout``), under the spec's FOVs with their
tolerance, the principal-point prior and the shape prior (``terms``). The law's parameters carry
the spec's conditioning: on a near-square sensor without dfov (848 x 800, 206 x 172 degrees)
hfov and vfov span radii 6 % apart and pin (f, a) only along one direction, which the number
shows (the zero-shot f is 838 px there against a true 289: 2.0 % of the width against a typical
0.5 %). ``ILL_CONDITIONED_FRACTION``: above this fraction of the image width the result carries
a warning.

Calibration of the priors (``terms``): with the principal-point prior (1.1 % of the width) and
the law-deviation prior (0.5 %), the zero-shot camera's true error on the line benchmark's
lenses is within twice this number for 99 % of them.

One constraint (one FOV, or the circle form alone). Nothing in the spec tells the lens shape: the
solver takes it from real lenses of that FOV (``zeroshot/lens_prior.py``; the circle alone: the
pure law), and the error bar is the Laplace approximation of f and the principal point with the
shape held (``_shape_held_uncertainty``) and, in quadrature, the spread of the shapes of real
lenses of that FOV (``lens_shape_spread``: the cameras of the prior's 16th and 84th percentile,
not a linearisation: the spread is bimodal where rectilinear wide-angles and fisheyes share a
FOV). The circle form alone is measured over its image circle. On the held-out lenses of
benchmarks/lens_profiles.py the true error is within twice this for over 90 % of them, for one
FOV as for two (the median true / stated is 0.2-0.4 for both).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Optional, Tuple

import numpy as np

from ..lens.models import ZeroShotCamera
from ..lens.wide_fov import WIDE_LAWS, WideFovCamera
from ..zeroshot.lens_prior import LensShape, a_for_law, focal_through, nearest_side, packaged_lens_prior
from ..zeroshot.solver import solve_zero_shot
from ..zeroshot.spec import CameraSpec
from ..zeroshot.wide_solver import spec_constraints
from .parameters import ZeroShotLayout, law_of
from .problem import Problem
from .terms import FOV_TOLERANCE_DEG, FovTerm, PrincipalPointPrior, ShapePrior

GRID = (33, 19)
RANK_TOLERANCE = 1e-10
ILL_CONDITIONED_FRACTION = 0.015
"""A zero-shot uncertainty above 1.5 % of the image width (29 px at 1920) is reported as an
ill-conditioned spec. Over the 4,620 usable profiles of ../shared/data/lens_profiles_dev.csv
(their implied FOVs, tolerance 1 degree) it flags none of the 908 wide ones with h+v+d (their
largest is 1.25 %; one with h+v only), and 12 % of the narrow ones with h+v+d (18 % with h+v),
where one degree of FOV is a large share of the angle: a 2-degree telephoto is then uncertain
by a third of its focal length, which the warning rightly says. The near-square 848 x 800,
206 x 172 degree spec without dfov gives 2.0 % (wide lenses typically 0.5 %)."""


@dataclass
class Uncertainty:
    """RMS over the image of the 1-sigma pixel displacement (image pixels), or None and why."""

    rms_px: Optional[float]
    reason: str = ''
    """How it was computed, or why it could not be."""
    warning: Optional[str] = None
    """Set when the result is too uncertain to be trusted (an ill-conditioned spec)."""
    covariance: Optional[np.ndarray] = field(default=None, repr=False)
    names: Tuple[str, ...] = ()
    lens_shape_px: Optional[float] = None
    """Of ``rms_px``, the part from the spread of real lens shapes a spec of one constraint
    leaves open (``lens_shape_spread``; None: the spec pins the shape); the rest,
    sqrt(rms_px^2 - lens_shape_px^2), is the FOV tolerance's and the priors'."""
    layout: object = field(default=None, repr=False)
    """The parameter layout ``covariance`` is over, and ``x`` the solution in it: with them the
    error can be mapped pixel by pixel (``uncertainty_map``)."""
    x: Optional[np.ndarray] = field(default=None, repr=False)
    spread_cameras: Tuple = field(default=(), repr=False)
    """(camera, weight) pairs whose displacement from the solution (after the best rotation) adds
    to the error in quadrature, weighted: the lens shapes of real lenses of a single FOV
    (``lens_shape_spread``), a lower order's bias (its distance from the highest order's camera)."""
    circle_radius: Optional[float] = None
    """When set, ``rms_px`` is over the image circle of this radius (px), centred on
    ``circle_centre`` (None: on the image's centre)."""
    circle_centre: Optional[Tuple[float, float]] = None

    @property
    def fov_part_px(self) -> Optional[float]:
        """The part of ``rms_px`` from the FOV tolerance and the priors."""
        if self.rms_px is None or self.lens_shape_px is None:
            return self.rms_px
        return math.sqrt(max(self.rms_px ** 2 - self.lens_shape_px ** 2, 0.0))


def error_bar_text(value_px: float, fov_tolerance_deg: float, over: str = 'image',
                   lens_shape_px: Optional[float] = None, digits: str = '.2f') -> str:
    """What an error bar is, in one line for users (the CLI's text and the report's title): the RMS
    over ``over`` ('image' or 'image circle') of the 1-sigma pixel error after the best rotation (a
    principal point error is mostly such a rotation: the raw pixel error can be larger), with the
    FOV tolerance and, for one FOV, the lens-shape spread's part ``lens_shape_px``."""
    shapes = '' if lens_shape_px is None else f' and the spread of real lens shapes of that FOV, {lens_shape_px:.3g} px of it'
    return (f'error bar {value_px:{digits}} px (RMS over the {over} of the 1-sigma pixel error after the best '
            f'rotation, FOVs +- {fov_tolerance_deg:g} deg{shapes})')


def pixel_grid(width: int, height: int, grid=GRID, circle_radius: Optional[float] = None,
               circle_centre: Optional[Tuple[float, float]] = None) -> np.ndarray:
    """grid[0] x grid[1] pixels from (0, 0) to (W, H) inclusive (the lens benchmark's grid);
    with ``circle_radius``, only those inside the image circle of that radius (px) centred on
    ``circle_centre`` (default the image's centre): a circular fisheye's image, the rest is dark."""
    u, v = np.meshgrid(np.linspace(0.0, width, grid[0]), np.linspace(0.0, height, grid[1]))
    pixels = np.stack([u.ravel(), v.ravel()], axis=-1)
    if circle_radius is not None:
        cx, cy = (width / 2.0, height / 2.0) if circle_centre is None else circle_centre
        pixels = pixels[np.hypot(pixels[:, 0] - cx, pixels[:, 1] - cy) <= circle_radius]
    return pixels


def image_circle_radius(spec: CameraSpec) -> Optional[float]:
    """The image circle's radius (px) of a spec of the circular-fisheye form alone, whose error
    bar is over the circle (the law is pinned at the circle only and nothing outside it is
    imaged); None for every other spec (the error bar is over the whole image)."""
    circle = getattr(spec, 'circle_diameter', None)
    return circle / 2.0 if circle is not None and not spec.given() else None


def covariance(jacobian: np.ndarray) -> Tuple[Optional[np.ndarray], str]:
    """(J^T J)^-1 of a whitened Jacobian, or (None, reason) when it is singular."""
    J = np.asarray(jacobian, dtype=float)
    if not np.all(np.isfinite(J)):
        return None, 'the Jacobian is not finite at the solution'
    scale = np.linalg.norm(J, axis=0)
    if np.any(scale == 0):
        return None, 'no evidence or prior constrains some parameter'
    _, s, Vt = np.linalg.svd(J / scale, full_matrices=False)
    if len(s) < J.shape[1]:
        return None, (f'the evidence does not determine the parameters ({J.shape[0]} residuals for '
                      f'{J.shape[1]} parameters)')
    if s[-1] < RANK_TOLERANCE * s[0]:
        return None, (f'the evidence does not determine the parameters (condition number '
                      f'{s[0] / max(s[-1], 1e-300):.2g})')
    inv = (Vt.T / s ** 2) @ Vt
    return inv / np.outer(scale, scale), 'Laplace approximation at the solution'


def _rotation(w):
    angle = float(np.linalg.norm(w))
    if angle == 0.0:
        return np.eye(3)
    k = np.asarray(w) / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


def pixel_jacobian(layout, x, grid=GRID, after_rotation: bool = True, after_zoom: bool = False,
                   circle_radius: Optional[float] = None, circle_centre: Optional[Tuple[float, float]] = None):
    """(A, rays): d pixel / d x (2N x p, rows x0 y0 x1 y1 ...) of the grid pixels' rays held fixed,
    projected off the three rotation fields when ``after_rotation`` (module docstring), and off
    the zoom field too when ``after_zoom`` (``zoom_field``); ``circle_radius``, ``circle_centre``:
    the pixels of the image circle only (``pixel_grid``)."""
    x = np.asarray(x, dtype=float)
    camera = layout.camera(x)
    pixels = pixel_grid(camera.width, camera.height, grid, circle_radius, circle_centre)
    rays = camera.unproject(pixels)
    rays = rays[np.all(np.isfinite(rays), axis=1)]
    if len(rays) == 0:
        return np.empty((0, x.size)), rays
    base = camera.project(rays).ravel()
    steps = layout.steps(x)
    A = np.empty((base.size, x.size))
    for j in range(x.size):
        xp = x.copy()
        xp[j] += steps[j]
        A[:, j] = (layout.camera(xp).project(rays).ravel() - base) / steps[j]
    if after_rotation or after_zoom:
        fields = ([rotation_fields(camera, rays, base)] if after_rotation else []) + \
            ([zoom_field(camera, rays, base)] if after_zoom else [])
        B = np.concatenate(fields, axis=1)
        A = A - B @ np.linalg.lstsq(B, A, rcond=None)[0]
    ok = np.all(np.isfinite(A.reshape(-1, 2, x.size)), axis=(1, 2))
    return A.reshape(-1, 2, x.size)[ok].reshape(-1, x.size), rays[ok]


def rotation_fields(camera, rays, base=None, eps: float = 1e-6) -> np.ndarray:
    """d pixel / d w (2N x 3) of small rotations w of the rays."""
    base = camera.project(rays).ravel() if base is None else base
    B = np.stack([(camera.project(rays @ _rotation(eps * e).T).ravel() - base) / eps for e in np.eye(3)], axis=1)
    return np.where(np.isfinite(B), B, 0.0)


def zoom_field(camera, rays, base=None, eps: float = 1e-6) -> np.ndarray:
    """d pixel / d s (2N x 1) of the zoom r -> (s x, s y, z) of the rays at s = 1: the one
    motion of a radial camera's pixels that keeps every straight line straight besides the
    rotations (it maps planes through the centre to planes through the centre; for a pinhole it
    is a change of f), so line evidence cannot see it and only the FOVs fix it."""
    base = camera.project(rays).ravel() if base is None else base
    z = (camera.project(rays * np.array([1.0 + eps, 1.0 + eps, 1.0])).ravel() - base) / eps
    return np.where(np.isfinite(z), z, 0.0)[:, None]


def pixel_rms(layout, x, cov: np.ndarray, grid=GRID, after_rotation: bool = True,
              circle_radius: Optional[float] = None, circle_centre: Optional[Tuple[float, float]] = None) -> float:
    """RMS over ``grid`` (inside the circle ``circle_radius``, ``circle_centre`` if given) of the
    1-sigma pixel displacement under ``cov`` (module docstring)."""
    A, _ = pixel_jacobian(layout, x, grid, after_rotation, circle_radius=circle_radius, circle_centre=circle_centre)
    if len(A) == 0:
        return float('nan')
    return float(math.sqrt(max(np.einsum('ij,jk,ik->', A, cov, A), 0.0) / (len(A) // 2)))


def displacement(reference, other, rays, iterations: int = 10) -> np.ndarray:
    """(N, 2) pixels of ``rays`` under ``other`` minus under ``reference``, after the rotation of
    the rays that makes them agree best (Gauss-Newton on the pixels, from the identity)."""
    target = reference.project(rays)
    R = np.eye(3)
    r = (other.project(rays) - target).ravel()
    for _ in range(iterations):
        turned = rays @ R.T
        B = rotation_fields(other, turned)
        step = -np.linalg.lstsq(B, np.where(np.isfinite(r), r, 0.0), rcond=None)[0]
        R_new = _rotation(step) @ R
        r_new = (other.project(rays @ R_new.T) - target).ravel()
        if not np.all(np.isfinite(r_new)) or r_new @ r_new > r @ r:
            break
        R, r = R_new, r_new
        if np.linalg.norm(step) < 1e-12:
            break
    return r.reshape(-1, 2)


def probability_other_is_better(layout, x, cov: np.ndarray, other, margin_px: float = 0.0,
                                grid=GRID, after_zoom: bool = False, circle_radius: Optional[float] = None,
                                circle_centre: Optional[Tuple[float, float]] = None) -> Tuple[float, float, float]:
    """Under the posterior N(x, cov), the probability that camera ``other`` is closer to the true
    camera than the estimate by more than ``margin_px`` (RMS over the grid after the best rotation).

    With e ~ N(0, S) the estimate's error field (S = A cov A^T) and d = other - estimate (after
    rotation), other wins by m when |e - d|^2 < (|e| - sqrt(N) m)^2, i.e. (|e| ~ sqrt(N) u) when
    2 e.d > N (rms(d)^2 + 2 m u - m^2); e.d is normal with variance d^T S d. Returns (probability,
    rms(d), u).

    ``after_zoom``: both fields compared off the zoom too (``zoom_field``): where two cameras
    are fitted to the same FOVs, the FOVs' error moves both along the zoom alike, so the
    posterior's spread there (most of it when lines are the only other evidence: lines cannot
    see the zoom) says nothing about which of the two is nearer the truth. ``circle_radius``,
    ``circle_centre``: over the pixels of the image circle only (``pixel_grid``)."""
    from scipy.special import ndtr  # the normal CDF (scipy.stats takes a second and a half to import)
    A, rays = pixel_jacobian(layout, x, grid, True, after_zoom, circle_radius, circle_centre)
    camera = layout.camera(x)
    d = displacement(camera, other, rays).ravel()
    if after_zoom:
        B = zoom_field(camera, rays)
        good = np.isfinite(d) & np.isfinite(B[:, 0])
        d = np.where(good, d - B[:, 0] * np.linalg.lstsq(B[good], d[good], rcond=None)[0][0], np.nan)
    ok = np.isfinite(d)
    A, d = A[ok], d[ok]
    n = len(d) / 2.0
    S_d = A.T @ d
    var = float(S_d @ cov @ S_d)
    u = math.sqrt(max(np.einsum('ij,jk,ik->', A, cov, A), 0.0) / n)
    rms_d = math.sqrt(float(d @ d) / n)
    gap = n * (rms_d ** 2 + 2 * margin_px * u - margin_px ** 2)
    if var <= 0:
        return (0.0 if gap > 0 else 1.0), rms_d, u
    return float(ndtr(-gap / (2.0 * math.sqrt(var)))), rms_d, u


def clustered_covariance(problem: Problem, x, J: np.ndarray) -> Tuple[Optional[np.ndarray], str]:
    """The Laplace covariance made robust to errors shared within a cluster of residuals (a
    curve's points: the same blur, the same LSD segment, a gently curved edge taken for a
    line), never smaller than the Laplace one in any direction.

    With r the whitened residuals at x, H = J^T J, and for every term with ``residual_clusters()``
    (the straightness term: one cluster per curve) g_c = J_c^T r_c summed per cluster, the
    cluster-robust ("sandwich") covariance is H^-1 M H^-1 with M = sum_c g_c g_c^T + the other
    terms' J^T J (priors are taken as stated). It equals H^-1 in expectation when the residuals
    are independent with the estimated sigma, and grows where curves err together: a
    nearly rectilinear lens, whose lines pin the principal point only through a small
    distortion, had its principal point 20 px (at 1920) off with a Laplace spread of a few px.
    Returned: H^-1/2 max(K, I) H^-1/2 with K = H^-1/2 M H^-1/2 (eigenvalues of K below 1 raised
    to 1), so that no direction is more certain than the Laplace approximation says."""
    J = np.asarray(J, dtype=float)
    r = problem.whitened(x)
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))) or len(r) != len(J):
        return covariance(J)
    scale = np.linalg.norm(J, axis=0)
    if np.any(scale == 0):
        return covariance(J)
    Js = J / scale
    _, s, Vt = np.linalg.svd(Js, full_matrices=False)
    if len(s) < J.shape[1] or s[-1] < RANK_TOLERANCE * s[0]:
        return covariance(J)
    M = np.zeros((J.shape[1], J.shape[1]))
    start = 0
    clustered = False
    camera = problem.layout.camera(x)
    for term in problem.terms:
        n = len(np.atleast_1d(term.residuals(camera)))
        block, rb = Js[start:start + n], r[start:start + n]
        start += n
        clusters = term.residual_clusters() if hasattr(term, 'residual_clusters') else None
        if clusters is not None and len(clusters) == n:
            g = np.zeros((int(clusters.max()) + 1 if n else 0, J.shape[1]))
            np.add.at(g, clusters, block * rb[:, None])
            M += g.T @ g
            clustered = True
        else:
            M += block.T @ block
    if start != len(r) or not clustered:
        return covariance(J)
    h_inv_half = (Vt.T / s) @ Vt
    K = h_inv_half @ M @ h_inv_half
    w, V = np.linalg.eigh(0.5 * (K + K.T))
    K = (V * np.maximum(w, 1.0)) @ V.T
    cov = h_inv_half @ K @ h_inv_half
    inflation = float(np.max(w)) if len(w) else 1.0
    return cov / np.outer(scale, scale), (f'Laplace approximation at the solution, robust to errors shared '
                                          f'along a curve (largest inflation {inflation:.2g}x in variance)')


def systematic_covariance(problem: Problem, x, J: np.ndarray, floor_px: float) -> Tuple[Optional[np.ndarray], str]:
    """The covariance when every cluster of a term's residuals (a curve of the straightness
    term, a board view of the corner term: ``residual_clusters``) may also err systematically,
    ``floor_px`` RMS in each of the term's ``systematic_modes`` (a bow and an S along a curve; a
    smooth field over a board; terms without the method are taken as they are).

    The noise of a curve's residuals is then sigma^2 I + floor^2 B B^T, and its information
    J_c^T (I + e^2 B B^T)^-1 J_c = J_c^T J_c - (J_c^T B)(e^-2 I + B^T B)^-1 (B^T J_c) in
    whitened units (e = floor / sigma; Woodbury): what a curve says through its curvature is
    capped at what a curvature error of ``floor_px`` allows, whatever its number of points.
    A fisheye's lines bend by pixels to tens of pixels and lose little; a nearly rectilinear
    lens's lines tell the principal point through curvatures of hundredths of a pixel, which
    no detector measures without bias: on such a lens of the line benchmark (rendered, Laowa
    7.5 mm) the curves detected under the TRUE camera were fitted 3.3 Laplace sigmas away from
    it in cx (Delta chi^2 = 46 in favour of the wrong camera)."""
    J = np.asarray(J, dtype=float)
    if not np.all(np.isfinite(J)):
        return covariance(J)
    camera = problem.layout.camera(x)
    H = np.zeros((J.shape[1], J.shape[1]))
    start = 0
    used = []
    for term in problem.terms:
        n = len(np.atleast_1d(term.residuals(camera)))
        block = J[start:start + n]
        start += n
        H += block.T @ block
        if floor_px > 0 and hasattr(term, 'systematic_modes') and np.isscalar(term.sigma):
            B = term.systematic_modes()
            if len(B) != n:
                continue
            clusters = term.residual_clusters()
            e2 = (floor_px / float(term.sigma)) ** 2
            C, K = int(clusters.max()) + 1, B.shape[1]
            JB = np.zeros((C, K, J.shape[1]))          # per cluster: B^T J_c
            np.add.at(JB, clusters, B[:, :, None] * block[:, None, :])
            BB = np.zeros((C, K, K))                   # per cluster: B^T B
            np.add.at(BB, clusters, B[:, :, None] * B[:, None, :])
            inner = np.linalg.inv(BB + np.eye(K)[None] / e2)
            H -= np.einsum('cip,cij,cjq->pq', JB, inner, JB)
            used.append(term.systematic_modes_text)
    if start != len(J):
        return covariance(J)
    # H is J^T J less what the systematic modes take; invert it the way covariance() does
    scale = np.sqrt(np.clip(np.diag(H), 0.0, None))
    if np.any(scale == 0):
        return None, 'no evidence or prior constrains some parameter'
    w, V = np.linalg.eigh(H / np.outer(scale, scale))
    if w[0] < RANK_TOLERANCE ** 2 * w[-1]:
        return None, (f'the evidence does not determine the parameters (condition number '
                      f'{math.sqrt(w[-1] / max(w[0], 1e-300)):.2g})')
    cov = (V / w) @ V.T / np.outer(scale, scale)
    reason = 'Laplace approximation at the solution'
    for text in used:
        reason += f', {text} of {floor_px:g} px RMS'
    return cov, reason


def problem_uncertainty(problem: Problem, x, jacobian: Optional[np.ndarray] = None,
                        clustered: bool = False, systematic_px: float = 0.0,
                        circle_radius: Optional[float] = None,
                        circle_centre: Optional[Tuple[float, float]] = None) -> Uncertainty:
    """Uncertainty of ``problem`` at its solution ``x`` (Jacobian recomputed unless given);
    ``clustered``: the covariance robust to errors shared within a curve
    (``clustered_covariance``); ``systematic_px`` > 0: every curve may also err by this much in
    a bow and an S (``systematic_covariance``); ``circle_radius``, ``circle_centre``: the error
    bar over that image circle only (``pixel_grid``)."""
    J = problem.jacobian(x) if jacobian is None else jacobian
    if systematic_px > 0:
        cov, reason = systematic_covariance(problem, x, J, systematic_px)
    else:
        cov, reason = clustered_covariance(problem, x, J) if clustered else covariance(J)
    if cov is None:
        return Uncertainty(None, reason, names=tuple(problem.layout.names))
    rms = pixel_rms(problem.layout, x, cov, circle_radius=circle_radius, circle_centre=circle_centre)
    if not math.isfinite(rms):
        return Uncertainty(None, 'no grid pixel has a ray under the camera', covariance=cov,
                           names=tuple(problem.layout.names))
    return Uncertainty(rms, reason, covariance=cov, names=tuple(problem.layout.names), layout=problem.layout,
                       x=np.asarray(x, dtype=float).copy(), circle_radius=circle_radius, circle_centre=circle_centre)


def zero_shot_problem(spec: CameraSpec, fov_tolerance_deg: float = FOV_TOLERANCE_DEG, solution=None):
    """(problem, x) of the zero-shot model under the spec's FOVs and the priors (module docstring)."""
    solution = solve_zero_shot(spec, 'auto') if solution is None else solution
    camera = solution.camera
    theta_max = camera.max_field_angle()
    if isinstance(camera, WideFovCamera) and camera.circle_radius is not None:
        theta_max = min(theta_max, float(camera.theta_from_theta_d(camera.circle_radius / camera.f)))
    layout = ZeroShotLayout(law_of(camera), spec.width, spec.height, theta_max)
    x = layout.x_from_zero_shot(camera)
    terms = [FovTerm.from_spec(spec, fov_tolerance_deg), PrincipalPointPrior(spec.width, spec.height),
             ShapePrior(layout.camera(x), theta_max)]
    return Problem(layout, terms), x


def single_constraint_shape(spec: CameraSpec, solution) -> Optional[LensShape]:
    """The spread of real lens shapes a spec of one constraint leaves open: the solution's own
    ``lens_shape`` (one FOV), or for the circle form alone the table's shape of that FOV across
    the side of the image its diameter is closest to; None with two constraints or more."""
    constraints = spec_constraints(spec)
    if len(constraints) != 1:
        return None
    shape = getattr(solution, 'lens_shape', None)
    if shape is not None:
        return shape
    c = constraints[0]
    if c.name != 'circle':
        return None  # one FOV solved without the prior (lens_prior=False): nothing to spread
    return packaged_lens_prior().shape('circle_fov', c.fov, spec.width, spec.height,
                                       nearest_side(c.radius, spec.width, spec.height))


def lens_shape_spread(spec: CameraSpec, solution, grid=GRID) -> Tuple[Optional[float], Optional[LensShape]]:
    """(px, shape): the RMS over the image of the pixel displacement, after the best rotation,
    between the solved camera and the cameras through the same single constraint whose lens is
    at the 16th and at the 84th percentile of real lenses of that FOV, or at the fisheye law
    when that is wider (``lens_prior.LensShape.spread``): the 1-sigma spread of the lens shapes
    the spec leaves open (root mean square of the two), or (None, None) when the spec pins the
    shape (two constraints or more).

    Cameras, not a linearisation: the spread is far from small where rectilinear wide-angles
    and fisheyes share a FOV, and the displacement of a lens law is not linear in its a."""
    spread, shape, _ = _lens_shape_spread(spec, solution, grid)
    return spread, shape


def _lens_shape_spread(spec: CameraSpec, solution, grid=GRID):
    """``lens_shape_spread`` and the cameras it measured the spread with (those whose
    displacement could be imaged)."""
    shape = single_constraint_shape(spec, solution)
    if shape is None:
        return None, None, []
    c = spec_constraints(spec)[0]
    camera = solution.camera
    law = getattr(camera.projection, 'law', camera.projection)
    pixels = pixel_grid(camera.width, camera.height, grid, image_circle_radius(spec))
    rays = camera.unproject(pixels)
    rays = rays[np.all(np.isfinite(rays), axis=1)]
    squares, cameras = [], []
    for a_table in shape.spread:
        a = a_for_law(replace(shape, a=a_table), law, c.radius, c.half_angle, spec.diagonal / 2.0,
                      math.pi if law.name in WIDE_LAWS else math.radians(89.9))
        f = focal_through(law, a, c.radius, c.half_angle)
        other = (WideFovCamera(f, camera.cx, camera.cy, camera.width, camera.height, a / f, law.name,
                               getattr(camera, 'circle_radius', None))
                 if law.name in WIDE_LAWS else
                 ZeroShotCamera(f, camera.cx, camera.cy, camera.width, camera.height, a / f, law))
        d = displacement(camera, other, rays)
        seen = np.all(np.isfinite(d), axis=1)
        if not np.any(seen):
            continue
        squares.append(float(np.mean(np.sum(d[seen] ** 2, axis=1))))
        cameras.append(other)
    if not squares:
        return None, shape, []
    return math.sqrt(sum(squares) / len(squares)), shape, cameras


SCALE_PARAMETERS = ('f', 'cx', 'cy')
"""What a spec of one constraint leaves to the Laplace approximation: the lens shape (a and the
law's deviation) is the spread of real lenses instead (``lens_shape_spread``)."""


def _shape_held_uncertainty(problem: Problem, x, circle_radius: Optional[float]) -> Uncertainty:
    """The Laplace approximation of f and the principal point with the lens shape held at the
    solution's: with one constraint the FOV term and the shape prior leave a and the law's
    deviation nearly collinear (on a narrow field, all of them move theta_d by theta^3 first),
    and a covariance of 1e7 in a that cancels to pixels is no error bar."""
    free = [i for i, name in enumerate(problem.layout.names) if name in SCALE_PARAMETERS]
    cov_free, reason = covariance(problem.jacobian(x)[:, free])
    names = tuple(problem.layout.names)
    if cov_free is None:
        return Uncertainty(None, reason, names=names)
    cov = np.zeros((len(x), len(x)))
    cov[np.ix_(free, free)] = cov_free
    rms = pixel_rms(problem.layout, x, cov, circle_radius=circle_radius)
    if not math.isfinite(rms):
        return Uncertainty(None, 'no grid pixel has a ray under the camera', covariance=cov, names=names)
    return Uncertainty(rms, reason + ' of f and the principal point (the lens shape held)', covariance=cov,
                       names=names, layout=problem.layout, x=np.asarray(x, dtype=float).copy(),
                       circle_radius=circle_radius)


def zero_shot_uncertainty(spec: CameraSpec, fov_tolerance_deg: float = FOV_TOLERANCE_DEG,
                          solution=None) -> Uncertainty:
    """The zero-shot camera's error bar from the FOV tolerance and the priors (module docstring)
    and, for a spec of one constraint, the spread of real lens shapes it leaves open
    (``lens_shape_spread``, added in quadrature); ``warning`` set when the part from the FOV
    tolerance and the priors exceeds ``ILL_CONDITIONED_FRACTION`` of the width (the assumption
    of a spec with one constraint is the solution's ``assumption``)."""
    solution = solve_zero_shot(spec, 'auto') if solution is None else solution
    problem, x = zero_shot_problem(spec, fov_tolerance_deg, solution)
    spread, shape, spread_cameras = _lens_shape_spread(spec, solution)
    if shape is None:
        result = problem_uncertainty(problem, x)
    else:
        result = _shape_held_uncertainty(problem, x, image_circle_radius(spec))
    if shape is not None and result.rms_px is not None:
        if spread is None:
            result = Uncertainty(None, 'the spread of real lens shapes of that FOV could not be imaged',
                                 names=result.names)
        else:
            fov_part = result.rms_px
            result.rms_px = math.hypot(fov_part, spread)
            result.lens_shape_px = spread
            result.spread_cameras = tuple((c, 1.0 / len(spread_cameras)) for c in spread_cameras)
            result.reason += (f'; with the spread of real lens shapes of that FOV ({spread:.3g} px; '
                              f'{fov_part:.3g} px from the FOV tolerance and the priors)')
    if result.rms_px is None:
        result.warning = (f'the spec does not determine the camera ({result.reason}): the zero-shot '
                          'result is a guess; give dfov or use line or checkerboard evidence')
    elif result.fov_part_px > ILL_CONDITIONED_FRACTION * spec.width:
        given = ', '.join(f'{k} {v:g}' for k, v in spec.given().items())
        result.warning = (f'ill-conditioned spec ({spec.width}x{spec.height}, {given}): the zero-shot '
                          f'camera is uncertain by {result.rms_px:.3g} px RMS over the image '
                          f'({100 * result.rms_px / spec.width:.2g} % of the width) for a FOV tolerance '
                          f'of {fov_tolerance_deg:g} degrees; more precise FOVs, a dfov, or line or '
                          'checkerboard evidence would pin it')
    return result


@dataclass
class UncertaintyMap:
    """The 1-sigma pixel displacement at each pixel of a grid over the image: where the
    calibration can be trusted and where less (``uncertainty_map``)."""

    width: int
    height: int
    pixels: np.ndarray
    """(rows, cols, 2) grid pixels, (0, 0) to (W, H) inclusive."""
    sigma_px: np.ndarray
    """(rows, cols) the 1-sigma displacement (image pixels, after the best rotation of the camera);
    NaN where a pixel has no ray, or outside the image circle the error bar is stated over."""

    @property
    def rms_px(self) -> float:
        """RMS of ``sigma_px`` over the grid pixels that have one: ``Uncertainty.rms_px`` on the
        same grid."""
        seen = np.isfinite(self.sigma_px)
        return float(np.sqrt(np.mean(self.sigma_px[seen] ** 2))) if np.any(seen) else float('nan')


def _pixel_variances(u: Uncertainty, grid, circle_radius, circle_centre):
    """(camera, rays, variance): for each grid pixel with a ray (inside the circle if given), the
    trace of A_i Sigma A_i^T plus the weighted squared displacements of ``u.spread_cameras``."""
    layout, x = u.layout, np.asarray(u.x, dtype=float)
    camera = layout.camera(x)
    A, rays = pixel_jacobian(layout, x, grid, True, circle_radius=circle_radius, circle_centre=circle_centre)
    if len(rays) == 0:
        return camera, rays, np.empty(0)
    A3 = A.reshape(-1, 2, x.size)
    variance = np.einsum('nij,jk,nik->n', A3, u.covariance, A3)
    for other, weight in u.spread_cameras:
        d = displacement(camera, other, rays)
        variance = variance + weight * np.sum(d * d, axis=1)
    return camera, rays, variance


def rms_over_circle(u: Uncertainty, circle_radius: float, circle_centre: Optional[Tuple[float, float]] = None,
                    grid=GRID) -> Optional[float]:
    """``u.rms_px`` stated over another image circle (radius and centre in ``u``'s image pixels):
    the RMS of the same 1-sigma pixel error (``uncertainty_map``'s) over the grid pixels inside
    it. What a camera's error bar and a refined camera's bar over the circle seen in the images
    are compared on. None when ``u`` has no covariance or layout, or no grid pixel is inside."""
    if u.rms_px is None or u.covariance is None or u.layout is None or u.x is None:
        return None
    _, _, variance = _pixel_variances(u, grid, circle_radius, circle_centre)
    variance = variance[np.isfinite(variance)]
    return float(math.sqrt(max(float(np.mean(variance)), 0.0))) if len(variance) else None


def uncertainty_map(u: Uncertainty, grid=GRID) -> Optional[UncertaintyMap]:
    """The pixel-by-pixel form of ``u`` on a grid[0] x grid[1] grid: at each pixel the root of
    trace(A_i Sigma A_i^T), A_i its rows of the pixel Jacobian off the rotations (as ``pixel_rms``),
    plus, in quadrature, the weighted squared displacements of ``u.spread_cameras`` there (the lens
    shapes a single FOV leaves open, a lower order's bias). Its RMS over ``GRID`` is ``u.rms_px``
    (to the rounding of the shape spread's rotation, found per grid). None when ``u`` has no
    covariance or no layout (no error bar, or one not from a fit)."""
    if u.rms_px is None or u.covariance is None or u.layout is None or u.x is None:
        return None
    cols, rows = grid
    camera, rays, variance = _pixel_variances(u, grid, u.circle_radius, u.circle_centre)
    pixels = pixel_grid(camera.width, camera.height, grid).reshape(rows, cols, 2)
    sigma2 = np.full((rows, cols), np.nan)
    if len(rays) == 0:
        return UncertaintyMap(camera.width, camera.height, pixels, sigma2)
    # pixel_jacobian keeps the grid pixels with a finite ray and Jacobian: find them again by
    # their projection (the grid is regular)
    at = camera.project(rays)
    ci = np.rint(at[:, 0] / camera.width * (cols - 1)).astype(int)
    ri = np.rint(at[:, 1] / camera.height * (rows - 1)).astype(int)
    inside = (ci >= 0) & (ci < cols) & (ri >= 0) & (ri < rows)
    sigma2[ri[inside], ci[inside]] = np.maximum(variance[inside], 0.0)
    return UncertaintyMap(camera.width, camera.height, pixels, np.sqrt(sigma2))
