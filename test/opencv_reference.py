"""Independent references computed with OpenCV only (no zeroshot_calib_ros code): the paper's
eq. 20 RMS reprojection error of a camera given as OpenCV K, D, and textured test images.

Used by tests that check what our CLI prints against numbers it did not compute itself.
"""
import cv2
import numpy as np
from scipy.optimize import least_squares


def _project(model, obj, rvec, tvec, K, D):
    if model == 'equidistant':
        pts, _ = cv2.fisheye.projectPoints(obj.reshape(-1, 1, 3), rvec.reshape(3, 1), tvec.reshape(3, 1),
                                           K, D.reshape(4, 1))
    else:
        pts, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, D)
    return pts.reshape(-1, 2)


def _undistort(model, pixels, K, D):
    pixels = np.ascontiguousarray(pixels, np.float64).reshape(-1, 1, 2)
    if model == 'equidistant':
        return cv2.fisheye.undistortPoints(pixels, K, D.reshape(4, 1)).reshape(-1, 2)
    return cv2.undistortPoints(pixels, K, D).reshape(-1, 2)


def board_points(cols, rows, square):
    """Inner corners of a cols x rows board in OpenCV's row-major order, z = 0."""
    return np.array([[c * square, r * square, 0.0] for r in range(rows) for c in range(cols)])


def eq20_squared_errors(model, K, D, obj, views):
    """(n_views, M) squared pixel errors of the best pose of each view: PnP (every solution of
    IPPE, and SQPnP) on OpenCV's undistorted points, each refined by Levenberg-Marquardt on the
    pixel error through cv2(.fisheye).projectPoints, the smallest error kept."""
    K = np.asarray(K, np.float64)
    D = np.asarray(D, np.float64).ravel()
    out = []
    for pixels in views:
        normalised = _undistort(model, pixels, K, D)
        starts = []
        ok = np.all(np.isfinite(normalised), axis=1)
        for flag in (cv2.SOLVEPNP_IPPE, cv2.SOLVEPNP_SQPNP):
            try:
                n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj[ok], normalised[ok], np.eye(3), None, flags=flag)
            except cv2.error:
                continue
            starts += [np.r_[np.ravel(r), np.ravel(t)] for r, t in zip(rvecs[:n], tvecs[:n])]
        best = None
        for x0 in starts:
            fit = least_squares(lambda x: (_project(model, obj, x[:3], x[3:], K, D) - pixels).ravel(), x0,
                                method='lm', xtol=1e-14, ftol=1e-14)
            sq = np.sum(fit.fun.reshape(-1, 2) ** 2, axis=1)
            if best is None or sq.sum() < best.sum():
                best = sq
        out.append(best)
    return np.array(out)


def rms(squared_errors):
    return float(np.sqrt(np.mean(squared_errors)))


def textured_image(width, height, channels=1, dtype=np.uint8, seed=0, smooth=True):
    """A random texture with a gradient, different in every channel; spans the dtype's range
    (uint8 / uint16) or 0.5-10.5 (float: depth in metres). ``smooth``: low-pass (so that 1/64 px
    map differences move values by little), else independent random pixels."""
    rng = np.random.default_rng(seed)
    planes = []
    for c in range(channels):
        if smooth:
            coarse = rng.uniform(0, 1, (max(2, height // 12), max(2, width // 12)))
            plane = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
        else:
            plane = rng.uniform(0, 1, (height, width))
        u = np.linspace(0, 1, width)[None, :]
        v = np.linspace(0, 1, height)[:, None]
        plane = 0.7 * plane + 0.3 * (u if c % 2 == 0 else v)  # a gradient along x or y
        plane = (plane - plane.min()) / (plane.max() - plane.min())
        planes.append(plane)
    image = np.stack(planes, axis=-1) if channels > 1 else planes[0]
    if np.dtype(dtype).kind == 'f':
        return (0.5 + 10.0 * image).astype(dtype)
    top = np.iinfo(dtype).max
    return np.round(image * top).astype(dtype)
