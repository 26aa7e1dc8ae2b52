"""The robust MAP fit of a Kannala-Brandt camera to line evidence, the spec's FOVs and the priors.

1. Robust fit at the highest order (soft_l1 on every line point, ``loss_scale`` sigmas), from the
   start camera (zero-shot's KB4 fit).
2. Outlier curves (arches, wheels, foliage: not straight under any camera) rejected by their RMS:
   a curve whose RMS distance from the image of its fitted line exceeds ``REJECT_SIGMAS`` times
   the noise is dropped and the fit repeated, until no curve changes side (at most
   ``MAX_ROUNDS``). The noise sigma is estimated from the inliers (the sum of squared point
   distances over the points less two plane parameters per curve and the camera's), so that the
   whitening, the rejection and the covariance all use the noise the images actually have.
3. Model order: k1..kn move (deviations from the zero-shot shape; the rest keep zero-shot's
   values), n from 4 down, each fitted to the inliers, and the order with the least
   chi^2 + ``ORDER_PENALTY`` x (number of parameters) is kept (chi^2 of the whole problem at the
   common sigma); the descent stops at the first order worse than the best so far. A shape
   parameter is freed only when the evidence pays for it. The penalty is AIC's 2, not BIC's
   ln N (7.5 for 1800 points): BIC charged each parameter more than what the spec's three FOVs
   can contribute, so it chose k1 alone where the lines were explained equally well by a zoom
   1.1 degrees off the FOVs; on the line benchmark at the default tolerance (80 lenses) BIC gave
   1.66 / 3.78 px median / p90, AIC 1.44 / 3.72, both with no accepted result worse than
   zero-shot. The uncertainty is always taken under the highest order (``refine._fit_uncertainty``).

The result keeps the problem so that ``uncertainty.problem_uncertainty`` can linearise it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np

from ..lens.models import KannalaBrandtCamera
from ..lines.straightness import StraightnessTerm
from .parameters import KB_TERMS, KannalaBrandtLayout
from .problem import Problem, ProblemSolution

REJECT_SIGMAS = 3.0
"""A curve whose RMS exceeds this many noise sigmas (and the robust spread of the curves' RMS) is an outlier."""
MAX_ROUNDS = 4
ORDER_PENALTY: Optional[float] = 2.0
"""Cost of a parameter in the order choice (chi^2 units): 2 is AIC's; None is BIC's ln N."""
MIN_SIGMA_PX = 0.05
"""Floor of the estimated line noise (px): sub-pixel detectors do not beat it and a smaller value
would let a handful of perfect curves outvote the spec."""


@dataclass
class LineFit:
    camera: KannalaBrandtCamera
    x: np.ndarray
    order: int
    problem: Problem
    solution: ProblemSolution
    inliers: np.ndarray
    """Boolean mask over the input curves."""
    sigma_px: float
    """Estimated noise of the line points (px per coordinate)."""
    curve_rms: np.ndarray
    """RMS (px) of every input curve under the fitted camera."""
    bic: Dict[int, float] = field(default_factory=dict)
    rounds: int = 0
    top_problem: Optional[Problem] = None
    """The fit at the highest order: its covariance is the honest one (see uncertainty)."""
    top_solution: Optional[ProblemSolution] = None


def estimate_sigma(term, camera, parameters: int, floor: float = MIN_SIGMA_PX) -> float:
    """Noise sigma (px) of a term's points: the sum of their squared distances
    (``term.squared_distances``) over the degrees of freedom (``term.noise_dof``: for curves one per
    point less two per curve for its plane, for board corners two per corner less each view's
    eliminated numbers) less the camera's ``parameters``, at least 1; at least ``floor``."""
    d2 = term.squared_distances(camera)
    dof = max(term.noise_dof(len(d2)) - parameters, 1)
    return max(float(math.sqrt(np.sum(d2) / dof)), floor)


def _outlier_curves(rms: np.ndarray, sigma: float) -> np.ndarray:
    """Curves whose RMS exceeds REJECT_SIGMAS noise sigmas and the robust spread of the RMS values."""
    median = float(np.median(rms))
    spread = 1.4826 * float(np.median(np.abs(rms - median)))
    threshold = max(REJECT_SIGMAS * sigma, median + 5.0 * spread)
    return ~(rms <= threshold)


def truncated_start(layout: KannalaBrandtLayout, camera: KannalaBrandtCamera,
                    theta_max: Optional[float] = None) -> np.ndarray:
    """Start of a lower order: f and the principal point of ``camera``, and the deviations that
    follow its theta_d best (linear least squares over the field: 0 to ``theta_max``, by default
    ``camera``'s largest field angle, or its base's)."""
    x0 = layout.x_from(camera)
    if layout.order:
        if theta_max is None:
            top = camera.max_field_angle()
            top = top if math.isfinite(top) and top > 0 else layout.base.max_field_angle()
            theta_max = top if math.isfinite(top) and top > 0 else 1.0
        theta = np.linspace(0.0, theta_max, 64)
        with np.errstate(invalid='ignore', over='ignore'):
            target = camera.theta_d(theta) - layout.base.theta_d(theta)
        ok = np.isfinite(target)
        basis = np.stack([theta ** (2 * j + 3) for j in range(layout.order)], axis=1)
        if ok.sum() >= layout.order:
            x0[3:] = np.linalg.lstsq(basis[ok], target[ok], rcond=None)[0]
        else:  # no usable field: the deviations of the chosen order start at zero
            x0[3:] = 0.0
    return x0


SOLVE_TOL = 1e-7
"""ftol and xtol of the line fits' solves: a relative cost change of 1e-7 is far below one chi^2
unit for any cost these problems reach (<= 1e5), and the camera then moves by ~1e-3 px; the
solver's default here (1e-10) took 2-3x the iterations for nothing (four 1080p frames: the same
camera to 0.002 px in f, half the time)."""


def _solve(layout, term, priors, x0, max_nfev=60):
    problem = Problem(layout, [term] + list(priors))
    return problem, problem.solve(x0, max_nfev=max_nfev, ftol=SOLVE_TOL, xtol=SOLVE_TOL)


def fit_lines(term: StraightnessTerm, priors: List, base: KannalaBrandtCamera,
              start: Optional[KannalaBrandtCamera] = None, orders=range(KB_TERMS + 1),
              max_nfev: int = 60) -> LineFit:
    """Steps 1-3 of the module docstring. ``term``: all curves; ``priors``: FovTerm,
    PrincipalPointPrior, ShapePrior, ...; ``base``: the camera whose shape the deviations start
    from (zero-shot's KB4); ``start``: the camera to start from (default ``base``)."""
    orders = sorted(orders)
    top = KannalaBrandtLayout(base, orders[-1])
    start = base if start is None else start
    x = top.x_from(start)
    inliers = np.ones(len(term), dtype=bool)
    sigma = term.sigma
    rounds = 0
    for rounds in range(1, MAX_ROUNDS + 1):
        sub = term.subset(inliers).with_sigma(sigma)
        problem, solution = _solve(top, sub, priors, x, max_nfev)
        x = solution.x
        camera = top.camera(x)
        rms = term.curve_rms(camera)
        # robust noise scale: the median curve's RMS among the current inliers
        sigma = max(float(np.median(rms[inliers])), MIN_SIGMA_PX)
        new = ~_outlier_curves(rms, sigma)
        if np.array_equal(new, inliers) or new.sum() < 2:
            break
        inliers = new
    sub = term.subset(inliers)
    sigma = estimate_sigma(sub, top.camera(x), x.size)
    sub = sub.with_sigma(sigma)
    n_points = int(sub.sizes.sum())
    fits = {}
    bic = {}
    penalty = ORDER_PENALTY if ORDER_PENALTY is not None else math.log(max(n_points, 2))
    for order in reversed(orders):
        layout = top.with_order(order)
        x0 = x if order == orders[-1] else truncated_start(layout, top.camera(x))
        problem, solution = _solve(layout, sub, priors, x0, max_nfev)
        fits[order] = (layout, problem, solution)
        bic[order] = 2.0 * solution.cost + (3 + order) * penalty
        if bic[order] > min(bic.values()):
            break  # fewer parameters explain the evidence worse still: stop going down
    order = min(bic, key=bic.get)
    layout, problem, solution = fits[order]
    camera = layout.camera(solution.x)
    top_layout, top_problem, top_solution = fits[orders[-1]]
    return LineFit(camera.plain(), solution.x, order, problem, solution, inliers, sigma,
                   term.curve_rms(camera), bic, rounds, top_problem, top_solution)
