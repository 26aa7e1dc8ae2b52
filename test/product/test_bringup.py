"""Robot bringup: the installed node started exactly as launch_ros starts it from the launch
file, in a namespace, with the package's params files from the install tree.

launch_ros turns ``Node(name=..., namespace=..., parameters=[file, {dict}], remappings=[...])``
into ``--ros-args -r __node:=NAME -r __ns:=/NS --params-file FILE --params-file TMP -r from:=to``,
where TMP holds the dict under the ``/**`` key (launch_ros.actions.Node
._create_params_file_from_dict). ``launch`` is not on PyPI, so where it is not importable the
launch file is evaluated with stand-in launch modules that record its Node(...) (test_config.py)
and this command line is built from what they recorded; where it is,
test_launch_file_runs_for_real runs the launch file.
"""
import importlib.util
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from paper_table2 import load_table2
from ros_peer import (LATCHED, NODE_EXECUTABLE, REPO, domain_id, image_msg, peer, qos,  # noqa: F401
                      ros_environment, start_node)
from test_config import evaluate_launch_file, real_launch_is_importable
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot

SHARE = REPO / 'install' / 'zeroshot_calib_ros' / 'share' / 'zeroshot_calib_ros'
PARAMS_FILES = sorted((REPO / 'config').glob('*.yaml'))


def launch_ros_arguments(tmp_path, params_file, namespace='/front', name='zeroshot_calib',
                         remappings=(), parameters=None):
    """The arguments launch_ros gives the executable for one Node action."""
    args = ['--ros-args', '-r', f'__node:={name}', '-r', f'__ns:={namespace}', '--params-file', str(params_file)]
    if parameters:
        extra = tmp_path / 'launch_params_dict.yaml'
        extra.write_text(yaml.dump({'/**': {'ros__parameters': parameters}}, default_flow_style=False))
        args += ['--params-file', str(extra)]
    for source, target in remappings:
        args += ['-r', f'{source}:={target}']
    return args


