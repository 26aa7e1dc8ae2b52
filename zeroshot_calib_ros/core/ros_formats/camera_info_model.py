"""A ROS-free pinhole camera model of a sensor_msgs/CameraInfo, as C++ image_geometry has it.

image_geometry's *Python* ``PinholeCameraModel`` ignores ``distortion_model``: it passes D to
cv2.undistortPoints / cv2.initUndistortRectifyMap whatever the model, so 4 ``equidistant``
(Kannala-Brandt) coefficients are read as plumb_bob k1, k2, p1, p2. Only the C++ image_geometry
(what image_proc rectifies with) switches to cv::fisheye for ``equidistant``.
``CameraInfoModel`` is the C++ behaviour in Python, numpy and OpenCV only (no rclpy):

    model = CameraInfoModel(camera_info_msg)           # or CameraInfoModel.from_calibration('cam.yaml')
    rect = model.rectify_image(raw)                     # what image_proc publishes as image_rect
    uv_rect = model.rectify_points(uv_raw)              # (N, 2) raw pixels -> rectified pixels
    ray = model.project_pixel_to_3d_ray(uv_rect)

It follows vision_opencv's image_geometry/src/pinhole_camera_model.cpp (ROS 2 rolling / jazzy)
call for call: ``fromCameraInfo`` (binning 0 = 1, an all-zero ROI = the full image, K and P
shifted by the ROI offset and then scaled by 1 / binning), ``initRectificationMaps`` (CV_16SC2
maps of the full image at the binned resolution, from cv2.initUndistortRectifyMap or, for
``equidistant``, cv2.fisheye.initUndistortRectifyMap; then cropped to the binned raw ROI),
``rectifyPoint`` (cv2.undistortPoints / cv2.fisheye.undistortPoints with K, D, R, P),
``unrectifyPoint`` (the pixel's z = 1 ray, rotated by R^T, through cv2.projectPoints /
cv2.fisheye.projectPoints), ``rectifyRoi`` (bounding box of the four rectified ROI corners in
full-resolution coordinates), ``reducedResolution`` and ``to{Full,Reduced}Resolution``.

Where C++ image_geometry surprises, and what this class does:

* All-zero (or empty) D means "no distortion": rectify_point(s) / unrectify_point(s) return
  their input and rectify_image copies the image, even when R or P differ from I and K, and
  even for ``equidistant``, where zero coefficients still mean the fisheye law r = f theta.
  Followed, so points agree with image_proc's image_rect (our calibration files store 1e-20
  instead of an exact zero for that reason, see CameraCalibration.from_solution).
* rectifyPoint rounds the point to float32 on the way in and out (steps of 1.2e-4 px at
  x = 1920). Not followed: points stay float64.
* rectifyPoint calls cv::undistortPoints with OpenCV's default stopping rule: 5 fixed-point
  iterations, whatever the residual. For plumb_bob / rational_polynomial that leaves errors of
  0.4 px at the corners of a moderate lens (k1 = -0.3 at 1280 x 720) and 6 px for the
  rational_polynomial lens of test/core/ros_formats/test_camera_info_model.py, more for stronger ones.
  Not followed by default: ``point_criteria`` = POINT_CRITERIA, up to
  200 iterations or a 1e-10 px reprojection residual (Newton steps of 1e-10 rad for
  ``equidistant``, whose OpenCV default, 10 Newton steps / 1e-8, is already accurate).
  ``point_criteria=None`` gives OpenCV's default rule, i.e. C++ image_geometry's numbers
  (up to its float32 rounding).
* rectifyPoint goes through undistortPoints, which uses P[:3, :3] only, while unrectifyPoint
  and projectPixelTo3dRay subtract Tx, Ty: for the right camera of a stereo pair (Tx != 0)
  the two are not inverses. Followed.
* projectPixelTo3dRay returns the ray with z = 1 (Python image_geometry returns a unit ray):
  ``project_pixel_to_3d_ray(uv, normalize=False)`` is C++, ``normalize=True`` is Python's.
* The reduced maps crop the *raw* ROI (a @todo in C++), with the offset integer-divided by the
  binning, while K and P are shifted by the exact offset; reduced_resolution uses the
  *rectified* ROI when roi.do_rectify is set, so it can differ from rectify_image's output
  size. Followed. (An ROI offset that is not a multiple of the binning makes maps and points
  disagree by the remainder, in C++ and here.)
* rectifyImage fills unseen pixels of float images with NaN, of integer images with 0.
  Followed. C++ does not check the raw image size; rectify_image raises ValueError instead.
* An unknown distortion_model makes C++ throw on first use; here the constructor raises.
"""
from __future__ import annotations

