"""The installed ROS node, in its own process, seen from another process (this one)."""

import math
import time

import cv2
import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParameters
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo

from ros_peer import (LATCHED, REPO, diagnostics_value, domain_id, image_msg, parameter_msg, peer,  # noqa: F401
                      qos, start_node)
from synthetic import find_corners, line_residuals, render_checkerboard
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot

W1_ARGS = ['--ros-args', '-p', 'hfov:=118', '-p', 'vfov:=69', '-p', 'width:=1920', '-p', 'height:=1080']


def frame(array, encoding, stamp_sec):
    return image_msg(array, encoding, stamp_sec * 1_000_000_000 + 123456789)


def set_parameter(peer, name, value):
    request = SetParameters.Request(parameters=[parameter_msg(name, value)])
    return peer.call(SetParameters, '/zeroshot_calib/set_parameters', request).results[0]


def test_camera_info_from_integer_command_line_parameters(peer, start_node):
    node = start_node(*W1_ARGS)
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    info = infos[0]
    K = np.array(info.k).reshape(3, 3)
    assert K[0, 0] == pytest.approx(876.0, abs=0.1) and K[1, 1] == K[0, 0]
    assert (K[0, 2], K[1, 2]) == (960.0, 540.0)
    assert info.distortion_model == 'equidistant' and len(info.d) == 4
    assert (info.width, info.height) == (1920, 1080)
    assert np.allclose(np.array(info.r).reshape(3, 3), np.eye(3))
    # D through OpenCV's fisheye model against the solver's exact model, over the whole image.
    solution = solve_zero_shot(CameraSpec(1920, 1080, 118, 69))
    u, v = np.meshgrid(np.linspace(0, 1920, 65), np.linspace(0, 1080, 37))
    pixels = np.stack([u, v], -1).reshape(-1, 2)
    xy = solution.undistort(pixels)
    projected, _ = cv2.fisheye.projectPoints(np.c_[xy, np.ones(len(xy))][None], np.zeros(3), np.zeros(3),
                                             K, np.array(info.d))
    assert np.abs(projected[0] - pixels).max() < 0.01
    # Without images: periodic, freshly stamped, with the configured frame_id.
    peer.spin_until(lambda: len(infos) >= 4, what='periodic camera_info')
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in infos[-3:]]
    assert stamps[0] < stamps[1] < stamps[2]
    assert infos[-1].header.frame_id == 'camera'
    peer.spin_until(lambda: 'f         875.9867 px' in node.log, timeout=5, what='the start-up block in the log')


def test_late_joiner_gets_camera_info(peer, start_node):
    start_node(*W1_ARGS, '-p', 'publish_rate:=0.05')  # one message every 20 s: only the latched one
    peer.spin_for(3.0)
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, timeout=10, what='latched camera_info')


def test_params_file_start_up(peer, start_node):
    start_node('--ros-args', '--params-file', str(REPO / 'config' / 'c922.yaml'))
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    assert infos[0].distortion_model == 'plumb_bob' and len(infos[0].d) == 5
    assert infos[0].k[0] == pytest.approx(907.0, abs=0.1)
    assert infos[0].header.frame_id == 'c922_optical_frame'


@pytest.mark.parametrize('args, parameter, allowed', [
    (['-p', 'hfov:=400', '-p', 'vfov:=69', '-p', 'width:=1920', '-p', 'height:=1080'], 'hfov', 'less than 360'),
    (['-p', 'hfov:=118', '-p', 'vfov:=69', '-p', 'width:=1920'], 'height', 'from 1 to 100000'),
    (['-p', 'hfov:=118', '-p', 'width:=1920', '-p', 'height:=1080', '-p', 'balance:=3'], 'balance', 'from 0 to 1'),
    (['-p', 'hfov:=118', '-p', 'width:=1920', '-p', 'height:=1080', '-p', 'projection:=fish'], 'projection',
     'equidistant'),
])
def test_invalid_spec_exits_with_one_line(start_node, args, parameter, allowed):
    node = start_node('--ros-args', *args)
    assert node.wait(30) == 2
    lines = node.log.strip().splitlines()
    assert len(lines) == 1, node.log
    assert lines[0].startswith(f'zeroshot_calib: error: {parameter} = ') and allowed in lines[0]


