"""The node's parameters, ROS-free: the table (type, default, range, read-only, description:
what generate_parameter_library would generate), ``Settings`` (one set of values, validated
whole) and the calibration they give. ``zeroshot_calib_ros.ros`` declares the table as ROS
parameters; tests and benchmarks reach everything here without DDS.
"""
from __future__ import annotations

import difflib
import os
from dataclasses import dataclass
from typing import Iterable, List, Optional, Tuple

import numpy as np

from ..zeroshot.presets import spec_with_preset
from ..zeroshot.solver import PROJECTION_CHOICES, solve_zero_shot
from ..zeroshot.spec import MAX_IMAGE_SIDE, CameraSpec, SpecError, value_text
from ..ros_formats.calibration_file import DISTORTION_MODELS, CameraCalibration, solution_summary
from .image_frames import ActiveCalibration
from ..ros_formats.rectify import INTERPOLATIONS

SPEC_PARAMETERS = ('preset', 'width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov',
                   'projection')

CALIBRATION_PARAMETERS = SPEC_PARAMETERS + ('distortion_model',)

RECTIFICATION_PARAMETERS = ('balance', 'fov_scale', 'rectify', 'interpolation')

FOV_PARAMETERS = ('hfov', 'vfov', 'dfov', 'circle_fov')


@dataclass(frozen=True)
class NodeParameter:
    """One parameter: its default, the text users see (``--help``, ``ros2 param describe``), its
    type ('bool', 'integer', 'double' or 'string'), whether it is read-only, its range and the
    allowed values in words. ``dynamic``: typed dynamically, so that integers are accepted where
    a number is expected (`-p hfov:=118`); the node then checks every value itself."""

    default: object
    description: str
    type: str
    read_only: bool = False
    range: Optional[Tuple[float, float]] = None
    constraints: str = ''
    dynamic: bool = False


def _parameter(default, description, kind, read_only=False, fp_range=None, int_range=None,
               constraints='', dynamic=False) -> NodeParameter:
    return NodeParameter(default, description, kind, read_only, fp_range or int_range, constraints, dynamic)


