"""The node's parameters and its refiner seen from another process: values set to what they
already are change nothing, rejections are whole, bounded and say why, unknown names are named,
start-up errors and Ctrl-C end cleanly; refine can be toggled while streaming without losing
frames, a dead worker is reported and restarted, and a restarted refiner keeps the 0.7x rule.
The parameter services and descriptors are ros/parameter_service.py's."""
import os
import re
import signal
import subprocess
import time

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.srv import SetParameters, SetParametersAtomically
from sensor_msgs.msg import CameraInfo

from ros_peer import (LATCHED, NODE_EXECUTABLE, diagnostics_value, domain_id, image_msg, parameter_msg,  # noqa: F401
                      peer, qos, ros_environment, start_node)
from test_node_refine import REFINE, SPEC, frames, stream  # noqa: F401
from scenes import render
from zeroshot_calib_ros.core import CameraCalibration
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera

SPEC_1080 = ['-p', 'width:=1920', '-p', 'height:=1080', '-p', 'hfov:=118', '-p', 'vfov:=69']


def set_parameters(peer, **values):
    request = SetParameters.Request(parameters=[parameter_msg(k, v) for k, v in values.items()])
    return peer.call(SetParameters, '/zeroshot_calib/set_parameters', request).results


def test_setting_the_values_in_force_keeps_a_calibration_from_a_file(peer, start_node, tmp_path):
    """ros2 param dump | load, or ros2 param set hfov 118 when it is 118: no change, the file's
    calibration stays (no spec solution published), no log line naming parameters as changed."""
    url = tmp_path / 'camera.yaml'
    K = np.array([[1000.0, 0, 950.0], [0, 1000.0, 530.0], [0, 0, 1]])
    CameraCalibration(1920, 1080, K, 'equidistant', np.array([0.01, -0.01, 0.002, 0.0])).save(str(url))
    node = start_node('--ros-args', *SPEC_1080, '-p', f'camera_info_url:=file://{url}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    # hfov was given as the INTEGER 118 on the command line: a DOUBLE 118.0 is the same value
    results = set_parameters(peer, width=1920, height=1080, hfov=118.0, vfov=69, projection='auto',
                             distortion_model='equidistant', rectify=False, balance=0.0, publish_rate=10.0)
    assert all(r.successful for r in results), [r.reason for r in results]
    results = set_parameters(peer, hfov=118)
    assert all(r.successful for r in results), [r.reason for r in results]
    peer.spin_for(1.5)
    assert all(list(m.k) == K.ravel().tolist() for m in infos), [m.k[0] for m in infos]
    assert 'parameters changed' not in node.log, node.log
    # a real change still is one
    assert set_parameters(peer, hfov=120.0)[0].successful
    peer.spin_until(lambda: infos[-1].k[0] != K[0, 0], what='the spec solution of hfov 120')
    assert node.log.count('parameters changed') == 1 and 'hfov=120.0' in node.log


def test_a_rejected_request_is_rejected_whole_and_every_result_says_why(peer, start_node):
    node = start_node('--ros-args', *SPEC_1080)
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    for bad in ({'vfov': 400.0}, {'rectfy': True}, {'rectify': 5}, {'camera_name': 'other'}):
        results = set_parameters(peer, publish_rate=10.0, hfov=100.0, **bad)
        assert len(results) == 3 and not any(r.successful for r in results), (bad, [r.reason for r in results])
        assert all(r.reason and list(bad)[0] in r.reason for r in results), (bad, [r.reason for r in results])
    results = set_parameters(peer, rectfy=True)
    assert "did you mean 'rectify'" in results[0].reason and '[]' not in results[0].reason, results[0].reason
    # a read-only value given as another type (False for the integer 0) is a change, refused
    results = set_parameters(peer, max_map_memory_mb=False, hfov=100.0)
    assert not any(r.successful for r in results) and all('max_map_memory_mb' in r.reason for r in results)
    # SetParametersAtomically (one result) by the same rules: a params file loaded back succeeds
    for values, ok in (({'publish_rate': 10.0, 'vfov': 400.0}, False), ({'publish_rate': 10.0, 'hfov': 100.0}, True)):
        request = SetParametersAtomically.Request(parameters=[parameter_msg(k, v) for k, v in values.items()])
        result = peer.call(SetParametersAtomically, '/zeroshot_calib/set_parameters_atomically', request).result
        assert result.successful == ok and (ok or 'vfov' in result.reason), result.reason
    peer.spin_until(lambda: infos[-1].k[0] != infos[0].k[0], what='the hfov 100 calibration')


def test_a_huge_rejected_value_is_shown_cut_and_its_repetitions_throttled(peer, start_node):
    node = start_node('--ros-args', *SPEC_1080)
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    huge = 'x' * 1_000_000
    for _ in range(3):
        results = set_parameters(peer, projection=huge)
        assert not results[0].successful
        assert len(results[0].reason) < 400 and '1000000 characters' in results[0].reason, len(results[0].reason)
    peer.spin_for(0.5)
    log = node.log
    assert max(len(line) for line in log.splitlines()) < 1000
    assert log.count('1000000 characters') == 1, log  # the same rejection again within seconds: not logged


def test_unknown_parameters_from_the_command_line_are_named(peer, start_node):
    node = start_node('--ros-args', *SPEC_1080, '-p', 'rectfy:=true')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    peer.spin_until(lambda: 'rectfy' in node.log, timeout=5, what='a warning naming rectfy')
    assert "did you mean 'rectify'" in node.log, node.log


@pytest.mark.parametrize('case', ['missing', 'directory', 'no file after it'])
def test_a_missing_params_file_is_one_clear_line(tmp_path, case):
    """--params-file naming a missing file or a directory, or given last with no file after it:
    one line on stderr saying what is wrong (naming the path), exit status 2, no traceback."""
    path = {'missing': tmp_path / 'missing.yaml', 'directory': tmp_path, 'no file after it': None}[case]
    args = ['--ros-args', '--params-file'] + ([] if path is None else [str(path)])
    done = subprocess.run([str(NODE_EXECUTABLE), *args], capture_output=True, text=True, timeout=60,
                          env=ros_environment(98))
    output = done.stdout + done.stderr
    assert done.returncode == 2, (done.returncode, output)
    assert 'Traceback' not in output, output
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    expected = {'missing': [str(path), 'no such file'], 'directory': [str(path), 'is a directory'],
                'no file after it': ['--params-file needs a file']}[case]
    assert all(words in lines[0] for words in expected), output


@pytest.mark.parametrize('delay', [0.05, 0.1, 0.15, 0.2, 0.3, 0.45, 0.6, 1.0, 2.5])
def test_ctrl_c_at_any_moment_ends_without_a_traceback(tmp_path, delay):
    env = ros_environment(97)
    env['ROS_HOME'] = str(tmp_path)
    process = subprocess.Popen([str(NODE_EXECUTABLE), '--ros-args', *SPEC_1080], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, env=env)
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=30)
    if output.startswith('Fatal Python error: init_import_site'):
        # On a loaded machine 0.05 s can fall inside the interpreter's own start-up (its site
        # import), before any line of the program runs: no program can catch that.
        assert delay <= 0.05, output
        return
    assert 'Traceback' not in output and 'KeyboardInterrupt' not in output, output
    assert process.returncode == 0, (process.returncode, output)


