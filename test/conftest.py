"""Test session set-up.

``make test`` runs the suite twice: everything in the ROS environment (.venv: ROS 2 Jazzy,
current numpy / OpenCV 5), then the ROS-free tests in .venv-jazzy-libs, which has the
numpy / SciPy / OpenCV 4 versions of Ubuntu 24.04, the platform of ROS 2 Jazzy
(ZEROSHOT_ROS_FREE_ONLY=1). Modules that need rclpy or the colcon install tree are left out of
that second run only.
"""
import os
from pathlib import Path

NEEDS_ROS = ['test_node.py', 'test_node_contracts.py', 'test_node_files.py', 'test_bringup.py',
             'test_reliability.py', 'test_packaging.py', 'test_node_observable.py',
             'test_node_fuzz.py', 'test_readme_claims_ros.py', 'test_raw_path.py', 'test_node_refine.py', 'test_node_params.py',
             'test_node_calibration_cycle.py', 'test_node_lazy.py']

ROS_FREE_ONLY = os.environ.get('ZEROSHOT_ROS_FREE_ONLY') == '1'
# ZEROSHOT_ROS_ONLY=1: the modules of NEEDS_ROS alone (`make test` runs them in one process and
# the ROS-free modules of the same environment in another, at the same time)
ROS_ONLY = os.environ.get('ZEROSHOT_ROS_ONLY') == '1'
if ROS_FREE_ONLY and ROS_ONLY:
    raise RuntimeError('ZEROSHOT_ROS_FREE_ONLY=1 and ZEROSHOT_ROS_ONLY=1 select nothing together')
if ROS_FREE_ONLY:
    collect_ignore = list(NEEDS_ROS)
elif ROS_ONLY:
    collect_ignore = sorted(p.name for p in Path(__file__).parent.glob('test_*.py') if p.name not in NEEDS_ROS)
else:
    collect_ignore = []


def pytest_report_header(config):
    import cv2
    import numpy
    import scipy
    header = f'numpy {numpy.__version__}, scipy {scipy.__version__}, OpenCV {cv2.__version__}'
    if ROS_FREE_ONLY:
        header += f"; ROS-free run: {', '.join(NEEDS_ROS)} not collected"
    elif ROS_ONLY:
        header += f"; ROS run: {', '.join(NEEDS_ROS)} only"
    return header