PARAMETERS = {
    # No camera is assumed: width, height and at least one FOV must be given (0 = not given).
    # Numbers are typed dynamically so that `-p hfov:=118` or `balance: 1` (INTEGERs on the
    # command line and in YAML) and `width:=1920.0` are accepted; the node checks every value.
    'width': _parameter(0, 'Image width in pixels (required unless the preset gives it)', 'integer',
                             int_range=(0, MAX_IMAGE_SIDE), dynamic=True,
                             constraints=f'an integer from 1 to {MAX_IMAGE_SIDE}'),
    'height': _parameter(0, 'Image height in pixels (required unless the preset gives it)', 'integer',
                              int_range=(0, MAX_IMAGE_SIDE), dynamic=True,
                              constraints=f'an integer from 1 to {MAX_IMAGE_SIDE}'),
    'hfov': _parameter(0.0, 'Horizontal field of view from the spec sheet, degrees (0 = not given; '
                                'integers accepted)', 'double', fp_range=(0.0, 360.0),
                                dynamic=True, constraints='a number in [0, 360); 0 means not given'),
    'vfov': _parameter(0.0, 'Vertical field of view from the spec sheet, degrees (0 = not given)',
                               'double', fp_range=(0.0, 360.0), dynamic=True,
                               constraints='a number in [0, 360); 0 means not given'),
    'dfov': _parameter(0.0, 'Diagonal field of view from the spec sheet, degrees (0 = not given); with '
                              'hfov and vfov it selects the projection', 'double',
                              fp_range=(0.0, 360.0), dynamic=True,
                              constraints='a number in [0, 360); 0 means not given'),
    'circle_diameter': _parameter(0.0, 'Circular fisheye: diameter of the image circle, pixels (0 = not '
                                         'given); with circle_fov', 'double',
                                         fp_range=(0.0, 2.0 * MAX_IMAGE_SIDE), dynamic=True,
                                         constraints='a number of pixels; 0 means not given'),
    'circle_fov': _parameter(0.0, 'Circular fisheye: field of view across the image circle, degrees '
                                    '(0 = not given)', 'double', fp_range=(0.0, 360.0), dynamic=True,
                                    constraints='a number in [0, 360); 0 means not given'),
    'preset': _parameter('', 'Camera preset (published spec sheet, `zeroshot-calib presets` lists them); '
                               'width, height and FOV parameters that are not 0 override its fields',
                               'string'),
    'projection': _parameter('auto', 'Fisheye projection of the lens', 'string',
                                       constraints='one of: ' + ', '.join(PROJECTION_CHOICES)),
    'camera_name': _parameter('camera', 'camera_name of calibration files and ${NAME} in camera_info_url',
                                          'string', read_only=True,
                                          constraints='letters, digits and _ (camera_info_manager\'s rule)'),
    'frame_id': _parameter('camera', 'header.frame_id of CameraInfo published without an image input '
                                       '(with images, the image header is copied)', 'string'),
    'publish_rate': _parameter(10.0, 'CameraInfo rate when no image arrives on image_raw, Hz',
                                       'double', fp_range=(0.01, 1000.0), read_only=True,
                                       dynamic=True, constraints='a number from 0.01 to 1000'),
    'distortion_model': _parameter('equidistant', 
        'CameraInfo distortion model: equidistant (OpenCV fisheye, k1..k4) or plumb_bob (narrow lenses)',
        'string', constraints='one of: ' + ', '.join(DISTORTION_MODELS)),
    'rectify': _parameter(False, 'Publish image_rect, rectified from image_raw', 'bool'),
    'balance': _parameter(0.0, 'Rectified camera: 0 keeps only valid pixels, 1 keeps every image edge '
                                 '(cv2.fisheye.estimateNewCameraMatrixForUndistortRectify)',
                                 'double', fp_range=(0.0, 1.0), dynamic=True,
                                 constraints='a number from 0 to 1'),
    'fov_scale': _parameter(1.0, 'Rectified camera: field of view scale (divides the focal length)',
                                   'double', fp_range=(0.1, 10.0), dynamic=True,
                                   constraints='a number from 0.1 to 10'),
    'interpolation': _parameter(1, 'Rectification interpolation as image_proc: 0 nearest, 1 linear, '
                                     '2 cubic, 4 lanczos4', 'integer', int_range=(0, 4),
                                     constraints='0, 1, 2 or 4'),
    'camera_info_url': _parameter('', 'Calibration file, camera_info_manager\'s rules: file:// or package:// '
                                        'URL or a path, ${NAME} = camera_name, ${ROS_HOME} (default ~/.ros); '
                                        'empty = file://${ROS_HOME}/camera_info/${NAME}.yaml. If the file exists '
                                        'it overrides the spec at start-up; set_camera_info saves there',
                                        'string', read_only=True),
    'max_map_memory_mb': _parameter(0, 'Memory budget of the rectification maps, MiB (0 = an eighth of the '
                                         'memory the node may use: the tightest of physical memory, cgroup '
                                         'and ulimit); a change or frame size whose maps exceed it is '
                                         'refused', 'integer', read_only=True, int_range=(0, 2**40),
                                         constraints='an integer number of MiB; 0 = automatic'),
    'refine': _parameter(False, 'Refine the calibration from straight lines in the streamed frames: '
                                'one frame every refine_interval s, lines and fit in a low-priority worker '
                                'process; when the quality gate passes, the refined calibration (in distortion_model, '
                                'source refined) is adopted and saved to camera_info_url. Only a calibration '
                                'from the spec (or an earlier refinement) is refined, never one from a file '
                                'or set_camera_info', 'bool'),
    'refine_interval': _parameter(2.0, 'With refine: seconds between the frames taken for refinement (at most '
                                       'one per interval, and only while the worker is idle)', 'double',
                                       fp_range=(0.1, 3600.0), dynamic=True,
                                       constraints='a number of seconds from 0.1 to 3600'),
}


ROS_PARAMETERS = ('use_sim_time', 'start_type_description_service')
"""Parameters every rclpy node declares itself."""
ROS_PARAMETER_PREFIXES = ('qos_overrides.',)
"""Parameters rclpy reads itself (QoS overrides of publishers and subscriptions)."""


