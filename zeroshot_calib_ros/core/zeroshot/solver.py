"""Zero-shot calibration: focal length and distortion from resolution and FOV (paper sec. 2).

Two FOVs across extents r_a > r_b of the image (e.g. W/2 and H/2) must give the same
undistorted focal length (square pixels, eqs. 12-17):

    f = G_w^-1(r_a) / tan(theta_a / 2) = G_w^-1(r_b) / tan(theta_b / 2)

The root w* of J_stable(w) = tan(theta_b/2)/tan(theta_a/2) - G_w^-1(r_b)/G_w^-1(r_a) (eq. 27,
generalised to any pair of extents and any projection) is found by bracketing: J_stable rises
monotonically from tan(theta_b/2)/tan(theta_a/2) - r_b/r_a at w -> 0 to tan(theta_b/2)/tan(theta_a/2)
as G_w^-1(r_a) -> inf at w = rho_max / r_a, so a barrel-distorted spec has exactly one root and
Brent's method finds it to machine precision. The paper's damped Newton iteration is kept as an
option (``method='newton'``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np

from ..lens.models import ZeroShotCamera
from .brent import brentq
from .lens_prior import LensShape, a_for_law, focal_through, lens_shape
from ..lens.projections import PROJECTIONS, FisheyeProjection
from .consistency import check_fov_tolerance, fov_warnings
from .spec import FOV_TOLERANCE_DEG, CameraSpec, SpecError
from ..lens.wide_fov import WIDE
from .wide_solver import WIDE_CHOICES, needs_wide_model, solve_wide

PROJECTION_CHOICES = ('auto',) + tuple(PROJECTIONS) + WIDE_CHOICES
DEFAULT_PROJECTION = 'equidistant'


class NoConvergence(RuntimeError):
    """The paper's Newton iteration did not reach a root (the bracketed solver always does)."""


class UnrepresentableSpec(SpecError):
    """The paper's model cannot represent the spec (rays 90 degrees or more off-axis); under
    projection='auto' the wide model (core/lens/wide_fov.py) takes over."""


@dataclass
class ZeroShotSolution:
    """A solved camera and how it was obtained."""

    spec: CameraSpec
    camera: ZeroShotCamera
    root_found: bool
    """False when no barrel-distortion root exists: w* = 0 and f is the mean perspective focal."""
    focal_estimates: Dict[str, float]
    """Undistorted focal length implied by each given FOV at w* (equal at a root)."""
    method: str
    dfov_residuals: Dict[str, float] = field(default_factory=dict)
    """With dfov and hfov + vfov given: predicted minus given dfov (degrees) for every projection."""
    iterations: int = 0
    warnings: List[str] = field(default_factory=list)
    """One line per way the solved camera misses the given FOVs by more than the tolerance
    (``consistency.fov_warnings``); [] when it shows them."""
    lens_shape: Optional[LensShape] = None
    """One FOV: the lens shape assumed from real lenses of that FOV (``lens_prior.py``); None
    when the spec determines the shape itself."""

    @property
    def assumption(self) -> Optional[str]:
        """What the solution assumes beyond the spec, in words (None: nothing)."""
        if self.lens_shape is not None:
            return self.lens_shape.assumption
        if getattr(self.spec, 'circle_diameter', None) is not None and not self.spec.given():
            law = getattr(self.camera.projection, 'law', self.camera.projection).name
            return (f'circle only: the pure {law} law is assumed across the image circle (a = 1); give hfov '
                    'or vfov too, or refine from images, to pin the lens shape')
        return None

    @property
    def omega(self) -> float:
        return self.camera.omega

    @property
    def f(self) -> float:
        return self.camera.f

    @property
    def projection(self) -> FisheyeProjection:
        return self.camera.projection

    @property
    def K(self) -> np.ndarray:
        return self.camera.K

    def distort(self, xy):
        return self.camera.distort(xy)

    def undistort(self, pixels):
        return self.camera.undistort(pixels)

    def predicted_fovs(self) -> dict:
        return self.camera.fields_of_view()


