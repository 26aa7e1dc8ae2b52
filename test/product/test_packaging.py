"""Packaging checks: the colcon install tree, the pip wheel, package.xml.

Runs after `make build` (as part of `make test`): it looks at the install
tree colcon produced under install/, and builds a wheel of a copy of the
sources with pip, to check that the ROS executable `node` is only ever
installed into lib/zeroshot_calib_ros/ and never into a bin/ directory (where
it would shadow Node.js).
"""

import ast
import configparser
import json
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PKG = 'zeroshot_calib_ros'
INSTALL = ROOT / 'install' / PKG
LIBEXEC = INSTALL / 'lib' / PKG

EXEC_DEPENDS = {
    'rclpy', 'rcl_interfaces', 'sensor_msgs', 'diagnostic_msgs', 'python3-numpy', 'python3-scipy',
    'python3-opencv', 'python3-yaml',
}
TEST_DEPENDS = {'python3-pytest'}
DATA_TABLES = ('camera_presets.csv', 'lens_prior.csv')
"""zeroshot_calib_ros/data/: package data (setup.py package_data), in the wheel and the install tree."""
# the rosdep key (package.xml) that provides each top-level module an installed file may import
ROSDEP_KEY_OF_MODULE = {
    'rclpy': 'rclpy', 'rcl_interfaces': 'rcl_interfaces', 'sensor_msgs': 'sensor_msgs',
    'diagnostic_msgs': 'diagnostic_msgs', 'numpy': 'python3-numpy', 'scipy': 'python3-scipy',
    'cv2': 'python3-opencv', 'yaml': 'python3-yaml', 'launch': 'launch', 'launch_ros': 'launch_ros',
    'ament_index_python': 'ament_index_python', 'argcomplete': 'python3-argcomplete',
}


@pytest.fixture(scope='module')
def source_copy(tmp_path_factory):
    """The package's sources copied to a temporary dir (repo stays clean)."""
    dst = tmp_path_factory.mktemp('src') / PKG
    dst.mkdir()
    for name in ('setup.py', 'setup.cfg', 'package.xml'):
        shutil.copy2(ROOT / name, dst / name)
    ignore = shutil.ignore_patterns('__pycache__', '*.pyc', '*.egg-info')
    for name in ('resource', 'config', 'launch', PKG):
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, dst / name, ignore=ignore)
    return dst


def _require_install_tree():
    if not LIBEXEC.is_dir():
        pytest.fail(f'{LIBEXEC} does not exist: run `make build` first')


@pytest.mark.parametrize('name', ['node', 'zeroshot-calib'])
def test_colcon_installs_executables_into_libexec(name):
    _require_install_tree()
    exe = LIBEXEC / name
    assert exe.is_file(), f'{exe} missing'
    assert os.access(exe, os.X_OK), f'{exe} is not executable'
    shebang = exe.read_text().splitlines()[0]
    assert shebang.startswith('#!')
    interpreter = shebang[2:].strip().split()[0]
    assert os.access(interpreter, os.X_OK), f'{exe}: bad interpreter {interpreter}'


def test_no_node_in_any_bin_dir():
    _require_install_tree()
    bin_dirs = [ROOT / '.venv' / 'bin']
    bin_dirs += [p for p in (ROOT / 'install').rglob('bin') if p.is_dir()]
    for d in bin_dirs:
        assert not (d / 'node').exists(), f'{d / "node"} exists (would shadow Node.js)'
    # and in the install tree, `node` lives in lib/zeroshot_calib_ros only
    found = sorted(p for p in (ROOT / 'install').rglob('node') if p.is_file())
    assert found == [LIBEXEC / 'node'], found


