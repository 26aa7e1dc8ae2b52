"""The shipped params files and launch file are what a ROS user loads."""
import importlib.util
import sys
import types
from pathlib import Path

import pytest
import yaml

from paper_table2 import load_table2
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / 'config'
LAUNCH_FILE = REPO / 'launch' / 'zeroshot_calib.launch.py'
BRINGUP_FILE = REPO / 'launch' / 'usb_cam_bringup.launch.py'
PARAMS_FILES = sorted(CONFIG.glob('*.yaml'))
PARAMS_FILE_CAMERAS = {
    # file: (its row of the paper's Table 2, frame_id, distortion_model and its number of coefficients)
    'hero9_w1.yaml': ('Hero9(W1)', 'hero9_optical_frame', 'equidistant', 4),
    'c922.yaml': ('C922', 'c922_optical_frame', 'plumb_bob', 5),
}


@pytest.mark.parametrize('path', PARAMS_FILES, ids=[p.name for p in PARAMS_FILES])
def test_params_files_are_standard_and_solve(path):
    """Each shipped file is a camera of the paper's Table 2 and gives its printed f* (to the
    table's 0.1 px), in the frame and CameraInfo model the file states."""
    data = yaml.safe_load(path.read_text())
    # rcl's wildcard: the node named zeroshot_calib in any namespace (a launch file always sets one)
    assert list(data) == ['/**/zeroshot_calib'] and list(data['/**/zeroshot_calib']) == ['ros__parameters']
    p = data['/**/zeroshot_calib']['ros__parameters']
    assert path.name in PARAMS_FILE_CAMERAS, f'{path.name}: add its camera to PARAMS_FILE_CAMERAS'
    camera, frame_id, model, coefficients = PARAMS_FILE_CAMERAS[path.name]
    row = next(r for r in load_table2() if r['camera'] == camera)
    assert (p['width'], p['height'], p['hfov'], p['vfov']) == (row['width'], row['height'], row['hfov'], row['vfov'])
    fovs = {k: (p.get(k) or None) for k in ('hfov', 'vfov', 'dfov')}
    solution = solve_zero_shot(CameraSpec(p['width'], p['height'], **fovs), p.get('projection', 'auto'))
    assert solution.f == pytest.approx(row['f_star'], abs=0.1)
    assert (p['frame_id'], p['distortion_model']) == (frame_id, model)
    calibration, _ = CameraCalibration.from_solution(solution, p['distortion_model'], p['balance'], p['fov_scale'],
                                                     p['camera_name'])
    assert calibration.distortion_model == model and calibration.D.size == coefficients
    assert calibration.K[0, 0] == pytest.approx(row['f_star'], abs=0.1)


def test_hero9_params_file_is_the_papers_camera():
    p = yaml.safe_load((CONFIG / 'hero9_w1.yaml').read_text())['/**/zeroshot_calib']['ros__parameters']
    assert (p['width'], p['height'], p['hfov'], p['vfov']) == (1920, 1080, 118, 69)


class _LaunchConfiguration:
    def __init__(self, variable_name, default=None):
        self.variable_name = variable_name


class _DeclareLaunchArgument:
    def __init__(self, name, default_value=None, description=None, **_):
        self.name, self.default_value, self.description = name, default_value, description


class _LaunchDescription:
    def __init__(self, initial_entities=None):
        self.entities = list(initial_entities or [])


class _Node:
    def __init__(self, *, executable, package=None, name=None, namespace=None, parameters=None,
                 remappings=None, **other):
        self.arguments = dict(package=package, executable=executable, name=name, namespace=namespace,
                              parameters=parameters, remappings=remappings, **other)


def _stand_in_modules(share) -> dict:
    """`launch`, `launch.actions`, `launch.substitutions`, `launch_ros.actions` (and
    `ament_index_python.packages`, its share directory ``share``) with just what the launch file
    uses, recording arguments."""
    modules = {}
    for name, members in [('launch', dict(LaunchDescription=_LaunchDescription)),
                          ('launch.actions', dict(DeclareLaunchArgument=_DeclareLaunchArgument)),
                          ('launch.substitutions', dict(LaunchConfiguration=_LaunchConfiguration)),
                          ('launch_ros', {}), ('launch_ros.actions', dict(Node=_Node)),
                          ('ament_index_python', {}),
                          ('ament_index_python.packages',
                           dict(get_package_share_directory=lambda package: str(share)))]:
        module = types.ModuleType(name)
        module.__dict__.update(members)
        modules[name] = module
    return modules


