"""Calibration from chessboard corners: the paper's FC_eq.d. and the OpenCV baselines.

Methods (``METHODS``), each on all images (full), on one image (single-shot) or on a few
(few-shot), chosen by ``views``:

``fc``       FC_eq.d. (paper sec. 3, baselines): the paper's model ``ZeroShotCamera`` (pinhole
             focal f, equidistant distortion map G_w, principal point at the image centre or free)
             fitted by Levenberg-Marquardt-type trust-region least squares
             (``scipy.optimize.least_squares``, 'trf' with ``x_scale='jac'``) on the pixel
             reprojection error over f, w and every image's (rvec, tvec). Initialised from a
             default camera: the equidistant fisheye r = f theta whose 180 degrees span the
             longer image side (f = max(W, H) / pi, w f = 1; OpenCV fisheye's own default focal),
             extrinsics from robust PnP through that camera.
``fc+zs``    The same, initialised from the zero-shot solution of the spec sheet (paper sec. 4,
             "FC + ZS" of Table 4).
``zhang``    ``cv2.calibrateCamera`` with default flags (plumb_bob k1, k2, p1, p2, k3).
``fisheye``  ``cv2.fisheye.calibrate`` (Kannala-Brandt k1..k4) with RECOMPUTE_EXTRINSIC and
             FIX_SKEW, as ROS's camera_calibration. OpenCV's implicit start values are tried
             first; if that raises, OpenCV's documented defaults (f = max(W, H) / pi, centred
             principal point) are passed explicitly with USE_INTRINSIC_GUESS. A run that still
             raises is returned as failed (``ok=False`` with OpenCV's message), never dropped.

The FC parameters are f, s = (w f)^2 (w f enters the model only squared, and s keeps a
non-zero gradient at the pinhole w = 0, where w itself has none) and optionally cx, cy.
Residuals are vectorised over all images; the Jacobian is central differences exploiting its
structure: the intrinsic columns are dense, each image's 6 extrinsic columns touch only that
image's rows, so all images' j-th extrinsic column costs one pair of evaluations. The paper's
model cannot image rays 90 degrees or more off-axis, so each corner also carries a residual that
is zero inside that domain and steep outside it (``DOMAIN_WEIGHT``).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import cv2
import numpy as np
from scipy import sparse
from scipy.optimize import least_squares

from ..lens.models import (CameraModel, KannalaBrandtCamera, PinholeCamera, PlumbBobCamera,
                            ZeroShotCamera)
from .corners import MIN_CORNERS_PER_IMAGE, CornerSet, check_corner_set
from .pose import board_poses, transform
from ..lens.projections import PROJECTIONS, FisheyeProjection
from ..zeroshot.solver import UnrepresentableSpec, solve_zero_shot
from ..zeroshot.spec import CameraSpec, SpecError

METHODS = ('fc', 'fc+zs', 'zhang', 'fisheye')
METHOD_LABELS = {'fc': 'FC_eq.d.', 'fc+zs': 'FC_eq.d.+ZS', 'zhang': 'Zhang',
                 'fisheye': 'OpenCV fisheye'}
DENSE_UP_TO_VIEWS = 1
"""FC uses a dense Jacobian (exact trust-region solve) up to this many images, a sparse one
(trust region solved by LSMR) above: a dense SVD of the full problem costs far more."""
MIN_VIEWS_FREE_PRINCIPAL_POINT = 3
"""With ``principal_point=None`` FC frees cx, cy from this many images on; with fewer (single- and
two-shot) it stays at the image centre, the paper's model assumption (sec. 2.1): one planar
view barely constrains it and freeing it lets a single-shot fit overfit."""


class CalibrationError(ValueError):
    """The input cannot be calibrated (too few corners or images, no spec for ZS...)."""


OUTLIER_K_SIGMA = 6.0
OUTLIER_MIN_PX = 3.0
"""FC rejects a corner whose reprojection error (px, distance) exceeds max(OUTLIER_K_SIGMA sigma,
OUTLIER_MIN_PX), sigma = median distance / sqrt(2 ln 2) (the per-axis sigma of 2-D Gaussian
noise, robust to the outliers themselves). 6 sigma: no Gaussian corner in 10^7 exceeds it; 3 px:
the model misfit of real lenses never rejects a sound corner (the shared set: the largest error
after the one real outlier is 2.4 px)."""
OUTLIER_LOSS = 'soft_l1'
OUTLIER_SCALE_PX = 1.0
"""Once a corner exceeds the threshold, FC refits from the start with this robust loss and
scale (px) before deciding which corners are outliers, so that an outlier that pulled the plain
least-squares fit cannot hide in it; the final fit is plain least squares over the inliers."""
MAX_REJECTION_ROUNDS = 4


@dataclass
class RejectedCorner:
    """A corner FC left out of its fit as an outlier."""

    image: str
    index: int
    """Corner index j = r * cols + c (row-major, as in the corners file)."""
    residual_px: float
    """Its reprojection error (px) through the final fit."""

    def to_dict(self) -> dict:
        return {'image': self.image, 'index': self.index, 'residual_px': self.residual_px}

    def __str__(self) -> str:
        return f'{os.path.basename(self.image)} #{self.index} ({self.residual_px:.1f} px)'


@dataclass
class CalibrationResult:
    """One calibration run. ``ok`` False: the method failed; ``error`` says how."""

    method: str
    views: tuple
    """Indices of the images (in the CornerSet) it was calibrated on."""
    camera: Optional[CameraModel] = None
    ok: bool = True
    error: str = ''
    rms_px: float = float('nan')
    """The calibration's own RMS reprojection error over its images (eq. 20 form, its own poses)."""
    opencv_rms: Optional[float] = None
    """What OpenCV returned as RMS (OpenCV baselines only)."""
    rvecs: Optional[np.ndarray] = None
    tvecs: Optional[np.ndarray] = None
    init: str = ''
    """How the intrinsics were initialised."""
    initial_camera: Optional[CameraModel] = None
    fixed_principal_point: Optional[bool] = None
    nfev: int = 0
    notes: List[str] = field(default_factory=list)
    rejected: List['RejectedCorner'] = field(default_factory=list)
    """FC: outlier corners left out of the fit (see OUTLIER_K_SIGMA)."""
    duplicates: List[tuple] = field(default_factory=list)
    """(name, earlier name, RMS difference px) of duplicate views among ``views``."""

    @property
    def label(self) -> str:
        return METHOD_LABELS.get(self.method, self.method)

    def extrinsics(self):
        """[(rvec, tvec)] per calibrated image, or None."""
        if self.rvecs is None:
            return None
        return list(zip(self.rvecs, self.tvecs))


