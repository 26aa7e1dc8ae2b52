# PYTHON_ARGCOMPLETE_OK (tab completion when argcomplete is installed: see main)
"""``zeroshot-calib``: the ROS-free command line.

    zeroshot-calib solve --width 1920 --height 1080 --hfov 118 --vfov 69 [--json] [--yaml FILE]
    zeroshot-calib solve --batch cameras.csv [--yaml-dir DIR]
    zeroshot-calib solve --preset gopro_hero9_wide [--hfov 120] [--json]
    zeroshot-calib presets [--json]
    zeroshot-calib rectify IN.png -o OUT.png --hfov 118 --vfov 69
    zeroshot-calib rectify IN.png -o OUT.png --calibration CALIB.yaml | --preset NAME
    zeroshot-calib calibrate 'images/*.png' [--board 8x6 --square 0.108] [--hfov H --vfov V] [--single IMG]
    zeroshot-calib evaluate 'images/*.png' --hfov H --vfov V [--json] [--save-corners FILE]

Errors exit with status 2 and one line on stderr, never a traceback; status 1: some --batch rows
failed (or an internal error, reported in one line); status 3: refine / calibrate ran but did not
adopt their result (the zero-shot camera of the spec is printed and written, and the file says so in
a comment). Warnings are one line each on stderr, ``zeroshot-calib: warning: ...``.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import difflib
import glob
import hashlib
import json
import math
import os
import re
import sys

# OpenCV's own pixel limit, read when cv2 loads (the header check of core/file_input.py comes
# first; this covers formats whose header it does not parse). A user's setting wins.
os.environ.setdefault('OPENCV_IO_MAX_IMAGE_PIXELS', '50000000')

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from . import __version__  # noqa: E402

from .core.checkerboard.calibration import as_solution, calibrate
from .core.ros_formats.calibration_file import (DISTORTION_MODELS, FORMATS, CalibrationFileError, CameraCalibration,
                                    MAX_FILE_BYTES, json_safe, solution_summary, stand_in_note, summary_text)
from .core.file_input import MAX_IMAGE_PIXELS, InputFileError, read_capped, read_image
from .core.lens.models import RadialCamera, camera_from_calibration
from .core.checkerboard.corners import SQUARE_ALLOWED, CornerSet, detect_corners, parse_board, square_ok
from .core.checkerboard.evaluation import evaluate, evaluation_to_dict, format_tables, reprojection_error
from .core.estimation.terms import FOV_TOLERANCE_DEG
from .core.lens.fitting import DISTORTION_FITS, FIT_WARNING_PX
from .core.zeroshot.presets import load_presets, spec_with_preset
from .core.ros_formats.rectify import INTERPOLATIONS, Rectifier, new_camera_matrix, principal_point_camera_matrix
from .core.zeroshot.solver import PROJECTION_CHOICES, NoConvergence, solve_zero_shot
from .core.zeroshot.spec import CameraSpec, SpecError


IMAGE_BUDGET = f'{MAX_IMAGE_PIXELS // 1_000_000} megapixels'
"""The pixel budget of every image read, as --help and the errors state it."""
EXIT_NOT_ADOPTED = 3
"""Exit status of `refine` / `calibrate` that ran fine but did not adopt their result: what they
print and write is the zero-shot camera of the spec (``accepted: false`` in --json)."""
EXIT_STATUSES = ('exit status: 0 done; 1 some --batch rows failed, or an internal error; 2 bad input or a '
                 'failure (one line on stderr); 3 refine / calibrate ran but did not adopt their result: the '
                 'zero-shot camera from the spec is printed and written (the file says so in a # comment; '
                 '--json: "accepted": false)')
"""The --help epilog on exit statuses."""


class CliError(Exception):
    """An error to report in one line."""


class _Parser(argparse.ArgumentParser):
    """argparse, with usage errors in one line (the usage itself is in --help)."""

    def error(self, message):
        self.exit(2, f'{self.prog}: error: {" ".join(str(message).split())} (see {self.prog} --help)\n')


_DECIMAL = re.compile(r'[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?\Z')
_NON_FINITE = re.compile(r'[-+]?(?:inf|infinity|nan)\Z', re.IGNORECASE)
_INTEGER = re.compile(r'[-+]?[0-9]+\Z')


def _number(text):
    """A float argument in ASCII decimal notation (Python's float() also takes '1_18', Arabic-Indic
    or fullwidth digits and surrounding spaces; those are refused). nan / inf pass here: the spec
    checks name the allowed range."""
    if not (_DECIMAL.match(text) or _NON_FINITE.match(text)):
        raise ValueError(f'not an ASCII decimal number: {text!r}')
    return float(text)


_number.__name__ = 'number'


def _whole_number(text):
    """An image side: an integer, or an integral float such as 1920.0 (1920.5 is refused by
    CameraSpec, which names the field and the range)."""
    if _INTEGER.match(text):
        return int(text)
    value = _number(text)
    return int(value) if math.isfinite(value) and value == int(value) else value


_whole_number.__name__ = 'whole number'


def _integer(text):
    """An integer argument, ASCII digits only."""
    if not _INTEGER.match(text):
        raise ValueError(f'not an ASCII integer: {text!r}')
    return int(text)


_integer.__name__ = 'integer'


def _add_spec_arguments(parser, size_required=True):
    parser.add_argument('--width', type=_whole_number, required=size_required, help='image width (px)')
    parser.add_argument('--height', type=_whole_number, required=size_required, help='image height (px)')
    parser.add_argument('--hfov', type=_number, help='horizontal field of view (deg)')
    parser.add_argument('--vfov', type=_number, help='vertical field of view (deg)')
    parser.add_argument('--dfov', type=_number, help='diagonal field of view (deg)')
    parser.add_argument('--model', default='auto', choices=PROJECTION_CHOICES,
                        help='fisheye projection; auto picks by dfov when all three FOVs are given, '
                             'else equidistant, and switches to wide (angle-space model for FOVs of '
                             '180 deg and more) only when needed (default: auto)')


def _add_output_arguments(parser):
    parser.add_argument('--distortion-model', default='equidistant', choices=DISTORTION_MODELS,
                        help='ROS distortion model to fit (default: equidistant)')
    parser.add_argument('--balance', type=_number, default=0.0,
                        help='rectified camera: 0 crops to valid pixels, 1 keeps every edge (default 0)')
    parser.add_argument('--fov-scale', type=_number, default=1.0,
                        help='rectified camera: divides its focal length (default 1)')


def _camera_name_of(row_name: str) -> str:
    """A batch row's name as a camera_name (camera_info_manager allows letters, digits and _ only:
    'hero9-wide' is written as hero9_wide), so that any row name gives a loadable file."""
    name = re.sub(r'[^A-Za-z0-9_]', '_', row_name)[:200]
    return name if name.strip('_') else 'camera'


def _solve(spec, args, camera_name='camera'):
    solution = solve_zero_shot(spec, args.model, getattr(args, 'method', 'bracketed'), args.fov_tolerance)
    calibration, fit = CameraCalibration.from_solution(
        solution, args.distortion_model, args.balance, args.fov_scale, camera_name)
    return solution, calibration, fit


def _fit_warnings(solution, calibration, fit):
    """One-line warnings (without the 'zeroshot-calib: warning: ' prefix) when the ROS
    distortion model written out (CameraInfo D, the YAML file) misses the solved camera by more
    than FIT_WARNING_PX somewhere in the image; [] otherwise."""
    error = fit.max_error_px
    if math.isfinite(error) and error <= FIT_WARNING_PX:
        return []
    model = calibration.distortion_model
    shown = f'{error:.3g} px' if math.isfinite(error) else 'not finite'
    text = (f'the ROS {model} fit of the solved camera is off by up to {shown} in the image (fit error; '
            f'warning above {FIT_WARNING_PX:g} px), so tools that rectify with its D coefficients are '
            'that far off')
    other = 'equidistant' if model == 'plumb_bob' else None
    if other is not None:
        other_error = DISTORTION_FITS[other](solution.camera).max_error_px
        if other_error < error:
            return [f'{text}: use --distortion-model {other} (fit error {other_error:.2g} px)']
    return [f'{text}: no ROS distortion model follows this lens to the image corners; rectify with the '
            "exact model instead (zeroshot-calib rectify, or the node's rectified images)"]


def _print_warnings(warnings, where=''):
    if warnings:
        _end_progress()
    for warning in warnings:
        print(f'zeroshot-calib: warning: {where}{warning}', file=sys.stderr, flush=True)


def _not_adopted(what, reason, yaml_path):
    """(file comment, stderr line) of a refine / calibrate whose result was not adopted (``what``:
    'not refined', 'board fit not adopted'): the camera printed and written is zero-shot's."""
    reason = ' '.join(str(reason).split())
    comment = f'{what}: {reason}; this is the zero-shot camera from the spec'
    held = f'{yaml_path} holds' if yaml_path else 'the camera printed is'
    line = (f'zeroshot-calib: {what}: {reason}; {held} the zero-shot camera from the spec '
            f'(exit status {EXIT_NOT_ADOPTED})')
    return comment, line


