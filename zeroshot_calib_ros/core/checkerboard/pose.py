"""Board poses seen through any camera model: robust PnP plus refinement in pixels.

One concept: given a camera (any ``CameraModel``), the board's object points and the detected
corners of one or many images, find each image's extrinsics (rvec, tvec) that minimise the
reprojection error in pixels *through the camera model*.

- Start poses come from PnP on normalised points with an identity K (the paper's sec. 3.2:
  PnP on ``K^-1 p``, generalised to ``camera.undistort(p)``). Every available solver (EPnP,
  iterative, SQPnP, IPPE, with all the solutions ``cv2.solvePnPGeneric`` returns) is tried on
  the model's undistorted points and on the plain pinhole ``K^-1 p`` points, so one bad EPnP
  solution or a model that cannot undistort some points never decides an image's pose.
- Every start pose is refined by a batched Levenberg-Marquardt on the pixel reprojection error
  (all poses of all images at once, 6x6 normal equations per pose), and per image the pose with
  the lowest error is kept.

Points a model cannot project (NaN, e.g. rays 90 degrees or more off-axis for the paper's model)
count as ``UNPROJECTABLE_PENALTY_PX`` in the refinement and are reported, never dropped.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import cv2
import numpy as np

from ..lens.models import CameraModel, PinholeCamera

PNP_SOLVERS = tuple(name for name in ('EPNP', 'ITERATIVE', 'SQPNP', 'IPPE')
                    if hasattr(cv2, f'SOLVEPNP_{name}'))
"""cv2.solvePnP methods tried for start poses (those this OpenCV build has)."""

MIN_PNP_POINTS = 4
UNPROJECTABLE_PENALTY_PX = 1000.0
"""Residual (px, per coordinate) of a point the camera model cannot project."""


def rodrigues(rvecs) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3), vectorised cv2.Rodrigues."""
    r = np.asarray(rvecs, dtype=float)
    theta2 = np.sum(r * r, axis=-1)[..., None, None]
    theta = np.sqrt(theta2)
    small = theta2 < 1e-12
    if not small.any():  # the usual case, the same numbers without the guards (a pose solve's hot path)
        a = np.sin(theta) / theta
        b = (1.0 - np.cos(theta)) / theta2
    else:
        safe = np.where(small, 1.0, theta)
        a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
        b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / np.where(small, 1.0, theta2))
    kx = np.zeros(r.shape[:-1] + (3, 3))  # the cross-product matrix of r
    kx[..., 0, 1], kx[..., 0, 2], kx[..., 1, 2] = -r[..., 2], r[..., 1], -r[..., 0]
    kx[..., 1, 0], kx[..., 2, 0], kx[..., 2, 1] = r[..., 2], -r[..., 1], r[..., 0]
    return np.eye(3) + a * kx + b * (kx @ kx)


def transform(rvecs, tvecs, points) -> np.ndarray:
    """Board points (M, 3) into the camera frames of poses (..., 3): (..., M, 3)."""
    R = rodrigues(rvecs)
    return np.asarray(points, dtype=float) @ np.swapaxes(R, -1, -2) \
        + np.asarray(tvecs, dtype=float)[..., None, :]


def _residuals(camera: CameraModel, obj, img, poses):
    """(K, M, 2) projected minus observed, NaN where the model cannot project."""
    return camera.project(transform(poses[:, :3], poses[:, 3:], obj)) - img


def _penalised(res):
    return np.where(np.isfinite(res), res, UNPROJECTABLE_PENALTY_PX)


