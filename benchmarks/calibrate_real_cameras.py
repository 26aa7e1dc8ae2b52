#!/usr/bin/env python3
"""Re-derive the "own chessboard" OpenCV-fisheye calibrations in benchmarks/data/real_cameras.csv.

Run benchmarks/fetch_real_cameras.py first; then
    python benchmarks/calibrate_real_cameras.py [benchmarks/data/real_cameras]
prints, per OCamCalib camera, the number of views used, the rms and max reprojection error and
fx, fy, cx, cy, k1..k4.  cv2.fisheye.calibrate fails to initialise on these >150 deg views, so the
Kannala-Brandt model is fitted here directly: per-view poses start from solvePnP on rays of an
equidistant guess, then all parameters are refined jointly (LM, then a Huber pass).
"""
import glob
import os
import sys

import cv2
import numpy as np
from scipy.optimize import least_squares

# camera dir -> (file glob, inner corners of the chessboard, initial focal length guess in px)
CAMERAS = {
    "ocam_fisheye190": ("Fisheye190deg*.jpg", (6, 7), 140.0),
    "ocam_fisheye1": ("Fisheye1_*.jpg", (6, 8), 330.0),
    "ocam_fisheye2": ("Fisheye2_*.jpg", (6, 8), 160.0),
    "ocam_back": ("imgBack*.jpg", (6, 8), 160.0),
    "ocam_ladybug": ("Ladybug*.jpg", (5, 8), 500.0),
}


def detect(files, pattern):
    board = np.zeros((pattern[0] * pattern[1], 3))
    board[:, :2] = np.mgrid[0:pattern[0], 0:pattern[1]].T.reshape(-1, 2)
    obj, img, used, shape = [], [], [], None
    for f in files:
        g = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        shape = g.shape
        ok, c = cv2.findChessboardCornersSB(g, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        if not ok:
            ok, c = cv2.findChessboardCorners(g, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if ok:
                c = cv2.cornerSubPix(g, c, (5, 5), (-1, -1), (3, 30, 1e-3))
        if ok:
            obj.append(board.copy())
            img.append(c.reshape(-1, 2).astype(np.float64))
            used.append(os.path.basename(f))
    return obj, img, used, shape


def kb_project(X, p):
    fx, fy, cx, cy, k1, k2, k3, k4 = p
    r = np.hypot(X[:, 0], X[:, 1])
    th = np.arctan2(r, X[:, 2])
    thd = th * (1 + k1 * th**2 + k2 * th**4 + k3 * th**6 + k4 * th**8)
    s = thd / np.maximum(r, 1e-12)
    return np.stack([fx * X[:, 0] * s + cx, fy * X[:, 1] * s + cy], 1)


def initial_pose(o, i, f0, cx, cy):
    d = (i - [cx, cy]) / f0
    th = np.linalg.norm(d, axis=1)
    keep = th < np.radians(80)
    phi = np.arctan2(d[:, 1], d[:, 0])
    n = np.stack([np.tan(th) * np.cos(phi), np.tan(th) * np.sin(phi)], 1)
    if keep.sum() < 6:
        return False, None, None
    return cv2.solvePnP(o[keep], n[keep], np.eye(3), None)


def calibrate(obj, img, shape, f0):
    cx, cy = shape[1] / 2, shape[0] / 2
    poses, keep = [], []
    for j, (o, i) in enumerate(zip(obj, img)):
        ok, rv, tv = initial_pose(o, i, f0, cx, cy)
        if ok and tv[2] > 0:
            poses.append(np.r_[rv.ravel(), tv.ravel()])
            keep.append(j)
    obj = [obj[j] for j in keep]
    img = [img[j] for j in keep]

    def residuals(x):
        out = []
        for j, (o, i) in enumerate(zip(obj, img)):
            pr = x[8 + 6 * j:14 + 6 * j]
            R, _ = cv2.Rodrigues(pr[:3])
            out.append((kb_project(o @ R.T + pr[3:], x[:8]) - i).ravel())
        return np.concatenate(out)

    x0 = np.r_[f0, f0, cx, cy, 0, 0, 0, 0, np.concatenate(poses)]
    s = least_squares(residuals, x0, method="lm", max_nfev=20000, x_scale="jac")
    s = least_squares(residuals, s.x, loss="huber", f_scale=1.0, max_nfev=20000, x_scale="jac")
    r = residuals(s.x).reshape(-1, 2)
    return s.x[:8], float(np.sqrt(np.mean(np.sum(r**2, 1)))), float(np.abs(r).max()), keep


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "data", "real_cameras")
    for cam, (pat, corners, f0) in CAMERAS.items():
        files = sorted(glob.glob(os.path.join(root, cam, pat)))
        if not files:
            print(f"{cam}: no photos under {root}/{cam}; run benchmarks/fetch_real_cameras.py first")
            continue
        obj, img, used, shape = detect(files, corners)
        p, rms, mx, keep = calibrate(obj, img, shape, f0)
        print(f"{cam}: {len(keep)}/{len(files)} views, rms {rms:.3f} px, max {mx:.2f} px, "
              f"fx,fy,cx,cy,k1..k4 = {np.round(p, 6).tolist()}")


if __name__ == "__main__":
    main()
