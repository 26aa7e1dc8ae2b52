"""The node's `refine` (issue 13), end to end: the installed node with refine:=true, this process
streaming frames rendered (test/scenes.py) through a known camera whose principal point is off
centre. The node adopts a refined calibration (CameraInfo nearer the truth, a new generation,
source `refined` in /diagnostics, saved to camera_info_url); a calibration loaded from a file
is never refined."""
import re
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CameraInfo
from sensor_msgs.srv import SetCameraInfo

from ros_peer import LATCHED, diagnostics_value, domain_id, image_msg, peer, qos, start_node  # noqa: F401
from scenes import dense_rms, render
from zeroshot_calib_ros.core import CameraCalibration
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera

TRUE = KannalaBrandtCamera(210.0, 210.0, 327.0, 176.0, 640, 360, np.array([0.02, -0.01, 0.003, -0.0005]))
SPEC = ['-p', 'width:=640', '-p', 'height:=360', '-p', 'hfov:=172.0', '-p', 'vfov:=97.0', '-p', 'dfov:=198.0']
REFINE = ['-p', 'refine:=true', '-p', 'refine_interval:=0.5']
FPS = 15


@pytest.fixture(scope='module')
def frames():
    return [render(TRUE, scene, seed=seed)[0] for scene, seed in (('room', 1), ('corridor', 2))]




def camera_of(info: CameraInfo) -> KannalaBrandtCamera:
    assert info.distortion_model == 'equidistant'
    return KannalaBrandtCamera(info.k[0], info.k[4], info.k[2], info.k[5], info.width, info.height, list(info.d))


def stream(peer, frames, until, timeout):
    """Publish ``frames`` in turn at FPS (stamps of this clock) until ``until()``; the seconds it took."""
    pub = peer.image_publisher(qos())
    start = time.monotonic()
    i = 0
    while not until():
        assert time.monotonic() - start < timeout, f'not within {timeout} s of streaming'
        pub.publish(image_msg(frames[i % len(frames)], 'mono8', time.time_ns()))
        i += 1
        peer.spin_for(1 / FPS)
    return time.monotonic() - start


