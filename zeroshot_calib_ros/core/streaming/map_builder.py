"""Rectification maps built off the ROS executor thread: one low-priority worker that builds
the maps of a new calibration (then handed back to be swapped in) and of new frame sizes, while
frames keep flowing with the calibration in force. ROS-free; the node owns one.
"""
from __future__ import annotations

import collections
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Optional, Tuple

from .heap import return_free_memory
from .image_frames import ActiveCalibration

REBUILD_MAP_THREADS = 1
"""Threads building the maps of a new calibration while frames stream: one, so the stream keeps
the other cores (with one per CPU, the longest gap between 1080p frames during a rebuild on 2
cores reached 318 ms, with one 40-90 ms; benchmarks/startup_and_memory.py). At start-up and
when no frame came for IMAGE_IDLE_SECONDS: one per CPU."""


@dataclass
class MapJob:
    """Maps the builder thread prepares: a calibration's (then swapped in) or a new frame size's."""

    active: ActiveCalibration
    log: str = ''
    map_threads: Optional[int] = REBUILD_MAP_THREADS
    size: Optional[Tuple[int, int]] = None
    """None: the calibration's configured size, swapped in when built; else another frame size."""
    values: Optional[dict] = None
    """The parameter values this calibration came from (restored if its maps cannot be built)."""
    seconds: float = 0.0
    error: Optional[BaseException] = None
    superseded: bool = False
    """Replaced by a newer calibration's job before its turn: never built."""
    finished: threading.Event = field(default_factory=threading.Event)
    """Set when the job has ended (built, failed or superseded), after ``done(job)``."""


class MapBuilder:
    """One worker thread for map building, at low CPU priority so the stream keeps its cores.

    First the maps of the newest calibration asked for (a request superseded by a newer one
    before its turn is dropped), then the maps of new frame sizes (each size once).
    ``done(job)`` is called on the worker thread when a job ends."""

    def __init__(self, done):
        self._done = done
        self._cond = threading.Condition()
        self._pending: Optional[MapJob] = None
        self._sizes = collections.deque()
        self._queued_sizes = {}  # (id(active), width, height) -> its MapJob, until built
        self._running: Optional[MapJob] = None
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name='map_builder', daemon=True)
        self._thread.start()

    @property
    def pending(self) -> Optional[MapJob]:
        return self._pending

    def submit(self, job: MapJob):
        """Build ``job`` next; a pending job it replaces before the worker took it is never built
        (``superseded``, ``finished`` set)."""
        with self._cond:
            replaced, self._pending = self._pending, job
            superseded = replaced is not None and replaced is not job and replaced is not self._running
            self._cond.notify()
        if superseded:
            replaced.superseded = True
            replaced.finished.set()

    def request_size(self, active: ActiveCalibration, width: int, height: int,
                     map_threads: Optional[int] = REBUILD_MAP_THREADS) -> MapJob:
        """Build the maps of ``width`` x ``height`` for ``active`` with ``map_threads`` threads
        (None: one per CPU); returns the job (a call while that size is queued or being built
        returns the job already queued; once it is done, a new call builds it again)."""
        key = (id(active), width, height)
        with self._cond:
            queued = self._queued_sizes.get(key)
            if queued is not None:
                return queued
            job = self._queued_sizes[key] = MapJob(active, size=(width, height), map_threads=map_threads)
            self._sizes.append(job)
            self._cond.notify()
        return job

    def stop(self, timeout: float = 5.0):
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout)

    def _run(self):
        try:  # Linux: a thread's nice value is its own
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
        except (AttributeError, OSError):
            pass
        while True:
            with self._cond:
                while self._pending is None and not self._sizes and not self._stopped:
                    self._cond.wait()
                if self._stopped:
                    return
                job = self._pending if self._pending is not None else self._sizes.popleft()
                self._running = job
            start = time.monotonic()
            try:
                if job.size is None:
                    job.active.prepare(job.map_threads)
                else:
                    job.active.build_maps(*job.size, map_threads=job.map_threads)
            except Exception as exc:  # reported by the node; the calibration in force stays
                job.error = exc
            job.seconds = time.monotonic() - start
            return_free_memory()  # the build's temporaries and any maps it evicted (heap.py)
            with self._cond:
                if self._pending is job:
                    self._pending = None
                self._running = None
                if job.size is not None:  # built or failed: the size may be asked for again
                    # (its maps can be evicted from the calibration's cache later, and a frame
                    # of that size then asks again; one that is still cached is not asked for)
                    self._queued_sizes.pop((id(job.active), *job.size), None)
            self._done(job)
            job.finished.set()

    def forget_size(self, active: ActiveCalibration, width: int, height: int):
        """Allow ``width`` x ``height`` to be requested again (its maps were released)."""
        with self._cond:
            self._queued_sizes.pop((id(active), width, height), None)