def test_run_time_change_accepted_and_rejected(peer, start_node):
    start_node(*W1_ARGS)
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    f0 = infos[-1].k[0]
    result = set_parameter(peer, 'hfov', 122)  # an integer, as a user types it
    assert result.successful, result.reason
    peer.spin_until(lambda: abs(infos[-1].k[0] - f0) > 1, what='re-solved camera_info')
    f1 = infos[-1].k[0]
    expected = solve_zero_shot(CameraSpec(1920, 1080, 122, 69)).f
    assert f1 == pytest.approx(expected, abs=1e-6)
    # Each rejection names the parameter and its allowed range (ours, or rclpy's range check).
    for name, value, reasons in [('hfov', 400.0, ['hfov', '360']),
                                 ('vfov', 'wide', ["vfov = 'wide'", 'a number']),
                                 ('balance', 1.5, ['balance', 'Min: 0.0, Max: 1.0']),
                                 ('projection', 'fish', ["projection = 'fish'", 'equidistant']),
                                 ('width', 0, ['width = 0', 'from 1 to'])]:
        result = set_parameter(peer, name, value)
        assert not result.successful and all(r in result.reason for r in reasons), (name, result.reason)
    n = len(infos)
    peer.spin_until(lambda: len(infos) >= n + 3, what='camera_info after rejections')
    assert infos[-1].k[0] == f1  # the calibration in force is kept


def test_set_camera_info_is_persisted_and_reloaded(peer, start_node, tmp_path):
    path = tmp_path / 'calib' / 'cam.yaml'
    url = f'file://{path}'
    node = start_node(*W1_ARGS, '-p', f'camera_info_url:={url}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    refined = CameraInfo()
    refined.width, refined.height = 1920, 1080
    refined.distortion_model = 'equidistant'
    refined.k = [880.0, 0.0, 955.0, 0.0, 880.0, 545.0, 0.0, 0.0, 1.0]
    refined.d = [0.05, -0.004, -0.001, 0.0002]
    refined.r = np.eye(3).ravel().tolist()
    refined.p = [700.0, 0.0, 955.0, 0.0, 0.0, 700.0, 545.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=refined))
    assert response.success, response.status_message
    saved = yaml.safe_load(path.read_text())
    assert saved['camera_matrix']['data'][0] == 880.0 and saved['distortion_model'] == 'equidistant'
    peer.spin_until(lambda: infos[-1].k[0] == 880.0, what='adopted calibration')
    bad = CameraInfo(width=1920, height=1080, distortion_model='equidistant')
    bad.k = [float('nan')] * 9
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=bad))
    assert not response.success and 'finite' in response.status_message
    node.stop()
    # Restart: the file now takes precedence over the spec. Wait for the new process to say so
    # (which also drains what the first process sent), then for its CameraInfo.
    restarted = start_node(*W1_ARGS, '-p', f'camera_info_url:={url}', name='restarted')
    peer.spin_until(lambda: 'calibration loaded from' in restarted.log, what='the restarted node loading the file')
    infos.clear()
    peer.spin_until(lambda: infos, what='camera_info of the restarted node')
    assert infos[-1].k[0] == 880.0 and list(infos[-1].p[:3]) == [700.0, 0.0, 955.0]


def test_rectified_stream_keeps_stamps_and_straightens_lines(peer, start_node):
    """A checkerboard rendered through the known equidistant zero-shot camera of the spec
    (960 x 540, hfov 118, vfov 69) goes through the node; image_rect carries each input stamp,
    CameraInfo carries the identical stamp, and the board's rows and columns come out straight."""
    camera = solve_zero_shot(CameraSpec(960, 540, 118, 69)).camera
    image, _ = render_checkerboard(camera)
    start_node('--ros-args', '-p', 'hfov:=118', '-p', 'vfov:=69', '-p', 'width:=960', '-p', 'height:=540',
               '-p', 'rectify:=true', '-p', 'balance:=1')
    reliable = qos(ReliabilityPolicy.RELIABLE)
    rects = peer.collect(Image, 'image_rect', reliable)
    infos = peer.collect(CameraInfo, 'camera_info', reliable)
    pub = peer.image_publisher(reliable)
    sent = []
    for i in range(5):
        msg = frame(image, 'mono8', 1000 + i)
        sent.append((msg.header.stamp.sec, msg.header.stamp.nanosec))
        pub.publish(msg)
        peer.spin_for(0.2)
    peer.spin_until(lambda: len(rects) >= 3, what='image_rect')

    def stamps(messages):
        return {(m.header.stamp.sec, m.header.stamp.nanosec) for m in messages if m.header.stamp.sec >= 1000}

    rect_stamps = stamps(rects)
    assert rect_stamps <= set(sent)
    # every rectified frame has a CameraInfo with the identical stamp (the topics are independent,
    # so wait for it rather than assume it came first)
    peer.spin_until(lambda: rect_stamps <= stamps(infos), timeout=10, what='camera_info of each image_rect')
    assert all(m.header.frame_id == 'cam' for m in rects)
    rect = np.frombuffer(rects[-1].data, np.uint8).reshape(540, 960)
    corners = find_corners(rect)
    assert corners is not None
    residual = line_residuals(corners)
    assert np.sqrt(np.mean(residual ** 2)) < 0.1 and residual.max() < 0.3
    info = next(m for m in infos if m.header.stamp.sec == rects[-1].header.stamp.sec)
    assert info.k[0] == pytest.approx(camera.f)


