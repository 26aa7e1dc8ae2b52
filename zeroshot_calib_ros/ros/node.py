"""ROS 2 node: CameraInfo from a camera's spec sheet, and optional live rectification.

    ros2 run zeroshot_calib_ros node --ros-args -p width:=1920 -p height:=1080 -p hfov:=118 -p vfov:=69

Only ROS plumbing lives here (parameters, topics, the service, QoS, timers, logging); every
computation is in ``zeroshot_calib_ros.core``, the node's own in rclpy-free collaborators in
``core/streaming/``: ``frame_path`` (a frame -> its CameraInfo bytes, its rectified bytes or why
it is skipped), ``map_requests`` (which maps are built when, and what a finished build means),
``calibration_cycle`` (which calibration is in force, the candidates from the spec, a file,
parameters, set_camera_info and refinement, the saves), ``refinement_control`` (the refiner's life
cycle) and ``diagnostics`` (the /diagnostics status and the state texts).

Threads: every ROS callback runs on the executor thread, and only there is the calibration in
force (``_active``) replaced. Rectification maps of a new calibration (parameter change,
set_camera_info) are built on a builder thread while frames keep the calibration in force; when
they are ready, a task on the executor (``executor.create_task``) swaps the new calibration in
on the executor thread. So a parameter change never stalls the stream, and every frame's
CameraInfo and image_rect come from one calibration. The executor is rclpy's
SingleThreadedExecutor, or its EventsExecutor with ZEROSHOT_CALIB_EXECUTOR=events (executors.py).

Lazy rectification: with rectify on, a frame is remapped only while image_rect has a subscriber
(the publisher's matched-subscription count, read per frame: a few microseconds, and exactly the
readers DDS would deliver that frame to), and no maps are built before one subscribes, as
image_proc does nothing until its output is subscribed. CameraInfo goes out with every frame
either way. When a subscriber appears (its match event, or the count read by the next frame), the
maps of the configured size and of the last frame's size are built at once, on every core; a
frame that comes while they are being built waits for them up to FIRST_FRAME_WAIT_SECONDS
(``map_requests``), so the first frame after a subscriber appears is rectified (with the
EventsExecutor there is no match event: the first frame starts the maps and waits). A
calibration adopted while nobody subscribes is in force at once (no maps to wait for). The start-up log and /diagnostics
(``rectify``, ``image_rect_subscribers``, ``frames_rectified``, ``frames_not_rectified_no_subscriber``)
say which state the node is in.

Frames (issue 14) are taken as the serialized bytes DDS delivered (``raw=True``): the Image header
is parsed in place (``core/ros_formats/cdr_image.py``), the pixels are viewed without a copy, remapped
into a reused buffer laid out as the serialized image_rect, and published as bytes, as is a
serialized CameraInfo whose stamp is patched. Frames that reader does not decode exactly as the
ROS deserializer would (another CDR encapsulation, unusual strings) are deserialized and take the
message path, counted (``frames_via_message_path``). The whole node takes the message path when
ZEROSHOT_CALIB_FRAME_PATH=message (the previous node, for comparisons) or on a big-endian host;
the start-up log and /diagnostics (``frame_path``) say which path is in use and why.
"""
from __future__ import annotations

import os
import sys
import time
from collections import Counter
from typing import Optional

# OpenCV's thread pool spins (busy-waits, sched_yield) around each parallel call before sleeping;
# with the image publisher and subscribers on the same few cores that steals their CPU (py-spy:
# 15 % of the node's samples in sched_yield; without the spinning the node sustained 26-38 % more
# frames per second at 1080p bgr8 on 2 cores). Read once, when cv2 loads, so set before the core
# modules import it; an environment that sets them wins.
for _name in ('OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER', 'OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN'):
    os.environ.setdefault(_name, '0')

import rclpy  # noqa: E402
import rclpy.executors  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rcl_interfaces.msg import SetParametersResult  # noqa: E402
from rclpy.event_handler import PublisherEventCallbacks  # noqa: E402
from rclpy.exceptions import ParameterException  # noqa: E402
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from sensor_msgs.srv import SetCameraInfo  # noqa: E402

from ..core.ros_formats.calibration_file import (CalibrationFileError, CameraCalibration,  # noqa: E402
                                              resolve_camera_info_url, summary_text)
from ..core.streaming.calibration_cycle import (REFINABLE_SOURCES, CalibrationCycle,  # noqa: E402
                                               refinement_texts, summary_warnings)
