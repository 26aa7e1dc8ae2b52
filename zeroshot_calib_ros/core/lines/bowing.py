"""Curves that bow the wrong way: toward the principal point, where the lens bows straight lines away.

A wide or fisheye lens compresses the periphery: every point of a straight line moves toward the
principal point by more the farther out it is, so the line's ends move in more than its middle
and its image bows away from the principal point (``r(theta) / tan(theta)`` falls with theta: a
barrel lens). A curve whose middle bulges toward the principal point is something else: a car's
bonnet or bumper, the edge of a robot's body, an arch seen from below. From one frame nothing
tells such a curve from a line but its shape, and a fit that takes it bends the camera toward
pincushion to straighten it (rendered fisheyes with a vehicle's bonnet in one frame were accepted
4 to 22 px worse than zero-shot at 1920, most of their curves on the bonnet).

``bows_the_wrong_way(curves, camera, width)``: a boolean mask over curves, True for a curve whose
curvature toward the principal point exceeds the one ``camera`` (zero-shot's: the plausible camera,
not one a bonnet may already have bent) predicts for the straight line through its ends by more
than ``BOW_CURVATURE_FLOOR`` (times the image's width: a shape, whatever the resolution) plus
``BOW_SHARE`` of that prediction, and by more than ``BOW_SIGMAS`` standard errors. Curvature, not
the bow in pixels: a lens that is not barrel everywhere (a phone's nearly rectilinear ultra-wide
bows a line inward by a pixel or two near its corners: 98 of 770 wide lens profiles by more than
1 px at 960 wide) bows a long line by more pixels than a short piece of it, while a bonnet's edge,
found in short pieces, curves as much in each. Curves bowing the right way, by any amount, are
left to the fit's outlier test (``estimation.fit``): they may be lines of a lens more barrel than
zero-shot thinks.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..lens.models import CameraModel

BOW_CURVATURE_FLOOR = 0.6
"""Inward curvature beyond the predicted one always allowed, times the image width (a radius of
curvature of W / 0.6 beyond the prediction). The curves of 60 rendered lenses in room views and of
the same 60 seen through a circle with a bonnet in one frame (15,876 curves; 13,447 within 0.15 px
RMS of a line under the true camera): at 0.6 plus ``BOW_SHARE`` of the prediction 6 of those lines
(in 5 lenses) and 640 of the others curve too far inward; at 1.0, 1 line and 568 others; at 0.5,
8 lines and 646 others. At 1.0 a bonnet as gentle as the image is wide (its pieces 0.7 to 1.0)
was taken from one frame, and bent a camera to 14.9 px against zero-shot's 2.9 at 1920; at 0.6 no
lens of 60 is accepted worse than zero-shot from one frame, in a room or a street, and the runs of
4 frames in rooms, streets and corridors return the same cameras. The same rule on the bow in pixels
(1 px at 960 wide plus half the prediction) took 8 lines and 357 others in the earlier count: a
bonnet's short pieces bow by little."""
BOW_SHARE = 0.5
"""And this share of the curvature zero-shot predicts for the line through the curve's ends (its
shape may be off)."""
BOW_SIGMAS = 3.0
"""The measured curvature must exceed the allowance by this many of its standard errors (the noise
of the curve's points about a parabola)."""
MIN_BOW_POINTS = 8


def _runs(sizes: np.ndarray) -> tuple:
    """(each curve's first index, each point's curve) of curves of ``sizes`` points laid one after
    another."""
    return np.r_[0, np.cumsum(sizes)[:-1]], np.repeat(np.arange(len(sizes)), sizes)


