#!/usr/bin/env python3
"""Zero-shot vs refined from straight lines, on real wide lenses (issue 13).

Profiles: the usable rows of ../shared/data/lens_profiles_dev.csv (``lens_profiles.py``'s loading
and exclusions) that are wide (implied hfov >= 100 degrees) with square pixels
(|fx - fy| / fx < 0.5 %), ``--profiles`` of them taken evenly through the file. The spec is what
the calibration implies (h + v + d, as the lens benchmark's 'ours auto'), exact unless
``--fov-round`` rounds it (a spec sheet's whole degrees: ``--fov-round 1``).

Evidence, ``--views`` views of one scene per profile:

- ``--evidence ideal``: the 3-D straight edges of a room (box edges, floor tiles, a door, windows,
  shelves) seen from random poses inside it, projected through the true camera, sampled every
  ~8 px along each visible run and perturbed by ``--noise`` px (Gaussian per coordinate); plus
  ``--outliers`` curved arcs per view (wheels, arches). Perfect line membership, no rendering.
- ``--evidence images``: the scene rendered through the true camera by ``test/scenes.py`` (ray
  cast, anti-aliased, textured, with curved distractors) and detected by
  ``core/lines/detect.py`` inside ``refine_from_images``. Profiles are scaled to
  ``--image-width`` px wide (the renderer's cost is per pixel); errors are reported at 1920 px
  as everywhere.

  ``--nuisances circle`` / ``all`` adds what real fisheye photos have (``test/scenes.py``'s
  ``Nuisances``): an image circle of radius 0.47 of the shorter side about the principal point,
  vignetted, with a dark but not black, noisy surround (and with ``all`` a vehicle body part at
  the bottom, blur, noise and JPEG); the spec is the profile's FOVs and the truth's FOV across
  that circle (what a circular fisheye's spec sheet states), and errors are over the circle.

- ``--evidence real``: the shared real images ``../shared/data/ros_fisheye_800x503`` (24 images
  800x503 of a wide lens with a checkerboard in each; its edges count as lines like any other,
  its geometry is not used), refined from ``--real-images`` of them (default 4 and all 24,
  evenly through the set), the spec's hfov / vfov derived from the authors' ``ost.yaml`` read
  as Kannala-Brandt (as ``paper_table4.py`` does), errors against ``ost.yaml``.

Metric: the lens benchmark's (``lens_profiles.best_rotation_rms``): RMS pixel error over a
33 x 19 grid after the best rotation, scaled to a 1920-px-wide image, for the zero-shot camera
(KB4 fit of 'auto', what the product publishes) and for the camera ``refine_camera`` returns
(refined when accepted, zero-shot otherwise). Uncertainty honesty: the fraction of profiles
whose true error is within 2x the reported ``uncertainty_px``.

    .venv/bin/python benchmarks/line_refinement.py --evidence ideal --profiles 80 \\
        --out benchmarks/results/line_refinement.md
    .venv/bin/python benchmarks/line_refinement.py --evidence images --profiles 60 \
        --render-cache /tmp/renders [--shard K/2 --dump DIR]   # then --rows-from DIR for the report
    .venv/bin/python benchmarks/line_refinement.py --evidence real --real-images 4,24

Constants are tuned on ``--tuning-set`` (the profiles halfway between the default ones) and
reported on the default set.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / 'benchmarks'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

import lens_profiles as lp  # noqa: E402
from zeroshot_calib_ros.core.estimation.refine import refine_camera, refine_from_images  # noqa: E402
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec, SpecError  # noqa: E402

SQUARE_PIXELS = 0.005
WORSE_PX = 0.3


# ---------------------------------------------------------------------------------------------
# Profiles


def wide_square_profiles(csv=lp.DEFAULT_CSV):
    """(profile, implied FOVs) of every usable wide square-pixel profile, in file order."""
    out = []
    for p in lp.load_profiles(csv):
        gt = p.camera()
        if lp.ground_truth_problem(gt) or abs(p.fx - p.fy) / p.fx >= SQUARE_PIXELS:
            continue
        fovs = fields_of_view_through_axis(gt)
        if not fovs['hfov'] >= lp.WIDE_HFOV:
            continue
        try:
            CameraSpec(p.width, p.height, **fovs)
        except SpecError:
            continue
        out.append((p, fovs))
    return out


def evenly(items, n, shift: float = 0.0):
    """``n`` items evenly through ``items``; ``shift`` 0.5 takes those halfway between (a disjoint
    set of the same spread when n is well under len(items) / 2: the tuning set)."""
    if n >= len(items):
        return list(items)
    step = (len(items) - 1) / max(n - 1, 1)
    picks = np.linspace(0, len(items) - 1, n) + shift * step
    return [items[int(i)] for i in np.clip(picks, 0, len(items) - 1).round()]


# ---------------------------------------------------------------------------------------------
# Ideal evidence: 3-D lines of a room projected through the true camera


def room_segments(rng):
    """(segments (N, 2, 3) in metres, half sizes (X, Y, Z)) of a box room, y down, with floor
    tiles, a door, two windows and shelves."""
    X, Y, Z = rng.uniform(2.5, 4.0), rng.uniform(1.2, 1.6), rng.uniform(3.0, 5.0)
    segs = []
    corners = [(sx * X, sy * Y, sz * Z) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    for i, a in enumerate(corners):
        for b in corners[i + 1:]:
            if sum(abs(p - q) > 1e-9 for p, q in zip(a, b)) == 1:
                segs.append((a, b))
    for x in np.arange(-X + 1.0, X, 1.0):
        segs.append(((x, Y, -Z), (x, Y, Z)))
    for z in np.arange(-Z + 1.0, Z, 1.5):
        segs.append(((-X, Y, z), (X, Y, z)))
    x0 = rng.uniform(-X + 0.5, X - 1.5)
    segs += [((x0, -0.7, Z), (x0, Y, Z)), ((x0 + 0.9, -0.7, Z), (x0 + 0.9, Y, Z)),
             ((x0, -0.7, Z), (x0 + 0.9, -0.7, Z))]
    for sx in (-1, 1):
        z0 = rng.uniform(-Z + 0.5, Z - 2.0)
        y0, y1 = -0.9, 0.3
        segs += [((sx * X, y0, z0), (sx * X, y0, z0 + 1.5)), ((sx * X, y1, z0), (sx * X, y1, z0 + 1.5)),
                 ((sx * X, y0, z0), (sx * X, y1, z0)), ((sx * X, y0, z0 + 1.5), (sx * X, y1, z0 + 1.5))]
    for y in (-0.6, 0.0, 0.6):
        segs.append(((-X + 0.3, y, -Z), (-X + 2.3, y, -Z)))
    return np.array(segs, dtype=float), (X, Y, Z)


def _rotation(yaw, pitch, roll):
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Rz @ Rx @ Ry


def view_curves(camera, theta_lim, segs, box, rng, noise=0.3, spacing_px=8.0, max_points=40,
                min_length=0.06, samples=800):
    """Curves (N, 2) of the segments visible from a random pose: each visible run of a segment,
    at least ``min_length`` x the width long, sampled every ``spacing_px`` along the image."""
    X, Y, Z = box
    position = np.array([rng.uniform(-0.5, 0.5) * X, rng.uniform(-0.3, 0.3) * Y, rng.uniform(-0.5, 0.5) * Z])
    R = _rotation(rng.uniform(0, 2 * math.pi), math.radians(rng.normal(0, 15)), math.radians(rng.normal(0, 5)))
    W, H = camera.width, camera.height
    curves = []
    t = np.linspace(0, 1, samples)
    for a, b in segs:
        rays = (a[None] + t[:, None] * (b - a)[None] - position) @ R.T
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        theta = np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2])
        px = camera.project(rays)
        ok = (theta < theta_lim) & np.all(np.isfinite(px), axis=1) & (px[:, 0] > 1) & (px[:, 0] < W - 1) \
            & (px[:, 1] > 1) & (px[:, 1] < H - 1)
        idx = np.nonzero(ok)[0]
        for run in np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1) if idx.size else []:
            if len(run) < 5:
                continue
            pts = px[run]
            arc = np.r_[0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
            if arc[-1] < min_length * W:
                continue
            n = int(min(max_points, max(8, arc[-1] / spacing_px)))
            tt = np.interp(np.linspace(0, arc[-1], n), arc, t[run])
            rq = (a[None] + tt[:, None] * (b - a)[None] - position) @ R.T
            q = camera.project(rq / np.linalg.norm(rq, axis=1, keepdims=True))
            curves.append(q + rng.normal(0, noise, q.shape))
    return curves


def outlier_curves(width, height, rng, count=2, noise=0.3):
    """Curved arcs (a wheel, an arch): circles of 8-20 % of the width, 90-170 degrees of arc."""
    out = []
    for _ in range(count):
        r = rng.uniform(0.08, 0.2) * width
        c = np.array([rng.uniform(0.25, 0.75) * width, rng.uniform(0.25, 0.75) * height])
        a0 = rng.uniform(0, 2 * math.pi)
        ang = np.linspace(a0, a0 + rng.uniform(1.5, 3.0), 30)
        pts = c + r * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        out.append(pts + rng.normal(0, noise, pts.shape))
    return out


@dataclass
class IdealCurve:
    points: np.ndarray
    image: int
    view: int = -1


def ideal_evidence(gt, views, rng, noise, outliers):
    segs, box = room_segments(rng)
    curves = []
    for v in range(views):
        for c in view_curves(gt, gt.theta_lim, segs, box, rng, noise) + \
                outlier_curves(gt.width, gt.height, rng, outliers, noise):
            curves.append(IdealCurve(c, v))
    return curves


# ---------------------------------------------------------------------------------------------
# One profile


@dataclass
class Row:
    index: int
    path: str
    width: int
    height: int
    zs_px: float = math.nan
    out_px: float = math.nan
    """Error of the camera refine_camera returns (refined if accepted, else zero-shot)."""
    fit_px: float = math.nan
    """Error of the fitted camera, accepted or not."""
    accepted: bool = False
    reason: str = ''
    zs_u: float = math.nan
    out_u: float = math.nan
    pp_zs: float = math.nan
    pp_out: float = math.nan
    seconds_per_image: float = math.nan
    lines: int = 0
    curves: int = 0
    order: Optional[int] = None
    failure: str = ''
    seconds_total: float = 0.0
    """Wall time of the profile (rendering included)."""


def _scaled_profile(p, fovs, width):
    """The profile's camera at ``width`` px wide (same aspect), its FOVs unchanged."""
    gt = p.camera()
    if width is None or width >= p.width:
        return gt
    s = width / p.width
    h = int(round(p.height * s))
    return lp.GroundTruthCamera(p.fx * s, p.fy * h / p.height, p.cx * s, p.cy * h / p.height, width, h, p.D)


