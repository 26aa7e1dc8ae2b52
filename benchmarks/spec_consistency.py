#!/usr/bin/env python3
"""How far the solved camera misses the FOVs of honest specs: the thresholds of the consistency
warnings (``core/zeroshot/consistency.py``) measured.

1. A spec sheet's rounding. Equidistant cameras of the paper's model, distortion-free to strongly
   barrel-distorted (w from 0 to 0.9 of the value that puts the image corner 90 degrees off-axis),
   hfov 20 to 170 degrees, nine image sizes; their hfov and vfov each moved by -0.5, 0 or +0.5
   degree (x 0.999: what printing whole degrees does at worst), in all nine combinations. Solved
   from the moved FOVs; the largest miss of a given FOV, over all cases.
2. Real lenses. ../shared/data/lens_profiles_dev.csv (Kannala-Brandt calibrations; their implied
   FOVs are the spec, as in benchmarks/lens_profiles.py), exact and rounded to whole degrees:
   h+v, and the diagonal beside them (h+v+d), how often the solved camera misses by more than a
   threshold; how many specs CameraSpec refuses as swapped.
3. The paper's Table 2 and the presets: the largest miss of each.

    .venv/bin/python benchmarks/spec_consistency.py --out benchmarks/results/spec_consistency.md
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / 'benchmarks', ROOT / 'test'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from lens_profiles import DEFAULT_CSV, ground_truth_problem, load_profiles  # noqa: E402
from paper_table2 import load_table2  # noqa: E402
from zeroshot_calib_ros.core.lens.models import ZeroShotCamera  # noqa: E402
from zeroshot_calib_ros.core.lens.projections import PROJECTIONS  # noqa: E402
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.consistency import (EXTRA_FOV_WARNING_DEG, fitted_and_extra,  # noqa: E402
                                                          predicted_fov)
from zeroshot_calib_ros.core.zeroshot.presets import load_presets  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.solver import NoConvergence, solve_zero_shot  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.spec import FOV_TOLERANCE_DEG, CameraSpec, SpecError  # noqa: E402

SIZES = ((1920, 1080), (1280, 720), (1280, 800), (1280, 960), (1920, 1440), (848, 800), (4608, 2592),
         (3000, 2000), (2560, 1080))
HFOVS = tuple(range(20, 171, 10))
SHARES = (0.0, 0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.75, 0.9)
THRESHOLDS = (1, 2, 5, 10, 15, 20)


def misses(spec, solution):
    """(largest miss of the FOVs solved from, largest miss of those beside them), degrees."""
    fitted, extra = fitted_and_extra(spec)

    def worst(constraints):
        values = [abs(predicted_fov(solution.camera, c) - c.fov) for c in constraints]
        return max(values, default=0.0) if all(math.isfinite(v) for v in values) else math.inf
    return worst(fitted), worst(extra)


def camera_with_hfov(w, h, omega, hfov):
    lo, hi = 1e-3, 1e7  # hfov falls as f grows
    for _ in range(200):
        f = math.sqrt(lo * hi)
        if ZeroShotCamera(f, w / 2, h / 2, w, h, omega).fields_of_view()['hfov'] > hfov:
            lo = f
        else:
            hi = f
    return ZeroShotCamera(f, w / 2, h / 2, w, h, omega)


def rounding_study():
    worst, all_misses, warned, cases, reversed_ = (0.0, None), [], 0, 0, 0
    for w, h in SIZES:
        corner = math.hypot(w, h) / 2
        for share in SHARES:
            omega = share * PROJECTIONS['equidistant'].rho_max / corner
            for hfov in HFOVS:
                fovs = camera_with_hfov(w, h, omega, hfov).fields_of_view()
                if not all(math.isfinite(v) and v < 180 for v in fovs.values()):
                    continue
                for dh in (-0.5, 0.0, 0.5):
                    for dv in (-0.5, 0.0, 0.5):
                        try:
                            spec = CameraSpec(w, h, fovs['hfov'] + 0.999 * dh, fovs['vfov'] + 0.999 * dv)
                        except SpecError:  # the offsets put them in the wrong order (rounding cannot)
                            reversed_ += 1
                            continue
                        solution = solve_zero_shot(spec)
                        miss = misses(spec, solution)[0]
                        all_misses.append(miss)
                        warned += bool(solution.warnings)
                        cases += 1
                        if miss > worst[0]:
                            worst = (miss, f'{w}x{h}, w share {share}, hfov {fovs["hfov"]:.1f}, '
                                           f'vfov {fovs["vfov"]:.1f}, moved by {dh:+g} / {dv:+g}')
    return cases, np.asarray(all_misses), worst, warned, reversed_


def real_lens_study(csv_path, step):
    """Misses on the profiles, their FOVs rounded to ``step`` degrees (None: exact)."""
    pair_hv, pair_hvd, extra, swapped, refused, usable = [], [], [], 0, 0, 0
    for profile in load_profiles(csv_path):
        camera = profile.camera()
        if ground_truth_problem(camera):
            continue
        fovs = fields_of_view_through_axis(camera)
        if step:
            fovs = {k: round(v / step) * step for k, v in fovs.items()}
        usable += 1
        try:
            spec2 = CameraSpec(profile.width, profile.height, hfov=fovs['hfov'], vfov=fovs['vfov'])
            spec3 = CameraSpec(profile.width, profile.height, **fovs)
        except SpecError as exc:
            swapped += 'swapped' in str(exc)
            refused += 1
            continue
        try:
            pair_hv.append(misses(spec2, solve_zero_shot(spec2))[0])
            fitted, beside = misses(spec3, solve_zero_shot(spec3))
        except (SpecError, NoConvergence, ValueError):
            refused += 1
            continue
        pair_hvd.append(fitted)
        extra.append(beside)
    return usable, refused, swapped, np.asarray(pair_hv), np.asarray(pair_hvd), np.asarray(extra)


def share_above(values, threshold):
    n = int(np.sum(values > threshold))
    return f'{n} ({100.0 * n / len(values):.1f} %)'


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--csv', default=str(DEFAULT_CSV))
    parser.add_argument('--out', help='write the markdown here (default: stdout)')
    args = parser.parse_args(argv)
    start = time.monotonic()
    lines = ['# Consistency warnings: how far honest specs are missed', '',
             f'Generated by `benchmarks/spec_consistency.py`. Thresholds: FOVs solved from '
             f'{FOV_TOLERANCE_DEG:g} deg (`--fov-tolerance` default), a FOV beside them '
             f'{EXTRA_FOV_WARNING_DEG:g} deg.', '']

    cases, values, worst, warned, reversed_ = rounding_study()
    lines += ['## 1. A spec sheet\'s rounding (hfov and vfov each off by up to 0.5 deg)', '',
              f'{cases} specs ({len(SIZES)} sizes, hfov {HFOVS[0]}-{HFOVS[-1]} deg, w share '
              f'{SHARES[0]}-{SHARES[-1]}, 9 offset combinations). Miss of a given FOV by the solved camera, '
              f'deg: median {np.median(values):.3f}, p99 {np.percentile(values, 99):.3f}, largest {worst[0]:.3f} '
              f'({worst[1]}). Specs warned about at the default tolerance: {warned}. Left out: {reversed_} whose '
              'offsets reverse the order of hfov and vfov (nearly square images; printing whole degrees '
              'cannot do that, and CameraSpec refuses them as swapped).', '']

    if Path(args.csv).is_file():
        lines += ['## 2. Real lenses (lens_profiles_dev.csv)', '',
                  '| FOVs | usable | refused (of them "swapped") | h+v: miss > 1 deg | h+v+d: solved-from miss > 1 deg | '
                  + ' | '.join(f'diagonal beside: miss > {t} deg' for t in THRESHOLDS) + ' |',
                  '|---|---:|---:|---:|---:|' + '---:|' * len(THRESHOLDS)]
        for step, label in ((None, 'exact'), (1.0, 'rounded to 1 deg')):
            usable, refused, swapped, hv, hvd, extra = real_lens_study(args.csv, step)
            lines.append(f'| {label} | {usable} | {refused} ({swapped}) | {share_above(hv, 1)} | {share_above(hvd, 1)} | '
                         + ' | '.join(share_above(extra, t) for t in THRESHOLDS) + ' |')
        lines.append('')
    else:
        lines += [f'## 2. Real lenses: skipped, {args.csv} is missing', '']

    lines += ['## 3. The paper\'s Table 2 and the presets', '',
              '| spec | FOVs | largest miss, solved from (deg) | largest miss, beside (deg) | warnings |',
              '|---|---|---:|---:|---:|']
    specs = [(f"Table 2 {row['camera']}", CameraSpec(int(row['width']), int(row['height']), row['hfov'], row['vfov']))
             for row in load_table2()]
    specs += [(f'preset {name}', preset.spec) for name, preset in load_presets().items()]
    for name, spec in specs:
        solution = solve_zero_shot(spec)
        fitted, beside = misses(spec, solution)
        given = '+'.join(k[0] for k in spec.given()) + ('+circle' if spec.circle_fov is not None else '')
        lines.append(f'| {name} | {given} | {fitted:.3f} | {beside:.3f} | {len(solution.warnings)} |')
    lines += ['', f'Run time {time.monotonic() - start:.0f} s.']
    text = '\n'.join(lines) + '\n'
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text, end='')


if __name__ == '__main__':
    main()