# ---------------------------------------------------------------------------------------------
# Start cameras: default, zero-shot, perspective


def default_camera(width: int, height: int, projection: str = 'equidistant') -> ZeroShotCamera:
    """The no-spec start: r = f theta with 180 degrees across the longer side (w f = 1)."""
    f = max(width, height) / math.pi
    return ZeroShotCamera(f, width / 2.0, height / 2.0, width, height, 1.0 / f, PROJECTIONS[projection])


def paper_zero_shot_camera(spec: CameraSpec, width: Optional[int] = None, height: Optional[int] = None,
                           solution=None):
    """(ZeroShotCamera, note) of ``spec`` with the paper's equidistant model, at ``width`` x
    ``height`` (a spec at another resolution of the same aspect is scaled): FC+ZS's start. Not
    ``core.estimation.zero_shot.zero_shot_camera`` (the 'auto' solution fitted to Kannala-Brandt).

    ``solution``: the spec's solution if already computed (``solve_zero_shot``, any projection):
    used when its camera is this one (the paper's model with the equidistant law: what 'auto'
    gives unless three FOVs choose another law or the spec needs the wide model), else the spec
    is solved here.

    The paper's model stops at 90 degrees off-axis, so ``solve_zero_shot`` refuses its
    equidistant model for specs whose image *corners* reach that (a 180-degree lens). Board
    corners inside the image can still be mapped by the same law, so such a spec is solved with
    'wide-equidistant' (core/lens/wide_fov.py: the paper's camera written in angle space, identical
    below 90 degrees), and ``note`` says so (empty otherwise).
    """
    note = ''
    try:
        if _is_paper_equidistant(spec, solution):
            camera = solution.camera
        else:
            camera = solve_zero_shot(spec, 'equidistant').camera
    except UnrepresentableSpec:
        camera = solve_zero_shot(spec, 'wide-equidistant').camera
        note = ("the paper's model cannot represent this spec (image corners 90 degrees or more "
                "off-axis); the same equidistant law in angle space (projection 'wide-equidistant') "
                f'gives f = {camera.f:.4g} px, w = {camera.omega:.6g} /px')
    width = spec.width if width is None else width
    height = spec.height if height is None else height
    if (width, height) != (spec.width, spec.height):
        if width * spec.height != height * spec.width:
            raise CalibrationError(f'the spec is {spec.width}x{spec.height} but the images are '
                                   f'{width}x{height}: aspect ratios differ')
        camera = camera.scaled(width, height)
    return camera, note


def _is_paper_equidistant(spec: CameraSpec, solution) -> bool:
    """Whether ``solution`` is of ``spec`` and its camera the paper's model with the equidistant law
    (what ``solve_zero_shot(spec, 'equidistant')`` gives)."""
    return (solution is not None and solution.spec == spec and type(solution.camera) is ZeroShotCamera
            and solution.camera.projection.name == 'equidistant')


