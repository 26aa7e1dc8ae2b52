"""``zeroshot-calib``: the ROS-free command line.

    zeroshot-calib solve --width 1920 --height 1080 --hfov 118 --vfov 69 [--json] [--yaml FILE]
    zeroshot-calib solve --batch cameras.csv [--yaml-dir DIR]
    zeroshot-calib solve --preset gopro_hero9_wide [--hfov 120] [--json]
    zeroshot-calib presets [--json]
    zeroshot-calib rectify IN.png -o OUT.png --hfov 118 --vfov 69
    zeroshot-calib calibrate 'images/*.png' [--board 8x6 --square 0.108] [--hfov H --vfov V] [--single IMG]
    zeroshot-calib evaluate 'images/*.png' --hfov H --vfov V [--json] [--save-corners FILE]

Errors exit with status 2 and one line on stderr, never a traceback.
"""
from __future__ import annotations

import argparse
import csv
import glob
import json
import os
import sys

import cv2

from .core.calibration import as_solution, calibrate
from .core.calibration_file import (DISTORTION_MODELS, CalibrationFileError, CameraCalibration,
                                    json_safe, solution_summary, summary_text)
from .core.camera_models import camera_from_calibration
from .core.corners import CornerSet, detect_corners, parse_board
from .core.evaluation import evaluate, evaluation_to_dict, format_tables, reprojection_error
from .core.presets import load_presets, spec_with_preset
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
                             'else equidistant, and switches to wide (angle-space model for FOVs of '
                             '180 deg and more) only when needed (default: auto)')


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


SOLVE_SPEC_FIELDS = ('width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov')


def _solve_spec(args):
    """The spec of `solve`: the --preset's fields, each overridden by a flag given explicitly."""
    if not args.preset and (args.width is None or args.height is None):
        raise CliError('--width and --height are required (or --preset NAME, or --batch FILE)')
    return spec_with_preset(args.preset, **{k: getattr(args, k, None) for k in SOLVE_SPEC_FIELDS})


def _cmd_presets(args):
    presets = load_presets()
    records = [{'name': p.name, 'width': p.spec.width, 'height': p.spec.height, 'hfov': p.spec.hfov,
                'vfov': p.spec.vfov, 'dfov': p.spec.dfov, 'circle_diameter': p.spec.circle_diameter,
                'circle_fov': p.spec.circle_fov, 'description': p.description, 'source': p.source}
               for p in presets.values()]
    if args.json:
        print(json.dumps(records))
        return 0

    def deg(value):
        return '-' if value is None else f'{value:g}'
    rows = [('name', 'resolution', 'hfov', 'vfov', 'dfov', 'circle', 'source')]
    for r in records:
        circle = '-' if r['circle_diameter'] is None else f"{r['circle_diameter']:g}px/{r['circle_fov']:g}"
        rows.append((r['name'], f"{r['width']}x{r['height']}", deg(r['hfov']), deg(r['vfov']),
                     deg(r['dfov']), circle, r['source']))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]) - 1)]
    for row in rows:
        print('  '.join(cell.ljust(w) for cell, w in zip(row, widths)) + '  ' + row[-1])
    return 0


def _cmd_solve(args):
    if args.batch:
        if args.preset:
            raise CliError('--preset and --batch cannot be combined')
        return _solve_batch(args)
    spec = _solve_spec(args)
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


# -- calibrate / evaluate: chessboard calibration and the paper's evaluation protocol --------------


def _add_corner_arguments(parser):
    parser.add_argument('images', nargs='*', help='chessboard images: files or glob patterns')
    parser.add_argument('--corners', metavar='FILE',
                        help='a corners file (JSON, see docs/calibration.md) instead of images')
    parser.add_argument('--board', default='8x6',
                        help='inner corners COLSxROWS, as OpenCV patternSize (default 8x6)')
    parser.add_argument('--square', type=float, default=0.108, help='square side in metres (default 0.108)')
    parser.add_argument('--skip-missing', action='store_true',
                        help='leave out (and list on stderr) images whose board is not found, '
                             'instead of failing')
    parser.add_argument('--save-corners', metavar='FILE', help='write the detected corners to FILE')
    parser.add_argument('--hfov', type=float, help='spec-sheet horizontal field of view (deg)')
    parser.add_argument('--vfov', type=float, help='spec-sheet vertical field of view (deg)')
    parser.add_argument('--dfov', type=float, help='spec-sheet diagonal field of view (deg)')


def _image_paths(patterns):
    paths = []
    for pattern in patterns:
        if any(ch in pattern for ch in '*?['):
            found = sorted(glob.glob(pattern))
            if not found:
                raise CliError(f'no image matches {pattern}')
            paths += found
        else:
            paths.append(pattern)
    return paths