@pytest.mark.parametrize('config', PARAMS_FILES, ids=[p.name for p in PARAMS_FILES])
def test_params_file_in_a_namespace_as_launch_ros_starts_it(peer, start_node, tmp_path, config):
    installed = SHARE / 'config' / config.name
    assert installed.exists(), f'{installed} is not installed (setup.py data_files)'
    p = next(iter(yaml.safe_load(config.read_text()).values()))['ros__parameters']
    node = start_node(*launch_ros_arguments(tmp_path, installed, remappings=[('image_raw', '/front/image_raw')],
                                            parameters={'rectify': True}))
    infos = peer.collect(CameraInfo, '/front/camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='/front/camera_info')
    info = infos[-1]
    fovs = {k: (p.get(k) or None) for k in ('hfov', 'vfov', 'dfov')}
    expected = solve_zero_shot(CameraSpec(p['width'], p['height'], **fovs), p.get('projection', 'auto'))
    assert (info.width, info.height) == (p['width'], p['height'])
    assert info.k[0] == pytest.approx(expected.f, abs=1e-6)
    assert info.distortion_model == p['distortion_model']
    assert info.header.frame_id == p['frame_id']
    reliable = qos(ReliabilityPolicy.RELIABLE)
    rects = peer.collect(Image, '/front/image_rect', reliable)
    pub = peer.image_publisher(reliable, topic='/front/image_raw')
    texture = np.random.default_rng(0).integers(0, 255, (p['height'], p['width']), dtype=np.uint8)
    # a camera streams: frames until one is rectified (those before the node's maps are built,
    # ~1 s on a busy machine, are skipped as maps_pending)
    frame = image_msg(texture, 'mono8', 5_000_000_000)
    deadline = time.monotonic() + 20
    while not rects and time.monotonic() < deadline:
        pub.publish(frame)
        peer.spin_for(0.5)
    assert rects, 'no /front/image_rect in 20 s of frames'
    assert (rects[0].width, rects[0].height) == (p['width'], p['height'])
    # the start-up block names what the node resolved, as `make run` shows it
    for line in ['publishes  /front/camera_info (sensor_msgs/CameraInfo, reliable, transient local, depth 5)',
                 'publishes  /front/image_rect (sensor_msgs/Image', 'subscribes /front/image_raw (sensor_msgs/Image',
                 'service    /front/set_camera_info (sensor_msgs/srv/SetCameraInfo', 'rectify    on',
                 f"at {p['publish_rate']:g} Hz while /front/image_raw has no publisher",
                 f"calibration file: none at {tmp_path}/ros_home/camera_info/{p['camera_name']}.yaml yet",
                 'frame path serialized: image_raw taken as CDR bytes, image_rect and camera_info published as bytes',
                 'memory     frames up to 32 MiB reused from the heap (glibc mmap threshold 32 MiB, trim threshold 64 MiB)']:
        assert line in node.log, line
    assert node.alive()


def test_old_root_namespace_key_is_gone():
    from doc_pages import PAGES
    for path in [*PARAMS_FILES, *(REPO / name for name in PAGES), *sorted((REPO / 'launch').glob('*.launch.py'))]:
        text = path.read_text()
        assert '\nzeroshot_calib:\n' not in text and '(zeroshot_calib: ros__parameters)' not in text, path


def test_launch_file_runs_for_real(tmp_path, domain_id):  # noqa: F811
    """Where ROS 2's launch is installed: the shipped launch file, run by a LaunchService as
    `ros2 launch zeroshot_calib_ros zeroshot_calib.launch.py namespace:=front ...` runs it."""
    if not (importlib.util.find_spec('launch') and importlib.util.find_spec('launch_ros')):
        pytest.skip('launch / launch_ros are not installed (not on PyPI); '
                    'test_params_file_in_a_namespace_as_launch_ros_starts_it runs its command line')
    script = f"""
import sys
from launch import LaunchDescription, LaunchService
from launch.actions import IncludeLaunchDescription, Shutdown, TimerAction
from launch.launch_description_sources import PythonLaunchDescriptionSource
arguments = {{'namespace': 'front', 'image': '/front/image_raw', 'rectify': 'true'}}.items()
service = LaunchService()
service.include_launch_description(LaunchDescription([
    IncludeLaunchDescription(PythonLaunchDescriptionSource({str(SHARE / 'launch' / 'zeroshot_calib.launch.py')!r}),
                             launch_arguments=arguments),
    TimerAction(period=8.0, actions=[Shutdown()])]))
sys.exit(service.run())
"""
    env = ros_environment(domain_id)
    env['ROS_HOME'] = str(tmp_path)
    done = subprocess.run([sys.executable, '-c', script], env=env, capture_output=True, text=True, timeout=60)
    out = done.stdout + done.stderr
    assert 'zero-shot calibration from the spec sheet' in out and '/front/camera_info' in out, out
    assert '[ERROR]' not in out and 'Traceback' not in out, out  # (the start-up block has a "fit error" line)


def launch_ros_command_line(tmp_path, node):
    """What launch_ros.actions.Node gives the executable for the recorded Node(...) arguments:
    its ros_arguments (after a --ros-args of their own), its name and namespace, each parameters
    entry as a --params-file (a dict written under ``/**``), then each remapping."""
    args = ['--ros-args', *node['ros_arguments']] if node['ros_arguments'] else []
    args += ['--ros-args', '-r', f"__node:={node['name']}", '-r', f"__ns:={node['namespace']}"]
    for i, entry in enumerate(node['parameters']):
        if isinstance(entry, dict):
            path = tmp_path / f'launch_params_{i}.yaml'
            path.write_text(yaml.dump({'/**': {'ros__parameters': entry}}, default_flow_style=False))
            entry = path
        args += ['--params-file', str(entry)]
    for source, target in node['remappings']:
        args += ['-r', f'{source}:={target}']
    return args


@pytest.mark.parametrize('params_file, camera', [(None, 'Hero9(W1)'), ('c922.yaml', 'C922')],
                         ids=['default', 'c922'])
def test_launch_file_node_runs_as_launch_ros_starts_it(peer, start_node, tmp_path, monkeypatch,
                                                       params_file, camera):
    """`ros2 launch zeroshot_calib_ros zeroshot_calib.launch.py namespace:=front
    image:=/front/image_raw rectify:=true [params_file:=...]` without `launch`: the launch file's
    Node(...) with these arguments, turned into launch_ros' command line for the installed
    executable; /front/camera_info comes with the paper's f* and the file's frame_id."""
    if real_launch_is_importable():
        pytest.skip('launch is importable: test_launch_file_runs_for_real runs the launch file itself')
    from ament_index_python.packages import get_package_prefix
    arguments = {'namespace': 'front', 'image': '/front/image_raw', 'rectify': 'true'}
    if params_file:
        arguments['params_file'] = str(SHARE / 'config' / params_file)
    node = evaluate_launch_file(monkeypatch, arguments)  # the real ament_index_python: the install tree
    installed = SHARE / 'config' / (params_file or 'hero9_w1.yaml')
    assert node['parameters'] == [str(installed), {'rectify': True, 'use_sim_time': False}]
    # launch_ros runs <prefix of package>/lib/<package>/<executable>, as `ros2 run`
    executable = f"{get_package_prefix(node['package'])}/lib/{node['package']}/{node['executable']}"
    assert executable == str(NODE_EXECUTABLE)
    process = start_node(*launch_ros_command_line(tmp_path, node))
    infos = peer.collect(CameraInfo, '/front/camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='/front/camera_info')
    p = next(iter(yaml.safe_load(installed.read_text()).values()))['ros__parameters']
    row = next(r for r in load_table2() if r['camera'] == camera)
    assert (infos[-1].width, infos[-1].height) == (row['width'], row['height'])
    assert infos[-1].k[0] == pytest.approx(row['f_star'], abs=0.1)
    assert (infos[-1].header.frame_id, infos[-1].distortion_model) == (p['frame_id'], p['distortion_model'])
    # rectify:=true reached the node, and image_raw is remapped
    peer.spin_until(lambda: peer.node.get_publishers_info_by_topic('/front/image_rect'), timeout=10,
                    what='/front/image_rect advertised')
    peer.spin_until(lambda: any(i.node_name == 'zeroshot_calib' and i.node_namespace == '/front'
                                for i in peer.node.get_subscriptions_info_by_topic('/front/image_raw')),
                    timeout=10, what='/front/image_raw subscribed')
    assert process.alive()


# what a robot team sets when the camera driver publishes its own camera_info (and offers
# set_camera_info) in the camera's namespace
ROBOT_ARGUMENTS = {'namespace': 'front', 'node_name': 'front_calib', 'image_topic': '/front/image_raw',
                   'camera_info_topic': '/front/zeroshot/camera_info',
                   'image_rect_topic': '/front/zeroshot/image_rect',
                   'set_camera_info_service': '/front/zeroshot/set_camera_info',
                   'rectify': 'true', 'log_level': 'debug', 'use_sim_time': 'true'}


def _launch_for_real(tmp_path, domain_id, arguments):  # noqa: F811
    """`ros2 launch` of the installed launch file as a bringup includes it (FindPackageShare +
    'launch'), in a process of its own; returns the process and its log file."""
    script = f"""
import sys
from launch import LaunchDescription, LaunchService
from launch.actions import IncludeLaunchDescription, Shutdown, TimerAction
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import PathJoinSubstitution
from launch_ros.substitutions import FindPackageShare
service = LaunchService()
service.include_launch_description(LaunchDescription([
    IncludeLaunchDescription(PythonLaunchDescriptionSource(PathJoinSubstitution(
        [FindPackageShare('zeroshot_calib_ros'), 'launch', 'zeroshot_calib.launch.py'])),
        launch_arguments={arguments!r}.items()),
    TimerAction(period=60.0, actions=[Shutdown()])]))
sys.exit(service.run())
"""
    env = ros_environment(domain_id)
    env['ROS_HOME'] = str(tmp_path / 'ros_home')
    log = tmp_path / 'launch.log'
    with open(log, 'w') as out:
        process = subprocess.Popen([sys.executable, '-c', script], env=env, stdout=out, stderr=subprocess.STDOUT)
    return process, log


def test_launch_arguments_remap_topics_and_set_name_log_level_and_sim_time(peer, start_node, tmp_path,
                                                                          monkeypatch, domain_id):  # noqa: F811
    """`ros2 launch zeroshot_calib_ros zeroshot_calib.launch.py namespace:=front node_name:=front_calib
    image_topic:=... camera_info_topic:=... image_rect_topic:=... set_camera_info_service:=...
    log_level:=debug use_sim_time:=true rectify:=true`: with the real launch where it is importable,
    else the launch file's Node(...) run with the command line launch_ros builds from it. The
    node takes the name, publishes CameraInfo and image_rect and offers set_camera_info where it
    was told (nothing on the driver's /front/camera_info), logs at debug level and stamps with
    /clock (none published: stamp 0)."""
    # the shipped files are keyed /**/zeroshot_calib: a team that renames the node keys its file
    # with the new name (the params_file description says so)
    hero9 = yaml.safe_load((SHARE / 'config' / 'hero9_w1.yaml').read_text())['/**/zeroshot_calib']
    params_file = tmp_path / 'front.yaml'
    params_file.write_text(yaml.safe_dump({'/**/front_calib': hero9}))
    arguments = {**ROBOT_ARGUMENTS, 'params_file': str(params_file)}
    if real_launch_is_importable():
        process, log = _launch_for_real(tmp_path, domain_id, arguments)
        alive, read_log = (lambda: process.poll() is None), log.read_text
    else:
        node = evaluate_launch_file(monkeypatch, arguments)
        started = start_node(*launch_ros_command_line(tmp_path, node))
        alive, read_log = started.alive, lambda: started.log
    try:
        infos = peer.collect(CameraInfo, '/front/zeroshot/camera_info', LATCHED)
        peer.spin_until(lambda: infos, timeout=30, what='/front/zeroshot/camera_info')
        ours = ('front_calib', '/front')
        publishers = peer.node.get_publishers_info_by_topic
        # the endpoint can be discovered before its node's name is (_NODE_NAME_UNKNOWN_): wait for it
        peer.spin_until(lambda: [(i.node_name, i.node_namespace) for i in publishers('/front/zeroshot/camera_info')]
                        == [ours], timeout=10, what='/front/zeroshot/camera_info published by front_calib')
        assert not publishers('/front/camera_info'), 'the driver\'s camera_info topic must stay its own'
        peer.spin_until(lambda: [(i.node_name, i.node_namespace) for i in publishers('/front/zeroshot/image_rect')]
                        == [ours], timeout=10, what='/front/zeroshot/image_rect advertised by front_calib')
        peer.spin_until(lambda: any((i.node_name, i.node_namespace) == ours for i in
                                    peer.node.get_subscriptions_info_by_topic('/front/image_raw')),
                        timeout=10, what='/front/image_raw subscribed by front_calib')
        services = dict(peer.node.get_service_names_and_types_by_node(*ours))
        assert '/front/zeroshot/set_camera_info' in services and '/front/set_camera_info' not in services, services
        # use_sim_time: the node follows /clock, which nobody publishes: ROS time 0
        peer.spin_until(lambda: any((i.node_name, i.node_namespace) == ours
                                    for i in peer.node.get_subscriptions_info_by_topic('/clock')),
                        timeout=10, what='/clock subscribed by front_calib')
        assert (infos[-1].header.stamp.sec, infos[-1].header.stamp.nanosec) == (0, 0)
        assert '[DEBUG]' in read_log(), read_log()[-3000:]
        assert alive(), read_log()[-3000:]
    finally:
        if real_launch_is_importable():
            process.send_signal(signal.SIGINT)
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def test_launch_default_spec_and_frames_of_another_aspect_ratio(peer, start_node, tmp_path):
    """`ros2 launch ... ` without params_file runs the Hero9 1920x1080 (16:9) spec; a 640x480
    (4:3) camera cannot be calibrated by it: no CameraInfo of that size (none made up), and the
    node says what is missing: a WARN for each frame size that names the parameters to set
    (repeats throttled, not once for all sizes) and a /diagnostics ERROR that names the size."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    node = start_node(*launch_ros_arguments(tmp_path, SHARE / 'config' / 'hero9_w1.yaml', namespace='/camera',
                                            remappings=[('image_raw', '/camera/image_raw')],
                                            parameters={'rectify': False, 'use_sim_time': False}))
    infos = peer.collect(CameraInfo, '/camera/camera_info', LATCHED)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pub = peer.image_publisher(qos(ReliabilityPolicy.RELIABLE), topic='/camera/image_raw')
    for (width, height), frames in [((640, 480), 8), ((320, 240), 4)]:
        frame = image_msg(np.zeros((height, width), np.uint8), 'mono8', 5_000_000_000)
        for _ in range(frames):
            pub.publish(frame)
            peer.spin_for(0.25)
    def errors():
        return [s.message for d in diagnostics for s in d.status if s.level == DiagnosticStatus.ERROR]

    peer.spin_until(lambda: any('320x240' in m for m in errors()), timeout=5, what='a /diagnostics ERROR on 320x240')
    assert any('640x480' in m for m in errors()), errors()  # the first size had its ERROR too (1 Hz)
    assert all('width' in m and 'hfov' in m for m in errors()), errors()
    assert not [i for i in infos if (i.width, i.height) != (1920, 1080)], 'CameraInfo for frames no spec describes'
    warnings = [line for line in node.log.splitlines() if '[WARN]' in line]
    for size in ('640x480', '320x240'):
        lines = [line for line in warnings if size in line]
        assert len(lines) == 1, (size, warnings)  # once per size within the throttle period (5 s)
        assert all(name in lines[0] for name in ('width', 'height', 'hfov', 'preset')), lines[0]
    assert node.alive()


def test_ros2_launch_show_args_describes_every_argument(monkeypatch):
    """`ros2 launch zeroshot_calib_ros zeroshot_calib.launch.py --show-args` (where ros2cli and
    ros2launch are importable; else the launch file's declarations through the stand-ins): every
    argument has a description, and the default params file's says what frames of another
    aspect ratio get."""
    if importlib.util.find_spec('ros2cli') and importlib.util.find_spec('ros2launch'):
        done = subprocess.run([sys.executable, '-c', 'import sys; from ros2cli.cli import main; sys.exit(main())',
                               'launch', 'zeroshot_calib_ros', 'zeroshot_calib.launch.py', '--show-args'],
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stdout + done.stderr
        blocks = [b.strip().splitlines() for b in done.stdout.split('\n\n')[1:] if b.strip()]
        described = {b[0].strip().strip("':"): b[1].strip() for b in blocks}
    else:
        from test_config import _DeclareLaunchArgument, _stand_in_modules
        for name, module in _stand_in_modules(SHARE).items():
            if name.startswith('launch'):
                monkeypatch.setitem(sys.modules, name, module)
        spec = importlib.util.spec_from_file_location('zeroshot_launch', REPO / 'launch' / 'zeroshot_calib.launch.py')
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        described = {e.name: e.description for e in module.generate_launch_description().entities
                     if isinstance(e, _DeclareLaunchArgument)}
    from test_config import LAUNCH_ARGUMENTS
    assert set(described) == LAUNCH_ARGUMENTS
    assert all(text and not text.startswith('(default') for text in described.values()), described
    assert all(word in described['params_file'] for word in ('aspect ratio', 'WARN', 'diagnostics')), described


def test_usb_cam_bringup_pairs_our_camera_info_with_the_drivers_frames(peer, start_node, tmp_path, monkeypatch,
                                                                      domain_id):  # noqa: F811
    """README quick start 1 (launch/usb_cam_bringup.launch.py), without usb_cam installed: both
    Node actions of the bringup run with the command lines launch_ros builds from them, the
    driver's executable replaced by test/fake_usb_cam.py (usb_cam's parameter names and topics,
    its camera_info published uncalibrated on the fully qualified name image_transport gives it).
    /camera/camera_info is ours alone, with our camera (the spec solved) and the header of each
    driver frame; the driver's own camera_info and set_camera_info are under /camera/driver/;
    /camera/image_rect comes rectified (rectify on by default)."""
    from test_config import BRINGUP_FILE, evaluate_launch_nodes
    arguments = {'width': '640', 'height': '360', 'hfov': '118', 'vfov': '69'}
    driver, ours = evaluate_launch_nodes(monkeypatch, arguments, launch_file=BRINGUP_FILE)
    (tmp_path / 'driver').mkdir()
    (tmp_path / 'ours').mkdir()
    env = ros_environment(domain_id)
    fake = subprocess.Popen([sys.executable, str(REPO / 'test' / 'fake_usb_cam.py'),
                             *launch_ros_command_line(tmp_path / 'driver', driver)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    try:
        node = start_node(*launch_ros_command_line(tmp_path / 'ours', ours))
        reliable = qos(ReliabilityPolicy.RELIABLE, depth=50)
        infos = peer.collect(CameraInfo, '/camera/camera_info', reliable)
        driver_infos = peer.collect(CameraInfo, '/camera/driver/camera_info', reliable)
        frames = peer.collect(Image, '/camera/image_raw', reliable)
        rects = peer.collect(Image, '/camera/image_rect', reliable)
        peer.spin_until(lambda: len(rects) >= 3 and len(driver_infos) >= 3, timeout=30,
                        what='/camera/image_rect and /camera/driver/camera_info')
        publishers = peer.node.get_publishers_info_by_topic
        peer.spin_until(lambda: [(i.node_name, i.node_namespace) for i in publishers('/camera/camera_info')]
                        == [('zeroshot_calib', '/camera')], timeout=10, what='/camera/camera_info: ours alone')
        assert [(i.node_name, i.node_namespace) for i in publishers('/camera/driver/camera_info')] == \
            [('usb_cam', '/camera')]
        expected = solve_zero_shot(CameraSpec(640, 360, hfov=118, vfov=69))
        ours_received = [i for i in infos if i.header.stamp.sec or i.header.stamp.nanosec]
        assert ours_received and all(i.k[0] == pytest.approx(expected.f, abs=1e-6) for i in ours_received)
        assert all(i.distortion_model == 'equidistant' and (i.width, i.height) == (640, 360) for i in ours_received)
        assert all(i.k[0] == 0 for i in driver_infos)  # the driver's, uncalibrated, stays aside

        def paired():  # our CameraInfos with exactly the header of a driver frame
            stamps = {(f.header.stamp.sec, f.header.stamp.nanosec, f.header.frame_id) for f in frames}
            return [i for i in infos if (i.header.stamp.sec, i.header.stamp.nanosec, i.header.frame_id) in stamps]
        peer.spin_until(lambda: len(paired()) >= 3, timeout=10, what='CameraInfos with the headers of driver frames')
        assert all(i.header.frame_id == 'camera_optical_frame' and i.k[0] == pytest.approx(expected.f, abs=1e-6)
                   for i in paired())
        assert (rects[-1].width, rects[-1].height, rects[-1].encoding) == (640, 360, 'mono8')
        services = {name for name, _ in peer.node.get_service_names_and_types_by_node('zeroshot_calib', '/camera')}
        assert '/camera/set_camera_info' in services
        peer.spin_until(lambda: '/camera/driver/set_camera_info' in {
            name for name, _ in peer.node.get_service_names_and_types_by_node('usb_cam', '/camera')},
            timeout=10, what="the driver's set_camera_info under /camera/driver/")
        assert node.alive() and fake.poll() is None
    finally:
        fake.send_signal(signal.SIGINT)
        try:
            fake.wait(10)
        except subprocess.TimeoutExpired:
            fake.kill()
            fake.wait()
