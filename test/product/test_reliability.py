"""Reliability (issue #6): bad parameter values, malformed frames, and streams that change under
the node never crash it, never give a non-finite CameraInfo, and never pair a frame with the
wrong calibration.

The bulk is ROS-free and property-based (hypothesis) against the code the node runs
(``Settings.from_values``, ``solve_from_settings``, ``image_array``, ``ActiveCalibration``); a
smaller set goes through the installed node in its own process.
"""
import math
import threading
import time

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from hypothesis import HealthCheck, given, settings, strategies as st
from rcl_interfaces.srv import SetParameters, SetParametersAtomically
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from ros_peer import (diagnostics_value, domain_id, image_msg, parameter_msg, peer, qos,  # noqa: F401
                      start_node)
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CalibrationFileError, CameraCalibration
from zeroshot_calib_ros.core.streaming.image_frames import ENCODINGS, ActiveCalibration, FrameSkipped, image_array
from zeroshot_calib_ros.core.zeroshot.solver import PROJECTION_CHOICES, NoConvergence
from zeroshot_calib_ros.core.zeroshot.spec import SpecError
from zeroshot_calib_ros.core.streaming.node_parameters import PARAMETERS, Settings, solve_from_settings
from zeroshot_calib_ros.ros.messages import fill_camera_info

EXPECTED_REJECTIONS = (SpecError, CalibrationFileError, NoConvergence, ValueError)
DEFAULTS = {name: parameter.default for name, parameter in PARAMETERS.items()}
NUMERIC = ('width', 'height', 'hfov', 'vfov', 'dfov', 'balance', 'fov_scale', 'publish_rate')
INT64 = st.integers(-2 ** 63, 2 ** 63 - 1)


# --- parameter values: ROS-free, the node's own checking and solving ----------------------------
def any_parameter_value():
    """What a ROS parameter of any type can hold (rclpy's types, int64 integers)."""
    scalar = st.one_of(st.floats(allow_nan=True, allow_infinity=True), INT64, st.booleans(),
                       st.text(max_size=6), st.sampled_from(['118', 'nan', 'inf', '', 'equidistant']))
    arrays = st.one_of(st.lists(INT64, max_size=3), st.lists(st.floats(), max_size=3),
                       st.lists(st.booleans(), max_size=3), st.lists(st.text(max_size=3), max_size=3),
                       st.lists(st.binary(min_size=1, max_size=1), max_size=3))
    return st.one_of(scalar, arrays, st.none())


def number():
    """Numbers around the edges: NaN, inf, negative, zero, huge, and plausible values."""
    return st.one_of(st.floats(allow_nan=True, allow_infinity=True), INT64,
                     st.sampled_from([0, 0.0, -0.0, -1, 1e-300, 1e308, 179.999, 180, 180.0, 359.99, 360,
                                      1, 10, 0.5, 1.0, 100000, 100001]),
                     st.floats(0, 400), st.integers(0, 400))


@st.composite
def parameter_sets(draw):
    values = dict(DEFAULTS)
    # a camera that is valid to start with, then disturbed
    width = draw(st.sampled_from([64, 640, 1920, 1080, 3840, 1000]))
    height = draw(st.sampled_from([36, 480, 1080, 1920, 2160, 1000]))
    values.update(width=width, height=height, hfov=draw(st.floats(20, 200)), vfov=draw(st.floats(10, 200)),
                  dfov=draw(st.sampled_from([0.0, 0.0, draw(st.floats(20, 359))])),
                  projection=draw(st.sampled_from(PROJECTION_CHOICES)),
                  distortion_model=draw(st.sampled_from(['equidistant', 'plumb_bob'])),
                  balance=draw(st.floats(0, 1)), fov_scale=draw(st.floats(0.1, 10)),
                  rectify=draw(st.booleans()))
    for name in draw(st.sets(st.sampled_from(sorted(PARAMETERS)), max_size=3)):
        values[name] = draw(number() if name in NUMERIC else any_parameter_value())
    if draw(st.booleans()):
        values[draw(st.sampled_from(NUMERIC))] = draw(any_parameter_value())
    return values


