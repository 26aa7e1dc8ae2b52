"""The ``zeroshot-calib`` command: its parser, one subcommand a module of this package, and
``main``, which checks the options known before any work, runs the verb and turns every failure
into one line on stderr with the exit status of EXIT_STATUSES."""
from __future__ import annotations

import argparse
import math
import os
import sys

import cv2

from .. import __version__
from ..core.ros_formats.calibration_file import FORMATS, CalibrationFileError
from ..core.zeroshot.solver import NoConvergence
from ..core.zeroshot.spec import SpecError
from . import calibrate, evaluate, presets, rectify, refine, solve
from .arguments import EXIT_STATUSES, CliError
from .output import check_png_output

VERBS = (solve, presets, rectify, refine, calibrate, evaluate)
"""The subcommands' modules, in the order --help lists them."""


class _Parser(argparse.ArgumentParser):
    """argparse, with usage errors in one line (the usage itself is in --help)."""

    def error(self, message):
        self.exit(2, f'{self.prog}: error: {" ".join(str(message).split())} (see {self.prog} --help)\n')


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog='zeroshot-calib',
        description='Zero-shot calibration of wide-angle and fisheye cameras from resolution and '
                    'spec-sheet field of view (J.-Y. Lee, CVPR 2021).', epilog=EXIT_STATUSES)
    parser.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    sub = parser.add_subparsers(dest='command', required=True, metavar='command',
                                help='solve, presets, rectify, refine, calibrate or evaluate')
    for verb in VERBS:
        verb.add_parser(sub)
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
        check_png_output(args.report, '--report')
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
