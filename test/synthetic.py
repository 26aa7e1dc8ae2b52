"""Synthetic images rendered through a known camera, for tests that need pixels."""
import cv2
import numpy as np


def render_checkerboard(camera, squares=(12, 6), extent=(2.4, 1.1), supersample=3):
    """A checkerboard on the plane z = 1 (centred, ``extent`` wide and high) seen by ``camera``,
    grey 128 elsewhere; anti-aliased by ``supersample``^2 rays per pixel. Returns (image,
    inner-corner plane points (rows, cols, 2) in OpenCV's row-major order)."""
    w, h = camera.width, camera.height
    sx, sy = squares
    size = extent[0] / sx
    acc = np.zeros((h, w))
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    for du in offsets:
        for dv in offsets:
            rays = camera.unproject(np.stack([u + du, v + dv], axis=-1))
            with np.errstate(invalid='ignore', divide='ignore'):
                X = rays[..., 0] / rays[..., 2] + extent[0] / 2
                Y = rays[..., 1] / rays[..., 2] + extent[1] / 2
                ix, iy = np.floor(X / size), np.floor(Y / size)
                inside = (rays[..., 2] > 0) & (ix >= 0) & (ix < sx) & (iy >= 0) & (iy < sy)
            acc += np.where(inside, np.where((ix + iy) % 2 == 0, 30.0, 225.0), 128.0)
    image = np.clip(np.round(acc / supersample ** 2), 0, 255).astype(np.uint8)
    gx = (np.arange(1, sx) * size) - extent[0] / 2
    gy = (np.arange(1, sy) * size) - extent[1] / 2
    corners = np.stack(np.meshgrid(gx, gy), axis=-1)
    return image, corners


def find_corners(image, squares=(12, 6)):
    """Sub-pixel inner corners (rows, cols, 2), or None."""
    pattern = (squares[0] - 1, squares[1] - 1)
    found, corners = cv2.findChessboardCorners(image, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH)
    if not found:
        return None
    corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4))
    corners = corners.reshape(pattern[1], pattern[0], 2)
    if corners[0, 0, 0] > corners[0, -1, 0]:  # OpenCV may start from the other end
        corners = corners[:, ::-1]
    if corners[0, 0, 1] > corners[-1, 0, 1]:
        corners = corners[::-1]
    return corners


def line_residuals(corners):
    """Distances (px) of each grid row's and column's corners from their best-fit straight line."""
    out = []
    for line in list(corners) + list(corners.transpose(1, 0, 2)):
        centred = line - line.mean(axis=0)
        normal = np.linalg.svd(centred)[2][-1]
        out.append(centred @ normal)
    return np.abs(np.concatenate(out))