def _save_calibration(calibration, path, comments=()):
    """Write ``calibration`` to ``path`` with ``comments`` (and what a stand-in D coefficient
    means) as # comment lines, which camera_calibration_parsers skips."""
    note = stand_in_note(calibration.distortion_model, calibration.D)
    comments = list(comments) + ([f'distortion_coefficients: {note}'] if note else [])
    try:
        calibration.save(path, comments)
    except OSError as exc:
        raise CliError(f'cannot write {path}: {exc.strerror or exc}') from None


SOLVE_SPEC_FIELDS = ('width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov')


def _options_given(args, names):
    """The command-line spelling of each of ``names`` given (not None) in ``args``."""
    return ['--' + n.replace('_', '-') for n in names if getattr(args, n, None) is not None]


def _solve_spec(args):
    """The spec of `solve`: the --preset's fields, each overridden by a flag given explicitly."""
    if not args.preset and (args.width is None or args.height is None):
        raise CliError('--width and --height are required (or --preset NAME, or --batch FILE)')
    return spec_with_preset(args.preset, **{k: getattr(args, k, None) for k in SOLVE_SPEC_FIELDS})


BATCH_INCOMPATIBLE = SOLVE_SPEC_FIELDS + ('preset', 'yaml', 'camera_name', 'report')
"""`solve` options a --batch run cannot honour: the CSV gives each camera's spec and name."""


def _cmd_presets(args):
    presets = load_presets()
    records = [{'name': p.name, 'width': p.spec.width, 'height': p.spec.height, 'hfov': p.spec.hfov,
                'vfov': p.spec.vfov, 'dfov': p.spec.dfov, 'circle_diameter': p.spec.circle_diameter,
                'circle_fov': p.spec.circle_fov, 'given': p.given, 'description': p.description,
                'source': p.source}
               for p in presets.values()]
    if args.json:
        print(json.dumps(records))
        return 0

    def deg(value):
        return '-' if value is None else f'{value:g}'
    rows = [('name', 'resolution', 'hfov', 'vfov', 'dfov', 'circle', 'given', 'source')]
    for r in records:
        circle = '-' if r['circle_diameter'] is None else f"{r['circle_diameter']:g}px/{r['circle_fov']:g}"
        rows.append((r['name'], f"{r['width']}x{r['height']}", deg(r['hfov']), deg(r['vfov']),
                     deg(r['dfov']), circle, r['given'], r['source']))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]) - 1)]
    for row in rows:
        print('  '.join(cell.ljust(w) for cell, w in zip(row, widths)) + '  ' + row[-1])
    return 0


def _cmd_solve(args):
    if args.batch is not None:
        given = _options_given(args, BATCH_INCOMPATIBLE)
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
    warnings = solution.warnings + _fit_warnings(solution, calibration, fit)
    warnings += _add_uncertainty(summary, spec, solution, args.fov_tolerance)
    warnings += _assumption_warnings(solution)
    summary['warning'] = warnings
    report = None
    if args.report:
        from .core.estimation.uncertainty import zero_shot_uncertainty
        from .core.report.calibration_report import ReportData
        report = ReportData('solve', solution.camera, summary['model'], None, '', spec, args.fov_tolerance,
                            zero_shot_uncertainty(spec, args.fov_tolerance, solution), summary['uncertainty_px'],
                            summary['uncertainty'], balance=args.balance, fov_scale=args.fov_scale,
                            warnings=warnings, camera_name=camera_name)
    if args.yaml:
        _save_calibration(calibration, args.yaml)
    _write_report(args, report, [f'--yaml {args.yaml}'] if args.yaml else [])
    if args.json:
        print(json.dumps(summary))
    else:
        print(summary_text(summary) + '\n' + _uncertainty_line(summary, args.fov_tolerance))
        if args.yaml:
            print(f'wrote {args.yaml}')
        if args.report:
            print(f'wrote {args.report}')
    _print_warnings(warnings)
    return 0


def _add_uncertainty(summary, spec, solution, fov_tolerance):
    """Put the zero-shot camera's error bar (core/estimation/uncertainty.py) into ``summary``;
    the ill-conditioning warning, if any, as a list."""
    from .core.estimation.uncertainty import image_circle_radius, zero_shot_uncertainty  # scipy: only when asked
    uncertainty = zero_shot_uncertainty(spec, fov_tolerance, solution)
    summary['uncertainty_px'] = uncertainty.rms_px
    summary['uncertainty'] = uncertainty.reason
    # of uncertainty_px, the part from the lens shapes a spec of one FOV (or the circle alone) leaves open
    summary['uncertainty_lens_shape_px'] = uncertainty.lens_shape_px
    summary['uncertainty_over'] = 'image circle' if image_circle_radius(spec) is not None else 'image'
    return [uncertainty.warning] if uncertainty.warning else []


def _assumption_warnings(solution):
    """The solution's assumption (one FOV: the lens shape of real lenses of that FOV) as a warning."""
    return [solution.assumption] if solution.assumption else []


def _uncertainty_line(summary, fov_tolerance):
    value = summary['uncertainty_px']
    if value is None:
        return f"error bar - ({summary.get('uncertainty') or 'not determined'})"
    shapes = summary.get('uncertainty_lens_shape_px')
    shapes = '' if shapes is None else f' and the spread of real lens shapes of that FOV, {shapes:.3g} px of it'
    return (f"error bar {value:.2f} px (RMS over the {summary.get('uncertainty_over', 'image')} of the 1-sigma "
            f'pixel error, FOVs +- {fov_tolerance:g} deg{shapes})')


BATCH_COLUMNS = ('name', 'width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov')
BATCH_POSITIONAL = BATCH_COLUMNS[:6]
"""The columns of a CSV without a header row, in this order."""
YAML_NAME_BYTES = 90
"""Longest file name (UTF-8 bytes, before a hash suffix and '.yaml') derived from a row name."""
_HEADER_CELL = re.compile(r'[A-Za-z_][A-Za-z0-9_ -]*\Z')


def _is_number(text):
    return bool(_DECIMAL.match(text) or _NON_FINITE.match(text))


def _is_header(cells):
    """A first row is the header when none of its cells is a number and they read as names."""
    names = [c.strip() for c in cells if c.strip()]
    if not names or any(_is_number(c) for c in names) or not all(_HEADER_CELL.match(c) for c in names):
        return False
    return len(names) >= 2 or names[0].lower() in BATCH_COLUMNS


def _batch_columns(cells, where):
    columns = [c.strip().lower() for c in cells]
    allowed = f'allowed: {", ".join(BATCH_COLUMNS)}'
    for i, column in enumerate(columns, start=1):
        if not column:
            raise CliError(f'{where}: header column {i} is empty: {allowed}')
        if column not in BATCH_COLUMNS:
            close = difflib.get_close_matches(column, BATCH_COLUMNS, n=1)
            hint = f' (did you mean {close[0]}?)' if close else ''
            raise CliError(f'{where}: header column {cells[i - 1].strip()!r} is unknown{hint}: {allowed} '
                           '(a first row without numbers is read as the header)')
        if columns.index(column) != i - 1:
            raise CliError(f'{where}: header column {column!r} appears twice: {allowed}, each once')
    return columns


MAX_BATCH_BYTES = 16 << 20
"""Largest --batch file read (a camera a row: about 100,000 cameras)."""
_CONTROL = re.compile('[\x00-\x08\x0b-\x1f\x7f-\x9f\u2028\u2029]')
"""Characters refused in a CSV cell: control characters and line / paragraph separators (a quoted
cell may hold a newline or a tab)."""


def _csv_records(text):
    """[(line number, cells or csv.Error)] of CSV text: records end only at \\n or \\r\\n outside
    quotes (a quoted cell may span lines, as spreadsheets write it); blank and # lines skipped."""
    lines = text.split('\n')
    if lines and lines[-1] == '':
        lines.pop()
    lines = [line[:-1] if line.endswith('\r') else line for line in lines]
    records, i = [], 0
    while i < len(lines):
        start, chunk = i + 1, [lines[i]]
        i += 1
        if not chunk[0].strip() or chunk[0].lstrip().startswith('#'):
            continue
        while sum(part.count('"') for part in chunk) % 2 and i < len(lines):
            chunk.append(lines[i])
            i += 1
        try:
            cells = next(csv.reader(['\n'.join(chunk)], strict=True))
            bad = next((c for c in cells if _CONTROL.search(c)), None)
            if bad is not None:
                char = _CONTROL.search(bad).group()
                raise csv.Error(f'a cell holds the control character U+{ord(char):04X} (lines end only at '
                                '\\n or \\r\\n): allowed: printable text')
        except csv.Error as exc:
            where = f'line {start}' if len(chunk) == 1 else f'lines {start}-{start + len(chunk) - 1}'
            cells = csv.Error(f'{where}: {exc}')
        records.append((start, cells))
    return records


