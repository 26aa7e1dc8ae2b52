"""``zeroshot-calib``: the ROS-free command line.

    zeroshot-calib solve --width 1920 --height 1080 --hfov 118 --vfov 69 [--json] [--yaml FILE]
    zeroshot-calib solve --batch cameras.csv [--yaml-dir DIR]
    zeroshot-calib rectify IN.png -o OUT.png --hfov 118 --vfov 69

Errors exit with status 2 and one line on stderr, never a traceback.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import sys

import cv2

from .core.calibration_file import (DISTORTION_MODELS, CalibrationFileError, CameraCalibration,
                                    solution_summary, summary_text)
from .core.rectify import INTERPOLATIONS, Rectifier
from .core.solver import PROJECTION_CHOICES, NoConvergence, solve_zero_shot
from .core.spec import CameraSpec, SpecError


class CliError(Exception):
    """An error to report in one line."""


def _add_spec_arguments(parser, size_required=True):
    parser.add_argument('--width', type=int, required=size_required, help='image width (px)')
    parser.add_argument('--height', type=int, required=size_required, help='image height (px)')
    parser.add_argument('--hfov', type=float, help='horizontal field of view (deg)')
    parser.add_argument('--vfov', type=float, help='vertical field of view (deg)')
    parser.add_argument('--dfov', type=float, help='diagonal field of view (deg)')
    parser.add_argument('--model', default='auto', choices=PROJECTION_CHOICES,
                        help='fisheye projection; auto picks by dfov when all three FOVs are given, '
                             'else equidistant (default: auto)')


def _add_output_arguments(parser):
    parser.add_argument('--distortion-model', default='equidistant', choices=DISTORTION_MODELS,
                        help='ROS distortion model to fit (default: equidistant)')
    parser.add_argument('--balance', type=float, default=0.0,
                        help='rectified camera: 0 crops to valid pixels, 1 keeps every edge (default 0)')
    parser.add_argument('--fov-scale', type=float, default=1.0,
                        help='rectified camera: divides its focal length (default 1)')


def _solve(spec, args, camera_name='camera'):
    solution = solve_zero_shot(spec, args.model, getattr(args, 'method', 'bracketed'))
    calibration, fit = CameraCalibration.from_solution(
        solution, args.distortion_model, args.balance, args.fov_scale, camera_name)
    return solution, calibration, fit


def _cmd_solve(args):
    if args.batch:
        return _solve_batch(args)
    if args.width is None or args.height is None:
        raise CliError('--width and --height are required (or --batch FILE)')
    spec = CameraSpec(args.width, args.height, args.hfov, args.vfov, args.dfov)
    solution, calibration, fit = _solve(spec, args, args.camera_name)
    summary = solution_summary(solution, calibration, fit)
    if args.yaml:
        calibration.save(args.yaml)
    if args.json:
        print(json.dumps(summary))
    else:
        print(summary_text(summary))
        if args.yaml:
            print(f'wrote {args.yaml}')
    return 0


def _cell(row, key, convert):
    value = (row.get(key) or '').strip()
    if not value:
        return None
    try:
        return convert(value)
    except ValueError:
        raise SpecError(key, value, 'a number') from None


def _solve_batch(args):
    """One JSON object per camera row; a bad row reports an error object and the rest go on."""
    failures = 0
    try:
        with open(args.batch, newline='') as f:
            text = f.read()
    except OSError as exc:
        raise CliError(f'cannot read {args.batch}: {exc.strerror}') from None
    lines = text.splitlines()
    columns = ['name', 'width', 'height', 'hfov', 'vfov', 'dfov']
    if lines and lines[0].split(',')[0].strip().lower() == 'name':
        columns = [c.strip().lower() for c in lines[0].split(',')]
        lines = lines[1:]
    if args.yaml_dir:
        os.makedirs(args.yaml_dir, exist_ok=True)
    for number, values in enumerate(csv.reader(lines), start=1):
        if not values or all(not v.strip() for v in values):
            continue
        row = dict(zip(columns, values))
        name = (row.get('name') or f'camera_{number}').strip()
        try:
            spec = CameraSpec(_cell(row, 'width', int), _cell(row, 'height', int), _cell(row, 'hfov', float),
                              _cell(row, 'vfov', float), _cell(row, 'dfov', float))
            solution, calibration, fit = _solve(spec, args, name)
            record = {'name': name, **solution_summary(solution, calibration, fit)}
            if args.yaml_dir:
                path = os.path.join(args.yaml_dir, f'{name}.yaml')
                calibration.save(path)
                record['yaml'] = path
        except (SpecError, CalibrationFileError, NoConvergence, ValueError) as exc:
            failures += 1
            record = {'name': name, 'row': number, 'error': str(exc)}
        print(json.dumps(record), flush=True)
    return 1 if failures else 0


def _cmd_rectify(args):
    image = cv2.imread(args.input, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise CliError(f'cannot read image {args.input}')
    height, width = image.shape[:2]
    spec_w, spec_h = args.width or width, args.height or height
    spec = CameraSpec(spec_w, spec_h, args.hfov, args.vfov, args.dfov)
    if spec_w * height != spec_h * width:
        raise CliError(f'the image is {width}x{height} but the spec is {spec_w}x{spec_h}: '
                       'aspect ratios differ')
    solution = solve_zero_shot(spec, args.model)
    camera = solution.camera if (spec_w, spec_h) == (width, height) else solution.camera.scaled(width, height)
    rectifier = Rectifier(camera, args.balance, args.fov_scale, args.interpolation)
    if not cv2.imwrite(args.output, rectifier.rectify(image)):
        raise CliError(f'cannot write image {args.output}')
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='zeroshot-calib',
        description='Zero-shot calibration of wide-angle and fisheye cameras from resolution and '
                    'spec-sheet field of view (J.-Y. Lee, CVPR 2021).')
    sub = parser.add_subparsers(dest='command', required=True)

    solve = sub.add_parser('solve', help='calibrate from a spec sheet')
    _add_spec_arguments(solve, size_required=False)
    _add_output_arguments(solve)
    solve.add_argument('--method', default='bracketed', choices=('bracketed', 'newton'),
                       help="root finder: bracketed (exact, default) or the paper's damped Newton")
    solve.add_argument('--camera-name', default='camera', help='camera_name in the YAML file')
    solve.add_argument('--json', action='store_true', help='print one JSON object')
    solve.add_argument('--yaml', metavar='FILE', help='write a camera_info_manager calibration file')
    solve.add_argument('--batch', metavar='CSV',
                       help='cameras, one per row: name,width,height,hfov,vfov,dfov (empty cells '
                            'allowed); prints one JSON object per line')
    solve.add_argument('--yaml-dir', metavar='DIR', help='with --batch: write DIR/<name>.yaml per camera')
    solve.set_defaults(run=_cmd_solve)

    rectify = sub.add_parser('rectify', help='rectify an image file')
    rectify.add_argument('input', help='input image')
    rectify.add_argument('-o', '--output', required=True, help='output image')
    _add_spec_arguments(rectify, size_required=False)
    _add_output_arguments(rectify)
    rectify.add_argument('--interpolation', type=int, default=1, choices=sorted(INTERPOLATIONS),
                         help='0 nearest, 1 linear, 2 cubic, 4 lanczos4 (default 1)')
    rectify.set_defaults(run=_cmd_rectify)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except (CliError, SpecError, CalibrationFileError, NoConvergence, ValueError, OSError) as exc:
        print(f'zeroshot-calib: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