def refine_poses(camera: CameraModel, object_points, image_points, rvecs, tvecs,
                 max_iterations: int = 60, tol: float = 1e-10):
    """Batched Levenberg-Marquardt of K poses on the pixel error through ``camera``.

    ``object_points`` (M, 3); ``image_points`` (K, M, 2) (the observed corners of the image
    each pose belongs to); ``rvecs``, ``tvecs`` (K, 3). Returns refined (rvecs, tvecs) and the
    per-pose sum of squared (penalised) residuals.
    """
    obj = np.asarray(object_points, dtype=float)
    img = np.asarray(image_points, dtype=float)
    poses = np.concatenate([np.asarray(rvecs, float).reshape(-1, 3),
                            np.asarray(tvecs, float).reshape(-1, 3)], axis=1)
    n = poses.shape[0]
    if n == 0:
        return poses[:, :3], poses[:, 3:], np.zeros(0)
    res = _penalised(_residuals(camera, obj, img, poses)).reshape(n, -1)
    cost = np.sum(res * res, axis=1)
    lam = np.full(n, 1e-3)
    active = np.ones(n, dtype=bool)
    eye = np.eye(6)
    for _ in range(max_iterations):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        p, r = poses[idx], res[idx]
        # central differences, the 12 stepped copies of every pose in one call (a call per
        # parameter was most of the cost of small boards: per-call overhead, not arithmetic)
        h = 1e-6 * np.maximum(1.0, np.abs(p))
        steps = np.zeros((6,) + p.shape)
        steps[np.arange(6), :, np.arange(6)] = h.T
        stepped = np.concatenate([p + steps, p - steps]).reshape(-1, 6)
        both = _residuals(camera, obj, np.tile(img[idx], (12, 1, 1)), stepped).reshape(2, 6, idx.size, -1)
        d = (both[0] - both[1]) / (2 * h.T[:, :, None])
        jac = np.moveaxis(np.where(np.isfinite(d), d, 0.0), 0, -1)
        jt = np.swapaxes(jac, 1, 2)
        A = jt @ jac
        g = (jt @ r[..., None])[..., 0]
        diag = np.einsum('kii->ki', A)
        damped = A + (lam[idx, None] * np.maximum(diag, 1e-12))[:, :, None] * eye
        try:
            step = np.linalg.solve(damped, -g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = np.stack([np.linalg.lstsq(m, -v, rcond=None)[0] for m, v in zip(damped, g)])
        trial = p + step
        new_res = _penalised(_residuals(camera, obj, img[idx], trial)).reshape(idx.size, -1)
        new_cost = np.sum(new_res * new_res, axis=1)
        better = np.isfinite(new_cost) & (new_cost < cost[idx])
        gain = np.where(better, cost[idx] - new_cost, 0.0)
        good = idx[better]
        poses[good], res[good], cost[good] = trial[better], new_res[better], new_cost[better]
        lam[good] = np.maximum(lam[good] / 3.0, 1e-12)
        lam[idx[~better]] *= 8.0
        small_step = np.linalg.norm(step, axis=1) <= tol * (1.0 + np.linalg.norm(p, axis=1))
        converged = (better & (gain <= tol * np.maximum(cost[idx], 1e-30))) | small_step \
            | (lam[idx] > 1e12)
        active[idx[converged]] = False
    return poses[:, :3], poses[:, 3:], cost


def _distinct(candidates, tol: float = 1e-3) -> list:
    """Drop start poses within ``tol`` (rad, relative translation) of an earlier one: they
    refine to the same pose."""
    kept = []
    for r, t in candidates:
        if not any(np.linalg.norm(r - r2) < tol
                   and np.linalg.norm(t - t2) < tol * (np.linalg.norm(t2) + 1e-12) for r2, t2 in kept):
            kept.append((r, t))
    return kept


def pnp_candidates(object_points, normalised) -> list:
    """Start poses (rvec, tvec) from every PnP solver on normalised points (identity K).

    Non-finite points are left out; fewer than MIN_PNP_POINTS finite points give no candidate.
    """
    obj = np.asarray(object_points, dtype=np.float64)
    pts = np.asarray(normalised, dtype=np.float64)
    ok = np.all(np.isfinite(pts), axis=-1)
    if np.count_nonzero(ok) < MIN_PNP_POINTS:
        return []
    o = np.ascontiguousarray(obj[ok]).reshape(-1, 1, 3)
    q = np.ascontiguousarray(pts[ok]).reshape(-1, 1, 2)
    out = []
    for name in PNP_SOLVERS:
        try:
            found, rvecs, tvecs, _ = cv2.solvePnPGeneric(o, q, np.eye(3), None,
                                                         flags=getattr(cv2, f'SOLVEPNP_{name}'))
        except cv2.error:
            continue
        if not found:
            continue
        for rv, tv in zip(rvecs, tvecs):
            rv, tv = np.asarray(rv, float).ravel(), np.asarray(tv, float).ravel()
            if rv.size == 3 and tv.size == 3 and np.all(np.isfinite(rv)) and np.all(np.isfinite(tv)):
                out.append((rv, tv))
    return out


@dataclass
class BoardPoses:
    """Per image: the refined pose and its residuals through the camera."""

    rvecs: np.ndarray
    """(n, 3)"""
    tvecs: np.ndarray
    """(n, 3)"""
    residuals: np.ndarray
    """(n, M, 2) projected minus detected (px); NaN where the model cannot project."""
    found: np.ndarray
    """(n,) False where no start pose could be made (no PnP solution at all)."""

    @property
    def errors(self) -> np.ndarray:
        """(n, M) point distances in px; UNPROJECTABLE_PENALTY_PX * sqrt(2) where not projectable,
        inf where no pose was found."""
        d = np.hypot(self.residuals[..., 0], self.residuals[..., 1])
        d = np.where(np.isfinite(d), d, UNPROJECTABLE_PENALTY_PX * np.sqrt(2.0))
        return np.where(self.found[:, None], d, np.inf)

    @property
    def unprojectable(self) -> int:
        """Number of points (of images with a pose) the model could not project."""
        bad = ~np.all(np.isfinite(self.residuals), axis=-1)
        return int(np.count_nonzero(bad & self.found[:, None]))


def board_poses(camera: CameraModel, object_points, image_points,
                initial: Optional[Sequence] = None) -> BoardPoses:
    """Robust per-image extrinsics of ``image_points`` (n, M, 2) through ``camera``.

    ``initial``: optional extra start poses, one (rvec, tvec) per image (e.g. the calibration's
    own extrinsics), tried alongside the PnP candidates.
    """
    obj = np.asarray(object_points, dtype=float)
    img = np.asarray(image_points, dtype=float)
    n = img.shape[0]
    pinhole = PinholeCamera(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        undistorted = camera.undistort(img)
        normalised = pinhole.undistort(img)
    owner, rv, tv = [], [], []
    for i in range(n):
        cands = pnp_candidates(obj, undistorted[i]) + pnp_candidates(obj, normalised[i])
        if initial is not None and initial[i] is not None:
            r0, t0 = initial[i]
            cands.append((np.asarray(r0, float).ravel(), np.asarray(t0, float).ravel()))
        for r, t in _distinct(cands):
            owner.append(i)
            rv.append(r)
            tv.append(t)
    owner = np.asarray(owner, dtype=int)
    rvecs = np.zeros((n, 3))
    tvecs = np.zeros((n, 3))
    found = np.zeros(n, dtype=bool)
    if owner.size:
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            r_ref, t_ref, cost = refine_poses(camera, obj, img[owner], np.array(rv), np.array(tv))
        for i in range(n):
            mine = np.flatnonzero(owner == i)
            if mine.size:
                best = mine[np.argmin(cost[mine])]
                rvecs[i], tvecs[i], found[i] = r_ref[best], t_ref[best], True
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        residuals = camera.project(transform(rvecs, tvecs, obj)) - img
    residuals[~found] = np.nan
    return BoardPoses(rvecs, tvecs, residuals, found)
