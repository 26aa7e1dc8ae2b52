#!/usr/bin/env python3
"""Zero-shot vs refined on real photos of real cameras, against their authors' calibrations.

The cameras are those of ``benchmarks/data/real_cameras.csv`` (where each comes from, its
licence and how its calibration was obtained: ``benchmarks/data/real_cameras.md``). The photos
are read from ``benchmarks/data/real_cameras/<camera>/``: the MyntEye pair is in the repository,
the others are extracted by ``benchmarks/fetch_real_cameras.py`` from copies of their source
repositories (a camera whose photos are absent is reported as skipped, saying what to fetch).

Per camera:

- **Truth**: the calibration as an OpenCV-fisheye (Kannala-Brandt) camera (the csv's
  ``opencv_fisheye_K_D``), inverted on its monotonic branch (``lens_profiles.GroundTruthCamera``).
  Where the calibration is ours (fitted to the repository's own chessboard photos), it is trusted
  only as far off-axis as its chessboard corners reached (``max_corner_theta_deg``, + 5 degrees):
  the error is measured over the pixels inside that angle, which is also where a published
  calibration's own views end; a published calibration counts over the whole image.
- **Spec**: what a spec sheet of this camera would say, derived from the truth: the image circle
  form (``--circle-diameter`` from the circle seen in the photos, ``--circle-fov`` the truth's
  angle at that radius) for the cameras whose circle is visible, else hfov + vfov + dfov;
  ``--spec hfov`` / ``--spec dfov``: that FOV alone, as most fisheye spec sheets print one (the
  lens shape is then the lens prior's).
- **Zero-shot**: ``refine_from_images`` 's zero-shot camera (what ``solve`` publishes);
  **refined**: the camera it returns (refined when its gate accepts, else zero-shot), and the
  fitted camera whether accepted or not.
- **Error**: the lens benchmark's metric (``lens_profiles.best_rotation_rms``): RMS pixel error
  over a 33 x 19 grid after the best rotation, scaled to 1920 px wide, over the trusted pixels.

    .venv/bin/python benchmarks/real_photos.py [--images 4] [--only NAME,...] [--spec sheet|hfov|dfov] [--out FILE]
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / 'benchmarks'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

import lens_profiles as lp  # noqa: E402
from zeroshot_calib_ros.core.estimation.refine import refine_from_images  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec  # noqa: E402

DATA = ROOT / 'benchmarks' / 'data'
TABLE = DATA / 'real_cameras.csv'
PHOTOS = DATA / 'real_cameras'
TRUST_MARGIN_DEG = 5.0
WORSE_PX = 0.3

# where each camera's photos are, and which of them show the scene (file name patterns)
PHOTO_GLOBS = {
    'ocam_fisheye190': ('ocam_fisheye190', 'Fisheye190deg*.jpg'),
    'ocam_fisheye1': ('ocam_fisheye1', 'Fisheye1_*.jpg'),
    'ocam_fisheye2': ('ocam_fisheye2', 'Fisheye2_*.jpg'),
    'ocam_back': ('ocam_back', 'imgBack*.jpg'),
    'ocam_ladybug': ('ocam_ladybug', 'Ladybug*.jpg'),
    'mynteye_s_jpl_left': ('mynteye_s_jpl', 'left_fisheye_img_*.png'),
    'mynteye_s_jpl_right': ('mynteye_s_jpl', 'right_fisheye_img_*.png'),
    'euroc_mt9v034': ('euroc_mt9v034', 'cam0/data/*.png'),
}


@dataclass
class RealCamera:
    name: str
    width: int
    height: int
    truth: lp.GroundTruthCamera
    published: bool
    trusted_deg: float
    """Largest off-axis angle (degrees) at which the truth is trusted (180: everywhere)."""
    circle: Optional[tuple]
    """(cx, cy, radius px) of the image circle seen in the photos, or None."""
    photos: List[Path]


def _number_key(path: Path):
    digits = ''.join(c if c.isdigit() else ' ' for c in path.stem).split()
    return (path.parent.name, int(digits[-1]) if digits else 0, path.name)


def load_cameras(table: Path = TABLE, photos: Path = PHOTOS) -> List[RealCamera]:
    rows = list(csv.DictReader(line for line in table.open() if not line.startswith('#')))
    cameras = []
    for row in rows:
        kd = json.loads(row['opencv_fisheye_K_D'])
        width, height = int(row['width']), int(row['height'])
        truth = lp.GroundTruthCamera(kd['fx'], kd['fy'], kd['cx'], kd['cy'], width, height, np.array(kd['D']))
        source = json.loads(row['params_source'])
        own = source.get('own_chessboard', source) if 'published_ocamcalib' not in source else None
        published = own is None or 'max_corner_theta_deg' not in own
        trusted = 180.0 if published else own['max_corner_theta_deg'] + TRUST_MARGIN_DEG
        circle = None
        fov = row['fov']
        if row['image_circle'].startswith('yes') and 'circle_px' in fov:
            part = fov[fov.index('"circle_px"'):]
            circle = tuple(json.loads(part[part.index('['):part.index(']') + 1]))
        folder, pattern = PHOTO_GLOBS[row['name']]
        found = sorted((photos / folder).glob(pattern), key=_number_key)
        cameras.append(RealCamera(row['name'], width, height, truth, published, trusted, circle, found))
    return cameras


SPEC_FORMS = ('sheet', 'hfov', 'dfov')
"""``--spec``: 'sheet' (the image circle's form where it is visible, else hfov + vfov + dfov), or one
FOV alone (what most fisheye spec sheets print), rounded to 0.1 degree as a sheet would."""


def spec_of(camera: RealCamera, form: str = 'sheet') -> CameraSpec:
    """The spec a sheet of this camera would give (module docstring); ``form``: ``SPEC_FORMS``."""
    t = camera.truth
    if form != 'sheet':
        value = t.fields_of_view().get(form, math.nan)
        if not math.isfinite(value):
            raise ValueError(f'the calibration gives no finite {form}')
        return CameraSpec(camera.width, camera.height, **{form: round(value, 1)})
    if camera.circle is not None:
        r = camera.circle[2]
        theta = float(t.theta_from_theta_d(np.array([r / ((t.fx + t.fy) / 2)]))[0])
        if not math.isfinite(theta):
            raise ValueError(f'the truth has no ray at the circle radius {r} px')
        return CameraSpec(camera.width, camera.height, circle_diameter=2 * r, circle_fov=2 * math.degrees(theta))
    # FOVs whose edge rays lie beyond the calibration's monotonic range are left out (as a sheet
    # would not print what the lens does not see)
    fovs = {k: v for k, v in t.fields_of_view().items() if k in ('hfov', 'vfov', 'dfov') and math.isfinite(v)}
    if not fovs:
        raise ValueError('the calibration gives no finite FOV')
    return CameraSpec(camera.width, camera.height, **fovs)


def trusted_pixels(camera: RealCamera):
    """(rays, pixels) of the 33 x 19 grid where the truth is trusted (inside its angle, and
    inside the image circle)."""
    pixels = lp.pixel_grid(camera.width, camera.height)
    rays = camera.truth.unproject(pixels)
    ok = np.all(np.isfinite(rays), axis=1)
    with np.errstate(invalid='ignore'):
        angle = np.degrees(np.arccos(np.clip(rays[:, 2] / np.linalg.norm(rays, axis=1), -1, 1)))
    ok &= angle <= camera.trusted_deg
    if camera.circle is not None:
        cx, cy, r = camera.circle
        ok &= np.hypot(pixels[:, 0] - cx, pixels[:, 1] - cy) <= r
    return rays[ok], pixels[ok]


def evenly(items, n):
    if n is None or n >= len(items):
        return list(items)
    return [items[int(i)] for i in np.linspace(0, len(items) - 1, n).round()]


def run_camera(camera: RealCamera, images: int, fov_tolerance: float = 1.0, form: str = 'sheet') -> dict:
    spec = spec_of(camera, form)
    paths = evenly(camera.photos, images)
    frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    start = time.perf_counter()
    result = refine_from_images(spec, frames, fov_tolerance_deg=fov_tolerance)
    seconds = time.perf_counter() - start
    rays, pixels = trusted_pixels(camera)
    scale = lp.REFERENCE_WIDTH / camera.width

    def err(c):
        return lp.best_rotation_rms(c, rays, pixels)[0] * scale if c is not None else math.nan
    return {'camera': camera.name, 'size': f'{camera.width}x{camera.height}', 'spec': _spec_text(spec),
            'images': len(paths), 'zero_shot_px': err(result.zero_shot_camera), 'returned_px': err(result.camera),
            'fitted_px': err(result.refined_camera), 'accepted': result.accepted, 'reason': result.reason,
            'lines': result.lines_used, 'seconds_per_image': seconds / len(paths),
            'uncertainty_px': (result.uncertainty_px or math.nan) * scale,
            'zero_shot_uncertainty_px': (result.zero_shot_uncertainty_px or math.nan) * scale,
            'trusted': 'published' if camera.published else f'own, to {camera.trusted_deg:.0f} deg',
            'grid_points': len(pixels)}


def _spec_text(spec: CameraSpec) -> str:
    if spec.circle_diameter is not None:
        return f'circle {spec.circle_diameter:.0f} px / {spec.circle_fov:.1f} deg'
    return ' / '.join(f'{k[0]} {v:.1f}' for k, v in spec.given().items())


def _f(x, d=2):
    return '-' if x is None or (isinstance(x, float) and not math.isfinite(x)) else f'{x:.{d}f}'


def report(runs, skipped, command, seconds) -> str:
    lines = ['## Real photos: zero-shot vs refined against the authors\' calibrations', '',
             f'`{command}` ({seconds:.0f} s).', '',
             'Errors: RMS px over a 33 x 19 grid after the best rotation, at 1920 px wide, over the pixels where '
             'the calibration is trusted (published: the whole image; ours: up to 5 degrees past the chessboard '
             'corners seen, and inside the image circle). "better": refined at least 10 % closer than zero-shot; '
             f'"worse": by more than {WORSE_PX} px.', '',
             '"error / bar": the returned camera\'s error over its stated 1-sigma error bar (both at 1920 px '
             'wide; the bar is over the whole image).', '',
             '| camera | size | spec | truth | images | zero-shot px | returned px | fitted px | accepted | '
             'error / bar | lines | s per image | reason |',
             '|---|---|---|---|---:|---:|---:|---:|---|---:|---:|---:|---|']
    for r in runs:
        lines.append(f"| {r['camera']} | {r['size']} | {r['spec']} | {r['trusted']} | {r['images']} | "
                     f"{_f(r['zero_shot_px'])} | {_f(r['returned_px'])} | {_f(r['fitted_px'])} | "
                     f"{'yes' if r['accepted'] else 'no'} | {_f(r['returned_px'] / r['uncertainty_px'], 1)} | "
                     f"{r['lines']} | {_f(r['seconds_per_image'])} | {r['reason'][:140]} |")
    better = sum(r['returned_px'] <= 0.9 * r['zero_shot_px'] for r in runs)
    worse = sum(r['returned_px'] > r['zero_shot_px'] + WORSE_PX for r in runs)
    lines += ['', f'{len(runs)} cameras: refined at least 10 % closer on {better}, worse by more than '
                  f'{WORSE_PX} px on {worse}.']
    for name, why in skipped:
        lines.append(f'- skipped {name}: {why}')
    return '\n'.join(lines) + '\n'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--images', type=int, default=4, help='photos per camera, evenly through its set')
    parser.add_argument('--only', default='', help='comma-separated camera names')
    parser.add_argument('--fov-tolerance', type=float, default=1.0)
    parser.add_argument('--spec', choices=SPEC_FORMS, default='sheet',
                        help="the spec given: 'sheet' (the image circle's form where it is visible, else "
                             'hfov + vfov + dfov) or one FOV alone')
    parser.add_argument('--out', help='write the report here too')
    args = parser.parse_args(argv)
    command = 'benchmarks/real_photos.py ' + ' '.join(argv if argv is not None else sys.argv[1:])
    only = {n for n in args.only.split(',') if n}
    start = time.perf_counter()
    runs, skipped = [], []
    for camera in load_cameras():
        if only and camera.name not in only:
            continue
        if not camera.photos:
            skipped.append((camera.name, 'photos absent: run benchmarks/fetch_real_cameras.py (see its --help)'))
            continue
        try:
            run = run_camera(camera, args.images, args.fov_tolerance, args.spec)
        except ValueError as exc:
            skipped.append((camera.name, str(exc)))
            continue
        print(json.dumps(run), flush=True)
        runs.append(run)
    text = report(runs, skipped, command.strip(), time.perf_counter() - start)
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
