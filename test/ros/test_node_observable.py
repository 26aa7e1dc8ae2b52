"""What a ROS user observes of the node and relies on, each checked from another process against
an independent reference (the sent messages, the wall clock, a closed form, the ROS graph):
CameraInfo carries exactly each image's header; /diagnostics reports the calibration source, its
generation and the frame counters truthfully; image_rect and image_raw follow the image
publisher's reliability; timer CameraInfo comes at publish_rate, stamped now; read-only
parameters refuse new values; the all-zero-D nudge; a spec's binning 0 / full roi; and every bad
value through SetParameters has its own expected outcome.

(``${NAME}`` / ``${ROS_HOME}`` in camera_info_url through the node:
test_node_files.py::test_url_variables_and_a_file_of_another_camera.)
"""
import math
import time

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, SetParameters, SetParametersAtomically
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo

from ros_peer import (LATCHED, diagnostics_value, domain_id, image_msg, parameter_msg, peer,  # noqa: F401
                      qos, start_node)
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot

SMALL = ['-p', 'width:=320', '-p', 'height:=180', '-p', 'hfov:=118', '-p', 'vfov:=69']
RELIABLE = qos(ReliabilityPolicy.RELIABLE, depth=50)
BEST_EFFORT = qos(ReliabilityPolicy.BEST_EFFORT, depth=50)
NODE = 'zeroshot_calib'


def texture(height=180, width=320, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (height, width), dtype=np.uint8)


def stamp_of(msg):
    return msg.header.stamp.sec, msg.header.stamp.nanosec


def set_parameters(peer, **values):
    request = SetParameters.Request(parameters=[parameter_msg(k, v) for k, v in values.items()])
    return peer.call(SetParameters, f'/{NODE}/set_parameters', request).results


def set_atomically(peer, **values):
    request = SetParametersAtomically.Request(parameters=[parameter_msg(k, v) for k, v in values.items()])
    return peer.call(SetParametersAtomically, f'/{NODE}/set_parameters_atomically', request).result


def get_parameters(peer, *names):
    response = peer.call(GetParameters, f'/{NODE}/get_parameters', GetParameters.Request(names=list(names)))
    field = {ParameterType.PARAMETER_BOOL: 'bool_value', ParameterType.PARAMETER_INTEGER: 'integer_value',
             ParameterType.PARAMETER_DOUBLE: 'double_value', ParameterType.PARAMETER_STRING: 'string_value'}
    return {n: getattr(v, field[v.type]) for n, v in zip(names, response.values)}