import os
from types import SimpleNamespace
from typing import Optional, Tuple

import cv2
import numpy as np

DISTORTION_COEFFICIENTS = {'plumb_bob': 5, 'rational_polynomial': 8, 'equidistant': 4}
"""Coefficients each supported distortion_model takes (0 also: no distortion)."""

POINT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-10)
"""Default stopping rule of rectify_point(s), instead of OpenCV's (see the module docstring)."""

_ROTATION_TOLERANCE = 1e-3  # calibration files round R to ~1e-9; anything worse is no rotation

_MSG_FIELDS = {'width': 'width', 'height': 'height', 'distortion_model': 'distortion_model',
               'd': 'd', 'k': 'k', 'r': 'r', 'p': 'p', 'binning_x': 'binning_x',
               'binning_y': 'binning_y', 'roi': 'roi'}
_FILE_FIELDS = {'width': 'image_width', 'height': 'image_height',
                'distortion_model': 'distortion_model', 'd': 'distortion_coefficients',
                'k': 'camera_matrix', 'r': 'rectification_matrix', 'p': 'projection_matrix',
                'binning_x': 'binning_x', 'binning_y': 'binning_y', 'roi': 'roi'}


def _message_field(msg, name):
    """A CameraInfo field, ROS 2 (lower-case k, d, r, p) or ROS 1 (upper-case) spelling."""
    if hasattr(msg, name):
        return getattr(msg, name)
    if hasattr(msg, name.upper()):
        return getattr(msg, name.upper())
    raise ValueError(f'camera_info has no field {name!r}: allowed: a sensor_msgs/CameraInfo')


def _unsigned(value, name, minimum=0) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f'{name} = {value!r} is invalid: allowed: an integer >= {minimum}')
    return int(value)


def _matrix(value, name, rows, cols) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f'{name} = {value!r} is invalid: allowed: {rows * cols} numbers') from None
    if m.size != rows * cols:
        raise ValueError(f'{name} has {m.size} values: allowed: {rows * cols} ({rows}x{cols})')
    if not np.all(np.isfinite(m)):
        raise ValueError(f'{name} = {m.tolist()} is invalid: allowed: finite numbers only')
    return m.reshape(rows, cols)


def _rect(x, y, w, h) -> Tuple[int, int, int, int]:
    return int(x), int(y), int(w), int(h)