NUISANCE_CIRCLE = 0.47
"""--nuisances: the image circle's radius, as a fraction of the shorter side."""


def _nuisances(scenes, kind: str, gt):
    """test/scenes.py's Nuisances for ``--nuisances``: none; 'circle', a vignetted image circle
    (radius NUISANCE_CIRCLE of the shorter side, about the principal point) with a dark, noisy,
    glowing surround; 'all', that and a vehicle body part at the bottom, blur, noise and JPEG."""
    if kind == 'none':
        return None
    radius = NUISANCE_CIRCLE * min(gt.width, gt.height)
    if kind == 'circle':
        return scenes.Nuisances(circle_radius=radius)
    return scenes.Nuisances(circle_radius=radius, vehicle=True, blur=0.6, noise=2.0, jpeg_quality=80)


def profile_spec(gt, fovs, args) -> CameraSpec:
    """The spec of a (scaled) profile: its FOVs (rounded with ``--fov-round``), and with
    ``--nuisances`` the truth's FOV across the image circle (raises SpecError)."""
    given = {k: (round(v / args.fov_round) * args.fov_round if args.fov_round else v) for k, v in fovs.items()}
    form = getattr(args, 'spec', 'hvd')
    if form != 'hvd':  # one FOV alone, as most spec sheets print
        if not math.isfinite(given.get(form, math.nan)):
            raise SpecError(form, given.get(form), 'a finite FOV', 'the profile has none', missing=form not in given)
        given = {form: given[form]}
    if args.evidence == 'images' and args.nuisances != 'none':
        # a circular fisheye's spec sheet states the FOV across its image circle: the truth's
        radius = NUISANCE_CIRCLE * min(gt.width, gt.height)
        ray = gt.unproject(np.array([[gt.cx + radius, gt.cy]]))[0]
        circle_fov = 2 * math.degrees(math.atan2(math.hypot(ray[0], ray[1]), ray[2]))
        given = dict(given, circle_diameter=2 * radius, circle_fov=circle_fov)
    return CameraSpec(gt.width, gt.height, **given)


