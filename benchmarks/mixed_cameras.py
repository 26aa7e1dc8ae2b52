#!/usr/bin/env python3
"""Images of two cameras given to `refine` as one: does the gate keep a camera between theirs?

A user who points `refine` at a folder that holds two cameras' frames (a stereo pair's, two
units of one model, a mislabelled set) gets one camera fitted to all of them. This benchmark
mixes the real photos of ``benchmarks/real_photos.py`` two cameras at a time (same image size,
the first camera's spec) and reports, for each camera of the pair, zero-shot's and the returned
camera's error against that camera's calibration (the lens benchmark's metric: RMS px over a
33 x 19 grid after the best rotation, at 1920 px wide, over the trusted pixels), the decision and
its reason, with the gate as it is and with the per-image check off
(``refine.MAX_IMAGE_WORSE`` = inf), and the largest per-image ratio of the fitted camera's line
RMS to zero-shot's (what that check compares).

    .venv/bin/python benchmarks/mixed_cameras.py [--out FILE]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / 'benchmarks'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

import lens_profiles as lp  # noqa: E402
import real_photos as rp  # noqa: E402
from zeroshot_calib_ros.core.estimation import refine as refine_module  # noqa: E402
from zeroshot_calib_ros.core.lines.straightness import StraightnessTerm, curve_image, curve_points  # noqa: E402

MIXES = [('ocam_fisheye2', 'ocam_back', 2), ('ocam_back', 'ocam_fisheye2', 2),
         ('mynteye_s_jpl_left', 'mynteye_s_jpl_right', 1), ('mynteye_s_jpl_right', 'mynteye_s_jpl_left', 1),
         ('ocam_fisheye190', 'euroc_mt9v034', 2), ('euroc_mt9v034', 'ocam_fisheye190', 2)]
"""(camera whose spec is given, the other camera, photos of each)."""


def largest_image_ratio(result) -> float:
    """The largest, over images with at least MIN_IMAGE_LINES used curves, of the fitted camera's
    line RMS over zero-shot's (``refine.image_line_rms``: what the per-image check compares; nan
    when fewer than two such images)."""
    if result.refined_camera is None:
        return math.nan
    used = [c for c, u in zip(result.curves, result.used) if u]
    term = StraightnessTerm([curve_points(c) for c in used], sigma=0.5)
    ratios = refine_module.image_line_rms(term, [curve_image(c) for c in used], result.refined_camera,
                                          result.zero_shot_camera)
    return max(a / b for a, b in ratios.values()) if len(ratios) >= 2 else math.nan


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', help='write the report here too')
    args = parser.parse_args(argv)
    cameras = {c.name: c for c in rp.load_cameras()}
    missing = sorted({n for a, b, _ in MIXES for n in (a, b) if not cameras[n].photos})
    if missing:
        print(f'photos missing for {", ".join(missing)}: run benchmarks/fetch_real_cameras.py first', file=sys.stderr)
        return 1
    start = time.perf_counter()
    rows = []
    for check in ('on', 'off'):
        refine_module.MAX_IMAGE_WORSE = 1.1 if check == 'on' else math.inf
        for a, b, n in MIXES:
            frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for name in (a, b)
                      for p in rp.evenly(cameras[name].photos, n)]
            result = refine_module.refine_from_images(rp.spec_of(cameras[a]), frames)
            errors = []
            for name in (a, b):
                rays, pixels = rp.trusted_pixels(cameras[name])
                scale = lp.REFERENCE_WIDTH / cameras[name].width
                errors.append((lp.best_rotation_rms(result.zero_shot_camera, rays, pixels)[0] * scale,
                               lp.best_rotation_rms(result.camera, rays, pixels)[0] * scale))
            rows.append((check, a, b, n, errors, result.accepted, largest_image_ratio(result), result.reason))
            print(f'{check} {a} + {b}: {"accepted" if result.accepted else "refused"} {result.reason[:100]}',
                  file=sys.stderr, flush=True)
    seconds = time.perf_counter() - start
    lines = ['## Images of two cameras given as one', '',
             f'`benchmarks/mixed_cameras.py` ({seconds:.0f} s). Python {sys.version_info[0]}.{sys.version_info[1]}, '
             f'OpenCV {cv2.__version__}, numpy {np.__version__}.', '',
             'Each row: the photos of two cameras (same size) with the first camera\'s spec; errors against each '
             'camera\'s calibration (RMS px at 1920 wide after the best rotation, over its trusted pixels). '
             '"check": the per-image check (an image whose lines the fitted camera straightens more than 1.1 times '
             'worse than zero-shot refuses it) on, or off; "ratio": the largest such ratio.', '',
             '| check | spec of | mixed with | photos each | zero-shot / returned px vs the first | zero-shot / '
             'returned px vs the second | accepted | ratio | reason |',
             '|---|---|---|---:|---:|---:|---|---:|---|']
    for check, a, b, n, errors, accepted, ratio, reason in rows:
        (za, ra), (zb, rb) = errors
        lines.append(f'| {check} | {a} | {b} | {n} | {za:.2f} / {ra:.2f} | {zb:.2f} / {rb:.2f} | '
                     f'{"yes" if accepted else "no"} | {ratio:.2f} | {reason[:110]} |')
    text = '\n'.join(lines) + '\n'
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
