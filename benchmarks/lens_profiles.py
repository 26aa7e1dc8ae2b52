#!/usr/bin/env python3
"""Zero-shot estimators against 4,913 real lens calibrations (../shared/data/lens_profiles_dev.csv).

Each row of the CSV is a real camera mode calibrated in the OpenCV fisheye / Kannala-Brandt model
(w, h, fx, fy, cx, cy, k1..k4). That calibration is the ground truth, and the "spec sheet" an
estimator receives is what the calibration implies:

* hfov: the angle between the rays of the pixels (0, cy) and (W, cy); vfov: between (cx, 0) and
  (cx, H); dfov: between (0, 0) and (W, H), (cx, cy) being the profile's own principal point.
  Below 180 degrees this is the plain angle between the two rays. When the two rays' off-axis
  angles add up to more than 180 degrees (a lens seeing beyond its side) the angle is measured
  through the optical axis (360 degrees minus the plain angle), which is what a spec sheet's
  "200 degrees" means (``wide_fov.fields_of_view_through_axis``).
* An estimator receives W, H and the FOVs (h + v, h + v + d, or one of them alone), never the
  calibration. The circle form ("circle"): an image circle as wide as the image's short side,
  centred on the image, and the FOV across its horizontal diameter at the principal point's row
  (what ``terms.FovTerm`` measures); its error is measured over the grid pixels inside that
  circle, as its error bar is.

Error of an estimate, per profile:

* reprojection: on a 33 x 19 grid of pixels spanning the whole image (corners and edges included),
  the ground truth's ray of each pixel is projected through the estimate; the RMS pixel distance
  to the pixel after the single best rotation of the rays (what the per-image extrinsics absorb
  in the paper's protocol: Kabsch on the rays, then Gauss-Newton on the pixel error), scaled to a
  1920-px-wide image;
* focal: |f - (fx + fy) / 2| / ((fx + fy) / 2).

Honesty, on the held-out split only (``build_lens_prior.held_out``: the camera models the
lens-law prior was not built from): every estimator of the solver also states ``uncertainty_px``
(``zero_shot_uncertainty``, FOV tolerance 1 degree, scaled to 1920 px like the error); the
table gives the share of held-out lenses whose true error is at most twice the stated one and
the median of true / stated.

Profiles an estimator cannot handle (it refuses the spec, or the estimate cannot image some of
the true rays) are counted per estimator in the table and listed in ``--failures FILE``
(default: next to ``--out``). Profiles whose ground truth is itself broken (Kannala-Brandt
polynomial not monotonic inside the image, rays that are NaN, implied FOVs that no camera spec
accepts) are excluded, counted, and listed with the reason in the same file.

    .venv/bin/python benchmarks/lens_profiles.py                      # full run, markdown to stdout
    .venv/bin/python benchmarks/lens_profiles.py --out benchmarks/results/lens_profiles.md
    .venv/bin/python benchmarks/lens_profiles.py --limit 200          # quick run

``ZEROSHOT_SHARED_DATA`` names the shared data folder when it is not ../shared/data.
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _path in (ROOT, ROOT / 'benchmarks'):
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

from build_lens_prior import held_out, shared_data_dir  # noqa: E402
from zeroshot_calib_ros.core.estimation.terms import FOV_TOLERANCE_DEG  # noqa: E402
from zeroshot_calib_ros.core.estimation.uncertainty import zero_shot_uncertainty  # noqa: E402
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, PinholeCamera, angle_between  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.solver import NoConvergence, solve_zero_shot  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec, SpecError  # noqa: E402
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis  # noqa: E402

DEFAULT_CSV = shared_data_dir() / 'lens_profiles_dev.csv'
GRID = (33, 19)
REFERENCE_WIDTH = 1920.0
WIDE_HFOV = 100.0
"""A profile is 'wide' when its implied hfov is at least this many degrees."""

COLUMNS = ('w', 'h', 'fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'k3', 'k4')


# ---------------------------------------------------------------------------------------------
# Ground truth


@dataclass
class Profile:
    index: int
    path: str
    brand: str
    model: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    D: np.ndarray

    @property
    def focal(self) -> float:
        return (self.fx + self.fy) / 2.0

    @property
    def held_out(self) -> bool:
        """Not among the lenses the lens-law prior was built from (build_lens_prior.held_out)."""
        return held_out(self.brand, self.model)

    def camera(self) -> 'GroundTruthCamera':
        return GroundTruthCamera(self.fx, self.fy, self.cx, self.cy, self.width, self.height, self.D)


def load_profiles(path=DEFAULT_CSV, limit: Optional[int] = None) -> List[Profile]:
    """The CSV's rows as Profiles, in file order (``limit``: the first N)."""
    profiles = []
    with open(path, newline='') as f:
        for i, row in enumerate(csv.DictReader(f)):
            if limit is not None and i >= limit:
                break
            v = {k: float(row[k]) for k in COLUMNS}
            profiles.append(Profile(i, row.get('path', str(i)), row.get('brand', ''), row.get('model', ''),
                                    int(v['w']), int(v['h']), v['fx'],
                                    v['fy'], v['cx'], v['cy'],
                                    np.array([v['k1'], v['k2'], v['k3'], v['k4']])))
    return profiles