def _corner_set(args, single=None):
    """The CornerSet of the images / --corners file; writes --save-corners."""
    if args.corners and args.images:
        raise CliError('give chessboard images or --corners FILE, not both')
    if args.corners:
        corners = CornerSet.load(args.corners)
    else:
        paths = _image_paths(args.images) or ([single] if single else [])
        if not paths:
            raise CliError('no input: give chessboard images or --corners FILE')
        corners = detect_corners(paths, parse_board(args.board, args.square), args.skip_missing)
        if corners.missing:
            print(f'zeroshot-calib: warning: board {corners.board.size} not found in '
                  f'{len(corners.missing)} of {len(paths)} images, left out: '
                  f'{", ".join(os.path.basename(p) for p in corners.missing)}', file=sys.stderr)
    if args.save_corners:
        corners.save(args.save_corners)
    return corners


def _fov_spec(args, corners):
    if args.hfov is None and args.vfov is None and args.dfov is None:
        return None
    return CameraSpec(corners.width, corners.height, args.hfov, args.vfov, args.dfov)


def _cmd_calibrate(args):
    corners = _corner_set(args, args.single)
    views = None
    if args.single:
        if os.path.basename(args.single) in {os.path.basename(p) for p in corners.missing}:
            raise CliError(f'board {corners.board.size} not found in {args.single}')
        views = [corners.index(args.single)]
    spec = _fov_spec(args, corners)
    principal_point = {'auto': None, 'fixed': False, 'free': True}[args.principal_point]
    result = calibrate(corners, 'fc+zs' if spec is not None else 'fc', views, spec, principal_point)
    if not result.ok:
        raise CliError(f'calibration failed: {result.error}')
    solution = as_solution(result, spec)
    calibration, fit = CameraCalibration.from_solution(solution, args.distortion_model, args.balance,
                                                       args.fov_scale, args.camera_name)
    summary = solution_summary(solution, calibration, fit)
    used = [corners.names[v] for v in result.views]
    summary.update({
        'method': result.label, 'init': result.init, 'a': solution.omega * solution.f,
        'principal_point': 'fixed' if result.fixed_principal_point else 'free',
        'images': len(used), 'image_names': used,
        'board': {'cols': corners.board.cols, 'rows': corners.board.rows, 'square': corners.board.square},
        'rms_px': result.rms_px, 'notes': list(result.notes),
    })
    if views is not None and len(corners) > 1:
        summary['eps_all_px'] = reprojection_error(result.camera, corners).rms
    if solution.camera.beyond_domain():
        summary['notes'].append('the image corners are 90 degrees or more off-axis in the calibrated '
                                f'model; {calibration.distortion_model} coefficients are fitted up to '
                                '90 degrees and extrapolate beyond')
    if args.yaml:
        calibration.save(args.yaml)
    if args.json:
        print(json.dumps(json_safe(summary)))
        return 0
    lines = summary_text(summary).splitlines()
    if spec is None:
        lines[0] = f"camera    {summary['width']} x {summary['height']} px, no spec (default start)"
    lines += [
        f"method    {summary['method']} (start: {result.init}), principal point {summary['principal_point']}",
        f"images    {len(used)}" + (f" ({os.path.basename(used[0])})" if len(used) == 1 else '')
        + f", board {corners.board.size}, square {corners.board.square:g} m",
        f"rms       {result.rms_px:.4f} px (reprojection, on the calibration images)",
    ]
    if 'eps_all_px' in summary:
        lines.append(f"eps all   {summary['eps_all_px']:.4f} px (eq. 20 on all {len(corners)} images)")
    lines += [f'note      {n}' for n in summary['notes']]
    if args.yaml:
        lines.append(f'wrote {args.yaml}')
    print('\n'.join(lines))
    return 0


def _evaluation_spec(args, corners):
    """(spec, spec_source, reference camera, reference_source) from the FOV flags or --spec-from."""
    if not args.spec_from:
        if args.spec_from_model:
            raise CliError('--spec-from-model needs --spec-from FILE')
        return _fov_spec(args, corners), 'spec sheet (command line)', None, ''
    if args.hfov is not None or args.vfov is not None or args.dfov is not None:
        raise CliError('give --spec-from FILE or --hfov / --vfov / --dfov, not both')
    source = CameraCalibration.load(args.spec_from)
    model = args.spec_from_model or source.distortion_model
    if (source.width, source.height) != (corners.width, corners.height):
        raise CliError(f'{args.spec_from} is {source.width}x{source.height} but the images are '
                       f'{corners.width}x{corners.height}')
    camera = camera_from_calibration(model, source.K, source.D, source.width, source.height)
    fovs = camera.fields_of_view()
    spec = CameraSpec(corners.width, corners.height, hfov=fovs['hfov'], vfov=fovs['vfov'])
    text = (f'no spec sheet: hfov / vfov derived from {args.spec_from} read as {model}, the angles between '
            'the rays of (0, cy)-(W, cy) and (cx, 0)-(cx, H)')
    return spec, text, camera, f'{args.spec_from} ({model})'