def _bows(points: np.ndarray, sizes: np.ndarray, centre) -> tuple:
    """``bow_toward`` of many curves at once: ``points`` (N, 2) the curves one after another,
    ``sizes`` their numbers of points (each at least 4); (bow, se, half) arrays, one per curve
    (se infinite where no parabola can be fitted)."""
    starts, owner = _runs(sizes)
    mean = np.add.reduceat(points, starts, axis=0) / sizes[:, None]
    d = points - mean[owner]
    scatter = np.stack([np.add.reduceat(d[:, 0] * d[:, 0], starts), np.add.reduceat(d[:, 0] * d[:, 1], starts),
                        np.add.reduceat(d[:, 1] * d[:, 1], starts)], axis=1)
    # the principal direction of each curve's 2 x 2 scatter (closed form), and its normal
    angle = 0.5 * np.arctan2(2.0 * scatter[:, 1], scatter[:, 0] - scatter[:, 2])
    along = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    across = np.stack([-along[:, 1], along[:, 0]], axis=1)
    t = np.sum(d * along[owner], axis=1)
    y = np.sum(d * across[owner], axis=1)
    t_max, t_min = np.maximum.reduceat(t, starts), np.minimum.reduceat(t, starts)
    half = 0.5 * (t_max - t_min)
    with np.errstate(invalid='ignore', divide='ignore'):
        t = t / half[owner]  # a well-conditioned parabola; its quadratic coefficient is then the bow
        powers = np.stack([np.add.reduceat(t ** k, starts) for k in range(5)], axis=1)
        normal = np.stack([powers[:, [0, 1, 2]], powers[:, [1, 2, 3]], powers[:, [2, 3, 4]]], axis=1)
        moments = np.stack([np.add.reduceat(y * t ** k, starts) for k in range(3)], axis=1)
        ok = np.isfinite(normal).all(axis=(1, 2)) & (half > 0) & (np.abs(np.linalg.det(np.where(
            np.isfinite(normal), normal, 0.0))) > 1e-12)
        inverse = np.full_like(normal, np.nan)
        inverse[ok] = np.linalg.inv(normal[ok])
        coef = np.einsum('cij,cj->ci', inverse, moments)
        fitted = coef[owner, 0] + coef[owner, 1] * t + coef[owner, 2] * t * t
        sigma = np.sqrt(np.add.reduceat((y - fitted) ** 2, starts) / (sizes - 3))
        se = sigma * np.sqrt(inverse[:, 2, 2])
        tm = 0.5 * (t_max + t_min) / half
    middle = mean + along * (tm * half)[:, None] + across * (coef[:, 0] + coef[:, 1] * tm + coef[:, 2] * tm * tm)[:, None]
    toward = np.where(np.sum((np.asarray(centre, float) - middle) * across, axis=1) > 0, 1.0, -1.0)
    bow = np.where(ok, toward * -coef[:, 2], 0.0)
    return bow, np.where(ok, se, np.inf), half


def bow_toward(points: np.ndarray, centre) -> tuple:
    """(bow, its standard error, half the chord), px: how far the middle of the parabola fitted to
    ``points`` (in the frame of their principal direction) lies from the chord between its ends,
    positive when the middle bulges toward ``centre``; its curvature is 2 bow / half^2."""
    p = np.asarray(points, float)
    if len(p) < 4:
        return 0.0, math.inf, 0.0
    bow, se, half = _bows(p, np.array([len(p)]), centre)
    return float(bow[0]), float(se[0]), float(half[0])


def _predicted_lines(points: np.ndarray, sizes: np.ndarray, camera: CameraModel) -> np.ndarray:
    """``predicted_line`` of many curves at once (``_bows``' layout)."""
    starts, owner = _runs(sizes)
    rays = np.asarray(camera.unproject(points), float)
    rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    normal = np.cross(rays[starts], rays[starts + sizes - 1])
    norm = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(norm > 1e-12, normal / np.where(norm > 1e-12, norm, 1.0), 0.0)
    n = normal[owner]
    return np.asarray(camera.project(rays - np.sum(rays * n, axis=1, keepdims=True) * n), float)


def predicted_line(points: np.ndarray, camera: CameraModel) -> np.ndarray:
    """The image under ``camera`` of the straight line through the ends of ``points``, at the
    points' own places along it (each point's ray projected onto the plane of the end rays)."""
    p = np.asarray(points, float)
    return _predicted_lines(p, np.array([len(p)]), camera)


def bows_the_wrong_way(curves: Sequence[np.ndarray], camera: CameraModel, width: int) -> np.ndarray:
    """Module docstring: True for each curve (an (N, 2) array of pixels) that curves toward
    ``camera``'s principal point by more than a straight line could under a plausible camera.
    All curves at once: a frame's hundreds of curves cost a few milliseconds."""
    out = np.zeros(len(curves), dtype=bool)
    judged = [i for i, c in enumerate(curves) if len(c) >= MIN_BOW_POINTS]
    if not judged:
        return out
    arrays = [np.asarray(curves[i], float) for i in judged]
    sizes = np.array([len(a) for a in arrays])
    points = np.concatenate(arrays)
    centre = (camera.cx, camera.cy)
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        lines = _predicted_lines(points, sizes, camera)
        finite = np.logical_and.reduceat(np.all(np.isfinite(lines), axis=1), _runs(sizes)[0])
        bow, se, half = _bows(points, sizes, centre)
        predicted = _bows(np.where(np.isfinite(lines), lines, 0.0), sizes, centre)[0]
        to_curvature = 2.0 * width / half ** 2  # a bow (px) as a curvature times the width
        allowed = BOW_CURVATURE_FLOOR + BOW_SHARE * np.abs(predicted) * to_curvature
        flagged = (bow - predicted) * to_curvature > allowed + BOW_SIGMAS * se * to_curvature
    out[judged] = flagged & finite & np.isfinite(se)  # se is infinite where no parabola fits (half 0)
    return out