def perspective_camera(spec: CameraSpec, width: Optional[int] = None,
                       height: Optional[int] = None) -> PinholeCamera:
    """The paper's "Pers." camera: the mean of the perspective focals (W/2) / tan(hfov/2),
    (H/2) / tan(vfov/2) (and the diagonal's) of the given FOVs, centred, no distortion."""
    focals = [spec.half_extents()[n] / math.tan(math.radians(v) / 2) for n, v in spec.given().items()
              if v < 180]
    if not focals:
        raise SpecError(next(iter(spec.given())), next(iter(spec.given().values())),
                        'less than 180 degrees', 'no perspective focal length exists')
    f = float(np.mean(focals))
    camera = PinholeCamera(f, f, spec.width / 2.0, spec.height / 2.0, spec.width, spec.height)
    width = spec.width if width is None else width
    height = spec.height if height is None else height
    if (width, height) != (spec.width, spec.height):
        s = width / spec.width
        camera = PinholeCamera(f * s, f * s, width / 2.0, height / 2.0, width, height)
    return camera


# ---------------------------------------------------------------------------------------------
# FC_eq.d.


def _fc_pixels(f, s, cx, cy, points, projection: FisheyeProjection):
    """The paper's model for camera-frame points (..., 3), continued smoothly past 90 degrees
    off-axis (r_d = f rho(atan2(a sin theta, cos theta)) / a, a = sqrt(s)), so the optimiser
    never meets NaN. Equal to ZeroShotCamera.project wherever that is defined.
    Returns (pixels (..., 2), theta (...))."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    rxy = np.hypot(x, y)
    theta = np.arctan2(rxy, z)
    a = math.sqrt(max(s, 1e-24))
    rd = f * projection.rho(np.arctan2(a * np.sin(theta), np.cos(theta))) / a
    with np.errstate(invalid='ignore', divide='ignore'):
        scale = np.where(rxy > 0, rd / np.where(rxy > 0, rxy, 1.0), f / z)
    return np.stack([cx + scale * x, cy + scale * y], axis=-1), theta


DOMAIN_MARGIN_RAD = 1e-3
DOMAIN_WEIGHT = 1e3
"""The paper's model cannot image rays 90 degrees or more off-axis (ZeroShotCamera.project is
NaN there). FC keeps every board corner inside: each corner adds the residual
DOMAIN_WEIGHT * f * max(0, theta - (pi/2 - DOMAIN_MARGIN_RAD)), zero for any valid pose."""


class _FcProblem:
    """FC's least-squares problem: x = [f, s, (cx, cy), rvec_0, tvec_0, rvec_1, ...]."""

    def __init__(self, obj, img, free_pp, cx0, cy0, projection):
        self.obj, self.img = obj, img
        self.n, self.m = img.shape[0], img.shape[1]
        self.weights = np.ones((self.n, self.m, 1))
        """0 for rejected corners (their pixel residuals are left out), else 1."""
        self.free_pp = free_pp
        self.k = 4 if free_pp else 2
        self.cx0, self.cy0 = cx0, cy0
        self.projection = projection

    def unpack(self, x):
        f, s = x[0], x[1]
        cx, cy = (x[2], x[3]) if self.free_pp else (self.cx0, self.cy0)
        poses = x[self.k:].reshape(self.n, 6)
        return f, s, cx, cy, poses

    def residuals(self, x):
        """Per image: 2 M pixel residuals, then M domain residuals (see DOMAIN_WEIGHT)."""
        f, s, cx, cy, poses = self.unpack(x)
        pts = transform(poses[:, :3], poses[:, 3:], self.obj)
        pixels, theta = _fc_pixels(f, s, cx, cy, pts, self.projection)
        domain = DOMAIN_WEIGHT * f * np.maximum(0.0, theta - (math.pi / 2 - DOMAIN_MARGIN_RAD))
        return np.concatenate([((pixels - self.img) * self.weights).reshape(self.n, -1), domain],
                              axis=1).ravel()

    def pixel_residuals(self, x) -> np.ndarray:
        """(n, M, 2), of every corner (rejected ones too)"""
        f, s, cx, cy, poses = self.unpack(x)
        pts = transform(poses[:, :3], poses[:, 3:], self.obj)
        return _fc_pixels(f, s, cx, cy, pts, self.projection)[0] - self.img

    def jacobian(self, x):
        """Central differences; dense for a few images, else sparse (CSR) with the block
        structure: intrinsic columns dense, each image's 6 extrinsic columns on its rows only."""
        n, m, k = self.n, self.m, self.k
        per = 3 * m  # rows per image
        rows = n * per
        dense = np.empty((rows, k))
        for j in range(k):
            h = 1e-6 * max(1.0, abs(x[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            if j == 1 and x[1] - h < 0:  # s >= 0: forward difference at the bound
                dense[:, j] = (self.residuals(xp) - self.residuals(x)) / h
                continue
            xm[j] -= h
            dense[:, j] = (self.residuals(xp) - self.residuals(xm)) / (2 * h)
        views = np.arange(n)
        blocks = np.empty((n, per, 6))
        for j in range(6):
            cols = k + 6 * views + j
            h = 1e-6 * np.maximum(1.0, np.abs(x[cols]))
            xp, xm = x.copy(), x.copy()
            xp[cols] += h
            xm[cols] -= h
            blocks[:, :, j] = (self.residuals(xp) - self.residuals(xm)).reshape(n, per) / (2 * h[:, None])
        if n <= DENSE_UP_TO_VIEWS:
            J = np.zeros((rows, x.size))
            J[:, :k] = dense
            Jv = J.reshape(n, per, x.size)
            for j in range(6):
                Jv[views, :, k + 6 * views + j] = blocks[:, :, j]
            return J
        # CSR: row r of image i holds k intrinsic entries, then its 6 extrinsic entries.
        data = np.concatenate([dense.reshape(n, per, k), blocks], axis=2).ravel()
        ext_cols = k + 6 * views[:, None, None] + np.arange(6)[None, None, :]
        cols = np.concatenate([np.broadcast_to(np.arange(k), (n, per, k)),
                               np.broadcast_to(ext_cols, (n, per, 6))], axis=2).ravel()
        indptr = np.arange(rows + 1) * (k + 6)
        return sparse.csr_matrix((data, cols, indptr), shape=(rows, x.size))


def _principal_point_outside(camera) -> str:
    """The error of a calibrated camera whose principal point is outside the image ('' if
    inside): no lens of a camera that imaged the board puts it there; the corners or the board
    declaration are wrong (e.g. a transposed board gave cy = 1475 px in a 750 px image)."""
    W, H = camera.width, camera.height
    if -0.5 <= camera.cx <= W - 0.5 and -0.5 <= camera.cy <= H - 0.5:
        return ''
    return (f'the calibrated principal point (cx, cy) = ({camera.cx:.1f}, {camera.cy:.1f}) px is '
            f'outside the {W}x{H} image: allowed: cx in [-0.5, {W - 0.5}], cy in [-0.5, {H - 0.5}] '
            '(check --board and the corners)')


def _checked(corners: CornerSet, views) -> tuple:
    """(views, CornerReport): the views after _check_views and check_corner_set (which raises
    CornersError on a wrong board or a degenerate view), duplicate views left out (they count once)."""
    views = _check_views(corners, views)
    report = check_corner_set(corners, views)
    return report.distinct(views), report


def _check_views(corners: CornerSet, views) -> tuple:
    if views is None:
        views = range(len(corners))
    views = tuple(int(v) for v in views)
    if not views:
        raise CalibrationError('no images to calibrate on: allowed: at least 1')
    bad = [v for v in views if not 0 <= v < len(corners)]
    if bad:
        raise CalibrationError(f'image index {bad[0]} is invalid: allowed: 0 to {len(corners) - 1}')
    if corners.board.count < MIN_CORNERS_PER_IMAGE:
        raise CalibrationError(f'{corners.board.count} corners per image are too few: allowed: at '
                               f'least {MIN_CORNERS_PER_IMAGE}')
    return views


def calibrate_fc(corners: CornerSet, views: Optional[Sequence[int]] = None,
                 initial_camera: Optional[ZeroShotCamera] = None, init: str = 'default',
                 principal_point: Optional[bool] = None, projection: str = 'equidistant',
                 max_nfev: int = 400, method: str = 'fc') -> CalibrationResult:
    """FC_eq.d. on ``views`` (all images by default) from ``initial_camera`` (the default camera
    when None). ``principal_point``: True frees cx, cy, False fixes them at the start camera's,
    None frees them from MIN_VIEWS_FREE_PRINCIPAL_POINT images on."""
    views, report = _checked(corners, views)
    W, H = corners.width, corners.height
    proj = PROJECTIONS[projection]
    start = initial_camera if initial_camera is not None else default_camera(W, H, projection)
    free_pp = (len(views) >= MIN_VIEWS_FREE_PRINCIPAL_POINT) if principal_point is None \
        else bool(principal_point)
    result = CalibrationResult(method, views, init=init, initial_camera=start,
                               fixed_principal_point=not free_pp, duplicates=report.duplicates,
                               notes=report.notes)
    obj = corners.object_points()
    img = corners.corners[list(views)]
    poses = board_poses(start, obj, img)
    if not np.all(poses.found):
        lost = [corners.names[views[i]] for i in np.flatnonzero(~poses.found)]
        result.ok = False
        result.error = (f'no start pose through the initial camera for {len(lost)} image(s): '
                        f'{", ".join(lost[:6])}')
        return result
    problem = _FcProblem(obj, img, free_pp, start.cx, start.cy, proj)
    s0 = max((start.omega * start.f) ** 2, 1e-8)
    x0 = np.concatenate([[start.f, s0], [start.cx, start.cy] if free_pp else [],
                         np.hstack([poses.rvecs, poses.tvecs]).ravel()])
    lb = np.full(x0.size, -np.inf)
    lb[0], lb[1] = 1e-6 * max(W, H), 0.0

    def solve(x_start, loss='linear'):
        tol = 1e-12 if loss == 'linear' else 1e-8  # the robust fit only classifies the corners
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            return least_squares(problem.residuals, x_start, jac=problem.jacobian, bounds=(lb, np.inf),
                                 method='trf', x_scale='jac', ftol=tol, xtol=tol, gtol=tol,
                                 max_nfev=max_nfev, loss=loss, f_scale=OUTLIER_SCALE_PX)

    def outliers(x):
        with np.errstate(invalid='ignore'):
            d = np.linalg.norm(problem.pixel_residuals(x), axis=-1)
        d = np.where(np.isfinite(d), d, np.inf)
        inlier = problem.weights[..., 0] > 0
        sigma = float(np.median(d[inlier])) / math.sqrt(2 * math.log(2))
        return d > max(OUTLIER_K_SIGMA * sigma, OUTLIER_MIN_PX), d

    try:
        sol = solve(x0)
        nfev = sol.nfev
        bad, _ = outliers(sol.x)
        if np.any(bad) and np.all(np.isfinite(sol.fun)):
            robust = solve(sol.x, OUTLIER_LOSS)
            nfev += robust.nfev
            x = robust.x
            for _ in range(MAX_REJECTION_ROUNDS):
                bad, _ = outliers(x)
                if np.array_equal(bad, problem.weights[..., 0] == 0):
                    break
                problem.weights = np.where(bad, 0.0, 1.0)[..., None]
                sol = solve(x)
                nfev += sol.nfev
                x = sol.x
            if not np.any(problem.weights == 0):
                sol = solve(x)  # nothing rejected after all: the plain fit from the robust one
                nfev += sol.nfev
    except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        result.ok = False
        result.error = f'least squares failed: {exc}'
        return result
    f, s, cx, cy, poses6 = problem.unpack(sol.x)
    if not np.all(np.isfinite(sol.fun)) or not (f > 0 and np.isfinite(s)):
        result.ok = False
        result.error = 'least squares diverged (non-finite parameters or residuals)'
        return result
    a = math.sqrt(max(s, 0.0))
    result.camera = ZeroShotCamera(f, cx, cy, W, H, a / f, proj)
    res = problem.pixel_residuals(sol.x)
    inlier = problem.weights[..., 0] > 0
    result.rms_px = float(np.sqrt(np.mean(np.sum(res * res, axis=-1)[inlier])))
    distance = np.linalg.norm(res, axis=-1)
    result.rejected = [RejectedCorner(corners.names[views[i]], int(j), float(distance[i, j]))
                       for i, j in zip(*np.nonzero(~inlier))]
    if result.rejected:
        result.notes.append(f'rejected {len(result.rejected)} outlier corner(s) (error > '
                            f'max({OUTLIER_K_SIGMA:g} sigma, {OUTLIER_MIN_PX:g} px)), left out of the fit: '
                            + ', '.join(str(r) for r in result.rejected[:10])
                            + (' ...' if len(result.rejected) > 10 else ''))
    result.rvecs, result.tvecs = poses6[:, :3].copy(), poses6[:, 3:].copy()
    result.nfev = int(nfev)
    if sol.status == 0:
        result.notes.append(f'stopped at max_nfev = {max_nfev}')
    outside = _principal_point_outside(result.camera)
    if outside:
        result.ok = False
        result.error = outside
        return result
    with np.errstate(invalid='ignore'):
        beyond = np.count_nonzero(~np.all(np.isfinite(result.camera.project(
            transform(result.rvecs, result.tvecs, obj))), axis=-1))
    if beyond:
        result.notes.append(f'{beyond} board corners lie 90 degrees or more off-axis in the '
                            'fitted model')
    return result


# ---------------------------------------------------------------------------------------------
# OpenCV baselines


def opencv_fisheye_flag(name: str) -> int:
    """A fisheye calibration flag on OpenCV 4.x (cv2.fisheye.CALIB_*) and 5.x (cv2.CALIB_*).
    The 4.x fisheye namespace is looked up first: its values differ from 4.x's cv2.CALIB_*."""
    value = getattr(getattr(cv2, 'fisheye', None), name, None)
    if value is None:
        value = getattr(cv2, name)
    return int(value)


def _opencv_lists(corners: CornerSet, views, dtype):
    obj = corners.object_points().astype(dtype).reshape(1, -1, 3)
    img = [corners.corners[v].astype(dtype).reshape(1, -1, 2) for v in views]
    return [obj] * len(views), img


def _own_rms(camera, obj, img, rvecs, tvecs):
    res = camera.project(transform(rvecs, tvecs, obj)) - img
    return float(np.sqrt(np.mean(np.sum(res * res, axis=-1))))


RMS_CONTRADICTION_PX = 1.0
RMS_CONTRADICTION_FACTOR = 2.0
"""An OpenCV result is unsound when its reprojection RMS recomputed independently
(cv2.projectPoints / cv2.fisheye.projectPoints on the K, D, rvecs, tvecs it returned) differs
from the RMS OpenCV reported by more than RMS_CONTRADICTION_PX *and* by more than a factor
RMS_CONTRADICTION_FACTOR (OpenCV 4.6 and 5.0 both return, for one real single image, 71-88 px
with a camera whose own RMS is 5e4-4e5 px), or when its principal point is outside the image."""


def _cv_rms(project, obj, img, rvecs, tvecs) -> float:
    """RMS (px, per-point distance) of ``project(obj, rvec, tvec)`` against ``img`` (n, M, 2)."""
    sq = []
    for points, r, t in zip(img, rvecs, tvecs):
        try:
            p = np.asarray(project(obj, np.asarray(r, float).reshape(3, 1),
                                   np.asarray(t, float).reshape(3, 1)), float).reshape(-1, 2)
        except cv2.error:
            return float('inf')
        sq.append(np.sum((p - points) ** 2, axis=1))
    with np.errstate(invalid='ignore', over='ignore'):
        rms = float(np.sqrt(np.mean(np.concatenate(sq))))
    return rms if math.isfinite(rms) else float('inf')


def _unsound(camera, rvecs, tvecs, obj, img, recomputed: float, reported: float,
             projector: str) -> str:
    """Why an OpenCV result is unsound ('' if it is sound), see RMS_CONTRADICTION_PX."""
    def contradicts(a, b):
        return not (abs(a - b) <= RMS_CONTRADICTION_PX
                    or b / RMS_CONTRADICTION_FACTOR <= a <= b * RMS_CONTRADICTION_FACTOR)

    if contradicts(recomputed, reported):
        return (f'its reprojection RMS recomputed with {projector} ({recomputed:.2f} px) contradicts '
                f"OpenCV's {reported:.2f} px")
    points = transform(rvecs, tvecs, obj)
    behind = int(np.count_nonzero(~(points[..., 2] > 0)))
    with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
        own = _own_rms(camera, obj, img, rvecs, tvecs)
    own = own if math.isfinite(own) else float('inf')
    if behind or contradicts(own, reported):
        where = (f'{behind} of {points.shape[0] * points.shape[1]} board corners are behind the '
                 f'camera (z <= 0) in its extrinsics, which {projector} mirrors in front; '
                 if behind else '')
        return (f'{where}its reprojection RMS through the camera model (rays at their angle off '
                f"the optical axis: {own:.2f} px) contradicts OpenCV's {reported:.2f} px")
    return _principal_point_outside(camera)


def _fc_start(corners: CornerSet, views):
    """A sound start for an OpenCV retry: FC_eq.d. on the same views (None if it fails)."""
    try:
        fc = calibrate_fc(corners, views)
    except ValueError:
        return None
    return fc.camera if fc.ok else None


def _run_attempts(result: CalibrationResult, attempts, run, name: str, obj, img) -> CalibrationResult:
    """Try ``attempts`` [(init label, start thunk returning (K0, D0, flags) or None)] in turn with
    ``run(K0, D0, flags)`` -> (camera, opencv rms, rvecs, tvecs, recomputed rms, projector).
    Raising attempts move on to the next; a sound first result is kept; an unsound one moves on
    to every retry (those marked retry=True), and the sound retry with the lowest RMS is kept:
    a retry can be sound and still far off (OpenCV 5.1's fisheye calibration from its documented
    default start ends at a 363 px RMS on a lens that the FC_eq.d. start fits to 0.07 px)."""
    raised, unsound, retried = [], [], []
    for init, start, retry in attempts:
        if retry and not unsound:
            break  # retries from a sound start are for unsound results only
        if not retry and not raised and init != attempts[0][0]:
            continue  # the explicit defaults are for an implicit start that raised
        begin = start()
        if begin is None:
            continue
        K0, D0, flags = begin
        try:
            camera, rms, rvecs, tvecs, recomputed, projector = run(K0, D0, flags)
        except cv2.error as exc:
            raised.append((init, _cv_message(exc)))
            continue
        except _NonFinite:
            raised.append((init, 'non-finite or non-positive K / D'))
            continue
        why = _unsound(camera, rvecs, tvecs, obj, img, recomputed, rms, projector)
        if why:
            unsound.append(f'{init}: {why}')
            continue
        if unsound:
            retried.append((float(rms), len(retried), init, camera, rvecs, tvecs))
            continue
        return _adopt_attempt(result, init, camera, rms, rvecs, tvecs, raised)
    if retried:
        rms, _, init, camera, rvecs, tvecs = min(retried)
        _adopt_attempt(result, init, camera, rms, rvecs, tvecs, raised)
        others = [f'{i} ({r:.2f} px)' for r, _, i, *_ in retried if i != init]
        result.notes.append(f'retried from {init}: {"; ".join(unsound)}'
                            + (f'; its RMS is the lowest of the sound retries (also {", ".join(others)})'
                               if others else ''))
        return result
    result.ok = False
    if not unsound:
        result.error = f'{name} raised: ' + ' / then: '.join(m for _, m in raised)
    else:
        result.error = (f'{name} gave no sound camera: ' + ' / then: '.join(
            [f'{m} (not used)' for m in unsound] + [f'from {i}: raised {m}' for i, m in raised]))
    return result


def _adopt_attempt(result: CalibrationResult, init: str, camera, rms, rvecs, tvecs, raised) -> CalibrationResult:
    result.init = init
    result.camera, result.opencv_rms = camera, float(rms)
    result.rvecs, result.tvecs = rvecs, tvecs
    if raised:
        result.notes.append(f'implicit start raised: {raised[0][1]}')
    return result


class _NonFinite(Exception):
    pass


def calibrate_zhang(corners: CornerSet, views: Optional[Sequence[int]] = None,
                    flags: int = 0) -> CalibrationResult:
    """``cv2.calibrateCamera`` (plumb_bob) on ``views``; failures returned with ok=False.

    A result that is unsound (see RMS_CONTRADICTION_PX) is retried once with
    CALIB_USE_INTRINSIC_GUESS from the FC_eq.d. camera of the same views (its f, cx, cy, D = 0)."""
    views, report = _checked(corners, views)
    W, H = corners.width, corners.height
    result = CalibrationResult('zhang', views, init='opencv', duplicates=report.duplicates,
                               notes=report.notes)
    obj, img = _opencv_lists(corners, views, np.float32)
    obj64 = corners.object_points()
    pts = corners.corners[list(views)]

    def run(K0, D0, fl):
        rms, K, D, rvecs, tvecs = cv2.calibrateCamera(obj, img, (W, H), K0, D0, flags=fl)
        D = np.asarray(D, float).ravel()
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D)) and K[0, 0] > 0 and K[1, 1] > 0):
            raise _NonFinite()
        camera = PlumbBobCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H, D[:5] if D.size >= 5 else D)
        rvecs = np.array([np.ravel(r) for r in rvecs], float)
        tvecs = np.array([np.ravel(t) for t in tvecs], float)
        Kc, Dc = np.asarray(K, float), D
        recomputed = _cv_rms(lambda o, r, t: cv2.projectPoints(o, r, t, Kc, Dc)[0], obj64, pts, rvecs, tvecs)
        return camera, rms, rvecs, tvecs, recomputed, 'cv2.projectPoints'

    def from_fc():
        cam = _fc_start(corners, views)
        if cam is None:
            return None
        K0 = np.array([[cam.f, 0, cam.cx], [0, cam.f, cam.cy], [0, 0, 1]])
        return K0, np.zeros(5), flags | cv2.CALIB_USE_INTRINSIC_GUESS

    attempts = [('opencv', lambda: (None, None, flags), False),
                ('the FC_eq.d. camera of the same images (f, cx, cy; D = 0)', from_fc, True)]
    _run_attempts(result, attempts, run, 'cv2.calibrateCamera', obj64, pts)
    if result.ok:
        result.rms_px = _own_rms(result.camera, obj64, pts, result.rvecs, result.tvecs)
    return result