def test_pip_wheel_has_no_node_entry_point(source_copy, tmp_path):
    out = tmp_path / 'wheels'
    proc = subprocess.run(
        [sys.executable, '-m', 'pip', 'wheel', '--no-deps', '--no-build-isolation',
         '--no-cache-dir', '-q', '-w', str(out), str(source_copy)],
        cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    wheels = list(out.glob('*.whl'))
    assert len(wheels) == 1, wheels
    with zipfile.ZipFile(wheels[0]) as zf:
        names = zf.namelist()
        ep_files = [n for n in names if n.endswith('.dist-info/entry_points.txt')]
        assert len(ep_files) == 1, names
        parser = configparser.ConfigParser()
        parser.optionxform = str  # keep names as they are
        parser.read_string(zf.read(ep_files[0]).decode())
    scripts = dict(parser.items('console_scripts'))
    assert scripts.get('zeroshot-calib') == 'zeroshot_calib_ros.cli:main'
    assert 'node' not in scripts, scripts
    assert not any(n.endswith('/scripts/node') for n in names), names
    # the package's tables travel with it (presets; the lens-law prior one-FOV specs are solved with)
    for table in DATA_TABLES:
        assert f'{PKG}/data/{table}' in names, names


def test_colcon_install_tree_carries_the_data_tables():
    _require_install_tree()
    for table in DATA_TABLES:
        found = list((INSTALL / 'lib').glob(f'python3*/site-packages/{PKG}/data/{table}'))
        assert len(found) == 1 and found[0].read_bytes() == (ROOT / PKG / 'data' / table).read_bytes(), table


def _setup_py_version(src):
    proc = subprocess.run([sys.executable, 'setup.py', '--version'], cwd=src,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.strip().splitlines()[-1].strip()


def test_package_xml(source_copy):
    root = ET.parse(ROOT / 'package.xml').getroot()
    assert root.tag == 'package'
    assert root.get('format') == '3'
    assert root.findtext('name') == PKG
    assert {e.text for e in root.findall('exec_depend')} >= EXEC_DEPENDS
    assert {e.text for e in root.findall('test_depend')} >= TEST_DEPENDS
    assert root.findtext('export/build_type') == 'ament_python'
    assert root.findtext('license') == 'Apache-2.0'
    maintainer = root.find('maintainer')
    assert maintainer is not None and maintainer.get('email') == 'maintainers@zeroshot-calib.dev'
    version = root.findtext('version')
    assert version and version == _setup_py_version(source_copy)


def test_sourcing_install_setup_bash_puts_the_cli_on_path():
    """README: `make build && source install/setup.bash && zeroshot-calib solve --preset
    gopro_hero9_wide`, in a shell that has nothing of ours (no venv, no PYTHONPATH)."""
    setup_bash = ROOT / 'install' / 'setup.bash'
    assert setup_bash.is_file(), 'make build must produce install/setup.bash (colcon-bash)'
    env = {'HOME': os.environ.get('HOME', '/root'), 'PATH': '/usr/local/bin:/usr/bin:/bin'}
    done = subprocess.run(['bash', '-c', f'source {setup_bash} && command -v zeroshot-calib && '
                           '{ command -v node | grep -c zeroshot || true; } && '
                           'zeroshot-calib solve --preset gopro_hero9_wide --json'],
                          env=env, capture_output=True, text=True, timeout=120, cwd='/')
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == str(ROOT / 'install' / 'zeroshot_calib_ros' / 'bin' / 'zeroshot-calib')
    assert lines[1] == '0'  # `node` stays off PATH
    result = json.loads(lines[2])
    assert abs(result['f'] - 876.0) < 0.1  # the paper's Table 2, Hero9(W1)


def test_installed_node_starts_on_what_its_first_camera_info_needs():
    """Start-up of the installed executable (issue 14): its wrapper imports the node module
    directly (setuptools' easy-install wrapper first scans the installed metadata with
    importlib.metadata, up to 0.1 s here), and the node module loads neither OpenCV (only rectification
    needs it), nor the online refinement (only refine:=true), nor scipy.optimize. `--help`
    imports the node module and stops before rclpy.init."""
    _require_install_tree()
    env = dict(os.environ, PYTHONPATH=str(next(INSTALL.glob('lib/python3*/site-packages'))))
    exe = LIBEXEC / 'node'
    interpreter = exe.read_text().splitlines()[0][2:].strip()
    result = subprocess.run([interpreter, '-X', 'importtime', str(exe), '--help'], env=env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr[-2000:]
    assert 'ros2 run zeroshot_calib_ros node' in result.stdout
    imported = {line.split('|')[-1].strip() for line in result.stderr.splitlines() if line.startswith('import time:')}
    assert 'zeroshot_calib_ros.ros.node' in imported
    unwanted = {'importlib.metadata', 'cv2', 'zeroshot_calib_ros.core.streaming.online_refinement', 'scipy.optimize'}
    assert not imported & unwanted, sorted(imported & unwanted)


def test_install_tree_is_byte_compiled():
    """Every module of the install tree has a current .pyc, as a user's colcon build leaves it
    (without, each start of the node compiles its modules again: 0.05-0.1 s before the first
    CameraInfo). The build must byte-compile even where PYTHONDONTWRITEBYTECODE is set."""
    import importlib.util
    _require_install_tree()
    sources = sorted(next(INSTALL.glob('lib/python3*/site-packages')).joinpath(PKG).rglob('*.py'))
    assert len(sources) > 20
    stale = []
    for source in sources:
        cached = Path(importlib.util.cache_from_source(str(source)))
        if not cached.is_file():
            stale.append(f'{source.name}: no .pyc')
            continue
        header = cached.read_bytes()[:16]
        if int.from_bytes(header[8:12], 'little') != int(source.stat().st_mtime) & 0xFFFFFFFF:
            stale.append(f'{source.name}: .pyc older than the source')
    assert not stale, stale


def _top_level_imports(path):
    """The top-level modules a Python file imports (absolute imports only; every import
    statement, also those inside functions and try blocks)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split('.')[0])
    return found


def test_package_xml_exec_depends_cover_every_import_of_the_install_tree():
    """`rosdep install --from-paths src` installs package.xml's exec_depends, and nothing else:
    every module that an installed .py file (the package, the launch files) imports must come
    from the standard library, the package itself or an exec_depend; and an installed launch
    file needs `ros2launch` for `ros2 launch` itself."""
    _require_install_tree()
    exec_depends = {e.text for e in ET.parse(ROOT / 'package.xml').getroot().findall('exec_depend')}
    files = sorted(INSTALL.rglob('*.py'))
    launch_files = [f for f in files if f.name.endswith('.launch.py')]
    assert launch_files, 'no launch file in the install tree'
    missing = {}
    for path in files:
        for module in sorted(_top_level_imports(path) - set(sys.stdlib_module_names) - {PKG}):
            assert module in ROSDEP_KEY_OF_MODULE, (
                f'{path.relative_to(INSTALL)} imports {module}: add its rosdep key to ROSDEP_KEY_OF_MODULE '
                'and to package.xml')
            if ROSDEP_KEY_OF_MODULE[module] not in exec_depends:
                missing.setdefault(ROSDEP_KEY_OF_MODULE[module], str(path.relative_to(INSTALL)))
    if 'ros2launch' not in exec_depends:
        missing['ros2launch'] = f'`ros2 launch` of {launch_files[0].name}'
    assert not missing, f'package.xml lacks <exec_depend>s (key: needed by): {missing}'


def test_launch_files_are_installed_under_share_launch():
    """Robot bringups include a package's launch files as
    ``PathJoinSubstitution([FindPackageShare('zeroshot_calib_ros'), 'launch', 'zeroshot_calib.launch.py'])``:
    the install tree has it at share/zeroshot_calib_ros/launch/, the repository keeps it in launch/,
    and none is kept beside the params files in config/ (an install tree built before
    the move keeps its stale copy there: `ros2 launch` then finds two; remove install/ once)."""
    _require_install_tree()
    share = INSTALL / 'share' / PKG
    for name in ('zeroshot_calib.launch.py', 'usb_cam_bringup.launch.py'):
        assert (share / 'launch' / name).is_file(), sorted(str(p.relative_to(share)) for p in share.rglob('*.launch.py'))
        assert (ROOT / 'launch' / name).is_file()
    assert not list((ROOT / 'config').glob('*.launch.py'))


def test_symlink_install_puts_the_cli_on_path(source_copy, tmp_path):
    """`colcon build --symlink-install` (setup.py develop): after `source install/setup.bash`
    the CLI runs from install/zeroshot_calib_ros/bin, `ros2 run` finds `node` in
    lib/zeroshot_calib_ros/, and `node` is on no PATH."""
    venv_bin = ROOT / '.venv' / 'bin'
    if not (venv_bin / 'colcon').exists():
        pytest.skip('colcon is not installed in .venv (make venv)')
    install = tmp_path / 'install'
    env = dict(os.environ, PATH=f'{venv_bin}:{os.environ["PATH"]}', VIRTUAL_ENV=str(ROOT / '.venv'))
    env.pop('PYTHONDONTWRITEBYTECODE', None)
    built = subprocess.run(['colcon', '--log-base', str(tmp_path / 'log'), 'build', '--symlink-install',
                            '--paths', str(source_copy), '--build-base', str(tmp_path / 'build'),
                            '--install-base', str(install), '--event-handlers', 'console_direct-'],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    log = tmp_path / 'log' / 'latest_build' / PKG / 'stdout_stderr.log'
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr[-2000:] + (log.read_text() if log.exists() else '')
    assert os.access(install / PKG / 'lib' / PKG / 'node', os.X_OK)
    clean = {'HOME': os.environ.get('HOME', '/root'), 'PATH': '/usr/local/bin:/usr/bin:/bin'}
    done = subprocess.run(['bash', '-c', f'source {install}/setup.bash && command -v zeroshot-calib && '
                           '{ command -v node | grep -c zeroshot || true; } && '
                           'zeroshot-calib solve --preset gopro_hero9_wide --json'],
                          env=clean, capture_output=True, text=True, timeout=120, cwd='/')
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == str(install / PKG / 'bin' / 'zeroshot-calib')
    assert lines[1] == '0'  # `node` stays off PATH
    assert abs(json.loads(lines[2])['f'] - 876.0) < 0.1  # the paper's Table 2, Hero9(W1)
