"""Which rectification maps the node asks for, and what a finished map build means, without ROS.

Lazy rectification: no maps are built while image_rect has no subscriber; when one appears, the
maps of the configured size and of the last frame's size are built at once, on every core, and
the first frame of such a size waits for them up to FIRST_FRAME_WAIT_SECONDS. A frame whose maps
are not built is skipped (``maps_pending``) while the ``MapBuilder`` builds them off the executor,
so that one frame of a new size never stalls the stream. A finished build is routed: a frame
size's maps (built, or failed: its frames are then skipped as ``maps_failed`` until a new
subscriber), a superseded calibration (nothing), a calibration whose maps failed, one to swap in.

The node (``zeroshot_calib_ros/ros/node.py``) reads image_rect's subscriber count, gives
``log(level, text)`` and ``wake()`` (called on the builder thread when a build ends, so that the
node takes the finished builds on its executor thread: ``take_finished``), and acts on what
``route`` returns (counts, keeps or swaps in the calibration).
"""
from __future__ import annotations

import threading
from typing import Callable, List, Optional

from ..ros_formats.calibration_file import CameraCalibration
from .frame_path import FramePath
from .image_frames import ActiveCalibration, FrameSkipped, binning_or_roi_reason
from .map_builder import REBUILD_MAP_THREADS, MapBuilder, MapJob

FIRST_FRAME_WAIT_SECONDS = 0.25
"""How long a frame waits for the maps being built because image_rect just got a subscriber (so
that the first frame after a subscriber appears is rectified): 1080p maps took 0.19-0.58 s on
every core of a 2-core machine busy with other jobs, 640x360 maps 0.06-0.09 s. Bounded so that
the frames queued behind it (image_raw keeps 10) are not lost; the frames that come while maps
take longer are counted as maps_pending and not rectified."""