def _finite_camera_info(calibration):
    msg = CameraInfo()
    fill_camera_info(msg, calibration)
    return all(math.isfinite(v) for v in (*msg.k, *msg.d, *msg.r, *msg.p)) and msg.k[0] > 0 and msg.k[4] > 0


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(parameter_sets())
def test_any_parameter_values_are_rejected_with_a_reason_or_give_a_valid_calibration(values):
    try:
        settings_ = Settings.from_values(values)
        active, summary = solve_from_settings(settings_, 1, build_maps=False)
    except EXPECTED_REJECTIONS as exc:
        text = str(exc)
        assert text.strip(), repr(exc)  # the reason given to the user
        if isinstance(exc, SpecError):
            assert all(name in PARAMETERS for name in exc.field.split(', ')), exc.field
            assert (f'{exc.field} = ' in text or f'{exc.field} is not given: ' in text) and 'allowed' in text
        return
    cal = active.calibration
    assert (cal.width, cal.height) == (settings_.spec.width, settings_.spec.height)
    assert _finite_camera_info(cal)
    assert np.all(np.isfinite(cal.P)) and cal.P[0, 0] > 0 and cal.P[1, 1] > 0
    assert summary['f'] > 0 and math.isfinite(summary['f'])


@pytest.mark.parametrize('name, value, fragment', [
    ('hfov', float('nan'), 'hfov = nan'), ('hfov', float('inf'), 'hfov = inf'), ('vfov', -5.0, 'vfov = -5.0'),
    ('hfov', 360.0, 'hfov = 360.0'), ('hfov', True, 'hfov = True'), ('vfov', '69', "vfov = '69'"),
    ('hfov', [118.0], 'hfov = [118.0]'), ('width', 0, 'width = 0'), ('width', 1920.5, 'width = 1920.5'),
    ('width', 10 ** 12, 'width = 1000000000000'), ('height', [1080], 'height = [1080]'),
    ('balance', float('nan'), 'balance = nan'), ('fov_scale', 0.0, 'fov_scale = 0.0'),
    ('fov_scale', -1, 'fov_scale = -1'), ('publish_rate', 0.0, 'publish_rate = 0.0'),
    ('interpolation', 3, 'interpolation = 3'), ('interpolation', [1], 'interpolation = [1]'),
    ('interpolation', True, 'interpolation = True'), ('rectify', 'false', "rectify = 'false'"),
    ('projection', ['equidistant'], "projection = ['equidistant']"), ('projection', 'fish', "projection = 'fish'"),
    ('distortion_model', 5, 'distortion_model = 5'), ('camera_name', 7, 'camera_name = 7'),
])
def test_each_bad_value_is_rejected_naming_it(name, value, fragment):
    values = dict(DEFAULTS, width=1920, height=1080, hfov=118.0, vfov=69.0)
    values[name] = value
    with pytest.raises(SpecError) as info:
        Settings.from_values(values)
    assert fragment in str(info.value) and 'allowed' in str(info.value)


@pytest.mark.parametrize('fovs, must_reject', [
    (dict(hfov=118.0, vfov=69.0, dfov=100.0), True),   # diagonal narrower than the horizontal
    (dict(hfov=118.0, vfov=69.0, dfov=69.0), True),
    (dict(hfov=118.0, dfov=118.0), True),
    (dict(hfov=60.0, vfov=90.0), True),                # vertical wider than horizontal on 16:9: looks swapped
    (dict(hfov=170.0, vfov=20.0, dfov=171.0), False),  # wildly different
    (dict(vfov=150.0, dfov=151.0), False),
])
def test_inconsistent_fov_triples_are_rejected_or_valid(fovs, must_reject):
    values = {**DEFAULTS, 'width': 1920, 'height': 1080, 'hfov': 0.0, 'vfov': 0.0, 'dfov': 0.0,
              'rectify': True, **fovs}
    try:
        active, _ = solve_from_settings(Settings.from_values(values), 1, build_maps=False)
    except EXPECTED_REJECTIONS as exc:
        assert must_reject, (fovs, exc)  # a valid triple must give a camera
        assert str(exc).strip()
        return
    assert not must_reject, fovs
    assert _finite_camera_info(active.calibration)


@settings(max_examples=60, deadline=None)
@given(projection=st.sampled_from(PROJECTION_CHOICES), hfov=st.floats(90.0, 359.9),
       ratio=st.floats(0.3, 0.95), distortion_model=st.sampled_from(['equidistant', 'plumb_bob']))
