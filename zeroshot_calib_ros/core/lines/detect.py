"""Straight-line evidence in ordinary images: curves that image one straight 3-D line each.

A straight 3-D edge images to a curve whose rays lie on one plane through the centre of
projection (a great circle of the ray sphere), however wide the lens. In a fisheye image such
edges are curved, so they are looked for where they are nearly straight:

1. **Virtual pinhole views** of the current camera estimate: several directions covering the
   field of view (rings of views around the axis, past 90 degrees off-axis for lenses that see
   that far), each a pinhole image made by ``cv2.remap`` with maps from ``camera.project`` of the
   view's rays, at about the raw image's own resolution (capped by ``max_view_px``).
2. **Segments** in each view: OpenCV's line segment detector (``cv2.createLineSegmentDetector``,
   present in OpenCV 4.6 and 5.x).
3. **Sub-pixel edge points in the raw image**: points along each segment are mapped back to raw
   pixels through the view's rays and ``camera.project``, then moved to the gradient maximum of
   the (lightly smoothed) raw image along the edge normal, with a parabolic peak fit. The curve's
   points are therefore raw measurements: the estimate only decides where to look and how
   straight things must be.
4. **Straightness under the estimate**, with a tolerance for an estimate that is off by a few
   percent in f and tens of pixels in the principal point: the rays of a piece (``unproject``)
   are fitted with a plane through the origin; points that stray are trimmed, pieces that stay
   curved are rejected.
5. **Merging** pieces of one 3-D line (from overlapping views, or broken by occlusions and by
   the polarity changes of a tiled floor), longest first: plane normals within a few degrees;
   where the spans along the great circle overlap, the points coincide (``duplicate_px``: the
   same edge, not its neighbour a few pixels away); across a gap (at most ``gap_ratio`` times
   the shorter side), the longer side's great circle extended passes through the other
   (``junction_px``, a great circle fitted through both could bend to join unrelated pieces);
   the joint fit stays within the tolerance. Duplicate points of overlapping views are thinned
   out; short and weak curves are dropped.

The straightness tolerance is loose on purpose (the estimate may be wrong). Curved edges (arcs
of discs, wheels, arches, foliage) are mostly rejected here (too curved, or too short once chance
alignments are not merged); a long, gently curved arc (a large rug's rim) can pass, and is then a
curve whose straightness residual under the true camera is several times that of real lines:
the estimator's robust fit has to reject it.

Only the part of the image that shows the scene is searched (``image_region.find_image_region``):
inside a fisheye's image circle, away from black or blown-out borders, by a margin, so that the
circle's boundary (dark, vignetted, noisy; long and gently curved) is never taken for a line.

``detect_curves(image, camera) -> List[Curve]``, which is ``find_edges`` (steps 1-3: raw edge
points) then ``curves_from_edges`` (steps 4-5, under a camera: a later, better estimate makes curves
of the same edge points again without looking again); ``make_views(camera)`` builds the views (and
their maps) once for several images of one camera; ``draw_curves`` makes a debug image.
Imports numpy and OpenCV, ``core.lens`` and ``image_region`` only.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from ..lens.models import CameraModel
from .image_region import ImageRegion, find_image_region
from .profiles import peak_offsets, sample

ImageId = Union[int, str, None]


@dataclass
class View:
    """A virtual pinhole view of the camera estimate: view pixel (x, y) has the camera-frame ray
    ``R @ ((x - c) / f, (y - c) / f, 1)``. ``map_x``, ``map_y`` (float32, view size) are the raw
    pixels of the view's pixels, clamped into the image (for ``cv2.remap``); ``inside`` marks
    the view pixels whose ray the camera images."""
    index: int
    R: np.ndarray
    f: float
    size: int
    direction: np.ndarray
    off_axis_deg: float
    scale: float                      # view pixels per raw pixel near the view's centre
    map_x: np.ndarray = field(repr=False)
    map_y: np.ndarray = field(repr=False)
    inside: np.ndarray = field(repr=False)

    @property
    def c(self) -> float:
        return (self.size - 1) / 2.0

    def rays(self, xy) -> np.ndarray:
        """Camera-frame unit rays of view pixels (..., 2)."""
        xy = np.asarray(xy, dtype=float)
        v = np.stack([(xy[..., 0] - self.c) / self.f, (xy[..., 1] - self.c) / self.f,
                      np.ones(xy.shape[:-1])], axis=-1)
        r = v @ self.R.T
        return r / np.linalg.norm(r, axis=-1, keepdims=True)

    def to_raw(self, camera: CameraModel, xy) -> np.ndarray:
        return camera.project(self.rays(xy))


@dataclass
class ViewSet:
    """The views of one camera estimate (build once, use for every image of that camera)."""
    camera: CameraModel
    views: List[View]
    half_fov_deg: float

    def __len__(self):
        return len(self.views)


@dataclass
class Curve:
    """Raw-image pixels believed to image ONE straight 3-D line.

    ``points``: (N, 2) float64 raw pixels in order along the curve. ``image``: index or name of
    the image it came from. ``view``: the view that gave its longest piece; ``views``: every view
    that contributed. ``normal``: the unit normal of the plane fitted to its rays under the
    camera used for detection; ``residual_px``: RMS distance (px) of the points from that plane's
    image (the straightness residual under that camera); ``length_px``: length along the curve;
    ``strength``: median gradient at the points (grey levels per pixel); ``span_deg``: the
    angle its rays span along the great circle."""
    points: np.ndarray
    image: ImageId = None
    view: int = -1
    views: Tuple[int, ...] = ()
    normal: Optional[np.ndarray] = None
    residual_px: float = math.nan
    length_px: float = 0.0
    strength: float = 0.0
    span_deg: float = 0.0


# ----------------------------------------------------------------------------- views

def _local_density(camera: CameraModel, direction: np.ndarray) -> float:
    """Raw pixels per radian around a ray (the smaller of the two directions), NaN if unseen."""
    d = direction / np.linalg.norm(direction)
    e1 = np.cross(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    h = 1e-3
    p = camera.project(np.stack([d, d + h * e1, d + h * e2]))
    if not np.isfinite(p).all():
        return math.nan
    J = np.stack([(p[1] - p[0]) / h, (p[2] - p[0]) / h], axis=1)
    return float(np.linalg.svd(J, compute_uv=False)[-1])


def _view_rotation(direction: np.ndarray) -> np.ndarray:
    z = direction / np.linalg.norm(direction)
    ref = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)  # columns: the view's axes in the camera frame


def _max_angle(camera: CameraModel) -> float:
    try:
        theta = float(camera.max_field_angle())
    except Exception:  # a model without it: sample the border
        theta = math.nan
    if not math.isfinite(theta):
        w, h = camera.width, camera.height
        t = np.linspace(0, 1, 33)
        border = np.concatenate([np.stack([t * w, 0 * t], 1), np.stack([t * w, 0 * t + h], 1),
                                 np.stack([0 * t, t * h], 1), np.stack([0 * t + w, t * h], 1)])
        rays = camera.unproject(border)
        theta = float(np.nanmax(np.arctan2(np.linalg.norm(rays[:, :2], axis=1), rays[:, 2])))
    return theta


def make_views(camera: CameraModel, half_fov_deg: float = 36.0, max_view_px: int = 640,
               min_inside: float = 0.12, workers: int = 1) -> ViewSet:
    """Pinhole views of ``camera`` covering its field of view.

    Square views of half-FOV ``half_fov_deg`` (edge to centre): one along the axis, then rings
    every 1.3 half-FOVs off-axis (as many views per ring as keep neighbours overlapping) up to
    the image's widest ray (beyond 90 degrees for a lens that sees that far). Each view's focal
    length matches the raw image's resolution near its centre, at most ``max_view_px`` wide.
    Views whose pixels fall mostly outside the image (``min_inside``) are left out. ``workers``
    > 1: the views are made in that many threads (OpenCV and numpy release the GIL over the maps;
    each view is made alone, so they are the same views)."""
    beta = math.radians(half_fov_deg)
    theta_max = _max_angle(camera)
    limit = getattr(camera, 'theta_max', None)
    step = 1.3 * beta
    directions = [np.array([0.0, 0.0, 1.0])]
    theta = step
    while theta - 0.8 * beta < theta_max and theta < math.pi - 0.3 * beta:
        n = max(3, int(math.ceil(2 * math.pi * math.sin(theta) / (1.35 * beta))))
        phase = 0.5 * (len(directions) % 2)
        for k in range(n):
            phi = 2 * math.pi * (k + phase) / n
            directions.append(np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi),
                                        math.cos(theta)]))
        theta += step
    if workers > 1 and len(directions) > 1:
        from concurrent.futures import ThreadPoolExecutor
        with ThreadPoolExecutor(max_workers=workers) as pool:
            made = list(pool.map(lambda d: _make_view(camera, d, beta, max_view_px, min_inside, limit), directions))
    else:
        made = [_make_view(camera, d, beta, max_view_px, min_inside, limit) for d in directions]
    views = []
    for view in made:
        if view is not None:
            view.index = len(views)
            views.append(view)
    return ViewSet(camera, views, half_fov_deg)


def _make_view(camera: CameraModel, d: np.ndarray, beta: float, max_view_px: int, min_inside: float,
               limit) -> Optional[View]:
    """One view of ``make_views`` along direction ``d`` (its index set by the caller), or None."""
    w, h = camera.width, camera.height
    density = _local_density(camera, d)
    if not math.isfinite(density) or density <= 0:
        return None
    native = 2 * density * math.tan(beta)
    size = int(min(max_view_px, max(64, round(native))))
    f = (size / 2) / math.tan(beta)
    R = _view_rotation(d)
    c = (size - 1) / 2.0
    # the maps only make the image the segment detector looks at (points are mapped back
    # exactly, through the view's rays): computed every 4th pixel and interpolated
    step = 4
    g = np.arange(0, size + step, step, dtype=float)
    xx, yy = np.meshgrid(g, g)
    v = np.stack([(xx - c) / f, (yy - c) / f, np.ones_like(xx)], axis=-1) @ R.T
    with np.errstate(invalid='ignore'):
        raw = camera.project(v)
        ok = np.isfinite(raw).all(axis=-1)
        if limit is not None and math.isfinite(limit):
            ok &= np.arctan2(np.linalg.norm(v[..., :2], axis=-1), v[..., 2]) <= limit
    mx_c = np.where(ok, raw[..., 0], -1e4).astype(np.float32)
    my_c = np.where(ok, raw[..., 1], -1e4).astype(np.float32)
    full = np.arange(size, dtype=np.float32) / step
    fx, fy = np.meshgrid(full, full)
    mx = cv2.remap(mx_c, fx, fy, cv2.INTER_LINEAR)
    my = cv2.remap(my_c, fx, fy, cv2.INTER_LINEAR)
    inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
    circle = getattr(camera, 'circle_radius', None)
    if circle is not None and math.isfinite(circle):
        inside &= np.hypot(mx - camera.cx, my - camera.cy) <= circle
    if inside.mean() < min_inside:
        return None
    # outside the image: repeat the nearest inside pixel (no artificial edge for the detector)
    if inside.all():
        mx, my = np.clip(mx, 0, w - 1), np.clip(my, 0, h - 1)
    else:
        source = _nearest_inside(inside)
        mx, my = _fill_outside(mx, inside, w, source), _fill_outside(my, inside, h, source)
    return View(-1, R, f, size, d, math.degrees(math.acos(max(-1.0, min(1.0, d[2])))),
                size / native, mx.astype(np.float32), my.astype(np.float32), inside)


_VIEW_CACHE: list = []   # [(key, ViewSet)], the few most recent cameras


def _camera_key(camera: CameraModel):
    return (type(camera).__name__,
            tuple(sorted((k, repr(v.tolist() if isinstance(v, np.ndarray) else v)) for k, v in vars(camera).items())))


def _cached_views(camera: CameraModel) -> ViewSet:
    """``make_views(camera)``, remembered for the last two cameras (same type and parameters):
    detection over many images of one camera builds its views once."""
    key = _camera_key(camera)
    for k, vs in _VIEW_CACHE:
        if k == key:
            return ViewSet(camera, vs.views, vs.half_fov_deg)
    vs = make_views(camera)
    _VIEW_CACHE.insert(0, (key, vs))
    del _VIEW_CACHE[2:]
    return vs


def _nearest_inside(inside: np.ndarray) -> Optional[np.ndarray]:
    """For every pixel, the flat index of the nearest pixel of ``inside`` (a distance transform;
    an inside pixel is its own), or None when no pixel is inside."""
    if not inside.any():
        return None
    _, labels = cv2.distanceTransformWithLabels((~inside).astype(np.uint8), cv2.DIST_L2, 5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    # labels index the zero pixels (inside) in scan order
    idx = np.flatnonzero(inside.ravel())
    lut = np.zeros(labels.max() + 1, dtype=np.int64)
    zero_labels = labels.ravel()[idx]
    lut[zero_labels] = idx
    return lut[labels.ravel()]


def _fill_outside(m, inside, limit, source: Optional[np.ndarray] = None):
    """Map values outside ``inside`` replaced by the nearest inside value; ``source``: the
    ``_nearest_inside(inside)`` already found (a view's two maps share one)."""
    out = np.array(m, dtype=np.float32)
    if source is None:
        source = _nearest_inside(inside)
    if source is None:
        return np.zeros_like(out)
    filled = out.ravel()[source].reshape(out.shape)
    return np.clip(np.where(inside, out, filled), 0, limit - 1)


# ----------------------------------------------------------------------------- geometry helpers

def _fit_plane(rays: np.ndarray) -> np.ndarray:
    """Unit normal of the plane through the origin nearest to unit rays (smallest singular vector)."""
    return np.linalg.svd(rays, full_matrices=False)[2][-1]


def plane_residual_px(camera: CameraModel, points: np.ndarray, normal: Optional[np.ndarray] = None,
                      rays: Optional[np.ndarray] = None):
    """Pixel residuals of raw points from the great circle of their rays' plane: each ray is
    moved onto the plane (orthogonal projection) and projected back; returns (distances (N,),
    normal). NaN where a point has no ray."""
    points = np.asarray(points, dtype=float)
    rays = camera.unproject(points) if rays is None else rays
    ok = np.isfinite(rays).all(axis=1)
    if normal is None:
        normal = _fit_plane(rays[ok]) if ok.sum() >= 2 else np.array([0.0, 0.0, 1.0])
    on = rays - (rays @ normal)[:, None] * normal[None, :]
    with np.errstate(invalid='ignore', divide='ignore'):
        px = camera.project(on / np.linalg.norm(on, axis=1, keepdims=True))
        d = np.linalg.norm(px - points, axis=1)
    return np.where(ok, d, np.nan), normal


# ----------------------------------------------------------------------------- image helpers

def _as_grey(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[..., 0]
        elif img.shape[2] in (3, 4):
            img = cv2.cvtColor(img if img.shape[2] == 3 else img[..., :3], cv2.COLOR_BGR2GRAY)
        else:
            raise ValueError(f'image must be grey or BGR, got shape {img.shape}')
    if img.ndim != 2:
        raise ValueError(f'image must be (H, W) or (H, W, 3), got shape {img.shape}')
    if img.dtype == np.uint8:
        return img
    f = img.astype(np.float32)
    finite = np.isfinite(f)
    if not finite.any():
        return np.zeros(img.shape, np.uint8)
    lo, hi = float(np.min(f[finite])), float(np.max(f[finite]))
    if img.dtype == np.uint16:
        lo, hi = 0.0, max(hi, 1.0)
    scale = 255.0 / (hi - lo) if hi > lo else 0.0
    return np.clip(np.nan_to_num((f - lo) * scale), 0, 255).astype(np.uint8)


_LSD = threading.local()
"""One line segment detector per thread: an OpenCV LSD object is not safe to share between
threads detecting at once."""


def _lsd():
    detector = getattr(_LSD, 'detector', None)
    if detector is None:
        if not hasattr(cv2, 'createLineSegmentDetector'):
            raise RuntimeError('this OpenCV has no line segment detector (cv2.createLineSegmentDetector)')
        detector = _LSD.detector = cv2.createLineSegmentDetector(1)  # LSD_REFINE_STD
    return detector


def _segments(view_image: np.ndarray) -> np.ndarray:
    """LSD segments (M, 4) x1 y1 x2 y2 of a view image (uint8)."""
    lines = _lsd().detect(view_image)[0]
    if lines is None:
        return np.zeros((0, 4))
    return np.asarray(lines, dtype=float).reshape(-1, 4)


# ----------------------------------------------------------------------------- pieces

@dataclass
class _Piece:
    points: np.ndarray      # (n, 2) raw pixels, in order along the segment
    rays: np.ndarray        # (n, 3) their rays under the estimate
    jac: np.ndarray         # (n, 2, 3) d pixel / d ray at each ray (for residuals in pixels)
    normal: np.ndarray
    strength: np.ndarray    # (n,) gradient at each point
    view: int
    rms: float
    density: float          # pixels per radian across the great circle, near the piece


def _refine_edges(smooth: np.ndarray, points: np.ndarray, normals: np.ndarray, seg: np.ndarray,
                  half_width: float, step: float = 0.5):
    """Move raw points to the gradient maximum along their normals, of the polarity of their
    segment's majority: the profile is sampled every ``step`` px (bicubic), differentiated
    (central differences) and the peak located by a parabola through three derivative samples
    (finer steps or bilinear sampling bias the peak toward the pixel grid by ~0.2 px).
    Returns (refined points, gradient at the peak, ok)."""
    s = np.arange(-half_width, half_width + step / 2, step)
    X = points[:, None, 0] + s[None, :] * normals[:, None, 0]
    Y = points[:, None, 1] + s[None, :] * normals[:, None, 1]
    prof = sample(smooth, X.astype(np.float32), Y.astype(np.float32), cv2.INTER_CUBIC)
    d = (prof[:, 2:] - prof[:, :-2]) / (2 * step)          # derivative at s[1:-1]
    sd = s[1:-1]
    centre = np.abs(sd) <= 1.0
    with np.errstate(invalid='ignore'):
        votes = np.nansum(d[:, centre], axis=1)
    polarity = np.sign(np.bincount(seg, weights=votes, minlength=int(seg.max()) + 1 if seg.size else 0))
    polarity[polarity == 0] = 1.0
    g = np.nan_to_num(d * polarity[seg][:, None], nan=-np.inf)
    offset, g1, ok = peak_offsets(g, sd, step)
    refined = points + offset[:, None] * normals
    return refined, np.where(ok, g1, 0.0), ok


def _view_points(view: View, camera: CameraModel, grey: np.ndarray, smooth: np.ndarray,
                 usable: np.ndarray, opts: dict):
    """Refined raw edge points of every LSD segment of one view: (points (n, 2), gradient (n,),
    segment id (n,)), in order along each segment."""
    empty = (np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=int))
    vimg = cv2.remap(grey, view.map_x, view.map_y, cv2.INTER_LINEAR)
    segs = _segments(vimg)
    if len(segs) == 0:
        return empty
    length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    keep = length >= opts['min_segment_view_px']
    segs, length = segs[keep], length[keep]
    if len(segs) == 0:
        return empty
    # points every ~spacing raw pixels along each segment, in view pixels
    spacing_view = opts['spacing_px'] * view.scale
    counts = np.maximum(2, np.ceil(length / spacing_view).astype(int) + 1)
    seg_id = np.repeat(np.arange(len(segs)), counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(seg_id.size) - np.repeat(first, counts)) / np.repeat(counts - 1, counts)
    p0, p1 = segs[seg_id, :2], segs[seg_id, 2:]
    q = p0 + t[:, None] * (p1 - p0)
    tangent_v = (p1 - p0) / length[seg_id, None]
    qi = np.clip(np.round(q).astype(int), 0, view.size - 1)
    inside = view.inside[qi[:, 1], qi[:, 0]]
    eps = 0.5
    with np.errstate(invalid='ignore', divide='ignore'):
        raw_all = camera.project(view.rays(np.concatenate([q, q + eps * tangent_v])))
        raw, raw2 = raw_all[:len(q)], raw_all[len(q):]
        tangent = raw2 - raw
        tangent = tangent / np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    ok = inside & np.isfinite(raw).all(axis=1) & np.isfinite(normal).all(axis=1)
    raw, normal, seg_id = raw[ok], normal[ok], seg_id[ok]
    if len(raw) == 0:
        return empty
    half = opts['search_px'] + 0.5 / max(view.scale, 1e-3)
    refined, grad, good = _refine_edges(smooth, raw, normal, seg_id, half)
    h, w = grey.shape
    b = opts['border_px']
    with np.errstate(invalid='ignore'):
        good &= (refined[:, 0] >= b) & (refined[:, 0] <= w - 1 - b) & \
            (refined[:, 1] >= b) & (refined[:, 1] <= h - 1 - b)
    idx = np.nonzero(good)[0]
    ri = np.round(refined[idx]).astype(int)
    good[idx[~usable[ri[:, 1], ri[:, 0]]]] = False
    # weak points: below the absolute floor or far below their segment's median
    med = np.zeros(len(segs))
    if good.any():
        med = np.nan_to_num(_group_median(grad[good], seg_id[good], len(segs)))
    good &= grad >= np.maximum(opts['min_gradient'], 0.35 * med[seg_id])
    return refined[good], grad[good], seg_id[good]


def _tolerance(opts, length_px):
    return opts['tolerance_px'] + opts['tolerance_per_px'] * length_px


def _path_length(points):
    if len(points) < 2:
        return 0.0
    step = points[1:] - points[:-1]
    return float(np.hypot(step[:, 0], step[:, 1]).sum())


def _median(values: np.ndarray) -> float:
    """``np.median`` of a 1-D array, the same number (the middle value, or the mean of the middle
    two: their sum halved), without its generic machinery (called thousands of times per image)."""
    n = len(values)
    if n == 0 or np.isnan(values).any():
        return float(np.median(values))
    half = n // 2
    if n % 2:
        return float(np.partition(values, half)[half])
    part = np.partition(values, (half - 1, half))
    return float((part[half - 1] + part[half]) / 2.0)


def _jacobians(camera: CameraModel, rays: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d project / d ray (N, 2, 3) by forward differences (project ignores the ray's length)."""
    p0 = camera.project(rays)
    J = np.empty((len(rays), 2, 3))
    for k in range(3):
        d = rays.copy()
        d[:, k] += h
        J[:, :, k] = (camera.project(d) - p0) / h
    return J


def _approx_residual_px(rays, jac, normal, per_point=False):
    """Signed pixel residuals from the plane of ``normal`` (or, ``per_point``, one normal per
    ray), to first order: the ray's angle to the plane times the pixel motion per radian across
    it (the exact residual moves the ray onto the plane and projects it: ``plane_residual_px``;
    they agree to ~1e-3 of the residual). Returns (residuals, pixels per radian)."""
    if per_point:
        a = np.sum(rays * normal, axis=1)
        perp = normal - a[:, None] * rays
    else:
        a = rays @ normal
        perp = normal[None, :] - a[:, None] * rays
    # np.linalg.norm's and np.clip's arithmetic, without their Python wrappers (the same numbers)
    perp /= np.maximum(np.sqrt(np.add.reduce(perp * perp, axis=1, keepdims=True)), 1e-12)
    motion = np.einsum('nij,nj->ni', jac, perp)
    speed = np.sqrt(np.add.reduce(motion * motion, axis=1))
    return np.arcsin(np.minimum(np.maximum(a, -1.0), 1.0)) * speed, speed


def _fit_plane_fast(rays):
    """The plane through the origin nearest to unit rays: the scatter matrix's smallest eigenvector."""
    return np.linalg.eigh(rays.T @ rays)[1][:, 0]


def _group_median(values: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """Median of ``values`` per group id (0..n_groups-1); NaN for an empty group (a NaN value
    sorts last, as in ``np.sort``). Only the middle values of each group's sorted values are
    needed, not a sort of all values by (group, value): when the groups are runs, as the points of
    a view's segments are, each run is one row of a NaN-padded array sorted along its rows;
    otherwise the values are sorted and then, stably, their groups."""
    n = len(values)
    counts = np.bincount(group, minlength=n_groups)
    start = np.cumsum(counts) - counts
    width = int(counts.max()) if n else 0
    if n and n_groups * width <= 4 * n + 1024 and bool((group[1:] >= group[:-1]).all()):
        rows = np.full((n_groups, width), np.nan)
        rows[group, np.arange(n) - start[group]] = values
        rows.sort(axis=1)
        v, first = rows.ravel(), np.arange(n_groups) * width
    else:
        order = np.argsort(values)
        g = group[order]
        v, first = values[order[np.argsort(g.astype(np.int16) if n_groups <= 32767 else g, kind='stable')]], start
    out = np.full(n_groups, np.nan)
    has = counts > 0
    lo = first[has] + (counts[has] - 1) // 2
    hi = first[has] + counts[has] // 2
    out[has] = 0.5 * (v[lo] + v[hi])
    return out


def _make_pieces(points, rays, jac, grad, seg, view_index, opts) -> List[_Piece]:
    """Straight pieces from the ordered raw points of each segment (``seg`` ids, contiguous):
    a plane fit per segment, outliers (points that jumped to a neighbouring edge) trimmed by
    their signed residual's distance from the segment's median, segments still curved beyond
    the tolerance rejected. All segments at once (batched fits)."""
    _, seg = np.unique(seg, return_inverse=True)
    n_seg = int(seg.max()) + 1 if seg.size else 0
    if n_seg == 0:
        return []
    active = np.ones(len(points), bool)
    # the six distinct products of each ray's outer product, summed per segment in the order of
    # the points (bincount adds as np.add.at does: the same sums)
    products = [(i, j, rays[:, i] * rays[:, j]) for i in range(3) for j in range(i, 3)]
    for it in range(5):
        in_seg = seg[active]
        counts = np.bincount(in_seg, minlength=n_seg)
        S = np.empty((n_seg, 3, 3))
        for i, j, product in products:
            S[:, i, j] = S[:, j, i] = np.bincount(in_seg, weights=product[active], minlength=n_seg)
        S[counts < 3] = np.eye(3)
        normals = np.linalg.eigh(S)[1][:, :, 0]
        res, speed = _approx_residual_px(rays, jac, normals[seg], per_point=True)
        if it == 4:
            break
        med = _group_median(res[active], seg[active], n_seg)
        mad = _group_median(np.abs(res - med[seg])[active], seg[active], n_seg)
        limit = np.maximum(opts['outlier_px'], 3.0 * 1.4826 * np.nan_to_num(mad))
        keep = active & (np.abs(res - med[seg]) <= limit[seg])
        if np.array_equal(keep, active):
            break
        active = keep
    pieces = []
    idx_all = np.nonzero(active)[0]
    cuts = np.nonzero(np.diff(seg[idx_all]))[0] + 1
    for idx in np.split(idx_all, cuts):
        if len(idx) < opts['min_points']:
            continue
        pts = points[idx]
        rms = _rms(res[idx])
        if not rms <= _tolerance(opts, _path_length(pts)):
            continue
        k = seg[idx[0]]
        pieces.append(_Piece(pts, rays[idx], jac[idx], normals[k], grad[idx], view_index, rms,
                             _median(speed[idx])))
    return pieces


@dataclass
class EdgePoints:
    """The sub-pixel edge points of one image, as ``find_edges`` measured them: per view that gave
    any, its index and (points (n, 2) raw pixels, gradient (n,), LSD segment id (n,)) in order
    along each segment. Raw measurements: the camera they were looked for with only decided
    where to look, so a better camera can make curves of them again (``curves_from_edges``)
    without looking again."""
    image_size: Tuple[int, int]
    """(width, height) of the image."""
    per_view: List[Tuple[int, Tuple[np.ndarray, np.ndarray, np.ndarray]]]
    options: dict = field(repr=False, default_factory=dict)
    """The detection options they were found with (``DEFAULTS`` completed)."""


def _pieces(camera: CameraModel, edges: EdgePoints, opts) -> List[_Piece]:
    per_view = [points for _, points in edges.per_view]
    sizes = [len(p[0]) for p in per_view]
    if sum(sizes) == 0:
        return []
    rays_all = camera.unproject(np.concatenate([p[0] for p in per_view]))  # one call: unproject may iterate
    ok_all = np.isfinite(rays_all).all(axis=1)
    jac_all = np.full((len(rays_all), 2, 3), np.nan)
    jac_all[ok_all] = _jacobians(camera, rays_all[ok_all])
    ok_all &= np.isfinite(jac_all).all(axis=(1, 2))
    pieces = []
    start = 0
    for (view_index, (pts, grad, seg)), n in zip(edges.per_view, sizes):
        rays, jac, ok = rays_all[start:start + n], jac_all[start:start + n], ok_all[start:start + n]
        start += n
        if n == 0 or not ok.any():
            continue
        # segments with too few usable points are dropped before fitting
        counts = np.bincount(seg[ok])
        keep = ok & (counts[np.minimum(seg, len(counts) - 1)] >= opts['min_points'])
        if keep.any():
            pieces += _make_pieces(pts[keep], rays[keep], jac[keep], grad[keep], seg[keep], view_index, opts)
    return pieces


# ----------------------------------------------------------------------------- merging

def _basis(normal):
    ref = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - (ref @ normal) * normal
    e1 /= math.sqrt(e1.dot(e1))  # np.linalg.norm's arithmetic, without its wrapper
    e2 = np.array([normal[1] * e1[2] - normal[2] * e1[1], normal[2] * e1[0] - normal[0] * e1[2],
                   normal[0] * e1[1] - normal[1] * e1[0]])
    return e1, e2


class _Cluster:
    """Pieces merged into one curve: points ordered along the great circle of ``normal``."""

    def __init__(self, piece: _Piece):
        self.parts = [piece]
        self.rms = piece.rms
        self._set(piece.points, piece.rays, piece.jac, piece.strength, piece.normal)

    def _set(self, points, rays, jac, strength, normal):
        self.normal = normal
        e1, e2 = _basis(normal)
        m = np.add.reduce(rays, axis=0) / len(rays)  # rays.mean(axis=0), the same numbers
        self.centre = math.atan2(m @ e2, m @ e1)
        self.e1, self.e2 = e1, e2
        phi = self.angles(rays)
        order = np.argsort(phi, kind='stable')
        self.points, self.rays, self.jac = points[order], rays[order], jac[order]
        self.strength, self.phi = strength[order], phi[order]

    def angles(self, rays):
        phi = np.arctan2(rays @ self.e2, rays @ self.e1) - self.centre
        return np.mod(phi + np.pi, 2 * np.pi) - np.pi

    def add(self, piece: _Piece, normal):
        self.parts.append(piece)
        self.rms = max(self.rms, piece.rms)
        self._set(np.concatenate([self.points, piece.points]), np.concatenate([self.rays, piece.rays]),
                  np.concatenate([self.jac, piece.jac]), np.concatenate([self.strength, piece.strength]), normal)


def _rms(x):
    # np.mean's sum and division, without its generic machinery (the same number)
    return math.sqrt(np.add.reduce(np.square(x)) / len(x)) if len(x) else math.inf


NEAREST_BRUTE_PAIRS = 4096
"""Below this many point pairs the nearest distances are found by brute force (every pair); above,
by a sweep along one axis (``_nearest_distances``). Both give the same distances."""


def _nearest_distances(mine: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    """The distance of each point of ``mine`` to its nearest point of ``theirs``.

    Large sets by a sweep: ``theirs`` sorted along the axis it spreads over most; each point of
    ``mine`` is first measured to its two neighbours in that order (a distance the nearest point
    cannot exceed), then to every point of ``theirs`` within that distance along the axis (a point
    farther along the axis is farther away). Every distance is the same sum of the squared
    coordinate differences as brute force computes, so the two give the same numbers."""
    n = len(theirs)
    if len(mine) * n <= NEAREST_BRUTE_PAIRS or n < 2:
        return np.sqrt(np.min(np.sum((mine[:, None, :] - theirs[None, :, :]) ** 2, axis=2), axis=1))
    tx, ty = theirs[:, 0], theirs[:, 1]
    mx, my = mine[:, 0], mine[:, 1]
    if tx.max() - tx.min() < ty.max() - ty.min():
        tx, ty, mx, my = ty, tx, my, mx
    order = np.argsort(tx, kind='stable')
    tx, ty = tx[order], ty[order]
    pos = np.searchsorted(tx, mx)
    np.clip(pos, 1, n - 1, out=pos)
    bound = np.minimum((mx - tx[pos - 1]) ** 2 + (my - ty[pos - 1]) ** 2, (mx - tx[pos]) ** 2 + (my - ty[pos]) ** 2)
    reach = np.sqrt(bound) * (1.0 + 1e-9) + 1e-9   # a margin over the rounding of the differences
    lo = np.searchsorted(tx, mx - reach, 'left')
    counts = np.maximum(np.searchsorted(tx, mx + reach, 'right') - lo, 1)
    ends = np.cumsum(counts)
    starts = ends - counts
    rows = np.repeat(np.arange(len(mx)), counts)
    cols = np.minimum(np.arange(ends[-1]) - np.repeat(starts - lo, counts), n - 1)
    return np.sqrt(np.minimum.reduceat((mx[rows] - tx[cols]) ** 2 + (my[rows] - ty[cols]) ** 2, starts))


def _try_merge(cl: _Cluster, piece: _Piece, opts, beat: float = math.inf):
    """(local RMS, joint normal) when ``piece`` continues or duplicates ``cl``, else None; also
    None, without the joint fit, when the local RMS is not below ``beat`` (the best found so far
    for this piece: this cluster cannot be the better choice)."""
    phi = cl.angles(piece.rays)
    pmin, pmax = phi.min(), phi.max()
    first, last = cl.phi[0], cl.phi[-1]
    lo, hi = max(pmin, first), min(pmax, last)
    local_tol = max(opts['junction_px'], 1.5 * max(cl.rms, piece.rms))
    if hi > lo:
        # overlapping spans: the same edge seen twice (or two edges side by side)
        mine = piece.points[(phi >= lo) & (phi <= hi)]
        # the cluster's angles are sorted: its points within [lo, hi] are one run
        theirs = cl.points[np.searchsorted(cl.phi, lo, 'left'):np.searchsorted(cl.phi, hi, 'right')]
        if len(mine) == 0 or len(theirs) == 0:
            return None
        local = _median(_nearest_distances(mine, theirs))
        if local > opts['duplicate_px'] or not local < beat:
            return None
        if pmin >= first and pmax <= last:
            return local, cl.normal  # inside the cluster's span: nothing new to check
    else:
        gap = lo - hi
        if gap > math.radians(opts['merge_gap_deg']):
            return None
        # across the gap, the longer of the two (the cluster's end near the junction, or the
        # piece) extended along its great circle passes through the other
        width = max(pmax - pmin, gap, math.radians(2.0))
        if pmin >= last:
            near = cl.phi >= last - width
            gap_px = math.hypot(*(piece.points[np.argmin(phi)] - cl.points[-1]))
        else:
            near = cl.phi <= first + width
            gap_px = math.hypot(*(piece.points[np.argmax(phi)] - cl.points[0]))
        if near.sum() < opts['min_points']:
            near = np.ones(len(cl.phi), bool)
        # a gap no longer than the shorter side (chance alignments of short pieces of different
        # things across wide gaps are not one line)
        len_near, len_piece = _path_length(cl.points[near]), _path_length(piece.points)
        if gap_px > max(opts['gap_px'], opts['gap_ratio'] * min(len_near, len_piece)):
            return None
        if len_near >= len_piece:
            res, _ = _approx_residual_px(piece.rays, piece.jac, _fit_plane_fast(cl.rays[near]))
        else:
            res, _ = _approx_residual_px(cl.rays[near], cl.jac[near], piece.normal)
        local = _rms(res)
        if not local <= local_tol + opts['tolerance_per_px'] * gap_px or not local < beat:
            return None
    rays = np.concatenate([cl.rays, piece.rays])
    normal = _fit_plane_fast(rays)
    res, _ = _approx_residual_px(rays, np.concatenate([cl.jac, piece.jac]), normal)
    length = _path_length(np.concatenate([cl.points, piece.points])[np.argsort(np.concatenate([cl.phi, phi]))])
    if not _rms(res) <= max(_tolerance(opts, length), local_tol):
        return None
    return local, normal


def _merge(camera: CameraModel, pieces: List[_Piece], opts) -> List[_Cluster]:
    pieces = sorted(pieces, key=lambda p: -len(p.points))
    clusters: List[_Cluster] = []
    # per cluster, for vectorised first tests: normal, great-circle basis, centre angle, span
    cap = max(16, len(pieces))
    N, E1, E2 = np.zeros((cap, 3)), np.zeros((cap, 3)), np.zeros((cap, 3))
    Cc, LO, HI = np.zeros(cap), np.zeros(cap), np.zeros(cap)
    cos_max = math.cos(math.radians(opts['merge_angle_deg']))
    gap_max = math.radians(opts['merge_gap_deg'])

    def store(k, cl):
        N[k], E1[k], E2[k], Cc[k], LO[k], HI[k] = cl.normal, cl.e1, cl.e2, cl.centre, cl.phi[0], cl.phi[-1]

    for piece in pieces:
        best, best_local, best_normal = None, math.inf, None
        c = len(clusters)
        if c:
            # cheap tests first: plane normals close; the piece's ends and middle near the plane;
            # spans along the great circle overlapping or close
            cand = np.nonzero(np.abs(N[:c] @ piece.normal) >= cos_max)[0]
            if cand.size:
                probe = piece.rays[[0, len(piece.rays) // 2, -1]]
                off = np.abs(N[cand] @ probe.T).max(axis=1) * piece.density
                near = off <= opts['merge_tolerance_px']
                cand, off = cand[near], off[near]
            if cand.size:
                phi = np.arctan2(piece.rays @ E2[cand].T, piece.rays @ E1[cand].T) - Cc[None, cand]
                phi = np.mod(phi + np.pi, 2 * np.pi) - np.pi
                overlap = np.minimum(phi.max(axis=0), HI[cand]) - np.maximum(phi.min(axis=0), LO[cand])
                ok = np.where(overlap > 0, off <= 2 * opts['duplicate_px'] + opts['merge_tolerance_px'] / 2,
                              -overlap <= gap_max)
                cand = cand[ok]
            for k in cand:
                found = _try_merge(clusters[k], piece, opts, best_local)
                if found is not None and found[0] < best_local:
                    best, (best_local, best_normal) = k, found
                    if best_local < 0.5 * opts['duplicate_px']:
                        break
        if best is None:
            clusters.append(_Cluster(piece))
            store(c, clusters[-1])
        else:
            clusters[best].add(piece, best_normal)
            store(best, clusters[best])
    return clusters


def _thin(pts: np.ndarray, min_d: float) -> np.ndarray:
    """Mask of the points kept when walking along ``pts`` and keeping each point at least
    ``min_d`` from the last kept one. Runs of points already that far apart from their
    predecessor are kept without a Python step each (most of a curve: only where overlapping
    views put duplicates does the walk have to decide point by point)."""
    n = len(pts)
    keep = np.zeros(n, bool)
    if n == 0:
        return keep
    step = np.hypot(*np.diff(pts, axis=0).T) if n > 1 else np.zeros(0)
    x, y = pts[:, 0].tolist(), pts[:, 1].tolist()
    far = (step >= min_d).tolist()
    keep[0] = True
    last = 0
    for i in range(1, n):
        # a point far from its predecessor, which was kept, is far enough from the last kept
        if (far[i - 1] and last == i - 1) or math.hypot(x[i] - x[last], y[i] - y[last]) >= min_d:
            keep[i] = True
            last = i
    return keep


def _finish(camera: CameraModel, cl: _Cluster, image: ImageId, opts) -> Optional[Curve]:
    pts, rays, phi, strength = cl.points, cl.rays, cl.phi, cl.strength
    # too short already: thinning leaves out points, which only shortens the path (a margin
    # over the rounding of the two sums); most clusters, single short pieces, end here
    if _path_length(pts) < opts['min_length_px'] * (1.0 - 1e-9):
        return None
    # thin out duplicates (overlapping views see the same edge): keep points >= 0.6 spacing apart
    min_d = 0.6 * opts['spacing_px']
    keep = _thin(pts, min_d)
    pts, rays, phi, strength = pts[keep], rays[keep], phi[keep], strength[keep]
    if len(pts) < opts['min_points']:
        return None
    length = _path_length(pts)
    if length < opts['min_length_px']:
        return None
    res, normal = plane_residual_px(camera, pts, rays=rays)
    rms = _rms(res)
    if not rms <= _tolerance(opts, length):
        return None
    views = tuple(sorted({p.view for p in cl.parts}))
    main = max(cl.parts, key=lambda p: len(p.points)).view
    return Curve(points=pts.astype(np.float64), image=image, view=main, views=views, normal=normal,
                 residual_px=rms, length_px=length, strength=_median(strength),
                 span_deg=float(np.degrees(phi[-1] - phi[0])))


# ----------------------------------------------------------------------------- entry points

DEFAULTS = dict(
    min_length_px=None,         # default: 4 % of the image diagonal (at least 20 px)
    spacing_px=2.0,             # distance between the points of a curve (raw px)
    min_points=8,
    min_segment_view_px=10.0,   # LSD segments shorter than this (view px) are ignored
    min_gradient=4.0,           # grey levels per pixel at the edge (smoothed image)
    search_px=1.5,              # half-width of the sub-pixel edge search (raw px; + 0.5 view px)
    smooth_sigma=0.7,           # Gaussian smoothing of the raw image before the edge search
    border_px=2.0,              # points this close to the image border are dropped
    tolerance_px=0.6,           # straightness tolerance under the estimate: this +
    tolerance_per_px=0.004,     #   this x the curve's length (a wrong estimate bends long lines)
    outlier_px=0.6,             # points of a piece this far from its median (or 3 sigma) are trimmed
    merge_angle_deg=3.0,        # plane normals of pieces of one line differ by less than this,
    merge_gap_deg=12.0,         # their spans along the great circle are at most this far apart,
    gap_px=6.0,                 #   and the gap at most this or gap_ratio x the shorter one's length,
    gap_ratio=1.5,
    duplicate_px=0.8,           # where they overlap, their points are this close (one edge),
    junction_px=0.8,            # where they meet, they fit one great circle this well (RMS),
    merge_tolerance_px=6.0,     # and (a quick test) the piece is this close to the other's plane
    max_curves=400,             # the longest ones are kept
)


def _options(options) -> dict:
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise TypeError(f"unknown option(s): {', '.join(sorted(unknown))}; allowed: {', '.join(DEFAULTS)}")
    opts = dict(DEFAULTS)
    opts.update(options)
    return opts


def find_edges(image, camera: CameraModel, views: Optional[ViewSet] = None, mask: Optional[np.ndarray] = None,
               region: Optional[ImageRegion] = None, **options) -> EdgePoints:
    """Steps 1-3 of the module docstring: the sub-pixel edge points of the LSD segments of the
    views of ``camera`` (arguments as ``detect_curves``)."""
    opts = _options(options)
    grey = _as_grey(image)
    h, w = grey.shape
    if (w, h) != (camera.width, camera.height):
        raise ValueError(f'image is {w}x{h} but the camera is {camera.width}x{camera.height}')
    if opts['min_length_px'] is None:
        opts['min_length_px'] = max(20.0, 0.04 * math.hypot(w, h))
    if views is None:
        views = _cached_views(camera)
    elif views.camera is not camera:
        raise ValueError('views were made for another camera: make_views(camera)')
    if region is None:
        region = find_image_region(grey)
    elif region.mask.shape != grey.shape:
        raise ValueError(f'region mask must have shape {grey.shape}, got {region.mask.shape}')
    usable = region.mask.copy()
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != grey.shape:
            raise ValueError(f'mask must have shape {grey.shape}, got {mask.shape}')
        usable &= mask
    edges = EdgePoints((w, h), [], opts)
    if not usable.any() or float(grey.std()) < 1.0:
        return edges
    smooth = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), opts['smooth_sigma'])
    for view in views.views:
        points = _view_points(view, camera, grey, smooth, usable, opts)
        if len(points[0]):
            edges.per_view.append((view.index, points))
    return edges


def curves_from_edges(edges: EdgePoints, camera: CameraModel, image_id: ImageId = None) -> List[Curve]:
    """Steps 4-5 of the module docstring: the curves that ``edges``' points make under ``camera``
    (pieces straight under it, merged), longest first. ``camera``: the one the edges were found
    with, or a better estimate of the same camera (a second round reuses the first's edges)."""
    if (camera.width, camera.height) != tuple(edges.image_size):
        raise ValueError(f'edges are of a {edges.image_size[0]}x{edges.image_size[1]} image but the camera is '
                         f'{camera.width}x{camera.height}')
    opts = edges.options
    pieces = _pieces(camera, edges, opts)
    clusters = _merge(camera, pieces, opts)
    curves = [c for c in (_finish(camera, cl, image_id, opts) for cl in clusters) if c is not None]
    curves.sort(key=lambda c: -c.length_px)
    return curves[:opts['max_curves']]


def detect_curves(image, camera: CameraModel, image_id: ImageId = None, views: Optional[ViewSet] = None,
                  mask: Optional[np.ndarray] = None, region: Optional[ImageRegion] = None,
                  **options) -> List[Curve]:
    """Curves of raw pixels that image one straight 3-D line each (module docstring).

    ``image``: (H, W) grey or (H, W, 3) BGR, the camera's size. ``camera``: the current estimate
    (any ``CameraModel``; it decides where to look, not where the points are). ``views``: from
    ``make_views(camera)`` to reuse for several images. ``mask``: optional bool (H, W), True
    where the image may be used. ``region``: the image's ``ImageRegion`` if already found (default:
    ``find_image_region(image)``); no point outside its mask is used, so the boundary of an
    image circle or of black borders is never a curve. ``options``: see ``DEFAULTS`` (e.g. ``tolerance_px``,
    ``min_length_px``). Longest first. The same as ``curves_from_edges(find_edges(...), camera)``."""
    edges = find_edges(image, camera, views=views, mask=mask, region=region, **options)
    return curves_from_edges(edges, camera, image_id)


def draw_curves(image, used: Sequence[Curve] = (), rejected: Sequence[Curve] = (), thickness: int = 1,
                static: Sequence[Curve] = ()):
    """A BGR copy of ``image`` with the ``used`` curves in green, the ``rejected`` in red and the
    ``static`` ones (left out for staying put across the images) in orange (each curve a polyline
    through its points, its first point marked)."""
    img = np.asarray(image)
    if img.ndim == 2:
        out = cv2.cvtColor(_as_grey(img), cv2.COLOR_GRAY2BGR)
    else:
        out = img[..., :3].copy() if img.dtype == np.uint8 else cv2.cvtColor(_as_grey(img), cv2.COLOR_GRAY2BGR)
    shift = 4
    for curves, colour in ((static, (0, 140, 255)), (rejected, (0, 0, 255)), (used, (0, 220, 0))):
        for c in curves:
            p = np.asarray(c.points, dtype=float)
            p = p[np.isfinite(p).all(axis=1)]
            if len(p) < 2:
                continue
            # a polyline per run of close points: gaps (occlusions, merged pieces) stay open
            step = np.hypot(*np.diff(p, axis=0).T)
            runs = np.split(p, np.nonzero(step > DRAW_GAP_PX)[0] + 1)
            pts = [np.round(r * (1 << shift)).astype(np.int32).reshape(-1, 1, 2) for r in runs if len(r) >= 2]
            cv2.polylines(out, pts, False, colour, thickness, cv2.LINE_AA, shift)
            cv2.circle(out, tuple(int(v) for v in np.round(p[0])), 2, colour, -1, cv2.LINE_AA)
    return out


DRAW_GAP_PX = 6.0
"""draw_curves leaves consecutive points farther apart than this unconnected."""