def test_ctrl_c_inside_the_executors_construction_prints_nothing(monkeypatch):
    """Ctrl-C can land inside rclpy's Executor.__init__ (seen on CI at 0.2 s after start). The
    half-built executor must not print 'Exception ignored in Executor.__del__' with a traceback
    when it is collected: the user pressed Ctrl-C and expects a quiet exit."""
    import gc
    import sys

    import rclpy
    import rclpy.executors
    from zeroshot_calib_ros.ros.executors import create_executor

    context = rclpy.Context()
    context.init(args=['--ros-args'])
    unraisable = []
    monkeypatch.setattr(sys, 'unraisablehook', unraisable.append)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(rclpy.executors, 'Clock', interrupted)  # past the guard, before the SIGINT guard
    try:
        with pytest.raises(KeyboardInterrupt):
            create_executor('single', context=context)
        gc.collect()
        monkeypatch.undo()
        executor, name, _ = create_executor('single', context=context)  # uninterrupted: rclpy's, working
        assert name == 'single' and isinstance(executor, rclpy.executors.SingleThreadedExecutor)
        task = executor.create_task(lambda: 42)
        executor.spin_once(timeout_sec=1.0)
        assert task.result() == 42
        executor.shutdown()
    finally:
        context.try_shutdown()
    assert [repr(u.exc_value) for u in unraisable] == []


