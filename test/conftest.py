"""Test session set-up.

``make test`` runs the suite twice: everything in the ROS environment (.venv: ROS 2 Jazzy,
current numpy / OpenCV 5), then the ROS-free tests in .venv-jazzy-libs, which has the
numpy / SciPy / OpenCV 4 versions of Ubuntu 24.04, the platform of ROS 2 Jazzy
(ZEROSHOT_ROS_FREE_ONLY=1). Modules that need rclpy or the colcon install tree are left out of
that second run only.
"""
import os
import sys
from pathlib import Path

# The tests mirror the package (test/core/zeroshot/test_solver.py tests
# zeroshot_calib_ros/core/zeroshot/solver.py; docs/architecture.md, "Where the tests are"). Without
# __init__.py files pytest puts test/ (this file's directory: the helpers, ros_peer.py, scenes.py...)
# and each test file's own directory on sys.path; a test module that imports another test module
# (`from test_calibration import TRUE`) finds it from any directory, and alone, because every
# directory of test files is on sys.path too (test file basenames are unique).
TEST_DIR = Path(__file__).resolve().parent
for _directory in sorted({path.parent for path in TEST_DIR.rglob('test_*.py')} - {TEST_DIR}):
    if str(_directory) not in sys.path:
        sys.path.append(str(_directory))

# Test files (basenames, wherever they are under test/) that need rclpy or the colcon install tree.
NEEDS_ROS = ['test_node.py', 'test_node_contracts.py', 'test_node_files.py', 'test_bringup.py',
             'test_reliability.py', 'test_packaging.py', 'test_node_observable.py',
             'test_node_fuzz.py', 'test_readme_claims_ros.py', 'test_node_raw_path.py', 'test_node_refine.py',
             'test_node_params.py', 'test_node_calibration_cycle.py', 'test_node_lazy.py']

ROS_FREE_ONLY = os.environ.get('ZEROSHOT_ROS_FREE_ONLY') == '1'


def pytest_ignore_collect(collection_path, config):
    """In the ROS-free run, the files of NEEDS_ROS are not collected, in whichever directory."""
    if ROS_FREE_ONLY and collection_path.name in NEEDS_ROS:
        return True
    return None


def pytest_report_header(config):
    import cv2
    import numpy
    import scipy
    header = f'numpy {numpy.__version__}, scipy {scipy.__version__}, OpenCV {cv2.__version__}'
    if ROS_FREE_ONLY:
        header += f"; ROS-free run: {', '.join(NEEDS_ROS)} not collected"
    return header
