"""The part of an image that shows the scene: inside a fisheye's image circle, off black or
blown-out borders.

A circular fisheye (or a 190-degree lens on a 16:9 sensor, whose circle the frame clips at the
top and bottom) images nothing outside its image circle. Outside is dark but rarely black: a
vignetting fall-off, flare, sensor noise and JPEG artefacts; its boundary is a strong, long,
gently curved edge that the line detector must never take for a straight line. The boundary is
also a measurement: its centre is the optical axis (the principal point) and its radius is where
the lens puts the spec's circle FOV.

``find_image_region(image) -> ImageRegion``:

1. **Dark surround** (on a copy at most ``COARSE_SIDE`` px wide, smoothed): the darkest level of
   the image's border ring (its 1st percentile: a clipped circle leaves only the corners dark)
   plus a step (several are tried, from a few grey levels up), and the connected dark regions
   that touch the border.
2. **Coarse circle**: RANSAC (three-point circles, a fixed seed: the same image gives the same
   answer) on those regions' boundary pixels, the image frame left out (a clipped circle fits
   from its visible arcs).
3. **Sub-pixel boundary**: radial profiles of the full-resolution image across the coarse circle,
   the steepest fall outward on each (parabolic peak); a robust (Tukey) geometric circle fit,
   twice. Its covariance (residual scatter, neighbouring points counted as correlated, plus a
   floor ``CIRCLE_FLOOR_PX``) gives ``centre_sigma_px`` and ``radius_sigma_px``. A soft rim
   (light fading to the surround over many pixels) has no one radius: the width of its fall
   beyond a sharp edge's is ``edge_sigma_px``, part of ``radius_uncertainty_px``.
4. **A circle or not**: the fitted edge points must lie on the circle (robust scatter at most
   ``MAX_SCATTER_PX``), cover opposite sides of it (an arc seen on one side only is a dark floor,
   a shadow, the night sky), with a clear step from inside to outside; the image outside the
   circle must be nearly all dark surround, and inside little of it. Its radius lies between a quarter of the shorter side
   and the half diagonal, its centre in the middle 40 % of each side. Ordinary (rectilinear,
   full-frame fisheye, dark or night) images fail these.

The usable ``mask`` is the disc shrunk by a margin (the boundary's blur and JPEG ringing, the
soft edge of the lens's vignetting, three measurement sigmas: ``default_margin_px``), less black
(<= 3) regions touching the border and letterbox bars (full rows or columns at the border that
are uniformly black or blown out). Without a circle, the black regions and bars alone are left
out, dilated by the margin.

Imports numpy and OpenCV only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import cv2
import numpy as np

from .profiles import peak_offsets, sample

COARSE_SIDE = 400
"""The dark surround and the coarse circle are found on a copy at most this many px wide."""
DARK_STEPS = (6.0, 12.0, 24.0, 40.0)
"""Grey levels above the border's darkest level tried for the dark surround, in turn."""
BLACK_LEVEL = 3
"""Regions this dark (after a 5 x 5 blur) touching the border are never scene."""
SATURATED_LEVEL = 252
MIN_RADIUS = 0.25
"""Smallest radius, as a fraction of the shorter side."""
CENTRE_BOX = 0.2
"""The centre lies within this fraction of each side from the image centre."""
MAX_SCATTER_PX = 6.0
"""Largest robust scatter (px) of the boundary points about the circle, at 1000 px radius (and
proportionally, at least 2 px): an image circle's boundary is a clear edge, softened by the lens
(the shared real 800 px wide fisheye images: 1.6 px)."""
MIN_INLIERS = 0.6
"""Fraction of the boundary profiles whose edge lies on the circle."""
MIN_STEP = 8.0
"""Least median step (grey levels) from just inside to just outside the circle."""
MIN_OUTSIDE_DARK = 0.8
"""Least fraction of the image outside the circle that is dark surround."""
MAX_INSIDE_DARK = 0.2
"""Largest fraction of the disc that is dark surround (a dark scene's bright round object, dark
all around and inside, is not an image circle)."""
CIRCLE_FLOOR_PX = 0.25
"""Added in quadrature to the measured sigmas (px): what a sub-pixel edge fit of a real, slightly
imperfect circle does not beat."""
SHARP_EDGE_SIGMA_PX = 2.5
"""Gaussian sigma (px) of a boundary sharp enough that its steepest fall is the circle to a
fraction of a pixel: our 1 px smoothing and a lens's focus blur (rendered circles: 2.1-2.3 px,
measured within 0.3 px; the rim of a real 190-degree OCamCalib camera: 1.9-2.3 px). A softer rim
(a lens whose light fades to the surround over 10-20 px: OCamCalib's other circular cameras,
5-7 px) has no one radius: the spec's circle may be anywhere across it, so the part of its width
beyond this is an uncertainty of the radius (``ImageCircle.edge_sigma_px``)."""
CORRELATION_PX = 4.0
"""Boundary points closer than this along the circle are counted as one (blur, JPEG blocks)."""