from ..core.ros_formats.cdr_image import CdrError, NotPlainCdr, parse_image, pixel_bytes  # noqa: E402
from ..core.streaming.diagnostics import calibration_status, frame_path_text, rectify_text  # noqa: E402
from ..core.streaming.frame_path import FramePath  # noqa: E402
from ..core.streaming.image_frames import (ActiveCalibration, FrameSkipped, MapBudgetExceeded,  # noqa: E402
                                          default_map_budget)
from ..core.streaming.heap import keep_frames_in_heap, resident_bytes  # noqa: E402
from ..core.streaming.map_builder import MapJob  # noqa: E402
from ..core.streaming.map_requests import MapRequests  # noqa: E402
from ..core.streaming.refinement_control import RefinementControl, refine_settings  # noqa: E402
from ..core.streaming.node_parameters import (CALIBRATION_PARAMETERS, PARAMETERS,  # noqa: E402
                                             RECTIFICATION_PARAMETERS, Settings, changed_parameters,
                                             number_in_range, params_file_errors,
                                             unknown_parameter_warnings,
                                             usage_text)
from ..core.zeroshot.solver import NoConvergence  # noqa: E402
from ..core.zeroshot.spec import SpecError, value_text  # noqa: E402
from .executors import create_executor, executor_choice, executor_text, spin  # noqa: E402
from .messages import calibration_from_camera_info, fill_camera_info, serialized_camera_info  # noqa: E402
from .parameter_service import AtomicParameterService, descriptor  # noqa: E402

NODE_NAME = 'zeroshot_calib'
IMAGE_IDLE_SECONDS = 1.0
"""Timer-driven CameraInfo resumes when no image arrived for this long."""
WARN_THROTTLE_SECONDS = 5.0
_WARNED_KEYS_KEPT = 64  # throttled warnings remembered (one key per frame size without a calibration)
OTHER_SIZE_IDLE_SECONDS = 10.0
"""Maps of a frame size other than the configured one are released after this long unused."""
SET_CAMERA_INFO_WAIT_SECONDS = 3.0
"""How long set_camera_info waits for the new calibration's maps (built on every core: frames
wait for the reply anyway) so that its "success" means in force; a larger calibration is
answered as accepted, with its maps being built, and saved when it is in force."""
FRAME_PATH_ENV = 'ZEROSHOT_CALIB_FRAME_PATH'
"""'serialized' (the default) or 'message': how frames are taken and published (see the module)."""
REFINE_PARAMETERS = ('refine', 'refine_interval')


def frame_path_choice(environ=os.environ) -> tuple:
    """(serialized: bool, why) of the frame path the environment and this host allow."""
    wanted = environ.get(FRAME_PATH_ENV, 'serialized').strip().lower() or 'serialized'
    if wanted == 'message':
        return False, f'{FRAME_PATH_ENV}=message'
    if sys.byteorder != 'little':
        return False, 'big-endian host (the serialized path writes little-endian pixels and CDR)'
    if wanted != 'serialized':
        return True, f'{FRAME_PATH_ENV}={wanted!r} is neither serialized nor message: serialized'
    return True, ''


def publish_serialized(publisher, buffer):
    """Publish a serialized message (``bytes`` or ``bytearray``) without another copy:
    rclpy's Publisher.publish takes ``bytes`` only, its handle's publish_raw a bytearray too
    (copied into the middleware before it returns, so the buffer can be reused)."""
    handle = publisher.handle
    with handle:
        handle.publish_raw(buffer)


