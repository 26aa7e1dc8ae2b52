"""The shipped params files and launch file are what a ROS user loads."""
import ast
import importlib.util
from pathlib import Path

import pytest
import yaml

from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot

CONFIG = Path(__file__).resolve().parents[1] / 'config'
LAUNCH_FILE = CONFIG / 'zeroshot_calib.launch.py'
PARAMS_FILES = sorted(CONFIG.glob('*.yaml'))


@pytest.mark.parametrize('path', PARAMS_FILES, ids=[p.name for p in PARAMS_FILES])
def test_params_files_are_standard_and_solve(path):
    data = yaml.safe_load(path.read_text())
    # rcl's wildcard: the node named zeroshot_calib in any namespace (a launch file always sets one)
    assert list(data) == ['/**/zeroshot_calib'] and list(data['/**/zeroshot_calib']) == ['ros__parameters']
    p = data['/**/zeroshot_calib']['ros__parameters']
    fovs = {k: (p.get(k) or None) for k in ('hfov', 'vfov', 'dfov')}
    solution = solve_zero_shot(CameraSpec(p['width'], p['height'], **fovs), p.get('projection', 'auto'))
    assert solution.f > 0


def test_hero9_params_file_is_the_papers_camera():
    p = yaml.safe_load((CONFIG / 'hero9_w1.yaml').read_text())['/**/zeroshot_calib']['ros__parameters']
    assert (p['width'], p['height'], p['hfov'], p['vfov']) == (1920, 1080, 118, 69)


def test_launch_file():
    """Builds the launch description where `launch` is installed (a ROS desktop); PyPI has no
    `launch`, so otherwise the file's syntax and what it declares are checked."""
    if importlib.util.find_spec('launch') and importlib.util.find_spec('launch_ros'):
        spec = importlib.util.spec_from_file_location('zeroshot_launch', LAUNCH_FILE)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        description = module.generate_launch_description()
        names = {getattr(e, 'name', None) for e in description.entities}
        assert {'params_file', 'namespace', 'image', 'rectify'} <= names
        return
    tree = ast.parse(LAUNCH_FILE.read_text(), filename=str(LAUNCH_FILE))
    functions = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)]
    declared = {c.args[0].value for c in calls
                if getattr(c.func, 'id', '') == 'DeclareLaunchArgument' and c.args}
    assert {'params_file', 'namespace', 'image', 'rectify'} <= declared
    node = next(c for c in calls if getattr(c.func, 'id', '') == 'Node')
    keywords = {k.arg: k.value for k in node.keywords}
    assert keywords['package'].value == 'zeroshot_calib_ros' and keywords['executable'].value == 'node'
    assert keywords['name'].value == 'zeroshot_calib'
    assert 'remappings' in keywords and 'parameters' in keywords
    assert "'hero9_w1.yaml'" in LAUNCH_FILE.read_text() and (CONFIG / 'hero9_w1.yaml').exists()