def profile_seed(args, p) -> int:
    """The seed of a profile's evidence (scene, poses, noise)."""
    return args.seed * 100003 + p.index


def render_views(p, gt, args, seed) -> list:
    """``args.views`` views of ``args.scene`` rendered through ``gt`` (with ``args.nuisances``),
    read from / written to ``args.render_cache`` when given."""
    sys.path.insert(0, str(ROOT / 'test'))
    import scenes
    scene = scenes.make_scene(args.scene, seed % 1000)
    images = []
    for v in range(args.views):
        tag = '' if args.nuisances == 'none' else f'_{args.nuisances}'
        cache = (Path(args.render_cache) / f'{args.scene}_{p.index}_{gt.width}_{seed}_{v}{tag}.png'
                 if args.render_cache else None)
        if cache is not None and cache.exists():
            images.append(cv2.imread(str(cache), cv2.IMREAD_UNCHANGED))
            continue
        pose = scenes.random_pose(scene, seed % 1000 * 10 + v)
        image, _ = scenes.render(gt, scene, pose=pose, seed=seed % 1000 * 10 + v,
                                 nuisances=_nuisances(scenes, args.nuisances, gt))
        if cache is not None:
            cache.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(cache), image)
        images.append(image)
    return images


def error_pixels(gt, args) -> np.ndarray:
    """The pixels errors are measured over: the 33 x 19 grid, or with ``--nuisances`` the points
    of a 65 x 37 grid inside the image circle (nothing outside it is imaged)."""
    if args.evidence == 'images' and args.nuisances != 'none':
        pixels = lp.pixel_grid(gt.width, gt.height, (65, 37))
        radius = NUISANCE_CIRCLE * min(gt.width, gt.height)
        return pixels[np.hypot(pixels[:, 0] - gt.cx, pixels[:, 1] - gt.cy) <= radius]
    return lp.pixel_grid(gt.width, gt.height)


