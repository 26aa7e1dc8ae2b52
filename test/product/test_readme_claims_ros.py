"""Claims of the README and docs/ros.md about the ROS node that no other test checked (the map of
every claim to its test is docs/readme_claims.md), each against the installed node in its own
process: the Parameters table (defaults, types, read-only, ranges, `--help`), the start-up log
docs/ros.md shows, the /diagnostics rate, integers in a params file, set_camera_info's answer
when the calibration is adopted but cannot be saved, `make echo`, and importing the library from
the install tree with the venv's Python.
"""
import re
import subprocess
import time

import cv2
import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters
from sensor_msgs.msg import CameraInfo
from sensor_msgs.srv import SetCameraInfo

from ros_peer import (LATCHED, NODE_EXECUTABLE, REPO, domain_id, peer, qos, ros_environment,  # noqa: F401
                      start_node)

from doc_pages import fenced_blocks, page, section

README = page('README.md')
ROS_DOC = page('docs/ros.md')
SHARE = REPO / 'install' / 'zeroshot_calib_ros' / 'share' / 'zeroshot_calib_ros'
NODE = '/zeroshot_calib'
RCLPY_PARAMETERS = {'use_sim_time', 'start_type_description_service'}  # every rclpy node has them


def readme_parameters():
    """{name: (type cell, default cell)} of docs/ros.md's Parameters table."""
    table = {}
    for line in section('docs/ros.md', 'Parameters').splitlines()[4:]:
        if not line.startswith('|'):
            break
        names, kind, default = [c.strip() for c in line.strip('|').split('|')][:3]
        for name in re.findall(r'`([a-z_]+)`', names):
            table[name] = (kind, default)
    return table


ROS_TYPES = {'string': ParameterType.PARAMETER_STRING, 'int': ParameterType.PARAMETER_INTEGER,
             'double': ParameterType.PARAMETER_DOUBLE, 'bool': ParameterType.PARAMETER_BOOL}


def expected_default(kind, cell):
    """The value a README default cell means for a parameter of that type."""
    base = kind.split()[0].rstrip(',')
    word = cell.split(' =')[0].strip('`').strip()
    if cell.startswith('required'):
        word = '0'  # not given: the node takes it from the preset (or refuses to start)
    if base == 'string':
        return '' if word == 'empty' else word
    if base == 'bool':
        return {'false': False, 'true': True}[word]
    return {'int': int, 'double': float}[base](word)


def _value(v):
    return {ParameterType.PARAMETER_BOOL: v.bool_value, ParameterType.PARAMETER_INTEGER: v.integer_value,
            ParameterType.PARAMETER_DOUBLE: v.double_value, ParameterType.PARAMETER_STRING: v.string_value}[v.type]


def _mem_total_mib():
    line = next(line for line in open('/proc/meminfo') if line.startswith('MemTotal:'))
    return int(line.split()[1]) * 1024 / 2**20


