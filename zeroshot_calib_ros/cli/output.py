"""What the verbs of ``zeroshot-calib`` share on the way out: warning lines, the text of the error
bar, the record of a Kannala-Brandt camera, writing calibration files and PNG pictures (checked
before any work), reading the input images and calibration files with one-line errors, and the
progress line on stderr."""
from __future__ import annotations

import math
import os
import shutil
import sys

import cv2
import numpy as np

from ..core.estimation.uncertainty import error_bar_text
from ..core.file_input import InputFileError, read_image
from ..core.lens.fitting import DISTORTION_FITS, FIT_WARNING_PX
from ..core.ros_formats.calibration_file import CalibrationFileError, CameraCalibration, spec_record, stand_in_note
from ..core.ros_formats.rectify import new_camera_matrix
from .arguments import EXIT_NOT_ADOPTED, CliError


def fit_warnings(solution, calibration, fit):
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


def print_warnings(warnings, where=''):
    if warnings:
        end_progress()
    for warning in warnings:
        print(f'zeroshot-calib: warning: {where}{warning}', file=sys.stderr, flush=True)


def not_adopted(what, reason, yaml_path):
    """(file comment, stderr line) of a refine / calibrate whose result was not adopted (``what``:
    'not refined', 'board fit not adopted'): the camera printed and written is zero-shot's."""
    reason = ' '.join(str(reason).split())
    comment = f'{what}: {reason}; this is the zero-shot camera from the spec'
    held = f'{yaml_path} holds' if yaml_path else 'the camera printed is'
    line = (f'zeroshot-calib: {what}: {reason}; {held} the zero-shot camera from the spec '
            f'(exit status {EXIT_NOT_ADOPTED})')
    return comment, line


def save_calibration(calibration, path, comments=()):
    """Write ``calibration`` to ``path`` with ``comments`` (and what a stand-in D coefficient
    means) as # comment lines, which camera_calibration_parsers skips."""
    note = stand_in_note(calibration.distortion_model, calibration.D)
    comments = list(comments) + ([f'distortion_coefficients: {note}'] if note else [])
    try:
        calibration.save(path, comments)
    except OSError as exc:
        raise CliError(f'cannot write {path}: {exc.strerror or exc}') from None


def assumption_warnings(solution):
    """The solution's assumption (one FOV: the lens shape of real lenses of that FOV) as a warning."""
    return [solution.assumption] if solution.assumption else []


def uncertainty_line(summary, fov_tolerance):
    value = summary['uncertainty_px']
    if value is None:
        return f"error bar - ({summary.get('uncertainty') or 'not determined'})"
    return error_bar_text(value, fov_tolerance, summary.get('uncertainty_over', 'image'),
                          summary.get('uncertainty_lens_shape_px'))


def error_bar_keys(uncertainty, over_circle: bool) -> dict:
    """`--json`'s keys on how an error bar (``core.estimation.uncertainty.Uncertainty``) was made,
    its lens-shape part, and what it is over: the same keys for every verb that states one."""
    return {'uncertainty': uncertainty.reason, 'uncertainty_lens_shape_px': uncertainty.lens_shape_px,
            'uncertainty_over': 'image circle' if over_circle else 'image'}


def kannala_brandt_record(camera, spec, model, args, distortion_model='equidistant', D=None, fit_error=0.0,
                           root_found=True, rectified=new_camera_matrix):
    """`solve --json`'s record of a Kannala-Brandt camera at the spec's size (refined or calibrated)
    and its CameraCalibration; ``D`` / ``fit_error``: of the ROS model when it is not equidistant
    (an equidistant D is the camera's own, exact); ``rectified``: the function that makes P."""
    P = np.hstack([rectified(camera, args.balance, args.fov_scale), np.zeros((3, 1))])
    calibration = CameraCalibration(spec.width, spec.height, camera.K, distortion_model,
                                    camera.D if D is None else D, np.eye(3), P, args.camera_name)
    fovs = camera.fields_of_view()
    summary = {
        'width': spec.width, 'height': spec.height, 'spec': spec_record(spec),
        'model': model, 'omega': None, 'f': float(camera.K[0, 0]),
        'cx': float(camera.cx), 'cy': float(camera.cy), 'K': calibration.K.tolist(),
        'distortion_model': distortion_model, 'D': calibration.D.tolist(), 'fit_error_px': fit_error,
        'P': calibration.P.tolist(),
        'hfov': fovs.get('hfov'), 'vfov': fovs.get('vfov'), 'dfov': fovs.get('dfov'),
        'root_found': root_found, 'dfov_residuals': {},
    }
    return summary, calibration


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