def pixel_grid(width: int, height: int, grid=GRID) -> np.ndarray:
    """grid[0] x grid[1] pixels from (0, 0) to (W, H) inclusive, shape (N, 2)."""
    u, v = np.meshgrid(np.linspace(0.0, width, grid[0]), np.linspace(0.0, height, grid[1]))
    return np.stack([u.ravel(), v.ravel()], axis=-1)


class GroundTruthCamera(KannalaBrandtCamera):
    """A profile's Kannala-Brandt camera, inverted robustly on its monotonic branch.

    KannalaBrandtCamera.theta_from_theta_d runs Newton from theta = theta_d, which can fail
    (NaN) on strongly distorting but perfectly valid polynomials. Here theta_d(theta) is
    inverted by bisection on [0, theta_lim], theta_lim being where the polynomial first stops
    rising (or 180 degrees), then polished by Newton; radii beyond theta_d(theta_lim) are NaN."""

    SAMPLES = 20001

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        theta = np.linspace(0.0, np.pi, self.SAMPLES)
        slope = self._dtheta_d(theta)
        stop = np.nonzero(slope <= 0)[0]
        self.theta_lim = float(theta[stop[0] - 1]) if stop.size else float(np.pi)
        if stop.size and stop[0] == 0:
            self.theta_lim = 0.0
        self.theta_d_lim = float(self.theta_d(self.theta_lim))

    def theta_from_theta_d(self, theta_d, iterations: int = 0):
        theta_d = np.asarray(theta_d, dtype=float)
        lo = np.zeros_like(theta_d)
        hi = np.full_like(theta_d, self.theta_lim)
        for _ in range(56):
            mid = 0.5 * (lo + hi)
            below = self.theta_d(mid) < theta_d
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        theta = 0.5 * (lo + hi)
        for _ in range(2):
            theta = np.clip(theta - (self.theta_d(theta) - theta_d) / self._dtheta_d(theta), lo, hi)
        with np.errstate(invalid='ignore'):
            ok = (theta_d >= 0) & (theta_d <= self.theta_d_lim)
        return np.where(ok, theta, np.nan)


