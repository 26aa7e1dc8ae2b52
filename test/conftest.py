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

import pytest

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
# ZEROSHOT_ROS_ONLY=1: the modules of NEEDS_ROS alone (`make test` runs them in one process and
# the ROS-free modules of the same environment in another, at the same time)
ROS_ONLY = os.environ.get('ZEROSHOT_ROS_ONLY') == '1'
if ROS_FREE_ONLY and ROS_ONLY:
    raise RuntimeError('ZEROSHOT_ROS_FREE_ONLY=1 and ZEROSHOT_ROS_ONLY=1 select nothing together')
TEST_FILES = sorted({p.name for p in TEST_DIR.rglob('test_*.py') if 'mutation' not in p.parts})
if ROS_FREE_ONLY:
    IGNORED = set(NEEDS_ROS)
elif ROS_ONLY:
    IGNORED = {name for name in TEST_FILES if name not in NEEDS_ROS}
else:
    IGNORED = set()

# ZEROSHOT_SHARD=k/n (1 <= k <= n): the k-th of n disjoint sets of whole modules (module-scoped
# fixtures are computed once), balanced by MODULE_SECONDS; `make test` runs the ROS-free tests of
# each environment as two such processes at the same time (one alone would be the longest chain).
MODULE_SECONDS = {  # a module's CPU seconds (user + sys, its subprocesses included) on .venv, roughly; the others: 1 s
    'test_cli_refine.py': 54, 'test_evaluation.py': 52, 'test_lens_prior.py': 40, 'test_cli_calibrate_checks.py': 36,
    'test_board_fit.py': 36, 'test_readme.py': 29, 'test_detect.py': 28, 'test_calibration_input_checks.py': 27,
    'test_cli_output.py': 26, 'test_cli.py': 24, 'test_cli_fuzz.py': 21, 'test_cli_files.py': 20,
    'test_calibration_report.py': 20, 'test_online_refinement.py': 19, 'test_spec_consistency.py': 18,
    'test_calibration_file_fuzz.py': 18, 'test_image_region.py': 14, 'test_refine.py': 12, 'test_real_photos.py': 12,
    'test_calibration.py': 11, 'test_readme_claims.py': 10, 'test_models.py': 10, 'test_static_curves.py': 9,
    'test_architecture.py': 5, 'test_zero_shot.py': 4, 'test_wide_fov.py': 3, 'test_rectify.py': 3,
    'test_corners_fuzz.py': 2, 'test_gate_stability.py': 2,
}


TOGETHER = [('test_evaluation.py', 'test_readme.py')]
"""Modules that check the computation of one session fixture (shared_set_evaluation, below): kept
in one shard, so that it runs once."""


def shards(names, n):
    """``names`` (module file names) in ``n`` disjoint lists, the costliest first to the least
    loaded; the modules of a TOGETHER group as one."""
    units = []
    for name in names:
        unit = [m for m in next((g for g in TOGETHER if name in g), (name,)) if m in names]
        if unit not in units:
            units.append(unit)
    cost = [sum(MODULE_SECONDS.get(m, 1) for m in unit) for unit in units]
    parts = [[] for _ in range(n)]
    load = [0.0] * n
    for c, unit in sorted(zip(cost, units), key=lambda cu: (-cu[0], cu[1])):
        k = min(range(n), key=lambda i: (load[i], i))
        parts[k].extend(unit)
        load[k] += c
    return parts


SHARD = os.environ.get('ZEROSHOT_SHARD')
if SHARD:
    _k, _n = (int(x) for x in SHARD.split('/'))
    if not 1 <= _k <= _n:
        raise RuntimeError(f'ZEROSHOT_SHARD={SHARD}: k/n with 1 <= k <= n')
    _selected = [name for name in TEST_FILES if name not in IGNORED]
    IGNORED |= {m for k, part in enumerate(shards(_selected, _n), 1) if k != _k for m in part}


def pytest_ignore_collect(collection_path, config):
    """The files this run leaves out (NEEDS_ROS in the ROS-free run, the others in the ROS run,
    the other shards' modules), by basename, in whichever directory they are."""
    if collection_path.name in IGNORED:
        return True
    return None


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


@pytest.fixture(scope='session')
def shared_set_evaluation():
    """docs/calibration.md's evaluate command on the shared data set (24 images, every single-shot
    run: the costliest computation of the suite), run once per process in-process and recorded
    (shared_set.EvaluateRun): test_readme.py compares its output with the page, test_evaluation.py
    checks its result and replays it to other runs of the CLI on the same inputs."""
    from shared_set import run_evaluate_command
    return run_evaluate_command()
