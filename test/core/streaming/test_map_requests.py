"""The node's map requests without DDS (core/streaming/map_requests.py): no maps and no remap
while image_rect has no subscriber; the maps built ahead when one appears, so that the first
frame after it is rectified; a frame of a new size skipped as maps_pending while its maps are
requested once; a failed build reported once and not retried until a new subscriber; finished
builds routed (a size's maps, a superseded calibration, a failed one, one to swap in).

The map builder is a fake without a thread: a test ends each build when it chooses."""
import threading
import time

import pytest

from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.streaming.frame_path import FramePath
from zeroshot_calib_ros.core.streaming.image_frames import ActiveCalibration, FrameSkipped
from zeroshot_calib_ros.core.streaming.map_builder import REBUILD_MAP_THREADS, MapJob
from zeroshot_calib_ros.core.streaming.map_requests import FIRST_FRAME_WAIT_SECONDS, MapRequests

WIDTH, HEIGHT = 320, 180  # the configured size
OTHER = (160, 90)  # another frame size of the same aspect ratio


class FakeBuilder:
    """MapBuilder's interface without its thread: the jobs asked for are kept (``sizes``: a size
    queued is returned again, as the builder does); ``end`` builds or fails one and hands it back."""

    def __init__(self, done):
        self.done = done
        self.sizes = []
        self.submitted = []
        self.forgotten = []
        self.stopped = False
        self.pending = None
        self._queued = {}

    def submit(self, job):
        self.submitted.append(job)
        self.pending = job

    def request_size(self, active, width, height, map_threads=REBUILD_MAP_THREADS):
        key = (id(active), width, height)
        if key not in self._queued:
            self._queued[key] = MapJob(active, size=(width, height), map_threads=map_threads)
            self.sizes.append(self._queued[key])
        return self._queued[key]

    def forget_size(self, active, width, height):
        self.forgotten.append((width, height))

    def stop(self):
        self.stopped = True

    def end(self, job, error=None):
        """What the builder thread does when it has built (or failed to build) ``job``."""
        if error is not None:
            job.error = error
        elif job.size is None:
            job.active.prepare(job.map_threads)
        else:
            job.active.build_maps(*job.size, map_threads=job.map_threads)
        job.seconds = 0.012
        if job.size is not None:
            self._queued.pop((id(job.active), *job.size), None)
        if self.pending is job:
            self.pending = None
        self.done(job)
        job.finished.set()


class Stream:
    """A MapRequests as the node drives it: frames through the FramePath, then their rectifier
    while image_rect has a subscriber; what it logs and how often it woke the executor."""

    def __init__(self, active):
        self.active = active
        self.frames = FramePath(lambda calibration, frame_id: bytearray())
        self.logged = []
        self.woken = []  # one entry per wake (appended from any thread)
        self.maps = MapRequests(self.frames, 2**40, lambda level, text: self.logged.append((level, text)),
                                self.wake, builder=FakeBuilder)
        self.builder = self.maps._builder

    def wake(self):
        self.woken.append(threading.current_thread().name)

    def subscribers(self, count):
        return self.maps.subscribers_now(count, self.active, self.active)

    def frame(self, width, height):
        """The rectifier of a frame (the node asks only while image_rect has a subscriber), or
        the FrameSkipped that says why it is not rectified."""
        calibration = self.frames.calibration(self.active, width, height, width, 'mono8', width * height)
        try:
            return self.maps.rectifier(self.active, calibration, width, height)
        except FrameSkipped as exc:
            return exc

    def finished(self):
        """The executor thread's turn: each finished build and what it means."""
        return [(job, self.maps.route(job, self.active)) for job in self.maps.take_finished()]


@pytest.fixture(scope='module')
def solved():
    solution = solve_zero_shot(CameraSpec(WIDTH, HEIGHT, 118, 69))
    return CameraCalibration.from_solution(solution)[0], solution.camera


def rectifying(solved, generation=0):
    calibration, camera = solved
    return ActiveCalibration(calibration, camera, 'spec', generation=generation, rectify=True, build_maps=False)


def test_no_maps_are_built_and_nothing_is_said_while_image_rect_has_no_subscriber(solved):
    stream = Stream(rectifying(solved))
    for _ in range(3):
        stream.frames.calibration(stream.active, WIDTH, HEIGHT, WIDTH, 'mono8', WIDTH * HEIGHT)
        assert stream.subscribers(0) is False  # the node then counts frames_not_rectified_no_subscriber
    assert stream.builder.sizes == [] and stream.builder.submitted == [] and stream.logged == []
    assert stream.active.rectifier_for(WIDTH, HEIGHT) is None
    assert (stream.maps.subscribers, stream.maps.ever_subscribed) == (0, False)


