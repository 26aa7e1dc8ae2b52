"""The node's calibration life cycle, in a real process (test/ros_peer.py): set_camera_info
answers "success" for what is in force, refuses what its maps cannot hold before saving,
frame sizes evicted from the map cache are rectified again, memory stays bounded over many
frame sizes.
"""
import time

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo

from ros_peer import (LATCHED, diagnostics_value, domain_id, image_msg, peer, qos,  # noqa: F401
                      start_node)

RELIABLE = qos(ReliabilityPolicy.RELIABLE, depth=50)
SPEC_720 = ['-p', 'width:=1280', '-p', 'height:=720', '-p', 'hfov:=118', '-p', 'vfov:=69']
ODD_SIZES = [(640, 360), (320, 180), (960, 540), (480, 270), (1600, 900), (256, 144)]
"""Six frame sizes of the configured aspect ratio beside 1280x720: more than the 4 the map cache holds."""


def rss_mib(pid) -> float:
    with open(f'/proc/{pid}/status') as f:
        return int(next(line for line in f if line.startswith('VmRSS')).split()[1]) / 1024


def stamp_of(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def send_until_rectified(peer, pub, rects, size, stamp, timeout=20.0):
    """Frames of ``size`` every 0.1 s until one comes back as image_rect; returns the next stamp."""
    width, height = size
    frame = np.random.default_rng(width).integers(0, 255, (height, width), np.uint8)
    deadline = time.monotonic() + timeout
    first = stamp
    while time.monotonic() < deadline:
        pub.publish(image_msg(frame, 'mono8', stamp))
        stamp += 1
        peer.spin_for(0.1)
        if any(stamp_of(m) >= first and (m.width, m.height) == size for m in rects):
            return stamp
    raise AssertionError(f'no image_rect of {width}x{height} within {timeout:.0f} s '
                         f'({stamp - first} frames sent)')


def test_every_frame_size_is_rectified_again_after_more_sizes_than_the_cache_holds(peer, start_node):
    """Two rounds over six odd sizes (the cache holds four): each size's frames come back
    rectified in both rounds, the evicted ones after their maps are built again."""
    node = start_node('--ros-args', *SPEC_720, '-p', 'rectify:=true')
    rects = peer.collect(Image, 'image_rect', RELIABLE)
    pub = peer.image_publisher(RELIABLE)
    stamp = 20_000_000_000
    for round_ in range(2):
        for size in ODD_SIZES:
            try:
                stamp = send_until_rectified(peer, pub, rects, size, stamp)
            except AssertionError as exc:
                raise AssertionError(f'round {round_ + 1}: {exc}') from None
    assert node.alive()


RSS_GROWTH_BOUND_MIB = 80
"""What the node may keep after every odd size's maps are released: the freed frame blocks the
heap keeps for the stream by design (trim threshold 64 MiB, core/streaming/heap.py) and the
transport's buffers of the largest frame seen (2560x1920 bgr8: 14 MiB). Before the maps' memory
was given back it kept +210 MiB (+290 MiB at the peak) with 2.3 MB of maps in force."""


def test_memory_is_given_back_after_many_odd_frame_sizes(peer, start_node):
    """bgr8 frames of five other sizes (same aspect ratio, so maps are built for each), two
    rounds, three frames each; once every odd size's maps are released (unused for 10 s), the
    node's RSS is within RSS_GROWTH_BOUND_MIB of what it was before, and /diagnostics says how
    much it holds (process_rss_mb, measured from outside within 10%)."""
    node = start_node('--ros-args', '-p', 'width:=640', '-p', 'height:=480', '-p', 'hfov:=100',
                      '-p', 'vfov:=80', '-p', 'rectify:=true')
    rects = peer.collect(Image, 'image_rect', RELIABLE)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pub = peer.image_publisher(RELIABLE)
    stamp = send_until_rectified(peer, pub, rects, (640, 480), 30_000_000_000)
    peer.spin_for(1.5)
    start = rss_mib(node.process.pid)
    peak = start
    for _ in range(2):
        for width, height in [(1280, 960), (1920, 1440), (2560, 1920), (800, 600), (1600, 1200)]:
            frame = np.zeros((height, width, 3), np.uint8)
            for _ in range(3):
                pub.publish(image_msg(frame, 'bgr8', stamp))
                stamp += 1
                peer.spin_for(0.3)
            peak = max(peak, rss_mib(node.process.pid))
    # the cache holds the configured size and the last three others; the rest were evicted
    peer.spin_until(lambda: all(f'maps of {s} released' in node.log for s in ('2560x1920', '800x600', '1600x1200')),
                    timeout=120, what='the odd sizes\' maps released')  # builds queue up on a loaded machine
    peer.spin_for(2.5)  # a diagnostics message after the release
    end = rss_mib(node.process.pid)
    print(f'node RSS: {start:.0f} MiB before, {peak:.0f} at the peak, {end:.0f} after the release')
    assert end - start <= RSS_GROWTH_BOUND_MIB, (start, peak, end)
    assert float(diagnostics_value(diagnostics, 'map_memory_mb')) < 3  # 640x480 float maps: 2.3 MiB
    assert float(diagnostics_value(diagnostics, 'process_rss_mb')) == pytest.approx(end, rel=0.1)


def camera_info(width, height, f_scale=0.5, d=(0.02, -0.01, 0.003, -0.0005), r=None):
    info = CameraInfo(width=width, height=height, distortion_model='equidistant')
    f = f_scale * width
    info.k = [f, 0.0, width / 2, 0.0, f, height / 2, 0.0, 0.0, 1.0]
    info.d = list(d)
    info.r = list(np.eye(3).ravel() if r is None else np.ravel(r))
    info.p = [0.9 * f, 0.0, width / 2, 0.0, 0.0, 0.9 * f, height / 2, 0.0, 0.0, 0.0, 1.0, 0.0]
    return info


def test_set_camera_info_success_means_in_force(peer, start_node, tmp_path):
    """rectify on, image_rect subscribed, a 4000x3000 calibration (92 MiB of maps, built in ~1 s):
    "adopted and saved" comes when it is in force (every CameraInfo after the reply has it, the
    file holds it); were its maps still building after SET_CAMERA_INFO_WAIT_SECONDS (a busy
    machine), the reply says so, and the file appears only with the calibration in force."""
    path = tmp_path / 'cam.yaml'
    node = start_node('--ros-args', *SPEC_720, '-p', 'rectify:=true', '-p', f'camera_info_url:=file://{path}')
    infos = peer.collect(CameraInfo, 'camera_info', RELIABLE)
    peer.collect(Image, 'image_rect', RELIABLE)
    peer.spin_until(lambda: infos and 'image_rect has a subscriber' in node.log, what='camera_info, image_rect matched')
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=camera_info(4000, 3000)))
    assert response.success, response.status_message
    if 'not in force yet' in response.status_message:
        assert 'are being built' in response.status_message and not path.exists()
        peer.spin_until(lambda: infos[-1].width == 4000, timeout=60, what='the calibration in force')
        peer.spin_until(path.exists, timeout=5, what='the file saved once in force')
    else:
        assert response.status_message == f'calibration adopted and saved to {path}'
        assert yaml.safe_load(path.read_text())['image_width'] == 4000
        peer.spin_for(0.05)  # what was on its way before the reply
        infos.clear()
        peer.spin_for(0.6)
        assert infos and all(m.width == 4000 for m in infos), [m.width for m in infos]