def _tan_half(deg: float) -> float:
    return math.tan(math.radians(deg) / 2.0)


def _check_representable(spec: CameraSpec, projection: FisheyeProjection):
    for name, deg in spec.given().items():
        if deg >= 180.0:
            raise UnrepresentableSpec(name, deg, f'less than 180 degrees for the {projection.name} model',
                            f'the {projection.name} model seen through a pinhole (the paper\'s model) '
                            'cannot represent rays 90 degrees or more off-axis')


def _ratio(projection, r_a, r_b, omega):
    """G_w^-1(r_b) / G_w^-1(r_a), with its w -> 0 limit r_b / r_a."""
    if omega == 0.0:
        return r_b / r_a
    return float(projection.undistort_radius(r_b, omega) / projection.undistort_radius(r_a, omega))


def _bracketed_root(projection, r_a, t_a, r_b, t_b):
    omega_max = projection.rho_max / r_a

    def j_stable(omega):
        return t_b / t_a - _ratio(projection, r_a, r_b, omega)

    # j_stable(omega_max) is t_b / t_a > 0 in the limit; stop one ulp short of the pole.
    hi = np.nextafter(omega_max, 0.0)
    return brentq(j_stable, 0.0, hi, xtol=1e-300, rtol=4 * np.finfo(float).eps, maxiter=500)


def _newton_root(projection, r_a, t_a, r_b, t_b, omega0=1e-4, gamma=0.1, tol=1e-12,
                 max_iter=2000):
    """The paper's damped Newton-Raphson on J_stable (eqs. 26-27): w0 = 1e-4, gamma = 0.1."""
    omega = omega0
    for k in range(1, max_iter + 1):
        if not 0.0 < omega < projection.rho_max / r_a:
            raise NoConvergence(f'Newton left the valid range at iteration {k}: w = {omega:.6g}')
        ua = projection.undistort_radius(r_a, omega)
        ub = projection.undistort_radius(r_b, omega)
        j = t_b / t_a - ub / ua
        dua = projection.d_undistort_radius_domega(r_a, omega)
        dub = projection.d_undistort_radius_domega(r_b, omega)
        dj = -(dub * ua - ub * dua) / ua ** 2
        step = gamma * j / dj
        omega = float(omega - step)
        if abs(step) <= tol * abs(omega):
            return omega, k
    raise NoConvergence(f'Newton did not converge in {max_iter} iterations (w = {omega:.6g})')


def _solve_pair(spec, projection, name_a, name_b, method):
    """Solve w*, f from the FOVs ``name_a`` and ``name_b`` (r_a >= r_b)."""
    extents = spec.half_extents()
    fovs = spec.given()
    (r_a, n_a), (r_b, n_b) = sorted([(extents[name_a], name_a), (extents[name_b], name_b)], reverse=True)
    t_a, t_b = _tan_half(fovs[n_a]), _tan_half(fovs[n_b])
    if r_a == r_b:
        # Only a square image with hfov == vfov gets here (spec validation rejects unequal FOVs).
        raise SpecError('dfov', spec.dfov, 'a diagonal FOV in degrees',
                        f'{n_a} and {n_b} span equal extents with equal angles on a square image, '
                        'so they cannot determine the distortion; give dfov as well')
    iterations = 0
    if t_b / t_a >= r_b / r_a:
        # No barrel root (pincushion or no distortion): the paper's Hero9(L) row, w* = 0.
        omega, root = 0.0, False
    else:
        root = True
        if method == 'newton':
            omega, iterations = _newton_root(projection, r_a, t_a, r_b, t_b)
        else:
            omega = _bracketed_root(projection, r_a, t_a, r_b, t_b)
    focal = {n: float(projection.undistort_radius(r, omega)) / t
             for n, r, t in ((n_a, r_a, t_a), (n_b, r_b, t_b))}
    if root:
        f = focal[n_a]
    else:
        f = (focal[n_a] + focal[n_b]) / 2.0
    return omega, f, focal, root, iterations


