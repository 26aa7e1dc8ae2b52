"""ROS 2 node: CameraInfo from a camera's spec sheet, and optional live rectification.

    ros2 run zeroshot_calib_ros node --ros-args -p width:=1920 -p height:=1080 -p hfov:=118 -p vfov:=69

Only ROS plumbing lives here (parameters, topics, the service, QoS); every computation is in
``zeroshot_calib_ros.core``.

Threads: every ROS callback runs on the executor thread (rclpy.spin), and only there is the
calibration in force (``_active``) replaced. Rectification maps of a new calibration (start-up,
parameter change, set_camera_info) are built on a builder thread while frames keep the
calibration in force; when they are ready, a guard condition swaps the new calibration in on the
executor thread. So a parameter change never stalls the stream, and every frame's CameraInfo and
image_rect come from one calibration.
"""
from __future__ import annotations

import array
import collections
import os
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass
from typing import Optional, Tuple

# OpenCV's thread pool spins (busy-waits, sched_yield) around each parallel call before sleeping;
# with the image publisher and subscribers on the same few cores that steals their CPU (py-spy:
# 15 % of the node's samples in sched_yield; without the spinning the node sustained 26-38 % more
# frames per second at 1080p bgr8 on 2 cores). Read once, when cv2 loads, so set before the core
# modules import it; an environment that sets them wins.
for _name in ('OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER', 'OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN'):
    os.environ.setdefault(_name, '0')

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
import rclpy.executors
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType,
                                SetParametersResult)
from rclpy.exceptions import ParameterException, ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_service import ParameterService
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo

from .core.calibration_file import (DISTORTION_MODELS, CalibrationFileError, CameraCalibration,
                                    RegionOfInterest, resolve_camera_info_url, solution_summary, summary_text)
from .core.fitting import FIT_WARNING_PX
from .core.image_frames import (ActiveCalibration, FrameSkipped, MapBudgetExceeded, check_frame,
                                check_map_budget, default_map_budget_mb, image_array, map_bytes)
from .core.rectify import INTERPOLATIONS
from .core.solver import PROJECTION_CHOICES, NoConvergence, solve_zero_shot
from .core.presets import spec_with_preset
from .core.spec import MAX_IMAGE_SIDE, CameraSpec, SpecError

NODE_NAME = 'zeroshot_calib'
SPEC_PARAMETERS = ('preset', 'width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov',
                   'projection')
CALIBRATION_PARAMETERS = SPEC_PARAMETERS + ('distortion_model',)
RECTIFICATION_PARAMETERS = ('balance', 'fov_scale', 'rectify', 'interpolation')
FOV_PARAMETERS = ('hfov', 'vfov', 'dfov', 'circle_fov')
IMAGE_IDLE_SECONDS = 1.0
"""Timer-driven CameraInfo resumes when no image arrived for this long."""
WARN_THROTTLE_SECONDS = 5.0
OTHER_SIZE_IDLE_SECONDS = 10.0
"""Maps of a frame size other than the configured one are released after this long unused."""
REBUILD_MAP_THREADS = 1
"""Threads building the maps of a new calibration while frames stream: one, so the stream keeps
the other cores (with one per CPU, the longest gap between 1080p frames during a rebuild on 2
cores reached 318 ms, with one 40-90 ms; benchmarks/startup_and_memory.py). At start-up and
when no frame came for IMAGE_IDLE_SECONDS: one per CPU."""


def _descriptor(description, kind, read_only=False, fp_range=None, int_range=None,
                constraints='', dynamic=False):
    d = ParameterDescriptor(description=description, type=kind, read_only=read_only,
                            additional_constraints=constraints, dynamic_typing=dynamic)
    if fp_range:
        d.floating_point_range = [FloatingPointRange(from_value=fp_range[0], to_value=fp_range[1])]
    if int_range:
        d.integer_range = [IntegerRange(from_value=int_range[0], to_value=int_range[1], step=1)]
    return d