def test_toggling_refine_while_streaming_loses_no_camera_info(peer, start_node, tmp_path, frames):  # noqa: F811
    """refine off/on 20 times at 30 fps while the worker is fitting: turning it off never waits
    for the worker on the node's executor thread, so no CameraInfo goes missing."""
    fps = 30
    start_node('--ros-args', *SPEC, '-p', 'refine:=true', '-p', 'refine_interval:=0.1',
               '-p', f'camera_info_url:=file://{tmp_path}/camera.yaml')
    arrivals = []
    peer.node.create_subscription(CameraInfo, 'camera_info', lambda m: arrivals.append(time.monotonic()),
                                  qos(depth=100))
    pub = peer.image_publisher(qos(depth=100))
    client = peer.node.create_client(SetParameters, '/zeroshot_calib/set_parameters')
    peer.spin_until(client.service_is_ready, what='set_parameters')
    refine, future, toggles, sent = True, None, 0, 0
    start = time.monotonic()
    next_toggle = start + 1.0
    while toggles < 20 or not future.done():
        now = time.monotonic()
        if now >= start + sent / fps:
            pub.publish(image_msg(frames[sent % len(frames)], 'mono8', time.time_ns()))
            sent += 1
        if toggles < 20 and (future is None or future.done()) and now >= next_toggle:
            refine = not refine
            request = SetParameters.Request(parameters=[parameter_msg('refine', refine)])
            future = client.call_async(request)
            toggles += 1
            next_toggle = now + 0.3
        peer.executor.spin_once(timeout_sec=0.002)
        assert now - start < 60
    end = time.monotonic()
    peer.spin_for(1.0)
    during = [t for t in arrivals if start + 1.0 <= t <= end]
    gaps = np.diff(during)
    print(f'{sent} frames in {end - start:.1f} s, {len(arrivals)} CameraInfo, largest gap {gaps.max():.3f} s')
    assert gaps.max() < 0.5, gaps.max()
    assert len(arrivals) >= 0.95 * sent, (len(arrivals), sent)


def _stream_until_refined(peer, node, frames, tmp_path):  # noqa: F811
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos and diagnostics, what='camera_info and /diagnostics')
    stream(peer, frames, lambda: diagnostics_value(diagnostics, 'source') == 'refined', timeout=180)
    return diagnostics


def test_a_restarted_refiner_does_not_readopt_a_fit_that_is_not_better(peer, start_node, tmp_path, frames):  # noqa: F811
    url = tmp_path / 'camera.yaml'
    node = start_node('--ros-args', *SPEC, *REFINE, '-p', f'camera_info_url:=file://{url}')
    diagnostics = _stream_until_refined(peer, node, frames, tmp_path)
    generation = diagnostics_value(diagnostics, 'generation')
    saved = url.read_text()
    assert all(r.successful for r in set_parameters(peer, refine=False))
    assert all(r.successful for r in set_parameters(peer, refine=True))
    # the same frames again: the new refiner's fits are no better than the calibration in force
    # (until it has fitted 3 frames, however long a loaded machine takes)
    diagnostics.clear()
    peer.spin_until(lambda: diagnostics and diagnostics_value(diagnostics, 'refine_frames') == '0', timeout=10,
                    what="the new refiner's diagnostics")
    stream(peer, frames, lambda: int(diagnostics_value(diagnostics, 'refine_frames')) >= 3, timeout=120)
    assert diagnostics_value(diagnostics, 'generation') == generation
    assert url.read_text() == saved
    assert node.log.count('refined calibration adopted') == 1, node.log