def test_bad_frames_are_skipped_counted_and_survived(peer, start_node):
    node = start_node('--ros-args', '-p', 'hfov:=118', '-p', 'vfov:=69', '-p', 'width:=640', '-p', 'height:=360',
                      '-p', 'rectify:=true')
    reliable = qos(ReliabilityPolicy.RELIABLE)
    rects = peer.collect(Image, 'image_rect', reliable)
    infos = peer.collect(CameraInfo, 'camera_info', reliable)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pub = peer.image_publisher(reliable)
    good = np.full((360, 640, 3), 90, np.uint8)
    bayer = frame(np.zeros((360, 640), np.uint8), 'bayer_rggb8', 2000)
    wrong_aspect = frame(np.zeros((480, 640, 3), np.uint8), 'bgr8', 2001)
    short = frame(good, 'bgr8', 2002)
    short.data = short.data[:-10]
    bad_step = frame(good, 'bgr8', 2003)
    bad_step.step = 100
    empty = frame(np.zeros((0, 0), np.uint8), 'mono8', 2004)
    for msg in (bayer, wrong_aspect, short, bad_step, empty):
        pub.publish(msg)
        peer.spin_for(0.1)
    pub.publish(frame(good, 'bgr8', 2005))
    # A new size (same aspect, half): its maps are built off the executor thread, so its first
    # frames get their CameraInfo but are not rectified (counted) until the maps are ready.
    half_stamps = []
    for i in range(40):
        half_stamps.append(2006 + i)
        pub.publish(frame(np.full((180, 320), 50, np.uint8), 'mono8', 2006 + i))
        peer.spin_for(0.1)
        if any(m.header.stamp.sec >= 2006 for m in rects):
            break
    # image_rect and camera_info are separate topics: neither arrives first for sure
    peer.spin_until(lambda: 2005 in {m.header.stamp.sec for m in rects} and
                    any(m.header.stamp.sec >= 2006 for m in rects), what='good frames rectified')
    peer.spin_until(lambda: {2005, 2006} <= {m.header.stamp.sec for m in infos}, what='their camera_info')
    peer.spin_until(lambda: int(diagnostics_value(diagnostics, 'frames_skipped_maps_pending') or 0) >= 1,
                    what='the half-size frame counted while its maps were built')
    peer.spin_until(lambda: diagnostics_value(diagnostics, 'frames_skipped_malformed') == '3',
                    what='skip counters')
    assert diagnostics_value(diagnostics, 'frames_skipped_encoding') == '1'
    assert diagnostics_value(diagnostics, 'frames_skipped_aspect') == '1'
    assert node.alive()
    peer.spin_until(lambda: "encoding 'bayer_rggb8'" in node.log, timeout=5, what='the encoding warning')
    # Same aspect, half size: scaled intrinsics, maps of its own.
    half_info = next(m for m in infos if m.header.stamp.sec == 2006)
    full_info = next(m for m in infos if m.header.stamp.sec == 2005)
    assert (half_info.width, half_info.height) == (320, 180)
    assert half_info.k[0] == pytest.approx(full_info.k[0] / 2) and half_info.k[2] == 160
    half_rect = next(m for m in rects if m.header.stamp.sec >= 2006)
    assert (half_rect.width, half_rect.height, half_rect.encoding) == (320, 180, 'mono8')
    # The camera_info of skipped wrong-aspect frames is not sent: no size describes them.
    assert 2001 not in {m.header.stamp.sec for m in infos}