def _cv_message(exc) -> str:
    text = ' '.join(str(exc).split())
    if 'error: (' in text:
        text = text[text.index('error: (') + len('error: '):]
    return text


def calibrate_opencv_fisheye(corners: CornerSet, views: Optional[Sequence[int]] = None,
                             flags: Optional[int] = None) -> CalibrationResult:
    """``cv2.fisheye.calibrate`` (KB4) on ``views``; failures returned with ok=False.

    Starts: OpenCV's implicit one; if that raises, OpenCV's documented defaults made explicit.
    A result that is unsound (see RMS_CONTRADICTION_PX) is retried with USE_INTRINSIC_GUESS from
    the documented defaults (if not yet tried) and then from the FC_eq.d. camera of the same
    views (its f, cx, cy and k1..k4 fitted to it); a result still unsound is returned failed."""
    views, report = _checked(corners, views)
    if flags is None:
        flags = opencv_fisheye_flag('CALIB_RECOMPUTE_EXTRINSIC') | opencv_fisheye_flag('CALIB_FIX_SKEW')
    guess = flags | opencv_fisheye_flag('CALIB_USE_INTRINSIC_GUESS')
    W, H = corners.width, corners.height
    result = CalibrationResult('fisheye', views, init='opencv', duplicates=report.duplicates,
                               notes=report.notes)
    obj, img = _opencv_lists(corners, views, np.float64)
    obj64 = corners.object_points()
    pts = corners.corners[list(views)]
    f0 = max(W, H) / math.pi
    defaults = np.array([[f0, 0, (W - 1) / 2.0], [0, f0, (H - 1) / 2.0], [0, 0, 1]])

    def run(K0, D0, fl):
        rms, K, D, rvecs, tvecs = cv2.fisheye.calibrate(obj, img, (W, H), K0.copy(), D0.copy(), flags=fl)
        D = np.asarray(D, float).ravel()
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D)) and K[0, 0] > 0 and K[1, 1] > 0):
            raise _NonFinite()
        camera = KannalaBrandtCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H, D)
        rvecs = np.array([np.ravel(r) for r in rvecs], float)
        tvecs = np.array([np.ravel(t) for t in tvecs], float)
        Kc, Dc = np.asarray(K, float), D.reshape(4, 1)
        recomputed = _cv_rms(lambda o, r, t: cv2.fisheye.projectPoints(o.reshape(-1, 1, 3), r, t, Kc, Dc)[0],
                             obj64, pts, rvecs, tvecs)
        return camera, rms, rvecs, tvecs, recomputed, 'cv2.fisheye.projectPoints'

    def from_fc():
        cam = _fc_start(corners, views)
        if cam is None:
            return None
        from ..lens.fitting import fit_kannala_brandt
        capped = _DomainCappedCamera(cam.f, cam.cx, cam.cy, W, H, cam.omega, cam.projection)
        try:
            D0 = fit_kannala_brandt(capped).D
        except ValueError:
            D0 = np.zeros(4)
        K0 = np.array([[cam.f, 0, cam.cx], [0, cam.f, cam.cy], [0, 0, 1]])
        return K0, np.asarray(D0, float).reshape(4, 1), guess

    tried_defaults = []

    def explicit_defaults():
        tried_defaults.append(True)
        return defaults, np.zeros((4, 1)), guess

    def defaults_retry():
        return None if tried_defaults else (defaults, np.zeros((4, 1)), guess)

    attempts = [('opencv', lambda: (np.zeros((3, 3)), np.zeros((4, 1)), flags), False),
                ('opencv defaults made explicit (f = max(W, H) / pi, centred) after the implicit '
                 'start raised', explicit_defaults, False),
                ('opencv defaults made explicit (f = max(W, H) / pi, centred)', defaults_retry, True),
                ('the FC_eq.d. camera of the same images (f, cx, cy, k1..k4 fitted to it)', from_fc, True)]
    _run_attempts(result, attempts, run, 'cv2.fisheye.calibrate', obj64, pts)
    if result.ok:
        result.rms_px = _own_rms(result.camera, obj64, pts, result.rvecs, result.tvecs)
    return result


