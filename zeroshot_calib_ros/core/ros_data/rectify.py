"""Rectification to a pinhole camera, with maps computed from the exact camera model.

OpenCV is imported where maps are built or images remapped, not with the module: a node with
rectify off never needs it, and its first CameraInfo should not wait the 5-20 ms of the import
(issue 14)."""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Optional, Tuple

import numpy as np

from ..lens.models import CameraModel

INTERPOLATIONS = {0: 0, 1: 1, 2: 2, 4: 4}
"""image_proc's ``interpolation`` values (3, area, has no remap equivalent) -> OpenCV's: the same
numbers (cv2.INTER_NEAREST, INTER_LINEAR, INTER_CUBIC, INTER_LANCZOS4; test_rectify checks)."""

_MAP_ROWS_PER_CHUNK = 128  # bounds the float64 temporaries to ~ 128 x width x 3 x 8 bytes

MAX_EDGE_ANGLE_DEG = 80.0
"""For lenses whose image edges reach 90 degrees off-axis or more (180-degree and wider lenses,
core/lens/wide_fov.py), which no pinhole can show: in ``new_camera_matrix`` every edge midpoint then
counts as at most this far off-axis (in its own direction), so balance = 1 shows up to +-80
degrees there and balance = 0 is set by the edges that are nearer the axis."""


def _edge_points_within_reach(camera: CameraModel, edges: np.ndarray) -> np.ndarray:
    """Normalised pinhole points of the edge midpoints with each ray's off-axis angle clamped
    to MAX_EDGE_ANGLE_DEG (edges without a ray: in the direction of the pixel)."""
    rays = camera.unproject(edges)
    offset = np.stack([(edges[:, 0] - camera.cx) / camera.fx, (edges[:, 1] - camera.cy) / camera.fy], axis=-1)
    direction = np.where(np.isfinite(rays[:, :2]).all(axis=1, keepdims=True), rays[:, :2], offset)
    norm = np.linalg.norm(direction, axis=1, keepdims=True)
    direction = direction / np.where(norm > 0, norm, 1.0)
    theta = np.arctan2(np.linalg.norm(rays[:, :2], axis=1), rays[:, 2])
    theta = np.where(np.isfinite(theta), np.minimum(theta, np.radians(MAX_EDGE_ANGLE_DEG)),
                     np.radians(MAX_EDGE_ANGLE_DEG))
    return direction * np.tan(theta)[:, None]