def same_value(name: str, old, new) -> bool:
    """Whether ``new`` is the value ``old`` of parameter ``name`` already is, compared as typed
    values: for a number parameter an INTEGER 115 is the DOUBLE 115.0 (the node reads both as
    the same number), never a bool or a string; for the others, the same type and value."""
    parameter = PARAMETERS.get(name)
    if parameter is not None and parameter.type in ('double', 'integer'):
        numbers = [v for v in (old, new) if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if len(numbers) == 2:
            return float(old) == float(new)
    return type(old) is type(new) and old == new


def changed_parameters(current: dict, parameters: Iterable[Tuple[str, object]]) -> List[str]:
    """Names of ``parameters`` ((name, value) pairs) whose value differs from ``current``'s
    (``same_value``); a name not in ``current`` is a change."""
    return [name for name, value in parameters
            if name not in current or not same_value(name, current[name], value)]


def unknown_parameter_warnings(names: Iterable[str]) -> List[str]:
    """One line per name that is none of the node's parameters (nor rclpy's own), with the
    closest declared name when there is one (a misspelled `-p rectfy:=true`)."""
    lines = []
    for name in names:
        if name in PARAMETERS or name in ROS_PARAMETERS or name.startswith(ROS_PARAMETER_PREFIXES):
            continue
        lines.append(f'unknown parameter {value_text(name)} ignored{closest_parameter_text(name)} '
                     '(--help lists the parameters)')
    return lines


def closest_parameter_text(name: str) -> str:
    """': did you mean 'rectify'?' for a misspelled ``name`` ('' when no declared name is close)."""
    close = difflib.get_close_matches(str(name), list(PARAMETERS), n=1)
    return f': did you mean {close[0]!r}?' if close else ''


def params_file_errors(argv) -> List[str]:
    """One line per ``--params-file FILE`` of the ROS arguments in ``argv`` that cannot be read
    (rcl would fail with a traceback-shaped error naming the whole argument)."""
    errors, in_ros_args = [], False
    argv = list(argv)
    for i, arg in enumerate(argv):
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg == '--params-file':
            if i + 1 >= len(argv):
                errors.append('--params-file needs a file: allowed: --params-file FILE (a YAML parameters file)')
                continue
            path = argv[i + 1]
            if not os.path.isfile(path):
                why = 'is a directory' if os.path.isdir(path) else 'no such file'
                errors.append(f'--params-file {path}: {why}: allowed: a readable YAML parameters file')
            elif not os.access(path, os.R_OK):
                errors.append(f'--params-file {path}: not readable (permission denied): allowed: a readable '
                              'YAML parameters file')
    return errors


def number_in_range(name, value, low, high, integer=False):
    """``value`` as a float (int if ``integer``) in [low, high], else SpecError naming the range."""
    allowed = f'{"an integer" if integer else "a number"} from {low:g} to {high:g}'
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) \
            or not low <= value <= high or (integer and value != int(value)):
        raise SpecError(name, value, allowed)
    return int(value) if integer else float(value)