D = ParameterType
PARAMETERS = {
    # name: (default, descriptor)
    # No camera is assumed: width, height and at least one FOV must be given (0 = not given).
    # Numbers are typed dynamically so that `-p hfov:=118` or `balance: 1` (INTEGERs on the
    # command line and in YAML) and `width:=1920.0` are accepted; the node checks every value.
    'width': (0, _descriptor('Image width in pixels (required unless the preset gives it)', D.PARAMETER_INTEGER,
                             int_range=(0, MAX_IMAGE_SIDE), dynamic=True,
                             constraints=f'an integer from 1 to {MAX_IMAGE_SIDE}')),
    'height': (0, _descriptor('Image height in pixels (required unless the preset gives it)', D.PARAMETER_INTEGER,
                              int_range=(0, MAX_IMAGE_SIDE), dynamic=True,
                              constraints=f'an integer from 1 to {MAX_IMAGE_SIDE}')),
    'hfov': (0.0, _descriptor('Horizontal field of view from the spec sheet, degrees (0 = not given; '
                                'integers accepted)', D.PARAMETER_DOUBLE, fp_range=(0.0, 360.0),
                                dynamic=True, constraints='a number in [0, 360); 0 means not given')),
    'vfov': (0.0, _descriptor('Vertical field of view from the spec sheet, degrees (0 = not given)',
                               D.PARAMETER_DOUBLE, fp_range=(0.0, 360.0), dynamic=True,
                               constraints='a number in [0, 360); 0 means not given')),
    'dfov': (0.0, _descriptor('Diagonal field of view from the spec sheet, degrees (0 = not given); with '
                              'hfov and vfov it selects the projection', D.PARAMETER_DOUBLE,
                              fp_range=(0.0, 360.0), dynamic=True,
                              constraints='a number in [0, 360); 0 means not given')),
    'circle_diameter': (0.0, _descriptor('Circular fisheye: diameter of the image circle, pixels (0 = not '
                                         'given); with circle_fov', D.PARAMETER_DOUBLE,
                                         fp_range=(0.0, 2.0 * MAX_IMAGE_SIDE), dynamic=True,
                                         constraints='a number of pixels; 0 means not given')),
    'circle_fov': (0.0, _descriptor('Circular fisheye: field of view across the image circle, degrees '
                                    '(0 = not given)', D.PARAMETER_DOUBLE, fp_range=(0.0, 360.0), dynamic=True,
                                    constraints='a number in [0, 360); 0 means not given')),
    'preset': ('', _descriptor('Camera preset (published spec sheet, `zeroshot-calib presets` lists them); '
                               'width, height and FOV parameters that are not 0 override its fields',
                               D.PARAMETER_STRING)),
    'projection': ('auto', _descriptor('Fisheye projection of the lens', D.PARAMETER_STRING,
                                       constraints='one of: ' + ', '.join(PROJECTION_CHOICES))),
    'camera_name': ('camera', _descriptor('camera_name of calibration files and ${NAME} in camera_info_url',
                                          D.PARAMETER_STRING, read_only=True,
                                          constraints='letters, digits and _ (camera_info_manager\'s rule)')),
    'frame_id': ('camera', _descriptor('header.frame_id of CameraInfo published without an image input '
                                       '(with images, the image header is copied)', D.PARAMETER_STRING)),
    'publish_rate': (10.0, _descriptor('CameraInfo rate when no image arrives on image_raw, Hz',
                                       D.PARAMETER_DOUBLE, fp_range=(0.01, 1000.0), read_only=True,
                                       dynamic=True, constraints='a number from 0.01 to 1000')),
    'distortion_model': ('equidistant', _descriptor(
        'CameraInfo distortion model: equidistant (OpenCV fisheye, k1..k4) or plumb_bob (narrow lenses)',
        D.PARAMETER_STRING, constraints='one of: ' + ', '.join(DISTORTION_MODELS))),
    'rectify': (False, _descriptor('Publish image_rect, rectified from image_raw', D.PARAMETER_BOOL)),
    'balance': (0.0, _descriptor('Rectified camera: 0 keeps only valid pixels, 1 keeps every image edge '
                                 '(cv2.fisheye.estimateNewCameraMatrixForUndistortRectify)',
                                 D.PARAMETER_DOUBLE, fp_range=(0.0, 1.0), dynamic=True,
                                 constraints='a number from 0 to 1')),
    'fov_scale': (1.0, _descriptor('Rectified camera: field of view scale (divides the focal length)',
                                   D.PARAMETER_DOUBLE, fp_range=(0.1, 10.0), dynamic=True,
                                   constraints='a number from 0.1 to 10')),
    'interpolation': (1, _descriptor('Rectification interpolation as image_proc: 0 nearest, 1 linear, '
                                     '2 cubic, 4 lanczos4', D.PARAMETER_INTEGER, int_range=(0, 4),
                                     constraints='0, 1, 2 or 4')),
    'camera_info_url': ('', _descriptor('Calibration file, camera_info_manager\'s rules: file:// or package:// '
                                        'URL or a path, ${NAME} = camera_name, ${ROS_HOME} (default ~/.ros); '
                                        'empty = file://${ROS_HOME}/camera_info/${NAME}.yaml. If the file exists '
                                        'it overrides the spec at start-up; set_camera_info saves there',
                                        D.PARAMETER_STRING, read_only=True)),
    'max_map_memory_mb': (0, _descriptor('Memory budget of the rectification maps, MiB (0 = an eighth of the '
                                         'machine\'s memory); a change or frame size whose maps exceed it is '
                                         'refused', D.PARAMETER_INTEGER, read_only=True, int_range=(0, 2**40),
                                         constraints='an integer number of MiB; 0 = automatic')),
}


def _number(name, value, low, high, integer=False):
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
        _number('publish_rate', values['publish_rate'], 0.01, 1000.0)
        return cls(spec, values['projection'], values['distortion_model'], values['camera_name'],
                   _number('balance', values['balance'], 0.0, 1.0),
                   _number('fov_scale', values['fov_scale'], 0.1, 10.0), values['rectify'],
                   int(interpolation))


def solve_from_settings(settings: Settings, generation: int, build_maps: bool = True,
                        map_budget_bytes: Optional[int] = None):
    """ActiveCalibration solved from the spec, and its summary (maps built unless ``build_maps``
    is False: then ``prepare()`` builds them)."""
    solution = solve_zero_shot(settings.spec, settings.projection)
    calibration, fit = CameraCalibration.from_solution(
        solution, settings.distortion_model, settings.balance, settings.fov_scale, settings.camera_name)
    active = ActiveCalibration(calibration, solution.camera, 'spec', generation, settings.rectify,
                               settings.interpolation, build_maps=build_maps, map_budget_bytes=map_budget_bytes)
    return active, solution_summary(solution, calibration, fit)


