"""Camera frames as arrays, and the calibration in force for a stream of them.

The ROS node hands raw message fields to ``image_array`` (a zero-copy view of the message
buffer) and frames to an ``ActiveCalibration``, which knows the calibration to publish and the
maps to rectify with for every image size of the configured aspect ratio. An
``ActiveCalibration`` never changes once built; a new calibration is a new object, swapped in
whole, so every frame sees one consistent calibration. Its maps can be built on another thread
(``build_maps=False``, then ``prepare()``) while frames keep using the calibration in force.
"""
from __future__ import annotations

import dataclasses
import os
import threading
import time
from typing import Dict, Optional, Tuple

import numpy as np

from ..ros_formats.calibration_file import CameraCalibration
from .heap import return_free_memory
from ..lens.models import CameraModel
from ..ros_formats.rectify import Rectifier, principal_point_camera_matrix

ENCODINGS: Dict[str, Tuple[np.dtype, int]] = {
    'mono8': (np.dtype(np.uint8), 1), 'mono16': (np.dtype(np.uint16), 1),
    'rgb8': (np.dtype(np.uint8), 3), 'bgr8': (np.dtype(np.uint8), 3),
    'rgba8': (np.dtype(np.uint8), 4), 'bgra8': (np.dtype(np.uint8), 4),
    'rgb16': (np.dtype(np.uint16), 3), 'bgr16': (np.dtype(np.uint16), 3),
    # generic encodings, what cv_bridge produces for images that are not colour or mono
    '8UC1': (np.dtype(np.uint8), 1), '8UC3': (np.dtype(np.uint8), 3), '8UC4': (np.dtype(np.uint8), 4),
    '16UC1': (np.dtype(np.uint16), 1), '16UC3': (np.dtype(np.uint16), 3),
    '32FC1': (np.dtype(np.float32), 1),  # depth in metres: rectified with a NaN border (Rectifier)
}
"""sensor_msgs/Image encodings that can be rectified: element type and channels."""

