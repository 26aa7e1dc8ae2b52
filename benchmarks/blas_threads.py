#!/usr/bin/env python3
"""Seconds of `zeroshot-calib calibrate` and `refine` with numpy's OpenBLAS on one thread (what the
command and the node set, ``OPENBLAS_NUM_THREADS=1``) against OpenBLAS's own default (a thread per
core), alone and with a second run of the same command on the cores at the same time.

Each run is the command in a fresh process of this interpreter (run the script with each
environment's python: ``.venv`` and ``.venv-jazzy-libs``). The cases of one repeat alternate so that
a machine whose load changes slows them alike; the table gives each case's median and its ratio to
one thread alone, in this one run.

    .venv/bin/python benchmarks/blas_threads.py [--repeats 3] [--out FILE]
    .venv-jazzy-libs/bin/python benchmarks/blas_threads.py [--repeats 3] [--out FILE]

Needs ../shared/data/ros_fisheye_800x503 (calibrate) and benchmarks/data/real_cameras/ocam_fisheye190
(refine: ``benchmarks/fetch_real_cameras.py``); a case whose data is missing is left out, said so.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get('ZEROSHOT_SHARED_DATA', REPO.parent / 'shared' / 'data')) / 'ros_fisheye_800x503'
OCAM = REPO / 'benchmarks' / 'data' / 'real_cameras' / 'ocam_fisheye190'

COMMANDS = {
    # one view of the shared set with its spec as evidence: a board fit, thousands of 6x6 solves
    'calibrate': (SHARED, lambda: ['calibrate', str(SHARED / 'left-*.png'), '--single', str(SHARED / 'left-0017.png'),
                                   '--hfov', '150', '--vfov', '105']),
    # four real 190-degree frames (detection in worker processes, one per core; the fit in this one)
    'refine': (OCAM, lambda: ['refine', *(str(OCAM / f'Fisheye190deg{k}.jpg') for k in (1, 2, 3, 4)),
                              '--vfov', '142.3']),
}


def run_case(command: list, blas_threads: int, copies: int) -> float:
    """Wall seconds until ``copies`` simultaneous runs of ``command`` have all ended."""
    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS=str(blas_threads))
    start = time.perf_counter()
    runs = [subprocess.Popen([sys.executable, '-m', 'zeroshot_calib_ros.cli', *command], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for _ in range(copies)]
    for run in runs:
        _, err = run.communicate(timeout=600)
        if run.returncode not in (0, 3):  # 3: ran, result not adopted (still the work measured)
            raise SystemExit(f'{" ".join(command)} failed ({run.returncode}): {err.strip()}')
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--out', help='append the table to this markdown file')
    args = parser.parse_args(argv)
    import cv2
    import numpy
    import scipy
    cores = os.cpu_count() or 1
    cases = [(name, threads, copies) for name, (data, _) in COMMANDS.items() if data.is_dir()
             for copies in (1, 2) for threads in (1, cores)]
    missing = [f'{name} ({data} not found)' for name, (data, _) in COMMANDS.items() if not data.is_dir()]
    seconds = {case: [] for case in cases}
    started = time.perf_counter()
    for _ in range(args.repeats):
        for case in cases:
            name, threads, copies = case
            seconds[case].append(run_case(COMMANDS[name][1](), threads, copies))
    lines = [f'`{Path(sys.executable).parent.parent.name}/bin/python benchmarks/blas_threads.py --repeats '
             f'{args.repeats}` ({time.perf_counter() - started:.0f} s)', '',
             f'numpy {numpy.__version__}, SciPy {scipy.__version__}, OpenCV {cv2.__version__}, Python '
             f'{platform.python_version()}; {cores} cores ({_cpu()}). Median wall seconds of {args.repeats} '
             'repeats; "two at once": until both of two simultaneous runs ended; ratio: to one BLAS thread alone.',
             '', '| command | BLAS threads | runs at once | seconds | ratio |', '|---|---:|---:|---:|---:|']
    for name in dict.fromkeys(c[0] for c in cases):
        base = statistics.median(seconds[(name, 1, 1)])
        for case in (c for c in cases if c[0] == name):
            median = statistics.median(seconds[case])
            label = '1 (the command\'s)' if case[1] == 1 else f'{case[1]} (OpenBLAS\'s default)'
            lines.append(f'| {name} | {label} | {case[2]} | {median:.2f} | {median / base:.2f} |')
    if missing:
        lines += ['', 'Left out: ' + '; '.join(missing)]
    text = '\n'.join(lines) + '\n'
    print(text)
    if args.out:
        with open(args.out, 'a') as out:
            out.write('\n' + text)
    return 0


def _cpu() -> str:
    try:
        return next(line.split(':', 1)[1].strip() for line in open('/proc/cpuinfo') if line.startswith('model name'))
    except (OSError, StopIteration):
        return platform.processor() or 'unknown CPU'


if __name__ == '__main__':
    sys.exit(main())
