"""Lazy rectification and the executor switch, seen from another process.

With rectify on, the node remaps no frame and builds no maps while image_rect has no subscriber
(its own counters in /diagnostics say so), still sends a CameraInfo with every frame, and
rectifies the first frame after a subscriber appears, as the core's Rectifier does (the public
API, independently of the node's code path). Both executors (rclpy's default, and its
EventsExecutor with ZEROSHOT_CALIB_EXECUTOR=events) publish, run the timers, take a parameter
change (maps built on the builder thread and handed back to the executor) and set_camera_info,
and end on Ctrl-C with status 0.
"""
import functools
import signal
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParameters
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo

from ros_peer import (LATCHED, diagnostics_value, domain_id, image_msg, parameter_msg, peer,  # noqa: F401
                      qos, start_node)
import test_node_observable as observable
from zeroshot_calib_ros.core import CameraSpec, Rectifier, solve_zero_shot

WIDTH, HEIGHT = 640, 360
SPEC = ['-p', f'width:={WIDTH}', '-p', f'height:={HEIGHT}', '-p', 'hfov:=118', '-p', 'vfov:=69',
        '-p', 'rectify:=true']
RELIABLE = qos(ReliabilityPolicy.RELIABLE, depth=100)
NODE = 'zeroshot_calib'
LEVELS = 1
"""Largest difference (8-bit levels) allowed between the node's image_rect and the reference:
the same maps and cv2.remap give the same pixels; one level leaves room for OpenCV builds that
split the remap differently across threads."""


def texture(height=HEIGHT, width=WIDTH, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (height, width), dtype=np.uint8)


def stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def reference(hfov=118.0, vfov=69.0, width=WIDTH, height=HEIGHT):
    """The core's Rectifier for the spec the node is given, with the node's defaults (balance 0,
    fov_scale 1, linear interpolation)."""
    return Rectifier(solve_zero_shot(CameraSpec(width, height, hfov, vfov)).camera, balance=0.0, fov_scale=1.0,
                     interpolation=1)


def rect_pixels(msg):
    return np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)[:, :msg.width]


# test_node_observable's wait (its callable values unused here), with this file's longer timeout: the
# first maps after a subscriber appears take up to 0.6 s on a loaded 2-core machine
wait_for_diagnostics = functools.partial(observable.wait_for_diagnostics, timeout=10.0)


def test_no_remap_and_no_maps_without_a_subscriber_and_the_first_frame_after_one_is_rectified(peer, start_node):
    node = start_node('--ros-args', *SPEC)
    infos = peer.collect(CameraInfo, 'camera_info', RELIABLE)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pub = peer.image_publisher(RELIABLE)
    image = texture()
    stamps = [1_000_000_000 + i for i in range(20)]
    for stamp in stamps:
        pub.publish(image_msg(image, 'mono8', stamp))
        peer.spin_for(0.05)
    # Nobody subscribes to image_rect: every frame got its CameraInfo, none was remapped, and no
    # maps exist (by the node's own counters and map memory).
    wait_for_diagnostics(peer, diagnostics, {
        'frames_received': 20, 'camera_info_published': 20, 'frames_rectified': 0,
        'frames_not_rectified_no_subscriber': 20, 'image_rect_subscribers': 0,
        'rectify': 'on, lazy: no subscriber yet', 'map_memory_mb': '0.0'}, 'frames taken without a subscriber')
    assert set(stamps) <= {stamp_ns(m) for m in infos}
    assert 'rectify    on, lazy: no subscriber yet (maps at most' in node.log
    assert 'rectification maps' not in node.log and 'being built' not in node.log

    # A subscriber appears: once the node has matched it, the next frame is rectified, exactly
    # as the core's Rectifier does, and carries the CameraInfo whose P is the Rectifier's.
    rects = []
    sub = peer.node.create_subscription(Image, 'image_rect', rects.append, RELIABLE)
    peer.spin_until(lambda: 'image_rect has a subscriber' in node.log, timeout=10, what='the node seeing the subscriber')
    assert f'maps of {WIDTH}x{HEIGHT} being built' in node.log  # at the match, before any frame
    first = 2_000_000_000
    pub.publish(image_msg(image, 'mono8', first))
    peer.spin_until(lambda: rects, timeout=10, what='the first frame after the subscriber, rectified')
    assert stamp_ns(rects[0]) == first and (rects[0].width, rects[0].height, rects[0].encoding) == (WIDTH, HEIGHT, 'mono8')
    rectifier = reference()
    expected = rectifier.rectify(image)
    difference = np.abs(rect_pixels(rects[0]).astype(int) - expected.astype(int))
    assert difference.max() <= LEVELS, difference.max()
    assert (expected > 0).mean() > 0.9  # a real image, not an empty border
    peer.spin_until(lambda: first in {stamp_ns(m) for m in infos}, what='its CameraInfo')
    info = next(m for m in infos if stamp_ns(m) == first)
    assert np.allclose(np.array(info.p).reshape(3, 4)[:, :3], rectifier.P, rtol=1e-9)
    wait_for_diagnostics(peer, diagnostics, {
        'frames_received': 21, 'frames_rectified': 1, 'frames_not_rectified_no_subscriber': 20,
        'image_rect_subscribers': 1, 'rectify': 'on: 1 subscriber'}, 'the first frame rectified')
    assert diagnostics_value(diagnostics[-1:], 'frames_skipped_maps_pending') is None

    # The subscriber goes: frames are not remapped again, and the node says so.
    peer.node.destroy_subscription(sub)
    peer.spin_until(lambda: 'image_rect has no subscriber' in node.log, timeout=10, what='the node seeing it go')
    for i in range(5):
        pub.publish(image_msg(image, 'mono8', 3_000_000_000 + i))
        peer.spin_for(0.05)
    wait_for_diagnostics(peer, diagnostics, {
        'frames_received': 26, 'camera_info_published': 26, 'frames_rectified': 1,
        'frames_not_rectified_no_subscriber': 25, 'rectify': 'on, lazy: no subscriber'}, 'frames after it went')
    assert node.alive()