def _cmd_evaluate(args):
    corners = _corner_set(args)
    spec, spec_source, reference, reference_source = _evaluation_spec(args, corners)
    if args.runs is not None and args.runs < 1:
        raise CliError(f'--runs {args.runs} is invalid: allowed: 1 or more')
    runs = None if args.runs is None else list(range(min(args.runs, len(corners))))
    if args.name:
        name = args.name
    elif args.corners:
        name = os.path.splitext(os.path.basename(args.corners))[0]
    else:
        name = os.path.basename(os.path.dirname(os.path.abspath(corners.names[0]))) or 'camera'
    progress = None
    if args.progress:
        progress = lambda m: print(f'zeroshot-calib: {m}', file=sys.stderr, flush=True)  # noqa: E731
    result = evaluate(corners, spec, shots=args.shots, runs=runs, name=name, spec_source=spec_source,
                      reference=reference, reference_source=reference_source, progress=progress)
    if args.json:
        print(json.dumps(json_safe(evaluation_to_dict(result))))
    else:
        print(format_tables(result))
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
    solve.add_argument('--preset', metavar='NAME',
                       help='start from a published spec (`zeroshot-calib presets` lists them); '
                            'explicit --width/--height/--hfov/... override its fields')
    solve.add_argument('--circle-diameter', type=float, metavar='PX',
                       help='circular fisheye: image-circle diameter (px), with --circle-fov')
    solve.add_argument('--circle-fov', type=float, metavar='DEG',
                       help='circular fisheye: field of view across the image circle (deg)')
    solve.set_defaults(run=_cmd_solve)

    presets = sub.add_parser('presets', help='list the camera presets (published spec sheets)')
    presets.add_argument('--json', action='store_true', help='print one JSON array')
    presets.set_defaults(run=_cmd_presets)

    rectify = sub.add_parser('rectify', help='rectify an image file')
    rectify.add_argument('input', help='input image')
    rectify.add_argument('-o', '--output', required=True, help='output image')
    _add_spec_arguments(rectify, size_required=False)
    _add_output_arguments(rectify)
    rectify.add_argument('--interpolation', type=int, default=1, choices=sorted(INTERPOLATIONS),
                         help='0 nearest, 1 linear, 2 cubic, 4 lanczos4 (default 1)')
    rectify.set_defaults(run=_cmd_rectify)
    calib = sub.add_parser('calibrate', help='calibrate from chessboard images or a corners file '
                                             '(FC_eq.d., zero-shot start when a spec is given)')
    _add_corner_arguments(calib)
    calib.add_argument('--single', metavar='IMAGE',
                       help='single-shot: calibrate on this image only (one of the inputs, a name in '
                            '--corners, or an image file on its own)')
    calib.add_argument('--principal-point', default='auto', choices=('auto', 'fixed', 'free'),
                       help='fixed at the image centre or free; auto: free from 3 images on (default)')
    _add_output_arguments(calib)
    calib.add_argument('--camera-name', default='camera', help='camera_name in the YAML file')
    calib.add_argument('--json', action='store_true', help='print one JSON object')
    calib.add_argument('--yaml', metavar='FILE', help='write a camera_info_manager calibration file')
    calib.set_defaults(run=_cmd_calibrate)

    ev = sub.add_parser('evaluate', help="the paper's evaluation (Tables 3 and 4 layouts) on chessboard "
                                         'images or a corners file')
    _add_corner_arguments(ev)
    ev.add_argument('--spec-from', metavar='CALIB.yaml',
                    help='no spec sheet: derive hfov / vfov from this calibration file (also shown '
                         'as the reference camera)')
    ev.add_argument('--spec-from-model', choices=('equidistant', 'plumb_bob'),
                    help="read --spec-from's coefficients as this model (default: its distortion_model)")
    ev.add_argument('--shots', type=int, default=1,
                    help='images per calibration in Table 4 (1: single-shot, default; 0: no Table 4)')
    ev.add_argument('--runs', type=int, help='only the first N single-shot runs (quicker, partial)')
    ev.add_argument('--name', help='camera name in the tables (default: the image folder / file name)')
    ev.add_argument('--json', action='store_true', help='print one JSON object')
    ev.add_argument('--progress', action='store_true', help='report progress on stderr')
    ev.set_defaults(run=_cmd_evaluate)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except BrokenPipeError:  # output piped into `head`: not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (CliError, SpecError, CalibrationFileError, NoConvergence, ValueError, OSError) as exc:
        print(f'zeroshot-calib: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
