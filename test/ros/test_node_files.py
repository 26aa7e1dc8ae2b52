"""Calibration files through the node, as camera_info_manager and camera_calibration use them:
the default URL under $ROS_HOME, ${NAME} / ${ROS_HOME}, cameracalibrator's COMMIT
(set_camera_info) surviving a restart, binning and roi kept, files without distortion_model,
.ini files, and broken files that must never crash the node."""
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo

from ros_peer import (LATCHED, diagnostics_value, domain_id, image_msg, peer, qos, ros_environment,  # noqa: F401
                      start_node)
from test_bringup import SHARE, launch_ros_arguments
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot

SPEC_720 = ['-p', 'width:=1280', '-p', 'height:=720', '-p', 'hfov:=86.5', '-p', 'vfov:=47.8']


def calibrated_info(width=1280, height=720, fx=871.5, model='plumb_bob'):
    """A CameraInfo as camera_calibration's MonoCalibrator.as_message() fills it."""
    msg = CameraInfo(width=width, height=height, distortion_model=model)
    msg.k = [fx, 0.0, 641.0, 0.0, fx, 359.0, 0.0, 0.0, 1.0]
    msg.d = [-0.31, 0.11, 0.0005, -0.0003, -0.02] if model == 'plumb_bob' else [0.02, -0.01, 0.003, -0.0005]
    msg.r = np.eye(3).ravel().tolist()
    msg.p = [fx * 0.9, 0.0, 640.0, 0.0, 0.0, fx * 0.9, 360.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


CAMERACALIBRATOR_COMMIT = textwrap.dedent('''
    """cameracalibrator's COMMIT: a client on its relative "camera/set_camera_info", remapped as
    users start it, called with the calibration (camera_calibration/camera_calibrator.py)."""
    import sys
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import CameraInfo
    from sensor_msgs.srv import SetCameraInfo
    rclpy.init(args=sys.argv)
    node = Node('cameracalibrator')
    client = node.create_client(SetCameraInfo, 'camera/set_camera_info')
    assert client.wait_for_service(timeout_sec=20), 'no ' + client.srv_name
    info = CameraInfo(width=1280, height=720, distortion_model='equidistant')
    info.k = [650.0, 0.0, 641.0, 0.0, 650.0, 359.0, 0.0, 0.0, 1.0]
    info.d = [0.02, -0.01, 0.003, -0.0005]
    info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    info.p = [600.0, 0.0, 640.0, 0.0, 0.0, 600.0, 360.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    future = client.call_async(SetCameraInfo.Request(camera_info=info))
    rclpy.spin_until_future_complete(node, future, timeout_sec=20)
    print(client.srv_name, future.result().success, future.result().status_message)
''')


def test_cameracalibrator_commit_is_saved_to_the_default_url_and_survives_a_restart(
        peer, start_node, tmp_path, domain_id):  # noqa: F811
    """The node as the launch file starts it (namespace my_camera, no camera_info_url): the
    default URL file://${ROS_HOME}/camera_info/${NAME}.yaml, as camera_info_manager."""
    params = SHARE / 'config' / 'hero9_w1.yaml'
    args = launch_ros_arguments(tmp_path, params, namespace='/my_camera', parameters={'camera_name': 'front_cam'})
    args += [*SPEC_720, '-p', 'projection:=auto']
    node = start_node(*args)
    expected_path = tmp_path / 'ros_home' / 'camera_info' / 'front_cam.yaml'
    peer.spin_until(lambda: f'none at {expected_path} yet: set_camera_info will save there' in node.log,
                    timeout=15, what='the calibration-file line of the start-up block')
    script = tmp_path / 'cameracalibrator_commit.py'
    script.write_text(CAMERACALIBRATOR_COMMIT)
    env = ros_environment(domain_id)
    done = subprocess.run([sys.executable, str(script), '--ros-args', '-r',
                           'camera/set_camera_info:=/my_camera/set_camera_info'],
                          env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.startswith('camera/set_camera_info True calibration adopted and saved to '), done.stdout
    saved = yaml.safe_load(expected_path.read_text())
    assert saved['camera_name'] == 'front_cam' and saved['camera_matrix']['data'][0] == 650.0
    node.stop()
    restarted = start_node(*args, name='restarted')
    peer.spin_until(lambda: f'loaded {expected_path}' in restarted.log, what='the file loaded on restart')
    infos = peer.collect(CameraInfo, '/my_camera/camera_info', LATCHED)
    peer.spin_until(lambda: infos and infos[-1].k[0] == 650.0, what='the committed calibration published')
    assert infos[-1].distortion_model == 'equidistant' and list(infos[-1].d) == [0.02, -0.01, 0.003, -0.0005]


def test_url_variables_and_a_file_of_another_camera(peer, start_node, tmp_path):
    """${ROS_HOME} and ${NAME} are substituted; a file whose camera_name and size differ from
    the node's is used, with a warning that names both."""
    ros_home = tmp_path / 'ros_home'
    path = ros_home / 'calibrations' / 'cam_a.yaml'
    path.parent.mkdir(parents=True)
    other = solve_zero_shot(CameraSpec(1920, 1080, 118, 69))
    K = other.K.ravel().tolist()
    path.write_text(yaml.safe_dump({
        'image_width': 1920, 'image_height': 1080, 'camera_name': 'rear_cam',
        'camera_matrix': {'rows': 3, 'cols': 3, 'data': K},
        'distortion_model': 'equidistant', 'distortion_coefficients': {'rows': 1, 'cols': 4, 'data': [0.06, 0, 0, 0]},
        'rectification_matrix': {'rows': 3, 'cols': 3, 'data': np.eye(3).ravel().tolist()},
        'projection_matrix': {'rows': 3, 'cols': 4, 'data': [K[0], 0, K[2], 0, 0, K[4], K[5], 0, 0, 0, 1, 0]}}))
    node = start_node('--ros-args', *SPEC_720, '-p', 'camera_name:=cam_a',
                      '-p', 'camera_info_url:=file://${ROS_HOME}/calibrations/${NAME}.yaml')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    assert infos[-1].k[0] == K[0] and (infos[-1].width, infos[-1].height) == (1920, 1080)
    peer.spin_until(lambda: f'loaded {path}' in node.log, timeout=5, what='the loaded line')
    warnings = [line for line in node.log.splitlines() if line.startswith('[WARN]')]
    assert any("'rear_cam'" in w and "'cam_a'" in w for w in warnings), warnings
    assert any('1920x1080' in w and '1280x720' in w for w in warnings), warnings


def test_binning_and_roi_are_kept_and_not_rectified_wrongly(peer, start_node, tmp_path):
    node = start_node('--ros-args', *SPEC_720, '-p', 'rectify:=true')
    infos = peer.collect(CameraInfo, 'camera_info', qos(ReliabilityPolicy.RELIABLE, depth=20))
    rects = peer.collect(Image, 'image_rect', qos(ReliabilityPolicy.RELIABLE))
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    peer.spin_until(lambda: infos, what='camera_info')
    info = calibrated_info()
    info.binning_x = info.binning_y = 2
    info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = 320, 180, 640, 360
    response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=info))
    assert response.success, response.status_message
    saved = tmp_path / 'ros_home' / 'camera_info' / 'camera.yaml'
    assert saved.exists()
    peer.spin_until(lambda: infos[-1].k[0] == 871.5, what='the new calibration')
    latest = infos[-1]
    assert (latest.binning_x, latest.binning_y) == (2, 2)
    assert (latest.roi.x_offset, latest.roi.y_offset, latest.roi.width, latest.roi.height) == (320, 180, 640, 360)
    # a binned ROI frame (640x360 of the full image, binned 2: 320x180): CameraInfo as given,
    # unscaled (binning and roi say how it maps), and no image_rect from the node (image_proc's job)
    pub = peer.image_publisher(qos(ReliabilityPolicy.RELIABLE))
    pub.publish(image_msg(np.zeros((180, 320), np.uint8), 'mono8', 4_000_000_000))
    peer.spin_until(lambda: diagnostics_value(diagnostics, 'frames_skipped_binning_roi') == '1',
                    what='the frame counted as binning/roi')
    assert not rects
    framed = next(m for m in infos if m.header.stamp.sec == 4)
    assert (framed.width, framed.height, framed.k[0], framed.binning_x) == (1280, 720, 871.5, 2)
    peer.spin_until(lambda: 'binning 2x2' in node.log, timeout=5, what='the warning')
    node.stop()
    restarted = start_node('--ros-args', *SPEC_720, name='restarted')
    again = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: again and again[-1].k[0] == 871.5, what='the saved calibration after a restart')
    assert (again[-1].binning_x, again[-1].roi.width) == (2, 640) and restarted.alive()


