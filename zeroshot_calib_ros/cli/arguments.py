"""What the verbs of ``zeroshot-calib`` share on the command line: the error reported in one line,
the number types of the options (ASCII notation, core/zeroshot/numbers.py), the option groups of
a spec sheet and of the written camera, and the texts of --help on image budgets and exit statuses."""
from __future__ import annotations

from ..core.estimation.terms import FOV_TOLERANCE_DEG
from ..core.file_input import MAX_IMAGE_PIXELS
from ..core.ros_formats.calibration_file import DISTORTION_MODELS
from ..core.zeroshot.numbers import parse_integer, parse_number, parse_whole_number
from ..core.zeroshot.solver import PROJECTION_CHOICES

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


REPORT_HELP = ("write a picture of the calibration (PNG): the lens curve against the spec's FOVs, the 1-sigma "
               'error over the image, a rectified preview{extra}, and the verdict (docs/report.md)')


SOLVE_SPEC_FIELDS = ('width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov')


class CliError(Exception):
    """An error to report in one line."""


def _argument_type(parse, name):
    """``parse`` as an argparse type called ``name`` in argparse's errors ('invalid number value: ...')."""
    def convert(text):
        return parse(text)
    convert.__name__ = name
    return convert


number = _argument_type(parse_number, 'number')
whole_number = _argument_type(parse_whole_number, 'whole number')
"""An image side: an integer, or an integral float such as 1920.0 (1920.5 is refused by
CameraSpec, which names the field and the range)."""
integer = _argument_type(parse_integer, 'integer')


def add_spec_arguments(parser, size_required=True):
    parser.add_argument('--width', type=whole_number, required=size_required, help='image width (px)')
    parser.add_argument('--height', type=whole_number, required=size_required, help='image height (px)')
    parser.add_argument('--hfov', type=number, help='horizontal field of view (deg)')
    parser.add_argument('--vfov', type=number, help='vertical field of view (deg)')
    parser.add_argument('--dfov', type=number, help='diagonal field of view (deg)')
    parser.add_argument('--model', default='auto', choices=PROJECTION_CHOICES,
                        help='fisheye projection; auto picks by dfov when all three FOVs are given, '
                             'else equidistant, and switches to wide (angle-space model for FOVs of '
                             '180 deg and more) only when needed (default: auto)')


def add_output_arguments(parser):
    parser.add_argument('--distortion-model', default='equidistant', choices=DISTORTION_MODELS,
                        help='ROS distortion model to fit (default: equidistant)')
    parser.add_argument('--balance', type=number, default=0.0,
                        help='rectified camera: 0 crops to valid pixels, 1 keeps every edge (default 0)')
    parser.add_argument('--fov-scale', type=number, default=1.0,
                        help='rectified camera: divides its focal length (default 1)')


def add_fov_tolerance_argument(parser):
    parser.add_argument('--fov-tolerance', type=number, default=FOV_TOLERANCE_DEG, metavar='DEG',
                        help='how far the spec-sheet FOVs may be off (1 sigma, degrees; default '
                             f'{FOV_TOLERANCE_DEG:g}): sets the reported uncertainty, the warning when '
                             'the solved camera misses a given FOV by more, and, for refine, how much '
                             'the lines may move the FOVs')


def add_circle_arguments(parser, refine=False):
    parser.add_argument('--circle-diameter', type=number, metavar='PX',
                        help='circular fisheye: image-circle diameter (px), with --circle-fov'
                        + ('; refine measures it in the images when it is left out' if refine else ''))
    parser.add_argument('--circle-fov', type=number, metavar='DEG',
                        help='circular fisheye: field of view across the image circle (deg)')


def add_progress_argument(parser):
    parser.add_argument('--progress', action='store_true',
                        help='report progress on stderr (default: when stderr is a terminal, without --json)')


def options_given(args, names):
    """The command-line spelling of each of ``names`` given (not None) in ``args``."""
    return ['--' + n.replace('_', '-') for n in names if getattr(args, n, None) is not None]
