"""Hypothesis settings shared by the fuzz suites: derandomized (CI sees the same cases every run),
no deadline (subprocesses and solves vary on a busy machine), ZEROSHOT_FUZZ_SCALE multiplies the
number of cases (default 1)."""
import os

from hypothesis import HealthCheck, settings

SCALE = float(os.environ.get('ZEROSHOT_FUZZ_SCALE', '1'))


def examples(n):
    return settings(max_examples=max(1, int(n * SCALE)), deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much, HealthCheck.function_scoped_fixture])