def ground_truth_problem(camera: GroundTruthCamera) -> Optional[tuple]:
    """(category, detail) of why the calibration cannot serve as ground truth, or None.

    The polynomial theta_d(theta) must rise monotonically from 0 to the normalised radius of the
    farthest image corner, else some pixels have no ray (or several)."""
    if not all(np.isfinite([camera.fx, camera.fy, camera.cx, camera.cy])) or not np.all(np.isfinite(camera.D)) \
            or camera.fx <= 0 or camera.fy <= 0:
        return 'non-finite or non-positive intrinsics', f'fx {camera.fx}, fy {camera.fy}, D {camera.D.tolist()}'
    corners = np.array([[0, 0], [camera.width, 0], [0, camera.height], [camera.width, camera.height]], float)
    r_max = float(np.max(np.hypot((corners[:, 0] - camera.cx) / camera.fx,
                                  (corners[:, 1] - camera.cy) / camera.fy)))
    if camera.theta_d_lim < r_max:
        return ('KB polynomial not monotonic inside the image (it turns back before the farthest '
                'corner, whose pixels then have no ray)',
                f'theta_d peaks at {camera.theta_d_lim:.4g} ({math.degrees(camera.theta_lim):.1f} deg '
                f'off-axis), the corner is at theta_d = {r_max:.4g}')
    rays = camera.unproject(pixel_grid(camera.width, camera.height))
    if not np.all(np.isfinite(rays)):
        return 'NaN rays on the evaluation grid', ''
    return None


# ---------------------------------------------------------------------------------------------
# Estimators: (W, H, fovs) -> camera model (raise SpecError / ValueError when not applicable)


def estimate_perspective(width, height, fovs):
    """A pinhole whose focal is the mean of the two perspective focals (Table 2, f~)."""
    focals = []
    for name, extent in (('hfov', width / 2.0), ('vfov', height / 2.0)):
        if fovs[name] >= 180.0:
            raise SpecError(name, fovs[name], 'less than 180 degrees', 'a pinhole cannot see 90 degrees off-axis')
        focals.append(extent / math.tan(math.radians(fovs[name]) / 2.0))
    f = sum(focals) / len(focals)
    return PinholeCamera(f, f, width / 2.0, height / 2.0, width, height)


def _solved(projection, names, lens_prior=True):
    def estimate(width, height, fovs):
        spec = CameraSpec(width, height, **{n: fovs[n] for n in names})
        return solve_zero_shot(spec, projection, lens_prior=lens_prior)
    return estimate


def circle_radius_of(width, height) -> float:
    """The image circle of the circle form: as wide as the short side, centred on the image."""
    return min(width, height) / 2.0


def circle_fov(camera, width, height) -> float:
    """Degrees across the circle's horizontal diameter at the principal point's row, through the
    axis beyond 180 (``terms.FovTerm``'s circle)."""
    r = circle_radius_of(width, height)
    rays = camera.unproject(np.array([[width / 2.0 - r, camera.cy], [width / 2.0 + r, camera.cy]]))
    off_axis = np.arctan2(np.linalg.norm(rays[:, :2], axis=-1), rays[:, 2])
    angle = float(angle_between(rays[0], rays[1]))
    if off_axis[0] + off_axis[1] > math.pi:
        angle = 2.0 * math.pi - angle
    return math.degrees(angle)


def estimate_circle(width, height, fovs):
    spec = CameraSpec(width, height, circle_diameter=2.0 * circle_radius_of(width, height), circle_fov=fovs['circle'])
    return solve_zero_shot(spec, 'auto')


@dataclass
class Estimator:
    name: str
    description: str
    estimate: Callable
    """(W, H, fovs) -> a camera, or a solve_zero_shot solution (which also states its error bar)."""
    inside_circle: bool = False
    """Errors over the grid pixels inside the circle form's image circle only."""


