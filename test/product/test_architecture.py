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
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / 'zeroshot_calib_ros'
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


# Where the tests are (docs/architecture.md): zeroshot_calib_ros/<dir>/<module>.py is tested in
# test/<dir>/test_<module>*.py, or, listed here, by the file that covers it (which names it) and why.
TESTED_THROUGH = {
    'core/atomic_file.py': ('test/core/ros_formats/test_calibration_file_save.py', 'calibration files saved'),
    'core/file_input.py': ('test/cli/test_cli_files.py', 'every file the CLI reads'),
    'core/checkerboard/corner_term.py': ('test/core/estimation/test_board_fit.py', 'the board fit\'s term'),
    'core/checkerboard/pose.py': ('test/core/checkerboard/test_evaluation.py', 'the protocol\'s poses'),
    'core/estimation/fit.py': ('test/core/estimation/test_refine.py', 'the fit refine runs'),
    'core/estimation/parameters.py': ('test/core/estimation/test_refine.py', 'refine\'s layouts'),
    'core/estimation/problem.py': ('test/core/estimation/test_refine.py', 'the loss, the Jacobian'),
    'core/estimation/terms.py': ('test/core/estimation/test_refine.py', 'refine\'s FOV terms, priors'),
    'core/estimation/uncertainty.py': ('test/core/estimation/test_refine.py', 'refine\'s error bar'),
    'core/lens/fitting.py': ('test/core/lens/test_models.py', 'the models\' ROS fits'),
    'core/lens/projections.py': ('test/core/zeroshot/test_solver.py', 'the laws, by Table 2'),
    'core/report/canvas.py': ('test/core/report/test_calibration_report.py', 'what it draws'),
    'core/report/debug_sheet.py': ('test/core/report/test_calibration_report.py', 'refine --debug-image'),
    'core/report/synthetic.py': ('test/core/report/test_calibration_report.py', 'the solve preview'),
    'core/zeroshot/brent.py': ('test/product/test_readme_claims.py', 'the solver\'s root, exact'),
    'core/zeroshot/consistency.py': ('test/core/zeroshot/test_spec_consistency.py', 'with the spec'),
    'core/zeroshot/wide_solver.py': ('test/core/lens/test_wide_fov.py', 'with the wide model'),
    'ros/echo.py': ('test/product/test_readme_claims_ros.py', 'as the docs use it'),
    'ros/entry_point.py': ('test/product/test_packaging.py', 'the installed node'),
    'ros/executors.py': ('test/ros/test_node_lazy.py', 'the node on both'),
    'ros/messages.py': ('test/product/test_reliability.py', 'CameraInfo of any calibration'),
    'ros/parameter_service.py': ('test/ros/test_node_params.py', 'parameters set from outside'),
}
TESTED_THROUGH.update({
    'cli/__main__.py': ('test/product/test_readme.py', 'python -m zeroshot_calib_ros.cli, as the README runs it'),
    'cli/arguments.py': ('test/cli/test_cli.py', 'every verb\'s options and their one-line errors'),
    'cli/command.py': ('test/cli/test_cli.py', 'zeroshot-calib as a user runs it'),
    'cli/corners.py': ('test/cli/test_cli_calibrate_checks.py', 'calibrate\'s chessboard input'),
    'cli/evaluate.py': ('test/cli/test_cli.py', 'evaluate\'s options and output'),
    'cli/presets.py': ('test/cli/test_cli_fuzz.py', 'the presets verb among every verb'),
    'cli/rectify.py': ('test/cli/test_cli.py', 'rectify\'s options and files'),
    'cli/solve.py': ('test/cli/test_cli.py', 'solve, its formats and --batch'),
    'core/zeroshot/numbers.py': ('test/core/zeroshot/test_batch.py', 'the numbers of a batch CSV'),
})
# A front end's module is tested in test/<front end>/test_<front end>_<module>*.py (test_cli_refine.py:
# test file names are unique, and core/estimation/refine.py has test_refine.py)
FRONT_END_PREFIX = {'cli': 'cli_'}
REPO, TESTS = PACKAGE.parent, PACKAGE.parent / 'test'
WHERE = 'docs/architecture.md, "Where the tests are": '


def modules():
    return sorted(p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob('*.py')
                  if p.name != '__init__.py' and '__pycache__' not in p.parts)


def own_tests(module):
    """test/<dir>/test_<module>*.py of zeroshot_calib_ros/<dir>/<module>.py."""
    directory = TESTS / Path(module).parent
    return directory, sorted(directory.glob(f'test_{own_prefix(module)}{Path(module).stem}*.py'))


def own_prefix(module):
    return FRONT_END_PREFIX.get(Path(module).parts[0], '') if len(Path(module).parts) > 1 else ''


def names(text, module):
    """A test file imports or mentions a module: dotted name, path or stem as a word."""
    path = Path(module)
    return ('zeroshot_calib_ros.' + '.'.join(path.with_suffix('').parts) in text or module in text
            or re.search(rf'(?i)(?<![a-z0-9]){path.stem}(?![a-z0-9])', text) is not None)


def test_every_module_has_its_tests_where_its_path_says():
    missing = [f'zeroshot_calib_ros/{m}: its tests go to {(d / ("test_" + own_prefix(m) + Path(m).stem)).relative_to(REPO)}'
               '[_<aspect>].py (or, if another file tests it, to TESTED_THROUGH of test/product/test_architecture.py)'
               for m in modules() for d, found in [own_tests(m)] if not found and m not in TESTED_THROUGH]
    assert missing == [], WHERE + '\n'.join(missing)


def test_tested_through_lists_modules_without_tests_and_files_that_test_them():
    wrong = []
    for module, (test_file, why) in TESTED_THROUGH.items():
        if module not in modules() or own_tests(module)[1]:
            wrong.append(f'TESTED_THROUGH: {module} is gone or has test files of its own: remove it')
        elif not (REPO / test_file).is_file() or not names((REPO / test_file).read_text(), module) or not why:
            wrong.append(f'TESTED_THROUGH: {test_file} is no file naming {module}: give the file that tests it')
    assert wrong == [], WHERE + '\n'.join(wrong)


def test_every_test_file_is_in_a_mirror_of_the_package_or_in_test_product():
    allowed = {TESTS, TESTS / 'product', TESTS / 'mutation'}
    allowed |= {TESTS / p.parent.relative_to(PACKAGE) for p in PACKAGE.rglob('__init__.py')}
    misplaced = [str(p.relative_to(REPO)) for p in TESTS.rglob('test_*.py') if p.parent not in allowed]
    assert misplaced == [], WHERE + 'the tests of zeroshot_calib_ros/<dir>/<module>.py go to ' \
        f'test/<dir>/test_<module>*.py, the tests of the product as a whole to test/product/: move {misplaced}'


def test_test_file_names_are_unique_and_test_has_no_init():
    """pytest imports test files by name (no __init__.py), and test modules each other."""
    paths = [p for p in TESTS.rglob('*.py') if 'mutation' not in p.parts]
    twice = sorted(str(p.relative_to(REPO)) for p in paths if [q.name for q in paths].count(p.name) > 1)
    assert twice == [], WHERE + f'one name, two files (pytest imports only one): rename one of {twice}'
    assert not list(TESTS.rglob('__init__.py')), WHERE + 'test/ has no __init__.py (helpers are imported by name)'