@dataclass
class ImageCircle:
    """A measured image circle (px): centre (cx, cy), radius, 1-sigma uncertainties of each centre
    coordinate and of the radius; ``arc_deg``: how much of the circle the boundary points cover;
    ``points``: boundary points used; ``images``: how many images the measurement combines."""
    cx: float
    cy: float
    radius: float
    centre_sigma_px: float
    radius_sigma_px: float
    arc_deg: float = 0.0
    points: int = 0
    images: int = 1
    fall_px: float = 0.0
    """How far inside the boundary the brightness is still falling towards it (px): the soft
    edge of a lens's vignetting, which the usable region leaves out too."""
    edge_sigma_px: float = 0.0
    """How far the radius is undefined (1 sigma, px) because the rim is soft: the width of the
    boundary's fall beyond a sharp edge's (``SHARP_EDGE_SIGMA_PX``). Averaging images does not
    shrink it; ``radius_sigma_px`` (where the steepest fall lies) does not include it."""

    @property
    def diameter(self) -> float:
        return 2.0 * self.radius

    @property
    def radius_uncertainty_px(self) -> float:
        """1-sigma uncertainty (px) of the radius as the spec's circle: the measurement's and the
        soft rim's."""
        return math.hypot(self.radius_sigma_px, self.edge_sigma_px)

    @property
    def sigma_px(self) -> float:
        """The larger of the centre's and the radius's 1-sigma uncertainty (px)."""
        return max(self.centre_sigma_px, self.radius_sigma_px)

    def scaled(self, s: float) -> 'ImageCircle':
        return ImageCircle(self.cx * s, self.cy * s, self.radius * s, self.centre_sigma_px * s,
                           self.radius_sigma_px * s, self.arc_deg, self.points, self.images, self.fall_px * s,
                           self.edge_sigma_px * s)


@dataclass
class ImageRegion:
    """``mask``: bool (H, W), True where the image shows the scene (away from every border by
    ``margin_px``); ``circle``: the image circle when one is seen, else None; ``excluded``: what
    was left out, in words (for logs)."""
    mask: np.ndarray = field(repr=False)
    circle: Optional[ImageCircle] = None
    margin_px: float = 0.0
    excluded: List[str] = field(default_factory=list)

    @property
    def usable_fraction(self) -> float:
        return float(self.mask.mean()) if self.mask.size else 0.0


# ----------------------------------------------------------------------------- helpers

def _grey(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., 0] if img.shape[2] == 1 else cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise ValueError(f'image must be (H, W) or (H, W, 3), got shape {img.shape}')
    if img.dtype != np.uint8:
        f = np.nan_to_num(img.astype(np.float32))
        hi = float(f.max()) if f.size else 0.0
        img = np.clip(f * (255.0 / hi if hi > 0 else 0.0), 0, 255).astype(np.uint8)
    return img


def _border_components(mask: np.ndarray, min_area: float) -> np.ndarray:
    """The connected parts of ``mask`` (4-connected) that touch the image border and cover at
    least ``min_area`` of it."""
    m = mask.astype(np.uint8)
    if not m.any():
        return np.zeros(mask.shape, bool)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=4)
    h, w = mask.shape
    keep = np.zeros(n, bool)
    for k in range(1, n):
        x, y, bw, bh, area = stats[k]
        if (x == 0 or y == 0 or x + bw == w or y + bh == h) and area >= min_area * h * w:
            keep[k] = True
    return keep[labels]


def _black_regions(grey: np.ndarray) -> np.ndarray:
    """Near-black (<= ``BLACK_LEVEL`` after a 5 x 5 blur) regions touching the border, over 1 %
    of the image: never scene, whatever else is found."""
    return _border_components(cv2.blur(grey, (5, 5)) <= BLACK_LEVEL, 0.01)