def _make_camera(spec, projection, omega, f):
    camera = ZeroShotCamera(f, spec.width / 2.0, spec.height / 2.0, spec.width, spec.height,
                            omega, projection)
    if omega * camera.corner_radius() >= projection.rho_max:
        given = spec.given()
        raise UnrepresentableSpec(', '.join(given), tuple(given.values()),
                        f'FOVs whose image corners stay below 90 degrees off-axis in the {projection.name} model',
                        f'they imply image corners 90 degrees or more off-axis (a diagonal FOV of 180 '
                        f'degrees or more), which the {projection.name} model through a pinhole cannot represent')
    return camera


def solve_zero_shot(spec: CameraSpec, projection: str = 'auto', method: str = 'bracketed',
                    fov_tolerance: float = FOV_TOLERANCE_DEG, lens_prior: bool = True) -> ZeroShotSolution:
    """Zero-shot calibration of ``spec``, with ``warnings`` when the solved camera misses a given
    FOV by more than ``fov_tolerance`` degrees (``consistency.py``).

    ``projection``: a name in PROJECTIONS, or 'auto': with hfov, vfov and dfov given, the
    projection whose predicted dfov is closest to the given one (the paper's proposed adaptive
    selection, sec. 5); otherwise equidistant, the paper's default.
    'wide' / 'wide-<law>': the paper's model continued in angle space past 90 degrees off-axis
    (core/lens/wide_fov.py: FOVs of 180 degrees and more, the circular-fisheye spec form); its camera
    is a WideFovCamera, ``omega`` its w = a / f (finite; the paper's w* wherever the paper's
    model represents the spec), ``dfov_residuals`` keyed 'wide-<law>', and it is always solved
    by bracketing. 'auto' switches to it only when the paper's model cannot represent the spec
    (a FOV of 180 degrees or more, the circle form, or image corners 90 degrees or more
    off-axis); every other spec gets the paper's result unchanged.
    ``method``: 'bracketed' (Brent, exact to machine precision) or 'newton' (the paper's).

    One FOV (hfov, vfov or dfov, without the circle form) determines only one point of the lens
    curve: the lens shape is that of the typical real lens of that FOV and aspect ratio
    (``lens_prior.py``; ``lens_shape`` of the solution), and f follows from the FOV exactly.
    Below 180 degrees with image corners below 90 degrees off-axis the camera is the paper's
    model, else the wide model of the same law and a, so f is continuous through 180 degrees.
    ``lens_prior=False``: the paper's reading instead, a pinhole (its C905 row; no camera past
    180 degrees).
    """
    fov_tolerance = check_fov_tolerance(fov_tolerance)
    solution = _solve_zero_shot(spec, projection, method, lens_prior)
    solution.warnings = fov_warnings(solution, fov_tolerance)
    return solution


def _solve_zero_shot(spec: CameraSpec, projection: str, method: str, lens_prior: bool) -> ZeroShotSolution:
    if projection not in PROJECTION_CHOICES:
        raise SpecError('projection', projection, ', '.join(PROJECTION_CHOICES))
    if method not in ('bracketed', 'newton'):
        raise SpecError('method', method, 'bracketed, newton')
    one_fov = lens_prior and len(spec.given()) == 1 and getattr(spec, 'circle_diameter', None) is None
    if projection in WIDE_CHOICES or (projection == 'auto' and needs_wide_model(spec)):
        return _solve_wide(spec, projection, one_fov)
    if getattr(spec, 'circle_diameter', None) is not None:
        raise SpecError('projection', projection, ', '.join(('auto',) + WIDE_CHOICES),
                        'the circular-fisheye form (circle_diameter, circle_fov) needs the wide model')
    try:
        if one_fov:
            return _solve_one_fov(spec, projection, method)
        return _solve_paper(spec, projection, method)
    except UnrepresentableSpec:
        if projection != 'auto':
            raise
        return _solve_wide(spec, projection, one_fov)


