"""The shared real data set (ros_fisheye_800x503 in ../shared/data, beside the repository: 24
chessboard images of a 180-degree lens and the authors' ost.yaml) and the one full evaluation of it
that several test modules check, computed once per test process (test/conftest.py's session
fixture ``shared_set_evaluation``; its TOGETHER keeps those modules in one shard)."""
import shlex
from dataclasses import dataclass

import pytest

from cli_run import RecordedComputation, run_main_alone
from doc_pages import REPO

SHARED_SET = REPO.parent / 'shared' / 'data' / 'ros_fisheye_800x503'

EVALUATE_COMMAND = ("zeroshot-calib evaluate '../shared/data/ros_fisheye_800x503/left-*.png' \\\n"
                    "    --spec-from ../shared/data/ros_fisheye_800x503/ost.yaml --spec-from-model equidistant")
"""docs/calibration.md's evaluate command, as written there (paths relative to the repository)."""


def argv_of(command: str) -> list:
    """The arguments of main() for a documented command line `zeroshot-calib ...`."""
    argv = shlex.split(command.replace('\\\n', ' '))
    assert argv[0] == 'zeroshot-calib'
    return argv[1:]


@dataclass
class EvaluateRun:
    """``EVALUATE_COMMAND`` run once in-process from the repository: its exit status, its stdout
    and stderr, and its computation (core evaluate(), as the CLI called it, with the result it
    returned), which ``replay`` hands to a later run of the CLI with the same inputs."""
    status: int
    out: str
    err: str
    computation: RecordedComputation

    @property
    def result(self):
        """The Evaluation (core evaluate()'s result) the command printed."""
        return self.computation.calls[-1][3]

    def replay(self, monkeypatch):
        """The CLI's evaluate() in this test: the recorded result, for the same arguments only."""
        self.computation.replay(monkeypatch, progress=False)


def run_evaluate_command() -> EvaluateRun:
    from zeroshot_calib_ros.cli import evaluate
    if not SHARED_SET.is_dir():
        pytest.skip(f'shared data set not found: {SHARED_SET}')
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(REPO)
        computation = RecordedComputation(patch, evaluate, 'evaluate')
        computation.record()
        status, out, err = run_main_alone(argv_of(EVALUATE_COMMAND))
    assert len(computation.calls) == 1, f'the command computed its evaluation once (exit status {status}: {err})'
    computation.monkeypatch = None  # its own has been undone: replays use the test's
    return EvaluateRun(status, out, '\n'.join(err), computation)
