"""``zeroshot-calib evaluate``: the paper's evaluation protocol (Tables 3 and 4 layouts) on
chessboard images or a corners file, against spec-sheet FOVs or FOVs derived from a calibration
file."""
from __future__ import annotations

import json
import os

from ..core.checkerboard.evaluation import evaluate, evaluation_to_dict, format_tables
from ..core.lens.models import camera_from_calibration
from ..core.lens.ray_limits import missing_fov
from ..core.ros_formats.calibration_file import json_safe
from ..core.zeroshot.spec import CameraSpec
from .arguments import CliError, add_progress_argument, integer
from .corners import add_corner_arguments, corner_set, fov_spec
from .output import end_progress, load_calibration, with_progress


def add_parser(subparsers):
    ev = subparsers.add_parser('evaluate', help="the paper's evaluation (Tables 3 and 4 layouts) on chessboard "
                                                'images or a corners file')
    add_corner_arguments(ev)
    ev.add_argument('--spec-from', metavar='CALIB.yaml',
                    help='no spec sheet: derive hfov / vfov from this calibration file (also shown '
                         'as the reference camera)')
    ev.add_argument('--spec-from-model', choices=('equidistant', 'plumb_bob'),
                    help="read --spec-from's coefficients as this model (default: its distortion_model)")
    ev.add_argument('--shots', type=integer, default=1,
                    help='images per calibration in Table 4 (1: single-shot, default; 0: no Table 4)')
    ev.add_argument('--runs', type=integer, help='only the first N single-shot runs (quicker, partial)')
    ev.add_argument('--name', help='camera name in the tables (default: the image folder / file name)')
    ev.add_argument('--json', action='store_true', help='print one JSON object')
    add_progress_argument(ev)
    ev.set_defaults(run=run)


def run(args):
    return with_progress(args, 'evaluate:', _evaluate)


def _evaluate(args, progress):
    corners = corner_set(args, progress=progress)
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
    result = evaluate(corners, spec, shots=args.shots, runs=runs, name=name, spec_source=spec_source,
                      reference=reference, reference_source=reference_source, progress=progress)
    end_progress()
    if args.json:
        print(json.dumps(json_safe(evaluation_to_dict(result))))
    else:
        print(format_tables(result))
    return 0


def _evaluation_spec(args, corners):
    """(spec, spec_source, reference camera, reference_source) from the FOV flags or --spec-from."""
    if not args.spec_from:
        if args.spec_from_model:
            raise CliError('--spec-from-model needs --spec-from FILE')
        return fov_spec(args, corners), 'spec sheet (command line)', None, ''
    if args.hfov is not None or args.vfov is not None or args.dfov is not None:
        raise CliError('give --spec-from FILE or --hfov / --vfov / --dfov, not both')
    source = load_calibration(args.spec_from, '--spec-from')
    model = args.spec_from_model or source.distortion_model
    if (source.width, source.height) != (corners.width, corners.height):
        raise CliError(f'{args.spec_from} is {source.width}x{source.height} but the images are '
                       f'{corners.width}x{corners.height}')
    camera = camera_from_calibration(model, source.K, source.D, source.width, source.height)
    fovs = camera.fields_of_view()
    _check_fovs_derived(camera, fovs, f'--spec-from {args.spec_from} (read as {model})')
    spec = CameraSpec(corners.width, corners.height, hfov=fovs['hfov'], vfov=fovs['vfov'])
    text = (f'no spec sheet: hfov / vfov derived from {args.spec_from} read as {model}, the sums of the '
            'half-angles either side of the principal point along (0, cy)-(W, cy) and (cx, 0)-(cx, H)')
    return spec, text, camera, f'{args.spec_from} ({model})'


def _check_fovs_derived(camera, fovs, source):
    """CliError when an edge pixel has no ray: the lens curve turns back before the image edge."""
    missing = missing_fov(camera, fovs)
    if missing is None:
        return
    if missing.side is not None:
        raise CliError(f"{source}: the calibration's distortion turns back at {missing.reach_px:.0f} px from the "
                       f'principal point, before the image edge ({missing.side}, {missing.edge_distance_px:.0f} px '
                       f'away), so it gives no {missing.fov}: allowed: a calibration whose distortion rises up to '
                       'the image edges (or give --hfov / --vfov instead of --spec-from)')
    raise CliError(f'{source}: {missing.fov} = {missing.value} cannot be derived: allowed: a calibration with rays '
                   'at the image edges')
