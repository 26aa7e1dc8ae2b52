"""The CLI run in-process, as the tests of its commands call it."""
import re

import pytest

from zeroshot_calib_ros.cli import main


def run_main(args, capsys):
    """(exit status, stdout, stderr lines) of main(args) in-process; argparse exits included."""
    try:
        status = main(args)
    except SystemExit as exc:
        status = exc.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err.strip().splitlines()


NUMBER = re.compile(r'-?\d+(\.\d+)?(e-?\d+)?')


def same_result(a, b, key=None, rel=1e-4):
    """The same record: the same keys, flags and texts (their numbers blanked), numbers to ``rel``.
    With Ubuntu 24.04's numpy 1.26 on a CPU with AVX-512, two runs of the same fit differ (its SIMD
    kernels round by memory alignment; the solvers stop at their tolerances a little elsewhere):
    the board fit's number of evaluations (48 against 41), its error bar by 1e-5 to 1e-3
    relative, a refinement's f by 1e-6 to 1e-3, and whether evaluate's FC_eq.d.+ZS stops at its
    evaluation limit (a note). Run time, evaluation counts and notes are not compared."""
    if key in ('seconds', 'evaluations', 'notes'):
        return True
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same_result(a[k], b[k], k, rel) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(same_result(x, y, None, rel) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, (int, float)) and not isinstance(b, bool):
        return a == pytest.approx(b, rel=rel, abs=1e-9)
    if isinstance(a, str) and isinstance(b, str):
        return NUMBER.sub('#', a) == NUMBER.sub('#', b)
    return a == b