def test_parameters_table_is_what_the_node_declares(peer, start_node):
    """ros.md, Parameters: every row's name, type, default, read-only flag and range ([0, 1] for
    balance, [0.1, 10] for fov_scale) is what the running node declares (ListParameters,
    GetParameters, DescribeParameters); and `node --help` prints "usage and every parameter,
    exit 0". The node is started from the preset alone, so every other parameter keeps its default
    (the preset's default is checked in --help)."""
    table = readme_parameters()
    assert len(table) == 21
    start_node('--ros-args', '-p', 'preset:=gopro_hero9_wide')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    assert infos[-1].k[0] == pytest.approx(876.0, abs=0.05)  # the preset's camera (Table 2, Hero9(W1))
    listed = peer.call(ListParameters, f'{NODE}/list_parameters', ListParameters.Request()).result.names
    ours = {n for n in listed if n not in RCLPY_PARAMETERS and not n.startswith('qos_overrides')}
    assert ours == set(table), (ours ^ set(table))
    names = list(table)
    values = peer.call(GetParameters, f'{NODE}/get_parameters', GetParameters.Request(names=names)).values
    described = peer.call(DescribeParameters, f'{NODE}/describe_parameters',
                          DescribeParameters.Request(names=names)).descriptors
    for name, value, descriptor in zip(names, values, described):
        kind, default = table[name]
        expected = expected_default(kind, default) if name != 'preset' else 'gopro_hero9_wide'  # given
        assert value.type == ROS_TYPES[kind.split()[0].rstrip(',')], (name, value.type)
        assert _value(value) == expected and type(_value(value)) is type(expected), (name, _value(value), default)
        assert descriptor.read_only == ('read-only' in kind), name
        bounds = re.search(r'\[([\d.]+), ([\d.]+)\]', kind)
        if bounds:
            fp = descriptor.floating_point_range[0]
            assert (fp.from_value, fp.to_value) == (float(bounds.group(1)), float(bounds.group(2))), name
    done = subprocess.run([str(NODE_EXECUTABLE), '--help'], capture_output=True, text=True, timeout=30,
                          env=ros_environment(99))
    assert done.returncode == 0 and done.stdout.startswith('usage: ros2 run zeroshot_calib_ros node')
    for name, (kind, default) in table.items():
        line = next((x for x in done.stdout.splitlines() if x.startswith(f'  {name} ')), None)
        assert line is not None, f'--help does not list {name}'
        assert f'default {expected_default(kind, default)!r}' in line, line


def test_start_up_log_is_the_readme_block_and_diagnostics_come_at_1_hz(peer, start_node, tmp_path):
    """ros.md: "At start-up the node logs the calibration block (spec, model, `w*`, `f*`, `K`,
    `D`, fit error), then what it resolved (`make run ARGS='-r __ns:=/front -p rectify:=true'`)"
    followed by the block it shows; `/diagnostics` "1 Hz". Started as `make run` starts it (the
    HERO9 params file, those ARGS): the calibration lines are those of the README's `zeroshot-calib
    solve` output for the same camera, the interface lines are the README's (the map budget an
    eighth of this machine's memory, the file under this test's ROS_HOME)."""
    node = start_node('--ros-args', '--params-file', str(SHARE / 'config' / 'hero9_w1.yaml'),
                      '-r', '__ns:=/front', '-p', 'rectify:=true')
    diagnostics = []
    peer.node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: diagnostics.append(time.monotonic()),
                                  qos())
    peer.spin_until(lambda: 'calibration file:' in node.log, timeout=20, what='the start-up block')
    log = node.log.splitlines()
    solve_output = re.search(r'zeroshot-calib solve --width 1920 --height 1080 --hfov 118 --vfov 69\n```\n```\n'
                             r'(.*?)```', README, re.S).group(1).strip().splitlines()
    # the node logs the calibration block; the error bar is the CLI's (estimation is not imported
    # by the node)
    solve_output = [line for line in solve_output if not line.startswith('error bar ')]
    assert len(solve_output) == 8
    for line in solve_output:
        assert any(x.endswith(line) for x in log), f'calibration block line missing: {line}'
    block = re.search(r'```\n(interfaces \(QoS.*?)```', ROS_DOC, re.S).group(1).strip().splitlines()
    budget = int(_mem_total_mib() // 8)
    block = [re.sub(r'max_map_memory_mb = \d+', f'max_map_memory_mb = {budget}', line) for line in block]
    block = [line.replace('/root/.ros', str(tmp_path / 'ros_home')) for line in block]
    for line in block:
        assert any(x.endswith(line) for x in log), f"interfaces line missing: {line!r}\n{node.log}"
    peer.spin_until(lambda: len(diagnostics) >= 5, timeout=15, what='/diagnostics')
    intervals = np.diff(diagnostics[-4:])
    assert np.median(intervals) == pytest.approx(1.0, abs=0.15), intervals
    assert node.alive()


def test_integers_in_a_params_file_are_numbers(peer, start_node, tmp_path):
    """ros.md: "Integers are fine where a number is expected (`-p hfov:=118`, `balance: 1` in
    YAML)". A params file with integer hfov, vfov, balance and fov_scale: the CameraInfo is the
    paper's HERO9 W1 (f* 876.0) with P = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify
    of its K, D at balance 1."""
    params = tmp_path / 'ints.yaml'
    params.write_text(yaml.safe_dump({'/**/zeroshot_calib': {'ros__parameters': {
        'width': 1920, 'height': 1080, 'hfov': 118, 'vfov': 69, 'balance': 1, 'fov_scale': 1}}}))
    assert 'balance: 1\n' in params.read_text()
    start_node('--ros-args', '--params-file', str(params))
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    info = infos[-1]
    K, D = np.array(info.k).reshape(3, 3), np.array(info.d).reshape(4, 1)
    assert K[0, 0] == pytest.approx(876.0, abs=0.05)
    P1 = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, (1920, 1080), np.eye(3), balance=1.0)
    P0 = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, (1920, 1080), np.eye(3), balance=0.0)
    np.testing.assert_allclose(np.array(info.p).reshape(3, 4)[:, :3], P1, atol=3e-3)
    assert abs(P1[0, 0] - P0[0, 0]) > 50  # balance 1 is not the default 0