class CameraInfoModel:
    """C++ image_geometry's PinholeCameraModel of one CameraInfo (see the module docstring).

    ``camera_info``: any object with CameraInfo's attributes (width, height, distortion_model,
    d, k, r, p, binning_x, binning_y, roi.x_offset / y_offset / width / height / do_rectify),
    e.g. a sensor_msgs.msg.CameraInfo. ``point_criteria``: the cv2 TermCriteria tuple of
    rectify_point(s); None: OpenCV's default, as C++ image_geometry.

    K, P, fx, ... describe the *reduced* image (binned, ROI-cropped) that a driver publishes
    with this CameraInfo; full_K, full_P the full-resolution calibration.
    """

    def __init__(self, camera_info, point_criteria=POINT_CRITERIA):
        self.point_criteria = point_criteria
        self._read(camera_info, _MSG_FIELDS)

    # -- construction ---------------------------------------------------------------------

    @classmethod
    def from_camera_info(cls, camera_info, point_criteria=POINT_CRITERIA) -> 'CameraInfoModel':
        return cls(camera_info, point_criteria)

    @classmethod
    def from_calibration(cls, calibration, binning_x: int = 0, binning_y: int = 0, roi=None,
                         point_criteria=POINT_CRITERIA) -> 'CameraInfoModel':
        """From a camera_calibration_parsers file: its YAML path, the loaded dict, or anything
        with ``to_dict()`` giving that dict (e.g. our CameraCalibration). Files carry no
        binning or ROI: give them here when the driver bins or crops (``roi``: an object with
        x_offset, y_offset, width, height, do_rectify, or a dict of those). A missing
        rectification_matrix is I, a missing projection_matrix [K | 0]."""
        source = calibration
        if isinstance(calibration, (str, os.PathLike)):
            import yaml  # only needed for files; the message path stays numpy / cv2 only
            try:
                with open(calibration) as f:
                    calibration = yaml.safe_load(f)
            except (OSError, yaml.YAMLError) as exc:
                raise ValueError(f'calibration = {str(source)!r} is invalid: cannot read it: {exc}') from None
        elif hasattr(calibration, 'to_dict'):
            calibration = calibration.to_dict()
        if not isinstance(calibration, dict):
            raise ValueError(f'calibration = {source!r} is invalid: allowed: a calibration file path, '
                             'its dict, or an object with to_dict()')
        d = calibration

        def data(key, required=True):
            if key not in d:
                if required:
                    raise ValueError(f'{key} is missing: allowed: a camera_calibration_parsers file')
                return None
            entry = d[key]
            return entry.get('data') if isinstance(entry, dict) else entry

        if 'image_width' not in d or 'image_height' not in d:
            raise ValueError('image_width / image_height is missing: '
                             'allowed: a camera_calibration_parsers file')
        if 'distortion_model' not in d:
            raise ValueError(f"distortion_model is missing: allowed: {', '.join(DISTORTION_COEFFICIENTS)}")
        K = data('camera_matrix')
        R = data('rectification_matrix', required=False)
        P = data('projection_matrix', required=False)
        if R is None:
            R = np.eye(3).ravel()
        if P is None:
            P = np.hstack([_matrix(K, 'camera_matrix', 3, 3), np.zeros((3, 1))]).ravel()
        if roi is None:
            roi = SimpleNamespace(x_offset=0, y_offset=0, width=0, height=0, do_rectify=False)
        elif isinstance(roi, dict):
            roi = SimpleNamespace(**{'do_rectify': False, **roi})
        info = SimpleNamespace(width=d['image_width'], height=d['image_height'],
                               distortion_model=d['distortion_model'],
                               d=data('distortion_coefficients'), k=K, r=R, p=P,
                               binning_x=binning_x, binning_y=binning_y, roi=roi)
        model = cls.__new__(cls)
        model.point_criteria = point_criteria
        model.camera_name = str(d.get('camera_name', 'camera'))
        model._read(info, _FILE_FIELDS)
        return model

    def update(self, camera_info) -> bool:
        """Re-read a CameraInfo (as C++ fromCameraInfo): True if anything changed, in which case
        the cached maps are dropped; a stream of identical messages costs a comparison each."""
        before = self._key
        self._read(camera_info, _MSG_FIELDS)
        return self._key != before

    def _read(self, msg, names):
        model = _message_field(msg, 'distortion_model')
        if model not in DISTORTION_COEFFICIENTS:
            raise ValueError(f"{names['distortion_model']} = {model!r} is invalid: allowed: "
                             f"{', '.join(DISTORTION_COEFFICIENTS)}")
        width = _unsigned(_message_field(msg, 'width'), names['width'], 1)
        height = _unsigned(_message_field(msg, 'height'), names['height'], 1)
        raw_d = _message_field(msg, 'd')
        D = np.asarray([] if raw_d is None else raw_d, dtype=float).ravel()
        n = DISTORTION_COEFFICIENTS[model]
        if D.size not in (0, n):
            raise ValueError(f"{names['d']} has {D.size} values for distortion_model {model!r}: "
                             f"allowed: {n} (or 0: no distortion)")
        if not np.all(np.isfinite(D)):
            raise ValueError(f"{names['d']} = {D.tolist()} is invalid: allowed: finite numbers only")
        K = _matrix(_message_field(msg, 'k'), names['k'], 3, 3)
        R = _matrix(_message_field(msg, 'r'), names['r'], 3, 3)
        P = _matrix(_message_field(msg, 'p'), names['p'], 3, 4)
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ValueError(f"{names['k']} = {K.ravel().tolist()} is invalid: allowed: fx = k[0] > 0 and "
                             'fy = k[4] > 0 (an all-zero K means an uncalibrated camera)')
        if not (P[0, 0] > 0 and P[1, 1] > 0):
            raise ValueError(f"{names['p']} = {P.ravel().tolist()} is invalid: allowed: fx = p[0] > 0 and "
                             'fy = p[5] > 0')
        if (np.abs(R @ R.T - np.eye(3)).max() > _ROTATION_TOLERANCE or np.linalg.det(R) <= 0):
            raise ValueError(f"{names['r']} = {R.ravel().tolist()} is invalid: allowed: a rotation matrix")
        # Binning 0 is binning 1 (fromCameraInfo).
        bx = _unsigned(_message_field(msg, 'binning_x'), names['binning_x']) or 1
        by = _unsigned(_message_field(msg, 'binning_y'), names['binning_y']) or 1
        roi = _message_field(msg, 'roi')
        rx = _unsigned(roi.x_offset, f"{names['roi']}.x_offset")
        ry = _unsigned(roi.y_offset, f"{names['roi']}.y_offset")
        rw = _unsigned(roi.width, f"{names['roi']}.width")
        rh = _unsigned(roi.height, f"{names['roi']}.height")
        do_rectify = bool(getattr(roi, 'do_rectify', False))
        if rx == ry == rw == rh == 0:  # an all-zero ROI is the full image (fromCameraInfo)
            rw, rh = width, height
        if not 0 < rw <= width - rx:
            raise ValueError(f"{names['roi']}.width = {rw} is invalid: allowed: 1 to {width - rx} "
                             f"(image width {width} - x_offset {rx}), or an all-zero roi")
        if not 0 < rh <= height - ry:
            raise ValueError(f"{names['roi']}.height = {rh} is invalid: allowed: 1 to {height - ry} "
                             f"(image height {height} - y_offset {ry}), or an all-zero roi")
        if width // bx == 0 or height // by == 0 or rw // bx == 0 or rh // by == 0:
            raise ValueError(f"{names['binning_x']} / {names['binning_y']} = {bx} / {by} is invalid: "
                             f'allowed: at most the roi size {rw} x {rh}')

        key = (model, width, height, D.tobytes(), K.tobytes(), R.tobytes(), P.tobytes(), bx, by,
               rx, ry, rw, rh, do_rectify)
        header = getattr(msg, 'header', None)
        self.tf_frame = str(getattr(header, 'frame_id', '')) if header is not None else ''
        if getattr(self, '_key', None) == key:
            return
        self._key = key
        self.distortion_model = model
        self._width, self._height = width, height
        self._D, self._K_full, self._R, self._P_full = D, K, R, P
        self._binning = (bx, by)
        self._raw_roi = _rect(rx, ry, rw, rh)
        self._do_rectify = do_rectify
        # Any non-zero coefficient means distortion (fromCameraInfo's distortion_state).
        self._calibrated = bool(np.any(D != 0))
        self._K, self._P = self._reduce(K, P, rx, ry)
        self._K_binned, self._P_binned = self._reduce(K, P, 0, 0)
        self._full_maps = None
        self._reduced_maps = None
        self._rectified_roi = None
        if not hasattr(self, 'camera_name'):
            self.camera_name = 'camera'

    def _reduce(self, K, P, x_offset, y_offset):
        """K and P of the binned, ROI-cropped image: shift by the offset first (the ROI is in
        full-resolution pixels), then scale (fromCameraInfo, and K_binned of
        initRectificationMaps with a zero offset)."""
        K, P = K.copy(), P.copy()
        K[0, 2] -= x_offset
        K[1, 2] -= y_offset
        P[0, 2] -= x_offset
        P[1, 2] -= y_offset
        bx, by = self._binning
        if bx > 1:
            K[0, [0, 2]] /= bx
            P[0, [0, 2, 3]] /= bx
        if by > 1:
            K[1, [1, 2]] /= by
            P[1, [1, 2, 3]] /= by
        return K, P

    # -- properties -----------------------------------------------------------------------

    K = property(lambda self: self._K.copy(), doc='Camera matrix of the reduced (binned, ROI) image.')
    P = property(lambda self: self._P.copy(), doc='Projection matrix of the reduced image.')
    full_K = property(lambda self: self._K_full.copy(), doc='Camera matrix at full resolution (k).')
    full_P = property(lambda self: self._P_full.copy(), doc='Projection matrix at full resolution (p).')
    D = property(lambda self: self._D.copy(), doc='Distortion coefficients (d).')
    R = property(lambda self: self._R.copy(), doc='Rectification rotation (r).')
    fx = property(lambda self: float(self._P[0, 0]))
    fy = property(lambda self: float(self._P[1, 1]))
    cx = property(lambda self: float(self._P[0, 2]))
    cy = property(lambda self: float(self._P[1, 2]))
    Tx = property(lambda self: float(self._P[0, 3]))
    Ty = property(lambda self: float(self._P[1, 3]))
    width = property(lambda self: self._width, doc='Full-resolution image width (CameraInfo width).')
    height = property(lambda self: self._height, doc='Full-resolution image height.')
    binning_x = property(lambda self: self._binning[0], doc='Binning, 0 read as 1.')
    binning_y = property(lambda self: self._binning[1])
    has_distortion = property(lambda self: self._calibrated,
                              doc='False when D is all zero or empty: points and images pass unchanged.')

    @property
    def full_resolution(self) -> Tuple[int, int]:
        """(width, height) of the full-resolution image."""
        return self._width, self._height

    @property
    def raw_roi(self) -> Tuple[int, int, int, int]:
        """(x, y, width, height) of the ROI in full-resolution raw pixels (all-zero: the image)."""
        return self._raw_roi

    @property
    def rectified_roi(self) -> Tuple[int, int, int, int]:
        """The ROI in full-resolution rectified pixels: the raw ROI unless roi.do_rectify, then
        the bounding box of its rectified corners, rounded inwards (rectifyRoi)."""
        if self._rectified_roi is None:
            if not self._do_rectify:
                self._rectified_roi = self._raw_roi
            else:
                x, y, w, h = self._raw_roi
                corners = np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], float)
                # In full-resolution pixels (the ROI is), so with the full K and P (rectifyRoi).
                tl, tr, br, bl = self._rectify(corners, self._K_full, self._P_full)
                left = int(np.ceil(min(tl[0], bl[0])))
                top = int(np.ceil(min(tl[1], tr[1])))
                right = int(np.floor(max(tr[0], br[0])))
                bottom = int(np.floor(max(bl[1], br[1])))
                self._rectified_roi = _rect(left, top, right - left, bottom - top)
        return self._rectified_roi

    @property
    def reduced_resolution(self) -> Tuple[int, int]:
        """(width, height) of the reduced image: the rectified ROI over the binning
        (reducedResolution)."""
        _, _, w, h = self.rectified_roi
        return w // self._binning[0], h // self._binning[1]

    @property
    def raw_image_size(self) -> Tuple[int, int]:
        """(width, height) of the raw image a driver publishes with this CameraInfo: the raw
        ROI over the binning (what rectify_image takes and returns)."""
        _, _, w, h = self._raw_roi
        return w // self._binning[0], h // self._binning[1]

    def to_full_resolution(self, uv_reduced) -> np.ndarray:
        """Reduced-image pixels (..., 2) in full-resolution pixels (via the rectified ROI)."""
        x, y, _, _ = self.rectified_roi
        uv = _points(uv_reduced, 'uv_reduced', flat=False)
        return uv * np.array(self._binning, float) + np.array([x, y], float)

    def to_reduced_resolution(self, uv_full) -> np.ndarray:
        """Full-resolution pixels (..., 2) in reduced-image pixels."""
        x, y, _, _ = self.rectified_roi
        uv = _points(uv_full, 'uv_full', flat=False)
        return (uv - np.array([x, y], float)) / np.array(self._binning, float)

    # -- points ---------------------------------------------------------------------------

    def rectify_points(self, uv_raw) -> np.ndarray:
        """Raw pixels (N, 2) of the reduced image -> rectified pixels (N, 2) (rectifyPoint)."""
        uv = _points(uv_raw, 'uv_raw', 2)
        return self._rectify(uv, self._K, self._P)

    def rectify_point(self, uv_raw) -> np.ndarray:
        return self.rectify_points(_one(uv_raw, 2, 'uv_raw'))[0]

    def unrectify_points(self, uv_rect) -> np.ndarray:
        """Rectified pixels (N, 2) of the reduced image -> raw pixels (N, 2) (unrectifyPoint)."""
        uv = _points(uv_rect, 'uv_rect', 2)
        if not self._calibrated or len(uv) == 0:
            return uv.copy()
        rays = self._rays(uv, self._P)
        rvec, _ = cv2.Rodrigues(self._R.T)
        tvec = np.zeros(3)
        objects = rays.reshape(-1, 1, 3)
        if self.distortion_model == 'equidistant':
            pixels, _ = cv2.fisheye.projectPoints(objects, rvec, tvec, self._K, self._D)
        else:
            pixels, _ = cv2.projectPoints(objects, rvec, tvec, self._K, self._D)
        return pixels.reshape(-1, 2).astype(float)

    def unrectify_point(self, uv_rect) -> np.ndarray:
        return self.unrectify_points(_one(uv_rect, 2, 'uv_rect'))[0]

    def project_3d_to_pixel(self, xyz) -> np.ndarray:
        """Points (..., 3) in the rectified camera frame -> rectified pixels (..., 2):
        u = (fx x + Tx) / z + cx (project3dToPixel)."""
        p = _points(xyz, 'xyz', 3, flat=False)
        u = (self.fx * p[..., 0] + self.Tx) / p[..., 2] + self.cx
        v = (self.fy * p[..., 1] + self.Ty) / p[..., 2] + self.cy
        return np.stack([u, v], axis=-1)

    def project_pixel_to_3d_ray(self, uv_rect, normalize: bool = False) -> np.ndarray:
        """Rectified pixels (..., 2) -> rays (..., 3) in the rectified camera frame: z = 1 as
        C++ projectPixelTo3dRay, or unit length as Python image_geometry (``normalize``)."""
        rays = self._rays(_points(uv_rect, 'uv_rect', 2, flat=False), self._P)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True) if normalize else rays

    @staticmethod
    def _rays(uv, P):
        fx, fy, cx, cy, Tx, Ty = P[0, 0], P[1, 1], P[0, 2], P[1, 2], P[0, 3], P[1, 3]
        x = (uv[..., 0] - cx - Tx) / fx
        y = (uv[..., 1] - cy - Ty) / fy
        return np.stack([x, y, np.ones_like(x)], axis=-1)

    def _rectify(self, uv, K, P):
        if not self._calibrated or len(uv) == 0:
            return uv.copy()
        src = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 1, 2)
        crit = self.point_criteria
        if self.distortion_model == 'equidistant':
            if crit is None:
                out = cv2.fisheye.undistortPoints(src, K, self._D, R=self._R, P=P)
            else:
                out = cv2.fisheye.undistortPoints(src, K, self._D, R=self._R, P=P, criteria=crit)
        elif crit is None:
            out = cv2.undistortPoints(src, K, self._D, R=self._R, P=P)
        elif hasattr(cv2, 'undistortPointsIter'):  # OpenCV 4: the criteria overload has its own name
            out = cv2.undistortPointsIter(src, K, self._D, self._R, P, crit)
        else:
            out = cv2.undistortPoints(src, K, self._D, R=self._R, P=P, criteria=crit)
        return out.reshape(-1, 2).astype(float)

    # -- images ---------------------------------------------------------------------------

    def rectification_maps(self, full: bool = False) -> Optional[Tuple[np.ndarray, np.ndarray]]:
        """The CV_16SC2 + CV_16UC1 maps rectify_image remaps with (``full``: of the whole
        binned image, before the ROI crop); None without distortion (rectify_image copies)."""
        if not self._calibrated:
            return None
        if self._full_maps is None:
            bx, by = self._binning
            size = (self._width // bx, self._height // by)
            init = (cv2.fisheye.initUndistortRectifyMap if self.distortion_model == 'equidistant'
                    else cv2.initUndistortRectifyMap)
            self._full_maps = init(self._K_binned, self._D, self._R, self._P_binned, size, cv2.CV_16SC2)
        if full:
            return self._full_maps
        if self._reduced_maps is None:
            x, y, w, h = self._raw_roi
            if x != 0 or y != 0 or w != self._width or h != self._height:
                bx, by = self._binning
                x, y, w, h = x // bx, y // by, w // bx, h // by
                map1, map2 = self._full_maps
                # map1 holds the integer part of the source pixel: shift it into the ROI;
                # map2 is the sub-pixel interpolation index, unchanged (initRectificationMaps).
                shifted = map1[y:y + h, x:x + w].astype(np.int32) - np.array([x, y], np.int32)
                self._reduced_maps = (np.clip(shifted, -32768, 32767).astype(np.int16),
                                      np.ascontiguousarray(map2[y:y + h, x:x + w]))
            else:
                self._reduced_maps = self._full_maps
        return self._reduced_maps

    def rectify_image(self, raw: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """The rectified image (rectifyImage): a copy without distortion, else cv2.remap with
        the maps, unseen pixels 0 (NaN for float images)."""
        raw = np.asarray(raw)
        w, h = self.raw_image_size
        if raw.ndim < 2 or raw.shape[:2] != (h, w):
            raise ValueError(f'raw image shape = {raw.shape} is invalid: allowed: ({h}, {w}[, channels]) '
                             '(the raw ROI over the binning)')
        if not self._calibrated:
            return raw.copy()
        map1, map2 = self.rectification_maps()
        if raw.dtype in (np.float32, np.float64):
            return cv2.remap(raw, map1, map2, interpolation, borderMode=cv2.BORDER_CONSTANT,
                             borderValue=float('nan'))
        return cv2.remap(raw, map1, map2, interpolation)

    def __repr__(self):
        return (f'CameraInfoModel({self.distortion_model}, {self._width}x{self._height}, '
                f'binning {self._binning[0]}x{self._binning[1]}, roi {self._raw_roi})')


def _points(value, name, dim=2, flat=True) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f'{name} = {value!r} is invalid: allowed: numbers of shape (N, {dim})') from None
    if a.ndim == 0 or a.shape[-1] != dim or (flat and a.ndim != 2):
        allowed = f'(N, {dim})' if flat else f'(..., {dim})'
        raise ValueError(f'{name} has shape {a.shape}: allowed: {allowed}')
    return a


def _one(value, dim, name) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.shape != (dim,):
        raise ValueError(f'{name} has shape {a.shape}: allowed: ({dim},)')
    return a[None]