def _batch_rows(path):
    """(columns, [(row number, line number, cells or csv error)]) of a --batch file."""
    try:
        data = read_capped(path, MAX_BATCH_BYTES, 'a CSV file, one camera a row')
    except InputFileError as exc:
        raise CliError(str(exc)) from None
    try:
        text = data.decode('utf-8-sig')
    except UnicodeDecodeError as exc:
        raise CliError(f'cannot read {path}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset '
                       f'{exc.start}): allowed: a UTF-8 CSV file') from None
    rows = _csv_records(text)
    columns = list(BATCH_POSITIONAL)
    if rows and not isinstance(rows[0][1], Exception) and _is_header(rows[0][1]):
        columns = _batch_columns(rows[0][1], f'{path} line {rows[0][0]}')
        rows = rows[1:]
    if not rows:
        raise CliError(f'{path} has no camera rows: allowed: one camera a row, '
                       f'{",".join(BATCH_POSITIONAL)} (a header row, # comments and blank lines optional)')
    return columns, [(number, line, cells) for number, (line, cells) in enumerate(rows, start=1)]


def _batch_spec(row):
    def cell(key, convert, allowed):
        value = (row.get(key) or '').strip()
        if not value:
            return None
        try:
            return convert(value)
        except ValueError:
            raise SpecError(key, value, allowed) from None
    sides = {k: cell(k, _whole_number, 'a whole number of pixels') for k in ('width', 'height')}
    return CameraSpec(**sides, **{k: cell(k, _number, 'a number') for k in BATCH_COLUMNS[3:]})


def _yaml_file_name(name):
    """A file name for ``name``: letters, digits, '-', '_' and '.' kept, anything else (path
    separators included) '_', no leading '.', at most YAML_NAME_BYTES bytes (longer names are cut
    and get a hash of the whole name); None if nothing is left."""
    safe = ''.join(ch if ch.isalnum() or ch in '-_.' else '_' for ch in name).lstrip('.')
    if len(safe.encode('utf-8')) > YAML_NAME_BYTES:
        cut = safe.encode('utf-8')[:YAML_NAME_BYTES].decode('utf-8', 'ignore')
        safe = f"{cut}-{hashlib.sha1(name.encode('utf-8')).hexdigest()[:8]}"
    return f'{safe}.yaml' if safe.strip('_') else None


def _solve_batch(args):
    """One JSON object per camera row; a bad row reports an error object and the rest go on. The
    --yaml-dir files are written only when every row has been solved (else none, and a warning
    says so); a file that cannot be written is its row's error, and the records with 'yaml' are
    the files written."""
    failures = 0
    columns, rows = _batch_rows(args.batch)
    written = {}  # file name (case-folded) -> (row, name) of the row that writes it
    outputs = []  # (row, line, name, JSON record, its warnings, (calibration, path) or None)
    for number, line, cells in rows:
        name = f'camera_{number}'
        try:
            if isinstance(cells, Exception):
                raise CliError(f'not a CSV row: {cells}')
            if len(cells) > len(columns):
                raise CliError(f'{len(cells)} cells, but the {"header" if columns != list(BATCH_POSITIONAL) else "file"} '
                               f'has {len(columns)} columns: allowed: at most {len(columns)} cells '
                               f'({",".join(columns)})')
            row = dict(zip(columns, cells))
            name = (row.get('name') or '').strip() or name
            spec = _batch_spec(row)
            solution, calibration, fit = _solve(spec, args, _camera_name_of(name))
            record = {'name': name, 'camera_name': calibration.camera_name,
                      **solution_summary(solution, calibration, fit)}
            warnings = solution.warnings + _fit_warnings(solution, calibration, fit)
            warnings += _add_uncertainty(record, spec, solution, args.fov_tolerance)
            warnings += _assumption_warnings(solution)
            record['warning'] = warnings
            if args.yaml_dir is not None:
                file_name = _yaml_file_name(name) or f'camera_{number}.yaml'
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
                _save_calibration(*output)
            except CliError as exc:
                failures += 1
                record = {'name': name, 'row': number, 'line': line, 'error': ' '.join(str(exc).split())}
                warnings = []
        print(json.dumps(record), flush=True)
        _print_warnings(warnings, f'row {number} ({name}): ')
    if bad_rows and written:
        _print_warnings([f'{bad_rows} of {len(rows)} rows failed: no files written to {args.yaml_dir} (fix '
                         'the rows and run again)'])
    return 1 if failures else 0


IMAGE_EXTENSIONS = ('.png', '.jpg', '.jpeg', '.tif', '.tiff', '.bmp', '.webp', '.jp2', '.ppm', '.pgm',
                    '.pbm', '.pnm', '.pfm', '.sr', '.ras', '.hdr', '.pic', '.avif', '.gif', '.exr')
"""Extensions cv2.imwrite may support; which it does depends on the OpenCV build."""


def _can_write_image(path):
    ext = os.path.splitext(path)[1].lower()
    if not ext or (ext == '.exr' and not os.environ.get('OPENCV_IO_ENABLE_OPENEXR')):
        return False  # OpenCV 4 raises (and logs) for .exr unless the codec is enabled
    try:
        return bool(cv2.haveImageWriter(path))
    except cv2.error:
        return False


def _check_output_image(path):
    if not _can_write_image(path):
        supported = [e for e in IMAGE_EXTENSIONS if _can_write_image('x' + e)]
        raise CliError(f'-o {path}: OpenCV {cv2.__version__} cannot write '
                       f'{os.path.splitext(path)[1] or "a file without an extension"}: allowed: '
                       f'{", ".join(supported)}')
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise CliError(f'-o {path}: cannot write image: directory {directory} does not exist')
    if os.path.isdir(path):
        raise CliError(f'-o {path}: cannot write image: it is a directory')


def _check_png_output(path, option):
    """One error line, before any work, when ``path`` cannot take a PNG picture."""
    if os.path.isdir(path):
        raise CliError(f'{option} {path}: it is a directory: allowed: a file name ending in .png')
    ext = os.path.splitext(path)[1]
    if ext.lower() != '.png':
        raise CliError(f'{option} {path}: the picture is a PNG image: allowed: a file name ending in .png '
                       f'(not {ext or "a name without an extension"})')
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise CliError(f'{option} {path}: cannot write the picture: directory {directory} does not exist')