class ZeroShotCalibNode(Node):
    """Publishes the zero-shot CameraInfo; rectifies image_raw into image_rect when asked."""

    def __init__(self, heap_text: str = 'allocator unchanged (the node was constructed outside main())',
                 executor_text: str = 'whichever spins the node (it was constructed outside main())',
                 matched_events: bool = True, **kwargs):
        super().__init__(NODE_NAME, start_parameter_services=False, **kwargs)
        self._heap_text = heap_text
        self._executor_text = executor_text
        # image_rect's matched-subscription events: not with the EventsExecutor, which has crashed
        # destroying a publisher with event callbacks while subscribers came and went (rclpy
        # issue 1644); the QoS matching destroys image_rect's publisher once a camera appears.
        # Without them, the first frame after a subscriber appears starts its maps and waits.
        self._matched_events = matched_events
        # Start-up (issue 14): what the first CameraInfo needs, then that CameraInfo, then the
        # map build, then the rest (services, the image endpoints, timers, the log: rclpy's
        # first log lines cost tens of ms each, so information lines wait until the CameraInfo
        # is out; warnings and errors do not, see _log).
        self._startup_log = []
        for name, parameter in PARAMETERS.items():
            self.declare_parameter(name, parameter.default, descriptor(parameter))
        # a misspelled -p rectfy:=true (command line or params file) would be ignored silently
        for text in unknown_parameter_warnings(getattr(self, '_parameter_overrides', None) or {}):
            self._log('warning', text)
        self._stats = Counter()
        self._warned_at = {}
        self._last_image_time = None  # time.monotonic() of the last frame
        # Until an image publisher is seen: reliable CameraInfo (what late joiners and the
        # default subscriber QoS want), best-effort image_raw (accepts either kind of publisher).
        self._reliability = ReliabilityPolicy.RELIABLE
        self._image_reliability = ReliabilityPolicy.BEST_EFFORT
        self._rect_pub = None
        self._rect_msg = Image()
        self._info_cache = (None, None)  # (calibration, its CameraInfo), reused frame after frame
        self._serialized, self._frame_path_reason = frame_path_choice()
        # the frame path's state: last frame size, uncalibrated frames, failed maps, reused buffers
        self._frames = FramePath(serialized_camera_info)
        self._reverting = False

        self._map_budget = number_in_range('max_map_memory_mb', self.get_parameter('max_map_memory_mb').value,
                                   0, 2**40, integer=True)
        self._map_budget_why = 'as set'
        if not self._map_budget:
            self._map_budget, self._map_budget_why = default_map_budget()
        settings = Settings.from_values(self._values())
        self._settings = settings
        # the refiner while refine is on: started, restarted and stopped with the newest calibration
        self._refinement = RefinementControl(*refine_settings(self._values()), log=self._log, due=self._due)
        url = self.get_parameter('camera_info_url').value
        # which calibration is in force, the newest accepted, pending saves, the last refinement
        self._cycle = CalibrationCycle(resolve_camera_info_url(url, settings.camera_name), self._map_budget_bytes)
        # The calibration is in force at once (CameraInfo needs no maps); its maps are built on
        # the builder thread, and frames that come before they are ready are not rectified.
        try:
            self._cycle.start(settings, self._log)
        except Exception:
            self._flush_startup_log()  # what was said before the failure
            raise
        self._cycle.values_in_force = self._values()
        self._create_info_publisher()
        # One at start-up whatever the camera does: transient local then holds a calibration for
        # late joiners even if a camera exists but has not sent a frame yet.
        self._publish_own_info()
        # The map builder (a low-priority thread); no maps yet: they are built when image_rect
        # gets a subscriber (lazy rectification, see the module's text).
        self._maps = MapRequests(self._frames, self._map_budget_bytes, self._log, self._on_maps_finished)

        self._parameter_service = AtomicParameterService(self)
        self._create_image_endpoints()
        self._set_camera_info_srv = self.create_service(SetCameraInfo, 'set_camera_info',
                                                        self._on_set_camera_info)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._rate = float(self.get_parameter('publish_rate').value)
        self._info_timer = self.create_timer(1.0 / self._rate, self._on_info_timer)
        self._housekeeping_timer = self.create_timer(1.0, self._on_housekeeping)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._flush_startup_log()
        self.get_logger().info(self._interfaces_text())
        self._follow_with_refiner(self._cycle.active)

    def _flush_startup_log(self):
        startup_log, self._startup_log = self._startup_log, None
        for level, text in startup_log or ():
            self._log(level, text)

    def _log(self, level: str, text: str):
        """Log now, or after the first CameraInfo while the node starts: only information waits;
        a warning or an error is logged at once, with what waited before it (in order), so it
        is in the log before the CameraInfo it concerns goes out. One call site per level:
        rclpy refuses another severity from a call site that logged once."""
        if self._startup_log is not None:
            self._startup_log.append((level, text))
            if level == 'info':
                return
            self._flush_startup_log()
        elif level == 'error':
            self.get_logger().error(text)
        elif level == 'warning':
            self.get_logger().warning(text)
        else:
            self.get_logger().info(text)

    @property
    def _map_budget_bytes(self) -> int:
        return int(self._map_budget) * 2**20

    # --- start-up -------------------------------------------------------------------------
    def _values(self, overrides=None) -> dict:
        values = {name: self.get_parameter(name).value for name in PARAMETERS}
        for p in overrides or ():
            values[p.name] = p.value
        return values

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
            f'  rectify    {self._rectify_text()}'
            f' (maps at most max_map_memory_mb = {self._map_budget}: {self._map_budget_why})',
            f'  calibration file: {self._cycle.file_state}',
            f'  frame path {self._frame_path_text()}',
            f'  executor   {self._executor_text}',
            f'  memory     {self._heap_text}',
        ])

    def _rectify_text(self) -> str:
        return rectify_text(self._cycle.active.rectify_enabled, self._maps.subscribers, self._maps.ever_subscribed)

    def _frame_path_text(self) -> str:
        return frame_path_text(self._serialized, self._frame_path_reason)

    def _create_endpoints(self):
        """Publishers and subscription with the reliability of the image publisher (see housekeeping)."""
        self._create_info_publisher()
        self._create_image_endpoints()

    def _create_info_publisher(self):
        info_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=self._reliability,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._info_pub = self.create_publisher(CameraInfo, 'camera_info', info_qos)

    def _create_image_endpoints(self):
        self._sync_rect_publisher()
        # depth 10 on the way in: a frame that takes long to arrive (a 30 MB one takes ~0.3 s
        # through DDS) must not push the frames queued behind it out of the reader's history
        image_qos = self._image_qos(self._image_reliability, depth=10)
        if self._serialized:
            try:
                self._image_sub = self.create_subscription(Image, 'image_raw', self._on_serialized_image,
                                                           image_qos, raw=True)
                return
            except TypeError:  # an rclpy without raw subscriptions
                self._serialized, self._frame_path_reason = False, 'this rclpy has no raw subscriptions'
                self.get_logger().warning(f'frame path {self._frame_path_text()}')
        self._image_sub = self.create_subscription(Image, 'image_raw', self._on_image, image_qos)

    def _sync_rect_publisher(self):
        """image_rect is advertised only while rectify is on (it would collide with image_proc's)."""
        if self._cycle.active.rectify_enabled and self._rect_pub is None:
            # matched: a subscriber's arrival starts its maps before the next frame comes
            events = PublisherEventCallbacks(matched=self._on_rect_matched) if self._matched_events else None
            self._rect_pub = self.create_publisher(Image, 'image_rect', self._image_qos(self._reliability),
                                                   event_callbacks=events)
        elif not self._cycle.active.rectify_enabled and self._rect_pub is not None:
            self.destroy_publisher(self._rect_pub)
            self._rect_pub = None
        self._rect_has_subscriber()

    # --- lazy rectification: remap only while image_rect has a subscriber --------------------
    def _on_rect_matched(self, _status):
        self._rect_has_subscriber()

    def _rect_has_subscriber(self) -> bool:
        """Whether image_rect has a subscriber now (its matched-subscription count, read per frame:
        a few microseconds); when the first one appears, ``MapRequests`` builds the maps at once."""
        pub = self._rect_pub
        return self._maps.subscribers_now(pub.get_subscription_count() if pub is not None else 0,
                                          self._cycle.active, self._cycle.newest)

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
        fill_camera_info(msg, self._cycle.active.calibration)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.get_parameter('frame_id').value
        self._info_pub.publish(msg)

    def _on_image(self, msg: Image):
        """The message path: a deserialized sensor_msgs/Image."""
        self._stats['frames_received'] += 1
        self._last_image_time = time.monotonic()
        self._process_message(msg)

    def _process_message(self, msg: Image):
        active = self._cycle.active  # one snapshot per frame: CameraInfo and image_rect agree
        calibration = self._frame_calibration(active, msg.width, msg.height, msg.step, msg.encoding, len(msg.data))
        if calibration is None:
            return
        info = self._camera_info_for(calibration)
        info.header = msg.header
        self._info_pub.publish(info)
        self._stats['camera_info_published'] += 1
        if self._refinement.refiner is not None:
            self._offer_frame(msg.data, msg.width, msg.height, msg.step, msg.encoding, msg.is_bigendian, copy=True)
        rectifier = self._frame_rectifier(active, calibration, msg.width, msg.height)
        if rectifier is None:
            return
        try:
            self._publish_rectified(msg, rectifier)
        except FrameSkipped as exc:
            self._skip(exc)
        except Exception as exc:
            self._skip(FrameSkipped('error', f'cannot rectify frame: {exc}'))

    def _on_serialized_image(self, raw: bytes):
        """The serialized path: the CDR bytes of a sensor_msgs/Image, read in place."""
        self._stats['frames_received'] += 1
        self._last_image_time = time.monotonic()
        try:
            header = parse_image(raw)
        except NotPlainCdr as exc:
            self._via_message_path(raw, exc)
            return
        except CdrError as exc:
            self._skip(FrameSkipped('malformed', str(exc)))
            return
        active = self._cycle.active  # one snapshot per frame: CameraInfo and image_rect agree
        width, height = header.width, header.height
        calibration = self._frame_calibration(active, width, height, header.step, header.encoding, header.data_size)
        if calibration is None:
            return
        publish_serialized(self._info_pub, self._frames.serialized_info(calibration, header))
        self._stats['camera_info_published'] += 1
        if self._refinement.refiner is not None:  # raw is an immutable bytes object: its pixels are held, not copied
            self._offer_frame(pixel_bytes(raw, header), width, height, header.step, header.encoding,
                              header.is_bigendian, copy=False)
        rectifier = self._frame_rectifier(active, calibration, width, height)
        if rectifier is None:
            return
        try:
            self._publish_rectified_serialized(raw, header, rectifier)
        except FrameSkipped as exc:
            self._skip(exc)
        except Exception as exc:
            self._skip(FrameSkipped('error', f'cannot rectify frame: {exc}'))

    def _via_message_path(self, raw: bytes, why: Exception):
        """A frame the serialized reader does not decode exactly: deserialized, then as before."""
        from rclpy.serialization import deserialize_message
        try:
            msg = deserialize_message(raw, Image)
        except Exception as exc:  # what the middleware cannot read either
            self._skip(FrameSkipped('malformed', f'serialized Image cannot be deserialized ({why}): {exc}'))
            return
        self._stats['frames_via_message_path'] += 1
        if self._due('message_path'):
            self.get_logger().info(f'frame taken on the message path: {why} '
                                   f'[{self._stats["frames_via_message_path"]} so far]')
        self._process_message(msg)

    def _frame_calibration(self, active: ActiveCalibration, width: int, height: int, step: int, encoding: str,
                           nbytes: int) -> Optional[CameraCalibration]:
        """The calibration of a frame, or None (skipped and counted)."""
        try:
            return self._frames.calibration(active, width, height, step, encoding, nbytes)
        except FrameSkipped as exc:
            if exc.reason == 'aspect':  # said for each size (throttled), and an ERROR in /diagnostics
                if len(self._warned_at) > _WARNED_KEYS_KEPT:  # a stream of ever new sizes
                    self._warned_at.clear()
                self._skip(exc, key=f'aspect {width}x{height}')
            else:
                self._skip(exc)
        return None

    def _frame_rectifier(self, active: ActiveCalibration, calibration: CameraCalibration, width: int, height: int):
        """The built rectifier of a frame, or None (not rectifying, or skipped and counted)."""
        if not active.rectify_enabled or self._rect_pub is None:
            return None
        if not self._rect_has_subscriber():
            self._stats['frames_not_rectified_no_subscriber'] += 1
            return None
        try:
            return self._maps.rectifier(active, calibration, width, height)
        except FrameSkipped as exc:
            self._skip(exc)
        return None

    def _camera_info_for(self, calibration: CameraCalibration) -> CameraInfo:
        """The CameraInfo of ``calibration``, filled once and reused (only the header changes;
        publish() serialises the message before it returns)."""
        cached_calibration, info = self._info_cache
        if cached_calibration is not calibration:
            info = CameraInfo()
            fill_camera_info(info, calibration)
            self._info_cache = (calibration, info)
        return info

    def _publish_rectified_serialized(self, raw: bytes, header, rectifier):
        publish_serialized(self._rect_pub, self._frames.rectified_serialized(raw, header, rectifier))
        self._stats['frames_rectified'] += 1

    def _publish_rectified(self, msg: Image, rectifier):
        data, height, width, step = self._frames.rectified_pixels(msg.data, msg.width, msg.height, msg.step,
                                                                  msg.encoding, msg.is_bigendian, rectifier)
        rect = self._rect_msg
        rect.header = msg.header
        rect.height, rect.width = height, width
        rect.encoding = msg.encoding
        rect.is_bigendian = 0
        rect.step = step
        rect.data = data
        self._rect_pub.publish(rect)
        self._stats['frames_rectified'] += 1

    def _skip(self, exc: FrameSkipped, key: Optional[str] = None):
        self._stats[f'frames_skipped_{exc.reason}'] += 1
        if self._due(key or exc.reason):
            self.get_logger().warning(f'frame skipped ({exc.reason}): {exc} '
                                      f'[{self._stats[f"frames_skipped_{exc.reason}"]} so far]')

    def _due(self, key: str) -> bool:
        """Whether a log line about ``key`` is due (at most one every WARN_THROTTLE_SECONDS)."""
        now = self.get_clock().now().nanoseconds
        last = self._warned_at.get(key)
        if last is None or now - last > WARN_THROTTLE_SECONDS * 1e9:
            self._warned_at[key] = now
            return True
        return False

    # --- housekeeping: QoS matching, memory and diagnostics ---------------------------------
    def _on_housekeeping(self):
        self._on_calibration_built()  # maps that finished before the node was added to an executor
        self._match_image_reliability()
        self._rect_has_subscriber()
        self._maps.release_unused(self._cycle.active, OTHER_SIZE_IDLE_SECONDS)
        self._poll_refiner()
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
        if self._frames.uncalibrated is not None and not self._camera_exists():
            self._frames.uncalibrated = None  # the camera has stopped
        pending = self._maps.pending
        state = calibration_status(
            self.get_name(), self._cycle.active, serialized=self._serialized, frame_path_reason=self._frame_path_reason,
            executor=self._executor_text, rectify=self._rectify_text(), rect_subscribers=self._maps.subscribers,
            qos_reliability=self._reliability.name, pending_generation=pending.active.generation if pending else '',
            maps_build_ms=self._maps.maps_build_ms, process_rss_bytes=resident_bytes(),
            refine=self._refinement.diagnostics(),
            stats=self._stats, uncalibrated=self._frames.uncalibrated)
        status = DiagnosticStatus(level=getattr(DiagnosticStatus, state.level), name=state.name,
                                  hardware_id=state.hardware_id, message=state.message,
                                  values=[KeyValue(key=k, value=str(v)) for k, v in state.values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(msg)

    # --- changes at run time --------------------------------------------------------------
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        if self._reverting:  # restoring the values in force (see _calibration_failed)
            return SetParametersResult(successful=True)
        # A change is a change only where a value differs (ros2 param load of a dump, or set to
        # the value in force, changes nothing: a calibration from a file or set_camera_info stays)
        changed = set(changed_parameters(self._values(), [(p.name, p.value) for p in parameters]))
        parameters = [p for p in parameters if p.name in changed]
        if not parameters:
            return SetParametersResult(successful=True)
        names = {p.name for p in parameters}
        refine_values = None
        if names & set(REFINE_PARAMETERS):
            try:
                refine_values = refine_settings(self._values(parameters))
            except SpecError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        if not names & set(CALIBRATION_PARAMETERS + RECTIFICATION_PARAMETERS):
            if refine_values is not None:
                self._set_refine(*refine_values)
            return SetParametersResult(successful=True)
        # Checked and solved here, whole (a rejection must name its reason, and a success means
        # adopted); the maps are built on the builder thread and swapped in when ready.
        values = self._values(parameters)
        try:
            settings, active, summary = self._cycle.for_parameters(names, values)
        except (SpecError, CalibrationFileError, NoConvergence, ValueError) as exc:
            reason = str(exc)
            if len(reason) > 1000:  # a message quoting a huge value: cut like one
                reason = value_text(reason, 300)
            if self._due(f'rejected {sorted(names)}'):  # rejected again soon: not logged again
                self.get_logger().warning(f'parameter change rejected, calibration unchanged: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        except Exception as exc:  # never let a parameter value take the node down
            reason = f'cannot calibrate with these values: {type(exc).__name__}: {value_text(str(exc), 300)}'
            if self._due(f'rejected {sorted(names)}'):
                self.get_logger().error(f'parameter change rejected, calibration unchanged: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        self._settings = settings
        if refine_values is not None:
            self._refinement.configure(*refine_values)
        changed = ', '.join(f'{p.name}={value_text(p.value)}' for p in parameters)
        self._adopt(active, f'parameters changed ({changed}), re-solved:\n' + summary_text(summary)
                    if summary else f'parameters changed ({changed})', values)
        for warning in summary_warnings(summary):
            self._log('warning', warning)
        return SetParametersResult(successful=True)

    # --- calibrations swapped in when their maps are ready --------------------------------
    def _adopt(self, active: ActiveCalibration, log: str, values: Optional[dict] = None,
               every_core: bool = False) -> MapJob:
        """``active`` in force once its maps are built (at once without rectification). Later
        changes build on it (``_newest``) even before it is in force."""
        self._cycle.accept(active)
        self._follow_with_refiner(active)
        job = MapJob(active, log, values=values if values is not None else self._values())
        if not active.rectify_enabled or not self._rect_has_subscriber():
            # nothing to build (rectify off, or nobody subscribes to image_rect: its maps are
            # built when someone does): in force at once
            self._swap_in(job)
            job.finished.set()
            return job
        streaming = self._last_image_time is not None and \
            time.monotonic() - self._last_image_time < IMAGE_IDLE_SECONDS
        self._maps.submit(job, streaming, every_core)
        return job

    def _on_maps_finished(self):
        """Builder thread: a map build ended; the executor thread takes it (a task: both executors
        take one from any thread; before the node is added to one, housekeeping takes it)."""
        executor = self.executor
        if executor is None:
            return
        try:
            executor.create_task(self._on_calibration_built)
        except Exception:  # shutting down
            pass

    def _on_calibration_built(self):
        """Executor thread: the map builds that ended, as ``MapRequests.route`` says."""
        for job in self._maps.take_finished():
            route = self._maps.route(job, self._cycle.active)
            if route == 'size_failed':
                self._stats['size_maps_failed'] += 1
            elif route == 'failed':
                self._calibration_failed(job)
            elif route == 'swap_in':
                self._swap_in(job)

    def _calibration_failed(self, job: MapJob):
        """Maps of an accepted change could not be built (e.g. memory): the calibration in force
        stays, and so that get_parameters, CameraInfo and the log agree, the parameters go back
        to the values in force."""
        self._stats['calibration_build_failed'] += 1
        self._drop_pending_save(job.active.generation, f'building its maps failed: {job.error!r}')
        if not self._cycle.build_failed(job.active):
            self.get_logger().warning(f'calibration (generation {job.active.generation}) not adopted, '
                                      f'building its maps failed: {job.error!r}; a newer change is pending')
            return
        restore = [Parameter(name, value=value) for name, value in self._cycle.values_to_restore(self._values()).items()]
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

    def _swap_in(self, job: MapJob):
        if not self._cycle.swap_in(job.active, job.values):
            return  # superseded while it was built
        self._frames.failed_maps.clear()
        self._stats['calibrations_adopted'] += 1
        self._sync_rect_publisher()
        if job.log:
            self.get_logger().info(job.log)
        self._on_info_timer()  # late joiners see the change at once (unless a camera publishes)
        said = self._cycle.save_in_force(job.active)
        if said is not None and said[1] is not None:
            self._log(*said)

    def _drop_pending_save(self, generation: int, why: str):
        text = self._cycle.drop_pending_save(generation, why)
        if text is not None:
            self.get_logger().warning(text)

    def destroy_node(self):
        maps = getattr(self, '_maps', None)
        if maps is not None:
            maps.stop()
        refinement = getattr(self, '_refinement', None)
        if refinement is not None:
            refinement.shutdown()
        return super().destroy_node()

    # --- refine: the calibration refined from straight lines in the frames ------------------
    def _set_refine(self, refine: bool, interval: float):
        self._refinement.configure(refine, interval)
        self._follow_with_refiner(self._cycle.newest)

    def _follow_with_refiner(self, active: ActiveCalibration):
        self._refinement.follow(active, self._settings.spec, self._cycle.refined)

    def _offer_frame(self, data, width: int, height: int, step: int, encoding: str, is_bigendian: bool, copy: bool):
        """Frame callback: a comparison unless the refiner takes this frame."""
        if self._refinement.offer(data, width, height, step, encoding, is_bigendian, copy, time.monotonic()):
            self._stats['refine_frames_sampled'] += 1

    def _poll_refiner(self):
        """Housekeeping: log the refiner's state changes; adopt an accepted refinement."""
        result = self._refinement.poll()
        if result is not None:
            self._adopt_refinement(result)

    def _adopt_refinement(self, result):
        basis = self._cycle.newest
        if basis.source not in REFINABLE_SOURCES:  # stopped refiners give no result; defensive
            self.get_logger().info(f'refined calibration discarded: the calibration is from {basis.source}')
            return
        try:
            active, fit_error_px = self._cycle.for_refinement(result.camera, self._settings)
        except (CalibrationFileError, MapBudgetExceeded, ValueError) as exc:
            self.get_logger().warning(f'refined calibration not adopted: {exc}')
            return
        for level, text in refinement_texts(result, basis, active, fit_error_px):
            self._log(level, text)
        saved_ok, saved = self._cycle.save(active.calibration)
        if not saved_ok:
            self.get_logger().warning(f'refined calibration {saved}')
        self._cycle.refined = (result.camera, result.status.uncertainty_px)
        self._adopt(active, f'refined calibration adopted (generation {active.generation}, source refined), '
                    f'{saved}')

    def _on_set_camera_info(self, request, response):
        """As camera drivers offer it to cameracalibrator: validated whole (plausibility, and the
        maps' memory with rectify on), adopted, and saved to camera_info_url once in force.
        "success" with "adopted and saved" means in force and saved, as camera_info_manager
        answers: the maps are built before the reply (up to SET_CAMERA_INFO_WAIT_SECONDS, on every
        core); a calibration whose maps take longer is answered as accepted with its maps being
        built, goes into force and is saved when they are (the log says so). Nothing is saved for
        a calibration that does not go into force."""
        try:
            calibration = calibration_from_camera_info(request.camera_info, self._settings.camera_name)
            active = self._cycle.for_camera_info(calibration, self._settings)
        except (CalibrationFileError, ValueError) as exc:
            response.success, response.status_message = False, f'rejected, calibration unchanged: {exc}'
            self.get_logger().warning(f'set_camera_info {response.status_message}')
            return response
        except Exception as exc:  # never let a request take the node down
            response.success, response.status_message = False, f'rejected, calibration unchanged: {exc!r}'
            self.get_logger().error(f'set_camera_info {response.status_message}')
            return response
        self._cycle.save_when_in_force = None  # a newer request replaces an older one still building
        start = time.monotonic()
        job = self._adopt(active, 'calibration from set_camera_info adopted', every_core=True)
        job.finished.wait(SET_CAMERA_INFO_WAIT_SECONDS)
        if job.finished.is_set() and job.error is None and not job.superseded:
            self._swap_in(job)  # in force now (a no-op when it already is)
            response.success, saved = self._cycle.save_camera_info(calibration)
            response.status_message = f'calibration adopted{saved}'
        elif job.finished.is_set():
            why = f'building its rectification maps failed: {job.error!r}' if job.error is not None \
                else 'a newer calibration replaced it'
            response.success = False
            response.status_message = f'not adopted, calibration unchanged: {why}; nothing saved'
        else:
            self._cycle.save_when_in_force = (calibration, active.generation)
            response.success = True
            response.status_message = (
                f'calibration accepted, not in force yet: its rectification maps of {active.size[0]}x'
                f'{active.size[1]} are being built ({time.monotonic() - start:.1f} s so far); it goes '
                f'into force and is saved to {self._cycle.url_path} when they are (the log says so)')
        self.get_logger().info(f'set_camera_info: {response.status_message}')
        return response


def main(args=None):
    """The node's executable. Ctrl-C at any moment ends it quietly with status 0 (including while
    it starts: rclpy then shuts its context down under the node being built)."""
    try:
        return _main(args)
    except KeyboardInterrupt:
        return 0


def _main(args):
    argv = sys.argv[1:] if args is None else list(args[1:])
    user_args = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in user_args or '--help' in user_args:
        print(usage_text())
        return 0
    errors = params_file_errors(argv)
    if errors:  # rcl would end in a traceback naming the whole argument
        for error in errors:
            print(f'{NODE_NAME}: error: {error}', file=sys.stderr)
        return 2
    # Process-wide, before rclpy allocates: frame-sized blocks stay in the heap (no page faults per frame)
    heap_text = keep_frames_in_heap()
    try:
        rclpy.init(args=args)
    except _rclpy.RCLError as exc:  # arguments rcl cannot parse (it has logged its own line before)
        print(f'{NODE_NAME}: error: {str(exc).splitlines()[0]}', file=sys.stderr)
        return 2
    choice, asked = executor_choice()
    node = None
    try:
        executor, name, why = create_executor(choice)
        why = why or asked
        node = ZeroShotCalibNode(heap_text=heap_text, executor_text=executor_text(name, why),
                                 matched_events=name != 'events')
    except (SpecError, CalibrationFileError, ParameterException) as exc:
        print(f'{NODE_NAME}: error: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    except Exception:
        if not rclpy.ok():  # Ctrl-C while starting: the context was shut down under the node
            return 0
        raise
    if why and name == 'single':  # a value that names no executor, or no EventsExecutor in this rclpy
        node.get_logger().warning(f'executor: {why}')
    try:
        executor.add_node(node)
        spin(executor, name)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
