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

BOW_CURVATURE_FLOOR = 1.0
"""Inward curvature beyond the predicted one always allowed, times the image width. On 60 rendered
lenses in room views together with 60 lenses seen through a circle with a bonnet in one frame
(15,077 curves that are lines under the true camera, 792 that are not): at 1.0 plus ``BOW_SHARE``
of the prediction no line and 567 of the others curve too far inward; at 0.5, 4 lines and 645
others. The same rule on the bow in pixels (1 px at 960 wide plus half the prediction) took
8 lines and 357 others: a bonnet's short pieces bow by little."""
BOW_SHARE = 0.5
"""And this share of the curvature zero-shot predicts for the line through the curve's ends (its
shape may be off)."""
BOW_SIGMAS = 3.0
"""The measured curvature must exceed the allowance by this many of its standard errors (the noise
of the curve's points about a parabola)."""
MIN_BOW_POINTS = 8


def bow_toward(points: np.ndarray, centre) -> tuple:
    """(bow, its standard error, half the chord), px: how far the middle of the parabola fitted to
    ``points`` (in the frame of their principal direction) lies from the chord between its ends,
    positive when the middle bulges toward ``centre``; its curvature is 2 bow / half^2."""
    p = np.asarray(points, float)
    mean = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - mean, full_matrices=False)
    along, across = vt[0], vt[1]
    t = (p - mean) @ along
    y = (p - mean) @ across
    half = 0.5 * float(t.max() - t.min())
    if len(p) < 4 or not half > 0:
        return 0.0, math.inf, half
    t = t / half  # a well-conditioned parabola; its quadratic coefficient is then the bow
    basis = np.stack([np.ones_like(t), t, t * t], axis=1)
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    residual = y - basis @ coef
    sigma = math.sqrt(float(residual @ residual) / (len(t) - 3))
    try:
        se = sigma * math.sqrt(float(np.linalg.inv(basis.T @ basis)[2, 2]))
    except np.linalg.LinAlgError:
        return 0.0, math.inf, half
    tm = 0.5 * float(t.max() + t.min())
    middle = mean + along * tm * half + across * (coef[0] + coef[1] * tm + coef[2] * tm * tm)
    toward = 1.0 if float(np.dot(np.asarray(centre, float) - middle, across)) > 0 else -1.0
    return toward * -float(coef[2]), se, half


def predicted_line(points: np.ndarray, camera: CameraModel) -> np.ndarray:
    """The image under ``camera`` of the straight line through the ends of ``points``, at the
    points' own places along it (each point's ray projected onto the plane of the end rays)."""
    rays = np.asarray(camera.unproject(np.asarray(points, float)), float)
    rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    normal = np.cross(rays[0], rays[-1])
    norm = np.linalg.norm(normal)
    if not norm > 1e-12:
        return np.asarray(points, float)
    normal /= norm
    on_plane = rays - np.outer(rays @ normal, normal)
    return np.asarray(camera.project(on_plane), float)


def bows_the_wrong_way(curves: Sequence[np.ndarray], camera: CameraModel, width: int) -> np.ndarray:
    """Module docstring: True for each curve (an (N, 2) array of pixels) that curves toward
    ``camera``'s principal point by more than a straight line could under a plausible camera."""
    out = np.zeros(len(curves), dtype=bool)
    centre = (camera.cx, camera.cy)
    for i, points in enumerate(curves):
        points = np.asarray(points, float)
        if len(points) < MIN_BOW_POINTS:
            continue
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            line = predicted_line(points, camera)
        if not np.all(np.isfinite(line)):
            continue
        bow, se, half = bow_toward(points, centre)
        if not (half > 0 and math.isfinite(se)):
            continue
        predicted = bow_toward(line, centre)[0]
        to_curvature = 2.0 * width / half ** 2  # a bow (px) as a curvature times the width
        allowed = BOW_CURVATURE_FLOOR + BOW_SHARE * abs(predicted) * to_curvature
        out[i] = (bow - predicted) * to_curvature > allowed + BOW_SIGMAS * se * to_curvature
    return out