# ---------------------------------------------------------------------------------------------


def calibrate(corners: CornerSet, method: str = 'fc', views: Optional[Sequence[int]] = None,
              spec: Optional[CameraSpec] = None, principal_point: Optional[bool] = None,
              solution=None) -> CalibrationResult:
    """Run ``method`` (one of METHODS) on ``views`` of ``corners``. ``fc+zs`` needs ``spec``
    (``solution``: its zero-shot solution if already computed, see ``paper_zero_shot_camera``).

    Input errors raise CalibrationError / SpecError; numerical failures of a method come back as
    a result with ``ok=False``.
    """
    if method == 'fc':
        return calibrate_fc(corners, views, principal_point=principal_point)
    if method == 'fc+zs':
        if spec is None:
            raise CalibrationError('fc+zs needs a spec: give hfov / vfov / dfov')
        start, note = paper_zero_shot_camera(spec, corners.width, corners.height, solution)
        result = calibrate_fc(corners, views, start, 'zero-shot', principal_point, method='fc+zs')
        if note:
            result.notes.append(note)
        return result
    if method == 'zhang':
        return calibrate_zhang(corners, views)
    if method == 'fisheye':
        return calibrate_opencv_fisheye(corners, views)
    raise CalibrationError(f'method = {method!r} is invalid: allowed: {", ".join(METHODS)}')