def test_a_small_calibration_from_set_camera_info_is_answered_in_force_and_saved(peer, start_node, tmp_path):
    """rectify on, a 640x360 calibration (1.8 MiB of maps, built in tens of milliseconds, well
    within the SET_CAMERA_INFO_WAIT_SECONDS = 3 s the reply waits): the reply is "calibration
    adopted and saved", as camera_info_manager answers, not "accepted, not in force yet"; the
    file holds it and every CameraInfo after the reply has it. Twice (a recalibration too)."""
    path = tmp_path / 'cam.yaml'
    start_node('--ros-args', *SPEC_720, '-p', 'rectify:=true', '-p', f'camera_info_url:=file://{path}')
    infos = peer.collect(CameraInfo, 'camera_info', RELIABLE)
    peer.spin_until(lambda: infos, what='camera_info')
    for f_scale in (0.5, 0.4):
        info = camera_info(640, 360, f_scale=f_scale)
        response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=info))
        replied_ns = time.time_ns()  # the node stamps its CameraInfo with the same (system) clock
        assert response.success, response.status_message
        assert response.status_message == f'calibration adopted and saved to {path}', response.status_message
        saved = yaml.safe_load(path.read_text())
        assert (saved['image_width'], saved['camera_matrix']['data'][0]) == (640, pytest.approx(info.k[0]))

        def after_reply():
            return [m for m in infos if stamp_of(m) > replied_ns]
        peer.spin_until(lambda: len(after_reply()) >= 3, what='CameraInfo stamped after the reply')
        assert all((m.width, m.k[0]) == (640, pytest.approx(info.k[0])) for m in after_reply()), \
            [(m.width, m.k[0]) for m in after_reply()]


