"""ROS 2 node: CameraInfo from a camera's spec sheet, and optional live rectification.

    ros2 run zeroshot_calib_ros node --ros-args -p width:=1920 -p height:=1080 -p hfov:=118 -p vfov:=69

Only ROS plumbing lives here (parameters, topics, the service, QoS); every computation is in
``zeroshot_calib_ros.core``.
"""
from __future__ import annotations

import array
import os
import sys
from collections import Counter
from dataclasses import dataclass
from typing import Optional

import numpy as np
import rclpy
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
from .core.image_frames import ENCODINGS, ActiveCalibration, FrameSkipped, image_array
from .core.rectify import INTERPOLATIONS
from .core.solver import PROJECTION_CHOICES, NoConvergence, solve_zero_shot
from .core.spec import MAX_IMAGE_SIDE, CameraSpec, SpecError

NODE_NAME = 'zeroshot_calib'
SPEC_PARAMETERS = ('width', 'height', 'hfov', 'vfov', 'dfov', 'projection')
CALIBRATION_PARAMETERS = SPEC_PARAMETERS + ('distortion_model', 'camera_name')
RECTIFICATION_PARAMETERS = ('balance', 'fov_scale', 'rectify', 'interpolation')
FOV_PARAMETERS = ('hfov', 'vfov', 'dfov')
IMAGE_IDLE_SECONDS = 1.0
"""Timer-driven CameraInfo resumes when no image arrived for this long."""
WARN_THROTTLE_SECONDS = 5.0


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
    'width': (0, _descriptor('Image width in pixels (required)', D.PARAMETER_INTEGER,
                             int_range=(0, MAX_IMAGE_SIDE), dynamic=True,
                             constraints=f'an integer from 1 to {MAX_IMAGE_SIDE}')),
    'height': (0, _descriptor('Image height in pixels (required)', D.PARAMETER_INTEGER,
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
        spec = CameraSpec(values['width'], values['height'], **fovs)
        if values['projection'] not in PROJECTION_CHOICES:
            raise SpecError('projection', values['projection'], ', '.join(PROJECTION_CHOICES))
        if values['distortion_model'] not in DISTORTION_MODELS:
            raise SpecError('distortion_model', values['distortion_model'], ', '.join(DISTORTION_MODELS))
        if values['interpolation'] not in INTERPOLATIONS:
            raise SpecError('interpolation', values['interpolation'], '0, 1, 2 or 4')
        _number('publish_rate', values['publish_rate'], 0.01, 1000.0)
        return cls(spec, values['projection'], values['distortion_model'], values['camera_name'],
                   _number('balance', values['balance'], 0.0, 1.0),
                   _number('fov_scale', values['fov_scale'], 0.1, 10.0), bool(values['rectify']),
                   int(values['interpolation']))


def solve_from_settings(settings: Settings, generation: int):
    """ActiveCalibration solved from the spec, and its summary."""
    solution = solve_zero_shot(settings.spec, settings.projection)
    calibration, fit = CameraCalibration.from_solution(
        solution, settings.distortion_model, settings.balance, settings.fov_scale, settings.camera_name)
    active = ActiveCalibration(calibration, solution.camera, 'spec', generation, settings.rectify,
                               settings.interpolation)
    return active, solution_summary(solution, calibration, fit)


def _calibration_from_msg(msg: CameraInfo, camera_name: str) -> CameraCalibration:
    return CameraCalibration(int(msg.width), int(msg.height), np.array(msg.k), msg.distortion_model,
                             np.array(msg.d), np.array(msg.r), np.array(msg.p), camera_name)


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
        self._last_image_time = None
        # Until an image publisher is seen: reliable CameraInfo (what late joiners and the
        # default subscriber QoS want), best-effort image_raw (accepts either kind of publisher).
        self._reliability = ReliabilityPolicy.RELIABLE
        self._image_reliability = ReliabilityPolicy.BEST_EFFORT
        self._out_buffer = None

        settings = Settings.from_values(self._values())
        self._settings = settings
        self._url_path = resolve_camera_info_url(self.get_parameter('camera_info_url').value,
                                                 settings.camera_name)
        self._active = self._initial_calibration(settings)

        self._create_endpoints()
        self._set_camera_info_srv = self.create_service(SetCameraInfo, 'set_camera_info',
                                                        self._on_set_camera_info)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        rate = float(self.get_parameter('publish_rate').value)
        self._info_timer = self.create_timer(1.0 / rate, self._on_info_timer)
        self._housekeeping_timer = self.create_timer(1.0, self._on_housekeeping)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._on_info_timer()

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
                                           settings.rectify, settings.interpolation)
            except (CalibrationFileError, ValueError) as exc:
                self.get_logger().error(f'ignoring camera_info_url: {exc}; solving from the spec instead')
            else:
                self.get_logger().info(
                    f'calibration loaded from {self._url_path} (takes precedence over the spec):\n'
                    f'  K {calibration.K.tolist()}\n  {calibration.distortion_model} D {calibration.D.tolist()}')
                return active
        active, summary = solve_from_settings(settings, 0)
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
        now = self.get_clock().now()
        if self._last_image_time is not None and \
                (now - self._last_image_time).nanoseconds < IMAGE_IDLE_SECONDS * 1e9:
            return  # images are flowing: CameraInfo goes out with each frame instead
        msg = CameraInfo()
        _fill_camera_info(msg, self._active.calibration)
        msg.header.stamp = now.to_msg()
        msg.header.frame_id = self.get_parameter('frame_id').value
        self._info_pub.publish(msg)

    def _on_image(self, msg: Image):
        self._stats['frames_received'] += 1
        self._last_image_time = self.get_clock().now()
        active = self._active  # one snapshot per frame: CameraInfo and image_rect agree
        try:
            calibration, rectifier = active.for_size(msg.width, msg.height)
        except FrameSkipped as exc:
            self._skip(exc)
            return
        except Exception as exc:  # never let a frame take the node down
            self._skip(FrameSkipped('error', f'cannot calibrate frame: {exc}'))
            return
        info = CameraInfo()
        _fill_camera_info(info, calibration)
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

    def _publish_rectified(self, msg: Image, rectifier):
        image = image_array(msg.data, msg.width, msg.height, msg.step, msg.encoding, msg.is_bigendian)
        nbytes = image.nbytes
        # The output message owns one buffer reused frame after frame; rclpy takes an
        # array('B') as is and serialises it during publish(), so reuse is safe.
        if self._out_buffer is None or len(self._out_buffer) != nbytes:
            self._out_buffer = array.array('B', bytes(nbytes))
        out = np.frombuffer(self._out_buffer, dtype=image.dtype).reshape(image.shape)
        rectifier.rectify(image, out=out)
        rect = Image()
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
        values = {'source': self._active.source, 'generation': self._active.generation,
                  'fx': self._active.calibration.K[0, 0], 'qos_reliability': self._reliability.name,
                  **self._stats}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(msg)

    # --- changes at run time --------------------------------------------------------------
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        names = {p.name for p in parameters}
        if not names & set(CALIBRATION_PARAMETERS + RECTIFICATION_PARAMETERS):
            return SetParametersResult(successful=True)
        try:
            settings = Settings.from_values(self._values(parameters))
            if names & set(CALIBRATION_PARAMETERS) or self._active.source == 'spec':
                active, summary = solve_from_settings(settings, self._active.generation + 1)
            else:  # a file / set_camera_info calibration stays; only P or the maps change
                active = ActiveCalibration(self._active.calibration, self._active.camera,
                                           self._active.source, self._active.generation + 1,
                                           settings.rectify, settings.interpolation)
                if names & {'balance', 'fov_scale'}:
                    active = active.with_rectification(settings.balance, settings.fov_scale)
                summary = None
        except (SpecError, CalibrationFileError, NoConvergence, ValueError) as exc:
            self.get_logger().warning(f'parameter change rejected, calibration unchanged: {exc}')
            return SetParametersResult(successful=False, reason=str(exc))
        self._settings, self._active = settings, active
        if summary is not None:
            self.get_logger().info('parameters changed, re-solved:\n' + summary_text(summary))
        return SetParametersResult(successful=True)

    def _on_set_camera_info(self, request, response):
        try:
            calibration = _calibration_from_msg(request.camera_info, self._settings.camera_name)
            active = ActiveCalibration(calibration, calibration.camera(), 'set_camera_info',
                                       self._active.generation + 1, self._settings.rectify,
                                       self._settings.interpolation)
        except (CalibrationFileError, ValueError) as exc:
            response.success, response.status_message = False, f'rejected: {exc}'
            self.get_logger().warning(f'set_camera_info {response.status_message}')
            return response
        self._active = active
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