def _calibration(model):
    msg = CameraInfo(width=640, height=480, distortion_model=model)
    msg.k = [300.0, 0.0, 321.0, 0.0, 300.0, 239.0, 0.0, 0.0, 1.0]
    msg.d = [0.03, -0.01, 0.002, -0.0004] if model == 'equidistant' else [-0.2, 0.05, 0.001, -0.001, 0.0]
    msg.r = np.eye(3).ravel().tolist()
    msg.p = [250.0, 0.0, 320.0, 0.0, 0.0, 250.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def test_set_camera_info_adopted_but_not_saved_answers_false_and_says_so(peer, start_node, tmp_path):
    """ros.md (set_camera_info): "`success` means adopted and saved; a calibration adopted but not
    saved answers `success: false` and says so". camera_info_url is an .ini file, whose format
    (camera_calibration_parsers' INI) has no equidistant model: an equidistant calibration is
    adopted (published) but not saved; a plumb_bob one is adopted and saved (success)."""
    url = tmp_path / 'calib' / 'cam.ini'
    node = start_node('--ros-args', '-p', 'width:=640', '-p', 'height:=480', '-p', 'hfov:=100', '-p', 'vfov:=80',
                      '-p', f'camera_info_url:=file://{url}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    request = SetCameraInfo.Request(camera_info=_calibration('equidistant'))
    response = peer.call(SetCameraInfo, 'set_camera_info', request)
    assert not response.success
    assert 'adopted' in response.status_message and 'NOT saved' in response.status_message, response.status_message
    peer.spin_until(lambda: infos[-1].k[0] == 300.0 and infos[-1].distortion_model == 'equidistant',
                    what='the calibration adopted')
    assert not url.exists()
    request = SetCameraInfo.Request(camera_info=_calibration('plumb_bob'))
    response = peer.call(SetCameraInfo, 'set_camera_info', request)
    assert response.success and 'saved' in response.status_message and 'NOT' not in response.status_message
    lines = url.read_text().splitlines()
    assert lines[0] == '# Camera intrinsics' and lines[lines.index('width') + 1] == '640'
    assert [float(x) for x in lines[lines.index('distortion') + 1].split()] == [-0.2, 0.05, 0.001, -0.001, 0.0]
    peer.spin_until(lambda: infos[-1].distortion_model == 'plumb_bob', what='the plumb_bob calibration adopted')
    assert node.alive()


def test_maps_of_another_frame_size_are_released_after_10_s_unused(monkeypatch):
    """README (Topics): the maps of frames of another size are "released after 10 s without such a
    frame". The node's idle limit, and what it releases with it (a clock moved by hand): the
    other size at 10 s after its last frame, never the configured size."""
    from zeroshot_calib_ros.core import CameraCalibration, CameraSpec, solve_zero_shot
    from zeroshot_calib_ros.core.streaming import image_frames
    from zeroshot_calib_ros.ros.node import OTHER_SIZE_IDLE_SECONDS
    assert OTHER_SIZE_IDLE_SECONDS == 10
    clock = [1000.0]
    monkeypatch.setattr(image_frames.time, 'monotonic', lambda: clock[0])
    solution = solve_zero_shot(CameraSpec(160, 90, 118, 69))
    calibration, _ = CameraCalibration.from_solution(solution)
    active = image_frames.ActiveCalibration(calibration, solution.camera, 'spec', 0, rectify=True,
                                            build_maps=False)
    active.build_maps(160, 90)
    active.build_maps(320, 180)
    clock[0] += 9.0
    assert active.rectifier_for(320, 180) is not None  # a frame of that size at 9 s
    clock[0] += 9.9
    assert active.release_unused(OTHER_SIZE_IDLE_SECONDS) == []
    clock[0] += 0.2  # 10.1 s after that frame
    assert active.release_unused(OTHER_SIZE_IDLE_SECONDS) == [(320, 180)]
    clock[0] += 100
    assert active.release_unused(OTHER_SIZE_IDLE_SECONDS) == [] and active.rectifier_for(160, 90) is not None


def _make(*args, domain, timeout=60):
    """`make -s ARGS` as a user types it in another terminal: the Makefile's DDS environment,
    the test's ROS domain (the node's)."""
    import os
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(('MAKE', 'MFLAGS', 'ROS_', 'RMW_', 'FASTDDS_', 'FASTRTPS_', 'PYTHONPATH'))}
    env['ROS_DOMAIN_ID'] = str(domain)
    return subprocess.run(['make', '-s', '-C', str(REPO), *args], capture_output=True, text=True, env=env,
                          timeout=timeout)


def _echoed(output):
    """The CameraInfos `make echo` printed: (frame_id, width, height, distortion_model, d, k, p)."""
    messages = []
    # (Fast DDS writes its own log lines, in colour, to stdout too, e.g. when another process holds
    # a shared-memory port, and a message of several lines has the colour on its first only: not
    # ours, so a message is read from its `header:` line on)
    output = ''.join(line for line in output.splitlines(keepends=True) if '\x1b[' not in line)
    for doc in output.split('---\n')[:-1]:
        assert '\nheader:' in '\n' + doc, output
        try:
            data = yaml.safe_load(doc[('\n' + doc).rindex('\nheader:'):])
        except yaml.YAMLError as e:
            raise AssertionError(f'{e}: in what make echo printed:\n{output}') from e
        messages.append((data['header']['frame_id'], data['width'], data['height'], data['distortion_model'],
                         data['d'], data['k'], data['p']))
    return messages


def test_make_echo_prints_the_camera_info_the_running_node_publishes(peer, start_node, domain_id):  # noqa: F811
    """README and ros.md: "While `make run` runs, `make echo` in another terminal prints the
    CameraInfo the node publishes, as `ros2 topic echo /camera_info` would"; `make echo
    TOPIC=/front/camera_info ECHO_ARGS='--count 3'`; with none "it says so in one line and
    fails". The node started as `make run` starts it (the HERO9 params file, root namespace) and
    one in /front: what `make echo` prints (YAML, one document per message, as ros2 topic echo)
    is, field for field, the CameraInfo a peer receives."""
    start_node('--ros-args', '--params-file', str(SHARE / 'config' / 'hero9_w1.yaml'))
    start_node('--ros-args', '--params-file', str(SHARE / 'config' / 'c922.yaml'), '-r', '__ns:=/front')
    infos = peer.collect(CameraInfo, '/camera_info', LATCHED)
    front = peer.collect(CameraInfo, '/front/camera_info', LATCHED)
    peer.spin_until(lambda: infos and front, what='/camera_info and /front/camera_info')

    def fields(msg):
        return (msg.header.frame_id, msg.width, msg.height, msg.distortion_model, list(msg.d), list(msg.k),
                list(msg.p))
    assert 'make echo' in ' '.join(README.split()) and "make echo TOPIC=/front/camera_info ECHO_ARGS='--count 3'" in ROS_DOC
    done = _make('echo', domain=domain_id)
    assert done.returncode == 0, done.stderr
    (echoed,) = _echoed(done.stdout)
    assert echoed == fields(infos[-1]) and echoed[5][0] == pytest.approx(876.0, abs=0.05)  # Hero9(W1), f*
    done = _make('echo', 'TOPIC=/front/camera_info', 'ECHO_ARGS=--count 3', domain=domain_id)
    assert done.returncode == 0, done.stderr
    echoed = _echoed(done.stdout)
    assert len(echoed) == 3 and all(e == fields(front[-1]) for e in echoed) and echoed[0][3] == 'plumb_bob'
    done = _make('echo', 'TOPIC=/rear/camera_info', 'ECHO_ARGS=--timeout 2', domain=domain_id)
    lines = done.stderr.strip().splitlines()
    assert done.returncode != 0 and _echoed(done.stdout) == [] and 'header:' not in done.stdout
    assert lines[0].startswith('make echo: no CameraInfo on /rear/camera_info within 2 s'), lines


def test_the_venv_python_imports_the_library_after_sourcing_the_install_tree(tmp_path):
    """README and library.md: after `make build`, `.venv/bin/python` alone does not see the
    package; after `source install/setup.bash` the documented one-liner prints what library.md
    says, from any directory (here /, with nothing of ours in the environment), and the module
    comes from install/."""
    import os
    (block,) = [body for info, body, _ in fenced_blocks(page('docs/library.md')) if info == 'sh']
    source, command = block.strip().splitlines()
    assert source == 'source install/setup.bash' and command.startswith(".venv/bin/python -c '")
    code = command[len(".venv/bin/python -c '"):-1]
    expected = re.search(r'which prints `([^`]+)` from any directory', page('docs/library.md')).group(1)
    env = {'HOME': os.environ.get('HOME', '/root'), 'PATH': '/usr/local/bin:/usr/bin:/bin'}
    python = str(REPO / '.venv' / 'bin' / 'python')
    alone = subprocess.run([python, '-c', code], cwd='/', env=env, capture_output=True, text=True, timeout=60)
    assert alone.returncode != 0 and "No module named 'zeroshot_calib_ros'" in alone.stderr
    done = subprocess.run(['bash', '-c', f'source {REPO}/install/setup.bash && {python} -c "$0" && '
                           f'{python} -c "import zeroshot_calib_ros; print(zeroshot_calib_ros.__file__)"', code],
                          cwd='/', env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    printed, where = done.stdout.strip().splitlines()
    assert printed == expected
    assert where.startswith(str(REPO / 'install' / 'zeroshot_calib_ros' / 'lib'))


def test_make_echo_defaults_are_ros_mds():
    """ros.md: `make echo` prints /camera_info (where `make run` publishes) once, waiting "up to 10 s
    (`ECHO_ARGS='--timeout S'`) for each CameraInfo"; a count or timeout it cannot use is one
    line and status 2."""
    from zeroshot_calib_ros.ros.echo import build_parser, main
    args = build_parser().parse_args([])
    assert (args.topic, args.count, args.timeout) == ('/camera_info', 1, 10.0)
    assert '`make echo` waits up to 10 s' in ' '.join(ROS_DOC.split())
    assert main(['--count', '0']) == 2 and main(['--timeout', '-1']) == 2
