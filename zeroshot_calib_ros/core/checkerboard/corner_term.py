"""The checkerboard-corner evidence term: detected corners against the board seen through a camera.

Residual: for every image i and corner j, detected pixel minus the projection of the board point
through the candidate camera at the image's board pose, two numbers per corner, in pixels (the
detector's noise is in pixels; this is FC's residual, ``calibration._FcProblem``, for any camera
model).

Board poses are nuisance parameters, ELIMINATED per evaluation (variable projection, as
``core.lines.straightness`` eliminates its planes): ``residuals(camera)`` first solves every
image's pose (rvec, tvec) for the current camera by Gauss-Newton on the same pixel residuals
(all images batched, central-difference pose Jacobians, step halving), warm-started from the
poses of the previous evaluation (the first from ``pose.board_poses``: robust PnP through the
camera), to convergence (step below ``POSE_TOL``). The residuals are then those of the reduced
problem r(c, p*(c)), so a finite-difference Jacobian with respect to the camera alone is the
reduced problem's Jacobian and the covariance of a fit accounts for the poses. Why not append
the poses to the parameter vector: the estimator's layouts map a vector to a camera and every
term sees only the camera (``core.estimation.problem``); elimination keeps that contract, and a
single or a few images cost 6 parameters each in a 6 x 6 solve per image.

Bent boards (``bend=True``): each view's board may also sag out of its plane by a quadratic
z = b1 s^2 + b2 s q + b3 q^2 of the board position (s, q in [-1, 1]), its 3 coefficients
eliminated with the pose (9 x 9 solves). A board held by hand or printed on card is not flat to
the tenth of a pixel that the corners measure: 0.5 % of the diagonal (2 mm on a 43 cm board) puts
the corners of a wide lens a pixel off, and one view cannot tell that from a camera with another
principal point or distortion. With the bend the corners say nothing about the camera that a
sag could also explain (the spec and the priors decide there), so a flat board gives a little
less and a bent one no longer misleads; ``sag()`` reports how bent each board was
(``board_fit.BOARD_BEND`` has the measurements).

Rejected corners (``weights`` 0) leave both the pose solve and the residuals (their residuals
are 0). Points the camera cannot project (NaN) count ``invalid_px`` per coordinate.

The term follows the estimation package's term interface (``name``, ``residuals(camera)``
unwhitened, ``sigma``, ``loss``, ``loss_scale``, ``group``) without importing it: core/checkerboard
sits below core/estimation.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..lens.models import CameraModel
from .pose import board_poses, transform

INVALID_PX = 50.0
"""Residual (px per coordinate) of a corner the camera cannot project."""
POSE_TOL = 1e-11
"""Gauss-Newton on the poses stops when every step is below this (rad; relative for t)."""
POSE_ITERATIONS = 30


def _bend_basis(obj: np.ndarray) -> np.ndarray:
    """(M, 3) out-of-plane shapes of a bent board at its points: s^2, s q, q^2 of the board
    position (s, q in [-1, 1] over the board's span) less their least-squares plane over the
    points (a plane is the pose's: without it the bend and the pose's distance and tilt trade
    off, and Gauss-Newton on the poses crawls), times the span's half diagonal (a coefficient is
    then of the order of the sag it makes, in the board's units)."""
    lo, span = obj[:, :2].min(axis=0), np.ptp(obj[:, :2], axis=0)
    s, q = ((obj[:, :2] - lo) / np.where(span > 0, span, 1.0) * 2.0 - 1.0).T
    shapes = np.stack([s * s, s * q, q * q], axis=1)
    plane = np.stack([np.ones_like(s), s, q], axis=1)
    shapes = shapes - plane @ np.linalg.lstsq(plane, shapes, rcond=None)[0]
    return shapes * (0.5 * float(np.hypot(*span)))


class CornerTerm:
    """Pixel residuals of checkerboard corners with the board poses eliminated (module docstring).

    ``object_points`` (M, 3) board points; ``image_points`` (n, M, 2) detected corners;
    ``sigma``: corner noise per coordinate (px); ``loss`` / ``loss_scale``: the robust loss per
    corner (both coordinates together), in sigmas; ``weights`` (n, M): 0 leaves a corner out."""

    name = 'corners'
    group = 2

    def __init__(self, object_points, image_points, sigma: float = 0.5, loss: Optional[str] = 'soft_l1',
                 loss_scale: float = 3.0, weights=None, invalid_px: float = INVALID_PX, poses=None,
                 bend: bool = False):
        self.obj = np.asarray(object_points, dtype=float).reshape(-1, 3)
        self.img = np.asarray(image_points, dtype=float).reshape(-1, len(self.obj), 2)
        if self.img.shape[0] == 0:
            raise ValueError('no images: a corner term needs at least one')
        if len(self.obj) < 4:
            raise ValueError(f'{len(self.obj)} board points: a corner term needs at least 4')
        self.n, self.m = self.img.shape[:2]
        self.weights = (np.ones((self.n, self.m)) if weights is None
                        else np.asarray(weights, dtype=float).reshape(self.n, self.m).copy())
        self.sigma = float(sigma)
        self.loss = loss
        self.loss_scale = float(loss_scale)
        self.invalid_px = float(invalid_px)
        self.bend = bool(bend)
        self._bend_basis = _bend_basis(self.obj) if self.bend else np.zeros((self.m, 0))
        self.k = 6 + self._bend_basis.shape[1]
        if poses is not None:  # (n, 6) poses of a flat board start a bent one flat
            poses = np.asarray(poses, dtype=float).reshape(self.n, -1)
            poses = np.hstack([poses[:, :6], np.zeros((self.n, self.k - 6))]) if poses.shape[1] != self.k else poses.copy()
        self._poses = poses

    def copy(self, sigma: Optional[float] = None, weights=None) -> 'CornerTerm':
        """The same corners with another sigma / weights (and the current poses as the start)."""
        return CornerTerm(self.obj, self.img, self.sigma if sigma is None else sigma, self.loss,
                          self.loss_scale, self.weights if weights is None else weights, self.invalid_px,
                          self._poses, self.bend)

    # -- poses ----------------------------------------------------------------------------------
    def _points(self, poses):
        """(K, M, 3) the board points of ``poses`` (K, k) in their camera frames."""
        obj = self.obj
        if self.bend:  # each view's board raised out of its plane (z) by its sag
            obj = obj + (poses[:, 6:] @ self._bend_basis.T)[..., None] * np.array([0.0, 0.0, 1.0])
        return transform(poses[:, :3], poses[:, 3:6], obj)

    def _raw(self, camera, poses):
        """(K, M, 2) detected minus projected through ``poses`` (K, k), weighted, NaN kept."""
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            projected = camera.project(self._points(poses))
        return (self.img - projected) * self.weights[..., None]

    def _penalised(self, camera, poses):
        r = self._raw(camera, poses)
        return np.where(np.isfinite(r), r, self.invalid_px)

    def _start_poses(self, camera) -> np.ndarray:
        if self._poses is not None:
            return self._poses.copy()
        found = board_poses(camera, self.obj, self.img)
        return np.hstack([found.rvecs, found.tvecs, np.zeros((self.n, self.k - 6))])

    def solve_poses(self, camera: CameraModel) -> np.ndarray:
        """(n, k) rvec, tvec (and with ``bend`` the 3 bend coefficients) of every image minimising
        its pixel residuals through ``camera``."""
        poses = self._start_poses(camera)
        r = self._penalised_rows(camera, poses, np.arange(self.n))
        cost = np.sum(r * r, axis=1)
        active = np.ones(self.n, dtype=bool)
        for _ in range(POSE_ITERATIONS):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            p = poses[idx]
            k = self.k
            h = 1e-6 * np.maximum(1.0, np.abs(p))
            plus = p[:, None, :] + np.eye(k)[None] * h[:, None, :]
            minus = p[:, None, :] - np.eye(k)[None] * h[:, None, :]
            both = np.concatenate([plus, minus], axis=1).reshape(-1, k)
            img = self.img[idx]
            with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
                proj = camera.project(self._points(both)).reshape(idx.size, 2 * k, self.m, 2)
            w = self.weights[idx][:, None, :, None]
            res = np.where(np.isfinite(proj), (img[:, None] - proj) * w, self.invalid_px)
            J = ((res[:, :k] - res[:, k:]) / (2 * h[:, :, None, None])).reshape(idx.size, k, -1)
            J = np.swapaxes(J, 1, 2)  # (views, 2M, k): d residual / d pose
            A = np.swapaxes(J, 1, 2) @ J
            g = (np.swapaxes(J, 1, 2) @ r[idx][..., None])[..., 0]
            A = A + 1e-12 * np.einsum('kii->ki', A)[:, :, None] * np.eye(k)
            try:
                step = -np.linalg.solve(A, g[..., None])[..., 0]
            except np.linalg.LinAlgError:
                step = -np.stack([np.linalg.lstsq(a, b, rcond=None)[0] for a, b in zip(A, g)])
            done = np.zeros(idx.size, dtype=bool)
            scale = np.ones(idx.size)
            for _half in range(8):
                todo = np.flatnonzero(~done)  # only the views still halving their step are evaluated
                trial = p[todo] + scale[todo, None] * step[todo]
                new_r = self._penalised_rows(camera, trial, idx[todo])
                new_cost = np.sum(new_r * new_r, axis=1)
                better = new_cost <= cost[idx[todo]] * (1 + 1e-12) + 1e-300
                take = idx[todo[better]]
                poses[take] = trial[better]
                r[take] = new_r[better]
                cost[take] = new_cost[better]
                done[todo[better]] = True
                if np.all(done):
                    break
                scale = np.where(done, scale, 0.5 * scale)
            tol = POSE_TOL * np.c_[np.ones((idx.size, 3)),
                                   np.repeat(np.maximum(1.0, np.linalg.norm(p[:, 3:6], axis=1))[:, None], k - 3, 1)]
            small = np.all(np.abs(scale[:, None] * step) <= tol, axis=1)
            active[idx[small | ~done]] = False
        self._poses = poses.copy()
        return poses

    def _penalised_rows(self, camera, poses, idx):
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            projected = camera.project(self._points(poses))
        r = (self.img[idx] - projected) * self.weights[idx][..., None]
        return np.where(np.isfinite(r), r, self.invalid_px).reshape(len(idx), -1)

    # -- residuals ------------------------------------------------------------------------------
    def squared_distances(self, camera: CameraModel) -> np.ndarray:
        """Squared distance (px^2) of every corner in use (not rejected) that ``camera`` projects."""
        r = self.point_residuals(camera)
        d2 = np.sum(r * r, axis=-1)[self.weights > 0]
        return d2[np.isfinite(d2)]

    def noise_dof(self, points: int) -> int:
        """Degrees of freedom of ``points`` such distances beside the camera: two a corner (its
        coordinates), less each view's eliminated numbers (``k``: 6 for the pose, 9 with the bend)."""
        return 2 * points - self.k * self.n

    def point_residuals(self, camera: CameraModel) -> np.ndarray:
        """(n, M, 2) detected minus projected at the eliminated poses; NaN where not projectable;
        rejected corners included (unweighted), so that they can be judged."""
        poses = self.solve_poses(camera)
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            projected = camera.project(self._points(poses))
        return self.img - projected

    def residuals(self, camera: CameraModel) -> np.ndarray:
        """Unwhitened residuals (2 n M,), px; rejected corners 0, unprojectable ``invalid_px``."""
        return self._penalised(camera, self.solve_poses(camera)).ravel()

    def rms(self, camera: CameraModel) -> float:
        """RMS corner distance (px) over the corners in use; inf when one cannot be projected."""
        d2 = np.sum(self.point_residuals(camera) ** 2, axis=-1)[self.weights > 0]
        return float(np.sqrt(np.mean(d2))) if np.all(np.isfinite(d2)) else float('inf')

    # -- systematic errors (uncertainty.systematic_covariance) ---------------------------------
    systematic_modes_text = 'every board view allowed a smooth systematic error (6 shapes per coordinate)'

    def systematic_modes(self) -> np.ndarray:
        """(2 n M, 12) per residual (the order of ``residuals``), the smooth shapes of a systematic
        error of its view's detected grid (a shift, a tilt, a bow: a detector biased under strong
        distortion, a board not flat): per coordinate 1, s, q, s^2, s q, q^2 of the corner's board
        position (s, q in [-1, 1]), each scaled to 1 px RMS over the board, zero at rejected
        corners."""
        span = np.ptp(self.obj[:, :2], axis=0)
        s, q = ((self.obj[:, :2] - self.obj[:, :2].min(axis=0)) / np.where(span > 0, span, 1.0) * 2.0 - 1.0).T
        scalar = np.stack([np.ones_like(s), s, q, s * s, s * q, q * q], axis=1)
        scalar = scalar / np.sqrt(np.mean(scalar * scalar, axis=0))
        K = scalar.shape[1]
        B = np.zeros((2 * self.m, 2 * K))
        B[0::2, :K] = scalar
        B[1::2, K:] = scalar
        w = np.repeat(self.weights, 2, axis=1)
        return (B[None] * w[:, :, None]).reshape(2 * self.n * self.m, 2 * K)

    def residual_clusters(self) -> np.ndarray:
        """The view of each residual (2 n M,): errors shared over a board view are one cluster."""
        return np.repeat(np.arange(self.n), 2 * self.m)

    @property
    def poses(self) -> Optional[np.ndarray]:
        """(n, 6) rvec, tvec of the last evaluation (None before the first)."""
        return None if self._poses is None else self._poses[:, :6].copy()

    @property
    def bends(self) -> Optional[np.ndarray]:
        """(n, 3) the bend coefficients of every board (``_bend_basis``) of the last evaluation;
        None before the first or without ``bend``."""
        return None if self._poses is None or not self.bend else self._poses[:, 6:].copy()

    def sag(self) -> np.ndarray:
        """(n,) how far each board of the last evaluation is from flat: the largest distance of a
        corner from the plane that fits the bent board's corners best, in the board's units
        (metres); zeros without ``bend``."""
        if self._poses is None or not self.bend:
            return np.zeros(self.n)
        # the basis has no plane part over the corners (``_bend_basis``): the sag is its height
        return np.abs(self._poses[:, 6:] @ self._bend_basis.T).max(axis=1)

    @property
    def corners_used(self) -> int:
        return int(np.count_nonzero(self.weights > 0))