def _calibration_from_msg(msg: CameraInfo, camera_name: str) -> CameraCalibration:
    roi = RegionOfInterest(int(msg.roi.x_offset), int(msg.roi.y_offset), int(msg.roi.height),
                           int(msg.roi.width), bool(msg.roi.do_rectify))
    return CameraCalibration(int(msg.width), int(msg.height), np.array(msg.k), msg.distortion_model,
                             np.array(msg.d), np.array(msg.r), np.array(msg.p), camera_name,
                             int(msg.binning_x), int(msg.binning_y), roi)


@dataclass
class _Job:
    """Maps the builder thread prepares: a calibration's (then swapped in) or a new frame size's."""

    active: ActiveCalibration
    log: str = ''
    map_threads: Optional[int] = REBUILD_MAP_THREADS
    size: Optional[Tuple[int, int]] = None
    """None: the calibration's configured size, swapped in when built; else another frame size."""
    values: Optional[dict] = None
    """The parameter values this calibration came from (restored if its maps cannot be built)."""
    seconds: float = 0.0
    error: Optional[BaseException] = None


class _MapBuilder:
    """One worker thread for map building, at low CPU priority so the stream keeps its cores.

    First the maps of the newest calibration asked for (a request superseded by a newer one
    before its turn is dropped), then the maps of new frame sizes (each size once).
    ``done(job)`` is called on the worker thread when a job ends."""

    def __init__(self, done):
        self._done = done
        self._cond = threading.Condition()
        self._pending: Optional[_Job] = None
        self._sizes = collections.deque()
        self._queued_sizes = set()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name='map_builder', daemon=True)
        self._thread.start()

    @property
    def pending(self) -> Optional[_Job]:
        return self._pending

    def submit(self, job: _Job):
        with self._cond:
            self._pending = job
            self._cond.notify()

    def request_size(self, active: ActiveCalibration, width: int, height: int):
        """Build the maps of ``width`` x ``height`` for ``active`` (once; later calls are no-ops)."""
        key = (id(active), width, height)
        with self._cond:
            if key in self._queued_sizes:
                return
            self._queued_sizes.add(key)
            self._sizes.append(_Job(active, size=(width, height)))
            self._cond.notify()

    def stop(self, timeout: float = 5.0):
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout)

    def _run(self):
        try:  # Linux: a thread's nice value is its own
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
        except (AttributeError, OSError):
            pass
        while True:
            with self._cond:
                while self._pending is None and not self._sizes and not self._stopped:
                    self._cond.wait()
                if self._stopped:
                    return
                job = self._pending if self._pending is not None else self._sizes.popleft()
            start = time.monotonic()
            try:
                if job.size is None:
                    job.active.prepare(job.map_threads)
                else:
                    job.active.build_maps(*job.size, map_threads=job.map_threads)
            except Exception as exc:  # reported by the node; the calibration in force stays
                job.error = exc
            job.seconds = time.monotonic() - start
            with self._cond:
                if self._pending is job:
                    self._pending = None
                if job.size is not None and job.error:  # a built size stays queued until released
                    self._queued_sizes.discard((id(job.active), *job.size))
            self._done(job)

    def forget_size(self, active: ActiveCalibration, width: int, height: int):
        """Allow ``width`` x ``height`` to be requested again (its maps were released)."""
        with self._cond:
            self._queued_sizes.discard((id(active), width, height))


def _fill_camera_info(msg: CameraInfo, calibration: CameraCalibration):
    msg.width, msg.height = calibration.width, calibration.height
    msg.distortion_model = calibration.distortion_model
    msg.d = calibration.D.tolist()
    msg.k = calibration.K.ravel().tolist()
    msg.r = calibration.R.ravel().tolist()
    msg.p = calibration.P.ravel().tolist()
    # as given (a file, set_camera_info); 0 and an all-zero roi mean the full image, unbinned
    msg.binning_x, msg.binning_y = int(calibration.binning_x), int(calibration.binning_y)
    roi = calibration.roi
    msg.roi.x_offset, msg.roi.y_offset = int(roi.x_offset), int(roi.y_offset)
    msg.roi.width, msg.roi.height = int(roi.width), int(roi.height)
    msg.roi.do_rectify = bool(roi.do_rectify)


def _binning_or_roi(calibration: CameraCalibration) -> str:
    """Why the node cannot rectify frames of this calibration itself ('' if it can)."""
    roi = calibration.roi
    partial_roi = not roi.is_full() and \
        (roi.x_offset, roi.y_offset, roi.width, roi.height) != (0, 0, calibration.width, calibration.height)
    if calibration.binning_x > 1 or calibration.binning_y > 1 or partial_roi:
        return (f'the calibration has binning {calibration.binning_x}x{calibration.binning_y} / roi '
                f'{roi.width}x{roi.height}+{roi.x_offset}+{roi.y_offset}: the node rectifies full, unbinned '
                'frames only (image_proc rectifies binned / ROI frames from this CameraInfo)')
    return ''


def _binned_roi_size(calibration: CameraCalibration) -> Tuple[int, int]:
    """The size of the frames a binned / ROI calibration describes, as image_geometry computes it."""
    roi = calibration.roi
    width, height = (calibration.width, calibration.height) if roi.is_full() else (roi.width, roi.height)
    return width // max(1, calibration.binning_x), height // max(1, calibration.binning_y)


