"""The shipped params files and launch file are what a ROS user loads."""
import importlib.util
import sys
import types
from pathlib import Path

import pytest
import yaml

from paper_table2 import load_table2
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_data.calibration_file import CameraCalibration

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / 'config'
LAUNCH_FILE = REPO / 'launch' / 'zeroshot_calib.launch.py'
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


def evaluate_launch_file(monkeypatch, launch_arguments=(), share=None):
    """The launch file's generate_launch_description() with stand-in launch modules (only where
    the real ones are not importable; with ``share``, ament_index_python's share directory too),
    and its one Node's arguments as launch_ros evaluates them for ``launch_arguments`` (what
    `ros2 launch ... name:=value` gives): LaunchConfigurations replaced by the argument or its
    declared default (an undeclared one is an error, as in launch), a relative namespace made
    absolute, a substitution in a parameter dict read as YAML (``'true'`` -> True)."""
    assert not real_launch_is_importable(), 'the real launch is importable: use it'
    for name, module in _stand_in_modules(share).items():
        if name.startswith('launch') or share is not None:
            monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location('zeroshot_launch', LAUNCH_FILE)
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

    nodes = [e for e in description.entities if isinstance(e, _Node)]
    assert len(nodes) == 1, description.entities
    arguments = {k: value(v) for k, v in nodes[0].arguments.items()
                 if k not in ('parameters', 'remappings')}
    arguments.setdefault('ros_arguments', None)
    if arguments['namespace'] is not None and not arguments['namespace'].startswith('/'):
        arguments['namespace'] = '/' + arguments['namespace']
    arguments['parameters'] = [
        {k: (yaml.safe_load(value(v)) if isinstance(v, _LaunchConfiguration) else v) for k, v in p.items()}
        if isinstance(p, dict) else value(p) for p in nodes[0].arguments['parameters'] or []]
    arguments['remappings'] = [(value(a), value(b)) for a, b in nodes[0].arguments['remappings'] or []]
    arguments['declared'] = declared
    return arguments


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
