"""Checkerboard calibration with the spec sheet as evidence: one MAP fit over corners, FOVs and priors.

``fit_board(corners, spec, views)``: the camera is a Kannala-Brandt k1..k4 camera (ROS
``equidistant``, ``parameters.KannalaBrandtLayout``: f, cx, cy and deviations from the zero-shot
shape), started from and shaped around the zero-shot camera (``zero_shot.zero_shot_start``:
'auto', fitted to KB4). Its evidence:

- ``core.checkerboard.corner_term.CornerTerm``: the detected corners, the board poses and bends
  (``BOARD_BEND``) eliminated per evaluation, robust soft_l1 per corner at ``LOSS_SCALE`` sigmas;
- ``terms.FovTerm``: the spec's FOVs, sigma = the tolerance (default 1 degree);
- ``terms.PrincipalPointPrior`` (1.1 % of the width per axis) and ``terms.ShapePrior`` around the
  zero-shot shape at ``terms.SHAPE_SIGMA`` (0.5 % RMS relative): the priors of the zero-shot
  camera's own error bar (``uncertainty.zero_shot_uncertainty``), so that the fit is the zero-shot
  posterior updated by the corners. Not the line refinement's 4x wider shape prior
  (``refine.REFINE_SHAPE_SIGMA``): lines reach the periphery, while one board view often covers a
  small part of the image, and with the shape prior at 2 % single views of the shared real set
  extrapolated their shape to the rest of the image (3 of 24 single-image runs worse than
  zero-shot alone by more than 0.2 px, against 1 at 0.5 %, with flat boards; benchmarks/results/board_with_spec.md).
  A heavy-tailed (Cauchy) prior at 0.5 % was worse still on real views (one run at 6.6 px).

This is what "the spec as evidence" means, against ``calibration.calibrate`` 'fc+zs' where the
spec only gives the start of FC and is forgotten after the first iteration.

Steps, as ``fit.fit_lines`` does for lines:

1. Robust fit at the highest order from the zero-shot camera (corner sigma ``INITIAL_SIGMA_PX``).
2. Corner noise sigma estimated from the fit (sum of squared distances over 2 M n - 6 n - p
   degrees of freedom, floor ``MIN_SIGMA_PX``), so that the weight of the corners against the
   FOVs is the noise the images actually have (model misfit included); corners farther than
   max(``calibration.OUTLIER_K_SIGMA`` sigma, ``calibration.OUTLIER_MIN_PX``) are left out (FC's
   rule) and the fit repeated, until the set is stable.
3. Model order: k1..kn free for n from 4 down, the least chi^2 + 2 (number of parameters) (AIC,
   ``fit.ORDER_PENALTY``) kept; the uncertainty is the highest order's at the chosen camera
   plus the restriction's bias in quadrature (as ``refine``).

4. The gate (``GATE``), the line refinement's (``refine``): the MAP replaces the zero-shot
   camera only when, under its posterior (the highest order's covariance at the chosen camera),
   the probability that zero-shot is nearer the truth by more than ``ZERO_SHOT_MARGIN`` (0.3 px
   at 1920 wide; RMS over the image after the best rotation, beside the zoom:
   ``GATE_AFTER_ZOOM``) is at most ``MAX_ZERO_SHOT_BETTER`` (1 %;
   ``uncertainty.probability_other_is_better``). The MAP is better on average, but one view
   pins the camera loosely and when zero-shot happens to lie close to the truth (inside the
   posterior's spread) the MAP moves away from it: on real lens profiles with synthetic single
   views (benchmarks/board_single_shot.py, benchmarks/results/board_single_shot.md) the MAP alone
   was worse than zero-shot by more than 0.48 px (at 1920; the shared set's 0.2 px at 800) in 30
   of 120 runs, with the gate in 8 (mean error 4.26 -> 4.33 px, zero-shot 5.28). Otherwise
   ``accepted`` is False, ``camera`` / ``uncertainty_px`` / ``rms_px`` / the poses are zero-shot's,
   ``reason`` and a note say so; ``fitted_camera``, ``fitted_uncertainty_px``, ``order``, the FOVs
   and ``spec_agrees`` stay the MAP's. What the gate cannot catch: a MAP many of its own sigmas
   from the truth (a view whose corners err smoothly beyond white noise and beyond what a bent
   board explains; with a flat-board model the shared set's bowed left-0008 was one, principal
   point 28 px off at 10 of its sigmas: hence ``BOARD_BEND``); ``SYSTEMATIC_PX`` lets the gate's
   posterior allow such errors (0: it did not pay on the tuning set).

The result reports ``uncertainty_px`` (``uncertainty``: RMS over the image of the 1-sigma pixel
displacement after the best rotation), the corner RMS, the FOVs of the result against the spec's
and ``spec_agrees``: False when a FOV misses the spec by more than ``refine.MAX_FOV_SIGMAS``
tolerances or the FOVs' chi^2 exceeds its ``FOV_AGREEMENT`` quantile, with a warning that names
them: the corners contradict the spec sheet (a wrong FOV, a
crop, another lens) and the MAP is a compromise between them that should not be trusted
silently.

5. The contradiction test (``spec_contradiction``): with one view the FOV term dominates and the
   MAP meets even a spec of another lens (60 x 40 degrees on the shared set's 180-degree lens: the
   FOVs within 2 tolerances, the corners fitted by a bent board and a wild k1..k4), so the FOV
   residuals at the MAP cannot show it. The likelihood ratio of the FOV term, at a real spec
   sheet's tolerance (``CONTRADICTION_TOLERANCE_DEG``), can; when it exceeds its chi^2 quantile
   (``CONTRADICTION_P``), or a FOV of the MAP is more than ``refine.MAX_FOV_SIGMAS`` such
   tolerances off, the result is never adopted: ``accepted`` False, ``spec_agrees`` False, the
   zero-shot camera without an error bar (it holds only if the spec does), and a warning.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np
from scipy.stats import chi2 as chi2_distribution

from ..checkerboard.calibration import OUTLIER_K_SIGMA, OUTLIER_MIN_PX, CalibrationError, RejectedCorner
from ..checkerboard.corner_term import CornerTerm
from ..checkerboard.corners import CornerSet, check_corner_set
from ..lens.models import KannalaBrandtCamera
from ..zeroshot.spec import CameraSpec
from .fit import ORDER_PENALTY, estimate_sigma, truncated_start
from .parameters import KB_TERMS, KannalaBrandtLayout
from .problem import Problem, one_blas_thread
from .refine import MAX_FOV_SIGMAS
from .terms import FOV_TOLERANCE_DEG, SHAPE_SIGMA, FovTerm, PrincipalPointPrior, ShapePrior
from .uncertainty import (Uncertainty, displacement, pixel_grid, probability_other_is_better, problem_uncertainty,
                          systematic_covariance)
from .zero_shot import zero_shot_start

INITIAL_SIGMA_PX = 0.5
MIN_SIGMA_PX = 0.05
"""Floor of the estimated corner noise (px): no detector beats it, and a smaller value would let
a few perfectly fitted corners outvote the spec."""
LOSS_SCALE = 3.0
MAX_ROUNDS = 4
FOV_AGREEMENT = 0.9973
"""The FOVs agree with the corners when no FOV of the result misses the spec's by more than
``refine.MAX_FOV_SIGMAS`` tolerances and their chi^2 (squared misses in tolerances, summed) is below
this quantile of the chi^2 distribution with one degree per FOV (the 3-sigma probability).