def test_refine_adopts_a_refined_calibration_while_frames_stream(peer, start_node, tmp_path, frames):  # noqa: F811
    url = tmp_path / 'calibration' / 'camera.yaml'
    node = start_node('--ros-args', *SPEC, *REFINE, '-p', f'camera_info_url:=file://{url}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    peer.spin_until(lambda: infos and diagnostics, what='camera_info and /diagnostics')
    assert diagnostics_value(diagnostics, 'source') == 'spec'
    assert diagnostics_value(diagnostics, 'refine_state') == 'collecting'
    zero_shot = camera_of(infos[-1])
    generation = int(diagnostics_value(diagnostics, 'generation'))
    seconds = stream(peer, frames, lambda: diagnostics_value(diagnostics, 'source') == 'refined', timeout=60)
    # the frames' CameraInfo carries the refined camera from the swap on
    stream(peer, frames, lambda: list(infos[-1].k) != list(zero_shot.K.ravel()), timeout=5)
    assert int(diagnostics_value(diagnostics, 'generation')) > generation
    assert diagnostics_value(diagnostics, 'refine_state') == 'refined'
    assert int(diagnostics_value(diagnostics, 'refine_lines')) >= 8
    assert float(diagnostics_value(diagnostics, 'refine_uncertainty_px')) < \
        float(diagnostics_value(diagnostics, 'refine_zero_shot_uncertainty_px'))
    refined = camera_of(infos[-1])
    assert abs(refined.cx - TRUE.cx) < 2 and abs(refined.cy - TRUE.cy) < 2  # zero-shot: (320, 180)
    error, zero_shot_error = dense_rms(refined, TRUE), dense_rms(zero_shot, TRUE)
    assert error < 1.5 and error < 0.25 * zero_shot_error, (error, zero_shot_error)
    assert int(diagnostics_value(diagnostics, 'refine_adopted')) >= 1
    # saved where set_camera_info would have saved it: the calibration in use (a fit of a frame
    # taken before the stream stopped may still replace it, if clearly better)
    peer.spin_until(lambda: np.allclose(CameraCalibration.load(str(url)).K.ravel(), infos[-1].k, rtol=1e-9),
                    timeout=30, what='the saved calibration to be the one published')
    saved = CameraCalibration.load(str(url))
    np.testing.assert_allclose(saved.K.ravel(), infos[-1].k, rtol=1e-9)
    np.testing.assert_allclose(saved.D.ravel(), infos[-1].d, rtol=1e-9)
    assert 'refinement accepted' in node.log and 'refined calibration adopted' in node.log, node.log
    print(f'adopted after {seconds:.1f} s of streaming')


def test_refine_leaves_a_calibration_from_a_file_alone(peer, start_node, tmp_path, frames):  # noqa: F811
    url = tmp_path / 'camera.yaml'
    K = np.array([[205.0, 0, 330.0], [0, 205.0, 170.0], [0, 0, 1]])
    CameraCalibration(640, 360, K, 'equidistant', np.array([0.01, -0.01, 0.002, 0.0])).save(str(url))
    text = url.read_text()
    node = start_node('--ros-args', *SPEC, *REFINE, '-p', f'camera_info_url:=file://{url}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    peer.spin_until(lambda: infos and diagnostics, what='camera_info and /diagnostics')
    # the same frames as above, for longer than the refinement takes there (3-4 s)
    deadline = time.monotonic() + 5
    stream(peer, frames, lambda: time.monotonic() > deadline, timeout=30)
    assert diagnostics_value(diagnostics, 'source').startswith('file')
    assert diagnostics_value(diagnostics, 'generation') == '0'
    assert diagnostics_value(diagnostics, 'refine_state') == 'off'
    assert 'file' in diagnostics_value(diagnostics, 'refine_reason')
    assert all(list(m.k) == K.ravel().tolist() for m in infos)
    assert url.read_text() == text
    assert 'refined calibration adopted' not in node.log


def test_a_calibration_set_while_refining_stops_the_refinement(peer, start_node, tmp_path, frames):  # noqa: F811
    """set_camera_info (cameracalibrator's COMMIT) while the node refines: the set calibration
    stays, refinement stops and what it was computing is discarded."""
    url = tmp_path / 'camera.yaml'
    node = start_node('--ros-args', *SPEC, *REFINE, '-p', f'camera_info_url:=file://{url}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    peer.spin_until(lambda: infos and diagnostics, what='camera_info and /diagnostics')
    given = CameraInfo(width=640, height=360, distortion_model='equidistant')
    given.k = [205.0, 0.0, 330.0, 0.0, 205.0, 170.0, 0.0, 0.0, 1.0]
    given.d = [0.01, -0.01, 0.002, 0.0]
    given.r = np.eye(3).ravel().tolist()
    given.p = [205.0, 0.0, 330.0, 0.0, 0.0, 205.0, 170.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    # until the node took a frame for refinement (its fit takes seconds): then set a calibration
    stream(peer, frames, lambda: diagnostics_value(diagnostics, 'refine_frames_sampled') is not None, timeout=30)
    assert peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=given)).success
    deadline = time.monotonic() + 5
    stream(peer, frames, lambda: time.monotonic() > deadline, timeout=30)
    assert diagnostics_value(diagnostics, 'source') == 'set_camera_info'
    assert diagnostics_value(diagnostics, 'refine_state') == 'off'
    assert 'set_camera_info' in diagnostics_value(diagnostics, 'refine_reason')
    assert list(infos[-1].k) == list(given.k)
    np.testing.assert_array_equal(CameraCalibration.load(str(url)).K.ravel(), given.k)
    assert re.search(r'refinement stopped \(collecting, [1-9]\d* frame\(s\) taken', node.log), node.log
    assert 'refined calibration adopted' not in node.log


def test_refine_interval_changes_at_run_time_and_the_refined_p_follows_balance_and_fov_scale(peer, start_node,  # noqa: F811
                                                                                              tmp_path, frames):
    """refine_interval set at run time governs the running refiner at once (an hour first: one
    frame taken, then none; 0.5 s: frames taken and a camera refined); the refined CameraInfo's P
    is chosen by the node's balance and fov_scale, as the zero-shot one's is, its principal point
    the refined camera's own (as camera_calibration writes P for a fisheye)."""
    from rcl_interfaces.srv import SetParameters
    from ros_peer import parameter_msg
    from zeroshot_calib_ros.core.ros_formats.rectify import new_camera_matrix, principal_point_camera_matrix
    node = start_node('--ros-args', *SPEC, '-p', 'refine:=true', '-p', 'refine_interval:=3600.0',
                      '-p', 'balance:=0.5', '-p', 'fov_scale:=0.8', '-p', f'camera_info_url:=file://{tmp_path}/c.yaml')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    peer.spin_until(lambda: infos and diagnostics, what='camera_info and /diagnostics')
    zero_shot = camera_of(infos[-1])
    np.testing.assert_allclose(np.reshape(infos[-1].p, (3, 4))[:, :3], new_camera_matrix(zero_shot, 0.5, 0.8),
                               rtol=1e-6)
    assert not np.allclose(new_camera_matrix(zero_shot, 0.5, 0.8), new_camera_matrix(zero_shot, 0.0, 1.0))
    black = [np.zeros_like(frames[0])]
    stream(peer, black, lambda: diagnostics_value(diagnostics, 'refine_frames_sampled') == '1', timeout=30)
    deadline = time.monotonic() + 3  # the room, for longer than a refinement takes: the hour holds
    stream(peer, frames, lambda: time.monotonic() > deadline, timeout=30)
    assert diagnostics_value(diagnostics, 'refine_frames_sampled') == '1'
    assert diagnostics_value(diagnostics, 'source') == 'spec'
    request = SetParameters.Request(parameters=[parameter_msg('refine_interval', 0.5)])
    assert peer.call(SetParameters, '/zeroshot_calib/set_parameters', request).results[0].successful
    stream(peer, frames, lambda: diagnostics_value(diagnostics, 'source') == 'refined', timeout=60)
    assert int(diagnostics_value(diagnostics, 'refine_frames_sampled')) >= 2
    stream(peer, frames, lambda: list(infos[-1].k) != list(zero_shot.K.ravel()), timeout=5)
    refined = camera_of(infos[-1])
    np.testing.assert_allclose(np.reshape(infos[-1].p, (3, 4))[:, :3],
                               principal_point_camera_matrix(refined, 0.5, 0.8), rtol=1e-6)
    assert node.alive()
