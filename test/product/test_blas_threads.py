"""The `zeroshot-calib` command and the node run numpy's OpenBLAS on one thread, and a user's
OPENBLAS_NUM_THREADS wins (cli/__init__.py, ros/__init__.py). Beside another busy process, the
waiting threads of a second BLAS thread made `calibrate` 5x slower with Ubuntu 24.04's numpy
(benchmarks/results/blas_threads.md); the fits gain nothing from it.

What is checked is what OpenBLAS did: the threads of a process that imported the front end and
then numpy (as the command and the node's executable do), against the same imports with the
variable set by hand. OpenBLAS starts its worker threads when it loads."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

# each front end as its executable imports it: the command's package, the node's entry point
FRONT_ENDS = {'command': 'zeroshot_calib_ros.cli', 'node': 'zeroshot_calib_ros.ros.entry_point'}


def _threads(imports: str, blas_threads=None, omp_threads=None) -> int:
    """Threads of a fresh interpreter after ``imports``, numpy and one BLAS call."""
    env = {k: v for k, v in os.environ.items() if k not in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS')}
    env['PYTHONPATH'] = str(REPO) + os.pathsep + env.get('PYTHONPATH', '')
    if blas_threads is not None:
        env['OPENBLAS_NUM_THREADS'] = str(blas_threads)
    if omp_threads is not None:  # OpenBLAS's fallback when OPENBLAS_NUM_THREADS is not set
        env['OMP_NUM_THREADS'] = str(omp_threads)
    code = (f'{imports}\nimport os, numpy\nnumpy.linalg.solve(numpy.eye(200), numpy.ones(200))\n'
            "print(len(os.listdir('/proc/self/task')))")
    done = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return int(done.stdout.split()[-1])


@pytest.fixture(scope='module')
def numpy_threads_blas():
    """numpy's own: more threads by default and with two BLAS threads than with one (else nothing
    to check here)."""
    if not Path('/proc/self/task').is_dir():
        pytest.skip('counting threads needs /proc')
    one, two, default = _threads('', 1), _threads('', 2), _threads('')
    if not two > one < default:
        pytest.skip(f"this numpy's BLAS starts no thread of its own on this machine ({one} threads with one "
                    f'BLAS thread, {two} with two, {default} by default)')


@pytest.mark.parametrize('front_end', FRONT_ENDS)
def test_the_front_ends_run_blas_on_one_thread_unless_the_user_says_otherwise(front_end, numpy_threads_blas):
    imports = f'import {FRONT_ENDS[front_end]}'
    assert _threads(imports) == _threads(imports, 1) < _threads(imports, 2)
    # OMP_NUM_THREADS, common in containers, is not the user asking for BLAS threads
    assert _threads(imports, omp_threads=2) == _threads(imports, 1)


def test_the_library_leaves_blas_threads_alone(numpy_threads_blas):
    """Importing the ROS-free core changes nothing of the user's program."""
    imports = 'import zeroshot_calib_ros.core'
    assert _threads(imports) > _threads(imports, 1)