Not a likelihood-ratio test of the FOVs against the corners (twice the MAP's cost less that of the
fit without the FOV term), though it catches a wrong FOV from fewer views (20 degrees too narrow
from 2 views with bent boards, ``BOARD_BEND``): on the shared set, whose spec is exact, it flagged 8
of 24 single-image runs at 1 degree, against 0 for this rule; the corners' likelihood is too
sure of itself (model misfit beside white noise) for its chi^2 to be calibrated."""
CONTRADICTION_TOLERANCE_DEG = 5.0
"""The contradiction test (``spec_contradiction``) takes the spec's FOVs as good to this (1 sigma,
degrees; or to --fov-tolerance when that is wider): what a real spec sheet meets (rounding, unit
spread, a FOV quoted for another mode), so that the test refuses a spec of another lens, not a
spec a few degrees off."""
CONTRADICTION_P = 1e-6
"""The corners contradict the spec when the likelihood ratio of the FOV term (at
``CONTRADICTION_TOLERANCE_DEG``) exceeds the chi^2 quantile 1 - CONTRADICTION_P (one degree of
freedom per FOV): 27.6 for two FOVs. On the shared real set (one view each, the authors' FOVs)
the ratio was at most 16 over the 24 views; a 60 x 40 degree spec on its 180 x 104 degree lens gave
37 to 28,000 on 10 of the first 16 views (0.2 to 13 on the other 6: one view may not tell, see
the one-view note), and far more from several views. The corner likelihood is over-confident
(model misfit beside white noise), hence the wide tolerance and the small P."""
METHOD_LABEL = 'MAP (corners + spec FOVs + priors)'
GATE = True
"""Keep zero-shot unless the MAP is reliably better (module docstring, step 4)."""
MAX_ZERO_SHOT_BETTER = 0.01
ZERO_SHOT_MARGIN = 0.3 / 1920
"""The gate keeps zero-shot when, under the fit's posterior, the probability that zero-shot is
nearer the truth by more than this fraction of the width (0.3 px at 1920 wide) exceeds
MAX_ZERO_SHOT_BETTER. Both the line refinement's values (``refine.MAX_ZERO_SHOT_BETTER``,
``refine.ZERO_SHOT_MARGIN``), kept equal here, not imported, so that each gate is changed knowingly."""
SYSTEMATIC_PX = 0.0
"""The gate's posterior may let every board view err systematically by this much (px RMS per
mode) in each of the smooth modes of ``CornerTerm.systematic_modes`` (``uncertainty.systematic_covariance``). 0: on the
synthetic tuning set (benchmarks/board_single_shot.py --tuning-set --gate-grid, 120 runs without
and 120 with a 0.2 px smooth error per board) floors of 0.1 / 0.3 px kept zero-shot in 14 / 27
and 11 / 20 more runs for 1 / 2 fewer runs worse than zero-shot by 0.48 px (of 4 and 4); the
shared set's left-0008, which a floor was meant for, stays accepted even at 0.5 px."""
BOARD_BEND = True
"""Every board view may be bent (``CornerTerm`` ``bend``: a quadratic sag, 3 nuisance numbers per
view, eliminated with its pose). Hand-held boards are not flat, and one view cannot tell a bent
board from a camera with another principal point or distortion. Measured with the flat model
(``--flat-boards`` of both benchmarks) against this one:

- shared set (benchmarks/board_with_spec.py, 1 degree): single-image runs worse than zero-shot
  by more than 0.2 px 1 -> 0 of 24 (left-0008, a board held by one edge and visibly bowed, 1.728
  -> 1.021 px: flat, its MAP put the principal point 28 px from ost.yaml's at 10 of its own
  sigmas), eq. 21 1.137 -> 1.116 px. The MAPs find the set's boards 2.0-19.2 mm from flat
  (median 5.7, left-0008's 5.7; 0.2-2.1 % of the 929 mm diagonal).
- synthetic single views (benchmarks/board_single_shot.py --profiles 30 --views 4; runs worse
  than zero-shot by more than 0.48 px at 1920, mean error; zero-shot 5.28 px):
  flat boards 8 -> 5 runs, 4.33 -> 4.74 px (what the bend costs when the board IS flat);
  sag 0.5 % of the diagonal (--bend 0.005) 51 -> 3 runs, 9.46 -> 4.59 px;
  sag 2 % 47 -> 5, 13.29 -> 4.58 px; a smooth 0.2 px detector error (--systematic 0.2) 11 -> 4,
  4.48 -> 4.58 px.

A Gaussian prior on the sag at 1 % of the diagonal (an experiment, not kept) left the flat and
the 2 % synthetic runs at 4.74 and 4.65 px, with 5 and 4 runs worse (the corners pin the sag
better than that prior), so the bend is free."""
BENT_NOTE = 0.005
"""A note names the views whose board is farther than this fraction of its diagonal from flat."""
GATE_AFTER_ZOOM = True
"""Compare the two cameras beside the zoom (``uncertainty.zoom_field``), as the line refinement
does: both take it mostly from the same FOVs, whose error moves both alike. On the tuning set
(as above) it kept zero-shot in 10 and 6 fewer runs (mean error 5.22 -> 5.04 and 5.14 -> 5.03 px
at 1920) for one run more worse than zero-shot (3 -> 4 in each)."""