def test_fov_beyond_a_models_limit_is_rejected_or_valid(projection, hfov, ratio, distortion_model):
    """Every projection asked for more than it can show: a reason, or a finite calibration."""
    values = dict(DEFAULTS, width=1920, height=1080, hfov=hfov, vfov=hfov * ratio, projection=projection,
                  distortion_model=distortion_model, rectify=True)
    try:
        active, _ = solve_from_settings(Settings.from_values(values), 1, build_maps=False)
    except EXPECTED_REJECTIONS as exc:
        assert str(exc).strip(), repr(exc)
        return
    assert _finite_camera_info(active.calibration)


# --- frames: ROS-free ----------------------------------------------------------------------------
def _reference_decode(data, width, height, step, encoding, big_endian):
    dtype, channels = ENCODINGS[encoding]
    rows = [np.frombuffer(bytes(data[r * step:r * step + width * channels * dtype.itemsize]),
                          dtype.newbyteorder('>' if big_endian else '<')) for r in range(height)]
    out = np.stack(rows).reshape(height, width, channels).astype(dtype)
    return out if channels > 1 else out[..., 0]


@st.composite
def image_fields(draw):
    encoding = draw(st.one_of(st.sampled_from(sorted(ENCODINGS)),
                              st.sampled_from(['bayer_rggb8', 'yuv422', '8UC3', '', 'BGR8', 'mono8 '])))
    width, height = draw(st.integers(0, 12)), draw(st.integers(0, 9))
    dtype, channels = ENCODINGS.get(encoding, (np.dtype(np.uint8), 1))
    row = width * channels * dtype.itemsize
    step = draw(st.one_of(st.just(row), st.integers(row, row + 9), st.integers(0, 200)))
    exact = step * height
    length = draw(st.one_of(st.just(exact), st.just(exact), st.integers(0, exact + 20)))
    data = draw(st.binary(min_size=length, max_size=length))
    return data, width, height, step, encoding, draw(st.booleans())


@settings(max_examples=600, deadline=None)
@given(image_fields())
def test_image_array_reads_or_skips_every_message(fields):
    data, width, height, step, encoding, big_endian = fields
    try:
        view = image_array(data, width, height, step, encoding, big_endian)
    except FrameSkipped as exc:
        assert exc.reason in ('encoding', 'malformed') and str(exc)
        if exc.reason == 'encoding':
            assert encoding not in ENCODINGS
        return
    assert encoding in ENCODINGS and width > 0 and height > 0 and len(data) == step * height
    dtype, channels = ENCODINGS[encoding]
    assert view.shape == ((height, width) if channels == 1 else (height, width, channels))
    assert view.dtype == dtype and view.dtype.isnative
    np.testing.assert_array_equal(view, _reference_decode(data, width, height, step, encoding, big_endian))


def test_big_endian_16_bit_is_converted_not_skipped():
    values = (np.arange(12).reshape(3, 4) * 1000).astype('>u2')
    view = image_array(values.tobytes(), 4, 3, 8, 'mono16', True)
    assert view.dtype == np.uint16 and view.dtype.isnative
    np.testing.assert_array_equal(view, values.astype(np.uint16))


@pytest.fixture(scope='module')
def small_camera():
    solution = solve_zero_shot(CameraSpec(64, 36, 118, 69))
    calibration, _ = CameraCalibration.from_solution(solution, balance=0.5)
    return calibration, solution.camera


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(sizes=st.lists(st.one_of(st.tuples(st.integers(-1, 200), st.integers(-1, 120)),
                                st.integers(0, 12).map(lambda k: (16 * k, 9 * k))), min_size=1, max_size=8))
def test_for_size_gives_scaled_calibrations_or_skips(small_camera, sizes):
    calibration, camera = small_camera
    active = ActiveCalibration(calibration, camera, 'spec', 3, rectify=True, build_maps=False)
    for width, height in sizes:
        try:
            cal, rectifier = active.for_size(width, height)
        except FrameSkipped as exc:
            assert exc.reason in ('malformed', 'aspect')
            assert width <= 0 or height <= 0 or width * 36 != height * 64
            continue
        assert width * 36 == height * 64 and (cal.width, cal.height) == (width, height)
        assert cal.K[0, 0] == pytest.approx(calibration.K[0, 0] * width / 64)
        assert cal.P[0, 0] == pytest.approx(calibration.P[0, 0] * width / 64)
        assert rectifier.size == (width, height) and rectifier.map1.shape[:2] == (height, width)
        assert active.for_size(width, height)[1] is rectifier  # built once
        assert len(active._rectifiers) <= 4
    assert active.calibration is calibration and active.generation == 3