ESTIMATORS = [
    Estimator('perspective', 'pinhole, f = mean of the perspective focals of hfov and vfov (h+v)',
              estimate_perspective),
    Estimator('paper ZS', "the paper's zero-shot: equidistant G_w from hfov + vfov "
              "(solve_zero_shot(projection='equidistant'), h+v)",
              _solved('equidistant', ('hfov', 'vfov'))),
    Estimator('ours auto', "adaptive model selection with dfov (solve_zero_shot(projection='auto'), h+v+d)",
              _solved('auto', ('hfov', 'vfov', 'dfov'))),
    Estimator('wide (h+v+d)', "angle-space wide-FOV model (solve_zero_shot(projection='wide'), h+v+d)",
              _solved('wide', ('hfov', 'vfov', 'dfov'))),
    Estimator('wide (h+v)', "angle-space wide-FOV model from hfov + vfov only (projection='wide', h+v)",
              _solved('wide', ('hfov', 'vfov'))),
    Estimator('d only', "one FOV, dfov alone: the lens shape of real lenses of that FOV "
              "(solve_zero_shot, 'auto'; core/zeroshot/lens_prior.py)", _solved('auto', ('dfov',))),
    Estimator('h only', 'one FOV, hfov alone (as d only)', _solved('auto', ('hfov',))),
    Estimator('v only', 'one FOV, vfov alone (as d only)', _solved('auto', ('vfov',))),
    Estimator('circle', 'the circle form alone: an image circle as wide as the short side and its FOV; '
              'the pure equidistant law (errors inside the circle)', estimate_circle, inside_circle=True),
    Estimator('d only, no prior', "dfov alone read as the paper reads one FOV (lens_prior=False): a pinhole "
              "below 180 degrees, the pure law a = 1 from 180", _solved('auto', ('dfov',), lens_prior=False)),
    Estimator('h only, no prior', 'hfov alone, lens_prior=False (as d only, no prior)',
              _solved('auto', ('hfov',), lens_prior=False)),
]
HONESTY_FACTOR = 2.0
"""A stated error bar is honest for a lens when its true error is at most this many times it."""


# ---------------------------------------------------------------------------------------------
# Error metric


def _rotvec_matrix(v):
    """Rodrigues: rotation matrix of the rotation vector v."""
    angle = float(np.linalg.norm(v))
    if angle < 1e-300:
        return np.eye(3)
    k = v / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


def kabsch(a, b) -> np.ndarray:
    """Rotation R minimising sum |R a_i - b_i|^2 (rows of a and b are vectors)."""
    H = a.T @ b
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def best_rotation_rms(estimate, rays, pixels, iterations: int = 20):
    """RMS pixel distance between ``pixels`` and ``estimate.project(R rays)`` at the best R.

    R starts from Kabsch between the true rays and the estimate's rays of the same pixels, then
    Gauss-Newton (with step halving) on the pixel error over a rotation vector. Returns (rms, R);
    rms is NaN when the estimate cannot image some of the rays."""
    est_rays = estimate.unproject(pixels)
    ok = np.all(np.isfinite(est_rays), axis=1)
    R = kabsch(rays[ok], est_rays[ok]) if ok.sum() >= 3 else np.eye(3)

    def residual(Rm):
        return (estimate.project(rays @ Rm.T) - pixels).ravel()

    r = residual(R)
    if not np.all(np.isfinite(r)):
        r0 = residual(np.eye(3))
        if not np.all(np.isfinite(r0)):
            return float('nan'), R
        R, r = np.eye(3), r0
    cost = float(r @ r)
    eps = 1e-7
    for _ in range(iterations):
        J = np.empty((r.size, 3))
        for j in range(3):
            d = np.zeros(3)
            d[j] = eps
            J[:, j] = (residual(_rotvec_matrix(d) @ R) - r) / eps
        if not np.all(np.isfinite(J)):
            break
        try:
            step = -np.linalg.solve(J.T @ J + 1e-12 * np.eye(3), J.T @ r)
        except np.linalg.LinAlgError:
            break
        improved = False
        for _ in range(20):
            R_new = _rotvec_matrix(step) @ R
            r_new = residual(R_new)
            c_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
            if c_new <= cost:
                improved = True
                break
            step = step / 2.0
        if not improved:
            break
        done = cost - c_new <= 1e-12 * cost + 1e-18
        R, r, cost = R_new, r_new, c_new
        if done or np.linalg.norm(step) < 1e-12:
            break
    return math.sqrt(cost / len(pixels)), R


# ---------------------------------------------------------------------------------------------
# One profile