@dataclass
class BoardFit:
    """The MAP calibration from corners and the spec (module docstring)."""

    camera: KannalaBrandtCamera
    uncertainty_px: Optional[float]
    uncertainty: Uncertainty = field(repr=False)
    views: tuple
    rms_px: float
    """RMS corner distance (px) over the corners used, at the eliminated poses."""
    sigma_px: float
    """Estimated corner noise per coordinate (px)."""
    order: int
    """Number of Kannala-Brandt coefficients the evidence moved (0..4)."""
    fov_tolerance_deg: float
    fovs_given: Dict[str, float]
    fovs_fitted: Dict[str, float]
    """The MAP's FOVs (``fitted_camera``'s, also when the gate kept zero-shot)."""
    fov_residuals_deg: Dict[str, float]
    """The MAP's minus the given (degrees)."""
    spec_agrees: bool
    """False when the corners contradict the spec (a FOV of the MAP beyond ``refine.MAX_FOV_SIGMAS``
    tolerances, their chi^2 beyond ``FOV_AGREEMENT``, or ``spec_contradiction``): then never adopted."""
    zero_shot_camera: KannalaBrandtCamera
    zero_shot_uncertainty_px: Optional[float]
    rvecs: np.ndarray = field(repr=False)
    tvecs: np.ndarray = field(repr=False)
    rejected: List[RejectedCorner] = field(default_factory=list)
    warnings: List[str] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)
    corners_used: int = 0
    evaluations: int = 0
    accepted: bool = True
    """False when the gate kept the zero-shot camera (``camera`` is then zero-shot's)."""
    reason: str = ''
    fitted_camera: Optional[KannalaBrandtCamera] = None
    """The MAP camera, whatever the gate decided."""
    fitted_uncertainty_px: Optional[float] = None
    zero_shot_better_probability: Optional[float] = None
    zero_shot_distance_px: Optional[float] = None
    gate_uncertainty_px: Optional[float] = None
    gate: object = field(default=None, repr=False)
    """(problem, x) of the highest order at the MAP: what the gate's posterior is computed from."""
    board_sag_m: List[float] = field(default_factory=list)
    """Per view, how far its board was from flat under the MAP (``CornerTerm.sag``, metres; 0
    without ``BOARD_BEND``)."""
    duplicates: List[tuple] = field(default_factory=list)
    """(name, earlier name, RMS difference px) of the views left out as copies of another
    (``corners.CornerReport``)."""

    def extrinsics(self):
        return list(zip(self.rvecs, self.tvecs))

    def summary(self) -> dict:
        """JSON-ready record of the fit (the CLI's ``fit`` key)."""
        return {
            'method': METHOD_LABEL, 'uncertainty_px': self.uncertainty_px,
            'uncertainty': self.uncertainty.reason, 'rms_px': self.rms_px, 'sigma_px': self.sigma_px,
            'order': self.order, 'fov_tolerance_deg': self.fov_tolerance_deg,
            'fovs_given': dict(self.fovs_given), 'fovs_fitted': dict(self.fovs_fitted),
            'fov_residuals_deg': dict(self.fov_residuals_deg),
            'fov_residuals_sigmas': {k: v / self.fov_tolerance_deg for k, v in self.fov_residuals_deg.items()},
            'spec_agrees': self.spec_agrees, 'corners_used': self.corners_used,
            'rejected_corners': [r.to_dict() for r in self.rejected],
            'zero_shot_uncertainty_px': self.zero_shot_uncertainty_px,
            'principal_point_shift_px': float(math.hypot(self.fitted.cx - self.zero_shot_camera.cx,
                                                         self.fitted.cy - self.zero_shot_camera.cy)),
            'evaluations': self.evaluations,
            'accepted': self.accepted, 'reason': self.reason,
            'fitted_uncertainty_px': self.fitted_uncertainty_px,
            'zero_shot_better_probability': self.zero_shot_better_probability,
            'zero_shot_distance_px': self.zero_shot_distance_px,
            'board_sag_mm': [1000.0 * v for v in self.board_sag_m],
        }

    @property
    def fitted(self) -> KannalaBrandtCamera:
        return self.fitted_camera if self.fitted_camera is not None else self.camera


