"""Curves that stay put from frame to frame: the robot's or the vehicle's own body in view, lens
dirt, the edge of a housing.

A moving camera sees the scene move across its frames; what is fixed to the camera stays at the
same pixels. Such a curve says nothing about the straight lines of the scene: a bumper's or a
robot arm's edge is curved in 3-D, and its image, a smooth arc, is straight under some wrong
camera. Worse, it is in every frame, so it counts as many times as there are frames, all of them
pulling the same way, which no outlier test over curves catches (rendered circular fisheyes with
a vehicle body at the bottom were refined 1 to 7 px worse than zero-shot, principal points pulled
7 px off the image circle's centre, by the body's edge seen in four frames).

``static_curves(curves, images)``: a boolean mask over the curves, True for a curve whose edge is
in the other images too, at the same pixels and facing the same way (the brightness gradient
across the curve within ``SEARCH_PX`` of ``MATCH_FRACTION`` of its points at least ``EDGE_SHARE``
of its own, with one sign along the curve: ``same_edge_share``), in at least ``MIN_SHARE`` of the other images. The other images' edges, not their
curves, are what is compared: the detector finds a body's rim in different pieces in every frame. When most curves are static
(``STILL_CAMERA_SHARE``) the camera did not move (a fixed surveillance camera, frames of one
pose): every frame shows the same scene, its curves are the scene's, and none is dropped.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

import cv2
import numpy as np

from .straightness import curve_image, curve_points

SEARCH_PX = 1
"""A curve's edge is looked for this far (px) on either side along its normal in the other images:
the detectors' points of one edge agree to well under a pixel, and a scene edge that moved by less
than this between two frames of a moving camera is rare."""
EDGE_SHARE = 0.25
"""A point is on the same edge in another image when the brightness gradient across the curve
there is at least this share of the curve's own (an edge, not texture, facing the same way)."""
MATCH_FRACTION = 0.8
"""Share of a curve's points that must be on the same edge in another image for it to be there too."""
MIN_SHARE = 0.75
"""A curve is static when it is found in at least this share of the other images (all of them up to
four images): a body in view is in every frame, while two frames of a moving camera can share a
scene line by chance (a door frame and a corridor's edge at the same pixels)."""
STILL_CAMERA_SHARE = 0.5
"""When more than this share of the curves are static, the camera did not move: nothing is dropped."""


def image_gradients(image) -> np.ndarray:
    """(2, H, W) float32 brightness gradient (grey levels per px) of a grey or BGR image, lightly
    smoothed: what ``static_curves`` samples, and keeps in its ``gradients`` dict (a caller may
    fill the dict ahead, e.g. while it detects curves in other threads)."""
    grey = np.asarray(image)
    if grey.ndim == 3:
        grey = cv2.cvtColor(grey[..., :3], cv2.COLOR_BGR2GRAY)
    grey = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), 1.0)
    return np.stack([cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)]) / 8.0


def _across(gradient: np.ndarray, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The brightness gradient across the curve (gradient . normal, signed) of largest magnitude
    within SEARCH_PX of each point along its normal (N,)."""
    _, height, width = gradient.shape
    best = np.zeros(len(points), dtype=np.float32)
    for offset in range(-SEARCH_PX, SEARCH_PX + 1):
        q = np.round(points + offset * normals).astype(int)
        inside = (q[:, 0] >= 0) & (q[:, 0] < width) & (q[:, 1] >= 0) & (q[:, 1] < height)
        g = np.zeros((len(points), 2), dtype=np.float32)
        g[inside] = gradient[:, q[inside, 1], q[inside, 0]].T
        across = np.sum(g * normals, axis=1)
        best = np.where(np.abs(across) > np.abs(best), across, best)
    return best


def same_edge_share(own: np.ndarray, there: np.ndarray) -> float:
    """Share of a curve's points whose gradient across it in another image (``there``) is at least
    EDGE_SHARE of its own (``own``), with one sign all along: a body's edge against a scene
    brighter in one frame and darker in another keeps one sign along it, while a texture's edges
    (a tiled floor) that happen to lie under the curve alternate."""
    magnitude = np.maximum(np.abs(own), 1e-6)
    ratio = there * np.sign(own) / magnitude
    return float(max(np.mean(ratio >= EDGE_SHARE), np.mean(ratio <= -EDGE_SHARE)))


def _normals(points: np.ndarray) -> np.ndarray:
    tangent = np.gradient(points, axis=0)
    length = np.linalg.norm(tangent, axis=1, keepdims=True)
    tangent = np.divide(tangent, length, out=np.zeros_like(tangent), where=length > 0)
    return np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)


def static_curves(curves: Sequence, images, gradients: Optional[dict] = None) -> np.ndarray:
    """Boolean mask over ``curves`` (``core.lines.detect.Curve``, each with its ``image``): the
    curves whose edge is at the same pixels in the other images (module docstring). ``images``:
    the images, indexed by the curves' ``image`` (a sequence or a mapping). All False with fewer
    than two images, or when the camera did not move. ``gradients``: a dict that keeps each
    image's gradients by its key across calls on the same ``images`` (a later round's curves of
    the same frames), filled here."""
    n = len(curves)
    static = np.zeros(n, dtype=bool)
    ids = [curve_image(c, 0) for c in curves]
    keys = list(dict.fromkeys(ids))
    if len(keys) < 2 or n == 0:
        return static
    cache = {} if gradients is None else gradients
    for key in keys:
        if key not in cache:
            cache[key] = image_gradients(images[key])
    gradients = {key: cache[key] for key in keys}
    # every curve's points and normals in one array, each image sampled once along all of them
    # (the per-point sampling is the same as curve by curve)
    usable, points, normals = [], [], []
    for i, curve in enumerate(curves):
        p = np.asarray(curve_points(curve), dtype=float)
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p) >= 3:
            usable.append(i)
            points.append(p)
            normals.append(_normals(p))
    found_in = np.zeros(n, dtype=int)
    if not usable:
        return static
    sizes = [len(p) for p in points]
    bounds = np.cumsum([0] + sizes)
    points, normals = np.concatenate(points), np.concatenate(normals)
    across = {key: _across(gradients[key], points, normals) for key in keys}
    for j, i in enumerate(usable):
        part = slice(bounds[j], bounds[j + 1])
        key = ids[i]
        own = across[key][part]
        for other in keys:
            if other != key and same_edge_share(own, across[other][part]) >= MATCH_FRACTION:
                found_in[i] += 1
    needed = max(1, math.ceil(MIN_SHARE * (len(keys) - 1)))
    static = found_in >= needed
    if static.mean() > STILL_CAMERA_SHARE:
        return np.zeros(n, dtype=bool)
    return static