def _bars(grey: np.ndarray) -> np.ndarray:
    """Letterbox bars: runs of full rows (columns) from a border that are uniformly black or
    blown out (98 % of their pixels <= ``BLACK_LEVEL`` + 5 or >= ``SATURATED_LEVEL``)."""
    h, w = grey.shape
    out = np.zeros(grey.shape, bool)
    flat = (grey <= BLACK_LEVEL + 5) | (grey >= SATURATED_LEVEL)
    rows, cols = flat.mean(axis=1) >= 0.98, flat.mean(axis=0) >= 0.98
    for line, n, axis in ((rows, h, 0), (cols, w, 1)):
        for order in (range(n), range(n - 1, -1, -1)):
            run = []
            for i in order:
                if not line[i]:
                    break
                run.append(i)
            if len(run) >= 2:
                if axis == 0:
                    out[run, :] = True
                else:
                    out[:, run] = True
    return out


def _circle_from_3(p: np.ndarray):
    """Circles (cx, cy, r) through point triples (n, 3, 2); NaN for collinear triples."""
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    d = 2 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    sa, sb, sc = (a * a).sum(1), (b * b).sum(1), (c * c).sum(1)
    with np.errstate(divide='ignore', invalid='ignore'):
        ux = (sa * (b[:, 1] - c[:, 1]) + sb * (c[:, 1] - a[:, 1]) + sc * (a[:, 1] - b[:, 1])) / d
        uy = (sa * (c[:, 0] - b[:, 0]) + sb * (a[:, 0] - c[:, 0]) + sc * (b[:, 0] - a[:, 0])) / d
    r = np.hypot(a[:, 0] - ux, a[:, 1] - uy)
    return ux, uy, r


def _algebraic_circle(p: np.ndarray):
    """Least-squares circle (Kasa) through points (n, 2)."""
    A = np.column_stack([2 * p[:, 0], 2 * p[:, 1], np.ones(len(p))])
    b = (p * p).sum(1)
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    cx, cy = sol[0], sol[1]
    return float(cx), float(cy), float(math.sqrt(max(sol[2] + cx * cx + cy * cy, 0.0)))


def _plausible(cx, cy, r, w, h):
    return ((r >= MIN_RADIUS * min(w, h)) & (r <= 0.5 * math.hypot(w, h))
            & (np.abs(cx - w / 2) <= CENTRE_BOX * w) & (np.abs(cy - h / 2) <= CENTRE_BOX * h))


def _ransac_circle(points: np.ndarray, tol: float, w: int, h: int, iterations: int = 400):
    """(cx, cy, r, inlier mask) of the circle with the most points within ``tol``, or None."""
    n = len(points)
    if n < 12:
        return None
    rng = np.random.default_rng(12345)
    idx = np.stack([rng.choice(n, 3, replace=False) for _ in range(iterations)])
    cx, cy, r = _circle_from_3(points[idx])
    ok = np.isfinite(r) & _plausible(cx, cy, r, w, h)
    if not ok.any():
        return None
    cx, cy, r = cx[ok], cy[ok], r[ok]
    best, best_count = None, 0
    for start in range(0, len(cx), 64):
        d = np.abs(np.hypot(points[None, :, 0] - cx[start:start + 64, None],
                            points[None, :, 1] - cy[start:start + 64, None]) - r[start:start + 64, None])
        counts = (d <= tol).sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best_count, best = int(counts[k]), (cx[start + k], cy[start + k], r[start + k])
    if best is None:
        return None
    inliers = np.abs(np.hypot(points[:, 0] - best[0], points[:, 1] - best[1]) - best[2]) <= tol
    for _ in range(3):  # refit on the inliers, take the inliers again
        if inliers.sum() < 3:
            return None
        c = _algebraic_circle(points[inliers])
        inliers = np.abs(np.hypot(points[:, 0] - c[0], points[:, 1] - c[1]) - c[2]) <= tol
    return c[0], c[1], c[2], inliers


