"""Robot bringup: the installed node started exactly as launch_ros starts it from the launch
file, in a namespace, with the package's params files from the install tree.

launch_ros turns ``Node(name=..., namespace=..., parameters=[file, {dict}], remappings=[...])``
into ``--ros-args -r __node:=NAME -r __ns:=/NS --params-file FILE --params-file TMP -r from:=to``,
where TMP holds the dict under the ``/**`` key (launch_ros.actions.Node
._create_params_file_from_dict). ``launch`` is not on PyPI, so where it is not importable this
command line is built by hand; where it is, test_launch_file_runs_for_real runs the launch file.
"""
import importlib.util
import subprocess
import sys

import numpy as np
import pytest
import yaml
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from ros_peer import (LATCHED, REPO, domain_id, image_msg, peer, qos,  # noqa: F401
                      ros_environment, start_node)
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
    pub.publish(image_msg(texture, 'mono8', 5_000_000_000))
    peer.spin_until(lambda: rects, what='/front/image_rect')
    assert (rects[0].width, rects[0].height) == (p['width'], p['height'])
    # the start-up block names what the node resolved, as `make run` shows it
    for line in ['publishes  /front/camera_info (sensor_msgs/CameraInfo, reliable, transient local, depth 5)',
                 'publishes  /front/image_rect (sensor_msgs/Image', 'subscribes /front/image_raw (sensor_msgs/Image',
                 'service    /front/set_camera_info (sensor_msgs/srv/SetCameraInfo', 'rectify    on',
                 f"at {p['publish_rate']:g} Hz while /front/image_raw has no publisher",
                 f"calibration file: none at {tmp_path}/ros_home/camera_info/{p['camera_name']}.yaml yet"]:
        assert line in node.log, line
    assert node.alive()


def test_old_root_namespace_key_is_gone():
    for path in [*PARAMS_FILES, REPO / 'README.md', REPO / 'config' / 'zeroshot_calib.launch.py']:
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
    IncludeLaunchDescription(PythonLaunchDescriptionSource({str(SHARE / 'config' / 'zeroshot_calib.launch.py')!r}),
                             launch_arguments=arguments),
    TimerAction(period=8.0, actions=[Shutdown()])]))
sys.exit(service.run())
"""
    env = ros_environment(domain_id)
    env['ROS_HOME'] = str(tmp_path)
    done = subprocess.run([sys.executable, '-c', script], env=env, capture_output=True, text=True, timeout=60)
    out = done.stdout + done.stderr
    assert 'zero-shot calibration from the spec sheet' in out and '/front/camera_info' in out, out
    assert 'error' not in out.lower(), out