def check_output_image(path, option='-o'):
    """One error line naming ``option``, before any work, when OpenCV cannot write an image to ``path``."""
    if not _can_write_image(path):
        supported = [e for e in IMAGE_EXTENSIONS if _can_write_image('x' + e)]
        raise CliError(f'{option} {path}: OpenCV {cv2.__version__} cannot write '
                       f'{os.path.splitext(path)[1] or "a file without an extension"}: allowed: '
                       f'{", ".join(supported)}')
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise CliError(f'{option} {path}: cannot write image: directory {directory} does not exist')
    if os.path.isdir(path):
        raise CliError(f'{option} {path}: cannot write image: it is a directory')


def check_png_output(path, option):
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


def write_png(path, image, option, written=()):
    """``image`` written to ``path`` as a PNG, all or nothing (core/atomic_file.py); one error line
    naming the option, and the files already written, when it cannot be."""
    from ..core.atomic_file import SaveError, write_atomically
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


def write_report(args, data, written=()):
    """--report: the calibration report (core/report/calibration_report.py) of ``data``."""
    if data is None or not getattr(args, 'report', None):
        return
    from ..core.report.calibration_report import render_report
    write_png(args.report, render_report(data).image, '--report', written)


def read_input_image(path, finite=False):
    """core/file_input.read_image: (image, sha1 of the file); every refusal one CliError naming
    the file (a regular file, at most MAX_IMAGE_PIXELS, decoded completely)."""
    try:
        return read_image(path, cv2.IMREAD_UNCHANGED, finite=finite)
    except InputFileError as exc:
        raise CliError(str(exc)) from None


def load_calibration(path, option):
    """CameraCalibration.load, every failure one CliError naming the option and the file; what
    loading assumed (a missing distortion_model, say) is a warning line."""
    try:
        calibration = CameraCalibration.load(path)
        print_warnings(calibration.load_warnings, f'{option} {path}: ')
        return calibration
    except CalibrationFileError as exc:
        message = str(exc)
    except (ArithmeticError, TypeError, KeyError, AttributeError, ValueError) as exc:
        message = f'not a usable calibration file: {type(exc).__name__}: {exc}'
    raise CliError(f'{option} {message}' if message.startswith(f'{path}:') else f'{option} {path}: {message}')


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # no such method, or a closed stream
        return False


def _columns(stream) -> int:
    """The width of the terminal ``stream`` writes to (its own, else the one ``COLUMNS`` or stdout
    say, else 80)."""
    try:
        columns = os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, ValueError, OSError):  # no file number (a test's stream), or no terminal
        columns = 0
    # a terminal whose size was never set (a pty of `script`, some CI runners) says 0 columns
    return columns if columns > 0 else shutil.get_terminal_size().columns


class ProgressLine:
    """Progress on a stream: one line rewritten in place (``\r``) on a terminal, cut to the
    terminal's width (a longer line wraps, and ``\r`` then rewrites only its last row, leaving the
    others behind on the screen), a line per report
    elsewhere (a log file has no use for carriage returns). ``refine``, ``calibrate`` and
    ``evaluate`` report through it (``progress_line``); any other output first ends the line
    (``end_progress``)."""

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
            text = text[:max(1, _columns(self.stream) - 1)]  # the last column would wrap the cursor
            self.stream.write('\r' + text.ljust(self.width))
            self.width = len(text)
            ProgressLine.active = self
        else:
            self.stream.write(text + '\n')
        self.stream.flush()

    def close(self) -> None:
        if self.in_place and self.width:
            self.stream.write('\n')
            self.stream.flush()
            self.width = 0
        if ProgressLine.active is self:
            ProgressLine.active = None


def end_progress() -> None:
    """End the progress line being rewritten in place, if any, so that what follows (a warning, the
    result) starts on a line of its own; the next report starts a new progress line."""
    if ProgressLine.active is not None:
        ProgressLine.active.close()


def progress_line(args, command):
    """A ProgressLine on stderr with --progress, or by default when stderr is a terminal and the
    output is not --json; None otherwise (silent)."""
    if args.progress or (not args.json and _is_terminal(sys.stderr)):
        return ProgressLine(sys.stderr, command)
    return None


def with_progress(args, label, run):
    """``run(args, progress)`` with the verb's progress line (None where it is not shown), the line
    ended whatever happens."""
    progress = progress_line(args, label)
    try:
        return run(args, progress)
    finally:
        if progress is not None:
            progress.close()
