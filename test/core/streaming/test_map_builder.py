"""The map builder and the calibration's map cache without ROS: sizes evicted from the cache are
built again when their frames come back; memory stays bounded over many frame sizes."""
import threading

import numpy as np

from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.streaming.image_frames import ActiveCalibration
from zeroshot_calib_ros.core.streaming.map_builder import MapBuilder


def small_active(build_maps=True):
    solution = solve_zero_shot(CameraSpec(640, 360, 118, 69))
    calibration, _ = CameraCalibration.from_solution(solution)
    return ActiveCalibration(calibration, solution.camera, 'spec', rectify=True, build_maps=build_maps)


class Finished:
    """The builder's done callback: jobs in order, and an event per job."""

    def __init__(self):
        self.jobs = []
        self.cond = threading.Condition()

    def __call__(self, job):
        with self.cond:
            self.jobs.append(job)
            self.cond.notify_all()

    def wait_for(self, count, timeout=20.0):
        with self.cond:
            assert self.cond.wait_for(lambda: len(self.jobs) >= count, timeout), \
                f'{len(self.jobs)} jobs finished, waited for {count}'


SIZES = [(320, 180), (480, 270), (160, 90), (800, 450), (960, 540), (1280, 720)]
"""Six sizes beside the configured 640x360: more than the cache holds."""


def test_sizes_evicted_from_the_cache_are_built_again_when_requested():
    active = small_active()
    finished = Finished()
    builder = MapBuilder(finished)
    try:
        for round_ in range(2):
            for width, height in SIZES:
                # what the node does for a frame: build only when the maps are not there
                if active.rectifier_for(width, height) is None:
                    builder.request_size(active, width, height)
                    finished.wait_for(len(finished.jobs) + 1)
                assert finished.jobs[-1].error is None
                assert active.rectifier_for(width, height) is not None, (round_, width, height)
    finally:
        builder.stop()
    assert len(finished.jobs) == 2 * len(SIZES)  # the LRU cache held 4: every size rebuilt once


def test_a_size_requested_twice_before_its_build_is_built_once():
    active = small_active()
    finished = Finished()
    gate = threading.Event()
    builder = MapBuilder(finished)
    try:
        # keep the worker busy on a first size while the same second size is requested twice
        original = active.build_maps

        def slow(*args, **kwargs):
            gate.wait(10)
            return original(*args, **kwargs)

        active.build_maps = slow
        builder.request_size(active, 320, 180)
        builder.request_size(active, 480, 270)
        builder.request_size(active, 480, 270)
        gate.set()
        finished.wait_for(2)
        np.testing.assert_equal(sorted(j.size for j in finished.jobs), [(320, 180), (480, 270)])
    finally:
        builder.stop()


def test_a_job_ends_finished_whether_built_failed_or_superseded():
    from zeroshot_calib_ros.core.streaming.map_builder import MapJob
    finished = Finished()
    builder = MapBuilder(finished)
    gate = threading.Event()
    try:
        busy = small_active(build_maps=False)
        original = busy.prepare
        busy.prepare = lambda *a, **k: (gate.wait(10), original(*a, **k))[1]
        first = MapJob(busy)
        builder.submit(first)  # the worker takes it and waits at the gate
        while builder._running is not first:
            threading.Event().wait(0.01)
        replaced, newest = MapJob(small_active(False)), MapJob(small_active(False))
        builder.submit(replaced)
        builder.submit(newest)  # replaces `replaced` before the worker took it
        assert replaced.finished.wait(1) and replaced.superseded
        gate.set()
        assert first.finished.wait(20) and newest.finished.wait(20)
        assert not first.superseded and first.error is None and newest.error is None
        assert newest.active.prepared and not replaced.active.prepared
    finally:
        builder.stop()


def test_each_build_gives_its_freed_memory_back(monkeypatch):
    """After every build (a new calibration's maps, or a frame size's) the builder hands glibc's
    freed blocks back to the kernel (heap.return_free_memory): the heap thresholds that keep
    stream frames resident would otherwise keep the build's temporaries (tens of MiB at 4000x3000)
    for the life of the process. Called once the job's maps are in place, before it is reported."""
    from zeroshot_calib_ros.core.streaming import map_builder
    calls = []
    monkeypatch.setattr(map_builder, 'return_free_memory', lambda: calls.append(len(finished.jobs)) or True)
    active = small_active(build_maps=False)
    finished = Finished()
    builder = MapBuilder(finished)
    try:
        for n, (width, height) in enumerate(SIZES[:3], start=1):
            builder.request_size(active, width, height)
            finished.wait_for(n)
            assert finished.jobs[-1].error is None
            assert len(calls) >= n and calls[n - 1] == n - 1, calls  # trimmed before the job was reported
    finally:
        builder.stop()
