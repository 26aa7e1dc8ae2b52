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

# ZEROSHOT_SHARD=k/n (1 <= k <= n): the k-th of n disjoint sets of whole modules (module-scoped
# fixtures are computed once), balanced by MODULE_SECONDS; `make test` runs the ROS-free tests on
# Jazzy's libraries as two such processes at the same time (one alone would be the longest chain).
MODULE_SECONDS = {  # a module's run time, roughly (--durations=0 on 2 cores); the others: 1 s
    'test_refine_cli.py': 90, 'test_evaluation.py': 104, 'test_readme.py': 86, 'test_spec_consistency.py': 46,
    'test_line_detection.py': 41, 'test_report.py': 41, 'test_cli_output.py': 25, 'test_lens_prior.py': 35,
    'test_calibrate_checks.py': 33, 'test_image_region.py': 31, 'test_online_refinement.py': 30,
    'test_board_fit.py': 28, 'test_input_checks.py': 28, 'test_static_curves.py': 26, 'test_cli_fuzz.py': 25,
    'test_cli_files.py': 18, 'test_real_photos.py': 17, 'test_readme_claims.py': 17,
    'test_calibration_file_fuzz.py': 15, 'test_cli.py': 14, 'test_camera_models.py': 12, 'test_calibration.py': 12,
    'test_wide_fov.py': 11, 'test_estimation.py': 10,
}


def shards(names, n):
    """``names`` (module file names) in ``n`` disjoint lists, the costliest first to the least loaded."""
    parts = [[] for _ in range(n)]
    load = [0.0] * n
    for name in sorted(names, key=lambda m: (-MODULE_SECONDS.get(m, 1), m)):
        k = min(range(n), key=lambda i: (load[i], i))
        parts[k].append(name)
        load[k] += MODULE_SECONDS.get(name, 1)
    return parts


SHARD = os.environ.get('ZEROSHOT_SHARD')
if SHARD:
    _k, _n = (int(x) for x in SHARD.split('/'))
    if not 1 <= _k <= _n:
        raise RuntimeError(f'ZEROSHOT_SHARD={SHARD}: k/n with 1 <= k <= n')
    _selected = sorted(p.name for p in Path(__file__).parent.glob('test_*.py') if p.name not in collect_ignore)
    collect_ignore = collect_ignore + [m for k, part in enumerate(shards(_selected, _n), 1) if k != _k for m in part]


def pytest_report_header(config):
    import cv2
    import numpy
    import scipy
    header = f'numpy {numpy.__version__}, scipy {scipy.__version__}, OpenCV {cv2.__version__}'
    if ROS_FREE_ONLY:
        header += f"; ROS-free run: {', '.join(NEEDS_ROS)} not collected"
    elif ROS_ONLY:
        header += f"; ROS run: {', '.join(NEEDS_ROS)} only"
    if SHARD:
        header += f'; shard {SHARD} of the modules'

    return header