def _outlier_corners(term: CornerTerm, camera, sigma: float) -> np.ndarray:
    d = np.linalg.norm(term.point_residuals(camera), axis=-1)
    d = np.where(np.isfinite(d), d, np.inf)
    return d > max(OUTLIER_K_SIGMA * sigma, OUTLIER_MIN_PX)


def _uncertainty(top: Problem, top_x, camera, order) -> Uncertainty:
    """The highest order's covariance at the chosen camera, plus the chosen order's bias (its
    distance from the highest order's solution, RMS over the image) in quadrature."""
    layout = top.layout
    x = layout.x_from(camera)
    u = problem_uncertainty(top, x)
    if u.rms_px is None or order == layout.order:
        return u
    rays = camera.unproject(pixel_grid(camera.width, camera.height))
    rays = rays[np.all(np.isfinite(rays), axis=1)]
    bias = displacement(camera, layout.camera(top_x), rays)
    bias_rms = float(np.sqrt(np.nanmean(np.sum(bias * bias, axis=1))))
    total = math.hypot(u.rms_px, bias_rms)
    return Uncertainty(total, f'{u.reason}, order {order} of {layout.order}: {bias_rms:.3g} px from the '
                       'highest order added', covariance=u.covariance, names=u.names, layout=layout, x=x,
                       spread_cameras=((layout.camera(top_x), 1.0),))