@dataclass
class Record:
    index: int
    path: str
    width: int
    height: int
    fovs: Dict[str, float] = field(default_factory=dict)
    max_angle_deg: float = float('nan')
    excluded: Optional[str] = None
    """Category of why the ground truth is unusable (None: usable)."""
    excluded_detail: str = ''
    held_out: bool = False
    """A camera model the lens-law prior was not built from."""
    rms: Dict[str, float] = field(default_factory=dict)
    """Reprojection RMS (px, scaled to a 1920-px-wide image) per estimator."""
    stated: Dict[str, float] = field(default_factory=dict)
    """Stated uncertainty_px (scaled like ``rms``) per estimator that states one (held-out only,
    unless every profile was asked for)."""
    focal_error: Dict[str, float] = field(default_factory=dict)
    failures: Dict[str, str] = field(default_factory=dict)


def evaluate_profile(profile: Profile, estimators=None, honesty: str = 'none') -> Record:
    """``honesty``: whose stated error bars to compute: 'held-out' profiles, 'all' or 'none'."""
    estimators = ESTIMATORS if estimators is None else estimators
    record = Record(profile.index, profile.path, profile.width, profile.height, held_out=profile.held_out)
    gt = profile.camera()
    problem = ground_truth_problem(gt)
    if problem:
        record.excluded, record.excluded_detail = problem
        return record
    fovs = fields_of_view_through_axis(gt)
    record.fovs = fovs
    record.max_angle_deg = math.degrees(gt.max_field_angle())
    try:
        CameraSpec(profile.width, profile.height, **fovs)
    except SpecError as exc:
        record.excluded = 'implied FOVs are not a valid camera spec'
        record.excluded_detail = str(exc)
        return record
    pixels = pixel_grid(profile.width, profile.height)
    rays = gt.unproject(pixels)
    inside = np.hypot(pixels[:, 0] - profile.width / 2.0, pixels[:, 1] - profile.height / 2.0) \
        <= circle_radius_of(profile.width, profile.height)
    given = dict(fovs, circle=circle_fov(gt, profile.width, profile.height))
    scale = REFERENCE_WIDTH / profile.width
    stating = honesty == 'all' or (honesty == 'held-out' and profile.held_out)
    for est in estimators:
        try:
            solution = est.estimate(profile.width, profile.height, given)
        except (SpecError, NoConvergence, ValueError) as exc:
            record.failures[est.name] = f'refused: {exc}'
            continue
        camera = getattr(solution, 'camera', solution)
        mask = inside if est.inside_circle else slice(None)
        rms, _ = best_rotation_rms(camera, rays[mask], pixels[mask])
        if not math.isfinite(rms):
            record.failures[est.name] = 'the estimate cannot image every true ray (rays beyond its field)'
            continue
        record.rms[est.name] = rms * scale
        record.focal_error[est.name] = abs(camera.fx - profile.focal) / profile.focal
        if stating and hasattr(solution, 'spec'):
            stated = zero_shot_uncertainty(solution.spec, FOV_TOLERANCE_DEG, solution).rms_px
            if stated is not None:
                record.stated[est.name] = stated * scale
    return record


def _evaluate_chunk(args):
    profiles, honesty = args
    return [evaluate_profile(p, honesty=honesty) for p in profiles]


def evaluate_all(profiles: List[Profile], jobs: int = 1, honesty: str = 'held-out') -> List[Record]:
    if jobs <= 1 or len(profiles) < 50:
        return _evaluate_chunk((profiles, honesty))
    from multiprocessing import get_context
    chunks = [(profiles[i::jobs * 8], honesty) for i in range(jobs * 8)]
    with get_context('fork' if hasattr(os, 'fork') else 'spawn').Pool(jobs) as pool:
        results = pool.map(_evaluate_chunk, chunks)
    records = [r for chunk in results for r in chunk]
    return sorted(records, key=lambda r: r.index)