def test_a_refine_worker_killed_after_adopting_is_reported_and_restarted(peer, start_node, tmp_path, frames):  # noqa: F811
    url = tmp_path / 'camera.yaml'
    node = start_node('--ros-args', *SPEC, *REFINE, '-p', f'camera_info_url:=file://{url}')
    diagnostics = _stream_until_refined(peer, node, frames, tmp_path)
    pid = int(re.findall(r'worker pid (\d+)', node.log)[-1])
    os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 4
    stream(peer, frames, lambda: time.monotonic() > deadline, timeout=30)
    assert diagnostics_value(diagnostics, 'refine_state') == 'failed'
    assert 'code -9' in diagnostics_value(diagnostics, 'refine_reason')
    warnings = [line for line in node.log.splitlines() if 'WARN' in line and 'code -9' in line]
    assert len(warnings) == 1, node.log
    assert all(r.successful for r in set_parameters(peer, refine=False))
    assert all(r.successful for r in set_parameters(peer, refine=True))
    peer.spin_until(lambda: len(re.findall(r'worker pid (\d+)', node.log)) == 2, timeout=5, what='a new worker')
    deadline = time.monotonic() + 3
    stream(peer, frames, lambda: time.monotonic() > deadline, timeout=30)
    assert diagnostics_value(diagnostics, 'refine_state') != 'failed'
    assert diagnostics_value(diagnostics, 'source') == 'refined'


def test_one_frame_of_another_size_first_does_not_block_refinement(peer, start_node, tmp_path, frames):  # noqa: F811
    url = tmp_path / 'camera.yaml'
    node = start_node('--ros-args', *SPEC, *REFINE, '-p', f'camera_info_url:=file://{url}')
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    peer.spin_until(lambda: diagnostics, what='/diagnostics')
    pub = peer.image_publisher(qos())
    big = cv2.resize(frames[1], (1280, 720), interpolation=cv2.INTER_LINEAR)  # twice the size, with lines
    pub.publish(image_msg(big, 'mono8', time.time_ns()))
    peer.spin_until(lambda: diagnostics_value(diagnostics, 'refine_frames') == '1', timeout=60,
                    what='the odd frame processed')
    # then the stream's own size: refinement goes on at that size
    stream(peer, frames, lambda: int(diagnostics_value(diagnostics, 'refine_frames')) >= 4, timeout=180)
    assert diagnostics_value(diagnostics, 'refine_state') != 'error', diagnostics_value(diagnostics, 'refine_reason')
    refine_warnings = [line for line in node.log.splitlines() if 'WARN' in line and 'refine' in line]
    assert len(refine_warnings) <= 1, refine_warnings
    stream(peer, frames, lambda: diagnostics_value(diagnostics, 'source') == 'refined', timeout=180)


NARROW = KannalaBrandtCamera(420.0, 420.0, 340.0, 168.0, 640, 360, np.array([0.12, -0.03, 0.0, 0.0]))
NARROW_SPEC = ['-p', 'width:=640', '-p', 'height:=360', '-p', 'hfov:=82.8', '-p', 'vfov:=48.1']  # NARROW's, rounded


def test_refine_publishes_and_saves_the_configured_plumb_bob_model(peer, start_node, tmp_path):  # noqa: F811
    """distortion_model plumb_bob (a narrow lens, as config/c922.yaml): the refined camera is
    published and saved in plumb_bob (fitted to the refined lens), in an .ini file too."""
    url = tmp_path / 'camera.ini'
    room = [render(NARROW, 'room', seed=1)[0]]
    node = start_node('--ros-args', *NARROW_SPEC, '-p', 'distortion_model:=plumb_bob', *REFINE,
                      '-p', f'camera_info_url:=file://{url}')
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos and diagnostics, what='camera_info and /diagnostics')
    stream(peer, room, lambda: diagnostics_value(diagnostics, 'source') == 'refined', timeout=180)
    stream(peer, room, lambda: infos[-1].k[2] != infos[0].k[2], timeout=5)
    info = infos[-1]
    assert info.distortion_model == 'plumb_bob' and len(info.d) == 5, (info.distortion_model, info.d)
    assert abs(info.k[2] - NARROW.cx) < 3 and abs(info.k[5] - NARROW.cy) < 3, info.k  # zero-shot: (320, 180)
    peer.spin_until(url.exists, timeout=10, what=f'{url} to be saved')
    saved = CameraCalibration.load(str(url))
    assert saved.distortion_model == 'plumb_bob'
    np.testing.assert_allclose(saved.K.ravel(), info.k, rtol=1e-9)
    assert 'fitted to the refined lens' in node.log, node.log