def vm_size_bytes(pid):
    with open(f'/proc/{pid}/status') as f:
        return int(next(line for line in f if line.startswith('VmSize')).split()[1]) * 1024


def test_under_a_memory_limit_a_calibration_whose_maps_cannot_be_built_is_refused_unsaved(
        peer, start_node, tmp_path):
    """The node under ulimit -v (prlimit --as): its default map budget is an eighth of the
    address space left (the start-up block says so), so a 20000x15000 calibration (2.2 GiB of
    maps; 3 GiB, an eighth of this machine, would have allowed it) is refused before it is saved,
    naming the budget; the calibration in force stays, and a restart publishes it."""
    probe = start_node('--ros-args', *SPEC_720, '-p', 'rectify:=true', name='probe')
    peer.spin_until(lambda: 'maps at most max_map_memory_mb' in probe.log, what='the start-up block')
    limit = vm_size_bytes(probe.process.pid) + (3 << 30)  # 3 GiB of address space to spare
    probe.stop()
    path = tmp_path / 'cam.yaml'
    args = ['--ros-args', *SPEC_720, '-p', 'rectify:=true', '-p', f'camera_info_url:=file://{path}']
    node = start_node(*args, prefix=['prlimit', f'--as={limit}', '--'])
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos and 'maps at most max_map_memory_mb' in node.log, what='camera_info')
    assert 'an eighth of ulimit -v (RLIMIT_AS)' in node.log, node.log
    response = peer.call(SetCameraInfo, 'set_camera_info',
                         SetCameraInfo.Request(camera_info=camera_info(20000, 15000)), timeout=60)
    assert not response.success, response.status_message
    assert 'max_map_memory_mb' in response.status_message and '20000x15000' in response.status_message
    assert not path.exists()
    peer.spin_for(1.0)
    assert infos[-1].width == 1280 and node.alive()
    # a calibration that fits is adopted and saved under the same limit
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=camera_info(1280, 720)))
    assert response.success and 'adopted and saved' in response.status_message, response.status_message
    assert yaml.safe_load(path.read_text())['image_width'] == 1280


