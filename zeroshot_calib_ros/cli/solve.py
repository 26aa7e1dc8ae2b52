"""``zeroshot-calib solve``: the camera of a spec sheet (flags, a --preset, or a --batch CSV of
cameras), printed as text or JSON and written as a camera_info_manager file and a report."""
from __future__ import annotations

import json
import os

from ..core.ros_formats.calibration_file import CalibrationFileError, CameraCalibration, solution_summary, summary_text
from ..core.zeroshot.batch import camera_name_of, read_batch, yaml_file_name
from ..core.zeroshot.presets import spec_with_preset
from ..core.zeroshot.solver import NoConvergence, solve_zero_shot
from ..core.zeroshot.spec import SpecError
from .arguments import (REPORT_HELP, SOLVE_SPEC_FIELDS, CliError, add_circle_arguments, add_fov_tolerance_argument,
                        add_output_arguments, add_spec_arguments, options_given)
from .output import (assumption_warnings, error_bar_keys, fit_warnings, print_warnings, save_calibration,
                     uncertainty_line, write_report)


def add_parser(subparsers):
    solve = subparsers.add_parser('solve', help='calibrate from a spec sheet')
    add_spec_arguments(solve, size_required=False)
    add_output_arguments(solve)
    solve.add_argument('--method', default='bracketed', choices=('bracketed', 'newton'),
                       help="root finder: bracketed (exact, default) or the paper's damped Newton")
    solve.add_argument('--camera-name', help='camera_name in the YAML file (default: camera)')
    add_fov_tolerance_argument(solve)
    solve.add_argument('--json', action='store_true', help='print one JSON object')
    solve.add_argument('--yaml', metavar='FILE', help='write a camera_info_manager calibration file')
    solve.add_argument('--report', metavar='OUT.png',
                       help=REPORT_HELP.format(extra=' (of a synthetic ruled cube)'))
    solve.add_argument('--batch', metavar='CSV',
                       help='cameras, one per row: name,width,height,hfov,vfov,dfov (empty cells '
                            'allowed), or the columns a header row names (those, circle_diameter, '
                            'circle_fov); # comments; prints one JSON object per line')
    solve.add_argument('--yaml-dir', metavar='DIR',
                       help='with --batch: write DIR/<name>.yaml per camera (the name made a safe file '
                            "name: letters, digits, '-', '_', '.'; others become '_')")
    solve.add_argument('--preset', metavar='NAME',
                       help='start from a published spec (`zeroshot-calib presets` lists them); '
                            'explicit --width/--height/--hfov/... override its fields')
    add_circle_arguments(solve)
    solve.set_defaults(run=run)


BATCH_INCOMPATIBLE = SOLVE_SPEC_FIELDS + ('preset', 'yaml', 'camera_name', 'report')
"""`solve` options a --batch run cannot honour: the CSV gives each camera's spec and name."""


def run(args):
    if args.batch is not None:
        given = options_given(args, BATCH_INCOMPATIBLE)
        if given:
            raise CliError(f'{given[0]} cannot be combined with --batch: each CSV row gives its camera '
                           '(columns name,width,height,hfov,vfov,dfov,circle_diameter,circle_fov)')
        return _solve_batch(args)
    if args.yaml_dir is not None:
        raise CliError('--yaml-dir needs --batch CSV (for one camera: --yaml FILE)')
    spec = _solve_spec(args)
    camera_name = 'camera' if args.camera_name is None else args.camera_name
    solution, calibration, fit = _solve(spec, args, camera_name)
    summary = solution_summary(solution, calibration, fit)
    warnings = solution.warnings + fit_warnings(solution, calibration, fit)
    warnings += _add_uncertainty(summary, spec, solution, args.fov_tolerance)
    warnings += assumption_warnings(solution)
    summary['warning'] = warnings
    report = None
    if args.report:
        from ..core.estimation.uncertainty import zero_shot_uncertainty
        from ..core.report.calibration_report import ReportData
        report = ReportData('solve', solution.camera, summary['model'], None, '', spec, args.fov_tolerance,
                            zero_shot_uncertainty(spec, args.fov_tolerance, solution), summary['uncertainty_px'],
                            summary['uncertainty'], balance=args.balance, fov_scale=args.fov_scale,
                            warnings=warnings, camera_name=camera_name)
    if args.yaml:
        save_calibration(calibration, args.yaml)
    write_report(args, report, [f'--yaml {args.yaml}'] if args.yaml else [])
    if args.json:
        print(json.dumps(summary))
    else:
        print(summary_text(summary) + '\n' + uncertainty_line(summary, args.fov_tolerance))
        if args.yaml:
            print(f'wrote {args.yaml}')
        if args.report:
            print(f'wrote {args.report}')
    print_warnings(warnings)
    return 0


