"""Camera frames as arrays, and the calibration in force for a stream of them.

The ROS node hands raw message fields to ``image_array`` (a zero-copy view of the message
buffer) and frames to an ``ActiveCalibration``, which knows the calibration to publish and the
maps to rectify with for every image size of the configured aspect ratio. An
``ActiveCalibration`` never changes once built; a new calibration is a new object, swapped in
whole, so every frame sees one consistent calibration. Its maps can be built on another thread
(``build_maps=False``, then ``prepare()``) while frames keep using the calibration in force.
"""
from __future__ import annotations

import threading
from typing import Dict, Optional, Tuple

import numpy as np

from .calibration_file import CameraCalibration
from .camera_models import CameraModel
from .rectify import Rectifier, new_camera_matrix

ENCODINGS: Dict[str, Tuple[np.dtype, int]] = {
    'mono8': (np.dtype(np.uint8), 1), 'mono16': (np.dtype(np.uint16), 1),
    '16UC1': (np.dtype(np.uint16), 1), '32FC1': (np.dtype(np.float32), 1),
    'rgb8': (np.dtype(np.uint8), 3), 'bgr8': (np.dtype(np.uint8), 3),
    'rgba8': (np.dtype(np.uint8), 4), 'bgra8': (np.dtype(np.uint8), 4),
}
"""sensor_msgs/Image encodings that can be rectified: element type and channels."""

_MAX_SIZES_CACHED = 4


class FrameSkipped(ValueError):
    """A frame that cannot be processed; ``reason`` is the counter it is reported under:
    'encoding', 'aspect' or 'malformed'."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


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
    with the same aspect ratio get scaled intrinsics and their own maps, built once.

    ``build_maps=True`` builds the maps of the configured size in the constructor (not on frame
    one); with ``build_maps=False`` they are built by ``prepare()`` (e.g. on a worker thread) or
    on first use. ``for_size`` is thread-safe: a frame asking for maps being built waits for them.
    With rectification on, a rectified camera P that cannot be inverted raises ValueError here,
    before any map is built.
    """

    def __init__(self, calibration: CameraCalibration, camera: CameraModel, source: str,
                 generation: int = 0, rectify: bool = False, interpolation: int = 1,
                 build_maps: bool = True):
        self.calibration = calibration
        self.camera = camera
        self.source = source
        self.generation = generation
        self.rectify_enabled = rectify
        self.interpolation = interpolation
        self._sizes: Dict[Tuple[int, int], Tuple[CameraCalibration, Optional[Rectifier]]] = {}
        self._lock = threading.Lock()
        if rectify:
            np.linalg.inv(np.asarray(calibration.P, dtype=float)[:3, :3])  # LinAlgError is a ValueError
        if build_maps:
            self.prepare()  # maps at start, not on frame one

    @property
    def prepared(self) -> bool:
        """Whether the configured size's maps (if rectifying) are built."""
        return (self.calibration.width, self.calibration.height) in self._sizes

    def prepare(self, map_threads: Optional[int] = None) -> 'ActiveCalibration':
        """Build the configured size's calibration and maps now (returns self); ``map_threads``
        threads build the maps (default: one per CPU; 1 leaves the other cores to a stream)."""
        self.for_size(self.calibration.width, self.calibration.height, map_threads)
        return self

    def with_rectification(self, balance: float, fov_scale: float,
                           build_maps: bool = True) -> 'ActiveCalibration':
        """The same calibration with P chosen by ``balance`` and ``fov_scale`` (new object)."""
        P = np.hstack([new_camera_matrix(self.camera, balance, fov_scale), np.zeros((3, 1))])
        c = self.calibration
        record = CameraCalibration(c.width, c.height, c.K, c.distortion_model, c.D, c.R, P, c.camera_name)
        return ActiveCalibration(record, self.camera, self.source, self.generation + 1,
                                 self.rectify_enabled, self.interpolation, build_maps=build_maps)

    def for_size(self, width: int, height: int,
                 map_threads: Optional[int] = None) -> Tuple[CameraCalibration, Optional[Rectifier]]:
        """(calibration, rectifier or None) for frames of ``width`` x ``height`` (maps built on
        first use, by ``map_threads`` threads)."""
        key = (width, height)
        cached = self._sizes.get(key)
        if cached is not None:
            return cached
        base = self.calibration
        if width <= 0 or height <= 0:
            raise FrameSkipped('malformed', f'image size {width}x{height} is empty')
        if width * base.height != height * base.width:
            raise FrameSkipped('aspect', f'image {width}x{height} does not have the aspect ratio of '
                               f'the calibration ({base.width}x{base.height})')
        with self._lock:  # one build per size, even when a frame and a worker ask at once
            cached = self._sizes.get(key)
            if cached is not None:
                return cached
            if key == (base.width, base.height):
                calibration, camera = base, self.camera
            else:
                calibration, camera = base.scaled(width, height), self.camera.scaled(width, height)
            rectifier = None
            if self.rectify_enabled:
                rectifier = Rectifier(camera, interpolation=self.interpolation, P=calibration.P,
                                      map_threads=map_threads)
            sizes = dict(self._sizes)  # readers without the lock see the old or the new dict
            if len(sizes) >= _MAX_SIZES_CACHED:
                sizes.pop(next(k for k in sizes if k != (base.width, base.height)))
            sizes[key] = (calibration, rectifier)
            self._sizes = sizes
            return calibration, rectifier