def _radial_profiles(smooth: np.ndarray, cx, cy, r, u: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Samples (n, len(offsets)) of ``smooth`` along the n directions ``u`` (outward unit
    vectors) at ``offsets`` px from the circle (cx, cy, r); NaN outside the image."""
    X = cx + (r + offsets)[None, :] * u[:, 0:1]
    Y = cy + (r + offsets)[None, :] * u[:, 1:2]
    return sample(smooth, X.astype(np.float32), Y.astype(np.float32))


def _boundary_points(smooth: np.ndarray, circle, half_width: float, step: float = 0.5):
    """Sub-pixel boundary points on radial profiles across ``circle``: on each, the steepest fall
    of brightness outward (parabolic peak). Returns (points (n, 2), angles (n,), fall (n,))."""
    h, w = smooth.shape
    cx, cy, r = circle
    count = int(min(1440, max(90, 2 * math.pi * r / 2.0)))
    phi = np.arange(count) * (2 * math.pi / count)
    u = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    edge = np.stack([cx + r * u[:, 0], cy + r * u[:, 1]], axis=1)
    m = 3.0  # profiles may run out of the image (NaN there): corner arcs of a large circle count
    seen = (edge[:, 0] >= m) & (edge[:, 0] <= w - 1 - m) & (edge[:, 1] >= m) & (edge[:, 1] <= h - 1 - m)
    phi, u = phi[seen], u[seen]
    if len(phi) == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    s = np.arange(-half_width, half_width + step / 2, step)
    prof = _radial_profiles(smooth, cx, cy, r, u, s)
    fall = -(prof[:, 2:] - prof[:, :-2]) / (2 * step)      # brightness falling outward, at s[1:-1]
    fall = np.nan_to_num(fall, nan=-np.inf)
    offset, g1, ok = peak_offsets(fall, s[1:-1], step)
    pts = np.stack([cx + (r + offset) * u[:, 0], cy + (r + offset) * u[:, 1]], axis=1)
    return pts[ok], phi[ok], g1[ok]


def _geometric_fit(points: np.ndarray, start, iterations: int = 12):
    """Robust geometric circle fit (Gauss-Newton, Tukey weights at 4.685 robust sigmas):
    (cx, cy, r, weights, robust sigma of the residuals, normal matrix J^T W J)."""
    cx, cy, r = start
    wts = np.ones(len(points))
    sigma = 1.0
    JTJ = np.eye(3)
    for _ in range(iterations):
        d = points - [cx, cy]
        rho = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        res = rho - r
        mad = float(np.median(np.abs(res - np.median(res))))
        sigma = max(1.4826 * mad, 0.3)  # a floor: quantised edges can make the MAD vanish
        t = (res - np.median(res)) / (4.685 * sigma)  # about the median: r is still to move
        wts = np.where(np.abs(t) < 1, (1 - t * t) ** 2, 0.0)
        J = np.column_stack([-d[:, 0] / rho, -d[:, 1] / rho, -np.ones(len(points))])
        JTJ = J.T @ (J * wts[:, None])
        try:
            step = np.linalg.solve(JTJ, -(J.T @ (wts * res)))
        except np.linalg.LinAlgError:
            return None
        cx, cy, r = cx + step[0], cy + step[1], r + step[2]
        if np.abs(step).max() < 1e-4:
            break
    d = points - [cx, cy]
    res = np.hypot(d[:, 0], d[:, 1]) - r
    inl = wts > 0
    sigma = float(np.sqrt(np.sum(wts * res * res) / max(np.sum(wts) - 3, 1))) if inl.sum() > 3 else sigma
    return cx, cy, r, wts, max(sigma, 0.05), JTJ


def _arc_coverage(phi: np.ndarray, bins: int = 24):
    """(degrees of the circle covered by 15-degree bins holding points, whether two opposite bins
    (within one bin) both hold points)."""
    if len(phi) == 0:
        return 0.0, False
    b = np.unique((np.mod(phi, 2 * math.pi) / (2 * math.pi) * bins).astype(int) % bins)
    occupied = np.zeros(bins, bool)
    occupied[b] = True
    opposite = any(occupied[k] and (occupied[(k + bins // 2 - 1) % bins] or occupied[(k + bins // 2) % bins]
                                    or occupied[(k + bins // 2 + 1) % bins]) for k in range(bins))
    return 360.0 * occupied.sum() / bins, opposite


# ----------------------------------------------------------------------------- the circle

def _noise_level(grey: np.ndarray, where: np.ndarray) -> float:
    """Robust sensor-noise sigma (grey levels) of ``grey`` where ``where``: MAD of the difference
    from a 3 x 3 mean."""
    hp = grey.astype(np.float32) - cv2.blur(grey.astype(np.float32), (3, 3))
    v = hp[where]
    if v.size < 50:
        return 1.0
    return float(max(1.4826 * np.median(np.abs(v - np.median(v))) * 1.06, 0.5))


def find_image_circle(image, trace: Optional[list] = None) -> Optional[ImageCircle]:
    """The image circle of ``image`` (grey or BGR), or None when the image shows none (module
    docstring, steps 1-4). ``trace``: a list to which each candidate tried is appended as
    (dark level, coarse circle (cx, cy, r), verdict) (to see why none was found)."""
    return _find_circle(_grey(image), trace)[0]


def _find_circle(grey: np.ndarray, trace: Optional[list] = None):
    """(ImageCircle or None, dark-surround mask at full size or None)."""
    h, w = grey.shape
    s = min(1.0, COARSE_SIDE / max(w, h))
    small = cv2.resize(grey, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA) \
        if s < 1 else grey.copy()
    small = cv2.blur(small, (3, 3)).astype(np.float32)
    sh, sw = small.shape
    ring = np.zeros(small.shape, bool)
    ring[:3, :], ring[-3:, :], ring[:, :3], ring[:, -3:] = True, True, True, True
    floor = float(np.percentile(small[ring], 1))
    smooth = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), 1.0)
    tried = set()
    for step in DARK_STEPS:
        level = floor + step
        if level >= 200:
            break
        dark = _border_components(small <= level, 0.001)
        key = dark.tobytes().__hash__()
        if not dark.any() or key in tried:
            continue
        tried.add(key)
        edge = dark & ~cv2.erode(dark.astype(np.uint8), np.ones((3, 3), np.uint8),
                                 borderType=cv2.BORDER_REPLICATE).astype(bool)
        edge[:2, :], edge[-2:, :], edge[:, :2], edge[:, -2:] = False, False, False, False
        ys, xs = np.nonzero(edge)
        if len(xs) < 20:
            continue
        pts = np.stack([xs, ys], axis=1).astype(float)
        if len(pts) > 3000:
            pts = pts[np.linspace(0, len(pts) - 1, 3000).astype(int)]
        coarse = _ransac_circle(pts, max(1.5, 0.01 * min(sw, sh)), sw, sh)
        if coarse is None or coarse[3].mean() < 0.3:
            continue
        circle = (coarse[0] / s, coarse[1] / s, coarse[2] / s)
        found, why = _fine_circle(grey, smooth, circle, level, dark, s)
        if trace is not None:
            trace.append((level, circle, why))
        if found is not None:
            full_dark = cv2.resize(dark.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
            return found, full_dark
    return None, None


def _fine_circle(grey, smooth, circle, level, dark_small, s) -> tuple:
    h, w = grey.shape
    # the coarse circle is an iso-contour of the dark surround: outside the boundary by the
    # width of a glow or a soft edge (a few percent of the radius)
    half = max(6.0, 3.0 / s, 0.1 * circle[2])
    noise = _noise_level(grey, _disc(grey.shape, circle[0], circle[1], circle[2] + 4, outside=True))
    min_step = max(MIN_STEP, 4 * noise)
    fit = None
    for half_width in (half, 6.0, 4.0):
        pts, phi, fall = _boundary_points(smooth, circle, half_width)
        # only profiles that step from the scene down into the surround locate the boundary (not
        # where the scene is as dark as the surround, or a body part covers the boundary)
        u = np.stack([np.cos(phi), np.sin(phi)], axis=1)
        step, _ = _step(smooth, pts, u, max(5.0, 0.025 * circle[2]))  # soft edges: a few % of r
        pts, phi = pts[step >= min_step], phi[step >= min_step]
        if len(pts) < 30:
            return None, 'few boundary points'
        fit = _geometric_fit(pts, circle)
        if fit is None:
            return None, 'no fit'
        circle = fit[:3]
    cx, cy, r, wts, sigma, JTJ = fit
    if not bool(_plausible(np.array(cx), np.array(cy), np.array(r), w, h)):
        return None, 'implausible size or centre'
    res = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) - r
    inl = np.abs(res) <= max(1.0, 3 * sigma)
    if inl.mean() < MIN_INLIERS or sigma > max(2.0, MAX_SCATTER_PX * r / 1000.0):
        return None, f'scatter {sigma:.2f} px, inliers {inl.mean():.2f}'
    arc, opposite = _arc_coverage(phi[inl])
    if arc < 60.0 or not opposite:
        return None, f'arc {arc:.0f} deg, opposite sides {opposite}'
    # a clear step from just inside to just outside, and the outside dark surround
    u = np.stack([np.cos(phi[inl]), np.sin(phi[inl])], axis=1)
    fall_px = _fall_width(smooth, cx, cy, r, u)
    d_in = max(5.0, min(fall_px, 0.05 * r))    # a soft edge: its step is complete only that far in
    inside = sample(smooth, (cx + (r - d_in) * u[:, 0]).astype(np.float32),
                     (cy + (r - d_in) * u[:, 1]).astype(np.float32))
    outside = sample(smooth, (cx + (r + 5) * u[:, 0]).astype(np.float32), (cy + (r + 5) * u[:, 1]).astype(np.float32))
    ok = np.isfinite(inside) & np.isfinite(outside)
    if ok.sum() < 10:
        return None, 'no step samples'
    step = float(np.median(inside[ok] - outside[ok]))
    if not step >= min_step:
        return None, f'step {step:.1f}, noise {noise:.1f}'
    sh, sw = dark_small.shape
    beyond = _disc((sh, sw), cx * s, cy * s, r * s + max(2.0, 6 * s), outside=True)
    if beyond.sum() > 0.002 * sh * sw and dark_small[beyond].mean() < MIN_OUTSIDE_DARK:
        return None, f'outside dark {dark_small[beyond].mean():.2f}'
    within = _disc((sh, sw), cx * s, cy * s, max(1.0, r * s - max(2.0, (fall_px + 4) * s)))
    if within.any() and dark_small[within].mean() > MAX_INSIDE_DARK:
        return None, f'inside dark {dark_small[within].mean():.2f}'
    # covariance: residual scatter, points within CORRELATION_PX along the arc counted as one
    spacing = 2 * math.pi * r / max(1, int(min(1440, max(90, 2 * math.pi * r / 2.0))))
    inflate = max(1.0, CORRELATION_PX / spacing)
    try:
        cov = sigma * sigma * inflate * np.linalg.inv(JTJ)
    except np.linalg.LinAlgError:
        return None, 'singular'
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    centre_sd = float(math.hypot(CIRCLE_FLOOR_PX, max(sd[0], sd[1])))
    radius_sd = float(math.hypot(CIRCLE_FLOOR_PX, sd[2]))
    return ImageCircle(float(cx), float(cy), float(r), centre_sd, radius_sd, arc, int(inl.sum()),
                       fall_px=fall_px, edge_sigma_px=_edge_sigma(smooth, cx, cy, r, u)), 'ok'


def _step(smooth, pts, u, d):
    """(brightness ``d`` px inside each boundary point (direction ``u`` outward) less ``d`` px
    outside, the brightness outside)."""
    a = pts - d * u
    b = pts + d * u
    inside = sample(smooth, a[:, 0].astype(np.float32), a[:, 1].astype(np.float32))
    outside = sample(smooth, b[:, 0].astype(np.float32), b[:, 1].astype(np.float32))
    return np.nan_to_num(inside - outside, nan=-np.inf), np.nan_to_num(outside, nan=np.inf)


def _fall_width(smooth, cx, cy, r, u, reach: float = 24.0) -> float:
    """Distance (px) inside the boundary at which the median radial profile has come within 10 %
    of its inside level (the level ``reach`` px in): the width of the soft edge."""
    s = np.arange(-reach, 1.0, 1.0)
    prof = _radial_profiles(smooth, cx, cy, r, u, s)
    with np.errstate(invalid='ignore'):
        med = np.nanmedian(prof, axis=0) if np.isfinite(prof).any() else np.full(len(s), np.nan)
    if not np.isfinite(med).all():
        return 0.0
    inside, edge = float(np.median(med[:4])), float(med[-1])
    if not inside > edge:
        return 0.0
    falling = med < edge + 0.9 * (inside - edge)
    k = np.nonzero(~falling)[0]
    return float(-s[k[-1]]) if len(k) else reach


def _edge_sigma(smooth, cx, cy, r, u, reach: float = 24.0, step: float = 0.5) -> float:
    """The soft rim's share of the radius's uncertainty (px): on each radial profile (direction
    ``u`` outward) the full width at half maximum of the brightness's fall at the boundary, as a
    Gaussian sigma (/ 2.355), median over the profiles, less a sharp edge's
    (``SHARP_EDGE_SIGMA_PX``) in quadrature."""
    s = np.arange(-reach, reach / 2 + step / 2, step)
    prof = _radial_profiles(smooth, cx, cy, r, u, s)
    fall = -(prof[:, 2:] - prof[:, :-2]) / (2 * step)
    fall = fall[np.isfinite(fall).all(axis=1)]
    if len(fall) == 0:
        return 0.0
    centre = int(np.argmin(np.abs(s[1:-1])))
    near = max(1, int(round(2.0 / step)))        # the boundary fitted is within a couple of px
    k = centre - near + np.argmax(fall[:, centre - near:centre + near + 1], axis=1)
    peak = fall[np.arange(len(fall)), k]
    below = fall <= 0.5 * peak[:, None]
    index = np.arange(fall.shape[1])[None, :]
    lo = np.where(below & (index < k[:, None]), index, -1).max(axis=1)       # -1: still above at the window's end
    hi = np.where(below & (index > k[:, None]), index, fall.shape[1]).min(axis=1)
    fwhm = (hi - lo) * step
    width = float(np.median(fwhm[peak > 0])) if np.any(peak > 0) else 0.0
    return math.sqrt(max(0.0, (width / 2.355) ** 2 - SHARP_EDGE_SIGMA_PX ** 2))


def _disc(shape, cx, cy, r, outside=False) -> np.ndarray:
    h, w = shape
    yy, xx = np.ogrid[:h, :w]
    inside = (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r
    return ~inside if outside else inside


# ----------------------------------------------------------------------------- the region

def default_margin_px(width: int, height: int, circle: Optional[ImageCircle] = None) -> float:
    """How far inside the boundary the usable region stops: 4 px or 0.6 % of the longer side, plus
    the width of the circle's soft edge (``ImageCircle.fall_px``) and three sigmas of its radius
    and centre when there is one."""
    m = max(4.0, 0.006 * max(width, height))
    if circle is not None:
        m += circle.fall_px + 3.0 * circle.radius_sigma_px + 3.0 * circle.centre_sigma_px
    return m


def find_image_region(image, margin_px: Optional[float] = None) -> ImageRegion:
    """The usable region of ``image`` (grey or BGR) and its image circle, if any (module
    docstring). ``margin_px``: override of ``default_margin_px``."""
    grey = _grey(image)
    h, w = grey.shape
    excluded = []
    black = _black_regions(grey)
    bars = _bars(grey)
    circle, _ = _find_circle(grey)
    margin = default_margin_px(w, h, circle) if margin_px is None else float(margin_px)
    k = int(2 * math.ceil(margin) + 1)
    bad = black | bars
    if bad.any():
        bad = cv2.dilate(bad.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        excluded.append('black or blown-out borders')
    mask = ~bad
    if circle is not None:
        mask &= _disc(grey.shape, circle.cx, circle.cy, circle.radius - margin)
        excluded.append(f'outside the image circle (centre {circle.cx:.1f}, {circle.cy:.1f}, radius '
                        f'{circle.radius:.1f} px)')
    return ImageRegion(mask, circle, margin, excluded)


def combine_circles(circles: Sequence[Optional[ImageCircle]]) -> Optional[ImageCircle]:
    """One camera's image circle from several images' measurements (None where an image showed
    none): inverse-variance weighted means; when the measurements scatter more than their
    sigmas allow (chi^2 per degree of freedom > 1), the sigmas are widened by that factor. The
    soft rim's ``edge_sigma_px`` is the largest seen: it is the lens's, which more images do not
    make sharper."""
    found = [c for c in circles if c is not None]
    if not found:
        return None
    if len(found) == 1:
        return found[0]

    def mean(values, sigmas):
        wts = 1.0 / np.square(sigmas)
        m = float(np.sum(wts * values) / np.sum(wts))
        sd = float(1.0 / math.sqrt(np.sum(wts)))
        chi2 = float(np.sum(wts * np.square(values - m))) / (len(values) - 1)
        return m, sd * math.sqrt(max(1.0, chi2))

    cs = np.array([c.centre_sigma_px for c in found])
    rs = np.array([c.radius_sigma_px for c in found])
    cx, sx = mean(np.array([c.cx for c in found]), cs)
    cy, sy = mean(np.array([c.cy for c in found]), cs)
    r, sr = mean(np.array([c.radius for c in found]), rs)
    return ImageCircle(cx, cy, r, max(sx, sy), sr, max(c.arc_deg for c in found),
                       sum(c.points for c in found), len(found), max(c.fall_px for c in found),
                       max(c.edge_sigma_px for c in found))