def _solve(spec, args, camera_name='camera'):
    solution = solve_zero_shot(spec, args.model, getattr(args, 'method', 'bracketed'), args.fov_tolerance)
    calibration, fit = CameraCalibration.from_solution(
        solution, args.distortion_model, args.balance, args.fov_scale, camera_name)
    return solution, calibration, fit


def _solve_spec(args):
    """The spec of `solve`: the --preset's fields, each overridden by a flag given explicitly."""
    if not args.preset and (args.width is None or args.height is None):
        raise CliError('--width and --height are required (or --preset NAME, or --batch FILE)')
    return spec_with_preset(args.preset, **{k: getattr(args, k, None) for k in SOLVE_SPEC_FIELDS})


def _add_uncertainty(summary, spec, solution, fov_tolerance):
    """Put the zero-shot camera's error bar (core/estimation/uncertainty.py) into ``summary``;
    the ill-conditioning warning, if any, as a list."""
    from ..core.estimation.uncertainty import image_circle_radius, zero_shot_uncertainty  # scipy: only when asked
    uncertainty = zero_shot_uncertainty(spec, fov_tolerance, solution)
    summary['uncertainty_px'] = uncertainty.rms_px
    # with, of uncertainty_px, the part from the lens shapes a spec of one FOV (or the circle alone) leaves open
    summary.update(error_bar_keys(uncertainty, image_circle_radius(spec) is not None))
    return [uncertainty.warning] if uncertainty.warning else []


def _solve_batch(args):
    """One JSON object per camera row; a bad row reports an error object and the rest go on. The
    --yaml-dir files are written only when every row has been solved (else none, and a warning
    says so); a file that cannot be written is its row's error, and the records with 'yaml' are
    the files written."""
    failures = 0
    rows = read_batch(args.batch)
    written = {}  # file name (case-folded) -> (row, name) of the row that writes it
    outputs = []  # (row, line, name, JSON record, its warnings, (calibration, path) or None)
    for row in rows:
        number, line, name = row.number, row.line, row.name
        try:
            spec = row.spec()
            solution, calibration, fit = _solve(spec, args, camera_name_of(name))
            record = {'name': name, 'camera_name': calibration.camera_name,
                      **solution_summary(solution, calibration, fit)}
            warnings = solution.warnings + fit_warnings(solution, calibration, fit)
            warnings += _add_uncertainty(record, spec, solution, args.fov_tolerance)
            warnings += assumption_warnings(solution)
            record['warning'] = warnings
            if args.yaml_dir is not None:
                file_name = yaml_file_name(name) or f'camera_{number}.yaml'
                key = file_name.casefold()
                if key in written:
                    first_row, first_name = written[key]
                    raise CliError(f'the name {name!r} gives the file {file_name}, already written for row '
                                   f'{first_row} ({first_name!r}): allowed: each name once (file names ignore case)')
                path = os.path.join(args.yaml_dir, file_name)
                written[key] = (number, name)
                record['yaml'] = path
                outputs.append((number, line, name, record, warnings, (calibration, path)))
            else:
                outputs.append((number, line, name, record, warnings, None))
        except (CliError, SpecError, CalibrationFileError, NoConvergence, ValueError) as exc:
            failures += 1
            record = {'name': name, 'row': number, 'line': line, 'error': ' '.join(str(exc).split())}
            outputs.append((number, line, name, record, [], None))
    bad_rows = failures
    if bad_rows and written:
        for _, _, _, record, _, _ in outputs:
            record.pop('yaml', None)
    for number, line, name, record, warnings, output in outputs:
        if output is not None and not bad_rows:  # a failed write: that row's error (its record has no 'yaml')
            try:
                save_calibration(*output)
            except CliError as exc:
                failures += 1
                record = {'name': name, 'row': number, 'line': line, 'error': ' '.join(str(exc).split())}
                warnings = []
        print(json.dumps(record), flush=True)
        print_warnings(warnings, f'row {number} ({name}): ')
    if bad_rows and written:
        print_warnings([f'{bad_rows} of {len(rows)} rows failed: no files written to {args.yaml_dir} (fix '
                        'the rows and run again)'])
    return 1 if failures else 0