def test_the_aspect_ratio_error_clears_once_frames_the_calibration_describes_come(peer, start_node):
    """A 1920x1080 spec and a camera streaming 640x480 (4:3): /diagnostics is an ERROR naming
    that size. Once the same camera streams frames the spec describes (960x540, 16:9), they get
    their CameraInfo and /diagnostics is OK again (and stays OK while they come)."""
    from diagnostic_msgs.msg import DiagnosticStatus
    start_node(*W1_ARGS)
    reliable = qos(ReliabilityPolicy.RELIABLE)
    infos = peer.collect(CameraInfo, 'camera_info', reliable)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pub = peer.image_publisher(reliable)
    stamp = [3000]

    def levels(messages):
        return [(s.level, s.message) for d in messages for s in d.status]

    def stream_until(array, predicate, timeout, what):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            pub.publish(frame(array, 'mono8', stamp[0]))
            stamp[0] += 1
            peer.spin_for(0.1)
            if predicate():
                return
        raise AssertionError(f'timed out after {timeout:g} s waiting for {what}; '
                             f'the newest /diagnostics: {levels(diagnostics[-3:])}')

    stream_until(np.zeros((480, 640), np.uint8),
                 lambda: any(level == DiagnosticStatus.ERROR and '640x480' in text
                             for level, text in levels(diagnostics)), 30, 'a /diagnostics ERROR naming 640x480')
    first_good = stamp[0]
    good = np.full((540, 960), 80, np.uint8)
    stream_until(good, lambda: any(m.header.stamp.sec >= first_good and (m.width, m.height) == (960, 540)
                                   for m in infos), 30, 'the CameraInfo of the 960x540 frames')
    seen = len(diagnostics)
    stream_until(good, lambda: any(level == DiagnosticStatus.OK for level, _ in levels(diagnostics[seen:])), 30,
                 '/diagnostics OK again while 960x540 frames come')
    ok_at = len(diagnostics)
    stream_until(good, lambda: len(diagnostics) >= ok_at + 2, 30, 'two more /diagnostics')
    assert all(level == DiagnosticStatus.OK for level, _ in levels(diagnostics[ok_at:])), levels(diagnostics[ok_at:])


@pytest.mark.parametrize('encoding, dtype, channels', [
    ('mono16', np.uint16, 1), ('16UC1', np.uint16, 1), ('32FC1', np.float32, 1), ('rgb8', np.uint8, 3),
    ('bgra8', np.uint8, 4), ('rgba8', np.uint8, 4)])
def test_every_supported_encoding_is_rectified(peer, start_node, encoding, dtype, channels):
    start_node('--ros-args', '-p', 'hfov:=100', '-p', 'vfov:=60', '-p', 'width:=160', '-p', 'height:=90',
               '-p', 'rectify:=true', '-p', 'interpolation:=0')
    reliable = qos(ReliabilityPolicy.RELIABLE)
    rects = peer.collect(Image, 'image_rect', reliable)
    pub = peer.image_publisher(reliable)
    shape = (90, 160) if channels == 1 else (90, 160, channels)
    array = np.full(shape, 300 if dtype != np.uint8 else 200, dtype)
    pub.publish(frame(array, encoding, 3000))
    peer.spin_until(lambda: rects, what='image_rect')
    rect = rects[0]
    assert rect.encoding == encoding and rect.step == 160 * channels * np.dtype(dtype).itemsize
    out = np.frombuffer(rect.data, dtype).reshape(shape)
    assert np.all(out[45, 80] == array[45, 80])


def test_camera_info_reliability_follows_the_image_publisher(peer, start_node):
    start_node(*W1_ARGS)
    best_effort = qos(ReliabilityPolicy.BEST_EFFORT)
    peer.node.create_publisher(Image, 'image_raw', best_effort)

    def node_info_reliability():
        infos = peer.node.get_publishers_info_by_topic('/camera_info')
        return infos[0].qos_profile.reliability if infos else None

    peer.spin_until(lambda: node_info_reliability() == ReliabilityPolicy.BEST_EFFORT, timeout=15,
                    what='camera_info publisher to become best effort')
    infos = peer.node.get_publishers_info_by_topic('/camera_info')
    assert infos[0].qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL


def test_preset_and_circular_fisheye_parameters(peer, start_node):
    start_node('--ros-args', '-p', 'preset:=gopro_hero9_wide', '-p', 'vfov:=70')  # vfov overrides
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info of the preset')
    assert (infos[0].width, infos[0].height) == (1920, 1080)
    assert infos[0].k[0] == pytest.approx(solve_zero_shot(CameraSpec(1920, 1080, 118, 70)).f, abs=1e-6)
    result = set_parameter(peer, 'preset', 'no_such_camera')
    assert not result.successful and "preset = 'no_such_camera'" in result.reason and 'unknown preset' in result.reason


def test_wide_lens_beyond_180_degrees(peer, start_node):
    start_node('--ros-args', '-p', 'width:=1280', '-p', 'height:=960', '-p', 'circle_diameter:=900',
               '-p', 'circle_fov:=200', '-p', 'projection:=auto')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info of a 200-degree circular fisheye')
    expected = solve_zero_shot(CameraSpec(1280, 960, circle_diameter=900, circle_fov=200))
    assert infos[0].k[0] == pytest.approx(expected.f, abs=1e-6) and infos[0].distortion_model == 'equidistant'
    assert all(math.isfinite(x) for x in list(infos[0].d) + list(infos[0].p))