_TYPE_TEXT = {ParameterType.PARAMETER_BOOL: 'true or false', ParameterType.PARAMETER_INTEGER: 'an integer',
              ParameterType.PARAMETER_DOUBLE: 'a number', ParameterType.PARAMETER_STRING: 'a string'}


class _AtomicParameterService(ParameterService):
    """rclpy's parameter services, except that one SetParameters request (``ros2 param set``,
    ``ros2 param load``) is one change: validated together, solved once, adopted whole or
    rejected whole. rclpy applies such a request value by value, which adopts intermediate
    calibrations nobody asked for (a new width with the old height). Read-only parameters given
    their current value (a params file loaded back) are no change and succeed."""

    def _set_parameters_callback(self, request, response):
        node = self._get_node()
        parameters = [Parameter.from_parameter_msg(p) for p in request.parameters]
        unchanged = set()
        for i, param in enumerate(parameters):
            if node.has_parameter(param.name) and node.describe_parameter(param.name).read_only and \
                    node.get_parameter(param.name).value == param.value:
                unchanged.add(i)
        changes = [p for i, p in enumerate(parameters) if i not in unchanged]
        wrong_type = next((text for text in map(self._wrong_type, changes) if text), None)
        try:
            if wrong_type:  # rclpy's reason would not name the parameter
                result = SetParametersResult(successful=False, reason=wrong_type)
            else:
                result = node.set_parameters_atomically(changes) if changes else SetParametersResult(successful=True)
        except ParameterNotDeclaredException as exc:
            result = SetParametersResult(successful=False, reason=f'{exc}: the whole request was rejected')
        # Whole: a rejected request rejects its unchanged read-only values too, so that no client
        # reads one result as "this part was applied".
        response.results = [SetParametersResult(successful=True, reason='unchanged (read-only)')
                            if i in unchanged and result.successful else result for i in range(len(parameters))]
        return response

    def _wrong_type(self, param: Parameter) -> str:
        """The reason a value of the wrong type for a statically typed parameter is rejected, naming
        the parameter as the node's own checks do ('' if the type is right or rclpy decides)."""
        node = self._get_node()
        if not node.has_parameter(param.name):
            return ''
        descriptor = node.describe_parameter(param.name)
        if descriptor.dynamic_typing or descriptor.read_only or param.type_.value == descriptor.type:
            return ''
        value = param.value if not hasattr(param.value, 'tolist') else param.value.tolist()
        allowed = _TYPE_TEXT.get(descriptor.type, Parameter.Type(descriptor.type).name.lower())
        if descriptor.additional_constraints:
            allowed += f' ({descriptor.additional_constraints})'
        return f'{param.name} = {value!r} is invalid: allowed: {allowed}'