class _SizeOnlySpec:
    """The spec of a calibration made without a spec sheet: size only, no FOV."""

    def __init__(self, width, height):
        self.width, self.height = width, height

    def given(self):
        return {}


@dataclass
class CalibratedSolution:
    """A calibrated ZeroShotCamera with ZeroShotSolution's interface, so that
    ``CameraCalibration.from_solution`` and ``solution_summary`` write the same YAML / JSON for
    ``calibrate`` as for ``solve``."""

    camera: ZeroShotCamera
    spec: object
    root_found: bool = True
    dfov_residuals: dict = field(default_factory=dict)

    @property
    def omega(self):
        return self.camera.omega

    @property
    def f(self):
        return self.camera.f

    @property
    def K(self):
        return self.camera.K

    @property
    def projection(self):
        return self.camera.projection

    def predicted_fovs(self):
        return self.camera.fields_of_view()


class _DomainCappedCamera(ZeroShotCamera):
    """A calibrated ZeroShotCamera whose ``max_field_angle`` stays inside the model's domain:
    when image corners are 90 degrees or more off-axis (NaN in the model), the largest angle is
    just below 90 degrees, so ``fit_kannala_brandt`` fits the whole range the model defines
    (and the fitted polynomial extrapolates beyond it)."""

    def max_field_angle(self) -> float:
        angle = super().max_field_angle()
        return angle if math.isfinite(angle) else math.pi / 2 * (1 - 1e-9)

    def beyond_domain(self) -> bool:
        return not math.isfinite(super().max_field_angle())


def as_solution(result: CalibrationResult, spec: Optional[CameraSpec] = None) -> CalibratedSolution:
    """The FC result as a solution object (see CalibratedSolution)."""
    if not result.ok or not isinstance(result.camera, ZeroShotCamera):
        raise CalibrationError(f'{result.label} did not produce a ZeroShotCamera: {result.error}')
    cam = result.camera
    capped = _DomainCappedCamera(cam.f, cam.cx, cam.cy, cam.width, cam.height, cam.omega, cam.projection)
    return CalibratedSolution(capped, spec if spec is not None else _SizeOnlySpec(cam.width, cam.height))