def test_without_a_subscriber_a_calibration_is_in_force_at_once_and_no_maps_are_built(peer, start_node, tmp_path):
    """rectify on, nobody subscribes to image_rect: a 16000x12000 set_camera_info calibration
    (1.4 GiB of maps, ~10 s to build) and a parameter change are in force at once, saved, and no
    map is built for either."""
    path = tmp_path / 'cam.yaml'
    node = start_node('--ros-args', *SPEC, '-p', f'camera_info_url:=file://{path}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    peer.spin_until(lambda: infos, what='camera_info')
    big = CameraInfo(width=16000, height=12000, distortion_model='equidistant', d=[0.02, -0.01, 0.003, 0.0],
                     k=[8000.0, 0.0, 8000.0, 0.0, 8000.0, 6000.0, 0.0, 0.0, 1.0], r=list(np.eye(3).ravel()),
                     p=[7200.0, 0.0, 8000.0, 0.0, 0.0, 7200.0, 6000.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    start = time.monotonic()
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=big), timeout=30)
    assert response.success and response.status_message == f'calibration adopted and saved to {path}', \
        response.status_message
    assert time.monotonic() - start < 2.0  # not the ~10 s of its maps
    peer.spin_until(lambda: infos[-1].width == 16000, what='the calibration in force')
    request = SetParameters.Request(parameters=[parameter_msg('fov_scale', 1.5)])
    assert peer.call(SetParameters, f'/{NODE}/set_parameters', request).results[0].successful
    peer.spin_until(lambda: infos[-1].width == 16000 and infos[-1].p[0] != 7200.0, what='the new P in force')
    wait_for_diagnostics(peer, diagnostics, {'generation': 2, 'map_memory_mb': '0.0',
                                             'rectify': 'on, lazy: no subscriber yet'}, 'both in force, no maps')
    assert 'rectification maps' not in node.log


@pytest.mark.parametrize('executor', ['single', 'events'])
def test_a_subscriber_joining_a_stream_gets_every_frame_from_its_first_on(peer, start_node, monkeypatch, executor):
    """30 fps of 640x360 frames; a subscriber joins mid-stream. The maps are built when it
    appears (with the EventsExecutor: when the first frame sees it), and a frame that comes while
    they are built waits for them: no frame is skipped for want of maps, every frame is either
    not remapped (no subscriber yet) or rectified, and the subscriber receives every frame from
    its first one on."""
    monkeypatch.setenv('ZEROSHOT_CALIB_EXECUTOR', executor)
    width, height = WIDTH, HEIGHT
    node = start_node('--ros-args', *SPEC)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pub = peer.image_publisher(RELIABLE)
    image = texture(height, width, seed=1)
    rects, sent, sub = [], [], None
    t0 = time.monotonic()
    for i in range(150):
        stamp = 4_000_000_000 + i * 33_000_000
        pub.publish(image_msg(image, 'mono8', stamp))
        sent.append(stamp)
        if i == 45:
            sub = peer.node.create_subscription(Image, 'image_rect', rects.append, RELIABLE)
        while time.monotonic() < t0 + (i + 1) / 30:
            peer.executor.spin_once(timeout_sec=0.003)
    peer.spin_for(1.0)
    assert sub is not None and rects, 'no image_rect after the subscriber joined'
    received = [stamp_ns(m) for m in rects]
    first = sent.index(received[0])
    assert received == sent[first:], f'missing after the first: {sorted(set(sent[first:]) - set(received))}'
    assert first < 120  # the subscriber was matched well before the end (discovery takes < 2 s)
    peer.spin_until(lambda: diagnostics and diagnostics_value(diagnostics[-1:], 'frames_received') == '150',
                    timeout=10, what='every frame counted')
    last = diagnostics[-1:]
    rectified = int(diagnostics_value(last, 'frames_rectified'))
    not_rectified = int(diagnostics_value(last, 'frames_not_rectified_no_subscriber'))
    assert rectified + not_rectified == 150 and rectified == len(received), (rectified, not_rectified, len(received))
    assert diagnostics_value(last, 'frames_skipped_maps_pending') is None
    assert node.alive()


@pytest.mark.parametrize('executor, name', [('single', 'SingleThreadedExecutor'),
                                            ('events', 'EventsExecutor (rclpy.experimental)')])
def test_both_executors_publish_take_changes_and_stop(peer, start_node, monkeypatch, executor, name):
    monkeypatch.setenv('ZEROSHOT_CALIB_EXECUTOR', executor)
    node = start_node('--ros-args', *SPEC, '-p', 'publish_rate:=20.0')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    # timers: CameraInfo at publish_rate without a camera, /diagnostics once a second
    peer.spin_until(lambda: len(infos) >= 6, timeout=15, what='timer CameraInfo')
    peer.spin_until(lambda: diagnostics, timeout=5, what='/diagnostics')
    assert diagnostics_value(diagnostics, 'executor').startswith(name)
    assert f'executor   {name}' in node.log
    # frames with a subscriber: rectified as the core's Rectifier does
    rects = peer.collect(Image, 'image_rect', RELIABLE)
    pub = peer.image_publisher(RELIABLE)
    image = texture(seed=2)
    stamp = 5_000_000_000
    deadline = time.monotonic() + 15
    while not rects and time.monotonic() < deadline:
        pub.publish(image_msg(image, 'mono8', stamp))
        stamp += 1
        peer.spin_for(0.1)
    assert rects, 'no image_rect'
    difference = np.abs(rect_pixels(rects[-1]).astype(int) - reference().rectify(image).astype(int))
    assert difference.max() <= LEVELS
    # a parameter change while frames stream and image_rect is subscribed: its maps are built on
    # the builder thread and swapped in on the executor thread; every frame keeps its CameraInfo
    request = SetParameters.Request(parameters=[parameter_msg('hfov', 122.0)])
    future = peer.node.create_client(SetParameters, f'/{NODE}/set_parameters').call_async(request)
    new_f = solve_zero_shot(CameraSpec(WIDTH, HEIGHT, 122.0, 69.0)).f
    deadline = time.monotonic() + 20
    changed = None
    while changed is None and time.monotonic() < deadline:
        pub.publish(image_msg(image, 'mono8', stamp))
        stamp += 1
        peer.spin_for(0.05)
        changed = next((m for m in infos if abs(m.k[0] - new_f) < 1e-6 and stamp_ns(m) >= 5_000_000_000), None)
    assert future.done() and future.result().results[0].successful
    assert changed is not None, 'no CameraInfo of the new hfov'
    peer.spin_until(lambda: stamp_ns(changed) in {stamp_ns(m) for m in rects}, what='its image_rect')
    rect = next(m for m in rects if stamp_ns(m) == stamp_ns(changed))
    difference = np.abs(rect_pixels(rect).astype(int) - reference(hfov=122.0).rectify(image).astype(int))
    assert difference.max() <= LEVELS
    assert 'rectification maps of generation 1 built' in node.log
    # set_camera_info: adopted, in force
    calibration = CameraInfo(width=WIDTH, height=HEIGHT, distortion_model='equidistant', d=[0.02, -0.01, 0.003, 0.0],
                             k=[300.0, 0.0, 320.0, 0.0, 300.0, 180.0, 0.0, 0.0, 1.0],
                             r=list(np.eye(3).ravel()), p=[270.0, 0.0, 320.0, 0.0, 0.0, 270.0, 180.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=calibration))
    assert response.success and 'calibration adopted' in response.status_message, response.status_message
    pub.publish(image_msg(image, 'mono8', stamp))
    peer.spin_until(lambda: infos[-1].k[0] == 300.0, what='the set_camera_info calibration in force')
    # Ctrl-C: a quiet exit with status 0
    node.process.send_signal(signal.SIGINT)
    assert node.process.wait(15) == 0
    assert 'Traceback' not in node.log and 'Segmentation' not in node.log


def test_the_events_executor_adopts_a_refinement_with_image_rect_subscribed(peer, start_node, monkeypatch):
    """refine on, the EventsExecutor, image_rect subscribed: frames go to the refiner's worker
    process, its result is polled by the housekeeping timer and adopted, the refined
    calibration's maps are built on the builder thread and swapped in on the executor thread,
    and image_rect keeps coming."""
    from scenes import render
    from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera

    monkeypatch.setenv('ZEROSHOT_CALIB_EXECUTOR', 'events')
    true = KannalaBrandtCamera(210.0, 210.0, 327.0, 176.0, 640, 360, np.array([0.02, -0.01, 0.003, -0.0005]))
    frames = [render(true, scene, seed=seed)[0] for scene, seed in (('room', 1), ('corridor', 2))]
    node = start_node('--ros-args', '-p', 'width:=640', '-p', 'height:=360', '-p', 'hfov:=172.0', '-p', 'vfov:=97.0',
                      '-p', 'dfov:=198.0', '-p', 'rectify:=true', '-p', 'refine:=true', '-p', 'refine_interval:=0.5')
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    rects = peer.collect(Image, 'image_rect', RELIABLE)
    pub = peer.image_publisher(qos())
    start, i = time.monotonic(), 0
    while diagnostics_value(diagnostics, 'source') != 'refined':
        assert time.monotonic() - start < 90, f'no refined calibration in 90 s: {diagnostics_value(diagnostics, "refine_state")}'
        pub.publish(image_msg(frames[i % 2], 'mono8', time.time_ns()))
        i += 1
        peer.spin_for(1 / 15)
    generation = int(diagnostics_value(diagnostics, 'generation'))
    assert generation >= 1 and f'rectification maps of generation {generation} built' in node.log
    count = len(rects)
    for _ in range(15):
        pub.publish(image_msg(frames[i % 2], 'mono8', time.time_ns()))
        i += 1
        peer.spin_for(1 / 15)
    peer.spin_until(lambda: len(rects) >= count + 10, what='image_rect after the refined calibration')
    assert node.alive() and 'Exception' not in node.log


def test_the_docs_command_starts_the_node_on_the_events_executor(peer, start_node, monkeypatch):
    """docs/performance.md's `ZEROSHOT_CALIB_EXECUTOR=events ros2 run zeroshot_calib_ros node
    --ros-args ...` (the installed executable, what ros2 run starts): the start-up block names the
    EventsExecutor and lazy rectification, as the doc quotes them; CameraInfo comes; Ctrl-C ends it."""
    import re
    import shlex
    from ros_peer import REPO
    line = next(l for l in (REPO / 'docs' / 'performance.md').read_text().splitlines()
                if l.startswith('ZEROSHOT_CALIB_EXECUTOR='))
    words = shlex.split(line)
    variable, value = words[0].split('=')
    assert words[1:5] == ['ros2', 'run', 'zeroshot_calib_ros', 'node']
    monkeypatch.setenv(variable, value)
    node = start_node(*words[5:])
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos and 'memory     ' in node.log, timeout=20, what='camera_info and the start-up block')
    doc = (REPO / 'docs' / 'performance.md').read_text()
    for quoted in re.findall(r'`(executor   [^`]*)`', doc) + ['rectify    on, lazy: no subscriber yet (maps at most max_map_memory_mb = ']:
        assert quoted in node.log, quoted
    assert infos[0].width == 1920
    node.process.send_signal(signal.SIGINT)
    assert node.process.wait(15) == 0


def test_an_executor_value_that_names_none_is_a_warning_and_the_default_runs(peer, start_node, monkeypatch):
    monkeypatch.setenv('ZEROSHOT_CALIB_EXECUTOR', 'fast')
    node = start_node('--ros-args', *SPEC)
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos and 'memory     ' in node.log, timeout=20, what='camera_info and the start-up block')
    warning = "ZEROSHOT_CALIB_EXECUTOR='fast' is none of single, events: the default, single, is used"
    assert f'[WARN]' in node.log and f'executor: {warning}' in node.log
    assert f'executor   SingleThreadedExecutor ({warning})' in node.log
    assert node.alive()