class MapRequests:
    """The map requests of a stream: image_rect's subscribers as last read (``subscribers``,
    ``ever_subscribed``), the maps built ahead for a new subscriber, the builds that ended
    (handed from the builder thread to the executor thread), the last map build's duration
    (``maps_build_ms``, for /diagnostics).

    ``builder(done)`` makes the map builder (``MapBuilder``: a thread; a test gives a fake)."""

    def __init__(self, frames: FramePath, budget_bytes: int, log: Callable[[str, str], None],
                 wake: Callable[[], None], builder=MapBuilder):
        self._frames = frames
        self._budget_bytes = budget_bytes
        self._log = log
        self._wake = wake
        self.subscribers = 0  # image_rect's matched subscriptions, as last read
        self.ever_subscribed = False
        self.maps_build_ms = float('nan')
        self._ahead_jobs: List[MapJob] = []  # MapJobs of the maps built when image_rect got a subscriber
        self._finished: List[MapJob] = []
        self._finished_lock = threading.Lock()
        self._builder = builder(self._builder_done)

    @property
    def pending(self) -> Optional[MapJob]:
        """The calibration whose maps are waiting to be built or being built, if any."""
        return self._builder.pending

    def stop(self):
        self._builder.stop()

    # --- lazy rectification: maps only while image_rect has a subscriber ----------------------
    def subscribers_now(self, count: int, active: ActiveCalibration, newest: ActiveCalibration) -> bool:
        """Whether image_rect has a subscriber, given its count just read; when the first one
        appears, the maps are built at once (``_maps_ahead``, if ``active``, the calibration in
        force, is the newest), and the change is logged."""
        before = self.subscribers
        if count == before:
            return count > 0
        self.subscribers = count
        if count and not before:
            self.ever_subscribed = True
            sizes = self._maps_ahead(active) if newest is active else []
            self._log('info', 'image_rect has a subscriber: rectifying frames' +
                      (f' (maps of {", ".join(f"{w}x{h}" for w, h in sizes)} being built)' if sizes else ''))
        elif not count and active.rectify_enabled:
            self._log('info', 'image_rect has no subscriber: frames are not rectified until one subscribes '
                      '(CameraInfo still goes out with every frame)')
        return count > 0

    def _maps_ahead(self, active: ActiveCalibration) -> list:
        """Build the maps of the configured size and of the last frame's size for ``active`` now,
        on every core (image_rect has just got a subscriber); returns the sizes being built."""
        if not active.rectify_enabled or binning_or_roi_reason(active.calibration):
            return []
        self._ahead_jobs = [job for job in self._ahead_jobs if not job.finished.is_set()]
        sizes = self._frames.ahead_sizes(active, self._budget_bytes)
        building = []
        for width, height in sizes:
            if active.rectifier_for(width, height) is None:
                self._ahead_jobs.append(self._builder.request_size(active, width, height, map_threads=None))
                building.append((width, height))
        return building

    def rectifier(self, active: ActiveCalibration, calibration: CameraCalibration, width: int, height: int):
        """The built rectifier of a frame (image_rect has a subscriber), else FrameSkipped: why
        the frame is not rectified (``maps_pending`` while its maps are being built; ``error``
        for anything unexpected)."""
        try:
            rectifier = active.rectifier_for(width, height) or self._ahead_rectifier(active, width, height)
            if rectifier is None:
                self._request_maps(active, calibration, width, height)
            return rectifier
        except FrameSkipped:
            raise
        except Exception as exc:
            raise FrameSkipped('error', f'cannot rectify frame: {exc}') from None

    def _ahead_rectifier(self, active: ActiveCalibration, width: int, height: int):
        """The rectifier of a frame whose maps are being built because image_rect has just got a
        subscriber: waited for, up to FIRST_FRAME_WAIT_SECONDS, by the first such frame only
        (None if not ready by then: that frame and the next ones are counted as maps_pending)."""
        for job in self._ahead_jobs:
            if job.active is active and job.size == (width, height):
                self._ahead_jobs.remove(job)
                job.finished.wait(FIRST_FRAME_WAIT_SECONDS)
                return active.rectifier_for(width, height)
        return None

    def _request_maps(self, active: ActiveCalibration, calibration: CameraCalibration, width: int, height: int):
        """A frame whose maps are not built: skipped (counted) while the builder builds them, so
        that one frame of a new size never stalls the stream."""
        self._frames.check_maps_request(active, calibration, width, height, self._budget_bytes)
        # (the configured size's maps too, when they are missing: being built since image_rect got
        # a subscriber, the request returns that build)
        self._builder.request_size(active, width, height)
        raise self._frames.maps_pending(width, height)

    def release_unused(self, active: ActiveCalibration, idle_seconds: float):
        """Release the maps of the sizes of ``active`` no frame used for ``idle_seconds`` (they
        may be requested again)."""
        for size in active.release_unused(idle_seconds):
            self._builder.forget_size(active, *size)
            self._log('info', f'rectification maps of {size[0]}x{size[1]} released (no such frame '
                      f'for {idle_seconds:g} s)')

    # --- a calibration's maps, and the builds that ended -------------------------------------
    def submit(self, job: MapJob, streaming: bool, every_core: bool):
        """Build the maps of ``job``'s calibration (then ``route``\\ d 'swap_in'): with one thread
        while frames stream, so the stream keeps the other cores, unless ``every_core``."""
        job.map_threads = REBUILD_MAP_THREADS if streaming and not every_core else None
        self._builder.submit(job)

    def _builder_done(self, job: MapJob):
        """Builder thread: keep the job for the executor thread, and wake it."""
        with self._finished_lock:
            self._finished.append(job)
        self._wake()

    def take_finished(self) -> List[MapJob]:
        """The jobs that ended since the last call, in the order they ended."""
        with self._finished_lock:
            jobs, self._finished = self._finished, []
        return jobs

    def route(self, job: MapJob, in_force: ActiveCalibration) -> str:
        """What a finished job means, logged: 'size_built' or 'size_failed' (maps of a frame size;
        the frames of a failed one are skipped as maps_failed until image_rect gets a new
        subscriber), 'superseded' (a calibration replaced before its maps were built: never in
        force), 'failed' (a calibration whose maps could not be built: the one ``in_force``
        stays), 'swap_in' (a calibration to put in force), 'built' (already ``in_force``)."""
        if job.size is not None:
            if job.error is not None:
                self._frames.maps_failed(job.active, job.size, str(job.error))
                self._log('warning', f'rectification maps of {job.size[0]}x{job.size[1]} not built: '
                          f'{job.error}; frames of that size stay unrectified')
                return 'size_failed'
            if job.size == job.active.size:
                self.maps_build_ms = job.seconds * 1e3
            self._log('info', f'rectification maps of {job.size[0]}x{job.size[1]} built in '
                      f'{job.seconds * 1e3:.0f} ms')
            return 'size_built'
        if job.superseded:
            return 'superseded'
        if job.error is not None:
            return 'failed'
        self.maps_build_ms = job.seconds * 1e3
        if job.active.rectify_enabled:
            self._log('info', f'rectification maps of generation {job.active.generation} built '
                      f'in {job.seconds * 1e3:.0f} ms')
        return 'built' if job.active is in_force else 'swap_in'