def evaluate(p, fovs, args, seed) -> Row:
    rng = np.random.default_rng(seed)
    gt = _scaled_profile(p, fovs, args.image_width if args.evidence == 'images' else None)
    row = Row(p.index, p.path, gt.width, gt.height)
    try:
        spec = profile_spec(gt, fovs, args)
    except SpecError as exc:
        row.failure = f'spec refused: {exc}'
        return row
    start = time.perf_counter()
    try:
        if args.evidence == 'ideal':
            curves = ideal_evidence(gt, args.views, rng, args.noise, args.outliers)
            result = refine_camera(spec, curves, fov_tolerance_deg=args.fov_tolerance)
        else:
            images = render_views(p, gt, args, seed)
            start = time.perf_counter()
            result = refine_from_images(spec, images, fov_tolerance_deg=args.fov_tolerance)
    except (SpecError, ValueError) as exc:
        row.failure = f'{type(exc).__name__}: {exc}'
        return row
    row.seconds_per_image = (time.perf_counter() - start) / args.views
    if args.dump:
        import pickle
        os.makedirs(args.dump, exist_ok=True)
        with open(os.path.join(args.dump, f'{p.index}.pkl'), 'wb') as f:
            pickle.dump({'gt': gt, 'spec': spec, 'result': result,
                         'curves': curves if args.evidence == 'ideal' else None}, f)
    pixels = error_pixels(gt, args)
    rays = gt.unproject(pixels)
    scale = lp.REFERENCE_WIDTH / gt.width
    row.zs_px = lp.best_rotation_rms(result.zero_shot_camera, rays, pixels)[0] * scale
    row.out_px = lp.best_rotation_rms(result.camera, rays, pixels)[0] * scale
    if result.refined_camera is not None:
        row.fit_px = lp.best_rotation_rms(result.refined_camera, rays, pixels)[0] * scale
    row.accepted = result.accepted
    row.reason = result.reason
    row.zs_u = (result.zero_shot_uncertainty_px or math.nan) * scale
    row.out_u = (result.uncertainty_px or math.nan) * scale
    row.pp_zs = math.hypot(result.zero_shot_camera.cx - gt.cx, result.zero_shot_camera.cy - gt.cy) * scale
    row.pp_out = math.hypot(result.camera.cx - gt.cx, result.camera.cy - gt.cy) * scale
    row.lines = result.lines_used
    row.curves = result.curves_given
    row.order = result.order
    return row


# ---------------------------------------------------------------------------------------------
# Report


def _q(values, q):
    values = np.asarray([v for v in values if math.isfinite(v)])
    return float(np.percentile(values, q)) if values.size else math.nan


def _f(x, d=2):
    return '-' if not math.isfinite(x) else f'{x:.{d}f}'


def _reason_kind(reason: str) -> str:
    return reason.split(':')[0] if reason else ''