def test_file_without_distortion_model_and_ini_files(peer, start_node, tmp_path):
    legacy = tmp_path / 'legacy.yaml'
    legacy.write_text(textwrap.dedent('''\
        image_width: 1280
        image_height: 720
        camera_name: legacy
        camera_matrix: {rows: 3, cols: 3, data: [900.0, 0, 640, 0, 900.0, 360, 0, 0, 1]}
        distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.01, 0, 0, 0]}
        rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
        projection_matrix: {rows: 3, cols: 4, data: [900.0, 0, 640, 0, 0, 900.0, 360, 0, 0, 0, 1, 0]}
        '''))
    node = start_node('--ros-args', *SPEC_720, '-p', 'camera_name:=legacy', '-p', f'camera_info_url:=file://{legacy}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    assert infos[-1].distortion_model == 'plumb_bob' and infos[-1].k[0] == 900.0
    peer.spin_until(lambda: 'plumb_bob' in node.log and '[WARN]' in node.log, timeout=5, what='the warning')
    node.stop()
    # camera_calibration_parsers' .ini layout (writeCalibrationIni)
    ini = tmp_path / 'cam.ini'
    ini.write_text(textwrap.dedent('''\
        # Camera intrinsics

        [image]

        width
        1280

        height
        720

        [narrow_stereo]

        camera matrix
        880.00000 0.00000 640.00000
        0.00000 880.00000 360.00000
        0.00000 0.00000 1.00000

        distortion
        -0.20000 0.05000 0.00000 0.00000 0.00000

        rectification
        1.00000 0.00000 0.00000
        0.00000 1.00000 0.00000
        0.00000 0.00000 1.00000

        projection
        800.00000 0.00000 640.00000 0.00000
        0.00000 800.00000 360.00000 0.00000
        0.00000 0.00000 1.00000 0.00000
        '''))
    node = start_node('--ros-args', *SPEC_720, '-p', f'camera_info_url:=file://{ini}', name='ini')
    infos.clear()
    peer.spin_until(lambda: infos and infos[-1].k[0] == 880.0, what='the .ini calibration')
    assert infos[-1].p[0] == 800.0 and infos[-1].distortion_model == 'plumb_bob'


@pytest.mark.parametrize('content', [
    'image_width: .inf\nimage_height: 720\n',
    '[' * 100_000 + ']' * 100_000 + '\n',
    'image_width: 1280.9\nimage_height: 720\n',
    '\x00\x01binary garbage\xff',
], ids=['inf', 'deep', 'fraction', 'binary'])
def test_a_broken_calibration_file_never_crashes_start_up(peer, start_node, tmp_path, content):
    bad = tmp_path / 'bad.yaml'
    bad.write_bytes(content.encode('utf-8', 'surrogateescape'))
    node = start_node('--ros-args', *SPEC_720, '-p', f'camera_info_url:=file://{bad}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info from the spec')
    assert infos[-1].k[0] == pytest.approx(solve_zero_shot(CameraSpec(1280, 720, 86.5, 47.8)).f)
    errors = [line for line in node.log.splitlines() if line.startswith('[ERROR]')]
    assert len(errors) == 1 and f'ignoring camera_info_url {bad}' in errors[0], node.log
    assert 'Traceback' not in node.log and node.alive()
