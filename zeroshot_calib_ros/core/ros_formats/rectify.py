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


def principal_point_camera_matrix(camera: CameraModel, balance: float = 0.0,
                                  fov_scale: float = 1.0) -> np.ndarray:
    """The rectified pinhole camera with its principal point at ``camera``'s own (the optical axis
    stays at the pixel where the raw image has it), as ROS camera_calibration writes P for a
    fisheye (calibrator.py, ``set_alpha``: P = K with the focal length scaled). The focal length
    keeps ``new_camera_matrix``'s meaning of ``balance`` (0: the tightest edge, no black border at
    the edge midpoints; 1: every edge midpoint kept) and ``fov_scale``, measured from that
    principal point instead of from the mean of the edge midpoints.

    Why not ``new_camera_matrix`` (OpenCV's estimateNewCameraMatrixForUndistortRectify) for a
    calibrated camera: it centres P on the mean of the undistorted edge midpoints, which for a
    lens whose edges are near 90 degrees off-axis is dominated by whichever edge is nearer 90
    degrees: a 172-degree lens 1 px off-centre gets a P principal point over 100 px from the
    image centre, and the rectified image shows the scene off-centre. For a camera centred in its
    image both agree (up to OpenCV's integer division of an odd image side)."""
    if not 0.0 <= balance <= 1.0:
        raise ValueError(f'balance = {balance!r} is invalid: allowed: 0 to 1')
    if not fov_scale > 0.0 or not np.isfinite(fov_scale):
        raise ValueError(f'fov_scale = {fov_scale!r} is invalid: allowed: greater than 0')
    w, h = camera.width, camera.height
    cx, cy = float(camera.cx), float(camera.cy)
    edges = np.array([(w // 2, 0), (w, h // 2), (w // 2, h), (0, h // 2)], dtype=float)  # new_camera_matrix's
    pts = camera.undistort(edges)
    if not np.all(np.isfinite(pts)):
        pts = _edge_points_within_reach(camera, edges)
    aspect = camera.fx / camera.fy
    pts = pts * np.array([1.0, aspect])
    (minx, miny), (maxx, maxy) = pts.min(axis=0), pts.max(axis=0)
    if not (0.0 < cx < w and 0.0 < cy < h and minx < 0.0 < maxx and miny < 0.0 < maxy):
        return new_camera_matrix(camera, balance, fov_scale)  # the principal point is not inside the edges
    focals = [cx / -minx, (w - cx) / maxx, cy * aspect / -miny, (h - cy) * aspect / maxy]
    f = (balance * min(focals) + (1.0 - balance) * max(focals)) / fov_scale
    return np.array([[f, 0.0, cx], [0.0, f / aspect, cy], [0.0, 0.0, 1.0]])


def _map_threads(rows: int) -> int:
    return max(1, min(os.cpu_count() or 1, -(-rows // _MAP_ROWS_PER_CHUNK)))


FLOAT_MAP_KERNELS = (4, 11)
"""The OpenCV release whose cv2.remap got vectorised kernels for 32-bit float maps (opencv#26348)."""


def opencv_version() -> Tuple[int, int]:
    import cv2

    major, minor = (cv2.__version__.split('.') + ['0'])[:2]
    return int(major), int(''.join(ch for ch in minor if ch.isdigit()) or 0)


def map_format_for(interpolation: int, version: Optional[Tuple[int, int]] = None) -> str:
    """'float' (two CV_32FC1 maps: the exact positions) or 'fixed' (CV_16SC2 + CV_16UC1 table,
    1/32 px: what cv2.initUndistortRectifyMap gives image_proc), whichever cv2.remap runs faster
    with OpenCV's ``interpolation`` flag, for every encoding (3-channel images with linear
    interpolation on OpenCV 4.11 and later are remapped as 4 channels: ``pads_to_four_channels``).

    Measured on this project's 2-core machine at 1920x1080 (ms per remap, fixed -> float):
    OpenCV 5.0, linear: mono8 4.8 -> 2.8, mono16 10.1 -> 3.3, 32FC1 7.5 -> 3.0, bgra8 8.8 -> 4.2;
    nearest: float faster for every encoding on 5.0 and 4.6 (bgr8 4.0 -> 2.0 and 5.5 -> 4.0);
    OpenCV 4.6 (Ubuntu 24.04), linear: fixed faster (mono8 6.9 -> 7.6, bgr8 10.5 -> 11.1);
    cubic and Lanczos: no gain (bgr8 24 -> 28 on 5.0). In the node's stream at 1080p mono8 the
    float maps took the node's highest rate from 82.4 to 122.3 fps (the two alternately in one
    run: benchmarks/results/float_maps.md). OpenCV releases between 4.6 and 4.11 were not
    measured and get the 4.6 rule."""
    if interpolation == 0:
        return 'float'
    if interpolation == 1 and (version or opencv_version()) >= FLOAT_MAP_KERNELS:
        return 'float'
    return 'fixed'


def pads_to_four_channels(channels: int, interpolation: int, version: Optional[Tuple[int, int]] = None) -> bool:
    """Whether a 3-channel image is remapped as 4 channels (cvtColor to BGRA, remap, cvtColor back;
    the same values to the bit, every channel interpolated on its own either way): from OpenCV
    4.11, whose float-map kernels are vectorised (opencv#26348), its 3-channel kernel is slower
    than the 4-channel one and both conversions together (0.2-0.3 ms each at 1080p).

    Measured alternately in one run (benchmarks/remap_kernels.py, results/remap_kernels.md; ms per
    frame back to back, 2-core AMD EPYC, OpenCV 5.0; 3 channels with fixed / float maps -> padded
    to 4 with float maps -> as ``Rectifier.rectify`` pads, the conversions on the calling thread):
    720p bgr8 3.01 / 3.11 -> 2.01 -> 2.47; 1080p bgr8 6.52 / 6.65 -> 4.50 -> 5.41; 4K bgr8
    27.9 / 30.5 -> 22.4 -> 25.7; 1080p bgr16 11.37 / 7.54 -> 6.18 -> 6.65. One call every 33 ms
    in an otherwise idle process the gain is gone at 1080p bgr8 (7.71 fixed, 10.00 padded); in
    the node's 30 fps stream, timed inside an instrumented copy of the node (not kept), the
    remap took 6.0-7.7 ms padded against 7.9-8.0 ms with 3 channels in fixed point (two rounds each). On OpenCV 4.6 no gain (1080p
    bgr8 5.83 fixed, 6.05 padded), so 3 channels stay 3 there."""
    return channels == 3 and interpolation == 1 and (version or opencv_version()) >= FLOAT_MAP_KERNELS


_SERIAL_PIXELS = 1 << 16
"""cv2.cvtColor splits an image into total / 2**16 stripes on its thread pool, and runs a smaller
one on the calling thread alone."""


def _convert_serially(src: np.ndarray, dst: np.ndarray, code: int):
    """cv2.cvtColor(src, code) into ``dst``, on this thread only, in bands of rows below OpenCV's
    threshold for parallel work. Why: a conversion takes 0.2-0.3 ms at 1080p, and a dispatch to
    the thread pool waits for its slowest worker, which on a 2-core machine shared with the
    camera driver and the image's consumers may be descheduled: with pooled conversions the
    node's 30 fps latency at 1080p bgr8 was 21.84 ms against 16.91 for the fixed-point node,
    alternately in one run (rectify_throughput.py --encodings bgr8 --baseline 39fc760 --rounds 2;
    not kept), although the padded remap is faster in isolation (results/remap_kernels.md)."""
    import cv2

    rows = max(1, _SERIAL_PIXELS // max(1, src.shape[1]))
    for top in range(0, src.shape[0], rows):
        cv2.cvtColor(src[top:top + rows], code, dst=dst[top:top + rows])


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
    costs one cv2.remap each and no allocation (3-channel images padded to 4 channels, where
    that is faster: two cvtColor as well, into two frames kept for the next one). The maps are
    built once, in the format OpenCV remaps fastest with (``map_format_for``).
    ``map_threads``: threads building the maps (default: one per CPU). ``R``: the rectification
    rotation of a CameraInfo (a stereo camera's), as cv2.initUndistortRectifyMap and image_proc
    apply it: the rectified pixel's ray is R^T P^-1 (u, v, 1) in the raw camera's frame
    (default: the identity).
    """

    def __init__(self, camera: CameraModel, balance: float = 0.0, fov_scale: float = 1.0,
                 interpolation: int = 1, P: Optional[np.ndarray] = None, map_threads: Optional[int] = None,
                 R: Optional[np.ndarray] = None):
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f'interpolation = {interpolation!r} is invalid: allowed: 0 (nearest), '
                             '1 (linear), 2 (cubic), 4 (lanczos4)')
        self.camera = camera
        self.P = new_camera_matrix(camera, balance, fov_scale) if P is None else np.asarray(P, float)[:3, :3]
        self.R = np.eye(3) if R is None else np.asarray(R, float).reshape(3, 3)
        self.size = (camera.width, camera.height)
        self.interpolation = INTERPOLATIONS[interpolation]
        self._version = opencv_version()
        self._four_channel_buffers = []  # (image, output) of 3-channel frames padded to 4, reused
        self._maps = rectification_maps(camera, self.P, self.size, R=self.R, threads=map_threads,
                                        map_format=map_format_for(self.interpolation, self._version))

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

    @property
    def frame_buffer_nbytes(self) -> int:
        """Memory of the 4-channel frames 3-channel images are padded to (``pads_to_four_channels``):
        two frames of the last such image, 8 bytes a pixel at 8 bits, held once used."""
        return sum(a.nbytes + b.nbytes for a, b in list(self._four_channel_buffers))

    def rectify(self, image: np.ndarray, out: Optional[np.ndarray] = None) -> np.ndarray:
        import cv2  # loaded by the maps already: a dictionary lookup per frame

        h, w = image.shape[:2]
        if (w, h) != self.size:
            raise ValueError(f'image is {w}x{h}, the rectifier was built for {self.size[0]}x{self.size[1]}')
        channels = image.shape[2] if image.ndim == 3 else 1
        # Unseen pixels of a float image (depth) are NaN, as image_proc / image_geometry fill them:
        # a 0 there would read as a valid depth and be blended into the edge pixels.
        border = float('nan') if image.dtype.kind == 'f' else 0
        map1, map2 = self._maps
        if not pads_to_four_channels(channels, self.interpolation, self._version):
            return cv2.remap(image, map1, map2, self.interpolation, dst=out,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=border)
        # list.pop / append are atomic: two threads rectifying at once never share buffers
        try:
            four, four_out = self._four_channel_buffers.pop()
        except IndexError:
            four = four_out = None
        if four is None or four.shape[:2] != image.shape[:2] or four.dtype != image.dtype:
            four = np.empty(image.shape[:2] + (4,), image.dtype)
            four_out = np.empty_like(four)
        if out is None:
            out = np.empty_like(image)
        try:
            _convert_serially(image, four, cv2.COLOR_BGR2BGRA)  # the order of the 3 is kept: rgb8 too
            cv2.remap(four, map1, map2, self.interpolation, dst=four_out,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=border)
            _convert_serially(four_out, out, cv2.COLOR_BGRA2BGR)
            return out
        finally:
            self._four_channel_buffers.append((four, four_out))