def calibration_msg(width=320, height=180, fx=200.0):
    """A CameraInfo as cameracalibrator sends it (equidistant)."""
    msg = CameraInfo(width=width, height=height, distortion_model='equidistant')
    msg.k = [fx, 0.0, width / 2 + 1, 0.0, fx, height / 2 - 1, 0.0, 0.0, 1.0]
    msg.d = [0.03, -0.01, 0.002, -0.0004]
    msg.r = np.eye(3).ravel().tolist()
    msg.p = [fx * 0.8, 0.0, width / 2, 0.0, 0.0, fx * 0.8, height / 2, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def wait_for_diagnostics(peer, diagnostics, expected, what, timeout=8.0):
    """Until the last /diagnostics message has every key = value of ``expected`` (compared as
    strings; a callable value is called each time: a count of messages still arriving)."""
    def wanted():
        return {k: str(v() if callable(v) else v) for k, v in expected.items()}

    def matches():
        return bool(diagnostics) and all(diagnostics_value(diagnostics[-1:], k) == v for k, v in wanted().items())
    try:
        peer.spin_until(matches, timeout=timeout, what=what)
    except AssertionError:
        got = {k: diagnostics_value(diagnostics[-1:], k) for k in expected}
        raise AssertionError(f'{what}: /diagnostics says {got}, expected {wanted()}') from None


def test_camera_info_with_images_carries_exactly_each_image_header(peer, start_node):
    """frame_id and stamp of every frame, not the frame_id parameter (that is for timer CameraInfo)."""
    start_node('--ros-args', *SMALL, '-p', 'frame_id:=param_frame')
    infos = peer.collect(CameraInfo, 'camera_info', RELIABLE)
    pub = peer.image_publisher(RELIABLE)
    image = texture()
    sent = {}
    for i in range(6):
        msg = image_msg(image, 'mono8', (7000 + i) * 1_000_000_000 + 123_456_789 + 1000 * i,
                        frame_id=('left_optical', 'right_optical')[i % 2])
        sent[stamp_of(msg)] = msg.header.frame_id
        pub.publish(msg)
        peer.spin_for(0.05)
    peer.spin_until(lambda: set(sent) <= {stamp_of(m) for m in infos}, timeout=10, what='a CameraInfo per frame')
    framed = {stamp_of(m): m.header.frame_id for m in infos if stamp_of(m) in sent}
    assert framed == sent
    assert all(m.header.frame_id == 'param_frame' for m in infos if stamp_of(m) not in sent)


def test_diagnostics_count_the_frames_received_and_rectified(peer, start_node):
    start_node('--ros-args', *SMALL, '-p', 'rectify:=true')
    rects = peer.collect(Image, 'image_rect', RELIABLE)
    infos = peer.collect(CameraInfo, 'camera_info', RELIABLE)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    wait_for_diagnostics(peer, diagnostics, {'source': 'spec', 'generation': 0}, 'the start-up calibration')
    pub = peer.image_publisher(RELIABLE)
    image = texture()
    sent = []
    # frames until a few are rectified (the first may come before the start-up maps are built)
    while len([m for m in rects if m.header.stamp.sec >= 100]) < 4 and len(sent) < 60:
        msg = image_msg(image, 'mono8', (100 + len(sent)) * 1_000_000_000)
        sent.append(stamp_of(msg))
        pub.publish(msg)
        peer.spin_for(0.1)
    peer.spin_until(lambda: set(sent) <= {stamp_of(m) for m in infos}, timeout=5, what='every CameraInfo')

    def count(messages):
        return lambda: len([m for m in messages if stamp_of(m) in set(sent)])
    wait_for_diagnostics(peer, diagnostics, {'frames_received': len(sent), 'frames_rectified': count(rects),
                                             'camera_info_published': count(infos)}, 'the frame counters')
    assert count(rects)() >= 4 and count(infos)() == len(sent)


def test_diagnostics_source_and_generation_follow_each_adopted_change(peer, start_node, tmp_path):
    """source: 'file PATH' / 'set_camera_info' / 'spec'; generation: 0 at start-up, one more
    for each adopted change, unchanged by a rejected one."""
    path = tmp_path / 'cam.yaml'
    msg = calibration_msg(fx=210.0)
    path.write_text(yaml.safe_dump({
        'image_width': 320, 'image_height': 180, 'camera_name': 'camera',
        'camera_matrix': {'rows': 3, 'cols': 3, 'data': [float(x) for x in msg.k]},
        'distortion_model': 'equidistant',
        'distortion_coefficients': {'rows': 1, 'cols': 4, 'data': [float(x) for x in msg.d]},
        'rectification_matrix': {'rows': 3, 'cols': 3, 'data': [float(x) for x in msg.r]},
        'projection_matrix': {'rows': 3, 'cols': 4, 'data': [float(x) for x in msg.p]}}))
    start_node('--ros-args', *SMALL, '-p', f'camera_info_url:=file://{path}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    file_source = f'file {path}'
    wait_for_diagnostics(peer, diagnostics, {'source': file_source, 'generation': 0}, 'the file at start-up')
    assert infos[-1].k[0] == 210.0

    def rejected_leaves(expected):
        diagnostics.clear()  # the next one is published after the rejection
        wait_for_diagnostics(peer, diagnostics, expected, 'after a rejected change')

    assert set_parameters(peer, balance=0.5)[0].successful  # P changes, the file's K / D stay
    wait_for_diagnostics(peer, diagnostics, {'source': file_source, 'generation': 1}, 'balance adopted')
    assert not set_parameters(peer, hfov=400.0)[0].successful  # rclpy's range check
    assert not set_parameters(peer, dfov=50.0)[0].successful  # the node's: narrower than hfov
    rejected_leaves({'source': file_source, 'generation': 1})
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=calibration_msg(fx=190.0)))
    assert response.success, response.status_message
    wait_for_diagnostics(peer, diagnostics, {'source': 'set_camera_info', 'generation': 2}, 'set_camera_info adopted')
    bad = calibration_msg()
    bad.k = [float('nan')] * 9
    assert not peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=bad)).success
    rejected_leaves({'source': 'set_camera_info', 'generation': 2})
    assert set_parameters(peer, hfov=120)[0].successful  # a spec parameter: re-solved from the spec
    wait_for_diagnostics(peer, diagnostics, {'source': 'spec', 'generation': 3}, 'the spec re-solved')
    peer.spin_until(lambda: infos[-1].k[0] == pytest.approx(solve_zero_shot(CameraSpec(320, 180, 120, 69)).f,
                                                             abs=1e-6), what='the re-solved CameraInfo')


