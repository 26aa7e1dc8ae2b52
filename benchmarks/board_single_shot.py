#!/usr/bin/env python3
"""Single-shot checkerboard calibration with the spec as evidence vs zero-shot alone, on real
lens profiles (synthetic corners; issue 13, Done 3's "never worse than zero-shot").

    .venv/bin/python benchmarks/board_single_shot.py [--profiles 60] [--views 4] [--tuning-set]
        [--systematic PX] [--bend FRACTION] [--out benchmarks/results/board_single_shot.md] [--json-out FILE]

Profiles: the wide (implied hfov >= 100 degrees), square-pixel, usable rows of
../shared/data/lens_profiles_dev.csv, ``--profiles`` of them evenly through the file
(``line_refinement.wide_square_profiles`` / ``evenly``; ``--tuning-set``: the profiles halfway
between, disjoint, where constants are chosen). The spec is the profile's implied FOVs
(``--fovs``, default hfov + vfov as the shared set's spec), rounded to whole degrees
(``--fov-round``, default 1: a spec sheet's precision).

Per profile, ``--views`` single-image runs, one board each (8 x 6 inner corners, 5 cm squares),
cycling through four kinds of view:

- ``centre``: a small board (15-30 degrees across) near the image centre, tilted 0-40 degrees;
- ``mid``: a board 30-60 degrees across within 30 % of the centre, tilted 10-50 degrees;
- ``periphery``: a board 25-50 degrees across centred 30-45 % of the width / height from the
  centre (towards a side or a corner), tilted 20-60 degrees;
- ``tilted``: a board 35-70 degrees across within 20 % of the centre, tilted 50-70 degrees.

The corners are the board's points projected through the true camera (not rendered), plus
Gaussian noise of sigma uniform in [0.1, 0.3] px (the profile's own pixels) per coordinate, and,
with ``--systematic PX``, a smooth error per board (a random quadratic field over the board,
``PX`` px RMS: what real corners have beyond white noise: detector bias under strong
distortion, a board not quite flat), and with ``--bend FRACTION`` boards that are physically not
flat: a random quadratic sag (s^2, s q, q^2 of the board position) whose largest value is that
fraction of the board's diagonal (a board held by one hand, as in the shared set's left-0008).

Metric: the lens benchmark's (``lens_profiles.best_rotation_rms``): RMS pixel error over a
33 x 19 grid spanning the image after the best rotation, scaled to 1920 px wide, against the
true camera, for zero-shot alone (the KB4 fit of 'auto', the MAP's start: ``fit.zero_shot_camera``),
for the MAP (``fit.fitted_camera``: the fit whatever the safeguard decided) and for the camera
``fit_board`` returns (``fit.camera``: the MAP, or zero-shot when the safeguard keeps it).
"Worse" counts runs worse than zero-shot by more than 0.48 px at 1920 (the shared set's 0.2 px
at its 800 px width, scaled) and by more than 0.2 px at 1920 (stricter).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / 'benchmarks'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

import lens_profiles as lp  # noqa: E402
from line_refinement import evenly, wide_square_profiles  # noqa: E402
from zeroshot_calib_ros.core.checkerboard.corners import Board, CornerSet  # noqa: E402
from zeroshot_calib_ros.core.checkerboard.pose import rodrigues  # noqa: E402
from zeroshot_calib_ros.core.estimation import board_fit  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec, SpecError  # noqa: E402

BOARD = Board(8, 6, 0.05)
KINDS = ('centre', 'mid', 'periphery', 'tilted')
WORSE_PX = (0.2 * 1920 / 800, 0.2)
"""Margins (px at 1920 wide): the shared set's 0.2 px at 800 px wide, scaled; and 0.2 px."""


def _kind_ranges(kind):
    """(angular size deg, (centre offset range as a fraction of W / H), tilt deg)."""
    return {'centre': ((15, 30), (0.0, 0.1), (0, 40)),
            'mid': ((30, 60), (0.0, 0.3), (10, 50)),
            'periphery': ((25, 50), (0.3, 0.45), (20, 60)),
            'tilted': ((35, 70), (0.0, 0.2), (50, 70))}[kind]