def report(rows: List[Row], args, seconds: float, command: str, table: bool = True) -> str:
    ok = [r for r in rows if not r.failure and math.isfinite(r.zs_px) and math.isfinite(r.out_px)]
    acc = [r for r in ok if r.accepted]
    worse = [r for r in acc if r.out_px > r.zs_px + WORSE_PX]
    honest_zs = np.mean([r.zs_px <= 2 * r.zs_u for r in ok]) if ok else math.nan
    honest_out = np.mean([r.out_px <= 2 * r.out_u for r in ok]) if ok else math.nan
    honest_acc = np.mean([r.out_px <= 2 * r.out_u for r in acc]) if acc else math.nan
    within_zs = np.mean([r.zs_u / 2 <= r.zs_px <= 2 * r.zs_u for r in ok]) if ok else math.nan
    within_out = np.mean([r.out_u / 2 <= r.out_px <= 2 * r.out_u for r in ok]) if ok else math.nan
    fov = 'exact' if not args.fov_round else f'rounded to {args.fov_round:g} degree(s)'
    fov_short = 'exact' if not args.fov_round else f'rounded to {args.fov_round:g}'
    lines = [
        f'## Line refinement: zero-shot vs refined ({args.evidence} evidence, FOVs {fov_short}, '
        f'tolerance {args.fov_tolerance:g} deg)',
        '',
        f'`{command}` ({seconds:.0f} s).',
        '',
        f'{len(rows)} wide (hfov >= {lp.WIDE_HFOV:g}) square-pixel (|fx - fy| / fx < {100 * SQUARE_PIXELS:g} %) '
        f'profiles of `../shared/data/lens_profiles_dev.csv`, taken evenly through the file; spec ' + {'hvd': 'h + v + d', 'hfov': 'hfov alone', 'dfov': 'dfov alone'}[getattr(args, 'spec', 'hvd')] + ', '
        f'{fov}; FOV tolerance {args.fov_tolerance:g} degree(s); {args.views} views each; '
        + (f'noise {args.noise:g} px, {args.outliers} curved outlier arcs per view.' if args.evidence == 'ideal'
           else f'scene `{args.scene}` rendered by test/scenes.py at {args.image_width} px wide, curves from '
                'core/lines/detect.py (refine_from_images)'
                + ('.' if getattr(args, 'nuisances', 'none') == 'none' else
                   f'; nuisances `{args.nuisances}`: an image circle of radius {NUISANCE_CIRCLE:g} of the shorter '
                   'side, vignetted, with a dark noisy surround' + (', a vehicle body part, blur, noise, JPEG 80'
                                                                    if args.nuisances == 'all' else '') + '.')),
        '',
        ('Errors: RMS over a 33 x 19 grid after the best rotation, px at 1920 wide (the lens benchmark\'s metric). '
         if getattr(args, 'nuisances', 'none') == 'none' else
         'Errors: RMS over the points of a 65 x 37 grid inside the image circle (nothing outside it is imaged) '
         'after the best rotation, px at 1920 wide. ') +
        '"returned": the camera refine_camera returns (refined when the gate accepts, zero-shot otherwise); '
        '"fitted": the refined fit whether accepted or not.',
        '',
        '| | n | median px | p90 px |',
        '|---|---:|---:|---:|',
        f'| zero-shot (auto, KB4 fit) | {len(ok)} | {_f(_q([r.zs_px for r in ok], 50))} | '
        f'{_f(_q([r.zs_px for r in ok], 90))} |',
        f'| returned | {len(ok)} | {_f(_q([r.out_px for r in ok], 50))} | {_f(_q([r.out_px for r in ok], 90))} |',
        f'| fitted | {sum(math.isfinite(r.fit_px) for r in ok)} | {_f(_q([r.fit_px for r in ok], 50))} | '
        f'{_f(_q([r.fit_px for r in ok], 90))} |',
        f'| zero-shot, accepted profiles | {len(acc)} | {_f(_q([r.zs_px for r in acc], 50))} | '
        f'{_f(_q([r.zs_px for r in acc], 90))} |',
        f'| refined, accepted profiles | {len(acc)} | {_f(_q([r.out_px for r in acc], 50))} | '
        f'{_f(_q([r.out_px for r in acc], 90))} |',
        '',
        f'- acceptance rate: {len(acc)} / {len(ok)} ({100 * len(acc) / max(len(ok), 1):.0f} %)',
        f'- accepted and worse than zero-shot by more than {WORSE_PX:g} px: {len(worse)}'
        + (' (' + ', '.join(f'{r.path}: {r.zs_px:.2f} -> {r.out_px:.2f}' for r in worse) + ')' if worse else ''),
        f'- principal point error, px at 1920, median / p90: zero-shot {_f(_q([r.pp_zs for r in ok], 50))} / '
        f'{_f(_q([r.pp_zs for r in ok], 90))}, returned {_f(_q([r.pp_out for r in ok], 50))} / '
        f'{_f(_q([r.pp_out for r in ok], 90))}',
        '- seconds per image (refine_camera' + ('' if args.evidence == 'ideal' else ' with detection') +
        f'), median / max: {_f(_q([r.seconds_per_image for r in ok], 50))} / '
        f'{_f(_q([r.seconds_per_image for r in ok], 100))}',
        f'- lines used per profile, median: {_f(_q([r.lines for r in ok], 50), 0)} '
        f'(curves given {_f(_q([r.curves for r in ok], 50), 0)})',
        f'- uncertainty honesty (true error <= 2 x uncertainty_px): zero-shot {100 * honest_zs:.0f} %, '
        f'returned {100 * honest_out:.0f} %, accepted refined {100 * honest_acc:.0f} %',
        f'- uncertainty sharpness (uncertainty / 2 <= true error <= 2 x uncertainty): zero-shot '
        f'{100 * within_zs:.0f} %, returned {100 * within_out:.0f} %',
        f'- uncertainty px at 1920, median: zero-shot {_f(_q([r.zs_u for r in ok], 50))}, returned '
        f'{_f(_q([r.out_u for r in ok], 50))}',
    ]
    kinds: Dict[str, int] = {}
    for r in ok:
        if not r.accepted:
            kinds[_reason_kind(r.reason)] = kinds.get(_reason_kind(r.reason), 0) + 1
    if kinds:
        lines.append('- refusals: ' + ', '.join(f'{v} {k}' for k, v in sorted(kinds.items(), key=lambda kv: -kv[1])))
    failures = [r for r in rows if r.failure]
    if failures:
        lines.append(f'- failures ({len(failures)}): ' + '; '.join(f'{r.path}: {r.failure}' for r in failures[:10]))
    orders: Dict[str, int] = {}
    for r in ok:
        orders[str(r.order)] = orders.get(str(r.order), 0) + 1
    lines.append('- model order chosen (KB coefficients moved by the lines): '
                 + ', '.join(f'{k}: {v}' for k, v in sorted(orders.items())))
    if not table:
        return '\n'.join(lines) + '\n'
    lines += ['', '| profile | size | zero-shot px | returned px | fitted px | accepted | lines | order | u zero-shot '
                  '| u returned | reason |',
              '|---|---|---:|---:|---:|---|---:|---:|---:|---:|---|']
    for r in rows:
        lines.append(f'| {r.path} | {r.width}x{r.height} | {_f(r.zs_px)} | {_f(r.out_px)} | {_f(r.fit_px)} | '
                     f'{"yes" if r.accepted else "no"} | {r.lines} | {r.order} | {_f(r.zs_u)} | {_f(r.out_u)} | '
                     f'{(r.failure or r.reason)[:120]} |')
    return '\n'.join(lines) + '\n'