def _reliabilities(peer):
    """Reliability of the node's camera_info and image_rect publishers and image_raw subscription."""
    def of(infos):
        return {i.qos_profile.reliability for i in infos if i.node_name == NODE}
    graph = peer.node
    return (of(graph.get_publishers_info_by_topic('/camera_info')),
            of(graph.get_publishers_info_by_topic('/image_rect')),
            of(graph.get_subscriptions_info_by_topic('/image_raw')))


def test_image_rect_and_image_raw_qos_follow_the_image_publisher(peer, start_node):
    start_node('--ros-args', *SMALL, '-p', 'rectify:=true')
    image = texture()
    for i, reliability in enumerate([ReliabilityPolicy.BEST_EFFORT, ReliabilityPolicy.RELIABLE]):
        pub = peer.node.create_publisher(Image, 'image_raw', qos(reliability, depth=5))
        want = ({reliability},) * 3
        try:
            peer.spin_until(lambda: _reliabilities(peer) == want, timeout=10,
                            what=f'camera_info, image_rect and image_raw {reliability.name}')
        except AssertionError:
            raise AssertionError(f'(camera_info, image_rect, image_raw) QoS of the node: '
                                 f'{_reliabilities(peer)}, wanted {want}') from None
        # and frames flow to a subscriber of the publisher's reliability
        rects = peer.collect(Image, 'image_rect', qos(reliability, depth=5))
        for n in range(50):
            pub.publish(image_msg(image, 'mono8', (10 * i + 1) * 1_000_000_000 + n))
            peer.spin_for(0.1)
            if rects:
                break
        assert rects and rects[0].header.stamp.sec == 10 * i + 1
        peer.node.destroy_publisher(pub)


def test_timer_camera_info_comes_at_publish_rate_stamped_now(peer, start_node):
    """No image publisher: CameraInfo at publish_rate (20 Hz here, the default is 10), each
    stamped with the time it is sent (the wall clock of this process, a few ms of transport)."""
    start_node('--ros-args', *SMALL, '-p', 'publish_rate:=20.0', '-p', 'frame_id:=timer_frame')
    received = []
    peer.node.create_subscription(CameraInfo, 'camera_info', lambda m: received.append((m, time.time())),
                                  qos(ReliabilityPolicy.RELIABLE, depth=50))  # volatile: no latched one
    peer.spin_until(lambda: len(received) >= 3, what='timer camera_info')
    peer.spin_for(1.0)  # past the start-up
    start = len(received)
    peer.spin_for(3.0)
    window = received[start:]
    # 60 at 20 Hz; a busy machine may delay a few ticks, the default 10 Hz gives 30
    count = len(window)
    assert 45 <= count <= 66, f'{count} CameraInfo in 3 s at publish_rate 20'
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m, _ in window])
    intervals = np.diff(stamps)
    assert np.all(intervals > 0)
    assert np.median(intervals) == pytest.approx(0.05, abs=0.01), np.median(intervals)
    lags = np.array([t for _, t in window]) - stamps
    assert np.all(np.abs(lags) < 0.5), (lags.min(), lags.max())
    assert {m.header.frame_id for m, _ in window} == {'timer_frame'}