def board_view(camera, kind, rng, noise, systematic, attempts=400, bend=0.0):
    """(corners (48, 2), description) of one board view of ``kind`` through ``camera``, or None."""
    obj = BOARD.object_points()
    centre = obj.mean(axis=0)
    extent = float(np.ptp(obj[:, 0]))
    size_deg, offset, tilt_deg = _kind_ranges(kind)
    W, H = camera.width, camera.height
    for _ in range(attempts):
        if kind == 'periphery':
            a = rng.uniform(0, 2 * math.pi)
            r = rng.uniform(*offset)
            du, dv = r * math.cos(a), r * math.sin(a)
        else:
            r = rng.uniform(*offset)
            a = rng.uniform(0, 2 * math.pi)
            du, dv = r * math.cos(a), r * math.sin(a)
        u, v = W * (0.5 + du), H * (0.5 + dv)
        ray = camera.unproject(np.array([[u, v]]))[0]
        if not np.all(np.isfinite(ray)):
            continue
        ray = ray / np.linalg.norm(ray)
        size = math.radians(rng.uniform(*size_deg))
        distance = extent / (2 * math.tan(size / 2))
        axis = np.r_[rng.normal(size=2), 0.0]
        axis /= np.linalg.norm(axis)
        R_tilt = rodrigues(axis * math.radians(rng.uniform(*tilt_deg)))
        # board frame: z towards the camera along -ray, then tilted
        z = -ray
        x = np.cross([0.0, 1.0, 0.0], z)
        if np.linalg.norm(x) < 1e-6:
            x = np.array([1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z], axis=1) @ R_tilt
        R = R @ rodrigues(np.array([0.0, 0.0, rng.uniform(-0.3, 0.3)]))
        t = ray * distance - R @ centre
        s = (obj[:, 0] - centre[0]) / (extent / 2)  # the board position, -1..1
        q = (obj[:, 1] - centre[1]) / (float(np.ptp(obj[:, 1])) / 2)
        board = obj
        if bend > 0:  # a board not flat: a random quadratic sag, ``bend`` of the board's diagonal at most
            sag = np.stack([s * s, s * q, q * q], axis=1) @ rng.normal(size=3)
            sag -= sag.mean()
            board = obj + np.outer(sag * bend * float(np.hypot(*np.ptp(obj[:, :2], axis=0))) / np.abs(sag).max(),
                                   [0.0, 0.0, 1.0])
        points = board @ R.T + t
        px = camera.project(points)
        if not (np.all(np.isfinite(px)) and np.all(px >= 5) and np.all(px[:, 0] <= W - 5)
                and np.all(px[:, 1] <= H - 5)):
            continue
        if np.any(np.linalg.norm(points, axis=1) < 0.05):
            continue
        px = px + rng.normal(scale=noise, size=px.shape)
        if systematic > 0:
            basis = np.stack([s * s, s * q, q * q, s, q], axis=1)
            field = basis @ rng.normal(size=(5, 2))
            field -= field.mean(axis=0)
            px = px + field * systematic / math.sqrt(np.mean(np.sum(field * field, axis=1)))
        hull_reach = float(np.max(np.hypot(px[:, 0] - W / 2, px[:, 1] - H / 2)) / math.hypot(W / 2, H / 2))
        span = (np.ptp(px[:, 0]) * np.ptp(px[:, 1])) / (W * H)
        return px, {'reach': hull_reach, 'bbox_fraction': float(span)}
    return None


def run_profile(p, fovs, args, seed, log):
    rng = np.random.default_rng(seed)
    gt = p.camera()
    keys = args.fovs.split(',')
    given = {k: (round(fovs[k] / args.fov_round) * args.fov_round if args.fov_round else fovs[k]) for k in keys}
    try:
        spec = CameraSpec(gt.width, gt.height, **given)
    except SpecError as exc:
        return [{'profile': p.index, 'failure': f'spec refused: {exc}'}]
    pixels = lp.pixel_grid(gt.width, gt.height)
    rays = gt.unproject(pixels)
    scale = lp.REFERENCE_WIDTH / gt.width
    rows = []
    for v in range(args.views):
        kind = KINDS[(v + seed) % len(KINDS)]
        noise = rng.uniform(0.1, 0.3)
        view = board_view(gt, kind, rng, noise, args.systematic, bend=args.bend)
        row = {'profile': p.index, 'path': p.path, 'width': gt.width, 'height': gt.height, 'kind': kind,
               'noise_px': noise}
        if view is None:
            row['failure'] = 'no board pose of this kind fits in the image'
            rows.append(row)
            continue
        px, desc = view
        row.update(desc)
        corners = CornerSet(gt.width, gt.height, BOARD, ['view.png'], px[None])
        t0 = time.perf_counter()
        try:
            fit = board_fit.fit_board(corners, spec, [0], fov_tolerance_deg=args.fov_tolerance)
        except Exception as exc:  # noqa: BLE001 - a benchmark records failures
            row['failure'] = f'{type(exc).__name__}: {exc}'
            rows.append(row)
            continue
        row['seconds'] = time.perf_counter() - t0
        err = lambda c: lp.best_rotation_rms(c, rays, pixels)[0] * scale  # noqa: E731
        fitted = getattr(fit, 'fitted_camera', None) or fit.camera
        row.update({
            'zs_px': err(fit.zero_shot_camera), 'map_px': err(fitted), 'out_px': err(fit.camera),
            'accepted': bool(getattr(fit, 'accepted', True)), 'reason': getattr(fit, 'reason', ''),
            'u_px': (fit.uncertainty_px or math.nan) * scale,
            'map_u_px': (getattr(fit, 'fitted_uncertainty_px', None) or fit.uncertainty_px or math.nan) * scale,
            'zs_u_px': (fit.zero_shot_uncertainty_px or math.nan) * scale,
            'p_zero_shot_better': getattr(fit, 'zero_shot_better_probability', None),
            'order': fit.order, 'sigma_px': fit.sigma_px, 'rms_px': fit.rms_px,
            'spec_agrees': fit.spec_agrees,
            'pp_shift_px': math.hypot(fitted.cx - fit.zero_shot_camera.cx, fitted.cy - fit.zero_shot_camera.cy) * scale,
        })
        if args.gate_grid and getattr(fit, 'gate', None) is not None:
            grid = {}
            for floor in (0.0, 0.1, 0.3):
                for zoom in (False, True):
                    prob, _, spread = board_fit.zero_shot_better(fit, floor, after_zoom=zoom)
                    grid[f'{floor:g}{"z" if zoom else ""}'] = (prob, spread * scale if spread is not None else None)
            row['gate_grid'] = grid
        rows.append(row)
        log(f"profile {p.index} {kind:9s} noise {noise:.2f}: zs {row['zs_px']:.2f} map {row['map_px']:.2f} "
            f"out {row['out_px']:.2f} u {row['map_u_px']:.2f} zs_u {row['zs_u_px']:.2f} "
            f"{'accepted' if row['accepted'] else 'ZS KEPT'} ({row['seconds']:.1f} s)")
    return rows


