"""The import rule of docs/architecture.md, enforced on the source: layers import only layers
below them (or modules of their own layer), siblings never import each other, the core never
imports ROS, and every module belongs to a layer (a new module must be placed in one). And the rule
of "Where the tests are": the tests of zeroshot_calib_ros/<dir>/<module>.py are
test/<dir>/test_<module>*.py (or the file of TESTED_THROUGH that covers it); tests of the product as
a whole are in test/product/.

    0 core/lens, core/atomic_file,    lens models, their ROS fits; writing files and reading them
      core/file_input                 bounded (and the version)
    1 core/zeroshot                   spec sheet -> camera (the paper's solver, presets, wide model)
    2 core/checkerboard, core/lines   calibration evidence: chessboard images, straight lines
    3 core/estimation                 the MAP fit over all evidence, its uncertainty, the quality gate
    4 core/ros_data                   what ROS carries, without ROS: files, CameraInfo, images, maps
    5 core/report                     pictures for a user: the calibration report, refine's contact sheet
    6 core (its __init__)             the public API: re-exports
    7 cli, ros                        the two front ends: zeroshot-calib, the ROS node
"""
import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGE = REPO / 'zeroshot_calib_ros'
TESTS = REPO / 'test'
LAYERS = {
    'core.lens': 0, 'core.atomic_file': 0, 'core.file_input': 0,
    'core.zeroshot': 1,
    'core.checkerboard': 2, 'core.lines': 2,
    'core.estimation': 3,
    'core.ros_data': 4,
    'core.report': 5,
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
    ('core/zeroshot/solver.py', 'from ..ros_data.rectify import Rectifier\n', 'imports run downwards only'),
    ('core/checkerboard/pose.py', 'from ..lines import x\n', 'independent'),
    ('core/ros_data/rectify.py', 'import rclpy\n', 'never imports ROS'),
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


# Where the tests are (docs/architecture.md): the tests of zeroshot_calib_ros/<dir>/<module>.py are
# test/<dir>/test_<module>.py and test/<dir>/test_<module>_<aspect>.py. A module without such a file
# is tested through another module's tests: it is listed here with the file that covers it (which
# must name it: import it, or mention its name or path) and why. Prefer a file the rule finds.
TESTED_THROUGH = {
    'core/atomic_file.py': ('test/core/ros_data/test_calibration_file_save.py',
                            'its callers: calibration files saved all or nothing, symlinks, modes'),
    'core/file_input.py': ('test/cli/test_cli_files.py', 'what the CLI reads: FIFOs, size caps, pixel budgets'),
    'core/checkerboard/corner_term.py': ('test/core/estimation/test_board_fit.py', 'the evidence term of the board fit'),
    'core/checkerboard/pose.py': ('test/core/checkerboard/test_evaluation.py', 'board poses of the paper\'s protocol'),
    'core/estimation/fit.py': ('test/core/estimation/test_refine.py', 'the line fit refine runs'),
    'core/estimation/parameters.py': ('test/core/estimation/test_refine.py', 'the layouts of refine\'s fit'),
    'core/estimation/problem.py': ('test/core/estimation/test_refine.py', 'the robust loss, the threaded Jacobian'),
    'core/estimation/terms.py': ('test/core/estimation/test_refine.py', 'the FOV terms and priors of refine'),
    'core/estimation/uncertainty.py': ('test/core/estimation/test_refine.py', 'the covariance and error bar of refine'),
    'core/lines/straightness.py': ('test/core/estimation/test_refine.py', 'the straightness residual refine fits'),
    'core/lens/fitting.py': ('test/core/lens/test_models.py', 'the ROS models\' fits, with the models'),
    'core/lens/projections.py': ('test/core/zeroshot/test_solver.py', 'the four laws, through the paper\'s Table 2'),
    'core/report/canvas.py': ('test/core/report/test_calibration_report.py', 'the pictures it draws'),
    'core/report/debug_sheet.py': ('test/core/report/test_calibration_report.py', 'refine --debug-image'),
    'core/report/synthetic.py': ('test/core/report/test_calibration_report.py', 'the solve report\'s preview'),
    'core/zeroshot/brent.py': ('test/product/test_readme_claims.py', 'the solver\'s root to machine precision'),
    'core/zeroshot/consistency.py': ('test/core/zeroshot/test_spec_consistency.py', 'FOV warnings with the spec\'s checks'),
    'core/zeroshot/wide_solver.py': ('test/core/lens/test_wide_fov.py', 'the solver of the wide model, with it'),
    'ros/echo.py': ('test/product/test_readme_claims_ros.py', 'the echo tool the docs use'),
    'ros/entry_point.py': ('test/product/test_packaging.py', 'the installed node executable'),
    'ros/executors.py': ('test/ros/test_node_lazy.py', 'the node under both executors'),
    'ros/messages.py': ('test/product/test_reliability.py', 'CameraInfo filled from any calibration'),
    'ros/parameter_service.py': ('test/ros/test_node_params.py', 'the node\'s parameters set from another process'),
}
# cli.py is becoming the package cli/ (one module per verb): its tests are already in test/cli/.
TEST_DIR_OF = {'cli.py': 'test/cli'}


def package_modules():
    """Paths of the package's modules relative to the package ('core/zeroshot/solver.py'), without
    the __init__.py files."""
    return sorted(path.relative_to(PACKAGE).as_posix() for path in PACKAGE.rglob('*.py')
                  if path.name != '__init__.py' and '__pycache__' not in path.parts)


def mirror_directory_of(module: str) -> Path:
    """test/<dir>/ for zeroshot_calib_ros/<dir>/<module>.py."""
    return REPO / TEST_DIR_OF[module] if module in TEST_DIR_OF else TESTS / Path(module).parent


def names(text: str, module: str) -> bool:
    """Whether a test file imports a module or mentions it: its dotted name, its path, or its name
    as a word (`brent` in "Brent's method", `executors` in "both executors")."""
    path = Path(module)
    dotted = '.'.join(path.with_suffix('').parts)
    package = '.'.join(path.parent.parts)
    return (f'zeroshot_calib_ros.{dotted}' in text or module in text
            or re.search(rf'from zeroshot_calib_ros\.{re.escape(package)} import [^\n]*\b{path.stem}\b', text) is not None
            or re.search(rf'(?i)(?<![a-z0-9]){re.escape(path.stem)}(?![a-z0-9])', text) is not None)


def test_every_module_has_its_tests_where_its_path_says():
    missing = []
    for module in package_modules():
        directory = mirror_directory_of(module)
        if any(directory.glob(f'test_{Path(module).stem}*.py')):
            continue
        if module in TESTED_THROUGH:
            continue
        missing.append(f'zeroshot_calib_ros/{module}: put its tests in '
                       f'{(directory / f"test_{Path(module).stem}.py").relative_to(REPO)} (or '
                       f'test_{Path(module).stem}_<aspect>.py beside it); if another module\'s tests cover it, '
                       'list it in TESTED_THROUGH of test/product/test_architecture.py with that file and why')
    assert missing == [], '\n'.join(['docs/architecture.md, "Where the tests are":'] + missing)


def test_tested_through_names_real_modules_and_files_that_name_them():
    modules = set(package_modules())
    wrong = []
    for module in sorted(set(TEST_DIR_OF) - modules):
        wrong.append(f'TEST_DIR_OF: zeroshot_calib_ros/{module} no longer exists: its tests go to test/<dir>/ '
                     'of its path now; remove the entry')
    for module, (test_file, why) in sorted(TESTED_THROUGH.items()):
        target = REPO / test_file
        if module not in modules:
            wrong.append(f'TESTED_THROUGH: zeroshot_calib_ros/{module} no longer exists: remove its entry')
        elif any(mirror_directory_of(module).glob(f'test_{Path(module).stem}*.py')):
            wrong.append(f'TESTED_THROUGH: zeroshot_calib_ros/{module} has its own test file now: remove its entry')
        elif not target.is_file():
            wrong.append(f'TESTED_THROUGH: {test_file} (for zeroshot_calib_ros/{module}) does not exist: name the '
                         'file that tests it now')
        elif not names(target.read_text(), module):
            wrong.append(f'TESTED_THROUGH: {test_file} neither imports nor mentions zeroshot_calib_ros/{module}: '
                         'is it really the file that tests it?')
        assert why, module
    assert wrong == [], '\n'.join(wrong)


def test_every_test_file_is_in_a_mirror_of_the_package_or_in_test_product():
    allowed = {TESTS, TESTS / 'product'} | {REPO / d for d in TEST_DIR_OF.values()}
    allowed |= {TESTS / path.relative_to(PACKAGE) for path in PACKAGE.rglob('*')
                if path.is_dir() and path.name != '__pycache__' and (path / '__init__.py').exists()}
    misplaced = [path.relative_to(REPO).as_posix() for path in sorted(TESTS.rglob('test_*.py'))
                 if path.parent not in allowed and 'mutation' not in path.relative_to(TESTS).parts]
    assert misplaced == [], (
        'test files outside the mirror of the package (docs/architecture.md, "Where the tests are": the tests '
        'of zeroshot_calib_ros/<dir>/<module>.py go to test/<dir>/test_<module>*.py, tests of the product as a '
        'whole to test/product/): ' + ', '.join(misplaced))


def test_test_file_names_are_unique():
    """Without __init__.py files, pytest imports each test file by its name alone (and test modules
    import each other by name: test/conftest.py puts every test directory on sys.path)."""
    seen = {}
    for path in sorted(TESTS.rglob('*.py')):
        if 'mutation' in path.relative_to(TESTS).parts or '__pycache__' in path.parts:
            continue
        seen.setdefault(path.name, []).append(path.relative_to(REPO).as_posix())
    twice = {name: paths for name, paths in seen.items() if len(paths) > 1}
    assert twice == {}, f'test files (and helpers) of the same name, which pytest cannot both import: {twice}; rename one'
    assert not list(TESTS.rglob('__init__.py')), 'test/ has no __init__.py (helpers are imported by name)'