def _write_png(path, image, option, written=()):
    """``image`` written to ``path`` as a PNG, all or nothing (core/atomic_file.py); one error line
    naming the option, and the files already written, when it cannot be."""
    from .core.atomic_file import SaveError, write_atomically
    done = f' ({", ".join(written)} written)' if written else ''
    if os.path.splitext(path)[1].lower() != '.png':  # --debug-image: any format OpenCV writes
        try:
            if cv2.imwrite(path, image):
                return
        except cv2.error:
            pass
        raise CliError(f'{option} {path}: cannot write image{done}')
    ok, data = cv2.imencode('.png', image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise CliError(f'{option} {path}: cannot encode the picture{done}')
    try:
        write_atomically(path, data.tobytes())
    except SaveError as exc:
        raise CliError(f'{option} {exc}{done}') from None


def _write_report(args, data, written=()):
    """--report: the calibration report (core/report/calibration_report.py) of ``data``."""
    if data is None or not getattr(args, 'report', None):
        return
    from .core.report.calibration_report import render_report
    _write_png(args.report, render_report(data).image, '--report', written)


def _read_image(path, finite=False):
    """core/file_input.read_image: (image, sha1 of the file); every refusal one CliError naming
    the file (a regular file, at most MAX_IMAGE_PIXELS, decoded completely)."""
    try:
        return read_image(path, cv2.IMREAD_UNCHANGED, finite=finite)
    except InputFileError as exc:
        raise CliError(str(exc)) from None


def _load_calibration(path, option):
    """CameraCalibration.load, every failure one CliError naming the option and the file; what
    loading assumed (a missing distortion_model, say) is a warning line."""
    try:
        calibration = CameraCalibration.load(path)
        _print_warnings(calibration.load_warnings, f'{option} {path}: ')
        return calibration
    except CalibrationFileError as exc:
        message = str(exc)
    except (ArithmeticError, TypeError, KeyError, AttributeError, ValueError) as exc:
        message = f'not a usable calibration file: {type(exc).__name__}: {exc}'
    raise CliError(f'{option} {message}' if message.startswith(f'{path}:') else f'{option} {path}: {message}')


RECTIFY_SPEC_OPTIONS = SOLVE_SPEC_FIELDS + ('preset', 'model')


_ONE_FOV_MEANING = {'hfov': 'the angle across the image width, edge to edge through the centre',
                    'vfov': 'the angle across the image height, edge to edge through the centre',
                    'dfov': 'the angle across the image diagonal, corner to corner'}


def _spec_words(spec, solution):
    """How `rectify` read the spec: the FOVs given and, for one FOV (or the circle) alone, what it
    was taken to mean and what was assumed (the warning gives the details)."""
    given = dict(spec.given())
    circle = spec.circle_diameter is not None and spec.circle_fov is not None
    text = ', '.join(f'{k} {v:g}' for k, v in given.items()) + (' deg' if given else '')
    if circle:
        text += (', ' if given else '') + f'circle {spec.circle_diameter:g} px across {spec.circle_fov:g} deg'
    if len(given) == 1 and not circle and solution.assumption:
        (key, _), = given.items()
        text += f' alone (taken as {_ONE_FOV_MEANING[key]}; lens shape assumed from real lenses of that FOV)'
    elif not given and circle:
        text += ' alone (the pure equidistant law assumed across the circle)'
    return text


def _rectify_camera(args, width, height, about=None):
    """(camera model, P, R) for an image of width x height (R: the calibration file's
    rectification rotation, honoured as image_proc does; the identity for a spec). ``about``, a
    dict, gets 'model' and 'source': where the camera comes from, in words."""
    about = {} if about is None else about
    balance = 0.0 if args.balance is None else args.balance
    fov_scale = 1.0 if args.fov_scale is None else args.fov_scale
    if args.calibration is not None:
        given = _options_given(args, RECTIFY_SPEC_OPTIONS)
        if given:
            raise CliError(f'{given[0]} cannot be combined with --calibration: the calibration file '
                           'gives the camera')
        calibration = _load_calibration(args.calibration, '--calibration')
        cw, ch = calibration.width, calibration.height
        about.update(model=calibration.distortion_model, source=f'from {args.calibration}' + (
            f' (for {cw}x{ch}, scaled)' if (cw, ch) != (width, height) else ''))
        if (cw, ch) != (width, height):
            if width * ch != height * cw:
                raise CliError(f'the image {args.input} is {width}x{height} but --calibration '
                               f'{args.calibration} is for {cw}x{ch}: allowed: {cw}x{ch} or the same '
                               'aspect ratio (then scaled)')
            calibration = calibration.scaled(width, height)
        camera = calibration.camera()
        if args.balance is not None or args.fov_scale is not None:
            return camera, new_camera_matrix(camera, balance, fov_scale), calibration.R
        P = np.asarray(calibration.P, dtype=float)[:3, :3]
        if not abs(np.linalg.det(P)) > 0:
            raise CliError(f'--calibration {args.calibration}: projection_matrix {P.tolist()} cannot be '
                           'inverted: allowed: an invertible P (or choose one with --balance / --fov-scale)')
        return camera, P, calibration.R
    fields = {k: getattr(args, k) for k in SOLVE_SPEC_FIELDS}
    if not args.preset:
        fields['width'] = width if args.width is None else args.width
        fields['height'] = height if args.height is None else args.height
    spec = spec_with_preset(args.preset, **fields)
    if spec.width * height != spec.height * width:
        raise CliError(f'the image is {width}x{height} but the spec is {spec.width}x{spec.height}: '
                       'aspect ratios differ')
    solution = solve_zero_shot(spec, args.model or 'auto', fov_tolerance=args.fov_tolerance)
    _print_warnings(solution.warnings + _assumption_warnings(solution))
    about.update(model=solution.projection.name, source=f'zero-shot from {_spec_words(spec, solution)}' + (
        f' (for {spec.width}x{spec.height}, scaled)' if (spec.width, spec.height) != (width, height) else ''))
    camera = solution.camera if (spec.width, spec.height) == (width, height) \
        else solution.camera.scaled(width, height)
    return camera, new_camera_matrix(camera, balance, fov_scale), None


def _cmd_rectify(args):
    _check_output_image(args.output)
    image, _ = _read_image(args.input)
    height, width = image.shape[:2]
    about = {}
    camera, P, R = _rectify_camera(args, width, height, about)
    rectifier = Rectifier(camera, interpolation=args.interpolation, P=P, R=R)
    try:
        written = cv2.imwrite(args.output, rectifier.rectify(image))
    except cv2.error as exc:
        raise CliError(f'cannot write image {args.output}: OpenCV: {exc}') from None
    if not written:
        raise CliError(f'cannot write image {args.output}')
    print(f'wrote {args.output}: {width}x{height} pinhole image ({_focal_and_centre(P)}) from {args.input}; '
          f"camera: {about['model']}, {about['source']}, K {_focal_and_centre(camera.K)}")
    return 0


def _focal_and_centre(matrix):
    """'f F px, principal point (X, Y)' of a 3x3 camera matrix (fx and fy when they differ)."""
    fx, fy, cx, cy = matrix[0][0], matrix[1][1], matrix[0][2], matrix[1][2]
    focal = f'f {fx:.2f} px' if abs(fx - fy) <= 1e-9 * abs(fx) else f'fx {fx:.2f} px, fy {fy:.2f} px'
    return f'{focal}, principal point ({cx:.1f}, {cy:.1f})'


# -- refine: the spec plus straight lines in ordinary images ---------------------------------------

REFINE_KEYS = ('accepted', 'reason', 'images_used', 'lines_used', 'line_residual_px_before',
               'line_residual_px_after', 'coverage', 'principal_point_shift_px')


def _refine_spec(args, width, height):
    """The spec of `refine`: the images' size, the FOVs of the flags / --preset (whose size, if it
    has one, must be the images' or of their aspect ratio: a crop is another camera)."""
    if args.preset:
        preset_spec = spec_with_preset(args.preset)
        if preset_spec.width * height != preset_spec.height * width:
            raise CliError(f'the images are {width}x{height} but --preset {args.preset} is for '
                           f'{preset_spec.width}x{preset_spec.height}: allowed: the same aspect ratio')
    fields = {k: getattr(args, k) for k in ('hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov')}
    if not args.preset and all(v is None for v in fields.values()):
        raise CliError('refine needs the spec sheet: --hfov / --vfov / --dfov, --circle-diameter with '
                       '--circle-fov, or --preset NAME')
    return spec_with_preset(args.preset, width=width, height=height, **fields)


def _kannala_brandt_record(camera, spec, model, args, distortion_model='equidistant', D=None, fit_error=0.0,
                           root_found=True, rectified=new_camera_matrix):
    """`solve --json`'s record of a Kannala-Brandt camera at the spec's size (refined or calibrated)
    and its CameraCalibration; ``D`` / ``fit_error``: of the ROS model when it is not equidistant
    (an equidistant D is the camera's own, exact); ``rectified``: the function that makes P."""
    P = np.hstack([rectified(camera, args.balance, args.fov_scale), np.zeros((3, 1))])
    calibration = CameraCalibration(spec.width, spec.height, camera.K, distortion_model,
                                    camera.D if D is None else D, np.eye(3), P, args.camera_name)
    fovs = camera.fields_of_view()
    summary = {
        'width': spec.width, 'height': spec.height, 'spec': dict(spec.given()),
        'model': model, 'omega': None, 'f': float(camera.K[0, 0]),
        'cx': float(camera.cx), 'cy': float(camera.cy), 'K': calibration.K.tolist(),
        'distortion_model': distortion_model, 'D': calibration.D.tolist(), 'fit_error_px': fit_error,
        'P': calibration.P.tolist(),
        'hfov': fovs.get('hfov'), 'vfov': fovs.get('vfov'), 'dfov': fovs.get('dfov'),
        'root_found': root_found, 'dfov_residuals': {},
    }
    return summary, calibration


def _refined_summary(result, spec, solution, args):
    """`solve --json`'s record of the camera ``refine`` gives (the refined one, or zero-shot's)."""
    if not result.accepted:
        calibration, fit = CameraCalibration.from_solution(solution, 'equidistant', args.balance, args.fov_scale,
                                                           args.camera_name)
        summary = solution_summary(solution, calibration, fit)
        return summary, calibration
    summary, calibration = _kannala_brandt_record(result.camera, spec, 'refined (Kannala-Brandt)', args,
                                                  root_found=solution.root_found)
    return json_safe(summary), calibration


def _debug_image(images, names, result, solution, args):
    """The contact sheet of --debug-image (core/report/debug_sheet.py), written by the caller once
    everything has succeeded."""
    from .core.report.debug_sheet import render_debug_sheet
    return render_debug_sheet(images, names, result, solution.camera, args.balance, args.fov_scale).image


def _preset_circle_diameter(args):
    """The circle diameter of --preset, if it has one."""
    return spec_with_preset(args.preset).circle_diameter if args.preset else None


def _image_circle_line(circle) -> str:
    """The text output's line on the image circle measured in the images."""
    if circle is None:
        return 'circle    none seen in the images'
    used = {'measured': ' (used as the spec\'s circle diameter)', 'given': ''}.get(circle['diameter_used'], '')
    return (f"circle    diameter {circle['diameter']:.1f} px +- {circle['diameter_sigma_px']:.2g}{used}, centre "
            f"({circle['cx']:.1f}, {circle['cy']:.1f}) +- {circle['centre_sigma_px']:.2g} px, measured in "
            f"{circle['measured_from']} of {circle['images']} image{'s' if circle['images'] > 1 else ''}")


MIN_REFINE_IMAGE_SIDE = 32
"""Smaller images hold no line long enough to measure a lens by (and their camera would be refused
as implausible, without naming the image)."""


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # no such method, or a closed stream
        return False


class _ProgressLine:
    """Progress on a stream: one line rewritten in place (``\r``) on a terminal, a line per report
    elsewhere (a log file has no use for carriage returns). ``refine``, ``calibrate`` and
    ``evaluate`` report through it (``_progress_line``); any other output first ends the line
    (``_end_progress``)."""

    active = None
    """The line being rewritten in place, if any."""

    def __init__(self, stream, command):
        self.stream = stream
        self.prefix = f'zeroshot-calib: {command} '
        self.in_place = _is_terminal(stream)
        self.width = 0

    def __call__(self, text) -> None:
        text = self.prefix + text
        if self.in_place:
            self.stream.write('\r' + text.ljust(self.width))
            self.width = len(text)
            _ProgressLine.active = self
        else:
            self.stream.write(text + '\n')
        self.stream.flush()

    def close(self) -> None:
        if self.in_place and self.width:
            self.stream.write('\n')
            self.stream.flush()
            self.width = 0
        if _ProgressLine.active is self:
            _ProgressLine.active = None


def _end_progress() -> None:
    """End the progress line being rewritten in place, if any, so that what follows (a warning, the
    result) starts on a line of its own; the next report starts a new progress line."""
    if _ProgressLine.active is not None:
        _ProgressLine.active.close()


def _progress_line(args, command):
    """A _ProgressLine on stderr with --progress, or by default when stderr is a terminal and the
    output is not --json; None otherwise (silent)."""
    if args.progress or (not args.json and _is_terminal(sys.stderr)):
        return _ProgressLine(sys.stderr, command)
    return None


def _refine_progress_text(p) -> str:
    """``refine``'s progress report (core/estimation/refine.py) as the text of its progress line."""
    camera = p.camera
    estimate = f'f {camera.fx:.1f} px, principal point ({camera.cx:.1f}, {camera.cy:.1f})'
    if p.stage == 'detection':
        return (f'round {p.round}/{p.rounds}: {p.frames_done}/{p.frames} images, {p.lines} lines found; '
                f'looking with {estimate}')
    return (f'round {p.round}/{p.rounds}: fitted {p.lines} lines: {estimate} '
            f'({"accepted" if p.accepted else "not accepted"})')


def _cmd_refine(args):
    from .core.estimation.refine import circle_diameter_agrees, refine_from_images  # scipy: only when asked
    from .core.lines.image_region import combine_circles, find_image_region
    if args.debug_image:
        _check_output_image(args.debug_image)
    images, names, seen = [], [], {}
    for path in args.images:
        key = os.path.realpath(path)
        if key in seen:
            _print_warnings([f'{path} is given more than once: counted once'])
            continue
        image, digest = _read_image(path, finite=True)
        if digest in seen.values():
            first = next(p for p, d in seen.items() if d == digest)
            _print_warnings([f'{path} has the same content as {first}: counted once'])
            seen[key] = digest
            continue
        seen[key] = digest
        if min(image.shape[:2]) < MIN_REFINE_IMAGE_SIDE:
            raise CliError(f'{path} is {image.shape[1]}x{image.shape[0]}: allowed: images at least '
                           f'{MIN_REFINE_IMAGE_SIDE} px wide and high (lines to straighten need room)')
        images.append(image)
        names.append(path)
    sizes = sorted({(im.shape[1], im.shape[0]) for im in images})
    if len(sizes) != 1:
        listed = ', '.join(f'{w}x{h}' for w, h in sizes)
        raise CliError(f'the images have different sizes ({listed}): allowed: images of one camera, one size')
    images = [im if im.dtype == np.uint8 else cv2.convertScaleAbs(im, alpha=255.0 / max(1.0, float(im.max())))
              for im in images]
    (width, height), = sizes
    # the part of each image that shows the scene, and the image circle if one is seen
    regions = [find_image_region(im) for im in images]
    circle = combine_circles([r.circle for r in regions])
    measured_in = sum(r.circle is not None for r in regions)
    circle_warnings = []
    given_diameter = args.circle_diameter
    measure_diameter = args.circle_fov is not None and given_diameter is None and _preset_circle_diameter(args) is None
    if measure_diameter:
        if circle is None:
            raise CliError(f'--circle-fov {args.circle_fov:g} needs the image circle\'s diameter, and none was found in '
                           f'the image{"s" if len(images) > 1 else ""} (looked for a dark surround with a circular '
                           'boundary seen on opposite sides): give --circle-diameter PX')
        args.circle_diameter = round(circle.diameter, 2)
    spec = _refine_spec(args, width, height)
    if circle is not None and spec.circle_diameter is not None and given_diameter is not None \
            and not circle_diameter_agrees(spec.circle_diameter, circle):
        circle_warnings.append(
            f'--circle-diameter {spec.circle_diameter:g} px differs from the image circle measured in the images: '
            f'{circle.diameter:.1f} +- {2 * circle.radius_sigma_px:.1f} px ({measured_in} of {len(images)} images); '
            'the given diameter is used, the measured centre only as the principal point: check --circle-diameter, '
            'or leave it out to use the measured diameter')
    solution = solve_zero_shot(spec, 'auto', fov_tolerance=args.fov_tolerance)
    progress = _progress_line(args, 'refine')
    # the images are detected in parallel threads (the same curves, in the same order)
    try:
        result = refine_from_images(spec, images, args.fov_tolerance, workers=os.cpu_count() or 1, regions=regions,
                                    progress=None if progress is None else
                                    (lambda report: progress(_refine_progress_text(report))))
    finally:
        if progress is not None:
            progress.close()
    summary, calibration = _refined_summary(result, spec, solution, args)
    summary['image_circle'] = None if circle is None else {
        'cx': circle.cx, 'cy': circle.cy, 'diameter': circle.diameter,
        'centre_sigma_px': circle.centre_sigma_px, 'diameter_sigma_px': 2 * circle.radius_sigma_px,
        'measured_from': measured_in, 'images': len(images),
        'diameter_used': 'measured' if measure_diameter else ('given' if spec.circle_diameter is not None else None)}
    warnings = list(solution.warnings) + circle_warnings  # the spec's FOVs against the zero-shot camera
    warnings += [] if result.accepted else _fit_warnings(solution, calibration, DISTORTION_FITS['equidistant'](solution.camera))
    summary['uncertainty_px'] = result.uncertainty_px if result.accepted else result.zero_shot_uncertainty_px
    summary['refinement'] = json_safe({k: getattr(result, k) for k in REFINE_KEYS})
    summary['refinement']['curves_static'] = len(result.static_curves)
    if getattr(result, 'zero_shot_uncertainty', None) is not None and result.zero_shot_uncertainty.warning \
            and not result.accepted:
        warnings.append(result.zero_shot_uncertainty.warning)
    summary['warning'] = warnings
    canvas = _debug_image(images, names, result, solution, args) if args.debug_image else None
    report = None
    if args.report:
        from .core.report.calibration_report import ReportData
        report = ReportData('refine', result.camera, summary['model'], result.accepted, result.reason, spec,
                            args.fov_tolerance, result.uncertainty, summary['uncertainty_px'],
                            getattr(result.uncertainty, 'reason', ''), result.zero_shot_camera, images[0],
                            os.path.basename(names[0]), args.balance, args.fov_scale, warnings=warnings,
                            camera_name=args.camera_name)
    refused = None if result.accepted else _not_adopted('not refined', result.reason, args.yaml)
    if args.yaml:  # written only now: every step has succeeded
        _save_calibration(calibration, args.yaml, [refused[0]] if refused else ())
    written = [f'--yaml {args.yaml}'] if args.yaml else []
    if canvas is not None:
        _write_png(args.debug_image, canvas, '--debug-image', written)
        written.append(f'--debug-image {args.debug_image}')
    _write_report(args, report, written)
    if args.json:
        print(json.dumps(summary))
    else:
        print(summary_text(summary) + '\n' + _uncertainty_line(summary, args.fov_tolerance))
        print(_image_circle_line(summary['image_circle']))
        if result.static_curves:
            print(f'left out  {len(result.static_curves)} curves at the same pixels in the images while the scene '
                  "moved (the vehicle's or robot's own body, lens dirt): not the scene's lines")
        print(f"refined   {'yes' if result.accepted else 'no'}: {result.reason}")
        if args.yaml:
            print(f'wrote {args.yaml}')
        if args.report:
            print(f'wrote {args.report}')
    _print_warnings(warnings)
    if refused:
        print(refused[1], file=sys.stderr, flush=True)
        return EXIT_NOT_ADOPTED
    return 0


# -- calibrate / evaluate: chessboard calibration and the paper's evaluation protocol --------------


def _add_corner_arguments(parser):
    parser.add_argument('images', nargs='*', help=f'chessboard images: files or glob patterns (at most {IMAGE_BUDGET} '
                        'each)')
    parser.add_argument('--corners', metavar='FILE',
                        help='a corners file (JSON, see docs/calibration.md) instead of images')
    parser.add_argument('--board', default='8x6',
                        help='inner corners COLSxROWS, as OpenCV patternSize (default 8x6)')
    parser.add_argument('--square', type=_number, default=0.108, help='square side in metres (default 0.108)')
    parser.add_argument('--skip-missing', action='store_true',
                        help='leave out (and list on stderr) images whose board is not found, '
                             'instead of failing')
    parser.add_argument('--save-corners', metavar='FILE', help='write the detected corners to FILE')
    parser.add_argument('--hfov', type=_number, help='spec-sheet horizontal field of view (deg)')
    parser.add_argument('--vfov', type=_number, help='spec-sheet vertical field of view (deg)')
    parser.add_argument('--dfov', type=_number, help='spec-sheet diagonal field of view (deg)')


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


def _corner_set(args, single=None, progress=None):
    """The CornerSet of the images / --corners file; writes --save-corners. ``progress``: a
    _ProgressLine told of each image searched."""
    if args.corners and args.images:
        raise CliError('give chessboard images or --corners FILE, not both')
    if not square_ok(args.square):
        raise CliError(f'--square {args.square:g} is invalid: allowed: {SQUARE_ALLOWED}, the side of one '
                       'board square')
    if args.corners:
        corners = CornerSet.load(args.corners)
    else:
        paths = _image_paths(args.images) or ([single] if single else [])
        if not paths:
            raise CliError('no input: give chessboard images or --corners FILE')
        corners = detect_corners(paths, parse_board(args.board, args.square), args.skip_missing, progress)
        if corners.missing:
            _end_progress()
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


def _calibrate_report(args, corners, used_views, camera, summary, **fields):
    """The ReportData of `calibrate` (None without --report): the board's views under ``camera``,
    the first used image for the preview when it can be read (not from a --corners file)."""
    if not args.report:
        return None
    from .core.report.calibration_report import ReportData, board_views
    image, name = None, ''
    path = corners.names[used_views[0]] if len(used_views) else None
    if path is not None and not args.corners and os.path.isfile(path):
        try:
            image, _ = _read_image(path)
            name = os.path.basename(path)
        except CliError:
            image = None
    if image is not None and (image.shape[1], image.shape[0]) != (camera.width, camera.height):
        image, name = None, ''
    return ReportData('calibrate', camera, summary['model'], image=image, image_name=name, balance=args.balance,
                      fov_scale=args.fov_scale, board=board_views(corners, camera, used_views),
                      warnings=summary['warning'], camera_name=args.camera_name,
                      fov_tolerance_deg=args.fov_tolerance, **fields)


def _calibrated_P(calibration, camera, args):
    """``calibration`` with P centred on the calibrated principal point, as ROS camera_calibration
    writes it for a fisheye (core/ros_formats/rectify.principal_point_camera_matrix)."""
    P = np.hstack([principal_point_camera_matrix(camera, args.balance, args.fov_scale), np.zeros((3, 1))])
    return dataclasses.replace(calibration, P=P)


def _with_progress(args, label, run):
    """``run(args, progress)`` with the verb's progress line (None where it is not shown), the line
    ended whatever happens."""
    progress = _progress_line(args, label)
    try:
        return run(args, progress)
    finally:
        if progress is not None:
            progress.close()


def _cmd_calibrate(args):
    return _with_progress(args, 'calibrate:', _calibrate)


def _calibrate(args, progress):
    corners = _corner_set(args, args.single, progress)
    views = None
    if args.single:
        if os.path.basename(args.single) in {os.path.basename(p) for p in corners.missing}:
            raise CliError(f'board {corners.board.size} not found in {args.single}')
        views = [corners.index(args.single)]
    spec = _fov_spec(args, corners)
    spec_warnings = _spec_warnings(spec, args.fov_tolerance)
    if spec is not None and args.spec_as == 'evidence':
        if args.principal_point != 'auto':
            raise CliError(f'--principal-point {args.principal_point} is for --spec-as start (FC_eq.d.): the '
                           'spec-as-evidence fit always frees the principal point under its prior')
        return _calibrate_with_spec(args, corners, views, spec, spec_warnings, progress)
    principal_point = {'auto': None, 'fixed': False, 'free': True}[args.principal_point]
    if progress is not None:
        progress(f'fitting FC_eq.d. to {len(corners) if views is None else len(views)} image(s)')
    result = calibrate(corners, 'fc+zs' if spec is not None else 'fc', views, spec, principal_point)
    _end_progress()
    if not result.ok:
        raise CliError(f'calibration failed: {result.error}')
    solution = as_solution(result, spec)
    calibration, fit = CameraCalibration.from_solution(solution, args.distortion_model, args.balance,
                                                       args.fov_scale, args.camera_name)
    calibration = _calibrated_P(calibration, solution.camera, args)
    if args.distortion_model == 'plumb_bob':
        _check_plumb_bob(solution.camera, fit.max_error_px, 'the calibrated camera')
    summary = solution_summary(solution, calibration, fit)
    summary['warning'] = spec_warnings + _fit_warnings(solution, calibration, fit)
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
        _save_calibration(calibration, args.yaml)
    _write_report(args, report, [f'--yaml {args.yaml}'] if args.yaml else [])
    _print_warnings(summary['warning'])
    if args.json:
        print(json.dumps(json_safe(summary)))
        return 0
    lines = summary_text(summary).splitlines()
    if spec is None:
        lines[0] = f"camera    {summary['width']} x {summary['height']} px, no spec (default start)"
    lines.append(f"method    {summary['method']} (start: {result.init}), principal point {summary['principal_point']}")
    _print_calibrate_text(lines + _board_lines(summary, corners, used, result.rms_px), summary, args)
    return 0


class _RadialView(RadialCamera):
    """A fx = fy Kannala-Brandt camera seen as a RadialCamera, for the ROS plumb_bob fit."""

    def __init__(self, camera):
        super().__init__(camera.fx, camera.cx, camera.cy, camera.width, camera.height)
        self.kb = camera

    def theta_d(self, theta):
        return self.kb.theta_d(theta)

    def theta_from_theta_d(self, theta_d):
        return self.kb.theta_from_theta_d(theta_d)


def _edge_angle_deg(camera) -> float:
    """Largest off-axis angle (degrees) of the rays of the image border (nan: a border pixel with
    no ray)."""
    w, h = camera.width, camera.height
    t = np.linspace(0.0, 1.0, 33)
    border = np.concatenate([np.c_[t * w, 0 * t], np.c_[t * w, 0 * t + h], np.c_[0 * t, t * h], np.c_[0 * t + w, t * h]])
    rays = camera.unproject(border)
    with np.errstate(invalid='ignore'):
        angles = np.degrees(np.arctan2(np.linalg.norm(rays[:, :2], axis=-1), rays[:, 2]))
    return float(np.max(angles)) if np.all(np.isfinite(angles)) else math.nan


def _check_plumb_bob(camera, fit_error, what):
    """CliError when --distortion-model plumb_bob cannot represent ``camera``: plumb_bob projects
    through a pinhole, so a lens that sees 90 degrees or more off-axis inside the image (a FOV of
    180 or more), or a fit that gives no finite error, would be written as a wrong D."""
    angle = _edge_angle_deg(camera)
    if math.isfinite(angle) and angle < 90.0 and math.isfinite(fit_error):
        return
    seen = (f'sees {angle:.1f} degrees off-axis at the image edge' if math.isfinite(angle)
            else 'has image pixels without a ray')
    raise CliError(f'--distortion-model plumb_bob cannot represent {what}: it {seen}, and plumb_bob projects '
                   'through a pinhole (allowed: lenses below 90 degrees off-axis, a FOV below 180): use '
                   '--distortion-model equidistant')


def _spec_warnings(spec, fov_tolerance):
    """The warnings of the zero-shot camera solved from ``spec`` (given FOVs it misses by more
    than ``fov_tolerance``); [] without a spec, or when none can be solved (the calibration then
    says why)."""
    if spec is None:
        return []
    try:
        return solve_zero_shot(spec, 'auto', fov_tolerance=fov_tolerance).warnings
    except (SpecError, NoConvergence):
        return []


def _calibrate_with_spec(args, corners, views, spec, spec_warnings=(), progress=None):
    """`calibrate` with the spec as evidence: the MAP over corners, FOVs and priors
    (core/estimation/board_fit.py); the camera is Kannala-Brandt (ROS equidistant, exact). Exit
    status EXIT_NOT_ADOPTED when the fit is not adopted (the zero-shot camera is written)."""
    from .core.estimation.board_fit import METHOD_LABEL, fit_board  # scipy.optimize: only when asked
    if not (args.fov_tolerance > 0 and math.isfinite(args.fov_tolerance)):
        raise CliError(f'--fov-tolerance {args.fov_tolerance:g} is invalid: allowed: degrees, greater than 0')
    fit = fit_board(corners, spec, views, fov_tolerance_deg=args.fov_tolerance, progress=progress)
    _end_progress()
    camera = fit.camera
    if args.distortion_model == 'equidistant':
        D, fit_error = np.asarray(camera.D, float), 0.0  # a Kannala-Brandt camera: its D is exact
        fit_warnings = []
    else:
        distortion = DISTORTION_FITS[args.distortion_model](_RadialView(camera))
        D, fit_error = distortion.D, distortion.max_error_px
        _check_plumb_bob(camera, fit_error, 'the calibrated camera' if fit.accepted else 'the camera written')
        fit_warnings = [] if fit_error <= FIT_WARNING_PX else [
            f'the ROS {args.distortion_model} fit of the calibrated camera is off by up to {fit_error:.3g} px in '
            f'the image (fit error; warning above {FIT_WARNING_PX:g} px), so tools that rectify with its D '
            'coefficients are that far off: use --distortion-model equidistant (exact)']
    # the gate may keep the zero-shot camera (fit_board, step 4): then that is what is written,
    # and the record says so where a user looks first (model, method), not only in the notes
    model = 'calibrated (Kannala-Brandt)' if fit.accepted else 'zero-shot (Kannala-Brandt fit; the board fit not adopted)'
    summary, calibration = _kannala_brandt_record(camera, spec, model, args, args.distortion_model, D, fit_error,
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
    refused = None if fit.accepted else _not_adopted('board fit not adopted', fit.reason.split(': ', 1)[-1],
                                                     args.yaml)
    if args.yaml:
        _save_calibration(calibration, args.yaml, [refused[0]] if refused else ())
    _write_report(args, report, [f'--yaml {args.yaml}'] if args.yaml else [])
    _print_warnings(summary['warning'])
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
    lines.append(_uncertainty_line(summary, args.fov_tolerance))
    lines.append(f"spec      {given} deg (given -> {'fitted' if fit.accepted else 'the board fit'}): "
                 + ('agrees' if fit.spec_agrees else 'DISAGREES with the corners (see the warning)'))
    _print_calibrate_text(lines, summary, args)
    return status


def _ray_reach(camera, edge):
    """Distance (px) from the principal point towards the pixel ``edge`` up to which the camera
    still gives rays (bisection on where unproject turns NaN)."""
    centre = np.array([camera.cx, camera.cy])
    direction = np.asarray(edge, dtype=float) - centre
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if np.all(np.isfinite(camera.unproject(centre + mid * direction))):
            lo = mid
        else:
            hi = mid
    return lo * float(np.hypot(*direction))


def _check_fovs_derived(camera, fovs, source):
    """CliError when an edge pixel has no ray: the lens curve turns back before the image edge."""
    w, h, cx, cy = camera.width, camera.height, camera.cx, camera.cy
    edges = {'hfov': (((0, cy), 'left'), ((w, cy), 'right')), 'vfov': (((cx, 0), 'top'), ((cx, h), 'bottom'))}
    for key, pair in edges.items():
        if math.isfinite(fovs[key]):
            continue
        for edge, side in pair:
            if not np.all(np.isfinite(camera.unproject(np.asarray(edge, dtype=float)))):
                reach = _ray_reach(camera, edge)
                distance = math.hypot(edge[0] - cx, edge[1] - cy)
                raise CliError(f"{source}: the calibration's distortion turns back at {reach:.0f} px from the "
                               f'principal point, before the image edge ({side}, {distance:.0f} px away), so '
                               f'it gives no {key}: allowed: a calibration whose distortion rises up to the image '
                               'edges (or give --hfov / --vfov instead of --spec-from)')
        raise CliError(f'{source}: {key} = {fovs[key]} cannot be derived: allowed: a calibration with rays at '
                       'the image edges')


def _evaluation_spec(args, corners):
    """(spec, spec_source, reference camera, reference_source) from the FOV flags or --spec-from."""
    if not args.spec_from:
        if args.spec_from_model:
            raise CliError('--spec-from-model needs --spec-from FILE')
        return _fov_spec(args, corners), 'spec sheet (command line)', None, ''
    if args.hfov is not None or args.vfov is not None or args.dfov is not None:
        raise CliError('give --spec-from FILE or --hfov / --vfov / --dfov, not both')
    source = _load_calibration(args.spec_from, '--spec-from')
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


def _cmd_evaluate(args):
    return _with_progress(args, 'evaluate:', _evaluate)


def _evaluate(args, progress):
    corners = _corner_set(args, progress=progress)
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
    _end_progress()
    if args.json:
        print(json.dumps(json_safe(evaluation_to_dict(result))))
    else:
        print(format_tables(result))
    return 0


def _add_fov_tolerance_argument(parser):
    parser.add_argument('--fov-tolerance', type=_number, default=FOV_TOLERANCE_DEG, metavar='DEG',
                        help='how far the spec-sheet FOVs may be off (1 sigma, degrees; default '
                             f'{FOV_TOLERANCE_DEG:g}): sets the reported uncertainty, the warning when '
                             'the solved camera misses a given FOV by more, and, for refine, how much '
                             'the lines may move the FOVs')


def _add_circle_arguments(parser, refine=False):
    parser.add_argument('--circle-diameter', type=_number, metavar='PX',
                        help='circular fisheye: image-circle diameter (px), with --circle-fov'
                        + ('; refine measures it in the images when it is left out' if refine else ''))
    parser.add_argument('--circle-fov', type=_number, metavar='DEG',
                        help='circular fisheye: field of view across the image circle (deg)')


REPORT_HELP = ("write a picture of the calibration (PNG): the lens curve against the spec's FOVs, the 1-sigma "
               'error over the image, a rectified preview{extra}, and the verdict (docs/report.md)')


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog='zeroshot-calib',
        description='Zero-shot calibration of wide-angle and fisheye cameras from resolution and '
                    'spec-sheet field of view (J.-Y. Lee, CVPR 2021).', epilog=EXIT_STATUSES)
    parser.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    sub = parser.add_subparsers(dest='command', required=True, metavar='command',
                                help='solve, presets, rectify, refine, calibrate or evaluate')

    solve = sub.add_parser('solve', help='calibrate from a spec sheet')
    _add_spec_arguments(solve, size_required=False)
    _add_output_arguments(solve)
    solve.add_argument('--method', default='bracketed', choices=('bracketed', 'newton'),
                       help="root finder: bracketed (exact, default) or the paper's damped Newton")
    solve.add_argument('--camera-name', help='camera_name in the YAML file (default: camera)')
    _add_fov_tolerance_argument(solve)
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
    _add_circle_arguments(solve)
    solve.set_defaults(run=_cmd_solve)

    presets = sub.add_parser('presets', help='list the camera presets (published spec sheets)')
    presets.add_argument('--json', action='store_true', help='print one JSON array')
    presets.set_defaults(run=_cmd_presets)

    rectify = sub.add_parser('rectify', help='rectify an image file')
    rectify.add_argument('input', help=f'input image (at most {IMAGE_BUDGET})')
    rectify.add_argument('-o', '--output', required=True, help='output image')
    _add_spec_arguments(rectify, size_required=False)
    _add_output_arguments(rectify)
    _add_circle_arguments(rectify)
    _add_fov_tolerance_argument(rectify)
    rectify.add_argument('--preset', metavar='NAME',
                         help='the camera of a published spec (`zeroshot-calib presets`); flags override '
                              'its fields; an image of another size with the same aspect ratio is scaled')
    rectify.add_argument('--calibration', metavar='FILE',
                         help='the camera of a calibration file (camera_calibration_parsers YAML or .ini) '
                              'instead of a spec; its P unless --balance / --fov-scale are given; an image '
                              'of another size with the same aspect ratio is scaled')
    rectify.add_argument('--interpolation', type=_integer, default=1, choices=sorted(INTERPOLATIONS),
                         help='0 nearest, 1 linear, 2 cubic, 4 lanczos4 (default 1)')
    rectify.set_defaults(run=_cmd_rectify, model=None, balance=None, fov_scale=None)
    refine = sub.add_parser('refine', help='the spec sheet plus straight lines in ordinary images of the camera',
                            epilog=EXIT_STATUSES)
    refine.add_argument('images', nargs='+', help='images of the camera (one size): rooms, streets, corridors; '
                        f'at most {IMAGE_BUDGET} each; an image given twice (same file or same content) counts once')
    refine.add_argument('--hfov', type=_number, help='horizontal field of view (deg)')
    refine.add_argument('--vfov', type=_number, help='vertical field of view (deg)')
    refine.add_argument('--dfov', type=_number, help='diagonal field of view (deg)')
    refine.add_argument('--preset', metavar='NAME', help='the FOVs of a published spec (`zeroshot-calib presets`)')
    _add_circle_arguments(refine, refine=True)
    _add_fov_tolerance_argument(refine)
    refine.add_argument('--balance', type=_number, default=0.0,
                        help='rectified camera: 0 crops to valid pixels, 1 keeps every edge (default 0)')
    refine.add_argument('--fov-scale', type=_number, default=1.0,
                        help='rectified camera: divides its focal length (default 1)')
    refine.add_argument('--camera-name', default='camera', help='camera_name in the YAML file')
    refine.add_argument('--json', action='store_true', help='print one JSON object')
    refine.add_argument('--yaml', metavar='FILE', help='write a camera_info_manager calibration file')
    refine.add_argument('--debug-image', metavar='OUT.png',
                        help='write a contact sheet of every image with its curves: used (green), rejected (red), '
                             'left out for staying put (orange), with the verdict, and the first image rectified '
                             'before (zero-shot) and after')
    refine.add_argument('--report', metavar='OUT.png', help=REPORT_HELP.format(extra=' of the first image'))
    refine.add_argument('--progress', action='store_true',
                        help='report progress on stderr (default: when stderr is a terminal, without --json)')
    refine.set_defaults(run=_cmd_refine)

    calib = sub.add_parser('calibrate', help='calibrate from chessboard images or a corners file (with a spec: '
                                             'MAP over corners and the spec FOVs; without: FC_eq.d.)',
                           description='Checkerboard calibration. Without a spec: FC_eq.d. (the paper\'s model) '
                                       'from the default start. With --hfov / --vfov / --dfov: by default the spec '
                                       'is EVIDENCE (--spec-as evidence): one MAP fit of a Kannala-Brandt camera '
                                       'over the corners, the spec FOVs (+- --fov-tolerance) and stated priors, '
                                       'reporting uncertainty_px; --spec-as start is the earlier behaviour, '
                                       'FC_eq.d. started from the zero-shot camera (FC_eq.d.+ZS), the spec '
                                       'forgotten after the start.', epilog=EXIT_STATUSES)
    _add_corner_arguments(calib)
    calib.add_argument('--spec-as', default='evidence', choices=('evidence', 'start'),
                       help='with a spec: evidence (default): MAP over corners + spec FOVs + priors, '
                            'Kannala-Brandt camera with uncertainty_px; start: FC_eq.d. from the zero-shot '
                            'camera (FC_eq.d.+ZS), the spec used only as the start')
    calib.add_argument('--fov-tolerance', type=_number, default=FOV_TOLERANCE_DEG, metavar='DEG',
                       help='how far the spec FOVs may be off (1 sigma, degrees; default '
                            f'{FOV_TOLERANCE_DEG:g}): with --spec-as evidence, their weight in the fit; '
                            'with a spec, the warning when the zero-shot camera misses a given FOV by more')
    calib.add_argument('--single', metavar='IMAGE',
                       help='single-shot: calibrate on this image only (one of the inputs, a name in '
                            '--corners, or an image file on its own)')
    calib.add_argument('--principal-point', default='auto', choices=('auto', 'fixed', 'free'),
                       help='--spec-as start or no spec: fixed at the image centre or free; auto: free from 3 '
                            'images on (default); with the spec as evidence it is free under its prior')
    _add_output_arguments(calib)
    calib.add_argument('--camera-name', default='camera', help='camera_name in the YAML file')
    calib.add_argument('--json', action='store_true', help='print one JSON object')
    calib.add_argument('--yaml', metavar='FILE', help='write a camera_info_manager calibration file')
    calib.add_argument('--report', metavar='OUT.png',
                       help=REPORT_HELP.format(extra=', the board coverage and the reprojection RMS of each image'))
    calib.add_argument('--progress', action='store_true',
                       help='report progress on stderr (default: when stderr is a terminal, without --json)')
    calib.set_defaults(run=_cmd_calibrate)

    ev = sub.add_parser('evaluate', help="the paper's evaluation (Tables 3 and 4 layouts) on chessboard "
                                         'images or a corners file')
    _add_corner_arguments(ev)
    ev.add_argument('--spec-from', metavar='CALIB.yaml',
                    help='no spec sheet: derive hfov / vfov from this calibration file (also shown '
                         'as the reference camera)')
    ev.add_argument('--spec-from-model', choices=('equidistant', 'plumb_bob'),
                    help="read --spec-from's coefficients as this model (default: its distortion_model)")
    ev.add_argument('--shots', type=_integer, default=1,
                    help='images per calibration in Table 4 (1: single-shot, default; 0: no Table 4)')
    ev.add_argument('--runs', type=_integer, help='only the first N single-shot runs (quicker, partial)')
    ev.add_argument('--name', help='camera name in the tables (default: the image folder / file name)')
    ev.add_argument('--json', action='store_true', help='print one JSON object')
    ev.add_argument('--progress', action='store_true',
                    help='report progress on stderr (default: when stderr is a terminal, without --json)')
    ev.set_defaults(run=_cmd_evaluate)
    return parser


def _check_options(args):
    """Every option whose range is known before any computation, so that a typo in the last option
    does not cost a whole fit first."""
    for name, low, low_included, high in (('balance', 0.0, True, 1.0), ('fov_scale', 0.0, False, math.inf),
                                          ('fov_tolerance', 0.0, False, math.inf)):
        value = getattr(args, name, None)
        if value is None:
            continue
        if not (math.isfinite(value) and (low <= value if low_included else low < value) and value <= high):
            allowed = '0 to 1' if name == 'balance' else 'greater than 0 (finite)'
            raise CliError(f'--{name.replace("_", "-")}: {name} = {value!r} is invalid: allowed: {allowed}')
    if getattr(args, 'report', None) is not None:
        _check_png_output(args.report, '--report')
    path = getattr(args, 'yaml', None)
    if path is not None:
        ext = os.path.splitext(path)[1]
        if ext not in FORMATS:
            raise CliError(f'--yaml {path}: unrecognized format {ext or "(no extension)"}: allowed: a file '
                           'name ending in .yaml, .yml or .ini (camera_calibration_parsers)')
        model = getattr(args, 'distortion_model', 'equidistant')
        if FORMATS[ext] == 'ini' and model != 'plumb_bob':
            raise CliError(f'--yaml {path}: the INI format holds plumb_bob only, not {model}: allowed: '
                           '.yaml / .yml, or .ini with --distortion-model plumb_bob')
        if os.path.isdir(path):
            raise CliError(f'--yaml {path}: it is a directory: allowed: a file name')


def _one_line(exc) -> str:
    return ' '.join(str(exc).split()) or type(exc).__name__


def _complete(parser):
    """Tab completion with argcomplete (as ros2cli has it), only when it is installed and the shell
    asks for completions (argcomplete's shell hook sets _ARGCOMPLETE); then it prints them and
    exits. Nothing is imported otherwise; pip does not install argcomplete (package.xml lists it
    for rosdep, as ros2cli does). Enable it in bash with
    eval "$(register-python-argcomplete zeroshot-calib)"."""
    if '_ARGCOMPLETE' not in os.environ:
        return
    try:
        import argcomplete
    except ImportError:
        return
    argcomplete.autocomplete(parser)


def main(argv=None) -> int:
    parser = build_parser()
    _complete(parser)
    args = parser.parse_args(argv)
    if hasattr(cv2, 'setLogLevel'):
        cv2.setLogLevel(1)  # fatal only: OpenCV's own warnings would be extra stderr lines; we report
    try:
        _check_options(args)
        return args.run(args)
    except BrokenPipeError:  # output piped into `head`: not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (CliError, SpecError, CalibrationFileError, NoConvergence, ValueError, OSError, cv2.error) as exc:
        print(f'zeroshot-calib: error: {_one_line(exc)}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # a bug: still one line, and not status 2 (which means bad input)
        print(f'zeroshot-calib: internal error: {type(exc).__name__}: {_one_line(exc)} (please report it '
              'with the command line)', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
