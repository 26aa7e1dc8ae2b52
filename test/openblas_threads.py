"""What tests of the fits' OpenBLAS thread count share (``problem.one_blas_thread``)."""
import pytest


def assert_solves_use_one_openblas_thread(monkeypatch, run):
    """Every OpenBLAS of this process set to 2 threads, ``run()``: each ``Problem.solve`` inside saw
    1, and the 2 is back afterwards. Skips where no OpenBLAS takes a thread count."""
    from zeroshot_calib_ros.core.estimation.problem import Problem, openblas_thread_controls
    controls = openblas_thread_controls()
    if not controls:
        pytest.skip('no OpenBLAS in this process')
    before = [get() for get, _ in controls]
    seen = []
    solve = Problem.solve

    def recorded(self, *args, **kwargs):
        seen.append([get() for get, _ in controls])
        return solve(self, *args, **kwargs)
    monkeypatch.setattr(Problem, 'solve', recorded)
    try:
        for _, put in controls:
            put(2)
        controls = [(get, put) for get, put in controls if get() == 2]  # single-threaded builds stay at 1
        if not controls:
            pytest.skip('no OpenBLAS here takes a thread count')
        run()
        assert seen and all(counts[:len(controls)] == [1] * len(controls) for counts in seen), seen
        assert [get() for get, _ in controls] == [2] * len(controls)
    finally:
        for (_, put), count in zip(openblas_thread_controls(), before):
            put(count)