def test_a_subscriber_gets_the_maps_of_the_configured_and_the_last_frames_size_built_at_once(solved):
    stream = Stream(rectifying(solved))
    stream.frames.calibration(stream.active, *OTHER, OTHER[0], 'mono8', OTHER[0] * OTHER[1])
    assert stream.subscribers(1) is True
    assert [(job.size, job.map_threads) for job in stream.builder.sizes] == [((WIDTH, HEIGHT), None), (OTHER, None)]
    assert stream.logged == [('info', 'image_rect has a subscriber: rectifying frames (maps of 320x180, 160x90 '
                                      'being built)')]
    assert (stream.maps.subscribers, stream.maps.ever_subscribed) == (1, True)
    assert stream.subscribers(2) is True and len(stream.builder.sizes) == 2  # a second one: nothing new
    assert stream.subscribers(0) is False
    assert stream.logged[-1] == ('info', 'image_rect has no subscriber: frames are not rectified until one '
                                         'subscribes (CameraInfo still goes out with every frame)')


def test_no_maps_ahead_for_a_calibration_that_is_about_to_be_replaced(solved):
    stream = Stream(rectifying(solved))
    assert stream.maps.subscribers_now(1, stream.active, rectifying(solved, generation=1)) is True
    assert stream.builder.sizes == []
    assert stream.logged == [('info', 'image_rect has a subscriber: rectifying frames')]


class BuiltWhileWaitedFor:
    """A job's ``finished`` whose build ends while a frame waits for it (or never, ``built=False``)."""

    def __init__(self, job, built=True):
        self.job, self.built, self.waits = job, built, []

    def wait(self, timeout):
        self.waits.append(timeout)
        if self.built:
            self.job.active.build_maps(*self.job.size)
        return self.built

    def is_set(self):
        return False


def test_the_first_frame_after_a_subscriber_appears_waits_for_its_maps_built_ahead_and_is_rectified(solved):
    stream = Stream(rectifying(solved))
    stream.subscribers(1)
    ahead = stream.builder.sizes[0]
    ahead.finished = BuiltWhileWaitedFor(ahead)
    rectifier = stream.frame(WIDTH, HEIGHT)
    assert rectifier is not None and rectifier is stream.active.rectifier_for(WIDTH, HEIGHT)
    assert ahead.finished.waits == [FIRST_FRAME_WAIT_SECONDS]
    assert stream.frame(WIDTH, HEIGHT) is rectifier and ahead.finished.waits == [FIRST_FRAME_WAIT_SECONDS]
    assert len(stream.builder.sizes) == 1  # nothing asked for again


def test_only_the_first_frame_waits_for_maps_that_take_longer(solved):
    stream = Stream(rectifying(solved))
    stream.subscribers(1)
    ahead = stream.builder.sizes[0]
    ahead.finished = BuiltWhileWaitedFor(ahead, built=False)
    for _ in range(3):
        skipped = stream.frame(WIDTH, HEIGHT)
        assert isinstance(skipped, FrameSkipped) and skipped.reason == 'maps_pending'
    assert ahead.finished.waits == [FIRST_FRAME_WAIT_SECONDS]
    assert stream.builder.sizes == [ahead]  # the build under way is the one asked for


def test_a_frame_of_a_new_size_is_skipped_as_maps_pending_and_its_maps_are_requested_once(solved):
    stream = Stream(rectifying(solved))
    stream.subscribers(1)
    stream.builder.end(stream.builder.sizes[0])
    for _ in range(3):
        skipped = stream.frame(*OTHER)
        assert isinstance(skipped, FrameSkipped) and skipped.reason == 'maps_pending'
        assert str(skipped) == ('rectification maps of 160x90 are being built; frames of that size are not '
                                'rectified until they are ready')
    requested = [job for job in stream.builder.sizes if job.size == OTHER]
    assert len(requested) == 1 and requested[0].map_threads == REBUILD_MAP_THREADS  # off the stream's cores
    stream.builder.end(requested[0])
    assert len(stream.woken) == 2
    assert [route for _, route in stream.finished()] == ['size_built', 'size_built']
    assert stream.logged[-2:] == [('info', 'rectification maps of 320x180 built in 12 ms'),
                                  ('info', 'rectification maps of 160x90 built in 12 ms')]
    assert stream.maps.maps_build_ms == pytest.approx(12.0)  # the configured size's
    assert stream.frame(*OTHER) is stream.active.rectifier_for(*OTHER) is not None
    assert stream.finished() == []


