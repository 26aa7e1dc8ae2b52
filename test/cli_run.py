"""The CLI run in-process, as the tests of its commands call it."""
import contextlib
import copy
import io
import re

import numpy as np
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


def run_main_alone(args):
    """run_main without capsys, for fixtures wider than a test (module, session): (exit status,
    stdout, stderr lines)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(args)
        except SystemExit as exc:
            status = exc.code
    return status, out.getvalue(), err.getvalue().strip().splitlines()


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


def result_differences(a, b, rel=1e-4, path=''):
    """The paths where ``same_result`` finds two records apart (for a failing test to show)."""
    if isinstance(a, dict) and isinstance(b, dict) and a.keys() == b.keys():
        return [d for k in a for d in (result_differences(a[k], b[k], rel, f'{path}/{k}')
                                       if k not in ('seconds', 'evaluations', 'notes') else [])]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in result_differences(x, y, rel, f'{path}[{i}]')]
    return [] if same_result(a, b, None, rel) else [f'{path}: {a!r} against {b!r}']


def _same_arguments(a, b) -> bool:
    if isinstance(a, (list, tuple)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(map(_same_arguments, a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and np.array_equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same_arguments(a[k], b[k]) for k in a)
    if hasattr(a, '__dict__') and not callable(a):  # e.g. a dataclass holding arrays
        return type(a) is type(b) and _same_arguments(vars(a), vars(b))
    return bool(a == b)


class RecordedComputation:
    """One real call of ``module.name`` (a computation with a ``progress`` callback, e.g.
    refine_from_images), recorded once and then replayed, for the tests of the CLI's progress
    output that run the same command on a terminal and elsewhere: the CLI's own code (whether it
    passes a callback, how it prints each report, how it ends the line) runs every time; the
    computation itself, whose results and reports do not depend on where stderr goes, runs once.

    ``record()``: the next calls run the real function, their reports passed on to the CLI's
    callback as they come and kept. ``replay()``: later calls must have the same arguments (else
    the test fails: the replay would not be what the CLI asked for); the kept reports are passed
    to whatever callback the CLI gives, in order, and a copy of the kept result returned."""

    def __init__(self, monkeypatch, module, name):
        self.monkeypatch, self.module, self.name = monkeypatch, module, name
        self.real = getattr(module, name)
        self.calls = []  # (args, kwargs without progress, reports, result)
        self.replayed = 0

    def record(self):
        def recording(*args, progress=None, **kwargs):
            reports = []

            def tee(report):
                reports.append(report)
                progress(report)
            result = self.real(*args, progress=None if progress is None else tee, **kwargs)
            self.calls.append((args, kwargs, reports, result))
            return result
        self.monkeypatch.setattr(self.module, self.name, recording)

    def replay(self, monkeypatch=None, progress=True):
        """``monkeypatch``: that of the test whose calls are replayed (default: the recording
        one's; a session fixture records with its own). ``progress=False``: a call recorded
        without a callback, replayed to calls that must pass none either."""
        args0, kwargs0, reports, result = self.calls[-1]
        assert reports or not progress, 'replay() needs a recorded call that reported progress'

        def replaying(*args, progress=None, **kwargs):
            assert _same_arguments(args, args0) and _same_arguments(kwargs, kwargs0), \
                f'{self.name} called with other arguments than the recorded call'
            assert progress is None or reports, f'{self.name} asked for progress the recorded call did not report'
            self.replayed += 1
            if progress is not None:
                for report in reports:
                    progress(report)
            return copy.deepcopy(result)
        (monkeypatch or self.monkeypatch).setattr(self.module, self.name, replaying)
