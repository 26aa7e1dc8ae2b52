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
import os
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass
from typing import Optional

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
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo

from .core.calibration_file import (DISTORTION_MODELS, CalibrationFileError, CameraCalibration,
                                    resolve_camera_info_url, solution_summary, summary_text)
from .core.image_frames import ActiveCalibration, FrameSkipped, image_array
from .core.rectify import INTERPOLATIONS
from .core.solver import PROJECTION_CHOICES, NoConvergence, solve_zero_shot
from .core.presets import spec_with_preset
from .core.spec import MAX_IMAGE_SIDE, CameraSpec, SpecError

NODE_NAME = 'zeroshot_calib'
SPEC_PARAMETERS = ('preset', 'width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov',
                   'projection')
CALIBRATION_PARAMETERS = SPEC_PARAMETERS + ('distortion_model', 'camera_name')
RECTIFICATION_PARAMETERS = ('balance', 'fov_scale', 'rectify', 'interpolation')
FOV_PARAMETERS = ('hfov', 'vfov', 'dfov', 'circle_fov')
IMAGE_IDLE_SECONDS = 1.0
"""Timer-driven CameraInfo resumes when no image arrived for this long."""
WARN_THROTTLE_SECONDS = 5.0
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
    'camera_name': ('camera', _descriptor('camera_name written to calibration files', D.PARAMETER_STRING)),
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
    'camera_info_url': ('', _descriptor('Calibration file (file:// or package:// URL, ${NAME} expands to '
                                        'camera_name); if it exists it overrides the spec at start-up, and '
                                        'set_camera_info saves there', D.PARAMETER_STRING, read_only=True)),
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
        if not isinstance(values['camera_name'], str):
            raise SpecError('camera_name', values['camera_name'], 'a string')
        _number('publish_rate', values['publish_rate'], 0.01, 1000.0)
        return cls(spec, values['projection'], values['distortion_model'], values['camera_name'],
                   _number('balance', values['balance'], 0.0, 1.0),
                   _number('fov_scale', values['fov_scale'], 0.1, 10.0), values['rectify'],
                   int(interpolation))


def solve_from_settings(settings: Settings, generation: int, build_maps: bool = True):
    """ActiveCalibration solved from the spec, and its summary (maps built unless ``build_maps``
    is False: then ``prepare()`` or the first frame builds them)."""
    solution = solve_zero_shot(settings.spec, settings.projection)
    calibration, fit = CameraCalibration.from_solution(
        solution, settings.distortion_model, settings.balance, settings.fov_scale, settings.camera_name)
    active = ActiveCalibration(calibration, solution.camera, 'spec', generation, settings.rectify,
                               settings.interpolation, build_maps=build_maps)
    return active, solution_summary(solution, calibration, fit)


def _calibration_from_msg(msg: CameraInfo, camera_name: str) -> CameraCalibration:
    return CameraCalibration(int(msg.width), int(msg.height), np.array(msg.k), msg.distortion_model,
                             np.array(msg.d), np.array(msg.r), np.array(msg.p), camera_name)


@dataclass
class _Job:
    """A calibration whose maps the builder thread prepares before it is swapped in."""

    active: ActiveCalibration
    log: str = ''
    map_threads: Optional[int] = REBUILD_MAP_THREADS
    seconds: float = 0.0
    error: Optional[BaseException] = None


class _CalibrationBuilder:
    """One thread that builds maps for the newest calibration asked for: a request superseded by
    a newer one before its turn is dropped. ``done(job)`` is called on the builder thread."""

    def __init__(self, done):
        self._done = done
        self._cond = threading.Condition()
        self._pending: Optional[_Job] = None
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name='calibration_builder', daemon=True)
        self._thread.start()

    @property
    def pending(self) -> Optional[_Job]:
        return self._pending

    def submit(self, job: _Job):
        with self._cond:
            self._pending = job
            self._cond.notify()

    def stop(self, timeout: float = 5.0):
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout)

    def _run(self):
        while True:
            with self._cond:
                while self._pending is None and not self._stopped:
                    self._cond.wait()
                if self._stopped:
                    return
                job = self._pending
            start = time.monotonic()
            try:
                job.active.prepare(job.map_threads)
            except Exception as exc:  # reported by the node; the calibration in force stays
                job.error = exc
            job.seconds = time.monotonic() - start
            with self._cond:
                if self._pending is job:
                    self._pending = None
            self._done(job)


def _fill_camera_info(msg: CameraInfo, calibration: CameraCalibration):
    msg.width, msg.height = calibration.width, calibration.height
    msg.distortion_model = calibration.distortion_model
    msg.d = calibration.D.tolist()
    msg.k = calibration.K.ravel().tolist()
    msg.r = calibration.R.ravel().tolist()
    msg.p = calibration.P.ravel().tolist()
    msg.binning_x = msg.binning_y = 0
    # roi all zeros: the full image, as camera drivers send it