class ZeroShotCalibNode(Node):
    """Publishes the zero-shot CameraInfo; rectifies image_raw into image_rect when asked."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, start_parameter_services=False, **kwargs)
        self._parameter_service = _AtomicParameterService(self)
        for name, (default, descriptor) in PARAMETERS.items():
            self.declare_parameter(name, default, descriptor)
        self._stats = Counter()
        self._warned_at = {}
        self._last_image_time = None  # time.monotonic() of the last frame
        # Until an image publisher is seen: reliable CameraInfo (what late joiners and the
        # default subscriber QoS want), best-effort image_raw (accepts either kind of publisher).
        self._reliability = ReliabilityPolicy.RELIABLE
        self._image_reliability = ReliabilityPolicy.BEST_EFFORT
        self._rect_pub = None
        self._out_buffer = None
        self._rect_msg = Image()
        self._info_cache = (None, None)  # (calibration, its CameraInfo), reused frame after frame
        self._maps_build_ms = float('nan')
        self._reverting = False

        self._map_budget = _number('max_map_memory_mb', self.get_parameter('max_map_memory_mb').value,
                                   0, 2**40, integer=True) or default_map_budget_mb()
        settings = Settings.from_values(self._values())
        self._settings = settings
        url = self.get_parameter('camera_info_url').value
        self._url_path = resolve_camera_info_url(url, settings.camera_name)
        # The calibration is in force at once (CameraInfo needs no maps); its maps are built on
        # the builder thread, and frames that come before they are ready are not rectified.
        self._active = self._initial_calibration(settings)
        self._values_in_force = self._values()
        self._newest = self._active  # the last calibration accepted (in force or being built)
        self._generation = self._active.generation
        self._built = []
        self._built_lock = threading.Lock()
        self._built_guard = self.create_guard_condition(self._on_calibration_built)
        self._builder = _MapBuilder(self._on_builder_done)

        self._create_endpoints()
        self._set_camera_info_srv = self.create_service(SetCameraInfo, 'set_camera_info',
                                                        self._on_set_camera_info)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._rate = float(self.get_parameter('publish_rate').value)
        self._info_timer = self.create_timer(1.0 / self._rate, self._on_info_timer)
        self._housekeeping_timer = self.create_timer(1.0, self._on_housekeeping)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # One at start-up whatever the camera does: transient local then holds a calibration for
        # late joiners even if a camera exists but has not sent a frame yet.
        self._publish_own_info()
        self.get_logger().info(self._interfaces_text())
        if self._active.rectify_enabled:  # after the first CameraInfo is out
            self._builder.submit(_Job(self._active, map_threads=None))

    @property
    def _map_budget_bytes(self) -> int:
        return int(self._map_budget) * 2**20

    # --- start-up -------------------------------------------------------------------------
    def _values(self, overrides=None) -> dict:
        values = {name: self.get_parameter(name).value for name in PARAMETERS}
        for p in overrides or ():
            values[p.name] = p.value
        return values

    def _initial_calibration(self, settings: Settings) -> ActiveCalibration:
        path = self._url_path
        self._file_state = f'none at {path} yet: set_camera_info will save there'
        if os.path.isfile(path):
            try:
                calibration = CameraCalibration.load(path)
                active = ActiveCalibration(calibration, calibration.camera(), f'file {path}', 0,
                                           settings.rectify, settings.interpolation, build_maps=False,
                                           map_budget_bytes=self._map_budget_bytes)
            except (CalibrationFileError, ValueError) as exc:
                self.get_logger().error(f'ignoring camera_info_url {path}: {exc}; solving from the spec '
                                        'instead (set_camera_info will overwrite the file)')
                self._file_state = f'{path} unreadable ({exc}): set_camera_info will overwrite it'
            else:
                for warning in getattr(calibration, 'load_warnings', ()):
                    self.get_logger().warning(f'{path}: {warning}')
                self._warn_if_file_differs(calibration, settings, path)
                self.get_logger().info(
                    f'calibration loaded from {path} (takes precedence over the spec):\n'
                    f'  {calibration.width} x {calibration.height} px, camera_name {calibration.camera_name}\n'
                    f'  K {calibration.K.tolist()}\n  {calibration.distortion_model} D {calibration.D.tolist()}')
                self._file_state = f'loaded {path}; set_camera_info saves there'
                return active
        active, summary = solve_from_settings(settings, 0, build_maps=False, map_budget_bytes=self._map_budget_bytes)
        self.get_logger().info('zero-shot calibration from the spec sheet:\n' + summary_text(summary))
        self._warn_fit(summary)
        return active

    def _warn_if_file_differs(self, calibration: CameraCalibration, settings: Settings, path: str):
        spec = settings.spec
        if calibration.camera_name != settings.camera_name:
            self.get_logger().warning(f'{path} is the calibration of camera_name {calibration.camera_name!r}, '
                                      f'this node is camera_name {settings.camera_name!r}; using the file')
        if (calibration.width, calibration.height) != (spec.width, spec.height):
            self.get_logger().warning(f'{path} is for {calibration.width}x{calibration.height} images, the spec '
                                      f'says {spec.width}x{spec.height}; using the file (frames of the spec '
                                      'size get scaled intrinsics if the aspect ratio agrees)')

    def _warn_fit(self, summary: Optional[dict]):
        if summary and summary['fit_error_px'] > FIT_WARNING_PX:
            self.get_logger().warning(
                f"the published {summary['distortion_model']} model departs from the zero-shot lens by up to "
                f"{summary['fit_error_px']:.3g} px (more than {FIT_WARNING_PX:g} px): consumers of CameraInfo "
                'see that error' + (' (use distortion_model: equidistant for a lens this wide)'
                                    if summary['distortion_model'] != 'equidistant' else ''))

    def _interfaces_text(self) -> str:
        def qos_text(reliability, durability='volatile', depth=5):
            return f'{reliability.name.lower()}, {durability}, depth {depth}'
        rect = (f'  publishes  {self._rect_pub.topic_name} (sensor_msgs/Image, {qos_text(self._reliability)})'
                if self._rect_pub else f'  (no {self.resolve_topic_name("image_rect")}: rectify is false)')
        return '\n'.join([
            'interfaces (QoS reliability follows the image publisher, checked once a second):',
            f'  publishes  {self._info_pub.topic_name} (sensor_msgs/CameraInfo, '
            f'{qos_text(self._reliability, "transient local")}): with every {self._image_sub.topic_name} frame '
            f'(its header), at {self._rate:g} Hz while {self._image_sub.topic_name} has no publisher',
            rect,
            f'  subscribes {self._image_sub.topic_name} (sensor_msgs/Image, {qos_text(self._image_reliability, depth=10)})',
            f'  service    {self.resolve_service_name(self._set_camera_info_srv.srv_name)} '
            '(sensor_msgs/srv/SetCameraInfo, for cameracalibrator)',
            f'  publishes  {self._diagnostics_pub.topic_name} (diagnostic_msgs/DiagnosticArray, 1 Hz)',
            f'  rectify    {"on" if self._active.rectify_enabled else "off"}'
            f' (maps at most max_map_memory_mb = {self._map_budget})',
            f'  calibration file: {self._file_state}',
        ])

    def _create_endpoints(self):
        """Publishers and subscription with the reliability of the image publisher (see housekeeping)."""
        info_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=self._reliability,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._info_pub = self.create_publisher(CameraInfo, 'camera_info', info_qos)
        self._sync_rect_publisher()
        # depth 10 on the way in: a frame that takes long to arrive (a 30 MB one takes ~0.3 s
        # through DDS) must not push the frames queued behind it out of the reader's history
        self._image_sub = self.create_subscription(Image, 'image_raw', self._on_image,
                                                   self._image_qos(self._image_reliability, depth=10))

    def _sync_rect_publisher(self):
        """image_rect is advertised only while rectify is on (it would collide with image_proc's)."""
        if self._active.rectify_enabled and self._rect_pub is None:
            self._rect_pub = self.create_publisher(Image, 'image_rect', self._image_qos(self._reliability))
        elif not self._active.rectify_enabled and self._rect_pub is not None:
            self.destroy_publisher(self._rect_pub)
            self._rect_pub = None

    @staticmethod
    def _image_qos(reliability, depth=5):
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
                          durability=DurabilityPolicy.VOLATILE)

    # --- publishing -----------------------------------------------------------------------
    def _camera_exists(self) -> bool:
        """Whether image_raw has a publisher (or frames came lately): then CameraInfo goes out
        with each frame only. A stamp of our own while a camera pauses is a CameraInfo no image
        has, which image_transport's CameraSubscriber reports as unsynchronised."""
        if self._last_image_time is not None and time.monotonic() - self._last_image_time < IMAGE_IDLE_SECONDS:
            return True
        return self.count_publishers(self._image_sub.topic_name) > 0

    def _on_info_timer(self):
        if not self._camera_exists():
            self._publish_own_info()

    def _publish_own_info(self):
        """A CameraInfo stamped now (no image to take the header from)."""
        msg = CameraInfo()
        _fill_camera_info(msg, self._active.calibration)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.get_parameter('frame_id').value
        self._info_pub.publish(msg)

    def _on_image(self, msg: Image):
        self._stats['frames_received'] += 1
        self._last_image_time = time.monotonic()
        active = self._active  # one snapshot per frame: CameraInfo and image_rect agree
        width, height = msg.width, msg.height
        try:
            # the same checks whatever rectify is: no CameraInfo for an image the message lacks
            check_frame(width, height, msg.step, msg.encoding, len(msg.data))
            if _binning_or_roi(active.calibration):
                # CameraInfo as given (binning and roi tell consumers how the frame maps); no scaling
                calibration = active.calibration
                if (width, height) != _binned_roi_size(calibration):
                    raise FrameSkipped('aspect', f'image {width}x{height} is not the {"x".join(map(str, _binned_roi_size(calibration)))} '
                                       'that the calibration\'s binning and roi describe')
            else:
                calibration = active.calibration_for(width, height)
        except FrameSkipped as exc:
            self._skip(exc)
            return
        except Exception as exc:  # never let a frame take the node down
            self._skip(FrameSkipped('error', f'cannot calibrate frame: {exc}'))
            return
        info = self._camera_info_for(calibration)
        info.header = msg.header
        self._info_pub.publish(info)
        self._stats['camera_info_published'] += 1
        if not active.rectify_enabled or self._rect_pub is None:
            return
        try:
            rectifier = active.rectifier_for(width, height)
            if rectifier is None:
                self._request_maps(active, calibration, width, height)
                return
            self._publish_rectified(msg, rectifier)
        except FrameSkipped as exc:
            self._skip(exc)
        except Exception as exc:
            self._skip(FrameSkipped('error', f'cannot rectify frame: {exc}'))

    def _request_maps(self, active: ActiveCalibration, calibration: CameraCalibration, width: int, height: int):
        """A frame whose maps are not built: skipped (counted) while the builder builds them, so
        that one frame of a new size never stalls the stream."""
        reason = _binning_or_roi(calibration)
        if reason:
            raise FrameSkipped('binning_roi', reason)
        if (width, height) != active.size:
            try:
                check_map_budget(width, height, self._map_budget_bytes - map_bytes(*active.size),
                                 what='rectification maps of this frame size (beside the configured size)')
            except MapBudgetExceeded as exc:
                raise FrameSkipped('maps_budget', str(exc)) from None
            self._builder.request_size(active, width, height)
        raise FrameSkipped('maps_pending', f'rectification maps of {width}x{height} are being built; '
                           'frames of that size are not rectified until they are ready')

    def _camera_info_for(self, calibration: CameraCalibration) -> CameraInfo:
        """The CameraInfo of ``calibration``, filled once and reused (only the header changes;
        publish() serialises the message before it returns)."""
        cached_calibration, info = self._info_cache
        if cached_calibration is not calibration:
            info = CameraInfo()
            _fill_camera_info(info, calibration)
            self._info_cache = (calibration, info)
        return info

    def _publish_rectified(self, msg: Image, rectifier):
        image = image_array(msg.data, msg.width, msg.height, msg.step, msg.encoding, msg.is_bigendian)
        nbytes = image.nbytes
        # The output message owns one buffer reused frame after frame; rclpy takes an
        # array('B') as is and serialises it during publish(), so reuse is safe.
        if self._out_buffer is None or len(self._out_buffer) != nbytes:
            self._out_buffer = array.array('B', bytes(nbytes))
        out = np.frombuffer(self._out_buffer, dtype=image.dtype).reshape(image.shape)
        rectifier.rectify(image, out=out)
        rect = self._rect_msg
        rect.header = msg.header
        rect.height, rect.width = image.shape[:2]
        rect.encoding = msg.encoding
        rect.is_bigendian = 0
        rect.step = image.shape[1] * (image.shape[2] if image.ndim == 3 else 1) * image.dtype.itemsize
        rect.data = self._out_buffer
        self._rect_pub.publish(rect)
        self._stats['frames_rectified'] += 1

    def _skip(self, exc: FrameSkipped):
        self._stats[f'frames_skipped_{exc.reason}'] += 1
        now = self.get_clock().now().nanoseconds
        last = self._warned_at.get(exc.reason)
        if last is None or now - last > WARN_THROTTLE_SECONDS * 1e9:
            self._warned_at[exc.reason] = now
            self.get_logger().warning(f'frame skipped ({exc.reason}): {exc} '
                                      f'[{self._stats[f"frames_skipped_{exc.reason}"]} so far]')

    # --- housekeeping: QoS matching, memory and diagnostics ---------------------------------
    def _on_housekeeping(self):
        self._match_image_reliability()
        for size in self._active.release_unused(OTHER_SIZE_IDLE_SECONDS):
            self._builder.forget_size(self._active, *size)
            self.get_logger().info(f'rectification maps of {size[0]}x{size[1]} released (no such frame '
                                   f'for {OTHER_SIZE_IDLE_SECONDS:g} s)')
        self._publish_diagnostics()

    def _match_image_reliability(self):
        infos = self.get_publishers_info_by_topic(self._image_sub.topic_name)
        if not infos:
            return
        best_effort = any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos)
        wanted = ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE
        if wanted != self._reliability or wanted != self._image_reliability:
            self.get_logger().info(f'image publisher is {wanted.name.lower()}: matching camera_info, '
                                   'image_rect and image_raw QoS')
            self._reliability = self._image_reliability = wanted
            self.destroy_publisher(self._info_pub)
            if self._rect_pub is not None:
                self.destroy_publisher(self._rect_pub)
                self._rect_pub = None
            self.destroy_subscription(self._image_sub)
            self._create_endpoints()

    def _publish_diagnostics(self):
        status = DiagnosticStatus(level=DiagnosticStatus.OK, name=f'{self.get_name()}: calibration',
                                  hardware_id=self._active.calibration.camera_name,
                                  message=f'calibration from {self._active.source}')
        pending = self._builder.pending
        values = {'source': self._active.source, 'generation': self._active.generation,
                  'fx': self._active.calibration.K[0, 0], 'qos_reliability': self._reliability.name,
                  'pending_generation': pending.active.generation if pending else '',
                  'maps_build_ms': f'{self._maps_build_ms:.1f}',
                  'map_memory_mb': f'{self._active.map_memory_bytes / 2**20:.1f}', **self._stats}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(msg)

    # --- changes at run time --------------------------------------------------------------
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        if self._reverting:  # restoring the values in force (see _on_calibration_built)
            return SetParametersResult(successful=True)
        names = {p.name for p in parameters}
        if not names & set(CALIBRATION_PARAMETERS + RECTIFICATION_PARAMETERS):
            return SetParametersResult(successful=True)
        # Checked and solved here, whole (a rejection must name its reason, and a success means
        # adopted); the maps are built on the builder thread and swapped in when ready.
        basis = self._newest
        generation = self._generation + 1
        values = self._values(parameters)
        summary = None
        try:
            settings = Settings.from_values(values)
            if names & set(CALIBRATION_PARAMETERS) or basis.source == 'spec':
                active, summary = solve_from_settings(settings, generation, build_maps=False,
                                                      map_budget_bytes=self._map_budget_bytes)
            else:  # a file / set_camera_info calibration stays; only P or the maps change
                new_p = bool(names & {'balance', 'fov_scale'})
                # with_rectification numbers its result one after the calibration it starts from
                active = ActiveCalibration(basis.calibration, basis.camera, basis.source,
                                           generation - 1 if new_p else generation,
                                           settings.rectify, settings.interpolation, build_maps=False,
                                           map_budget_bytes=self._map_budget_bytes)
                if new_p:
                    active = active.with_rectification(settings.balance, settings.fov_scale, build_maps=False)
        except (SpecError, CalibrationFileError, NoConvergence, ValueError) as exc:
            self.get_logger().warning(f'parameter change rejected, calibration unchanged: {exc}')
            return SetParametersResult(successful=False, reason=str(exc))
        except Exception as exc:  # never let a parameter value take the node down
            self.get_logger().error(f'parameter change rejected, calibration unchanged: {exc!r}')
            return SetParametersResult(successful=False, reason=f'cannot calibrate with these values: {exc!r}')
        self._settings = settings
        changed = ', '.join(f'{p.name}={p.value!r}' for p in parameters)
        self._adopt(active, f'parameters changed ({changed}), re-solved:\n' + summary_text(summary)
                    if summary else f'parameters changed ({changed})', values)
        self._warn_fit(summary)
        return SetParametersResult(successful=True)

    # --- calibrations swapped in when their maps are ready --------------------------------
    def _adopt(self, active: ActiveCalibration, log: str, values: Optional[dict] = None):
        """``active`` in force once its maps are built (at once without rectification). Later
        changes build on it (``_newest``) even before it is in force."""
        self._generation = max(self._generation, active.generation)
        self._newest = active
        job = _Job(active, log, values=values if values is not None else self._values())
        if not active.rectify_enabled:  # nothing to build: in force at once
            self._swap_in(job)
            return
        streaming = self._last_image_time is not None and \
            time.monotonic() - self._last_image_time < IMAGE_IDLE_SECONDS
        job.map_threads = REBUILD_MAP_THREADS if streaming else None
        self._builder.submit(job)

    def _on_builder_done(self, job: _Job):
        """Builder thread: hand the job to the executor thread."""
        with self._built_lock:
            self._built.append(job)
        try:
            self._built_guard.trigger()
        except Exception:  # shutting down
            pass

    def _on_calibration_built(self):
        with self._built_lock:
            jobs, self._built = self._built, []
        for job in jobs:
            if job.size is not None:
                if job.error is not None:
                    self._stats['size_maps_failed'] += 1
                    self.get_logger().warning(f'rectification maps of {job.size[0]}x{job.size[1]} not built: '
                                              f'{job.error}; frames of that size stay unrectified')
                else:
                    self.get_logger().info(f'rectification maps of {job.size[0]}x{job.size[1]} built in '
                                           f'{job.seconds * 1e3:.0f} ms')
                continue
            if job.error is not None:
                self._calibration_failed(job)
                continue
            self._maps_build_ms = job.seconds * 1e3
            if job.active.rectify_enabled:
                self.get_logger().info(f'rectification maps of generation {job.active.generation} built '
                                       f'in {job.seconds * 1e3:.0f} ms')
            if job.active is not self._active:
                self._swap_in(job)

    def _calibration_failed(self, job: _Job):
        """Maps of an accepted change could not be built (e.g. memory): the calibration in force
        stays, and so that get_parameters, CameraInfo and the log agree, the parameters go back
        to the values in force."""
        self._stats['calibration_build_failed'] += 1
        if job.active is not self._newest:
            self.get_logger().warning(f'calibration (generation {job.active.generation}) not adopted, '
                                      f'building its maps failed: {job.error!r}; a newer change is pending')
            return
        self._newest = self._active
        restore = [Parameter(name, value=value) for name, value in self._values_in_force.items()
                   if name in CALIBRATION_PARAMETERS + RECTIFICATION_PARAMETERS and
                   self.get_parameter(name).value != value]
        self._reverting = True
        try:
            self.set_parameters_atomically(restore)
        finally:
            self._reverting = False
        self._settings = Settings.from_values(self._values())
        self.get_logger().warning(
            f'calibration (generation {job.active.generation}) not adopted, building its maps failed: '
            f'{job.error!r}; parameters restored to the values in force '
            f'({", ".join(f"{p.name}={p.value!r}" for p in restore) or "unchanged"})')

    def _swap_in(self, job: _Job):
        if job.active.generation <= self._active.generation:
            return  # superseded while it was built
        self._active = job.active
        if job.values is not None:
            self._values_in_force = job.values
        self._stats['calibrations_adopted'] += 1
        self._sync_rect_publisher()
        if job.log:
            self.get_logger().info(job.log)
        self._on_info_timer()  # late joiners see the change at once (unless a camera publishes)

    def destroy_node(self):
        builder = getattr(self, '_builder', None)
        if builder is not None:
            builder.stop()
        return super().destroy_node()

    def _on_set_camera_info(self, request, response):
        """As camera drivers offer it to cameracalibrator: validated whole (including the maps'
        memory with rectify on), saved to camera_info_url, then adopted. "success" means adopted
        and saved, as camera_info_manager answers."""
        try:
            calibration = _calibration_from_msg(request.camera_info, self._settings.camera_name)
            active = ActiveCalibration(calibration, calibration.camera(), 'set_camera_info',
                                       self._generation + 1, self._settings.rectify,
                                       self._settings.interpolation, build_maps=False,
                                       map_budget_bytes=self._map_budget_bytes)
        except (CalibrationFileError, ValueError) as exc:
            response.success, response.status_message = False, f'rejected, calibration unchanged: {exc}'
            self.get_logger().warning(f'set_camera_info {response.status_message}')
            return response
        except Exception as exc:  # never let a request take the node down
            response.success, response.status_message = False, f'rejected, calibration unchanged: {exc!r}'
            self.get_logger().error(f'set_camera_info {response.status_message}')
            return response
        try:
            calibration.save(self._url_path)
            saved = f' and saved to {self._url_path}'
            response.success = True
        except (OSError, CalibrationFileError) as exc:
            saved = f' but NOT saved to {self._url_path}: {getattr(exc, "strerror", None) or exc}'
            response.success = False
        self._adopt(active, f'calibration from set_camera_info adopted{saved}')
        response.status_message = f'calibration adopted{saved}'
        self.get_logger().info(f'set_camera_info: {response.status_message}')
        return response


def usage() -> str:
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
    for name, (default, descriptor) in PARAMETERS.items():
        flags = ' (read-only)' if descriptor.read_only else ''
        allowed = f'; allowed: {descriptor.additional_constraints}' if descriptor.additional_constraints else ''
        lines.append(f'  {name:17s} default {default!r}{flags}: {descriptor.description}{allowed}')
    lines += ['', 'topics (relative; namespace and remap them): camera_info, image_rect (with rectify), '
              'image_raw (in), service set_camera_info, /diagnostics']
    return '\n'.join(lines)


def main(args=None):
    argv = sys.argv[1:] if args is None else list(args[1:])
    user_args = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in user_args or '--help' in user_args:
        print(usage())
        return 0
    rclpy.init(args=args)
    node = None
    try:
        node = ZeroShotCalibNode()
    except (SpecError, CalibrationFileError, ParameterException) as exc:
        print(f'{NODE_NAME}: error: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
