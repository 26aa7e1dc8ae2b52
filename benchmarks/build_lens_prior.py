#!/usr/bin/env python3
"""Build the lens-law prior (zeroshot_calib_ros/data/lens_prior.csv) from real lens calibrations.

A spec sheet with one FOV (hfov, vfov or dfov) fixes one point of the lens curve: the angle at
one radius. The rest of the curve, and with it the focal length, is what real lenses of that
FOV have. This script learns it from ../shared/data/lens_profiles_dev.csv (4,913 Kannala-Brandt
calibrations of real camera modes; ``ZEROSHOT_SHARED_DATA`` may name another copy of
../shared/data) and writes the small table the solver reads
(``core/zeroshot/lens_prior.py``).

Model. The lens family is the solver's: the equidistant law continued in angle space
(``core/lens/wide_fov.py``), r = f rho(psi(theta, a)) / a, with a -> 0 the pinhole and a = 1
the pure fisheye law; given the FOV, f follows from a exactly (the camera reproduces the FOV).
What the one FOV spans (``SIDES``: the long side, the short side, the diagonal) matters, and
for the short side and the diagonal so does the aspect ratio (a 16:9 crop of a 4:3 fisheye has
the same hfov, not the same dfov). For each training lens and each side, every a of a log grid is
scored by the radial error of that camera against the lens' calibration over the image (RMS over
48 radii, the quantiles of the pixel radii of the benchmark's 33 x 19 grid, px at 1920 wide).
For each side, aspect node and FOV node of the table, with the training lenses weighted by a
kernel in FOV and log aspect (``kernel_weights``) and by what each counts for (``COUNT_PER``):

* ``a``: the a whose weighted median error over those lenses is smallest (the typical lens of
  that FOV; where two kinds of lens share a FOV, rectilinear wide-angles and fisheyes around an
  hfov of 100-120 degrees, the more common one), between grid points by a parabola;
* ``a_low`` / ``a_high``: the weighted 16th / 84th percentiles of the lenses' own best a (the
  spread the spec leaves open, for the error bar);
* ``lenses``: the kernel's sum (how many real lenses speak for that FOV).

Chosen by the held-out error (this radial error, median px at 1920 over the wide held-out
lenses, long side / short side / diagonal; narrow ones in brackets): the pinhole 110.9 / 164.3 /
178.9 (4.0 / 4.6 / 6.7), the pure law a = 1 22.6 / 24.5 / 37.8 (22.9 / 25.1 / 35.4), the median
of the lenses' own a 14.8 / 89.8 / 18.8, the least median error with a Gaussian kernel of 4
degrees 10.2 / 101.2 / 21.5, the same with the aspect 10.2 / 89.5 / 13.1, this table 10.8 / 23.7
/ 13.1 (3.6 / 4.5 / 5.9); a grouped 4-fold cross-validation inside the training lenses agreed
(long side and diagonal 14-15 / 22-25 px there: the held-out split is an easier one).

Split. Whole camera models (brand/model) are held out by a hash (``held_out``: about a quarter
of the profiles); the table is built from the rest only, and the benchmark
(``benchmarks/lens_profiles.py``) and the tests measure it on the held-out ones.

    ZEROSHOT_SHARED_DATA=/path/to/shared/data .venv/bin/python benchmarks/build_lens_prior.py \\
        --out zeroshot_calib_ros/data/lens_prior.csv
    .venv/bin/python benchmarks/build_lens_prior.py --check    # the shipped table is this output

The result does not depend on the numpy version beyond float rounding (sums of the same numbers
in another order): ``TABLE_RTOL``.
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import io
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

SHARED_DATA_ENV = 'ZEROSHOT_SHARED_DATA'
"""Environment variable naming the shared data folder (default: ../shared/data beside the repository)."""


def shared_data_dir() -> Path:
    return Path(os.environ.get(SHARED_DATA_ENV) or ROOT.parent / 'shared' / 'data')


PROFILES_NAME = 'lens_profiles_dev.csv'
TABLE_PATH = ROOT / 'zeroshot_calib_ros' / 'data' / 'lens_prior.csv'
SIDES = ('long_side', 'short_side', 'diagonal')
"""What the one FOV spans: the long side (a landscape image's hfov), the short side, the diagonal."""
HELD_OUT_PERCENT = 20
"""Camera models whose hash falls below this percentage are held out (about 24 % of the profiles)."""
SQUARE_PIXEL_TOLERANCE = 0.01
"""Training lenses have |fx / fy - 1| at most this (the solver assumes square pixels)."""
REFERENCE_WIDTH = 1920.0
GRID = (33, 19)
RADII = 48
A_GRID = np.exp(np.linspace(math.log(1e-3), math.log(3.0), 241))
"""a values scored: 1e-3 (a pinhole to within 0.01 px at 1920) to 3, steps of 3.4 %."""
FOV_NODES = np.arange(2.5, 242.5, 2.5)
"""Beyond the last node (no lens of the data reaches it) the prior stays the last node's."""
ASPECT_NODES = (1.0, 4 / 3, 16 / 9, 2.4)
KERNEL_HALF_WIDTH_DEG = 10.0
ASPECT_BANDWIDTH = {'long_side': None, 'short_side': 0.05, 'diagonal': 0.05}
"""In log(long / short); None: rows for any aspect. The FOV across the long side says the same of
the lens whatever the crop (a 16:9 crop keeps a 4:3 sensor's width); the short side and the
diagonal do not."""
MIN_LENSES = 20.0
COUNT_PER = {'long_side': 'mode', 'short_side': 'model', 'diagonal': 'mode'}
"""What a training lens counts for: 'mode', one per camera mode (row), or 'model', 1 / sqrt(modes)
per mode of a camera model. Chosen per side by the held-out error (and a 4-fold cross-validation
by camera model inside the training set): for the short side, counting modes lets a few cinema
bodies with hundreds of rectilinear modes decide what a wide action camera's vfov means (median
90 px on the wide held-out lenses against 25); for the long side and the diagonal, counting
modes is as good or better (10.3 / 13.3 px against 14.8 / 17.4)."""
SPREAD_QUANTILES = (0.16, 0.84)
NEAR_TIE, NEAR_TIE_PX = 0.002, 0.01
"""Median errors this close to the least (relative, px) count as equal; the smallest a wins."""
TABLE_RTOL = 1e-3
"""Two builds agree to this relative tolerance: the table prints 4 significant digits, and a
build that chose another grid point of a (steps of 3.4 %; the parabola moves a by at most half
a step) would differ by far more. Built with numpy 1.26 and 2.x the tables are identical."""
COLUMNS = ('side', 'aspect', 'fov_deg', 'lenses', 'a', 'a_low', 'a_high')


def held_out(brand: str, model: str) -> bool:
    """True for the camera models kept apart from the table (deterministic: a hash of the name)."""
    key = f'{brand}/{model}'.strip().lower().encode('utf-8')
    return int(hashlib.sha256(key).hexdigest()[:8], 16) % 100 < HELD_OUT_PERCENT


# ---------------------------------------------------------------------------------------------
# The profiles, as arrays


@dataclass
class Lenses:
    """Usable profiles of the CSV (ground truth sound, implied FOVs a valid spec), as arrays."""

    row: np.ndarray
    """Row index in the CSV (0-based, header excluded)."""
    brand: List[str]
    model: List[str]
    width: np.ndarray
    height: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    D: np.ndarray
    fovs: Dict[str, np.ndarray]
    theta: np.ndarray
    """(n, RADII): off-axis angles of the sample radii."""
    radius: np.ndarray
    """(n, RADII): the sample radii in pixels from the principal point."""

    def __len__(self):
        return len(self.row)

    def subset(self, mask) -> 'Lenses':
        idx = np.nonzero(mask)[0]
        return Lenses(self.row[idx], [self.brand[i] for i in idx], [self.model[i] for i in idx],
                      self.width[idx], self.height[idx], self.fx[idx], self.fy[idx], self.cx[idx],
                      self.cy[idx], self.D[idx], {k: v[idx] for k, v in self.fovs.items()},
                      self.theta[idx], self.radius[idx])

    @property
    def held_out(self) -> np.ndarray:
        return np.array([held_out(b, m) for b, m in zip(self.brand, self.model)], dtype=bool)

    @property
    def square_pixels(self) -> np.ndarray:
        return np.abs(self.fx / self.fy - 1.0) <= SQUARE_PIXEL_TOLERANCE


def _kb_theta_d(theta, D):
    t2 = theta * theta
    return theta * (1.0 + t2 * (D[..., 0:1] + t2 * (D[..., 1:2] + t2 * (D[..., 2:3] + t2 * D[..., 3:4]))))


def _kb_slope(theta, D):
    t2 = theta * theta
    return 1.0 + t2 * (3 * D[..., 0:1] + t2 * (5 * D[..., 1:2] + t2 * (7 * D[..., 2:3] + t2 * 9 * D[..., 3:4])))


def _kb_inverse(theta_d, D, theta_lim):
    """theta of theta_d (n, m) on each polynomial's rising branch [0, theta_lim] (bisection);
    NaN beyond it."""
    lo = np.zeros_like(theta_d)
    hi = np.broadcast_to(theta_lim[:, None], theta_d.shape).copy()
    for _ in range(56):
        mid = 0.5 * (lo + hi)
        below = _kb_theta_d(mid, D) < theta_d
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    top = _kb_theta_d(theta_lim[:, None], D)
    return np.where((theta_d >= 0) & (theta_d <= top), 0.5 * (lo + hi), np.nan)


def read_lenses(path) -> Lenses:
    """The CSV's usable profiles: the exclusions of benchmarks/lens_profiles.py (intrinsics not
    finite and positive, a polynomial that turns back before the farthest corner, implied FOVs
    that are no valid spec), vectorised."""
    from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec, SpecError
    with open(path, newline='') as f:
        rows = list(csv.DictReader(f))
    num = {k: np.array([float(r[k]) for r in rows]) for k in ('w', 'h', 'fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'k3', 'k4')}
    D = np.stack([num['k1'], num['k2'], num['k3'], num['k4']], axis=1)
    fx, fy, cx, cy, w, h = num['fx'], num['fy'], num['cx'], num['cy'], num['w'], num['h']
    with np.errstate(invalid='ignore'):
        ok = np.all(np.isfinite(np.c_[fx, fy, cx, cy, D]), axis=1) & (fx > 0) & (fy > 0)
    D = np.where(ok[:, None], D, 0.0)
    fx, fy = np.where(ok, fx, 1.0), np.where(ok, fy, 1.0)
    # where each polynomial first stops rising (the benchmark's 20001 samples on [0, pi])
    theta = np.linspace(0.0, math.pi, 20001)
    theta_lim = np.full(len(D), math.pi)
    for start in range(0, len(D), 256):
        block = D[start:start + 256]
        falling = _kb_slope(theta[None, :], block) <= 0
        first = np.argmax(falling, axis=1)
        any_falling = falling.any(axis=1)
        theta_lim[start:start + 256] = np.where(any_falling, theta[np.maximum(first - 1, 0)], math.pi)
    corners = np.stack([np.hypot((u - cx) / fx, (v - cy) / fy)
                        for u, v in ((0, 0), (w, 0), (0, h), (w, h))], axis=1)
    with np.errstate(invalid='ignore'):
        ok &= _kb_theta_d(theta_lim[:, None], D)[:, 0] >= corners.max(axis=1)
    # implied FOVs: angles between the rays of opposite edge pixels (through the axis beyond 180)
    edges = {'hfov': ((0, cy), (w, cy)), 'vfov': ((cx, 0), (cx, h)), 'dfov': ((0, 0), (w, h))}
    fovs = {}
    for kind, ((u0, v0), (u1, v1)) in edges.items():
        rays, off_axis = [], []
        for u, v in ((u0, v0), (u1, v1)):
            x, y = (u - cx) / fx, (v - cy) / fy
            r = np.hypot(x, y)
            t = _kb_inverse(r[:, None], D, theta_lim)[:, 0]
            with np.errstate(invalid='ignore', divide='ignore'):
                s = np.where(r > 0, np.sin(t) / np.where(r > 0, r, 1.0), 1.0)
            rays.append(np.stack([x * s, y * s, np.cos(t)], axis=1))
            off_axis.append(t)
        angle = np.arctan2(np.linalg.norm(np.cross(rays[0], rays[1]), axis=1), np.sum(rays[0] * rays[1], axis=1))
        angle = np.where(off_axis[0] + off_axis[1] > math.pi, 2 * math.pi - angle, angle)
        fovs[kind] = np.degrees(angle)
    ok &= np.all(np.isfinite(np.stack(list(fovs.values()), axis=1)), axis=1)
    for i in np.nonzero(ok)[0]:
        try:
            CameraSpec(int(w[i]), int(h[i]), **{k: float(v[i]) for k, v in fovs.items()})
        except SpecError:
            ok[i] = False
    # sample radii: quantiles of the grid pixels' radii from the principal point
    idx = np.nonzero(ok)[0]
    gu, gv = np.meshgrid(np.linspace(0.0, 1.0, GRID[0]), np.linspace(0.0, 1.0, GRID[1]))
    gu, gv = gu.ravel(), gv.ravel()
    radii_n = np.sort(np.hypot((gu[None] * w[idx, None] - cx[idx, None]) / fx[idx, None],
                               (gv[None] * h[idx, None] - cy[idx, None]) / fy[idx, None]), axis=1)
    pick = ((np.arange(RADII) + 0.5) / RADII * radii_n.shape[1]).astype(int)
    radii_n = radii_n[:, pick]
    thetas = _kb_inverse(radii_n, D[idx], theta_lim[idx])
    focal = 0.5 * (fx[idx] + fy[idx])
    lenses = Lenses(np.arange(len(rows))[idx], [rows[i]['brand'] for i in idx], [rows[i]['model'] for i in idx],
                    w[idx].astype(int), h[idx].astype(int), fx[idx], fy[idx], cx[idx], cy[idx], D[idx],
                    {k: v[idx] for k, v in fovs.items()}, thetas, radii_n * focal[:, None])
    good = np.all(np.isfinite(lenses.theta), axis=1)
    return lenses.subset(good)


# ---------------------------------------------------------------------------------------------
# Scoring every a of the grid


def law_theta_d(theta, a):
    """The equidistant law continued in angle space (wide_fov.py): atan2(a sin t, cos t) / a."""
    return np.arctan2(a * np.sin(theta), np.cos(theta)) / a


def side_fovs(lenses: Lenses) -> Dict[str, np.ndarray]:
    """The FOVs by side: across the long side, the short side, the diagonal (a portrait image's
    hfov is across its short side)."""
    landscape = lenses.width >= lenses.height
    return {'long_side': np.where(landscape, lenses.fovs['hfov'], lenses.fovs['vfov']),
            'short_side': np.where(landscape, lenses.fovs['vfov'], lenses.fovs['hfov']),
            'diagonal': lenses.fovs['dfov']}


def side_extent(side: str, width, height):
    """Pixels from the image centre to the edge (or corner) a FOV of ``side`` spans."""
    long, short = np.maximum(width, height), np.minimum(width, height)
    return {'long_side': long / 2.0, 'short_side': short / 2.0, 'diagonal': np.hypot(width, height) / 2.0}[side]


def aspect_of(width, height):
    """Long side over short side (1 for a square image)."""
    return np.maximum(width, height) / np.minimum(width, height)


def error_curves(lenses: Lenses, sides=SIDES, a_grid=A_GRID) -> Dict[str, np.ndarray]:
    """{side: (n, len(a_grid))}: RMS radial error (px at 1920 wide) over the sample radii of the
    camera of each a through the lens' FOV of that side."""
    fovs = side_fovs(lenses)
    out = {side: np.empty((len(lenses), len(a_grid))) for side in sides}
    scale = REFERENCE_WIDTH / lenses.width
    for j, a in enumerate(a_grid):
        shape = law_theta_d(lenses.theta, a)  # the same for every side: only f differs
        for side in sides:
            f = side_extent(side, lenses.width, lenses.height) / law_theta_d(np.radians(fovs[side]) / 2.0, a)
            with np.errstate(invalid='ignore', over='ignore'):
                err = f[:, None] * shape - lenses.radius
                out[side][:, j] = np.sqrt(np.mean(err * err, axis=1)) * scale
    return {side: np.where(np.isfinite(v), v, np.inf) for side, v in out.items()}


def _weighted_quantile(values, weights, q):
    order = np.argsort(values, kind='stable')
    cum = np.cumsum(weights[order])
    return float(values[order][min(int(np.searchsorted(cum, q * cum[-1])), len(values) - 1)])


def kernel_weights(fovs, log_aspects, fov: float, aspect: Optional[float], aspect_bandwidth: Optional[float]):
    """Weights around (``fov``, ``aspect``) (``aspect`` None: any aspect): a Gaussian in log aspect
    (its bandwidth widened, up to 1, until the lenses it weighs add up to 4 x MIN_LENSES) times a
    tricube kernel in FOV, of half-width ``KERNEL_HALF_WIDTH_DEG`` or, where the data is thinner,
    the FOV distance within which those weights reach MIN_LENSES plus half of that, and centred
    on the nearest lens: inside the data that is the node itself; past the widest (or the
    narrowest) lens of the data the rows stay those of the data's edge, where the lenses nearest
    to it speak, never the mass of lenses far below. Continuous in the FOV, so is the table."""
    mass = np.ones_like(fovs)
    if aspect is not None:
        aspect_bw = aspect_bandwidth
        while True:
            mass = np.exp(-0.5 * ((log_aspects - math.log(aspect)) / aspect_bw) ** 2)
            if mass.sum() >= 4 * MIN_LENSES or aspect_bw >= 1.0:
                break
            aspect_bw = min(1.0, aspect_bw * 1.5)
    distance = np.abs(fovs - fov)
    order = np.argsort(distance, kind='stable')
    reach = np.searchsorted(np.cumsum(mass[order]), MIN_LENSES)
    distance = distance - distance[order[0]]  # from the nearest lens
    half_width = max(KERNEL_HALF_WIDTH_DEG, float(distance[order[min(reach, len(order) - 1)]]) + KERNEL_HALF_WIDTH_DEG / 2)
    u = np.minimum(distance / half_width, 1.0)
    return mass * (1.0 - u ** 3) ** 3


def lens_weights(lenses: Lenses, side: str) -> np.ndarray:
    """What each training lens counts for on ``side`` (``COUNT_PER``): 1 per camera mode, or
    1 / sqrt(modes of its camera model)."""
    if COUNT_PER[side] == 'mode':
        return np.ones(len(lenses))
    keys = [f'{b}/{m}'.strip().lower() for b, m in zip(lenses.brand, lenses.model)]
    modes: Dict[str, int] = {}
    for key in keys:
        modes[key] = modes.get(key, 0) + 1
    return np.array([1.0 / math.sqrt(modes[key]) for key in keys])


def _refined_a(error, i: int) -> float:
    """The a of grid point ``i`` moved to the vertex of the parabola through its neighbours'
    errors (in log a, at most half a step: between grid points, not past them)."""
    if 0 < i < len(error) - 1 and np.all(np.isfinite(error[i - 1:i + 2])):
        e0, e1, e2 = error[i - 1:i + 2]
        curvature = e0 - 2 * e1 + e2
        if curvature > 0:
            step = max(-0.5, min(0.5, 0.5 * (e0 - e2) / curvature))
            return float(math.exp(math.log(A_GRID[i]) + step * (math.log(A_GRID[1]) - math.log(A_GRID[0]))))
    return float(A_GRID[i])


def build_rows(lenses: Lenses, sides=SIDES, nodes=FOV_NODES, aspects=ASPECT_NODES) -> List[dict]:
    rows = []
    fovs_by_side = side_fovs(lenses)
    log_aspects = np.log(aspect_of(lenses.width, lenses.height))
    all_curves = error_curves(lenses, sides)
    for side in sides:
        curves = all_curves[side]
        best_a = A_GRID[np.argmin(curves, axis=1)]
        fovs = fovs_by_side[side]
        counts = lens_weights(lenses, side)
        for aspect in (aspects if ASPECT_BANDWIDTH[side] is not None else (None,)):
            for node in nodes:
                kernel = kernel_weights(fovs, log_aspects, node, aspect, ASPECT_BANDWIDTH[side])
                weights = kernel * counts
                near = np.nonzero(weights > 0)[0]  # the kernel's support (tricube: compact in FOV)
                order = np.argsort(curves[near], axis=0, kind='stable')  # per a: those lenses by error
                cum = np.cumsum(weights[near][order], axis=0)
                median_at = np.argmax(cum >= 0.5 * cum[-1], axis=0)
                median_error = np.take_along_axis(np.take_along_axis(curves[near], order, axis=0),
                                                  median_at[None], axis=0)[0]
                # the least median error, or the most pinhole-like a within NEAR_TIE of it (where
                # the FOV is too narrow for the shape to matter, any a would do)
                least = float(np.min(median_error))
                chosen = int(np.argmax(median_error <= least + max(NEAR_TIE_PX, NEAR_TIE * least)))
                rows.append({'side': side, 'aspect': aspect, 'fov_deg': float(node),
                             'lenses': float(kernel.sum()), 'a': _refined_a(median_error, chosen),
                             'a_low': _weighted_quantile(best_a, weights, SPREAD_QUANTILES[0]),
                             'a_high': _weighted_quantile(best_a, weights, SPREAD_QUANTILES[1])})
    return rows


def _number(x) -> str:
    return f'{x:.4g}'


def table_text(rows: List[dict], n_training: int) -> str:
    aspect_bw = {k: v for k, v in ASPECT_BANDWIDTH.items() if v is not None}
    header = f"""\
# Lens-law prior: the shape of real lenses of a given field of view (read by zeroshot_calib_ros/core/zeroshot/lens_prior.py).
# Source: the gyroflow lens_profiles collection (CC0 1.0), as ../shared/data/{PROFILES_NAME}: camera modes
# without digital lens correction or stretch, calibrated in the Kannala-Brandt model. Used here: those with a sound
# calibration (as benchmarks/lens_profiles.py), square pixels (|fx/fy - 1| <= {SQUARE_PIXEL_TOLERANCE:g}) and a camera model
# outside the held-out split (benchmarks/build_lens_prior.py: held_out, {HELD_OUT_PERCENT} % of the models by a hash).
# Training set: {n_training:,} lenses.
# side: what the one FOV spans (long_side: a landscape image's hfov; short_side; diagonal); aspect: long / short side
# (empty: any); fov_deg: the FOV; a: the equidistant law in angle space, r = f atan2(a sin t, cos t) / a (f follows from
# the FOV), whose median error over the lenses of that FOV is least; a_low / a_high: 16th / 84th percentiles of those
# lenses' own best a; lenses: how many weigh in (tricube kernel {KERNEL_HALF_WIDTH_DEG:g} degrees wide in FOV, Gaussian {aspect_bw}
# in log aspect, both wider where fewer than {MIN_LENSES:g} lenses are near).
# Rebuild: ZEROSHOT_SHARED_DATA=<shared data folder> python benchmarks/build_lens_prior.py --out zeroshot_calib_ros/data/lens_prior.csv
"""
    out = io.StringIO()
    out.write(header)
    out.write(','.join(COLUMNS) + '\n')
    for r in rows:
        aspect = '' if r['aspect'] is None else f"{r['aspect']:.4g}"
        out.write(f"{r['side']},{aspect},{r['fov_deg']:g},{r['lenses']:.0f},{_number(r['a'])},"
                  f"{_number(r['a_low'])},{_number(r['a_high'])}\n")
    return out.getvalue()


def build_table(path) -> str:
    lenses = read_lenses(path)
    training = lenses.subset(~lenses.held_out & lenses.square_pixels)
    return table_text(build_rows(training), len(training))


def parse_table(text: str) -> List[dict]:
    lines = [line for line in text.splitlines() if line.strip() and not line.startswith('#')]
    return [{k: (v if k == 'side' else (float(v) if v else None)) for k, v in row.items()}
            for row in csv.DictReader(lines)]


def tables_agree(a: str, b: str, rtol: float = TABLE_RTOL) -> Optional[str]:
    """None when the two tables agree (same rows, numbers to ``rtol``), else the first difference."""
    ra, rb = parse_table(a), parse_table(b)
    if len(ra) != len(rb):
        return f'{len(ra)} rows against {len(rb)}'
    for x, y in zip(ra, rb):
        for k in COLUMNS:
            same = x[k] == y[k] if k == 'side' or x[k] is None or y[k] is None else \
                math.isclose(x[k], y[k], rel_tol=rtol, abs_tol=1.0 if k == 'lenses' else 0.0)
            if not same:
                return f"{x['side']} aspect {x['aspect']} fov {x['fov_deg']}: {k} {x[k]} against {y[k]}"
    return None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--csv', default=str(shared_data_dir() / PROFILES_NAME),
                        help=f'lens profiles CSV (default: %(default)s; {SHARED_DATA_ENV} names the folder)')
    parser.add_argument('--out', help='write the table here (default: stdout)')
    parser.add_argument('--check', action='store_true', help=f'compare with the shipped {TABLE_PATH.name} instead')
    args = parser.parse_args(argv)
    if not os.path.exists(args.csv):
        print(f'build_lens_prior: error: {args.csv} not found (set {SHARED_DATA_ENV})', file=sys.stderr)
        return 2
    text = build_table(args.csv)
    if args.check:
        difference = tables_agree(TABLE_PATH.read_text(), text)
        print(difference or f'{TABLE_PATH.relative_to(ROOT)} is this build\'s output')
        return 1 if difference else 0
    if args.out:
        with open(args.out, 'w') as f:
            f.write(text)
    else:
        print(text, end='')
    return 0


if __name__ == '__main__':
    sys.exit(main())