# ---------------------------------------------------------------------------------------------
# The shared real images: ros_fisheye_800x503 against its authors' ost.yaml

DEFAULT_REAL = ROOT.parent / 'shared' / 'data' / 'ros_fisheye_800x503'


def real_spec_and_truth(data: Path):
    """(spec, authors' camera) of the shared set: hfov / vfov from ost.yaml read as
    Kannala-Brandt (as benchmarks/paper_table4.py derives them; the set has no spec sheet)."""
    from zeroshot_calib_ros.core.lens.models import camera_from_calibration
    from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
    ost = CameraCalibration.load(str(data / 'ost.yaml'))
    authors = camera_from_calibration('equidistant', ost.K, ost.D, ost.width, ost.height)
    fovs = authors.fields_of_view()
    return CameraSpec(ost.width, ost.height, hfov=fovs['hfov'], vfov=fovs['vfov']), authors


def real_images(data: Path, count: Optional[int]):
    """``count`` of the set's images, evenly through it (all when None)."""
    paths = sorted(data.glob('left-*.png'))
    if count is not None and count < len(paths):
        paths = [paths[int(i)] for i in np.linspace(0, len(paths) - 1, count).round()]
    return paths


def real_run(data: Path, count: Optional[int], fov_tolerance: float = 1.0) -> dict:
    """Refine from ``count`` images of the set (straight lines only: the board's edges count as
    lines, its geometry is not used); errors against ost.yaml with the lens benchmark's metric
    (RMS over a 33 x 19 grid after the best rotation), scaled to 1920 px wide."""
    spec, authors = real_spec_and_truth(data)
    paths = real_images(data, count)
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    start = time.perf_counter()
    result = refine_from_images(spec, images, fov_tolerance_deg=fov_tolerance)
    seconds = time.perf_counter() - start
    pixels = lp.pixel_grid(authors.width, authors.height)
    rays = authors.unproject(pixels)
    scale = lp.REFERENCE_WIDTH / authors.width
    err = lambda c: (lp.best_rotation_rms(c, rays, pixels)[0] * scale) if c is not None else math.nan  # noqa: E731
    return {'images': len(paths), 'zero_shot_px': err(result.zero_shot_camera), 'returned_px': err(result.camera),
            'fitted_px': err(result.refined_camera), 'accepted': result.accepted, 'reason': result.reason,
            'uncertainty_px': (result.uncertainty_px or math.nan) * scale,
            'zero_shot_uncertainty_px': (result.zero_shot_uncertainty_px or math.nan) * scale,
            'lines': result.lines_used, 'seconds_per_image': seconds / len(paths),
            'pp_zero_shot_px': math.hypot(result.zero_shot_camera.cx - authors.cx,
                                          result.zero_shot_camera.cy - authors.cy) * scale,
            'pp_returned_px': math.hypot(result.camera.cx - authors.cx, result.camera.cy - authors.cy) * scale}