def _solve_wide(spec: CameraSpec, projection: str, one_fov: bool = False) -> ZeroShotSolution:
    fit = solve_wide(spec, None if projection in ('auto', WIDE) else projection, one_fov)
    residuals = {law: res['dfov'] for law, res in fit.residuals.items() if 'dfov' in res}
    return ZeroShotSolution(spec, fit.camera, fit.root_found, fit.focal_estimates, 'bracketed', residuals,
                            lens_shape=fit.lens_shape)


def _solve_one_fov(spec: CameraSpec, projection: str, method: str) -> ZeroShotSolution:
    """One FOV: the lens shape of real lenses of that FOV (``lens_prior.py``), f from the FOV; the
    paper's camera (UnrepresentableSpec where its image corners reach 90 degrees off-axis)."""
    (name, deg), = spec.given().items()
    proj = PROJECTIONS[DEFAULT_PROJECTION if projection == 'auto' else projection]
    _check_representable(spec, proj)
    shape = lens_shape(name, deg, spec.width, spec.height)
    radius, half_angle = spec.half_extents()[name], math.radians(deg) / 2.0
    a = a_for_law(shape, proj, radius, half_angle, spec.diagonal / 2.0, math.radians(89.9))
    f = focal_through(proj, a, radius, half_angle)
    camera = _make_camera(spec, proj, a / f, f)
    return ZeroShotSolution(spec, camera, False, {name: f}, method, lens_shape=shape)


def _solve_paper(spec: CameraSpec, projection: str, method: str) -> ZeroShotSolution:
    """The paper's model (every projection choice but the wide ones)."""
    given = spec.given()

    if len(given) == 1:
        # Perspective only (the paper's C905, lens_prior=False): one FOV fixes f, nothing constrains w.
        (name, deg), = given.items()
        proj = PROJECTIONS[DEFAULT_PROJECTION if projection == 'auto' else projection]
        _check_representable(spec, proj)
        f = spec.half_extents()[name] / _tan_half(deg)
        return ZeroShotSolution(spec, _make_camera(spec, proj, 0.0, f), False, {name: f}, method)

    square = spec.width == spec.height
    if 'hfov' in given and 'vfov' in given and (not square or 'dfov' not in given):
        pair = ('hfov', 'vfov')  # the paper's case (a square image with only these fails below)
    else:
        pair = ('dfov', 'hfov' if 'hfov' in given else 'vfov')
    # Adaptive selection needs a constraint the solve did not use: dfov beside hfov + vfov.
    selecting = len(given) == 3 and pair == ('hfov', 'vfov')
    if selecting:
        candidates = list(PROJECTIONS)  # residuals of every model are reported, forced or not
    else:
        candidates = [DEFAULT_PROJECTION if projection == 'auto' else projection]

    solutions, errors = {}, {}
    for name in candidates:
        proj = PROJECTIONS[name]
        try:
            _check_representable(spec, proj)
            omega, f, focal, root, iters = _solve_pair(spec, proj, *pair, method)
            camera = _make_camera(spec, proj, omega, f)
        except (SpecError, NoConvergence) as exc:
            errors[name] = exc
            continue
        solutions[name] = ZeroShotSolution(spec, camera, root, focal, method, iterations=iters)

    if selecting:
        residuals = {n: s.camera.fields_of_view()['dfov'] - spec.dfov for n, s in solutions.items()}
        wanted = projection if projection != 'auto' else (
            min(residuals, key=lambda n: abs(residuals[n])) if residuals else None)
    else:
        residuals = {}
        wanted = candidates[0]
    if wanted not in solutions:
        raise errors.get(wanted) or next(iter(errors.values()))
    chosen = solutions[wanted]
    chosen.dfov_residuals = residuals
    return chosen