def test_read_only_parameters_refuse_new_values(peer, start_node, tmp_path):
    url = f'file://{tmp_path}/calibrations/ro_cam.yaml'
    start_node('--ros-args', *SMALL, '-p', 'camera_name:=ro_cam', '-p', 'publish_rate:=20.0',
               '-p', f'camera_info_url:={url}', '-p', 'max_map_memory_mb:=512')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    f0 = solve_zero_shot(CameraSpec(320, 180, 118, 69)).f
    assert infos[-1].k[0] == pytest.approx(f0, abs=1e-6)
    in_force = {'camera_name': 'ro_cam', 'publish_rate': 20.0, 'camera_info_url': url, 'max_map_memory_mb': 512}
    new = {'camera_name': 'other_cam', 'publish_rate': 5.0, 'camera_info_url': f'file://{tmp_path}/x.yaml',
           'max_map_memory_mb': 64}
    for name, value in new.items():
        result = set_parameters(peer, **{name: value})[0]
        assert not result.successful and name in result.reason and 'read-only' in result.reason, (name, result)
    # with a valid change in the same request: the whole request is refused
    results = set_parameters(peer, hfov=120, publish_rate=5.0)
    assert not any(r.successful for r in results), [r.reason for r in results]
    assert get_parameters(peer, *in_force, 'hfov') == {**in_force, 'hfov': 118}
    # their current values (a params file loaded back) are no change, and succeed
    assert all(r.successful for r in set_parameters(peer, **in_force))
    peer.spin_for(1.0)
    assert {(m.width, m.height, m.k[0]) for m in infos[-5:]} == {(320, 180, infos[0].k[0])}
    n = len(infos)
    peer.spin_for(1.0)  # still 20 Hz, not 5
    assert len(infos) - n >= 14, len(infos) - n


def test_an_exactly_zero_equidistant_fit_publishes_1e_20(peer, start_node):
    """A pure equidistant lens (the circle form alone, read as the pure law: r = f theta,
    f = (d / 2) / (circle_fov / 2)): its equidistant fit is exactly zero, which image_geometry /
    image_proc would read as "no distortion"; the node publishes 1e-20 as k4. A pinhole (hfov and
    vfov of a pinhole, no barrel root: omega 0, f = (w / 2) / tan(hfov / 2)) in plumb_bob has no
    distortion: D stays exactly zero. (One FOV is no pinhole: it takes a real lens' shape.)"""
    start_node('--ros-args', '-p', 'width:=640', '-p', 'height:=480', '-p', 'circle_diameter:=640.0',
               '-p', 'circle_fov:=120.0', '-p', 'projection:=wide-equidistant')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    assert infos[-1].k[0] == pytest.approx(320 / math.radians(60), rel=1e-9)
    assert infos[-1].distortion_model == 'equidistant' and list(infos[-1].d) == [0.0, 0.0, 0.0, 1e-20]
    f = 320 / math.tan(math.radians(60))
    vfov = 2 * math.degrees(math.atan(240 / f)) + 1e-9  # a hair wider than the pinhole's: no barrel root
    # one request, one change (the node applies SetParameters whole)
    assert all(r.successful for r in set_parameters(peer, circle_diameter=0.0, circle_fov=0.0, hfov=120.0, vfov=vfov,
                                                    projection='equidistant', distortion_model='plumb_bob'))
    peer.spin_until(lambda: infos[-1].distortion_model == 'plumb_bob', what='the plumb_bob calibration')
    assert infos[-1].k[0] == pytest.approx(f, rel=1e-9)
    assert list(infos[-1].d) == [0.0] * 5


