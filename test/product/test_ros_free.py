"""The core and the CLI work on machines without ROS: nothing they import may be a ROS module."""
import subprocess
import sys
import textwrap

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ROS_MODULES = ['rclpy', 'rcl_interfaces', 'sensor_msgs', 'std_msgs', 'builtin_interfaces',
               'ament_index_python', 'rosidl_runtime_py', 'rpyutils', 'launch', 'launch_ros']


def test_core_and_cli_import_with_ros_unimportable():
    code = textwrap.dedent(f'''
        import sys
        BLOCKED = {ROS_MODULES!r}

        class NoRos:
            def find_spec(self, name, path=None, target=None):
                if name.split('.')[0] in BLOCKED:
                    raise ImportError(f'ROS module {{name}} imported by the ROS-free core')
                return None

        sys.meta_path.insert(0, NoRos())
        import zeroshot_calib_ros.core as core
        import zeroshot_calib_ros.cli as cli
        import pkgutil, importlib
        for info in pkgutil.walk_packages(core.__path__, 'zeroshot_calib_ros.core.'):
            importlib.import_module(info.name)
        solution = core.solve_zero_shot(core.CameraSpec(1920, 1080, 118, 69))
        assert abs(solution.f - 876.0) < 0.05
        leaked = [m for m in sys.modules if m.split('.')[0] in BLOCKED]
        assert not leaked, leaked
        print('ok')
    ''')
    run = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, cwd=REPO)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == 'ok'


def _top_level_imports(path):
    import ast
    roots = set()
    for statement in ast.parse(path.read_text()).body:
        if isinstance(statement, ast.Import):
            roots |= {alias.name.split('.')[0] for alias in statement.names}
        elif isinstance(statement, ast.ImportFrom) and statement.module and statement.level == 0:
            roots.add(statement.module.split('.')[0])
    return roots


def test_every_test_module_that_imports_ros_is_left_out_of_the_ros_free_run():
    """`make test`'s second run (Ubuntu 24.04's libraries, no ROS) collects every test module
    not in conftest.NEEDS_ROS: one that imports a ROS module at its top ends that whole run in a
    collection error (seen on a clean clone: diagnostic_msgs, a new node test)."""
    from conftest import NEEDS_ROS
    needs = []
    for path in sorted((REPO / 'test').rglob('test_*.py')):
        roots = _top_level_imports(path)
        if any(root in ROS_MODULES or root == 'ros_peer' or root.endswith(('_msgs', '_srvs', '_interfaces'))
               for root in roots):
            needs.append(path.name)
    assert needs, 'no ROS test module found: the scan is broken'
    assert not set(needs) - set(NEEDS_ROS), f'add to NEEDS_ROS in test/conftest.py: {sorted(set(needs) - set(NEEDS_ROS))}'