def test_for_size_builds_once_when_asked_from_two_threads(small_camera):
    calibration, camera = small_camera
    active = ActiveCalibration(calibration, camera, 'spec', rectify=True, build_maps=False)
    assert not active.prepared
    results = []
    threads = [threading.Thread(target=lambda: results.append(active.for_size(640, 360))) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len({id(r[1]) for r in results}) == 1
    assert active.prepare() is active and active.prepared


def test_singular_rectified_camera_is_rejected_before_maps_whatever_rectify_is(small_camera):
    calibration, camera = small_camera
    # refused whatever rectify is: a calibration adopted (and saved) with rectify off must still
    # work after rectify is turned on, and load again
    with pytest.raises(CalibrationFileError, match=r'P \(projection_matrix\)'):
        CameraCalibration(64, 36, calibration.K, calibration.distortion_model, calibration.D,
                          np.eye(3), np.zeros((3, 4)))


# --- through the node ------------------------------------------------------------------------------
def stamp_of(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def finite_info(msg):
    return all(math.isfinite(v) for v in (*msg.k, *msg.d, *msg.r, *msg.p))


class Streamer:
    """Publishes one frame on image_raw every ``period`` s from the peer's executor (so frames
    keep flowing while the peer waits for a service)."""

    def __init__(self, peer, image, encoding, period=1 / 30, reliability=ReliabilityPolicy.RELIABLE):
        self.peer, self.image, self.encoding = peer, image, encoding
        self.sent = []
        self.pub = peer.node.create_publisher(Image, 'image_raw', qos(reliability, depth=5))
        self.timer = peer.node.create_timer(period, self._tick)

    def _tick(self):
        stamp = time.time_ns()
        self.pub.publish(image_msg(self.image, self.encoding, stamp))
        self.sent.append(stamp)

    def stop(self):
        self.peer.node.destroy_timer(self.timer)
        self.peer.node.destroy_publisher(self.pub)


SMALL = ['--ros-args', '-p', 'width:=320', '-p', 'height:=180', '-p', 'hfov:=118', '-p', 'vfov:=69',
         '-p', 'rectify:=true']


def test_bad_parameters_through_the_node_never_stop_it(peer, start_node):
    node = start_node(*SMALL)
    best_effort = qos(ReliabilityPolicy.BEST_EFFORT, depth=50)
    infos = peer.collect(CameraInfo, 'camera_info', best_effort)
    rects = peer.collect(Image, 'image_rect', best_effort)
    streamer = Streamer(peer, np.full((180, 320), 90, np.uint8), 'mono8', period=0.05)
    peer.spin_until(lambda: len(rects) >= 3, what='image_rect')
    client = peer.node.create_client(SetParameters, '/zeroshot_calib/set_parameters')
    cases = [('hfov', float('nan')), ('hfov', float('inf')), ('hfov', -1.0), ('hfov', 0.0), ('vfov', 1e308),
             ('hfov', 359.9), ('hfov', 'wide'), ('hfov', True), ('hfov', [118.0, 1.0]), ('hfov', [1, 2]),
             ('hfov', [True]), ('hfov', ['a']), ('hfov', None), ('width', -1), ('width', 2 ** 63 - 1),
             ('width', 1920.5), ('height', float('nan')), ('dfov', 50.0), ('balance', float('nan')),
             ('fov_scale', float('inf')), ('fov_scale', 0.0), ('interpolation', 3), ('interpolation', 2.0),
             ('projection', 'orthographic'), ('hfov', 200.0), ('projection', 5), ('rectify', 'yes'),
             ('publish_rate', 0.0), ('vfov', 300.0), ('camera_name', 3)]
    outcomes = []
    for name, value in cases:
        future = client.call_async(SetParameters.Request(parameters=[parameter_msg(name, value)]))
        peer.spin_until(future.done, what=f'set {name}')
        result = future.result().results[0]
        outcomes.append((name, value, result.successful, result.reason))
        if not result.successful:
            assert result.reason.strip(), (name, value)
        assert node.alive(), node.log
    # ordinary values are still accepted after all that, and the stream goes on
    good = dict(hfov=121, vfov=69.0, dfov=0.0, projection='auto', width=320, height=180, balance=0.0,
                fov_scale=1.0, interpolation=1, rectify=True)
    atomic = peer.node.create_client(SetParametersAtomically, '/zeroshot_calib/set_parameters_atomically')
    future = atomic.call_async(SetParametersAtomically.Request(parameters=[parameter_msg(k, v) for k, v in good.items()]))
    peer.spin_until(future.done, what='set_parameters_atomically')
    assert future.result().result.successful, future.result().result.reason
    n = len(rects)
    peer.spin_until(lambda: len(rects) >= n + 10, what='image_rect after the bad values')
    active, _ = solve_from_settings(Settings.from_values(dict(DEFAULTS, **good)), 0, build_maps=False)
    expected_f = active.calibration.K[0, 0]
    peer.spin_until(lambda: abs(infos[-1].k[0] - expected_f) < 1e-6, what='calibration of hfov 121')
    streamer.stop()
    assert all(finite_info(m) for m in infos)
    # the only values that are cameras (each asserted adopted with its f in
    # test_node_observable.py::test_each_bad_value_through_the_node_has_its_expected_outcome)
    # (applied in this order, orthographic after hfov 359.9 is no camera either)
    accepted = [(name, value) for name, value, ok, _ in outcomes if ok]
    assert accepted == [('hfov', 0.0), ('hfov', 359.9), ('hfov', 200.0)], outcomes
    assert node.alive() and 'Traceback' not in node.log


def test_more_malformed_frames_are_skipped_counted_and_survived(peer, start_node):
    """Beyond test_node.py: big-endian 16-bit (converted), a 16-bit step that splits a pixel,
    data longer than step x height, a huge claimed size the data does not back (no maps built
    for it), an unknown encoding (CameraInfo still goes out), zero width."""
    node = start_node(*SMALL, '-p', 'interpolation:=0')
    reliable = qos(ReliabilityPolicy.RELIABLE, depth=50)
    rects = peer.collect(Image, 'image_rect', reliable)
    infos = peer.collect(CameraInfo, 'camera_info', reliable)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pub = peer.image_publisher(reliable)
    big_endian = image_msg(np.full((180, 320), 0x1234, '>u2'), 'mono16', 10)
    big_endian.is_bigendian = 1
    odd_step = image_msg(np.zeros((180, 320), np.uint16), 'mono16', 11)
    odd_step.step = 641
    odd_step.data = bytes(641 * 180)
    longer = image_msg(np.zeros((180, 320), np.uint8), 'mono8', 12)
    longer.data = bytes(320 * 180 + 7)
    huge = image_msg(np.zeros((9, 16), np.uint8), 'mono8', 13)
    huge.width, huge.height, huge.step = 64000, 36000, 64000  # 16:9 claims 2.3 GB of maps
    yuv = image_msg(np.zeros((180, 640), np.uint8), 'yuv422', 14)
    yuv.width = 320
    zero_width = image_msg(np.zeros((180, 1), np.uint8), 'mono8', 15)
    zero_width.width, zero_width.step, zero_width.data = 0, 0, b''
    for msg in (big_endian, odd_step, longer, huge, yuv, zero_width):
        pub.publish(msg)
        peer.spin_for(0.1)
    pub.publish(image_msg(np.full((180, 320, 3), 77, np.uint8), 'bgr8', 16))
    peer.spin_until(lambda: {10, 16} <= {m.header.stamp.nanosec for m in rects}, what='good frames rectified')
    rect = next(m for m in rects if m.header.stamp.nanosec == 10)
    assert rect.is_bigendian == 0 and np.frombuffer(rect.data, np.uint16).reshape(180, 320)[90, 160] == 0x1234
    peer.spin_until(lambda: diagnostics_value(diagnostics, 'frames_skipped_malformed') == '4',
                    what='skip counters')
    assert diagnostics_value(diagnostics, 'frames_skipped_encoding') == '1'
    assert 14 in {m.header.stamp.nanosec for m in infos}  # unknown encoding: CameraInfo still sent
    assert 13 not in {m.header.stamp.nanosec for m in infos}
    assert node.alive() and 'Traceback' not in node.log


def test_frames_stay_paired_with_their_calibration_through_changes_restarts_and_late_joiners(
        peer, start_node):
    """Frames stream while hfov and balance change, the image publisher restarts (reliable ->
    best effort: the node re-creates its endpoints) and a second subscriber joins late. For every
    frame received, its CameraInfo is exactly one of the calibrations set, and its image_rect is
    that calibration's rectification of the frame (done here with OpenCV from the CameraInfo)."""
    width, height = 320, 180
    node = start_node(*SMALL, '-p', 'balance:=0.3')
    image = cv2.GaussianBlur(np.random.default_rng(1).integers(0, 256, (height, width), np.uint8), (0, 0), 1.5)
    yy, xx = np.mgrid[0:height, 0:width]
    image = np.clip(image // 2 + ((xx // 20 + yy // 20) % 2) * 120, 0, 255).astype(np.uint8)
    best_effort = qos(ReliabilityPolicy.BEST_EFFORT, depth=100)
    infos = peer.collect(CameraInfo, 'camera_info', best_effort)
    rects = peer.collect(Image, 'image_rect', best_effort)
    streamer = Streamer(peer, image, 'mono8')
    peer.spin_until(lambda: len(rects) >= 5, what='image_rect')
    client = peer.node.create_client(SetParametersAtomically, '/zeroshot_calib/set_parameters_atomically')

    def set_params(**params):  # atomically: one calibration per step, none in between
        future = client.call_async(SetParametersAtomically.Request(
            parameters=[parameter_msg(k, v) for k, v in params.items()]))
        peer.spin_until(future.done, what='set_parameters_atomically')
        assert future.result().result.successful, future.result().result.reason

    late_infos, late_rects = [], []
    schedule = [dict(hfov=110.0), dict(hfov=125.0), dict(balance=0.8), dict(hfov=100.0),
                'restart', dict(hfov=118.0, balance=0.5), 'late', dict(hfov=112.0), dict(balance=0.0)]
    for step in schedule:
        if step == 'restart':
            streamer.stop()
            peer.spin_for(0.3)
            streamer = Streamer(peer, image, 'mono8', reliability=ReliabilityPolicy.BEST_EFFORT)
            n = len(rects)
            peer.spin_until(lambda: len(rects) >= n + 5, timeout=15, what='frames after the restart')
        elif step == 'late':
            peer.node.create_subscription(CameraInfo, 'camera_info', late_infos.append, best_effort)
            peer.node.create_subscription(Image, 'image_rect', late_rects.append, best_effort)
            peer.spin_until(lambda: len(late_rects) >= 5, what='late subscriber frames')
        else:
            set_params(**step)
            peer.spin_for(0.7)  # frames during and after the map build
    peer.spin_for(0.5)
    streamer.stop()
    peer.spin_for(0.3)
    assert node.alive() and 'Traceback' not in node.log

    # The calibrations that were in force, as the node solves them.
    candidates = {}
    current = dict(DEFAULTS, width=width, height=height, hfov=118.0, vfov=69.0, rectify=True, balance=0.3)
    for step in [{}] + [s for s in schedule if isinstance(s, dict)]:
        current.update(step)
        active, _ = solve_from_settings(Settings.from_values(current), 0, build_maps=False)
        cal = active.calibration
        K, D, P = cal.K, cal.D, cal.P[:3, :3]
        m1, m2 = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), P, (width, height), cv2.CV_16SC2)
        expected = cv2.remap(image, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        candidates[(round(K[0, 0], 9), round(P[0, 0], 9))] = (cal, expected)
    assert len(candidates) == 8

    def check(info_msgs, rect_msgs):
        by_stamp = {stamp_of(m): m for m in info_msgs}
        seen, paired = set(), 0
        for rect in rect_msgs:
            info = by_stamp.get(stamp_of(rect))
            if info is None:
                continue
            paired += 1
            key = (round(info.k[0], 9), round(info.p[0], 9))
            assert key in candidates, f'CameraInfo of frame {stamp_of(rect)} is none of the calibrations set'
            cal, expected = candidates[key]
            np.testing.assert_allclose(np.array(info.k).reshape(3, 3), cal.K, rtol=1e-12)
            np.testing.assert_allclose(np.array(info.p).reshape(3, 4), cal.P, rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(np.array(info.d), cal.D, rtol=1e-12, atol=1e-15)
            got = np.frombuffer(rect.data, np.uint8).reshape(height, width)
            errors = {k: np.abs(got.astype(int) - e.astype(int)).mean() for k, (_, e) in candidates.items()}
            assert errors[key] < 1.0 and min(errors, key=errors.get) == key, (key, errors)
            seen.add(key)
        return seen, paired

    seen, paired = check(infos, rects)
    assert paired >= 0.8 * len(rects) and paired >= 100, (paired, len(rects))
    assert len(seen) >= 6, seen  # frames went out under (nearly) every calibration
    late_seen, late_paired = check(late_infos, late_rects)
    assert late_paired >= 10 and late_seen
    assert all(finite_info(m) for m in infos + late_infos)
