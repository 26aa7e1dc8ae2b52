"""Hypothesis settings shared by the fuzz suites: derandomized (CI sees the same cases every run),
no deadline (subprocesses and solves vary on a busy machine), ZEROSHOT_FUZZ_SCALE multiplies the
number of cases (default 1).

ZEROSHOT_FUZZ_PART=K/N (``make test``: 1/2 in the run on the newest libraries, 2/2 in the run on
Ubuntu 24.04's) runs the K-th of N parts of the cases: 1/N of them, drawn from a seed of their own,
so that the two runs of the ROS-free tests fuzz different cases instead of the same ones twice."""
import math
import os

from hypothesis import HealthCheck, seed, settings

SCALE = float(os.environ.get('ZEROSHOT_FUZZ_SCALE', '1'))


def _part(text: str):
    try:
        k, n = (int(v) for v in text.split('/'))
    except ValueError:
        raise ValueError(f'ZEROSHOT_FUZZ_PART = {text!r} is invalid: allowed: K/N with 1 <= K <= N') from None
    if not 1 <= k <= n:
        raise ValueError(f'ZEROSHOT_FUZZ_PART = {text!r} is invalid: allowed: K/N with 1 <= K <= N')
    return k, n


PART, PARTS = _part(os.environ.get('ZEROSHOT_FUZZ_PART', '1/1'))


def share(n: int) -> int:
    """This run's number of cases of a fuzz test of ``n`` (scaled, split between the parts)."""
    return max(1, math.ceil(n * SCALE / PARTS))


def examples(n):
    chosen = settings(max_examples=share(n), deadline=None, derandomize=True,
                      suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                             HealthCheck.filter_too_much, HealthCheck.function_scoped_fixture])
    if PARTS == 1:
        return chosen
    return lambda test: seed(PART)(chosen(test))  # a seed of its own (it overrides derandomize's)
