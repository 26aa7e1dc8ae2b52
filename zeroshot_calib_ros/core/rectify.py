"""Rectification to a pinhole camera, with maps computed from the exact camera model."""
from __future__ import annotations

from typing import Optional, Tuple

import cv2
import numpy as np

from .camera_models import CameraModel

INTERPOLATIONS = {0: cv2.INTER_NEAREST, 1: cv2.INTER_LINEAR, 2: cv2.INTER_CUBIC, 4: cv2.INTER_LANCZOS4}
"""image_proc's ``interpolation`` values (3, area, has no remap equivalent)."""

_MAP_ROWS_PER_CHUNK = 128  # bounds the float64 temporaries to ~ 128 x width x 3 x 8 bytes


def new_camera_matrix(camera: CameraModel, balance: float = 0.0, fov_scale: float = 1.0,
                      new_size: Optional[Tuple[int, int]] = None) -> np.ndarray:
    """The rectified pinhole camera, with the meaning cv2.fisheye.estimateNewCameraMatrixForUndistortRectify
    gives ``balance`` (0: focal of the tightest edge, no black border; 1: the whole image edge-to-edge
    is kept) and ``fov_scale`` (divides the focal length), computed with ``camera``'s exact model.
    """
    if not 0.0 <= balance <= 1.0:
        raise ValueError(f'balance = {balance!r} is invalid: allowed: 0 to 1')
    if not fov_scale > 0.0 or not np.isfinite(fov_scale):
        raise ValueError(f'fov_scale = {fov_scale!r} is invalid: allowed: greater than 0')
    w, h = camera.width, camera.height
    # The edge midpoints, with OpenCV's integer division of the size.
    edges = np.array([[w // 2, 0], [w, h // 2], [w // 2, h], [0, h // 2]], dtype=float)
    pts = camera.undistort(edges)
    if not np.all(np.isfinite(pts)):
        raise ValueError('the image edges are 90 degrees or more off-axis: no pinhole camera can show them')
    cn = pts.mean(axis=0)
    aspect = camera.fx / camera.fy
    cn[0] *= aspect  # sic: OpenCV scales cn[0] but the points' y; kept for identical results
    pts[:, 1] *= aspect
    minx, miny = pts.min(axis=0)
    maxx, maxy = pts.max(axis=0)
    focals = [w * 0.5 / (cn[0] - minx), w * 0.5 / (maxx - cn[0]),
              h * 0.5 * aspect / (cn[1] - miny), h * 0.5 * aspect / (maxy - cn[1])]
    f = balance * min(focals) + (1.0 - balance) * max(focals)
    f /= fov_scale
    new_f = np.array([f, f / aspect])
    new_c = -cn * f + np.array([w, h * aspect]) * 0.5
    new_c[1] /= aspect
    if new_size is not None:
        scale = np.array([new_size[0] / w, new_size[1] / h])
        new_f, new_c = new_f * scale, new_c * scale
    return np.array([[new_f[0], 0.0, new_c[0]], [0.0, new_f[1], new_c[1]], [0.0, 0.0, 1.0]])


def rectification_maps(camera: CameraModel, P: np.ndarray, size: Tuple[int, int],
                       R: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Fixed-point maps (CV_16SC2 + CV_16UC1 interpolation table, as cv2.initUndistortRectifyMap
    gives image_proc) sending each pixel of the rectified image (camera matrix P[:3, :3], rotation
    R) to where ``camera`` saw it. Pixels whose ray the camera cannot see map outside the image."""
    width, height = size
    Pinv = np.linalg.inv(np.asarray(P, dtype=float)[:3, :3])
    M = Pinv if R is None else np.asarray(R, dtype=float).T @ Pinv
    map1 = np.empty((height, width, 2), np.int16)
    map2 = np.empty((height, width), np.uint16)
    u = np.arange(width, dtype=float)
    for top in range(0, height, _MAP_ROWS_PER_CHUNK):
        v = np.arange(top, min(top + _MAP_ROWS_PER_CHUNK, height), dtype=float)
        uu, vv = np.meshgrid(u, v)
        rays = np.stack([uu, vv, np.ones_like(uu)], axis=-1) @ M.T
        pix = camera.project(rays).astype(np.float32)
        pix[~np.isfinite(pix)] = -1e4  # unseen: sample the constant border
        np.clip(pix, -1e4, 3e4, out=pix)  # keep within int16 after fixed-point conversion
        m1, m2 = cv2.convertMaps(np.ascontiguousarray(pix[..., 0]), np.ascontiguousarray(pix[..., 1]),
                                 cv2.CV_16SC2)
        map1[top:top + len(v)] = m1
        map2[top:top + len(v)] = m2
    return map1, map2


class Rectifier:
    """Undistorts images of ``camera`` into the pinhole camera ``P``; maps are built once.

    ``rectify`` writes into a caller-provided buffer when given one, so a stream of frames
    costs one cv2.remap each and no allocation.
    """

    def __init__(self, camera: CameraModel, balance: float = 0.0, fov_scale: float = 1.0,
                 interpolation: int = 1, P: Optional[np.ndarray] = None):
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f'interpolation = {interpolation!r} is invalid: allowed: 0 (nearest), '
                             '1 (linear), 2 (cubic), 4 (lanczos4)')
        self.camera = camera
        self.P = new_camera_matrix(camera, balance, fov_scale) if P is None else np.asarray(P, float)[:3, :3]
        self.size = (camera.width, camera.height)
        self.interpolation = INTERPOLATIONS[interpolation]
        self.map1, self.map2 = rectification_maps(camera, self.P, self.size)

    def rectify(self, image: np.ndarray, out: Optional[np.ndarray] = None) -> np.ndarray:
        h, w = image.shape[:2]
        if (w, h) != self.size:
            raise ValueError(f'image is {w}x{h}, the rectifier was built for {self.size[0]}x{self.size[1]}')
        return cv2.remap(image, self.map1, self.map2, self.interpolation, dst=out,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