def _corners_at(term: CornerTerm, camera):
    """(board poses (n, 6), corner distances (n, M) px, RMS over the corners in use, sag of each
    board (n,) m) under ``camera``, on a copy of ``term`` (its poses solved for this camera)."""
    final = term.copy()
    poses = final.solve_poses(camera)[:, :6]
    d = np.linalg.norm(final.point_residuals(camera), axis=-1)
    used = final.weights > 0
    rms = float(np.sqrt(np.mean(d[used] ** 2))) if np.all(np.isfinite(d[used])) else float('inf')
    return poses, d, rms, final.sag()


def zero_shot_better(fit: 'BoardFit', floor_px: float = SYSTEMATIC_PX, margin_px: Optional[float] = None,
                     after_zoom: bool = GATE_AFTER_ZOOM):
    """(probability, distance px, spread px) that the zero-shot camera is nearer the truth than the
    MAP by more than ``margin_px`` (default ``ZERO_SHOT_MARGIN`` of the width) under the posterior
    with the systematic floor ``floor_px`` (``uncertainty.systematic_covariance`` with the corner
    term's ``systematic_modes``; ``uncertainty.probability_other_is_better``); (None, None, None)
    without a covariance."""
    problem, x = fit.gate
    cov, _ = systematic_covariance(problem, x, problem.jacobian(x), floor_px)
    if cov is None:
        return None, None, None
    margin = ZERO_SHOT_MARGIN * fit.zero_shot_camera.width if margin_px is None else margin_px
    return probability_other_is_better(problem.layout, x, cov, fit.zero_shot_camera, margin,
                                       after_zoom=after_zoom)