# ---------------------------------------------------------------------------------------------
# Report

GROUPS = [
    ('all', lambda r: True),
    (f'wide (hfov >= {WIDE_HFOV:g})', lambda r: r.fovs['hfov'] >= WIDE_HFOV),
    (f'narrow (hfov < {WIDE_HFOV:g})', lambda r: r.fovs['hfov'] < WIDE_HFOV),
    ('any FOV >= 180 deg', lambda r: max(r.fovs.values()) >= 180.0),
    ('rays >= 90 deg off-axis', lambda r: r.max_angle_deg >= 90.0),
]

HEAD_TO_HEAD = [('ours auto', 'paper ZS'), ('wide (h+v+d)', 'paper ZS'), ('wide (h+v)', 'paper ZS'),
                ('paper ZS', 'perspective')]
"""Pairs compared profile by profile on the wide profiles both estimators handled."""
TIE_PX = 0.01


def _stat(values, q):
    return float(np.percentile(values, q)) if len(values) else float('nan')


def honesty(records: List[Record], name: str):
    """(n, share with true <= HONESTY_FACTOR x stated, median true / stated) over the records
    with both a true error and a stated one for estimator ``name``."""
    pairs = [(r.rms[name], r.stated[name]) for r in records if name in r.rms and name in r.stated]
    if not pairs:
        return 0, float('nan'), float('nan')
    true, stated = np.array(pairs).T
    return len(pairs), float(np.mean(true <= HONESTY_FACTOR * stated)), float(np.median(true / stated))


def summary_rows(records: List[Record], estimators=None):
    """[(group, n_profiles, estimator, n_handled, n_failed, rms median, rms p90, ferr median,
    ferr p90, held-out n, held-out rms median, honest share, median true / stated)] over the
    usable (not excluded) records; the last four on the held-out ones."""
    estimators = ESTIMATORS if estimators is None else estimators
    usable = [r for r in records if r.excluded is None]
    rows = []
    for group, member in GROUPS:
        members = [r for r in usable if member(r)]
        held = [r for r in members if r.held_out]
        for est in estimators:
            rms = [r.rms[est.name] for r in members if est.name in r.rms]
            ferr = [r.focal_error[est.name] for r in members if est.name in r.focal_error]
            failed = sum(1 for r in members if est.name in r.failures)
            held_rms = [r.rms[est.name] for r in held if est.name in r.rms]
            _, honest, ratio = honesty(held, est.name)
            rows.append((group, len(members), est.name, len(rms), failed,
                         _stat(rms, 50), _stat(rms, 90), 100 * _stat(ferr, 50), 100 * _stat(ferr, 90),
                         len(held_rms), _stat(held_rms, 50), 100 * honest, ratio))
    return rows


def head_to_head_rows(records: List[Record], pairs=HEAD_TO_HEAD):
    """[(a, b, n, median a, median b, median (a - b), share where a is better, share where a is
    worse)] over the usable wide profiles both a and b handled; 'better' / 'worse' mean by more
    than TIE_PX (the rest are ties)."""
    member = GROUPS[1][1]
    wide = [r for r in records if r.excluded is None and member(r)]
    rows = []
    for a, b in pairs:
        both = [r for r in wide if a in r.rms and b in r.rms]
        if not both:
            continue
        va = np.array([r.rms[a] for r in both])
        vb = np.array([r.rms[b] for r in both])
        rows.append((a, b, len(both), float(np.median(va)), float(np.median(vb)), float(np.median(va - vb)),
                     float(np.mean(va < vb - TIE_PX)), float(np.mean(va > vb + TIE_PX))))
    return rows


def _fmt(x, digits=2):
    return '-' if not math.isfinite(x) else f'{x:.{digits}f}'


