#!/usr/bin/env python3
"""The pictures of the docs, made again from the shared data so that they stay true.

    .venv/bin/python benchmarks/make_figures.py [--data ../shared/data/ros_fisheye_800x503]
        [--out docs/images] [--only NAME ...]

Every picture is what the `zeroshot-calib` CLI writes (run in-process), on the shared real set
``ros_fisheye_800x503`` (24 frames 800x503 of a fixed wide-angle camera in a lab, a chessboard
carried around; no spec sheet: hfov / vfov derived from its authors' ost.yaml read as
Kannala-Brandt and rounded to 0.01 degree, 180.81 x 103.52, as docs/calibration.md does), or on
scenes rendered by test/scenes.py through a known Kannala-Brandt camera:

- ``before_after.png``: frame ``left-0003.png`` as the camera gives it, and rectified with the
  zero-shot camera of the spec (`zeroshot-calib rectify --hfov --vfov`), side by side;
- ``report_solve.png``: `zeroshot-calib solve --report` for the spec;
- ``report_refine.png``: `zeroshot-calib refine --report` on four frames of the set
  (left-0000, -0006, -0012, -0018, as benchmarks/line_refinement.py takes them);
- ``report_refine_rendered.png``: the same on three rendered scenes (a room, a corridor, a
  street) of test/refine_cli's camera (640x360, principal point off-centre);
- ``debug_refine.png``: `refine --debug-image` of the four frames;
- ``report_calibrate.png``: `zeroshot-calib calibrate --report` on all 24 frames with the spec.

Each picture is a PNG of at most ``MAX_BYTES``: one over it has the grey pixels of its photos
rounded to fewer levels, as few as needed (``lighten``); the script prints each file's size.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))

import cv2  # noqa: E402

from zeroshot_calib_ros.cli import main  # noqa: E402
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, camera_from_calibration  # noqa: E402
from zeroshot_calib_ros.core.report.canvas import INK, MUTED, PAPER, put_text  # noqa: E402
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration  # noqa: E402

DEFAULT_DATA = ROOT.parent / 'shared' / 'data' / 'ros_fisheye_800x503'
DEFAULT_OUT = ROOT / 'docs' / 'images'
MAX_BYTES = 300_000
FRAME = 'left-0003.png'
REFINE_FRAMES = ('left-0000.png', 'left-0006.png', 'left-0012.png', 'left-0018.png')
# test/cli/test_cli_refine.py's camera and its FOVs rounded to a degree
RENDERED = KannalaBrandtCamera(210.0, 210.0, 327.0, 176.0, 640, 360, np.array([0.02, -0.01, 0.003, -0.0005]))
RENDERED_SPEC = ['--hfov', '172', '--vfov', '97', '--dfov', '198']


def spec_flags(data: Path):
    """--hfov / --vfov of the set: its authors' calibration read as Kannala-Brandt, to 0.01 deg."""
    ost = CameraCalibration.load(str(data / 'ost.yaml'))
    fovs = camera_from_calibration('equidistant', ost.K, ost.D, ost.width, ost.height).fields_of_view()
    return ['--hfov', f"{fovs['hfov']:.2f}", '--vfov', f"{fovs['vfov']:.2f}"]