def test_a_spec_whose_fovs_the_camera_misses_is_warned_at_start_up_on_a_change_and_in_diagnostics(peer, start_node):
    """hfov 118 / vfov 117 on 1920x1080 (the solved camera has 129.4 x 99.9): a WARN naming both
    values at start-up and /diagnostics at WARN level with spec_warning; an honest change (vfov 69)
    clears it, another contradictory one (vfov 100: 92.7) warns again; swapped FOVs are rejected
    saying so, and swapped sides stop the start with one line."""
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    node = start_node('--ros-args', '-p', 'width:=1920', '-p', 'height:=1080', '-p', 'hfov:=118', '-p', 'vfov:=117')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    warned = [line for line in node.log.splitlines() if 'vfov: given 117 deg, the solved camera has 99.9 deg' in line]
    assert len(warned) == 1 and warned[0].startswith('[WARN]') and 'hfov: given 118 deg' in warned[0], node.log

    def status():
        return diagnostics[-1].status[0] if diagnostics else None
    peer.spin_until(lambda: status() is not None, what='/diagnostics')
    assert status().level == DiagnosticStatus.WARN and 'do not fit' in status().message
    assert 'vfov: given 117 deg' in diagnostics_value(diagnostics, 'spec_warning')

    assert set_parameters(peer, vfov=69.0)[0].successful
    peer.spin_until(lambda: status().level == DiagnosticStatus.OK and
                    'spec_warning' not in {kv.key for kv in status().values}, what='diagnostics back to OK')
    assert node.log.count('[WARN]') == 1, node.log
    assert set_parameters(peer, vfov=100.0)[0].successful
    peer.spin_until(lambda: 'vfov: given 100 deg, the solved camera has 92.7 deg' in node.log, what='the WARN')
    line = next(x for x in node.log.splitlines() if 'given 100 deg' in x)
    assert line.startswith('[WARN]') and node.log.index('parameters changed') < node.log.index(line)
    peer.spin_until(lambda: status().level == DiagnosticStatus.WARN, what='diagnostics at WARN again')

    result = set_parameters(peer, hfov=69.0, vfov=118.0)
    assert not any(r.successful for r in result) and all('hfov and vfov look swapped' in r.reason for r in result)
    peer.spin_until(lambda: 'parameter change rejected' in node.log, what='the rejection')
    assert 'look swapped' in next(x for x in node.log.splitlines() if 'parameter change rejected' in x)

    turned = start_node('--ros-args', '-p', 'width:=1080', '-p', 'height:=1920', '-p', 'hfov:=118', '-p', 'vfov:=69',
                        name='turned')
    assert turned.wait(30) == 2
    lines = turned.log.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('zeroshot_calib: error: width, height = ') and \
        'width and height look swapped' in lines[0], turned.log


def test_one_fov_is_warned_as_an_assumption_at_start_up_and_named_in_diagnostics_until_a_second_fov(peer, start_node):
    """hfov alone: the lens shape is assumed from real lenses of that FOV (a fisheye, not a
    pinhole: f near 896 px, where the pinhole reading gave 577). The node says so once as a WARN
    (as the CLI's warning) and /diagnostics carries it as `assumption` while staying OK (the
    camera is usable, only less certain); giving vfov pins the shape and the key goes away."""
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    node = start_node('--ros-args', '-p', 'width:=1920', '-p', 'height:=1080', '-p', 'hfov:=118')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    assert 800 < infos[-1].k[0] < 1000, infos[-1].k  # a fisheye's f, not the pinhole's 577
    warned = [line for line in node.log.splitlines() if line.startswith('[WARN]') and 'one FOV (hfov 118 deg)' in line]
    assert len(warned) == 1 and 'give a second FOV' in warned[0], node.log

    def status():
        return diagnostics[-1].status[0] if diagnostics else None
    peer.spin_until(lambda: status() is not None, what='/diagnostics')
    assert status().level == DiagnosticStatus.OK
    assert 'one FOV (hfov 118 deg)' in diagnostics_value(diagnostics, 'assumption')

    assert set_parameters(peer, vfov=69.0)[0].successful
    peer.spin_until(lambda: 'assumption' not in {kv.key for kv in status().values}, what='assumption gone')
    assert status().level == DiagnosticStatus.OK
    assert node.log.count('[WARN]') == 1, node.log