def spec_contradiction(problem: Problem, x, fov: FovTerm, tolerance_deg: float, max_nfev: int = 60):
    """(likelihood ratio, threshold) of the spec's FOVs against the corners and priors: twice the
    least cost of ``problem`` (the MAP's terms) with the FOV term at ``tolerance_deg`` less the
    least cost without it, both solved from ``x`` (the MAP); a poorer minimum of the second only
    lowers the ratio (the test errs towards agreeing). The threshold: chi^2 quantile
    1 - CONTRADICTION_P with one degree per FOV."""
    others = [t for t in problem.terms if t is not fov]
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        free = Problem(problem.layout, others).solve(x, max_nfev=max_nfev)
        wide = copy.copy(fov)
        wide.sigma = float(tolerance_deg)
        held = Problem(problem.layout, others + [wide]).solve(x, max_nfev=max_nfev)
    ratio = 2.0 * (held.cost - free.cost)
    ratio = max(ratio, 0.0) if math.isfinite(ratio) else math.inf
    return ratio, float(chi2_distribution.ppf(1.0 - CONTRADICTION_P, len(fov.keys)))


@one_blas_thread()  # its pose solves are tiny: OpenBLAS's threads only wait (problem.py)
def fit_board(corners: CornerSet, spec: CameraSpec, views: Optional[Sequence[int]] = None,
              fov_tolerance_deg: float = FOV_TOLERANCE_DEG, orders=range(KB_TERMS + 1),
              max_nfev: int = 60, shape_sigma: float = SHAPE_SIGMA,
              progress: Optional[Callable[[str], None]] = None, solution=None) -> BoardFit:
    """The MAP calibration of ``views`` (all images by default) of ``corners`` with ``spec``'s FOVs
    as evidence (module docstring); ``orders``: the model orders tried; ``shape_sigma``: the shape
    prior's RMS relative deviation; ``progress`` is told of each fit before it runs; ``solution``: the
    spec's zero-shot solution if already computed, or its whole zero-shot result at the images' size
    and ``fov_tolerance_deg`` (a ``zero_shot.ZeroShotStart``). Input errors
    raise CalibrationError / CornersError / SpecError."""
    say = progress or (lambda message: None)
    if spec is None or not (spec.given() or getattr(spec, 'circle_fov', None) is not None):
        raise CalibrationError('the spec as evidence needs a FOV: give hfov / vfov / dfov')
    views = tuple(range(len(corners))) if views is None else tuple(int(v) for v in views)
    if not views:
        raise CalibrationError('no images to calibrate on: allowed: at least 1')
    bad = [v for v in views if not 0 <= v < len(corners)]
    if bad:
        raise CalibrationError(f'image index {bad[0]} is invalid: allowed: 0 to {len(corners) - 1}')
    report = check_corner_set(corners, views)
    views = report.distinct(views)  # a copy of a view adds no evidence: it counts once
    W, H = corners.width, corners.height
    if (W, H) != (spec.width, spec.height):
        raise CalibrationError(f'the spec is {spec.width}x{spec.height} but the images are {W}x{H}')
    start = zero_shot_start(spec, W, H, fov_tolerance_deg, solution)
    zs, zs_u = start.camera, start.uncertainty
    zs_u_px = zs_u.rms_px
    fov = FovTerm.from_spec(spec, fov_tolerance_deg, W, H)
    theta_max = float(zs.max_field_angle()) if math.isfinite(zs.max_field_angle()) else math.pi / 2
    priors = [fov, PrincipalPointPrior(W, H), ShapePrior(zs, theta_max, shape_sigma)]
    orders = sorted(orders)
    top = KannalaBrandtLayout(zs, orders[-1], W, H)
    x = top.x_from(zs)
    term = CornerTerm(corners.object_points(), corners.corners[list(views)], INITIAL_SIGMA_PX, 'soft_l1', LOSS_SCALE,
                      bend=BOARD_BEND)
    evaluations = 0

    def solve(layout, t, x0):
        nonlocal evaluations
        problem = Problem(layout, [t] + priors)
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            solution_ = problem.solve(x0, max_nfev=max_nfev)
        evaluations += solution_.evaluations
        return problem, solution_

    sigma = INITIAL_SIGMA_PX
    for round_ in range(1, MAX_ROUNDS + 1):
        say(f'fitting {len(views)} image{"s" if len(views) > 1 else ""} and the spec: round {round_} '
            f'(outlier corners left out so far: {int(np.sum(term.weights == 0))})')
        problem, sol = solve(top, term.copy(sigma=sigma), x)
        x = sol.x
        camera = top.camera(x)
        sigma = estimate_sigma(term, camera, x.size, MIN_SIGMA_PX)
        rejected = _outlier_corners(term, camera, sigma)
        weights = np.where(rejected, 0.0, 1.0)
        if np.array_equal(weights, term.weights):
            break
        term = term.copy(weights=weights)
    term = term.copy(sigma=sigma)
    fits, score = {}, {}
    for order in reversed(orders):
        say(f'fitting {len(views)} image{"s" if len(views) > 1 else ""} and the spec: lens model with '
            f'{order} distortion coefficient{"s" if order != 1 else ""}')
        layout = top.with_order(order)
        x0 = x if order == orders[-1] else truncated_start(layout, top.camera(x), layout.theta_max)
        problem, sol = solve(layout, term.copy(), x0)
        fits[order] = (layout, problem, sol)
        score[order] = 2.0 * sol.cost + (3 + order) * ORDER_PENALTY
        if score[order] > min(score.values()):
            break
    order = min(score, key=score.get)
    layout, problem, sol = fits[order]
    camera = layout.camera(sol.x).plain()
    _, top_problem, top_sol = fits[orders[-1]]
    u = _uncertainty(top_problem, top_sol.x, camera, order)
    u_px = u.rms_px

    fitted = fov.predicted(camera)
    residuals = {k: float(fitted[k] - fov.fovs[k]) for k in fov.keys}
    z = {k: v / fov_tolerance_deg for k, v in residuals.items()}
    chi2 = float(sum(v * v for v in z.values())) if all(math.isfinite(v) for v in z.values()) else math.inf
    agrees = bool(max(abs(v) for v in z.values()) <= MAX_FOV_SIGMAS
                  and chi2 <= float(chi2_distribution.ppf(FOV_AGREEMENT, len(z))))
    warnings = [zs_u.warning] if zs_u.warning else []
    test_tolerance = max(fov_tolerance_deg, CONTRADICTION_TOLERANCE_DEG)
    ratio, threshold = spec_contradiction(top_problem, top_sol.x, fov, test_tolerance, max_nfev)
    far = max(abs(v) for v in residuals.values()) > MAX_FOV_SIGMAS * test_tolerance \
        if all(math.isfinite(v) for v in residuals.values()) else True
    # a MAP a few tolerances off a spec the corners pin (many views) is the corners' camera, adopted
    # with the disagreement warning; one the spec cannot be at a real spec sheet's tolerance is not
    contradicted = far or ratio > threshold
    if contradicted:
        agrees = False
        listed = ', '.join(f'{k} {fitted[k]:.1f} against {fov.fovs[k]:g}' for k in fov.keys)
        evidence = (f'the MAP camera, pulled towards the spec, still has {listed}, more than {MAX_FOV_SIGMAS:g} x '
                    f'{test_tolerance:g} degrees off' if far else
                    f'the MAP camera ({listed}) explains the corners only by bending the lens to the spec: a '
                    f'likelihood ratio of {ratio:.3g} against the corners alone, above {threshold:.3g} (chi^2, P = '
                    f'{CONTRADICTION_P:g})')
        warnings.append(
            f'the corners contradict the spec, even with its FOVs taken as good to {test_tolerance:g} degrees: '
            f'{evidence}; not adopted: check the FOVs (a crop or another lens?), or calibrate without a spec')
    elif not agrees:
        listed = ', '.join(f'{k} {fitted[k]:.1f} against {fov.fovs[k]:g} ({z[k]:+.1f} sigma)' for k in fov.keys)
        warnings.append(
            f'the corners disagree with the spec: the MAP camera has {listed} (tolerance {fov_tolerance_deg:g} '
            f'degrees; chi^2 {chi2:.1f} for {len(z)} FOVs); the result is a compromise between them: check the '
            'FOVs (a crop or another lens?), or calibrate with --spec-as start')
    poses, d, rms, sag = _corners_at(term, camera)
    used = term.weights > 0
    rejected_list = [RejectedCorner(corners.names[views[i]], int(j), float(d[i, j]))
                     for i, j in zip(*np.nonzero(~used))]
    notes = list(report.notes)
    diagonal = float(np.hypot(*np.ptp(corners.object_points()[:, :2], axis=0)))
    bent = [(corners.names[views[i]], v) for i, v in enumerate(sag) if v > BENT_NOTE * diagonal]
    if bent:
        notes.append('board not flat (its sag is modelled, so the fit holds; a flatter board gives more): '
                     + ', '.join(f'{Path(name).name} {1000 * v:.1f} mm' for name, v in bent[:10])
                     + (' ...' if len(bent) > 10 else '') + f' from its best plane ({1000 * diagonal:.0f} mm diagonal)')
    if BOARD_BEND and len(views) == 1:
        notes.append('one view: the corners check the spec\'s FOVs loosely (a board that may bend and the focal '
                     'length trade off in one view), so a wrong FOV can go unflagged; more views check it better')
    if rejected_list:
        notes.append(f'rejected {len(rejected_list)} outlier corner(s) (error > max({OUTLIER_K_SIGMA:g} sigma, '
                     f'{OUTLIER_MIN_PX:g} px)), left out of the fit: '
                     + ', '.join(str(r) for r in rejected_list[:10]) + (' ...' if len(rejected_list) > 10 else ''))
    result = BoardFit(camera, u_px, u, views, rms, sigma, order, fov_tolerance_deg, dict(fov.fovs), fitted,
                      residuals, agrees, zs, zs_u_px, poses[:, :3].copy(), poses[:, 3:].copy(), rejected_list,
                      warnings, notes, int(used.sum()), evaluations, fitted_camera=camera, fitted_uncertainty_px=u_px,
                      gate=(top_problem, top_problem.layout.x_from(camera)), board_sag_m=[float(v) for v in sag],
                      duplicates=list(report.duplicates))
    p, distance, spread = zero_shot_better(result)
    result.zero_shot_better_probability, result.zero_shot_distance_px, result.gate_uncertainty_px = p, distance, spread
    margin = ZERO_SHOT_MARGIN * W
    zoom = 'beside the zoom ' if GATE_AFTER_ZOOM else ''
    if contradicted:
        keep = ('not adopted: the corners contradict the spec (see the warning), so neither the MAP nor the '
                'zero-shot camera of this spec can be trusted; the zero-shot camera is written without an error bar')
    elif GATE and p is None:
        keep = 'zero-shot kept: the MAP has no covariance (the corners and priors do not determine it)'
    elif not GATE or p <= MAX_ZERO_SHOT_BETTER:
        keep = None
        result.reason = 'accepted (no gate)' if p is None else (
            f'accepted: {zoom}the MAP is {distance:.3g} px RMS from zero-shot with an uncertainty of {spread:.3g} px '
            f'(probability {100 * p:.2g} % that zero-shot is better by {margin:.2g} px)')
    else:
        keep = (f'zero-shot kept: {zoom}the MAP is {distance:.3g} px RMS from zero-shot with an uncertainty of '
                f'{spread:.3g} px, so zero-shot may be as good (probability {100 * p:.0f} % that it is better by '
                f'{margin:.2g} px)')
    if keep is not None:
        result.reason = keep
        result.accepted = False
        result.camera = zs
        result.uncertainty_px = zs_u_px
        result.uncertainty = zs_u
        if contradicted:  # zero-shot's error bar holds only if the spec does: none is claimed
            result.uncertainty_px = None
            result.uncertainty = Uncertainty(None, 'none: the corners contradict the spec this camera comes from')
        poses, _, result.rms_px, _ = _corners_at(term, zs)
        result.rvecs, result.tvecs = poses[:, :3].copy(), poses[:, 3:].copy()
        result.notes.append(result.reason + (f'; the MAP (not used): order {order}, uncertainty {u_px:.3g} px'
                                             if u_px is not None else ''))
    return result
