"""``zeroshot-calib calibrate``: a camera from chessboard images or a corners file; with a spec
sheet, by default the MAP fit over corners and the spec's FOVs (core/estimation/board_fit.py),
else FC_eq.d. (core/checkerboard/calibration.py)."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import sys

import numpy as np

from ..core.checkerboard.calibration import as_solution, calibrate
from ..core.checkerboard.evaluation import reprojection_error
from ..core.estimation.terms import FOV_TOLERANCE_DEG
from ..core.lens.fitting import DISTORTION_FITS, FIT_WARNING_PX
from ..core.lens.models import RadialKannalaBrandtCamera
from ..core.lens.ray_limits import plumb_bob_refusal
from ..core.ros_formats.calibration_file import CameraCalibration, json_safe, solution_summary, summary_text
from ..core.ros_formats.rectify import principal_point_camera_matrix
from ..core.zeroshot.solver import NoConvergence, solve_zero_shot
from ..core.zeroshot.spec import SpecError
from .arguments import (EXIT_NOT_ADOPTED, EXIT_STATUSES, REPORT_HELP, CliError, add_output_arguments,
                        add_progress_argument, number)
from .corners import add_corner_arguments, corner_set, fov_spec
from .output import (end_progress, fit_warnings, kannala_brandt_record, not_adopted, print_warnings,
                     read_input_image, save_calibration, uncertainty_line, with_progress, write_report)


def add_parser(subparsers):
    calib = subparsers.add_parser(
        'calibrate', help='calibrate from chessboard images or a corners file (with a spec: '
                          'MAP over corners and the spec FOVs; without: FC_eq.d.)',
        description='Checkerboard calibration. Without a spec: FC_eq.d. (the paper\'s model) '
                    'from the default start. With --hfov / --vfov / --dfov: by default the spec '
                    'is EVIDENCE (--spec-as evidence): one MAP fit of a Kannala-Brandt camera '
                    'over the corners, the spec FOVs (+- --fov-tolerance) and stated priors, '
                    'reporting uncertainty_px; --spec-as start is the earlier behaviour, '
                    'FC_eq.d. started from the zero-shot camera (FC_eq.d.+ZS), the spec '
                    'forgotten after the start.', epilog=EXIT_STATUSES)
    add_corner_arguments(calib)
    calib.add_argument('--spec-as', default='evidence', choices=('evidence', 'start'),
                       help='with a spec: evidence (default): MAP over corners + spec FOVs + priors, '
                            'Kannala-Brandt camera with uncertainty_px; start: FC_eq.d. from the zero-shot '
                            'camera (FC_eq.d.+ZS), the spec used only as the start')
    calib.add_argument('--fov-tolerance', type=number, default=FOV_TOLERANCE_DEG, metavar='DEG',
                       help='how far the spec FOVs may be off (1 sigma, degrees; default '
                            f'{FOV_TOLERANCE_DEG:g}): with --spec-as evidence, their weight in the fit; '
                            'with a spec, the warning when the zero-shot camera misses a given FOV by more')
    calib.add_argument('--single', metavar='IMAGE',
                       help='single-shot: calibrate on this image only (one of the inputs, a name in '
                            '--corners, or an image file on its own)')
    calib.add_argument('--principal-point', default='auto', choices=('auto', 'fixed', 'free'),
                       help='--spec-as start or no spec: fixed at the image centre or free; auto: free from 3 '
                            'images on (default); with the spec as evidence it is free under its prior')
    add_output_arguments(calib)
    calib.add_argument('--camera-name', default='camera', help='camera_name in the YAML file')
    calib.add_argument('--json', action='store_true', help='print one JSON object')
    calib.add_argument('--yaml', metavar='FILE', help='write a camera_info_manager calibration file')
    calib.add_argument('--report', metavar='OUT.png',
                       help=REPORT_HELP.format(extra=', the board coverage and the reprojection RMS of each image'))
    add_progress_argument(calib)
    calib.set_defaults(run=run)


def run(args):
    return with_progress(args, 'calibrate:', _calibrate)


def _calibrate(args, progress):
    corners = corner_set(args, args.single, progress)
    views = None
    if args.single:
        if os.path.basename(args.single) in {os.path.basename(p) for p in corners.missing}:
            raise CliError(f'board {corners.board.size} not found in {args.single}')
        views = [corners.index(args.single)]
    spec = fov_spec(args, corners)
    zero_shot = _spec_solution(spec, args.fov_tolerance)
    spec_warnings = [] if zero_shot is None else zero_shot.warnings
    if spec is not None and args.spec_as == 'evidence':
        if args.principal_point != 'auto':
            raise CliError(f'--principal-point {args.principal_point} is for --spec-as start (FC_eq.d.): the '
                           'spec-as-evidence fit always frees the principal point under its prior')
        return _calibrate_with_spec(args, corners, views, spec, spec_warnings, progress, zero_shot)
    principal_point = {'auto': None, 'fixed': False, 'free': True}[args.principal_point]
    if progress is not None:
        progress(f'fitting FC_eq.d. to {len(corners) if views is None else len(views)} image(s)')
    result = calibrate(corners, 'fc+zs' if spec is not None else 'fc', views, spec, principal_point, zero_shot)
    end_progress()
    if not result.ok:
        raise CliError(f'calibration failed: {result.error}')
    solution = as_solution(result, spec)
    calibration, fit = CameraCalibration.from_solution(solution, args.distortion_model, args.balance,
                                                       args.fov_scale, args.camera_name)
    calibration = _calibrated_P(calibration, solution.camera, args)
    if args.distortion_model == 'plumb_bob':
        _check_plumb_bob(solution.camera, fit.max_error_px, 'the calibrated camera')
    summary = solution_summary(solution, calibration, fit)
    summary['warning'] = spec_warnings + fit_warnings(solution, calibration, fit)
    used = [corners.names[v] for v in result.views]
    summary.update({
        'method': result.label, 'init': result.init, 'a': solution.omega * solution.f,
        'principal_point': 'fixed' if result.fixed_principal_point else 'free',
        'images': len(used), 'image_names': used,
        'board': {'cols': corners.board.cols, 'rows': corners.board.rows, 'square': corners.board.square},
        'rms_px': result.rms_px, 'notes': list(result.notes),
        'rejected_corners': [r.to_dict() for r in result.rejected],
        'duplicate_views': [{'image': a, 'same_as': b, 'rms_difference_px': d}
                            for a, b, d in result.duplicates],
        'spec_as': 'start' if spec is not None else None, 'uncertainty_px': None,
        'uncertainty': 'not estimated for FC_eq.d. (no spec, or the spec as a start): give the spec with '
                       '--spec-as evidence (the default) for an error bar',
    })
    if views is not None and len(corners) > 1:
        summary['eps_all_px'] = reprojection_error(result.camera, corners).rms
    if solution.camera.beyond_domain():
        summary['notes'].append('the image corners are 90 degrees or more off-axis in the calibrated '
                                f'model; {calibration.distortion_model} coefficients are fitted up to '
                                '90 degrees and extrapolate beyond')
    report = _calibrate_report(args, corners, list(result.views), solution.camera, summary, accepted=None,
                               reason=f'{result.label} calibration (start: {result.init}), rms {result.rms_px:.3g} px: '
                                      'no quality gate without the spec as evidence',
                               spec=spec, uncertainty_reason=summary['uncertainty'])
    if args.yaml:
        save_calibration(calibration, args.yaml)
    write_report(args, report, [f'--yaml {args.yaml}'] if args.yaml else [])
    print_warnings(summary['warning'])
    if args.json:
        print(json.dumps(json_safe(summary)))
        return 0
    lines = summary_text(summary).splitlines()
    if spec is None:
        lines[0] = f"camera    {summary['width']} x {summary['height']} px, no spec (default start)"
    lines.append(f"method    {summary['method']} (start: {result.init}), principal point {summary['principal_point']}")
    _print_calibrate_text(lines + _board_lines(summary, corners, used, result.rms_px), summary, args)
    return 0


def _calibrate_with_spec(args, corners, views, spec, spec_warnings=(), progress=None, solution=None):
    """`calibrate` with the spec as evidence: the MAP over corners, FOVs and priors
    (core/estimation/board_fit.py); the camera is Kannala-Brandt (ROS equidistant, exact). Exit
    status EXIT_NOT_ADOPTED when the fit is not adopted (the zero-shot camera is written)."""
    from ..core.estimation.board_fit import METHOD_LABEL, fit_board  # scipy.optimize: only when asked
    if not (args.fov_tolerance > 0 and math.isfinite(args.fov_tolerance)):
        raise CliError(f'--fov-tolerance {args.fov_tolerance:g} is invalid: allowed: degrees, greater than 0')
    fit = fit_board(corners, spec, views, fov_tolerance_deg=args.fov_tolerance, progress=progress, solution=solution)
    end_progress()
    camera = fit.camera
    if args.distortion_model == 'equidistant':
        D, fit_error = np.asarray(camera.D, float), 0.0  # a Kannala-Brandt camera: its D is exact
        fit_warnings = []
    else:
        distortion = DISTORTION_FITS[args.distortion_model](RadialKannalaBrandtCamera(camera))
        D, fit_error = distortion.D, distortion.max_error_px
        _check_plumb_bob(camera, fit_error, 'the calibrated camera' if fit.accepted else 'the camera written')
        fit_warnings = [] if fit_error <= FIT_WARNING_PX else [
            f'the ROS {args.distortion_model} fit of the calibrated camera is off by up to {fit_error:.3g} px in '
            f'the image (fit error; warning above {FIT_WARNING_PX:g} px), so tools that rectify with its D '
            'coefficients are that far off: use --distortion-model equidistant (exact)']
    # the gate may keep the zero-shot camera (fit_board, step 4): then that is what is written,
    # and the record says so where a user looks first (model, method), not only in the notes
    model = 'calibrated (Kannala-Brandt)' if fit.accepted else 'zero-shot (Kannala-Brandt fit; the board fit not adopted)'
    summary, calibration = kannala_brandt_record(camera, spec, model, args, args.distortion_model, D, fit_error,
                                                  rectified=principal_point_camera_matrix)
    used = [corners.names[v] for v in fit.views]
    summary.update({
        'warning': list(spec_warnings) + fit_warnings + list(fit.warnings),
        'method': METHOD_LABEL if fit.accepted else f'zero-shot kept ({METHOD_LABEL} not adopted)',
        'accepted': fit.accepted, 'reason': fit.reason, 'init': 'zero-shot', 'a': None, 'spec_as': 'evidence',
        'principal_point': 'free (prior)', 'images': len(used), 'image_names': used,
        'board': {'cols': corners.board.cols, 'rows': corners.board.rows, 'square': corners.board.square},
        'rms_px': fit.rms_px, 'notes': list(fit.notes),
        'rejected_corners': [r.to_dict() for r in fit.rejected],
        'duplicate_views': [{'image': a, 'same_as': b, 'rms_difference_px': d} for a, b, d in fit.duplicates],
        'uncertainty_px': fit.uncertainty_px, 'uncertainty': fit.uncertainty.reason,
        'fit': fit.summary(),
    })
    if views is not None and len(corners) > 1:
        summary['eps_all_px'] = reprojection_error(camera, corners).rms
    report = _calibrate_report(args, corners, list(fit.views), camera, summary, accepted=fit.accepted,
                               reason=fit.reason, spec=spec, uncertainty=fit.uncertainty,
                               uncertainty_px=fit.uncertainty_px, uncertainty_reason=fit.uncertainty.reason,
                               zero_shot_camera=fit.zero_shot_camera)
    refused = None if fit.accepted else not_adopted('board fit not adopted', fit.reason.split(': ', 1)[-1],
                                                     args.yaml)
    if args.yaml:
        save_calibration(calibration, args.yaml, [refused[0]] if refused else ())
    write_report(args, report, [f'--yaml {args.yaml}'] if args.yaml else [])
    print_warnings(summary['warning'])
    status = 0
    if refused:
        print(refused[1], file=sys.stderr, flush=True)
        status = EXIT_NOT_ADOPTED
    if args.json:
        print(json.dumps(json_safe(summary)))
        return status
    given = ', '.join(f'{k} {v:g} -> {fit.fovs_fitted[k]:.2f}' for k, v in fit.fovs_given.items())
    method = (f"method    {METHOD_LABEL}, spec as evidence (FOVs +- {args.fov_tolerance:g} deg), start: zero-shot, "
              f"principal point free (prior), k1..k{fit.order} moved" if fit.accepted else
              f"method    zero-shot kept: the {METHOD_LABEL} was not adopted ({fit.reason.split(': ', 1)[-1]})")
    lines = summary_text(json_safe(summary)).splitlines() + [method] + _board_lines(summary, corners, used, fit.rms_px)
    lines.append(uncertainty_line(summary, args.fov_tolerance))
    lines.append(f"spec      {given} deg (given -> {'fitted' if fit.accepted else 'the board fit'}): "
                 + ('agrees' if fit.spec_agrees else 'DISAGREES with the corners (see the warning)'))
    _print_calibrate_text(lines, summary, args)
    return status


def _spec_solution(spec, fov_tolerance):
    """The zero-shot solution of ``spec``, its warnings the given FOVs it misses by more than
    ``fov_tolerance``; None without a spec, or when none can be solved (the calibration then
    says why)."""
    if spec is None:
        return None
    try:
        return solve_zero_shot(spec, 'auto', fov_tolerance=fov_tolerance)
    except (SpecError, NoConvergence):
        return None


def _calibrated_P(calibration, camera, args):
    """``calibration`` with P centred on the calibrated principal point, as ROS camera_calibration
    writes it for a fisheye (core/ros_formats/rectify.principal_point_camera_matrix)."""
    P = np.hstack([principal_point_camera_matrix(camera, args.balance, args.fov_scale), np.zeros((3, 1))])
    return dataclasses.replace(calibration, P=P)


def _calibrate_report(args, corners, used_views, camera, summary, **fields):
    """The ReportData of `calibrate` (None without --report): the board's views under ``camera``,
    the first used image for the preview when it can be read (not from a --corners file)."""
    if not args.report:
        return None
    from ..core.report.calibration_report import ReportData, board_views
    image, name = None, ''
    path = corners.names[used_views[0]] if len(used_views) else None
    if path is not None and not args.corners and os.path.isfile(path):
        try:
            image, _ = read_input_image(path)
            name = os.path.basename(path)
        except CliError:
            image = None
    if image is not None and (image.shape[1], image.shape[0]) != (camera.width, camera.height):
        image, name = None, ''
    return ReportData('calibrate', camera, summary['model'], image=image, image_name=name, balance=args.balance,
                      fov_scale=args.fov_scale, board=board_views(corners, camera, used_views),
                      warnings=summary['warning'], camera_name=args.camera_name,
                      fov_tolerance_deg=args.fov_tolerance, rectified=principal_point_camera_matrix, **fields)


def _board_lines(summary, corners, used, rms_px):
    """`calibrate`'s text lines of the images used, the reprojection RMS and eq. 20 on all images."""
    lines = [
        f"images    {len(used)}" + (f" ({os.path.basename(used[0])})" if len(used) == 1 else '')
        + f", board {corners.board.size}, square {corners.board.square:g} m",
        f"rms       {rms_px:.4f} px (reprojection, on the calibration images)",
    ]
    if 'eps_all_px' in summary:
        lines.append(f"eps all   {summary['eps_all_px']:.4f} px (eq. 20 on all {len(corners)} images)")
    return lines


def _print_calibrate_text(lines, summary, args):
    lines += [f'note      {n}' for n in summary['notes']]
    if args.yaml:
        lines.append(f'wrote {args.yaml}')
    if args.report:
        lines.append(f'wrote {args.report}')
    print('\n'.join(lines))


def _check_plumb_bob(camera, fit_error, what):
    """CliError when --distortion-model plumb_bob cannot represent ``camera`` (core/lens/ray_limits.py)."""
    refusal = plumb_bob_refusal(camera, fit_error)
    if refusal is not None:
        raise CliError(f'--distortion-model plumb_bob cannot represent {what}: {refusal}: use '
                       '--distortion-model equidistant')