def real_report(data: Path, counts, fov_tolerance: float, command: str, seconds: float, runs) -> str:
    spec, _ = real_spec_and_truth(data)
    lines = [f'## Line refinement on the shared real images ({data.name})', '',
             f'`{command}` ({seconds:.0f} s).', '',
             f'{data.name}: 24 real images {spec.width}x{spec.height} of a wide-angle lens (a checkerboard in '
             'each: its '
             'edges are used as straight lines like any other, its geometry is not used). No spec sheet: hfov '
             f'{spec.hfov:.2f} / vfov {spec.vfov:.2f} derived from the authors\' ost.yaml read as Kannala-Brandt '
             f'(as benchmarks/paper_table4.py does); FOV tolerance {fov_tolerance:g} degree(s). Errors against '
             'ost.yaml: '
             'RMS over a 33 x 19 grid after the best rotation, px scaled to 1920 wide (the lens benchmark\'s '
             'metric). Images taken evenly through the set.', '',
             '| images | zero-shot px | returned px | fitted px | accepted | uncertainty px (zero-shot / returned) '
             '| principal point error px (zero-shot / returned) | lines | s per image | reason |',
             '|---:|---:|---:|---:|---|---:|---:|---:|---:|---|']
    for r in runs:
        lines.append(f"| {r['images']} | {_f(r['zero_shot_px'])} | {_f(r['returned_px'])} | {_f(r['fitted_px'])} | "
                     f"{'yes' if r['accepted'] else 'no'} | {_f(r['zero_shot_uncertainty_px'])} / "
                     f"{_f(r['uncertainty_px'])} | {_f(r['pp_zero_shot_px'])} / {_f(r['pp_returned_px'])} | "
                     f"{r['lines']} | {_f(r['seconds_per_image'])} | {r['reason']} |")
    return '\n'.join(lines) + '\n'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--evidence', choices=('ideal', 'images', 'real'), default='ideal',
                        help='ideal curves, rendered images, or the shared real images (--real-data)')
    parser.add_argument('--real-data', default=str(DEFAULT_REAL),
                        help='real evidence: the ros_fisheye_800x503 directory')
    parser.add_argument('--real-images', default='4,24',
                        help='real evidence: comma-separated numbers of images to refine from (default %(default)s)')
    parser.add_argument('--profiles', type=int, default=80,
                        help='profiles, evenly through the file (default %(default)s)')
    parser.add_argument('--views', type=int, default=4)
    parser.add_argument('--noise', type=float, default=0.3, help='ideal evidence: px per coordinate')
    parser.add_argument('--outliers', type=int, default=2, help='ideal evidence: curved arcs per view')
    parser.add_argument('--spec', choices=('hvd', 'hfov', 'dfov'), default='hvd',
                        help='the FOVs the spec gives: hfov + vfov + dfov, or one of them alone (as most fisheye '
                             'spec sheets print one)')
    parser.add_argument('--fov-round', type=float, default=0.0,
                        help='round the spec FOVs to this many degrees (0: exact)')
    parser.add_argument('--fov-tolerance', type=float, default=1.0)
    parser.add_argument('--scene', default='room', help='images evidence: room, corridor or street')
    parser.add_argument('--image-width', type=int, default=960, help='images evidence: width the profile is scaled to')
    parser.add_argument('--nuisances', choices=('none', 'circle', 'all'), default='none',
                        help='images evidence: what real photos add (test/scenes.py Nuisances): a vignetted image '
                        'circle with a dark, noisy surround (circle), and also a vehicle body part, blur, noise and '
                        'JPEG (all); default none')
    parser.add_argument('--render-cache', help='images evidence: directory where rendered views are kept (PNG, '
                        'lossless) and read back on later runs; rendering is the same with or without it')
    parser.add_argument('--tuning-set', action='store_true',
                        help='take the profiles halfway between those of the default set (where constants '
                             'are tuned; the default set is where they are reported)')
    parser.add_argument('--dump', help='pickle every profile\'s result (and ideal curves) into this directory')
    parser.add_argument('--shard', help='K/N: evaluate only every N-th profile from the K-th (with --dump, several '
                        'processes share a run; --rows-from makes the report of all)')
    parser.add_argument('--rows-from', help='comma-separated --dump directories: report their profiles\' rows '
                        '(of the --profiles set) instead of evaluating')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--csv', default=str(lp.DEFAULT_CSV))
    parser.add_argument('--out', help='write the markdown report here too')
    parser.add_argument('--append', action='store_true', help='append to --out instead of replacing it')
    parser.add_argument('--no-table', action='store_true', help='leave out the per-profile table')
    args = parser.parse_args(argv)
    if not os.path.exists(args.csv):
        print(f'line_refinement: error: {args.csv} not found', file=sys.stderr)
        return 2
    command = 'benchmarks/line_refinement.py ' + ' '.join(argv if argv is not None else sys.argv[1:])
    start = time.perf_counter()
    if args.evidence == 'real':
        data = Path(args.real_data)
        if not (data / 'ost.yaml').exists():
            print(f'line_refinement: error: {data}/ost.yaml not found', file=sys.stderr)
            return 2
        counts = [int(c) for c in args.real_images.split(',') if c.strip()]
        runs = []
        for count in counts:
            runs.append(real_run(data, count, args.fov_tolerance))
            print(f"[{count} images] {runs[-1]}", file=sys.stderr, flush=True)
        text = real_report(data, counts, args.fov_tolerance, command.strip(), time.perf_counter() - start, runs)
        print(text, end='')
        if args.out:
            with open(args.out, 'a' if args.append else 'w') as f:
                f.write(('\n' if args.append else '') + text)
        return 0
    chosen = evenly(wide_square_profiles(args.csv), args.profiles, 0.5 if args.tuning_set else 0.0)
    shard, shards = (int(v) for v in args.shard.split('/')) if args.shard else (0, 1)
    rows = []
    if args.rows_from:
        import pickle
        for directory in args.rows_from.split(','):
            for name in sorted(os.listdir(directory)):
                if name.endswith('.row.pkl'):
                    with open(os.path.join(directory, name), 'rb') as f:
                        rows.append(pickle.load(f))
        order = {p.index: k for k, (p, _) in enumerate(chosen)}
        rows = sorted((r for r in rows if r.index in order), key=lambda r: order[r.index])
        seconds = sum(r.seconds_total for r in rows)
        text = report(rows, args, seconds, command.strip(), table=not args.no_table)
        print(text, end='')
        if args.out:
            with open(args.out, 'a' if args.append else 'w') as f:
                f.write(('\n' if args.append else '') + text)
        return 0
    for k, (p, fovs) in enumerate(chosen):
        if k % shards != shard:
            continue
        t0 = time.perf_counter()
        rows.append(evaluate(p, fovs, args, profile_seed(args, p)))
        rows[-1].seconds_total = time.perf_counter() - t0
        if args.dump:
            import pickle
            with open(os.path.join(args.dump, f'{p.index}.row.pkl'), 'wb') as f:
                pickle.dump(rows[-1], f)
        r = rows[-1]
        print(f'[{k + 1}/{len(chosen)}] {r.path}: zs {_f(r.zs_px)} -> {_f(r.out_px)} fit {_f(r.fit_px)} '
              f'u {_f(r.zs_u)} -> {_f(r.out_u)} {_f(r.seconds_per_image)} s/img '
              f'({"accepted" if r.accepted else "refused"}) {r.failure or r.reason[:90]}', file=sys.stderr, flush=True)
    text = report(rows, args, time.perf_counter() - start, command.strip(), table=not args.no_table)
    print(text, end='')
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, 'a' if args.append else 'w') as f:
            f.write(('\n' if args.append else '') + text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