class ZeroShotCalibNode(Node):
    """Publishes the zero-shot CameraInfo; rectifies image_raw into image_rect when asked."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        for name, (default, descriptor) in PARAMETERS.items():
            self.declare_parameter(name, default, descriptor)
        self._stats = Counter()
        self._warned_at = {}
        self._last_image_time = None  # time.monotonic() of the last frame
        # Until an image publisher is seen: reliable CameraInfo (what late joiners and the
        # default subscriber QoS want), best-effort image_raw (accepts either kind of publisher).
        self._reliability = ReliabilityPolicy.RELIABLE
        self._image_reliability = ReliabilityPolicy.BEST_EFFORT
        self._out_buffer = None
        self._rect_msg = Image()
        self._info_cache = (None, None)  # (calibration, its CameraInfo), reused frame after frame
        self._maps_build_ms = float('nan')

        settings = Settings.from_values(self._values())
        self._settings = settings
        self._url_path = resolve_camera_info_url(self.get_parameter('camera_info_url').value,
                                                 settings.camera_name)
        # The calibration is in force at once (CameraInfo needs no maps); its maps are built on
        # the builder thread, and a frame arriving before they are ready waits for them.
        self._active = self._initial_calibration(settings)
        self._newest = self._active  # the last calibration accepted (in force or being built)
        self._generation = self._active.generation
        self._built = []
        self._built_lock = threading.Lock()
        self._built_guard = self.create_guard_condition(self._on_calibration_built)
        self._builder = _CalibrationBuilder(self._on_builder_done)

        self._create_endpoints()
        self._set_camera_info_srv = self.create_service(SetCameraInfo, 'set_camera_info',
                                                        self._on_set_camera_info)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        rate = float(self.get_parameter('publish_rate').value)
        self._info_timer = self.create_timer(1.0 / rate, self._on_info_timer)
        self._housekeeping_timer = self.create_timer(1.0, self._on_housekeeping)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._on_info_timer()
        if self._active.rectify_enabled:  # after the first CameraInfo is out
            self._builder.submit(_Job(self._active, map_threads=None))

    # --- start-up -------------------------------------------------------------------------
    def _values(self, overrides=None) -> dict:
        values = {name: self.get_parameter(name).value for name in PARAMETERS}
        for p in overrides or ():
            values[p.name] = p.value
        return values

    def _initial_calibration(self, settings: Settings) -> ActiveCalibration:
        if self._url_path and os.path.isfile(self._url_path):
            try:
                calibration = CameraCalibration.load(self._url_path)
                active = ActiveCalibration(calibration, calibration.camera(), f'file {self._url_path}', 0,
                                           settings.rectify, settings.interpolation, build_maps=False)
            except (CalibrationFileError, ValueError) as exc:
                self.get_logger().error(f'ignoring camera_info_url: {exc}; solving from the spec instead')
            else:
                self.get_logger().info(
                    f'calibration loaded from {self._url_path} (takes precedence over the spec):\n'
                    f'  K {calibration.K.tolist()}\n  {calibration.distortion_model} D {calibration.D.tolist()}')
                return active
        active, summary = solve_from_settings(settings, 0, build_maps=False)
        self.get_logger().info('zero-shot calibration from the spec sheet:\n' + summary_text(summary))
        return active

    def _create_endpoints(self):
        """Publishers and subscription with the reliability of the image publisher (see housekeeping)."""
        info_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=self._reliability,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._info_pub = self.create_publisher(CameraInfo, 'camera_info', info_qos)
        self._rect_pub = self.create_publisher(Image, 'image_rect', self._image_qos(self._reliability))
        self._image_sub = self.create_subscription(Image, 'image_raw', self._on_image,
                                                   self._image_qos(self._image_reliability))

    @staticmethod
    def _image_qos(reliability):
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=reliability,
                          durability=DurabilityPolicy.VOLATILE)

    # --- publishing -----------------------------------------------------------------------
    def _on_info_timer(self):
        if self._last_image_time is not None and \
                time.monotonic() - self._last_image_time < IMAGE_IDLE_SECONDS:
            return  # images are flowing: CameraInfo goes out with each frame instead
        msg = CameraInfo()
        _fill_camera_info(msg, self._active.calibration)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.get_parameter('frame_id').value
        self._info_pub.publish(msg)

    def _on_image(self, msg: Image):
        self._stats['frames_received'] += 1
        self._last_image_time = time.monotonic()
        active = self._active  # one snapshot per frame: CameraInfo and image_rect agree
        try:
            if active.rectify_enabled and len(msg.data) < msg.width * msg.height:
                # no maps are built for a size the data does not back (any encoding >= 1 byte/px)
                raise FrameSkipped('malformed', f'data has {len(msg.data)} bytes, fewer than one per pixel '
                                   f'of {msg.width}x{msg.height}')
            calibration, rectifier = active.for_size(msg.width, msg.height)
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
        if rectifier is not None:
            try:
                self._publish_rectified(msg, rectifier)
            except FrameSkipped as exc:
                self._skip(exc)
            except Exception as exc:
                self._skip(FrameSkipped('error', f'cannot rectify frame: {exc}'))

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

    # --- housekeeping: QoS matching and diagnostics -----------------------------------------
    def _on_housekeeping(self):
        self._match_image_reliability()
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
            self.destroy_publisher(self._rect_pub)
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
                  'maps_build_ms': f'{self._maps_build_ms:.1f}', **self._stats}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(msg)

    # --- changes at run time --------------------------------------------------------------
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        names = {p.name for p in parameters}
        if not names & set(CALIBRATION_PARAMETERS + RECTIFICATION_PARAMETERS):
            return SetParametersResult(successful=True)
        # Checked and solved here (a rejection must name its reason); the maps are built on the
        # builder thread, and the new calibration is swapped in when they are ready.
        basis = self._newest
        generation = self._generation + 1
        try:
            settings = Settings.from_values(self._values(parameters))
            if names & set(CALIBRATION_PARAMETERS) or basis.source == 'spec':
                active, summary = solve_from_settings(settings, generation, build_maps=False)
            else:  # a file / set_camera_info calibration stays; only P or the maps change
                active = ActiveCalibration(basis.calibration, basis.camera, basis.source, generation,
                                           settings.rectify, settings.interpolation, build_maps=False)
                if names & {'balance', 'fov_scale'}:
                    active = active.with_rectification(settings.balance, settings.fov_scale, build_maps=False)
                summary = None
        except (SpecError, CalibrationFileError, NoConvergence, ValueError) as exc:
            self.get_logger().warning(f'parameter change rejected, calibration unchanged: {exc}')
            return SetParametersResult(successful=False, reason=str(exc))
        except Exception as exc:  # never let a parameter value take the node down
            self.get_logger().error(f'parameter change rejected, calibration unchanged: {exc!r}')
            return SetParametersResult(successful=False, reason=f'cannot calibrate with these values: {exc!r}')
        self._settings = settings
        self._adopt(active, 'parameters changed, re-solved:\n' + summary_text(summary) if summary else
                    'parameters changed')
        return SetParametersResult(successful=True)

    # --- calibrations swapped in when their maps are ready --------------------------------
    def _adopt(self, active: ActiveCalibration, log: str):
        """``active`` in force once its maps are built (at once without rectification). Later
        changes build on it (``_newest``) even before it is in force."""
        self._generation = max(self._generation, active.generation)
        self._newest = active
        if not active.rectify_enabled:  # nothing to build: in force at once
            self._swap_in(_Job(active.prepare(), log))
            return
        streaming = self._last_image_time is not None and \
            time.monotonic() - self._last_image_time < IMAGE_IDLE_SECONDS
        self._builder.submit(_Job(active, log, map_threads=REBUILD_MAP_THREADS if streaming else None))

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
            if job.error is not None:
                self._stats['calibration_build_failed'] += 1
                self.get_logger().error(f'calibration (generation {job.active.generation}) not adopted, '
                                        f'building its maps failed: {job.error!r}')
                continue
            self._maps_build_ms = job.seconds * 1e3
            if job.active.rectify_enabled:
                self.get_logger().info(f'rectification maps of generation {job.active.generation} built '
                                       f'in {job.seconds * 1e3:.0f} ms')
            if job.active is not self._active:
                self._swap_in(job)

    def _swap_in(self, job: _Job):
        if job.active.generation <= self._active.generation:
            return  # superseded while it was built
        self._active = job.active
        self._stats['calibrations_adopted'] += 1
        if job.log:
            self.get_logger().info(job.log)
        self._on_info_timer()  # late joiners and idle streams see the change at once

    def destroy_node(self):
        builder = getattr(self, '_builder', None)
        if builder is not None:
            builder.stop()
        return super().destroy_node()

    def _on_set_camera_info(self, request, response):
        try:
            calibration = _calibration_from_msg(request.camera_info, self._settings.camera_name)
            active = ActiveCalibration(calibration, calibration.camera(), 'set_camera_info',
                                       self._generation + 1, self._settings.rectify,
                                       self._settings.interpolation, build_maps=False)
        except (CalibrationFileError, ValueError) as exc:
            response.success, response.status_message = False, f'rejected: {exc}'
            self.get_logger().warning(f'set_camera_info {response.status_message}')
            return response
        self._adopt(active, 'calibration from set_camera_info adopted')
        response.success, response.status_message = True, 'calibration adopted'
        if self._url_path:
            try:
                calibration.save(self._url_path)
                response.status_message += f' and saved to {self._url_path}'
            except OSError as exc:
                response.success = False
                response.status_message += f' but not saved to {self._url_path}: {exc.strerror}'
        self.get_logger().info(f'set_camera_info: {response.status_message}')
        return response


def main(args=None):
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