@dataclass(frozen=True)
class Settings:
    """Parameter values the calibration depends on, checked."""

    spec: CameraSpec
    projection: str
    distortion_model: str
    camera_name: str
    balance: float
    fov_scale: float
    rectify: bool
    interpolation: int

    @classmethod
    def from_values(cls, values: dict) -> 'Settings':
        for name in FOV_PARAMETERS:
            value = values[name]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise SpecError(name, value, 'a number of degrees in [0, 360); 0 means not given')
        fovs = {n: (float(values[n]) if values[n] != 0 else None) for n in FOV_PARAMETERS}
        circle = values['circle_diameter']
        if isinstance(circle, bool) or not isinstance(circle, (int, float)):
            raise SpecError('circle_diameter', circle, 'a number of pixels; 0 means not given')
        if not isinstance(values['preset'], str):
            raise SpecError('preset', values['preset'], 'a preset name')
        size = {n: values[n] for n in ('width', 'height')}
        if values['preset']:  # 0 = take the preset's
            size = {n: (v if v != 0 else None) for n, v in size.items()}
        spec = spec_with_preset(values['preset'], **size, **fovs,
                                circle_diameter=float(circle) if circle != 0 else None)
        # rclpy enforces the types of the parameters below; checked again for other callers
        for name, choices in (('projection', PROJECTION_CHOICES), ('distortion_model', DISTORTION_MODELS)):
            if not isinstance(values[name], str) or values[name] not in choices:
                raise SpecError(name, values[name], ', '.join(choices))
        interpolation = values['interpolation']
        if isinstance(interpolation, bool) or not isinstance(interpolation, int) or \
                interpolation not in INTERPOLATIONS:
            raise SpecError('interpolation', interpolation, '0, 1, 2 or 4')
        if not isinstance(values['rectify'], bool):
            raise SpecError('rectify', values['rectify'], 'true or false')
        name = values['camera_name']
        # camera_info_manager's validateName: the name goes into file names (${NAME}) and files
        if not isinstance(name, str) or not name or not all(c.isascii() and (c.isalnum() or c == '_') for c in name):
            raise SpecError('camera_name', name, "letters, digits and _ (camera_info_manager's rule), not empty")
        number_in_range('publish_rate', values['publish_rate'], 0.01, 1000.0)
        return cls(spec, values['projection'], values['distortion_model'], values['camera_name'],
                   number_in_range('balance', values['balance'], 0.0, 1.0),
                   number_in_range('fov_scale', values['fov_scale'], 0.1, 10.0), values['rectify'],
                   int(interpolation))


def solve_from_settings(settings: Settings, generation: int, build_maps: bool = True,
                        map_budget_bytes: Optional[int] = None):
    """ActiveCalibration solved from the spec, and its summary (maps built unless ``build_maps``
    is False: then ``prepare()`` builds them). The solution's warnings (given FOVs its camera
    misses, at the default tolerance) are the summary's ``warning`` and ``active.spec_warnings``;
    what it assumed (one FOV: the lens shape) is ``active.assumption`` and a warning too."""
    solution = solve_zero_shot(settings.spec, settings.projection)
    calibration, fit = CameraCalibration.from_solution(
        solution, settings.distortion_model, settings.balance, settings.fov_scale, settings.camera_name)
    active = ActiveCalibration(calibration, solution.camera, 'spec', generation, settings.rectify,
                               settings.interpolation, build_maps=build_maps, map_budget_bytes=map_budget_bytes)
    active.spec_warnings = tuple(solution.warnings)
    active.assumption = solution.assumption
    summary = solution_summary(solution, calibration, fit)
    # the assumption is a warning too, as in the CLI: the camera is usable, its lens shape a guess
    summary['warning'] = list(solution.warnings) + ([solution.assumption] if solution.assumption else [])
    return active, summary


def usage_text() -> str:
    """`node --help`: how to start the node, and every parameter with its type, default and range."""
    lines = ['usage: ros2 run zeroshot_calib_ros node --ros-args [-p NAME:=VALUE ...] [--params-file FILE]',
             '             [-r __ns:=/NAMESPACE] [-r image_raw:=/camera/image_raw]',
             '',
             'Publishes sensor_msgs/CameraInfo (equidistant) computed from a camera\'s spec sheet',
             '(zero-shot calibration, J.-Y. Lee, CVPR 2021); with rectify:=true also image_rect.',
             'Example: ros2 run zeroshot_calib_ros node --ros-args -p width:=1920 -p height:=1080 '
             '-p hfov:=118 -p vfov:=69',
             '',
             'parameters:']
    for name, parameter in PARAMETERS.items():
        flags = ' (read-only)' if parameter.read_only else ''
        allowed = f'; allowed: {parameter.constraints}' if parameter.constraints else ''
        lines.append(f'  {name:17s} default {parameter.default!r}{flags}: {parameter.description}{allowed}')
    lines += ['', 'topics (relative; namespace and remap them): camera_info, image_rect (with rectify), '
              'image_raw (in), service set_camera_info, /diagnostics']
    return '\n'.join(lines)