@pytest.mark.parametrize('field, value, words', [
    ('k', 0, ['K (camera_matrix) fx', 'allowed']),
    ('d', 1, ['D (distortion_coefficients) [1]', 'allowed']),
    ('r', None, ['R (rectification_matrix)', 'a rotation']),
    ('k', 2, ['K (camera_matrix) cx', 'allowed']),
])
def test_set_camera_info_refuses_an_absurd_calibration_naming_the_field(peer, start_node, tmp_path, field, value,
                                                                         words):
    path = tmp_path / 'cam.yaml'
    start_node('--ros-args', *SPEC_720, '-p', f'camera_info_url:=file://{path}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    info = camera_info(1280, 720)
    if field == 'r':
        info.r = list((5 * np.eye(3)).ravel())
    else:
        values = list(getattr(info, field))
        values[value] = 1e300 if field == 'k' and value == 0 else 1e12 if field == 'k' else 1e300
        setattr(info, field, values)
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=info))
    assert not response.success and all(w in response.status_message for w in words), response.status_message
    assert not path.exists()
    peer.spin_for(0.3)
    assert infos[-1].k[0] != info.k[0]


def test_a_calibration_whose_maps_take_long_is_answered_as_not_in_force_yet_and_saved_when_it_is(
        peer, start_node, tmp_path):
    """16000x12000 (1.4 GiB of maps, within the default budget of this machine; ~10 s to build),
    image_rect subscribed (without a subscriber no maps are built: test_node_lazy.py): the reply
    says it is accepted and its maps are being built, no file yet; the calibration in force stays
    until they are built; then it is in force and saved."""
    path = tmp_path / 'cam.yaml'
    node = start_node('--ros-args', *SPEC_720, '-p', 'rectify:=true', '-p', f'camera_info_url:=file://{path}')
    infos = peer.collect(CameraInfo, 'camera_info', RELIABLE)
    peer.collect(Image, 'image_rect', RELIABLE)
    peer.spin_until(lambda: infos and 'image_rect has a subscriber' in node.log, what='camera_info, image_rect matched')
    response = peer.call(SetCameraInfo, 'set_camera_info',
                         SetCameraInfo.Request(camera_info=camera_info(16000, 12000)), timeout=30)
    assert response.success, response.status_message
    assert 'not in force yet' in response.status_message and '16000x12000 are being built' in response.status_message
    assert not path.exists()
    peer.spin_for(0.5)
    assert infos[-1].width == 1280
    peer.spin_until(lambda: infos[-1].width == 16000, timeout=120, what='the calibration in force')
    peer.spin_until(path.exists, timeout=5, what='the file, once in force')
    assert yaml.safe_load(path.read_text())['image_width'] == 16000
    # The node logs after saving, and its output reaches us through a pipe: wait for the line
    saved = f'calibration from set_camera_info in force and saved to {path}'
    peer.spin_until(lambda: saved in node.log, timeout=5, what='the log saying it is in force and saved')


def test_image_rect_honours_the_rotation_of_a_set_camera_info_calibration(peer, start_node):
    """set_camera_info with a 5-degree stereo R (equidistant): image_rect is what OpenCV's maps
    for K, D, R, P make of the frame (image_proc's), within 2 grey levels on a smooth texture."""
    import cv2
    from test_rectify_rotation import calibration, opencv_maps, smooth_image
    from zeroshot_calib_ros.ros.messages import fill_camera_info
    start_node('--ros-args', *SPEC_720, '-p', 'rectify:=true')
    rects = peer.collect(Image, 'image_rect', RELIABLE)
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    cal = calibration('equidistant')
    info = CameraInfo()
    fill_camera_info(info, cal)
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=info))
    assert response.success, response.status_message
    pub = peer.image_publisher(RELIABLE)
    image = smooth_image()
    stamp = 40_000_000_000
    pub.publish(image_msg(image, 'mono8', stamp))
    peer.spin_until(lambda: any(stamp_of(m) == stamp for m in rects), what='image_rect')
    msg = next(m for m in rects if stamp_of(m) == stamp)
    ours = np.frombuffer(bytes(msg.data), np.uint8).reshape(720, 1280).astype(float)
    mx, my = opencv_maps(cal)
    reference = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT).astype(float)
    inside = (mx > 1) & (mx < 1278) & (my > 1) & (my < 718)
    assert np.abs(ours - reference)[inside].max() <= 2