def new_camera_matrix(camera: CameraModel, balance: float = 0.0, fov_scale: float = 1.0,
                      new_size: Optional[Tuple[int, int]] = None) -> np.ndarray:
    """The rectified pinhole camera, with the meaning cv2.fisheye.estimateNewCameraMatrixForUndistortRectify
    gives ``balance`` (0: focal of the tightest edge, no black border; 1: the whole image edge-to-edge
    is kept) and ``fov_scale`` (divides the focal length), computed with ``camera``'s exact model.
    When an edge is 90 degrees or more off-axis (no pinhole shows it), every edge counts as at
    most MAX_EDGE_ANGLE_DEG off-axis (see there); other cameras are unaffected.
    """
    if not 0.0 <= balance <= 1.0:
        raise ValueError(f'balance = {balance!r} is invalid: allowed: 0 to 1')
    if not fov_scale > 0.0 or not np.isfinite(fov_scale):
        raise ValueError(f'fov_scale = {fov_scale!r} is invalid: allowed: greater than 0')
    w, h = camera.width, camera.height
    # The edge midpoints, with OpenCV's integer division of the size.
    edges = np.array([[w // 2, 0], [w, h // 2], [w // 2, h], [0, h // 2]], dtype=float)
    pts = camera.undistort(edges)
    if not np.all(np.isfinite(pts)):
        pts = _edge_points_within_reach(camera, edges)
    cn = pts.mean(axis=0)
    aspect = camera.fx / camera.fy
    # To square pixels: y scaled by fx / fy, the centre's as the points'. (OpenCV up to 4.6, the
    # version of Ubuntu 24.04, scaled cn[0] instead, a typo that moves P's principal point when
    # fx != fy and the principal point is off-centre: opencv/opencv#22537, fixed in 4.7 by #22604.)
    cn[1] *= aspect
    pts[:, 1] *= aspect
    minx, miny = pts.min(axis=0)
    maxx, maxy = pts.max(axis=0)
    focals = [w * 0.5 / (cn[0] - minx), w * 0.5 / (maxx - cn[0]),
              h * 0.5 * aspect / (cn[1] - miny), h * 0.5 * aspect / (maxy - cn[1])]
    f = balance * min(focals) + (1.0 - balance) * max(focals)
    f /= fov_scale
    new_f = np.array([f, f / aspect])
    new_c = -cn * f + np.array([w, h * aspect]) * 0.5
    new_c[1] /= aspect
    if new_size is not None:
        scale = np.array([new_size[0] / w, new_size[1] / h])
        new_f, new_c = new_f * scale, new_c * scale
    return np.array([[new_f[0], 0.0, new_c[0]], [0.0, new_f[1], new_c[1]], [0.0, 0.0, 1.0]])


def _map_threads(rows: int) -> int:
    return max(1, min(os.cpu_count() or 1, -(-rows // _MAP_ROWS_PER_CHUNK)))


FLOAT_MAP_KERNELS = (4, 11)
"""The OpenCV release whose cv2.remap got vectorised kernels for 32-bit float maps (opencv#26348)."""


def opencv_version() -> Tuple[int, int]:
    import cv2

    major, minor = (cv2.__version__.split('.') + ['0'])[:2]
    return int(major), int(''.join(ch for ch in minor if ch.isdigit()) or 0)


def map_format_for(channels: int, interpolation: int, version: Optional[Tuple[int, int]] = None) -> str:
    """'float' (two CV_32FC1 maps: the exact positions) or 'fixed' (CV_16SC2 + CV_16UC1 table,
    1/32 px: what cv2.initUndistortRectifyMap gives image_proc), whichever cv2.remap runs faster
    for images of ``channels`` channels with OpenCV's ``interpolation`` flag.

    Measured on this project's 2-core machine at 1920x1080 (ms per remap, fixed -> float):
    OpenCV 5.0, linear: mono8 4.8 -> 2.8, mono16 10.1 -> 3.3, 32FC1 7.5 -> 3.0, bgra8 8.8 -> 4.2,
    but bgr8 7.3 -> 8.7 (its 3-channel kernel is slower); nearest: float faster for every
    encoding on 5.0 and 4.6 (bgr8 4.0 -> 2.0 and 5.5 -> 4.0); OpenCV 4.6 (Ubuntu 24.04), linear:
    fixed faster (mono8 6.9 -> 7.6, bgr8 10.5 -> 11.1); cubic and Lanczos: no gain (bgr8 24 -> 28
    on 5.0). In the node's stream at 1080p mono8 the float maps took the node's highest rate
    from 82.4 to 122.3 fps (the two alternately in one run: benchmarks/results/float_maps.md).

    ``channels`` 3 keeps fixed point. Remapping bgr8 as BGRA with float maps (cvtColor, remap,
    cvtColor: 6.2 against 9.9 ms per frame on 5.0) raised the node's highest rate at 1080p
    1.16x (52.4 against 45.3 fps) but its 30 fps latency from 33.6 to 45.1 ms (probably its
    three OpenCV thread-pool dispatches per frame instead of one, on cores the publisher and
    subscriber share; alternately in one run), so it is not done. OpenCV releases between 4.6
    and 4.11 were not measured and get the 4.6 rule."""
    if interpolation == 0:
        return 'float'
    if interpolation == 1 and (version or opencv_version()) >= FLOAT_MAP_KERNELS and channels != 3:
        return 'float'
    return 'fixed'


def convert_maps(maps: Tuple[np.ndarray, np.ndarray], to: str) -> Tuple[np.ndarray, np.ndarray]:
    """``maps`` in the format ``to`` ('float' / 'fixed'; float -> fixed is exact to the 1/32 px
    of the fixed format, fixed -> float keeps those positions)."""
    import cv2

    is_float = maps[0].dtype == np.float32
    if is_float == (to == 'float'):
        return maps
    return tuple(cv2.convertMaps(maps[0], maps[1], cv2.CV_32FC1 if to == 'float' else cv2.CV_16SC2))


def rectification_maps(camera: CameraModel, P: np.ndarray, size: Tuple[int, int],
                       R: Optional[np.ndarray] = None, threads: Optional[int] = None,
                       map_format: str = 'fixed') -> Tuple[np.ndarray, np.ndarray]:
    """Maps sending each pixel of the rectified image (camera matrix P[:3, :3], rotation R) to
    where ``camera`` saw it, as ``map_format`` says: 'fixed', CV_16SC2 + CV_16UC1 interpolation
    table (as cv2.initUndistortRectifyMap gives image_proc), or 'float', two CV_32FC1 maps (x, y).
    Pixels whose ray the camera cannot see map outside the image.

    Rows are computed in chunks of float64 work on ``threads`` threads (default: one per CPU;
    numpy and OpenCV release the GIL, so the chunks run in parallel); the result does not depend
    on the number of threads."""
    import cv2

    if map_format not in ('fixed', 'float'):
        raise ValueError(f'map_format = {map_format!r} is invalid: allowed: fixed, float')
    width, height = size
    Pinv = np.linalg.inv(np.asarray(P, dtype=float)[:3, :3])
    M = Pinv if R is None else np.asarray(R, dtype=float).T @ Pinv
    if map_format == 'float':
        map1 = np.empty((height, width), np.float32)
        map2 = np.empty((height, width), np.float32)
    else:
        map1 = np.empty((height, width, 2), np.int16)
        map2 = np.empty((height, width), np.uint16)
    u = np.arange(width, dtype=float)

    def chunk(top):
        v = np.arange(top, min(top + _MAP_ROWS_PER_CHUNK, height), dtype=float)[:, None]
        rays = np.empty((len(v), width, 3))
        for i in range(3):  # rays = M @ (u, v, 1), without a meshgrid
            rays[..., i] = M[i, 0] * u + (M[i, 1] * v + M[i, 2])
        pix = camera.project(rays).astype(np.float32)
        pix[~np.isfinite(pix)] = -1e4  # unseen: sample the constant border
        np.clip(pix, -1e4, 3e4, out=pix)  # keep within int16 after fixed-point conversion
        rows = slice(top, top + len(v))
        if map_format == 'float':
            map1[rows], map2[rows] = pix[..., 0], pix[..., 1]
            return
        map1[rows], map2[rows] = cv2.convertMaps(np.ascontiguousarray(pix[..., 0]),
                                                 np.ascontiguousarray(pix[..., 1]), cv2.CV_16SC2)

    tops = range(0, height, _MAP_ROWS_PER_CHUNK)
    threads = _map_threads(height) if threads is None else max(1, int(threads))
    if threads == 1:
        for top in tops:
            chunk(top)
    else:
        with ThreadPoolExecutor(max_workers=threads, thread_name_prefix='rectification_maps') as pool:
            for future in [pool.submit(chunk, top) for top in tops]:
                future.result()  # re-raises a chunk's exception
    return map1, map2


class Rectifier:
    """Undistorts images of ``camera`` into the pinhole camera ``P``; maps are built once.

    ``rectify`` writes into a caller-provided buffer when given one, so a stream of frames
    costs one cv2.remap each and no allocation. The maps are held in one format
    (``map_format_for``: built as a one-channel image wants them; the first frame with more
    channels that is faster the other way converts them once, 2-12 ms at 1080p).
    ``map_threads``: threads building the maps (default: one per CPU).
    """

    def __init__(self, camera: CameraModel, balance: float = 0.0, fov_scale: float = 1.0,
                 interpolation: int = 1, P: Optional[np.ndarray] = None, map_threads: Optional[int] = None):
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f'interpolation = {interpolation!r} is invalid: allowed: 0 (nearest), '
                             '1 (linear), 2 (cubic), 4 (lanczos4)')
        self.camera = camera
        self.P = new_camera_matrix(camera, balance, fov_scale) if P is None else np.asarray(P, float)[:3, :3]
        self.size = (camera.width, camera.height)
        self.interpolation = INTERPOLATIONS[interpolation]
        self._version = opencv_version()
        self._maps = rectification_maps(camera, self.P, self.size, threads=map_threads,
                                        map_format=map_format_for(1, self.interpolation, self._version))

    @property
    def map1(self) -> np.ndarray:
        return self._maps[0]

    @property
    def map2(self) -> np.ndarray:
        return self._maps[1]

    @property
    def map_format(self) -> str:
        return 'float' if self._maps[0].dtype == np.float32 else 'fixed'

    @property
    def map_nbytes(self) -> int:
        return self._maps[0].nbytes + self._maps[1].nbytes

    def rectify(self, image: np.ndarray, out: Optional[np.ndarray] = None) -> np.ndarray:
        import cv2  # loaded by the maps already: a dictionary lookup per frame

        h, w = image.shape[:2]
        if (w, h) != self.size:
            raise ValueError(f'image is {w}x{h}, the rectifier was built for {self.size[0]}x{self.size[1]}')
        wanted = map_format_for(image.shape[2] if image.ndim == 3 else 1, self.interpolation, self._version)
        if wanted != self.map_format:
            self._maps = convert_maps(self._maps, wanted)
        # Unseen pixels of a float image (depth) are NaN, as image_proc / image_geometry fill them:
        # a 0 there would read as a valid depth and be blended into the edge pixels.
        border = float('nan') if image.dtype.kind == 'f' else 0
        map1, map2 = self._maps
        return cv2.remap(image, map1, map2, self.interpolation, dst=out,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=border)