def markdown_report(records: List[Record], source: str, seconds: float, failures_file: Optional[str],
                    estimators=None) -> str:
    estimators = ESTIMATORS if estimators is None else estimators
    excluded = [r for r in records if r.excluded is not None]
    usable = [r for r in records if r.excluded is None]
    lines = [
        '# Zero-shot estimators on real lens calibrations',
        '',
        f'Source: `{source}`, {len(records)} profiles; {len(usable)} usable, {len(excluded)} excluded '
        '(ground truth broken, see below). Generated by `benchmarks/lens_profiles.py` '
        f'in {seconds:.0f} s.',
        '',
        'Reprojection: RMS pixel error over a 33 x 19 grid spanning the image after the best '
        'rotation, scaled to a 1920-px-wide image (circle: the grid pixels inside the image '
        'circle). Focal: |f - (fx+fy)/2| / ((fx+fy)/2). '
        'Cells: median / 90th percentile over the profiles the estimator handled (n); '
        '"failed": profiles it refused or whose true rays it cannot image (listed in the '
        'failures file).',
        '',
        f'Held-out split (the {sum(r.held_out for r in usable)} usable profiles of camera models the lens-law '
        'prior was not built from, benchmarks/build_lens_prior.py): "held-out n" and its median RMS; '
        f'"honest": the share of them whose true error is at most {HONESTY_FACTOR:g} x the stated '
        'uncertainty_px (FOV tolerance 1 degree); "true/stated": the median of true / stated '
        '("-": the estimator states none).',
        '',
        '| group | profiles | estimator | n | failed | RMS px median | RMS px p90 | focal err % median '
        '| focal err % p90 | held-out n | held-out RMS px median | honest (held-out) | true/stated median |',
        '|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|',
    ]
    for group, n, name, handled, failed, m, p90, fm, fp90, hn, hm, honest, ratio in summary_rows(records, estimators):
        lines.append(f'| {group} | {n} | {name} | {handled} | {failed} | {_fmt(m)} | {_fmt(p90)} | '
                     f'{_fmt(fm, 1)} | {_fmt(fp90, 1)} | {hn} | {_fmt(hm)} | '
                     f'{_fmt(honest, 0) + " %" if math.isfinite(honest) else "-"} | {_fmt(ratio)} |')
    present = {e.name for e in estimators}
    pairs = [(a, b) for a, b in HEAD_TO_HEAD if a in present and b in present]
    if pairs:
        lines += ['', f'Head to head, RMS px on the wide profiles (hfov >= {WIDE_HFOV:g}) that both handled:', '',
                  '| A | B | n | A median | B median | median of A - B | A better | A worse |',
                  '|---|---|---:|---:|---:|---:|---:|---:|']
        for a, b, n, ma, mb, md, better, worse in head_to_head_rows(records, pairs):
            lines.append(f'| {a} | {b} | {n} | {ma:.2f} | {mb:.2f} | {md:+.3f} | {100 * better:.0f} % | '
                         f'{100 * worse:.0f} % |')
        lines.append(f'(better / worse: by more than {TIE_PX:g} px; the rest are ties)')
    lines += ['', 'Estimators:', '']
    lines += [f'- **{e.name}**: {e.description}' for e in estimators]
    reasons: Dict[str, int] = {}
    for r in excluded:
        reasons[r.excluded] = reasons.get(r.excluded, 0) + 1
    lines += ['', f'Excluded profiles ({len(excluded)}):', '']
    lines += [f'- {count}: {reason}' for reason, count in sorted(reasons.items(), key=lambda kv: -kv[1])]
    failure_counts = {e.name: sum(1 for r in usable if e.name in r.failures) for e in estimators}
    lines += ['', 'Failures per estimator: ' + ', '.join(f'{k} {v}' for k, v in failure_counts.items())]
    if failures_file:
        lines.append(f'(every excluded profile and every failure, with its reason: `{failures_file}`)')
    return '\n'.join(lines) + '\n'


def write_failures(records: List[Record], path: str):
    with open(path, 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['index', 'path', 'kind', 'estimator', 'reason'])
        for r in records:
            if r.excluded is not None:
                writer.writerow([r.index, r.path, 'excluded', '',
                                 f'{r.excluded}: {r.excluded_detail}' if r.excluded_detail else r.excluded])
            for name, reason in r.failures.items():
                writer.writerow([r.index, r.path, 'failed', name, reason])