class FrameSkipped(ValueError):
    """A frame that cannot be processed; ``reason`` is the counter it is reported under:
    'encoding', 'aspect', 'malformed', 'maps_pending' (maps of a new size not built yet),
    'maps_budget' (maps of that size would not fit max_map_memory_mb), 'maps_failed' (building
    them failed), 'binning_roi'."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


MAP_BYTES_PER_PIXEL = 8
"""Memory of one pixel's rectification maps at most: two CV_32FC1 maps (8 bytes), or CV_16SC2
(4 bytes) + CV_16UC1 table (2 bytes) where OpenCV remaps faster with those
(``rectify.map_format_for``). Budgets count the larger, whichever OpenCV the node runs on."""

_MAX_SIZES_CACHED = 4


_NO_LIMIT = 1 << 60  # cgroup v1 writes 9223372036854771712 for "no limit"


def _read_number(path: str) -> Optional[int]:
    try:
        with open(path) as f:
            text = f.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None  # 'max' (cgroup v2): no limit


def _proc_status_bytes(status_text: str, key: str) -> Optional[int]:
    for line in status_text.splitlines():
        if line.startswith(key + ':'):
            parts = line.split()
            return int(parts[1]) * 1024 if len(parts) > 1 and parts[1].isdigit() else None
    return None


def memory_limits(root: str = '/', getrlimit=None) -> list:
    """The memory the process may still use, under each limit it has: [(bytes, what)], the
    machine's physical memory first, then a cgroup's (v2 memory.max, v1
    memory.limit_in_bytes: its own and its ancestors', less what the cgroup uses now) and the
    rlimits (RLIMIT_AS less the address space mapped now, RLIMIT_DATA less the data segment).
    ``root`` and ``getrlimit`` stand in for '/' and resource.getrlimit in tests."""
    if getrlimit is None:
        import resource
        getrlimit = resource.getrlimit
    path = lambda *parts: os.path.join(root, *[p.lstrip('/') for p in parts])  # noqa: E731
    limits = []
    try:
        total = os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') if root == '/' else None
    except (ValueError, OSError, AttributeError):  # not on Linux
        total = None
    meminfo = _read_text(path('proc/meminfo'))
    if meminfo and root != '/':
        total = _proc_status_bytes(meminfo, 'MemTotal')
    limits.append((total or 8 * 2**30, 'physical memory' if total else 'memory (unknown: 8 GiB assumed)'))
    for line in (_read_text(path('proc/self/cgroup')) or '').splitlines():
        parts = line.split(':', 2)
        if len(parts) != 3:
            continue
        if parts[0] == '0' and parts[1] == '':  # cgroup v2
            base, limit_file, usage_file, label = 'sys/fs/cgroup', 'memory.max', 'memory.current', 'cgroup memory.max'
        elif 'memory' in parts[1].split(','):  # cgroup v1
            base, limit_file, usage_file = 'sys/fs/cgroup/memory', 'memory.limit_in_bytes', 'memory.usage_in_bytes'
            label = 'cgroup memory.limit_in_bytes'
        else:
            continue
        group = parts[2].strip('/')
        # the process's own cgroup and its ancestors (a container sees its own as the root)
        candidates = [group]
        while group:
            group = os.path.dirname(group)
            candidates.append(group)
        for group in candidates:
            limit = _read_number(path(base, group, limit_file))
            if limit is None or limit >= _NO_LIMIT:
                continue
            used = _read_number(path(base, group, usage_file)) or 0
            limits.append((max(0, limit - used), f'{label} {limit / 2**20:.0f} MiB ({used / 2**20:.0f} MiB in use)'))
    status = _read_text(path('proc/self/status')) or ''
    import resource
    for name, key, label in (('RLIMIT_AS', 'VmSize', 'ulimit -v (RLIMIT_AS)'),
                             ('RLIMIT_DATA', 'VmData', 'ulimit -d (RLIMIT_DATA)')):
        resource_id = getattr(resource, name, None)
        if resource_id is None:
            continue
        try:
            soft, _ = getrlimit(resource_id)
        except (OSError, ValueError):
            continue
        if soft == resource.RLIM_INFINITY or soft < 0 or soft >= _NO_LIMIT:
            continue
        used = _proc_status_bytes(status, key) or 0
        limits.append((max(0, soft - used), f'{label} {soft / 2**20:.0f} MiB ({used / 2**20:.0f} MiB mapped)'))
    return limits


def _read_text(path: str) -> Optional[str]:
    try:
        with open(path) as f:
            return f.read()
    except OSError:
        return None


def default_map_budget(root: str = '/', getrlimit=None) -> Tuple[int, str]:
    """The default max_map_memory_mb and why: an eighth of the memory the process may still use
    under the tightest of its limits (``memory_limits``: physical memory, cgroup, ulimit), so
    that no frame size or calibration can make the node take the machine or its container, and
    maps that could not be built are refused before anything is adopted or saved (3 GiB on a
    24 GiB machine without limits: the maps of 400 megapixels)."""
    room, what = min(memory_limits(root, getrlimit), key=lambda limit: limit[0])
    return max(64, int(room // 8 // 2**20)), f'an eighth of {what}'


def default_map_budget_mb() -> int:
    """The default max_map_memory_mb (``default_map_budget``)."""
    return default_map_budget()[0]


def map_bytes(width: int, height: int) -> int:
    """Memory the rectification maps of a width x height image take."""
    return int(width) * int(height) * MAP_BYTES_PER_PIXEL


class MapBudgetExceeded(ValueError):
    """Rectification maps that would not fit the memory budget (the message says how much)."""


def check_map_budget(width: int, height: int, budget_bytes: Optional[int], what: str = 'rectification maps'):
    """Raise MapBudgetExceeded unless the maps of a width x height image fit ``budget_bytes``."""
    need = map_bytes(width, height)
    if budget_bytes is not None and need > budget_bytes:
        raise MapBudgetExceeded(f'{what} of {width}x{height} need {need / 2**20:.0f} MiB, more than '
                                f'max_map_memory_mb = {budget_bytes / 2**20:.0f}: allowed: at most '
                                f'{budget_bytes // MAP_BYTES_PER_PIXEL} pixels (raise max_map_memory_mb '
                                'or turn rectify off)')


def check_frame(width: int, height: int, step: int, encoding: str, nbytes: int):
    """Raise FrameSkipped('malformed') unless a message's fields describe the bytes it carries.

    Every frame is checked, whatever rectify is: a CameraInfo goes out with each frame, and none
    may describe an image the message does not contain. Encodings that cannot be rectified
    (Bayer, YUV) still get their CameraInfo; for them only what holds for every encoding (at
    least one byte per pixel) is checked."""
    if width <= 0 or height <= 0:
        raise FrameSkipped('malformed', f'image size {width}x{height} is empty')
    known = ENCODINGS.get(encoding)
    row = width * (known[1] * known[0].itemsize if known else 1)
    if step < row:
        raise FrameSkipped('malformed', f'step {step} is shorter than a row of {width} pixels of '
                           f'{encoding!r} ({row} bytes)')
    if nbytes != step * height:
        raise FrameSkipped('malformed', f'data has {nbytes} bytes, step x height is {step * height}')


def image_array(data, width: int, height: int, step: int, encoding: str,
                is_bigendian: bool = False) -> np.ndarray:
    """A (height, width[, channels]) view of an image message's buffer, without copying
    (a big-endian 16/32-bit image is converted). Raises FrameSkipped for what cannot be read."""
    if encoding not in ENCODINGS:
        raise FrameSkipped('encoding', f'encoding {encoding!r} cannot be rectified (supported: '
                           f'{", ".join(ENCODINGS)}; debayer or convert it first)')
    dtype, channels = ENCODINGS[encoding]
    if width <= 0 or height <= 0:
        raise FrameSkipped('malformed', f'image size {width}x{height} is empty')
    row = width * channels * dtype.itemsize
    if step < row or step % dtype.itemsize:
        raise FrameSkipped('malformed', f'step {step} does not fit width {width} of {encoding} '
                           f'(needs a multiple of {dtype.itemsize} of at least {row} bytes)')
    buffer = np.frombuffer(data, np.uint8)
    if buffer.size != step * height:
        raise FrameSkipped('malformed', f'data has {buffer.size} bytes, step x height is {step * height}')
    view = np.ndarray((height, width, channels), dtype=dtype.newbyteorder('>' if is_bigendian else '<'),
                      buffer=buffer, strides=(step, channels * dtype.itemsize, dtype.itemsize))
    if not view.dtype.isnative:
        view = view.astype(dtype.newbyteorder('='))  # rare: OpenCV needs native byte order
    return view if channels > 1 else view[..., 0]


class ActiveCalibration:
    """The calibration in force: what CameraInfo carries and the exact model the maps come from.

    ``calibration`` is the ROS record (K, D, R, P) at the configured size; ``camera`` is the model
    the rectification maps are computed from (the exact zero-shot model when solved from a spec,
    the record's own model when loaded from a file or set_camera_info). Frames of another size
    with the same aspect ratio get scaled intrinsics and maps of their own.

    Maps are built by ``prepare()`` (configured size) or ``build_maps(w, h)`` (another size),
    meant for a worker thread; ``rectifier_for`` only looks up what is built, so a frame never
    waits for a build. ``for_size`` builds on demand (for scripts and benchmarks).
    ``map_budget_bytes`` bounds the memory of all cached maps: the configured size must fit it
    (checked here, before anyone is told the calibration was adopted); other sizes evict the
    least recently used ones and are refused when they cannot fit.
    """

    spec_warnings: Tuple[str, ...] = ()
    """Solved from a spec: the given FOVs its camera misses (``ZeroShotSolution.warnings``)."""
    assumption: Optional[str] = None
    """Solved from a spec that leaves the lens shape open (one FOV): what was assumed, in words
    (``ZeroShotSolution.assumption``)."""

    def __init__(self, calibration: CameraCalibration, camera: CameraModel, source: str,
                 generation: int = 0, rectify: bool = False, interpolation: int = 1,
                 build_maps: bool = True, map_budget_bytes: Optional[int] = None):
        self.calibration = calibration
        self.camera = camera
        self.source = source
        self.generation = generation
        self.rectify_enabled = rectify
        self.interpolation = interpolation
        self.map_budget_bytes = map_budget_bytes
        self._calibrations: Dict[Tuple[int, int], CameraCalibration] = {
            (calibration.width, calibration.height): calibration}
        self._rectifiers: Dict[Tuple[int, int], Rectifier] = {}
        self._last_used: Dict[Tuple[int, int], float] = {}
        self._building: Dict[Tuple[int, int], threading.Event] = {}
        self._lock = threading.Lock()
        # P is usable for rectification whatever rectify is: CameraCalibration refuses any other
        if rectify:
            check_map_budget(calibration.width, calibration.height, map_budget_bytes)
        if build_maps:
            self.prepare()  # maps at start, not on frame one

    @property
    def size(self) -> Tuple[int, int]:
        return self.calibration.width, self.calibration.height

    @property
    def prepared(self) -> bool:
        """Whether the configured size's maps (if rectifying) are built."""
        return not self.rectify_enabled or self.size in self._rectifiers

    def prepare(self, map_threads: Optional[int] = None) -> 'ActiveCalibration':
        """Build the configured size's maps now, if rectifying (returns self); ``map_threads``
        threads build them (default: one per CPU; 1 leaves the other cores to a stream)."""
        if self.rectify_enabled:
            self.build_maps(*self.size, map_threads)
        return self

    def with_rectification(self, balance: float, fov_scale: float,
                           build_maps: bool = True) -> 'ActiveCalibration':
        """The same calibration with P chosen by ``balance`` and ``fov_scale`` (new object), its
        principal point the camera's own (``principal_point_camera_matrix``: a calibrated camera
        is not centred in its image, and OpenCV's rule can put P's principal point off it; the
        spec's zero-shot camera is solved again instead, ``CalibrationCycle.for_parameters``)."""
        P = np.hstack([principal_point_camera_matrix(self.camera, balance, fov_scale), np.zeros((3, 1))])
        record = dataclasses.replace(self.calibration, P=P)  # keeps every other field
        return ActiveCalibration(record, self.camera, self.source, self.generation + 1,
                                 self.rectify_enabled, self.interpolation, build_maps=build_maps,
                                 map_budget_bytes=self.map_budget_bytes)

    def calibration_for(self, width: int, height: int) -> CameraCalibration:
        """The calibration of frames of ``width`` x ``height`` (cheap: no maps); FrameSkipped for
        a size no calibration describes."""
        key = (width, height)
        cached = self._calibrations.get(key)
        if cached is not None:
            return cached
        base = self.calibration
        if width <= 0 or height <= 0:
            raise FrameSkipped('malformed', f'image size {width}x{height} is empty')
        if width * base.height != height * base.width:
            raise FrameSkipped('aspect', f'image {width}x{height} does not have the aspect ratio of '
                               f'the calibration ({base.width}x{base.height}), so it gets no CameraInfo: set '
                               'width, height and hfov, vfov or dfov (or preset) of this camera mode, or give a '
                               'calibration of it (camera_info_url, set_camera_info)')
        calibration = base.scaled(width, height)
        with self._lock:
            calibrations = dict(self._calibrations)  # readers without the lock see old or new
            if len(calibrations) > 2 * _MAX_SIZES_CACHED:
                calibrations = {k: v for k, v in calibrations.items() if k == self.size}
            calibrations[key] = calibration
            self._calibrations = calibrations
        return calibration

    def rectifier_for(self, width: int, height: int) -> Optional[Rectifier]:
        """The built rectifier of that size, or None (not rectifying, or not built yet)."""
        rectifier = self._rectifiers.get((width, height))
        if rectifier is not None:
            self._last_used[(width, height)] = time.monotonic()
        return rectifier

    def build_maps(self, width: int, height: int, map_threads: Optional[int] = None) -> Rectifier:
        """Build (once) and cache the rectifier of frames of ``width`` x ``height``. Another size's
        maps evict the least recently used sizes to fit ``map_budget_bytes``; MapBudgetExceeded
        when they cannot fit beside the configured size's. The maps are built outside the lock,
        so frames and housekeeping never wait for a build (seconds for a very large size)."""
        key = (width, height)
        calibration = self.calibration_for(width, height)
        while True:
            with self._lock:
                cached = self._rectifiers.get(key)
                if cached is not None:
                    return cached
                budget = self.map_budget_bytes
                if key != self.size and budget is not None:
                    budget -= map_bytes(*self.size)
                check_map_budget(width, height, budget)
                building = self._building.get(key)
                if building is None:  # this thread builds it
                    building = self._building[key] = threading.Event()
                    break
            building.wait()  # another thread builds it: take its result (or build if it failed)
        try:
            camera = self.camera if key == self.size else self.camera.scaled(width, height)
            rectifier = Rectifier(camera, interpolation=self.interpolation, P=calibration.P,
                                  map_threads=map_threads, R=calibration.R)
            with self._lock:
                rectifiers = dict(self._rectifiers)  # readers without the lock see old or new
                others = sorted((k for k in rectifiers if k != self.size),
                                key=lambda k: self._last_used.get(k, 0.0))
                while others and (len(rectifiers) >= _MAX_SIZES_CACHED or (
                        self.map_budget_bytes is not None and
                        sum(map_bytes(*k) for k in rectifiers) + map_bytes(width, height) > self.map_budget_bytes)):
                    rectifiers.pop(others.pop(0))
                rectifiers[key] = rectifier
                self._last_used[key] = time.monotonic()
                self._rectifiers = rectifiers
            return rectifier
        finally:
            with self._lock:
                self._building.pop(key).set()

    def release_unused(self, idle_seconds: float) -> list:
        """Drop the maps of other sizes than the configured one unused for ``idle_seconds``
        (one odd frame must not pin its maps' memory); returns the sizes dropped."""
        now = time.monotonic()
        with self._lock:
            stale = [k for k in self._rectifiers
                     if k != self.size and now - self._last_used.get(k, 0.0) > idle_seconds]
            if stale:
                self._rectifiers = {k: v for k, v in self._rectifiers.items() if k not in stale}
        if stale:
            return_free_memory()  # freed maps stay resident in the heap otherwise (heap.py)
        return stale

    @property
    def map_memory_bytes(self) -> int:
        """Memory the maps hold now (budgets count ``map_bytes``, the most they can hold)."""
        return sum(r.map_nbytes for r in self._rectifiers.values())

    @property
    def frame_buffer_bytes(self) -> int:
        """Memory of the rectifiers' working frames (3-channel images padded to 4 channels)."""
        return sum(r.frame_buffer_nbytes for r in self._rectifiers.values())

    def for_size(self, width: int, height: int,
                 map_threads: Optional[int] = None) -> Tuple[CameraCalibration, Optional[Rectifier]]:
        """(calibration, rectifier or None) for frames of ``width`` x ``height``, building the
        maps now if needed (scripts and benchmarks; the node never builds on a frame)."""
        calibration = self.calibration_for(width, height)
        if not self.rectify_enabled:
            return calibration, None
        return calibration, self.build_maps(width, height, map_threads)


def binning_or_roi_reason(calibration: CameraCalibration) -> str:
    """Why the node cannot rectify frames of this calibration itself ('' if it can)."""
    roi = calibration.roi
    partial_roi = not roi.is_full() and \
        (roi.x_offset, roi.y_offset, roi.width, roi.height) != (0, 0, calibration.width, calibration.height)
    if calibration.binning_x > 1 or calibration.binning_y > 1 or partial_roi:
        return (f'the calibration has binning {calibration.binning_x}x{calibration.binning_y} / roi '
                f'{roi.width}x{roi.height}+{roi.x_offset}+{roi.y_offset}: the node rectifies full, unbinned '
                'frames only (image_proc rectifies binned / ROI frames from this CameraInfo)')
    return ''


def binned_roi_size(calibration: CameraCalibration) -> Tuple[int, int]:
    """The size of the frames a binned / ROI calibration describes, as image_geometry computes it."""
    roi = calibration.roi
    width, height = (calibration.width, calibration.height) if roi.is_full() else (roi.width, roi.height)
    return width // max(1, calibration.binning_x), height // max(1, calibration.binning_y)