def test_a_spec_calibration_is_the_full_image_unbinned(peer, start_node):
    """binning 0 and an all-zero roi (do_rectify false), as camera_info_manager publishes a full
    image, on timer CameraInfo and on the CameraInfo of each frame."""
    start_node('--ros-args', *SMALL)
    infos = peer.collect(CameraInfo, 'camera_info', RELIABLE)
    peer.spin_until(lambda: infos, what='timer camera_info')
    pub = peer.image_publisher(RELIABLE)
    pub.publish(image_msg(texture(), 'mono8', 42_000_000_000))
    peer.spin_until(lambda: any(m.header.stamp.sec == 42 for m in infos), what='the frame CameraInfo')
    for m in (infos[0], next(m for m in infos if m.header.stamp.sec == 42)):
        assert (m.width, m.height, m.binning_x, m.binning_y) == (320, 180, 0, 0)
        assert (m.roi.x_offset, m.roi.y_offset, m.roi.width, m.roi.height, m.roi.do_rectify) == (0, 0, 0, 0, False)


BASE = dict(width=320, height=180, hfov=118.0, vfov=69.0, dfov=0.0, projection='auto', balance=0.0,
            fov_scale=1.0, interpolation=1, rectify=True)
# (name, value, None = rejected with a reason naming the parameter | the spec it is a valid camera of)
BAD_VALUES = [
    ('hfov', float('nan'), None), ('hfov', float('inf'), None), ('hfov', -1.0, None),
    ('hfov', 0.0, (320, 180, None, 69.0)),           # 0 = not given: vfov alone, a real lens' shape
    ('vfov', 1e308, None),
    ('hfov', 359.9, (320, 180, 359.9, 69.0)),        # a (wild) wide lens: both FOVs fit r = f' theta'
    ('hfov', 'wide', None), ('hfov', True, None), ('hfov', [118.0, 1.0], None), ('hfov', [1, 2], None),
    ('hfov', [True], None), ('hfov', ['a'], None), ('hfov', None, None), ('width', -1, None),
    ('width', 2 ** 63 - 1, None), ('width', 1920.5, None), ('height', float('nan'), None),
    ('dfov', 50.0, None),                            # narrower than hfov
    ('balance', float('nan'), None), ('fov_scale', float('inf'), None), ('fov_scale', 0.0, None),
    ('interpolation', 3, None), ('interpolation', 2.0, None),
    ('projection', 'orthographic', (320, 180, 118.0, 69.0, 'orthographic')),  # 59 deg < 90: fine
    ('hfov', 200.0, (320, 180, 200.0, 69.0)),        # beyond 180 degrees: the wide models
    ('projection', 5, None), ('rectify', 'yes', None), ('rectify', None, None),
    ('publish_rate', 0.0, None), ('vfov', 300.0, None),  # vfov wider than hfov on a 16:9 image
    ('camera_name', 3, None)]


def test_each_bad_value_through_the_node_has_its_expected_outcome(peer, start_node):
    """Every value through SetParameters (`ros2 param set`) either is rejected with a reason that
    names the parameter, the calibration in force kept, or is a valid camera and is adopted."""
    node = start_node('--ros-args', *SMALL, '-p', 'rectify:=true')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    f_base = solve_zero_shot(CameraSpec(320, 180, 118, 69)).f
    wrong = []
    for name, value, valid_spec in BAD_VALUES:
        result = set_parameters(peer, **{name: value})[0]
        if valid_spec is None:
            if result.successful or name not in result.reason:
                wrong.append((name, value, result.successful, result.reason))
            continue
        if not result.successful:
            wrong.append((name, value, 'valid camera rejected', result.reason))
            continue
        spec, projection = CameraSpec(*valid_spec[:4]), (valid_spec[4:] or ('auto',))[0]
        expected = solve_zero_shot(spec, projection).f
        peer.spin_until(lambda: infos[-1].k[0] == pytest.approx(expected, abs=1e-6), timeout=10,
                        what=f'{name} = {value!r} adopted')
        assert set_atomically(peer, **BASE).successful
        peer.spin_until(lambda: infos[-1].k[0] == pytest.approx(f_base, abs=1e-6), timeout=10, what='restored')
    assert not wrong, wrong
    assert infos[-1].k[0] == pytest.approx(f_base, abs=1e-6)
    assert get_parameters(peer, *BASE) == BASE
    assert node.alive() and 'Traceback' not in node.log