def write_details(records: List[Record], path: str, estimators=None):
    """One row per profile: implied FOVs, largest ray angle, whether it is held out, and per
    estimator the RMS (px at 1920 wide), the focal error (fraction) and the stated uncertainty_px
    (px at 1920 wide), empty where it failed, states none or the profile was excluded."""
    estimators = ESTIMATORS if estimators is None else estimators
    with open(path, 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['index', 'path', 'width', 'height', 'hfov', 'vfov', 'dfov', 'max_angle_deg', 'excluded',
                         'held_out'] + [f'rms[{e.name}]' for e in estimators]
                        + [f'focal_error[{e.name}]' for e in estimators] + [f'stated[{e.name}]' for e in estimators])
        for r in records:
            fov = [f'{r.fovs[k]:.6f}' if k in r.fovs else '' for k in ('hfov', 'vfov', 'dfov')]
            writer.writerow([r.index, r.path, r.width, r.height, *fov,
                             '' if not math.isfinite(r.max_angle_deg) else f'{r.max_angle_deg:.4f}',
                             r.excluded or '', int(r.held_out)]
                            + [f'{r.rms[e.name]:.6f}' if e.name in r.rms else '' for e in estimators]
                            + [f'{r.focal_error[e.name]:.8f}' if e.name in r.focal_error else ''
                               for e in estimators]
                            + [f'{r.stated[e.name]:.6f}' if e.name in r.stated else '' for e in estimators])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--csv', default=str(DEFAULT_CSV),
                        help='lens profiles CSV (default: %(default)s; ZEROSHOT_SHARED_DATA names its folder)')
    parser.add_argument('--limit', type=int, help='only the first N profiles (quick run)')
    parser.add_argument('--out', help='also write the markdown table to this file')
    parser.add_argument('--failures', help='CSV of excluded profiles and estimator failures '
                                           '(default: <out without .md>_failures.csv when --out is given)')
    parser.add_argument('--details', help='also write every profile\'s FOVs and per-estimator errors to '
                                          'this CSV (about 1 MB for the full set)')
    parser.add_argument('--jobs', type=int, default=min(2, os.cpu_count() or 1),
                        help='worker processes (default: %(default)s)')
    parser.add_argument('--honesty', choices=('held-out', 'all', 'none'), default='held-out',
                        help='whose stated error bars to compute (default: %(default)s; 0.1 s per '
                             'profile and estimator)')
    args = parser.parse_args(argv)
    if not os.path.exists(args.csv):
        print(f'lens_profiles: error: {args.csv} not found (ZEROSHOT_SHARED_DATA names the shared data folder)',
              file=sys.stderr)
        return 2
    start = time.perf_counter()
    profiles = load_profiles(args.csv, args.limit)
    records = evaluate_all(profiles, args.jobs, args.honesty)
    seconds = time.perf_counter() - start
    failures = args.failures
    if failures is None and args.out:
        failures = os.path.splitext(args.out)[0] + '_failures.csv'
    details = args.details
    # the shared data folder by the name the repository gives it, wherever ZEROSHOT_SHARED_DATA puts it
    shown_csv = ('../shared/data/' + os.path.basename(args.csv)
                 if os.path.abspath(os.path.dirname(args.csv)) == os.path.abspath(shared_data_dir())
                 else os.path.relpath(args.csv, ROOT) if os.path.isabs(args.csv) else args.csv)
    report = markdown_report(records, shown_csv, seconds,
                             os.path.relpath(failures, ROOT) if failures else None)
    print(report, end='')
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, 'w') as f:
            f.write(report)
    if failures:
        write_failures(records, failures)
    if details:
        write_details(records, details)
    return 0


if __name__ == '__main__':
    sys.exit(main())
