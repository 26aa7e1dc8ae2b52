"""The import rule of docs/architecture.md, enforced on the source: layers import only layers
below them (or modules of their own layer), siblings never import each other, the core never
imports ROS, and every module belongs to a layer (a new module must be placed in one).

    0 core/lens, core/atomic_file,    lens models, their ROS fits; writing files and reading them
      core/file_input                 bounded (and the version)
    1 core/zeroshot                   spec sheet -> camera (the paper's solver, presets, wide model)
    2 core/checkerboard, core/lines   calibration evidence: chessboard images, straight lines
    3 core/estimation                 the MAP fit over all evidence, its uncertainty, the quality gate
    4 core/ros_formats                the formats ROS carries, without ROS: files, CameraInfo, images, maps
    5 core/streaming                  the pipeline the node drives, without ROS: frames, map builds, refiner
      core/report                     pictures for a user: the calibration report, refine's contact sheet
    6 core (its __init__)             the public API: re-exports
    7 cli, ros                        the two front ends: zeroshot-calib, the ROS node
"""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'zeroshot_calib_ros'
LAYERS = {
    'core.lens': 0, 'core.atomic_file': 0, 'core.file_input': 0,
    'core.zeroshot': 1,
    'core.checkerboard': 2, 'core.lines': 2,
    'core.estimation': 3,
    'core.ros_formats': 4,
    'core.streaming': 5, 'core.report': 5,
    'core': 6,
    'cli': 7, 'ros': 7,
    '': 0,  # zeroshot_calib_ros/__init__.py: the version, nothing else
}
ROS_PACKAGES = {'rclpy', 'rcl_interfaces', 'sensor_msgs', 'diagnostic_msgs', 'std_msgs', 'builtin_interfaces',
                'launch', 'launch_ros', 'ament_index_python', 'rosidl_runtime_py', 'cv_bridge', 'image_geometry'}


def unit_of(module: str) -> str:
    """The layer unit of a dotted module name relative to the package ('core.lens.models' ->
    'core.lens'); the longest prefix found in LAYERS."""
    if module == '':
        return ''
    parts = module.split('.')
    for n in range(len(parts), 0, -1):
        prefix = '.'.join(parts[:n])
        if prefix in LAYERS:
            return prefix
    raise KeyError(f'zeroshot_calib_ros.{module} is in no layer of docs/architecture.md')


def module_name(path: Path, package: Path = PACKAGE) -> str:
    relative = path.relative_to(package).with_suffix('')
    parts = list(relative.parts)
    if parts[-1] == '__init__':
        parts = parts[:-1]
    return '.'.join(parts)


def imports_of(path: Path, package_root: Path = PACKAGE):
    """(line, absolute module name relative to the package or a top-level package name,
    is_ours) of every import in a file."""
    tree = ast.parse(path.read_text(), str(path))
    name = module_name(path, package_root)
    package = name.split('.') if path.name == '__init__.py' else name.split('.')[:-1]
    package = [p for p in package if p]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                name = alias.name
                if name == 'zeroshot_calib_ros' or name.startswith('zeroshot_calib_ros.'):
                    yield node.lineno, name[len('zeroshot_calib_ros.'):], True
                else:
                    yield node.lineno, name.split('.')[0], False
        elif isinstance(node, ast.ImportFrom):
            if node.level or node.module == 'zeroshot_calib_ros' or node.module.startswith('zeroshot_calib_ros.'):
                if node.level:
                    base = package[:len(package) - (node.level - 1)] if node.level > 1 else package
                    target = '.'.join(base + ([node.module] if node.module else []))
                else:
                    target = node.module[len('zeroshot_calib_ros.'):] if '.' in node.module else ''
                for alias in node.names:
                    candidate = f'{target}.{alias.name}'.lstrip('.')
                    is_module = (package_root / Path(*candidate.split('.'))).with_suffix('.py').exists() or \
                        (package_root / Path(*candidate.split('.')) / '__init__.py').exists()
                    yield node.lineno, candidate if is_module else target, True
            else:
                yield node.lineno, node.module.split('.')[0], False


def violations(package: Path = PACKAGE):
    found = []
    for path in sorted(package.rglob('*.py')):
        if '__pycache__' in path.parts:
            continue
        name = module_name(path, package)
        unit = unit_of(name)
        for line, target, ours in imports_of(path, package):
            where = f'{path.relative_to(package.parent)}:{line}'
            if not ours:
                if unit.startswith('core') and target in ROS_PACKAGES:
                    found.append(f'{where}: {name} imports {target}: the core never imports ROS')
                continue
            target_unit = unit_of(target)
            if target_unit == unit:
                continue
            if LAYERS[target_unit] > LAYERS[unit]:
                found.append(f'{where}: {name} (layer {LAYERS[unit]}, {unit}) imports {target} '
                             f'(layer {LAYERS[target_unit]}, {target_unit}): imports run downwards only')
            elif LAYERS[target_unit] == LAYERS[unit]:
                found.append(f'{where}: {name} imports its sibling {target}: {unit} and {target_unit} '
                             'are independent')
    return found


def test_every_module_belongs_to_a_layer():
    for path in PACKAGE.rglob('*.py'):
        unit_of(module_name(path))  # KeyError: a module outside every layer
    for directory in (PACKAGE / 'core').iterdir():
        if directory.is_dir() and directory.name != '__pycache__':
            assert f'core.{directory.name}' in LAYERS, f'core/{directory.name}/ is in no layer of docs/architecture.md'


def test_imports_run_one_way_and_the_core_never_imports_ros():
    assert violations() == []


def test_the_layers_are_the_ones_docs_architecture_describes():
    text = (PACKAGE.parent / 'docs' / 'architecture.md').read_text()
    for unit in LAYERS:
        if unit:
            assert f'`{unit.replace(".", "/")}' in text, f'{unit} is not described in docs/architecture.md'


@pytest.mark.parametrize('importer, imported, expected', [
    ('core/lens/models.py', 'from ..zeroshot.spec import CameraSpec\n', 'imports run downwards only'),
    ('core/zeroshot/solver.py', 'from ..ros_formats.rectify import Rectifier\n', 'imports run downwards only'),
    ('core/ros_formats/rectify.py', 'from ..streaming.image_frames import ActiveCalibration\n',
     'imports run downwards only'),
    ('core/streaming/map_builder.py', 'from ..report.canvas import x\n', 'independent'),
    ('core/checkerboard/pose.py', 'from ..lines import x\n', 'independent'),
    ('core/ros_formats/rectify.py', 'import rclpy\n', 'never imports ROS'),
    ('core/streaming/image_frames.py', 'import rclpy\n', 'never imports ROS'),
    ('core/lens/fitting.py', 'from zeroshot_calib_ros.cli import main\n', 'imports run downwards only'),
])
def test_the_rule_catches_an_upward_import(tmp_path, importer, imported, expected):
    """The checker itself: a copy of the package with one offending import added."""
    import shutil
    copy = tmp_path / 'zeroshot_calib_ros'
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns('__pycache__'))
    target = copy / importer
    target.write_text(imported + target.read_text())
    found = violations(copy)
    assert len(found) == 1 and expected in found[0], found