def _importable(name):
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def real_launch_is_importable():
    return _importable('launch') and _importable('launch_ros')


def evaluate_launch_nodes(monkeypatch, launch_arguments=(), share=None, launch_file=LAUNCH_FILE):
    """A launch file's generate_launch_description() with stand-in launch modules (only where
    the real ones are not importable; with ``share``, ament_index_python's share directory too),
    and the arguments of each of its Nodes as launch_ros evaluates them for ``launch_arguments``
    (what `ros2 launch ... name:=value` gives): LaunchConfigurations replaced by the argument or
    its declared default (an undeclared one is an error, as in launch), a relative namespace made
    absolute, a substitution in a parameter dict read as YAML where that gives a bool, a number
    or a string (``'true'`` -> True, ``'118'`` -> 118, ``''`` stays ``''``), as launch_ros does.
    The stand-ins take the place of the real modules even where those are importable."""
    for name, module in _stand_in_modules(share).items():
        if name.startswith('launch') or share is not None:
            monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location('zeroshot_launch', launch_file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    declared = {e.name: e.default_value for e in description.entities if isinstance(e, _DeclareLaunchArgument)}
    unknown = set(dict(launch_arguments)) - set(declared)
    assert not unknown, f'launch arguments {unknown} are not declared'
    context = {**declared, **dict(launch_arguments)}

    def value(v):
        if isinstance(v, _LaunchConfiguration):  # a declared default may itself be a LaunchConfiguration
            assert v.variable_name in context, f'LaunchConfiguration {v.variable_name!r} is not declared'
            return value(context[v.variable_name])
        if isinstance(v, list):
            return [value(item) for item in v]
        return v

    def parameter(v):
        if not isinstance(v, _LaunchConfiguration):
            return v
        text = value(v)
        parsed = yaml.safe_load(text)  # launch_ros.utilities.evaluate_parameters
        return parsed if type(parsed) in (bool, int, float, str) else text

    nodes = []
    for node in (e for e in description.entities if isinstance(e, _Node)):
        arguments = {k: value(v) for k, v in node.arguments.items() if k not in ('parameters', 'remappings')}
        arguments.setdefault('ros_arguments', None)
        if arguments['namespace'] is not None and not arguments['namespace'].startswith('/'):
            arguments['namespace'] = '/' + arguments['namespace']
        arguments['parameters'] = [{k: parameter(v) for k, v in p.items()} if isinstance(p, dict) else value(p)
                                   for p in node.arguments['parameters'] or []]
        arguments['remappings'] = [(value(a), value(b)) for a, b in node.arguments['remappings'] or []]
        arguments['declared'] = declared
        nodes.append(arguments)
    return nodes


def evaluate_launch_file(monkeypatch, launch_arguments=(), share=None):
    """The one Node of launch/zeroshot_calib.launch.py, as evaluate_launch_nodes gives it."""
    assert not real_launch_is_importable(), 'the real launch is importable: use it'
    nodes = evaluate_launch_nodes(monkeypatch, launch_arguments, share)
    assert len(nodes) == 1, nodes
    return nodes[0]


LAUNCH_ARGUMENTS = {'params_file', 'namespace', 'node_name', 'image', 'image_topic', 'camera_info_topic',
                    'image_rect_topic', 'set_camera_info_service', 'rectify', 'log_level', 'use_sim_time'}


def test_launch_file(monkeypatch):
    """Builds the launch description: with `launch` where it is installed (a ROS desktop);
    PyPI has no `launch`, so otherwise with stand-in modules that record what it asks of
    launch_ros (test_bringup.py runs the node with the command line that makes)."""
    if real_launch_is_importable():
        spec = importlib.util.spec_from_file_location('zeroshot_launch', LAUNCH_FILE)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        description = module.generate_launch_description()
        names = {getattr(e, 'name', None) for e in description.entities}
        assert LAUNCH_ARGUMENTS <= names
        return
    node = evaluate_launch_file(monkeypatch, share=REPO)
    assert set(node['declared']) == LAUNCH_ARGUMENTS
    assert (node['package'], node['executable'], node['name']) == ('zeroshot_calib_ros', 'node', 'zeroshot_calib')
    assert node['namespace'] == '/camera'
    assert node['parameters'] == [str(REPO / 'config' / 'hero9_w1.yaml'), {'rectify': False, 'use_sim_time': False}]
    assert node['remappings'] == [('image_raw', 'image_raw'), ('camera_info', 'camera_info'),
                                  ('image_rect', 'image_rect'), ('set_camera_info', 'set_camera_info')]
    assert node['ros_arguments'] == ['--log-level', 'info']
    c922 = str(CONFIG / 'c922.yaml')
    node = evaluate_launch_file(monkeypatch, {'params_file': c922, 'namespace': 'front', 'image': '/front/image_raw',
                                              'rectify': 'true'}, share=REPO)
    assert node['namespace'] == '/front'
    assert node['parameters'] == [c922, {'rectify': True, 'use_sim_time': False}]
    assert node['remappings'][0] == ('image_raw', '/front/image_raw')  # `image`, the older name of image_topic


BRINGUP_ARGUMENTS = {'namespace', 'video_device', 'width', 'height', 'hfov', 'vfov', 'dfov', 'pixel_format',
                     'framerate', 'frame_id', 'distortion_model', 'rectify'}


def test_usb_cam_bringup_starts_the_driver_with_its_camera_info_moved_aside(monkeypatch):
    """README quick start 1, `ros2 launch zeroshot_calib_ros usb_cam_bringup.launch.py
    video_device:=/dev/video0 width:=1920 height:=1080 hfov:=118 vfov:=69`: usb_cam's driver
    (package usb_cam, executable usb_cam_node_exe, its parameter names) and the node in one
    namespace; the size reaches both, the FOVs and rectify:=true (the default) the node; the
    driver's camera_info and set_camera_info are remapped under driver/ while the node's keep
    their names (camera/camera_info is ours alone). Every argument is described; FOVs not given
    are 0 (the node's "not given"), so a bringup without one exits naming them."""
    arguments = {'video_device': '/dev/video0', 'width': '1920', 'height': '1080', 'hfov': '118', 'vfov': '69'}
    driver, ours = evaluate_launch_nodes(monkeypatch, arguments, launch_file=BRINGUP_FILE)
    assert set(driver['declared']) == BRINGUP_ARGUMENTS
    assert (driver['package'], driver['executable'], driver['name']) == ('usb_cam', 'usb_cam_node_exe', 'usb_cam')
    assert (ours['package'], ours['executable'], ours['name']) == ('zeroshot_calib_ros', 'node', 'zeroshot_calib')
    assert driver['namespace'] == ours['namespace'] == '/camera'
    assert driver['parameters'] == [{'video_device': '/dev/video0', 'image_width': 1920, 'image_height': 1080,
                                     'pixel_format': 'mjpeg2rgb', 'framerate': 30.0,
                                     'frame_id': 'camera_optical_frame'}]
    assert type(driver['parameters'][0]['framerate']) is float  # usb_cam declares a double
    assert ours['parameters'] == [{'width': 1920, 'height': 1080, 'hfov': 118, 'vfov': 69, 'dfov': 0,
                                   'frame_id': 'camera_optical_frame', 'distortion_model': 'equidistant',
                                   'rectify': True}]
    assert driver['remappings'] == [('camera_info', 'driver/camera_info'),
                                    ('set_camera_info', 'driver/set_camera_info')]
    assert ours['remappings'] == []  # image_raw, camera_info, image_rect, set_camera_info: in the namespace
    # the node reads these parameters as the spec it solves (the paper's HERO9 W1: f* 876.0)
    p = ours['parameters'][0]
    fovs = {k: (p[k] or None) for k in ('hfov', 'vfov', 'dfov')}
    assert solve_zero_shot(CameraSpec(p['width'], p['height'], **fovs)).f == pytest.approx(876.0, abs=0.1)
    assert all(isinstance(d, str) and d for d in _bringup_descriptions(monkeypatch).values())
    driver, ours = evaluate_launch_nodes(monkeypatch, {'namespace': 'front', 'width': '1280', 'height': '720',
                                                       'dfov': '78.5', 'rectify': 'false'}, launch_file=BRINGUP_FILE)
    assert driver['namespace'] == ours['namespace'] == '/front'
    assert (driver['parameters'][0]['image_width'], driver['parameters'][0]['image_height']) == (1280, 720)
    assert {k: ours['parameters'][0][k] for k in ('width', 'height', 'hfov', 'vfov', 'dfov', 'rectify')} == \
        {'width': 1280, 'height': 720, 'hfov': 0, 'vfov': 0, 'dfov': 78.5, 'rectify': False}


def _bringup_descriptions(monkeypatch):
    for name, module in _stand_in_modules(None).items():
        if name.startswith('launch'):
            monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location('zeroshot_bringup', BRINGUP_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return {e.name: e.description for e in module.generate_launch_description().entities
            if isinstance(e, _DeclareLaunchArgument)}