def test_a_failed_build_is_reported_once_and_not_retried_until_a_new_subscriber(solved):
    stream = Stream(rectifying(solved))
    stream.subscribers(1)
    stream.builder.end(stream.builder.sizes[0])
    stream.frame(*OTHER)
    stream.builder.end(stream.builder.sizes[-1], error=MemoryError('out of memory'))
    assert [route for _, route in stream.finished()][-1] == 'size_failed'  # the node counts size_maps_failed
    warnings = [text for level, text in stream.logged if level == 'warning']
    assert warnings == ['rectification maps of 160x90 not built: out of memory; frames of that size stay unrectified']
    for _ in range(3):
        skipped = stream.frame(*OTHER)
        assert isinstance(skipped, FrameSkipped) and skipped.reason == 'maps_failed'
        assert 'out of memory' in str(skipped)
    assert [job.size for job in stream.builder.sizes] == [(WIDTH, HEIGHT), OTHER]
    assert stream.finished() == [] and len([text for level, text in stream.logged if level == 'warning']) == 1
    stream.subscribers(0)
    stream.subscribers(1)  # a new subscriber: tried again, as the last frame's size
    assert [job.size for job in stream.builder.sizes] == [(WIDTH, HEIGHT), OTHER, OTHER]


def test_a_superseded_calibration_is_never_swapped_in_a_newer_one_is(solved):
    stream = Stream(rectifying(solved))
    older, newer = rectifying(solved, generation=1), rectifying(solved, generation=2)
    jobs = [MapJob(older, 'older adopted'), MapJob(newer, 'newer adopted')]
    stream.maps.submit(jobs[0], streaming=True, every_core=False)
    stream.maps.submit(jobs[1], streaming=True, every_core=False)
    jobs[0].superseded = True  # the builder reports it so: replaced before its turn, never built
    stream.builder.done(jobs[0])
    stream.builder.end(jobs[1])
    assert [route for _, route in stream.finished()] == ['superseded', 'swap_in']
    assert stream.logged == [('info', 'rectification maps of generation 2 built in 12 ms')]
    assert older.rectifier_for(WIDTH, HEIGHT) is None


def test_a_calibration_whose_maps_failed_is_routed_failed_and_one_already_in_force_is_not_swapped_in(solved):
    stream = Stream(rectifying(solved))
    failed = MapJob(rectifying(solved, generation=1), error=MemoryError('out of memory'))
    stream.builder.done(failed)
    in_force = MapJob(stream.active, seconds=0.5)
    stream.builder.done(in_force)
    assert [route for _, route in stream.finished()] == ['failed', 'built']
    assert stream.maps.maps_build_ms == pytest.approx(500.0)
    assert stream.logged == [('info', 'rectification maps of generation 0 built in 500 ms')]


def test_a_calibration_is_built_on_one_thread_while_frames_stream_else_on_every_core(solved):
    stream = Stream(rectifying(solved))
    for streaming, every_core, threads in [(True, False, REBUILD_MAP_THREADS), (False, False, None),
                                           (True, True, None)]:
        job = MapJob(stream.active)
        stream.maps.submit(job, streaming=streaming, every_core=every_core)
        assert stream.maps.pending is job and job.map_threads == threads


def test_builds_that_end_on_the_builder_thread_are_each_taken_once_on_the_executor_thread(solved):
    stream = Stream(rectifying(solved))
    jobs = [MapJob(stream.active, size=OTHER) for _ in range(50)]
    threads = [threading.Thread(target=stream.builder.done, args=(job,)) for job in jobs]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    taken = stream.maps.take_finished()
    assert sorted(map(id, taken)) == sorted(map(id, jobs)) and len(stream.woken) == 50
    assert stream.maps.take_finished() == []


def test_maps_unused_for_a_while_are_released_and_may_be_requested_again(solved):
    stream = Stream(rectifying(solved))
    stream.active.build_maps(*OTHER)
    stream.maps.release_unused(stream.active, 10.0)
    assert stream.builder.forgotten == [] and stream.logged == []
    time.sleep(0.02)
    stream.maps.release_unused(stream.active, 0.01)
    assert stream.builder.forgotten == [OTHER] and stream.active.rectifier_for(*OTHER) is None
    assert stream.logged == [('info', 'rectification maps of 160x90 released (no such frame for 0.01 s)')]


def test_an_unexpected_error_skips_the_frame_as_error(solved):
    stream = Stream(rectifying(solved))
    stream.subscribers(1)

    def broken(width, height):
        raise RuntimeError('boom')
    stream.active.rectifier_for = broken
    skipped = stream.frame(WIDTH, HEIGHT)
    assert isinstance(skipped, FrameSkipped) and skipped.reason == 'error'
    assert str(skipped) == 'cannot rectify frame: boom'


def test_stop_stops_the_builder(solved):
    stream = Stream(rectifying(solved))
    stream.maps.stop()
    assert stream.builder.stopped