def summarise(rows, key):
    ok = [r for r in rows if 'failure' not in r and math.isfinite(r.get(key, math.nan))]
    values = np.array([r[key] for r in ok])
    zs = np.array([r['zs_px'] for r in ok])
    return {
        'runs': len(ok), 'mean': float(np.mean(values)), 'median': float(np.median(values)),
        'p90': float(np.percentile(values, 90)), 'worst': float(np.max(values)),
        'worse_by': [int(np.sum(values > zs + m)) for m in WORSE_PX],
        'worse_at_all': int(np.sum(values > zs + 1e-9)),
        'worst_excess': float(np.max(values - zs)),
    }


def markdown(rows, args, command, seconds):
    ok = [r for r in rows if 'failure' not in r]
    failed = len(rows) - len(ok)
    out = ['# Single-shot checkerboard + spec vs zero-shot alone, on real lens profiles (synthetic corners)', '',
           f'Command: `{command}`  ',
           f'Wall time: {seconds:.0f} s on this machine (2 shared cores); {len(ok)} runs'
           + (f' ({failed} without a run: no pose of the kind fits, or a failure)' if failed else '') + '.', '',
           f"Spec {args.fovs} rounded to {args.fov_round:g} degree(s), tolerance {args.fov_tolerance:g} degree(s); "
           f"corner noise 0.1-0.3 px; systematic per-board error {args.systematic:g} px RMS; "
           f"board sag up to {args.bend:g} of its diagonal; the MAP's boards "
           + ('bent (board_fit.BOARD_BEND). ' if board_fit.BOARD_BEND else 'flat (--flat-boards). ') +
           'Error: RMS over the image after the best rotation against the true camera, px at 1920 wide. '
           f'Worse: by more than {WORSE_PX[0]:.2f} px (0.2 px at 800 wide) / {WORSE_PX[1]:.2f} px.', '',
           '| camera | mean | median | p90 | worst | runs worse than ZS by > 0.48 / > 0.2 px | worse at all | '
           'worst excess over ZS |', '|---|---|---|---|---|---|---|---|']
    for key, label in (('zs_px', 'zero-shot alone'), ('map_px', 'MAP (spec as evidence), no safeguard'),
                       ('out_px', 'fit_board result (MAP, or zero-shot when the safeguard keeps it)')):
        s = summarise(rows, key)
        out.append(f"| {label} | {s['mean']:.2f} | {s['median']:.2f} | {s['p90']:.2f} | {s['worst']:.2f} | "
                   f"{s['worse_by'][0]} / {s['worse_by'][1]} of {s['runs']} | {s['worse_at_all']} | "
                   f"{s['worst_excess']:+.2f} |")
    kept = [r for r in ok if not r['accepted']]
    out += ['', f'Zero-shot kept by the safeguard in {len(kept)} of {len(ok)} runs.', '',
            '| kind | runs | ZS mean | MAP mean | result mean | MAP worse by > 0.48 | result worse by > 0.48 | '
            'ZS kept |', '|---|---|---|---|---|---|---|---|']
    for kind in KINDS:
        rs = [r for r in ok if r['kind'] == kind]
        if not rs:
            continue
        out.append(f"| {kind} | {len(rs)} | {np.mean([r['zs_px'] for r in rs]):.2f} | "
                   f"{np.mean([r['map_px'] for r in rs]):.2f} | {np.mean([r['out_px'] for r in rs]):.2f} | "
                   f"{sum(r['map_px'] > r['zs_px'] + WORSE_PX[0] for r in rs)} | "
                   f"{sum(r['out_px'] > r['zs_px'] + WORSE_PX[0] for r in rs)} | "
                   f"{sum(not r['accepted'] for r in rs)} |")
    honest = [r for r in ok if math.isfinite(r['map_u_px'])]
    if honest:
        within = sum(r['map_px'] <= 2 * r['map_u_px'] for r in honest)
        out += ['', f"MAP uncertainty honesty: true error within 2x the MAP's uncertainty_px in {within} of "
                f"{len(honest)} runs; zero-shot within 2x its own: "
                f"{sum(r['zs_px'] <= 2 * r['zs_u_px'] for r in ok if math.isfinite(r['zs_u_px']))} of {len(ok)}."]
    worst = sorted((r for r in ok if r['map_px'] > r['zs_px'] + WORSE_PX[0]),
                   key=lambda r: r['zs_px'] - r['map_px'])
    if worst:
        out += ['', 'Runs where the MAP is worse than zero-shot by > 0.48 px:', '',
                '| profile | kind | noise | ZS | MAP | result | MAP u | ZS u | order | pp shift | reach | kept? |',
                '|---|---|---|---|---|---|---|---|---|---|---|---|']
        for r in worst:
            out.append(f"| {r['profile']} | {r['kind']} | {r['noise_px']:.2f} | {r['zs_px']:.2f} | {r['map_px']:.2f} | "
                       f"{r['out_px']:.2f} | {r['map_u_px']:.2f} | {r['zs_u_px']:.2f} | {r['order']} | "
                       f"{r['pp_shift_px']:.1f} | {r['reach']:.2f} | {'ZS kept' if not r['accepted'] else ''} |")
    return '\n'.join(out) + '\n'


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--profiles', type=int, default=60)
    parser.add_argument('--views', type=int, default=4, help='single-image runs per profile')
    parser.add_argument('--tuning-set', action='store_true',
                        help='the profiles halfway between the default ones (where constants are chosen)')
    parser.add_argument('--fovs', default='hfov,vfov', help='comma-separated FOVs of the spec')
    parser.add_argument('--fov-round', type=float, default=1.0)
    parser.add_argument('--fov-tolerance', type=float, default=1.0)
    parser.add_argument('--systematic', type=float, default=0.0,
                        help='smooth per-board corner error, px RMS (default 0: white noise only)')
    parser.add_argument('--bend', type=float, default=0.0,
                        help='boards not flat: a random quadratic sag of at most this fraction of the board diagonal')
    parser.add_argument('--flat-boards', action='store_true',
                        help='fit every board as flat (board_fit.BOARD_BEND off): the model before boards could bend')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--csv', default=str(lp.DEFAULT_CSV))
    parser.add_argument('--out', help='write the markdown report here')
    parser.add_argument('--append', action='store_true', help='append to --out')
    parser.add_argument('--json-out', help='write every run as JSON here')
    parser.add_argument('--quiet', action='store_true')
    parser.add_argument('--gate-grid', action='store_true',
                        help="also record the gate's probability for systematic floors 0 / 0.1 / 0.3 px, with and "
                             'without the zoom (to choose the gate constants on the tuning set)')
    args = parser.parse_args(argv)
    if args.flat_boards:
        board_fit.BOARD_BEND = False
    if not Path(args.csv).exists():
        print(f'board_single_shot: error: {args.csv} not found', file=sys.stderr)
        return 2

    def log(message):
        if not args.quiet:
            print(f'[{time.strftime("%X")}] {message}', file=sys.stderr, flush=True)

    start = time.perf_counter()
    chosen = evenly(wide_square_profiles(args.csv), args.profiles, 0.5 if args.tuning_set else 0.0)
    rows = []
    for p, fovs in chosen:
        rows += run_profile(p, fovs, args, args.seed * 100003 + p.index, log)
    seconds = time.perf_counter() - start
    command = ('.venv/bin/python benchmarks/board_single_shot.py '
               + ' '.join(argv if argv is not None else sys.argv[1:])).strip()
    text = markdown(rows, args, command, seconds)
    print(text, end='')
    if args.out:
        with open(args.out, 'a' if args.append else 'w') as f:
            f.write(('\n' if args.append else '') + text)
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(rows, default=float))
    return 0


if __name__ == '__main__':
    sys.exit(main())