def cli(*argv, allowed=(0,)):
    """Run zeroshot-calib in-process; its stdout is returned, its warnings pass to stderr. A status
    not in ``allowed`` stops the script (``refine`` exits 3 when it keeps zero-shot: the pictures
    are made all the same, and show why)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status = main([str(a) for a in argv])
    if status not in allowed:
        raise SystemExit(f'zeroshot-calib {" ".join(map(str, argv))}: exit status {status}')
    return out.getvalue()


def before_after(data: Path, path: Path, spec):
    frame = data / FRAME
    with tempfile.TemporaryDirectory() as tmp:
        rectified = Path(tmp) / 'rectified.png'
        cli('rectify', frame, '-o', rectified, *spec)
        after = cv2.imread(str(rectified), cv2.IMREAD_GRAYSCALE)
    before = cv2.imread(str(frame), cv2.IMREAD_GRAYSCALE)
    h, w = before.shape
    width = 640  # each side; the pair is 1300 px wide
    height = round(h * width / w)
    sides = [cv2.resize(im, (width, height), interpolation=cv2.INTER_AREA) for im in (before, after)]
    gap, band = 20, 34
    canvas = np.full((band + height, 2 * width + gap, 3), PAPER, np.uint8)
    given = ' '.join(spec)
    for k, (side, title) in enumerate(zip(sides, (f'{FRAME} as the camera gives it (800x503)',
                                                  f'rectified with the zero-shot camera of {given}'))):
        x = k * (width + gap)
        canvas[band:, x:x + width] = cv2.cvtColor(side, cv2.COLOR_GRAY2BGR)
        put_text(canvas, title, x, 9, 0.5, INK if k else MUTED, 1)
    write(path, canvas)


def write(path: Path, image):
    ok, data = cv2.imencode('.png', image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    assert ok
    path.write_bytes(data.tobytes())


def lighten(path: Path) -> int:
    """A picture over ``MAX_BYTES`` (PNGs of noisy photos compress poorly) has its grey pixels
    (the photos in it) rounded to fewer levels, the finest rounding that fits; text, curves and
    colour maps are not grey and stay as the CLI drew them. Returns the rounding step (1: none)."""
    if path.stat().st_size <= MAX_BYTES:
        return 1
    original = cv2.imread(str(path))
    grey = (original[..., 0] == original[..., 1]) & (original[..., 1] == original[..., 2])
    for step in (2, 3, 4, 6, 8):
        image = original.copy()
        image[grey] = np.clip((image[grey] // step) * step + step // 2, 0, 255)
        write(path, image)
        if path.stat().st_size <= MAX_BYTES:
            break
    return step


def rendered_views(directory: Path):
    from scenes import render
    paths = []
    for i, (scene, seed) in enumerate([('room', 1), ('corridor', 2), ('street', 3)]):
        image, _ = render(RENDERED, scene, seed=seed)
        paths.append(directory / f'{scene}.png')
        cv2.imwrite(str(paths[-1]), image)
    return paths


def main_(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA, help='the ros_fisheye_800x503 directory')
    parser.add_argument('--out', type=Path, default=DEFAULT_OUT, help='where the pictures go (default docs/images)')
    parser.add_argument('--only', nargs='*', help='file names (without .png) to make; default all')
    args = parser.parse_args(argv)
    if not (args.data / 'ost.yaml').is_file():
        raise SystemExit(f'{args.data}: not the shared ros_fisheye_800x503 set (no ost.yaml)')
    args.out.mkdir(parents=True, exist_ok=True)
    spec = spec_flags(args.data)
    frames = [args.data / f for f in REFINE_FRAMES]

    def wanted(name):
        return not args.only or name in args.only

    made = []
    if wanted('before_after'):
        before_after(args.data, args.out / 'before_after.png', spec)
        made.append('before_after')
    if wanted('report_solve'):
        cli('solve', '--width', 800, '--height', 503, *spec, '--report', args.out / 'report_solve.png')
        made.append('report_solve')
    if wanted('report_refine') or wanted('debug_refine'):
        cli('refine', *frames, *spec, '--report', args.out / 'report_refine.png', '--debug-image',
            args.out / 'debug_refine.png', allowed=(0, 3))
        made += ['report_refine', 'debug_refine']
    if wanted('report_refine_rendered'):
        with tempfile.TemporaryDirectory() as tmp:
            cli('refine', *rendered_views(Path(tmp)), *RENDERED_SPEC, '--report',
                args.out / 'report_refine_rendered.png', allowed=(0, 3))
        made.append('report_refine_rendered')
    if wanted('report_calibrate'):
        cli('calibrate', args.data / 'left-*.png', *spec, '--report', args.out / 'report_calibrate.png')
        made.append('report_calibrate')
    too_big = []
    for name in made:
        path = args.out / f'{name}.png'
        step = lighten(path)
        size = path.stat().st_size
        image = cv2.imread(str(path))
        rounded = f', greys rounded to steps of {step}' if step > 1 else ''
        print(f'{path}: {image.shape[1]}x{image.shape[0]}, {size / 1000:.0f} kB{rounded}')
        if size > MAX_BYTES:
            too_big.append(f'{path} is {size / 1000:.0f} kB (at most {MAX_BYTES / 1000:.0f})')
    if too_big:
        raise SystemExit('; '.join(too_big))
    return 0


if __name__ == '__main__':
    sys.exit(main_())
