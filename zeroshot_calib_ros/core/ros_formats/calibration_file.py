"""Calibration records: what a ROS CameraInfo carries, in camera_calibration_parsers' files.

The formats are the ones camera_calibration_parsers reads and writes and camera_info_manager
loads from ``camera_info_url``: YAML (parse_yml.cpp) for ``.yaml`` / ``.yml`` and the Videre INI
(parse_ini.cpp) for ``.ini``, chosen by extension as readCalibration / writeCalibration do. So a
file written here can be given to any ROS camera driver, and theirs load here.

Reading follows yaml-cpp's view of a document (every scalar a string, converted per field) and
is stricter than the C++ parsers where they would load garbage (``stoi("1280.9")`` is 1280,
a short INI row becomes NaN): every malformed file raises CalibrationFileError with one line
that names the file, the field and what is allowed. What a CameraCalibration holds is always
valid, so whatever is saved loads again.

binning_x, binning_y and roi are CameraInfo fields that neither C++ format has. They are
written only when they differ from their defaults (0 = no binning, all-zero roi = the full
image), as extra YAML keys after the standard ones and as extra keys in the INI ``[image]``
section; the C++ parsers ignore both (parse_yml.cpp indexes the keys it knows, parse_ini.cpp's
parse_image_section looks only for the lines ``width`` and ``height``).
"""
from __future__ import annotations

import math
import os
import re
import reprlib
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np
import yaml

from ..atomic_file import SaveError, write_atomically
from ..file_input import InputFileError, read_capped
from ..lens.models import FOV_NAMES, CameraModel, camera_from_calibration, fov_edge_pixels
from ..lens.fitting import DISTORTION_FITS
from .rectify import new_camera_matrix
from ..zeroshot.solver import ZeroShotSolution
from ..zeroshot.spec import MAX_IMAGE_SIDE

DISTORTION_MODELS = tuple(DISTORTION_FITS)
"""The models ``from_solution`` can fit."""
NONZERO_EPSILON = 1e-20
"""Stand-in for an exact-zero coefficient of a distorting model (see ``CameraCalibration.from_solution``)."""


def stand_in_note(distortion_model: str, D) -> Optional[str]:
    """What a D of zeros but one NONZERO_EPSILON (``from_solution``'s stand-in) means, in words for
    the one who reads the file or the output; None for any other D."""
    D = np.asarray(D, dtype=float).ravel()
    if D.size == 0 or np.count_nonzero(D) != 1 or D[np.nonzero(D)[0][0]] != NONZERO_EPSILON:
        return None
    if distortion_model in ('equidistant', 'fisheye'):
        meaning = 'no correction: the lens follows the fisheye law r = f * theta exactly'
    else:
        meaning = 'every fitted coefficient is 0'
    return (f'{meaning}; the {NONZERO_EPSILON:g} stands for 0, written because image_proc takes an all-zero D '
            'as "no distortion" and would not rectify (it moves no pixel)')

DISTORTION_COEFFICIENTS = {'equidistant': (4,), 'fisheye': (4,), 'plumb_bob': (0, 4, 5, 8),
                           'rational_polynomial': (8,)}
"""The models a loaded calibration may have (what ``camera_from_calibration`` can rectify) and
their allowed numbers of coefficients."""

DEFAULT_CAMERA_INFO_URL = 'file://${ROS_HOME}/camera_info/${NAME}.yaml'
"""camera_info_manager's URL for an empty ``camera_info_url`` (loading and saving)."""
FORMATS = {'.yaml': 'yaml', '.yml': 'yaml', '.ini': 'ini'}
"""parse.cpp: the extension picks the format, exactly (``.YAML`` is refused there too)."""
UNKNOWN_CAMERA_NAME = 'unknown'
"""parse_yml.cpp's camera name for a file without one."""
MAX_CAMERA_NAME = 200
"""Longest camera_name: ``${NAME}.yaml`` must fit a 255-byte file name."""
MAX_FILE_BYTES = 1 << 20
"""Largest calibration file read (a real one is about 1 kB); bigger is refused unread."""
MAX_YAML_DEPTH = 32
"""Deepest YAML nesting accepted (a calibration file nests 2 deep); PyYAML's composer recurses."""
MAX_YAML_VALUES = 10000
"""Most values a YAML document may hold with its aliases expanded (a calibration file holds about
50): a few hundred bytes of nested aliases would otherwise stand for billions ("billion laughs")."""
MAX_DISTORTION_VALUES = 64
_CONDITION_LIMIT = 1e12
"""A 3x3 matrix whose singular values differ by more than this is taken as singular."""

FOCAL_MIN_PER_SIDE = 0.01
"""Smallest focal length (K's and P's fx, fy), times the image's smaller side: a field of view of
~100 radians, far past any lens (a 360-degree equidistant lens has f = side / (2 pi) = 0.16 x side;
what the zero-shot solver gives for any spec it accepts is above 0.04 x the smaller side)."""
FOCAL_MAX_PER_SIDE = 1e5
"""Largest focal length, times the image's larger side: a field of view of 0.0006 degrees (a 2 m
telescope on a 1/2.3" sensor is 320 x side)."""
PRINCIPAL_POINT_MARGIN = 1.0
"""cx, cy of K and P may lie this many image widths / heights outside the image, no further
(a shifted lens or a rectified stereo camera moves it by a fraction of the image)."""
MAX_SKEW_PER_FOCAL = 0.1
"""|skew| (K[0, 1], P[0, 1]) at most this times fx: 5.7 degrees between the pixel axes (real
sensors: 0)."""
MAX_DISTORTION_TERM = 1e6
"""Each distortion coefficient's term, at the image corner farthest from the principal point
(normalised radius rho = its distance / f), may scale the radius by at most this factor:
|D[i]| rho^n_i <= 1e6, with n_i the power of the term (equidistant k1..k4: 2, 4, 6, 8 in theta;
plumb_bob / rational_polynomial k1, k2, p1, p2, k3, k4, k5, k6: 2, 4, 1, 1, 6, 2, 4, 6). Real lenses
keep each term below 10; the zero-shot fits of extreme specs reach 1e5 (a KB4 fit of a 180-degree
lens: alternating coefficients of 1e4 that cancel), a 0.05-degree lens's KB4 k4 = 7.5e11 means
7.5e11 x (5e-4)^8 = 3e-15 there. So the bound is on what a coefficient does to the image, not on
its value."""
_TERM_POWERS = {'equidistant': (2, 4, 6, 8), 'fisheye': (2, 4, 6, 8)}
_PLUMB_BOB_POWERS = (2, 4, 1, 1, 6, 2, 4, 6)
ROTATION_TOLERANCE = 1e-3
"""R must be a rotation: |R R^T - I| at most this per element, det(R) > 0 (files round R to 6-9
digits, cameracalibrator's to 6: errors of 1e-6)."""

_CAMERA_NAME = re.compile(r'[A-Za-z0-9_]+')  # camera_info_manager setCameraName (C-locale isalnum)
_INTEGER_TEXT = re.compile(r'[0-9]{1,12}')
_NUMBER_TEXT = re.compile(r'[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?')
_NON_FINITE_TEXT = re.compile(r'[-+]?\.?(?:inf|infinity|nan)', re.IGNORECASE)
_TRUE, _FALSE = {'true', 'yes', 'on', 'y'}, {'false', 'no', 'off', 'n'}  # yaml-cpp as<bool>
_ROI_KEYS = ('x_offset', 'y_offset', 'height', 'width', 'do_rectify')  # RegionOfInterest.msg order
_INI_RESERVED = ('image', 'externals')  # parse_ini.cpp sections that are not a camera section


def _one_line(message) -> str:
    return ' '.join(str(message).splitlines())


class CalibrationFileError(ValueError):
    """A calibration file, record or URL cannot be used; the message (always one line, so it can
    go into a log line or a service response) says which field and what is allowed."""

    def __init__(self, message):
        super().__init__(_one_line(message))


class CalibrationSaveError(SaveError, CalibrationFileError):
    """``CameraCalibration.save`` failed. An OSError, as the errors callers caught before, and a
    CalibrationFileError; ``strerror`` is the reason alone, ``str()`` names the target file too.
    The target is left as it was and no temporary file stays behind."""


_SHORT_REPR = reprlib.Repr()
_SHORT_REPR.maxlevel, _SHORT_REPR.maxlist, _SHORT_REPR.maxtuple, _SHORT_REPR.maxdict = 3, 6, 6, 4
_SHORT_REPR.maxstring = _SHORT_REPR.maxother = 120


def _show(value, limit: int = 40) -> str:
    """repr of ``value`` cut to ``limit`` characters, built in bounded time and memory whatever the
    value (a list nested 9 deep with 9 items each is never written out whole)."""
    if isinstance(value, str):
        text = repr(value[:limit + 1])
    elif isinstance(value, (list, tuple, dict, set, frozenset)):
        text = _SHORT_REPR.repr(value)
    else:
        text = repr(value)
    return text if len(text) <= limit else text[:limit] + '...'


def _float_text(value: float) -> str:
    """Shortest exact text of a finite float that both yaml-cpp and PyYAML read as a float:
    PyYAML's YAML 1.1 resolver wants a '.' in the mantissa (``1e-20`` would be a string)."""
    text = repr(float(value))
    mantissa, e, exponent = text.partition('e')
    if e and '.' not in mantissa:
        text = f'{mantissa}.0e{exponent}'
    return text


def _integer(name: str, value, low: int, high: int, what: str = '') -> int:
    """An integer field, given as text (a file) or a Python / numpy integer (never bool or float)."""
    allowed = f'allowed: an integer from {low} to {high}{what}'
    if isinstance(value, str) and _INTEGER_TEXT.fullmatch(value):
        number = int(value)
    elif isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        number = int(value)
    else:
        raise CalibrationFileError(f'{name} = {_show(value)} is invalid: {allowed}')
    if not low <= number <= high:
        raise CalibrationFileError(f'{name} = {number} is invalid: {allowed}')
    return number


def _file_number(name: str, value) -> float:
    """A finite number, given as text (a file) or a Python / numpy number (never bool)."""
    if isinstance(value, str) and _NUMBER_TEXT.fullmatch(value):
        number = float(value)
    elif isinstance(value, str) and _NON_FINITE_TEXT.fullmatch(value):
        number = math.nan
    elif isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)):
        number = float(value)
    else:
        raise CalibrationFileError(f'{name} = {_show(value)} is invalid: allowed: a finite number')
    if not math.isfinite(number):
        raise CalibrationFileError(f'{name} = {_show(value)} is invalid: allowed: finite numbers only')
    return number


def _boolean(name: str, value) -> bool:
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, str) and value.lower() in _TRUE | _FALSE:
        return value.lower() in _TRUE
    raise CalibrationFileError(f'{name} = {_show(value)} is invalid: allowed: true or false')


def check_camera_name(name) -> str:
    """``name`` if camera_info_manager's setCameraName accepts it (not empty; ASCII letters,
    digits and '_'), else CalibrationFileError. It goes into ``${NAME}`` file paths and INI
    section headers, where '/', '..', ']' or a newline would write somewhere else or something
    unreadable."""
    if not isinstance(name, str) or not _CAMERA_NAME.fullmatch(name) or len(name) > MAX_CAMERA_NAME:
        raise CalibrationFileError(
            f'camera_name = {_show(name)} is invalid: allowed: 1 to {MAX_CAMERA_NAME} ASCII letters, digits '
            "and '_' (camera_info_manager's rule)")
    return name


@dataclass(frozen=True)
class RegionOfInterest:
    """sensor_msgs/RegionOfInterest: the part of the full-resolution (unbinned) image that is
    sent. All zeros (the default) means the full image."""

    x_offset: int = 0
    y_offset: int = 0
    height: int = 0
    width: int = 0
    do_rectify: bool = False

    def is_full(self) -> bool:
        return self.x_offset == self.y_offset == self.height == self.width == 0

    def to_dict(self) -> dict:
        return {key: getattr(self, key) for key in _ROI_KEYS}

    @classmethod
    def from_value(cls, value, name: str = 'roi') -> 'RegionOfInterest':
        """A RegionOfInterest from itself or a mapping of its fields (missing ones: defaults)."""
        if isinstance(value, RegionOfInterest):
            return value
        if not isinstance(value, dict):
            raise CalibrationFileError(f'{name} = {_show(value)} is invalid: allowed: a mapping of '
                                       f'{", ".join(_ROI_KEYS)}')
        unknown = [key for key in value if key not in _ROI_KEYS]
        if unknown:
            raise CalibrationFileError(f'{name}.{_show(unknown[0])} is unknown: allowed: {", ".join(_ROI_KEYS)}')
        fields = {key: _integer(f'{name}.{key}', value[key], 0, MAX_IMAGE_SIDE, ' (pixels)')
                  for key in _ROI_KEYS[:4] if key in value}
        if 'do_rectify' in value:
            fields['do_rectify'] = _boolean(f'{name}.do_rectify', value['do_rectify'])
        return cls(**fields)


def _check_text(kind: str, text):
    """CalibrationFileError unless ``text`` is a str of a calibration file's size."""
    if not isinstance(text, str):
        raise CalibrationFileError(f'{kind} text = {_show(text)} is invalid: allowed: a str')
    if len(text) > MAX_FILE_BYTES:
        raise CalibrationFileError(f'the {kind} text is larger than {MAX_FILE_BYTES} bytes: allowed: '
                                   'a camera calibration file (about 1 kB)')


def _as_matrix(label: str, value, rows: int, cols: Optional[int] = None) -> np.ndarray:
    """``value`` as a float array of rows x cols (cols None: a vector), copied."""
    shape = f'{rows} x {cols}' if cols else 'a list of'
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise CalibrationFileError(f'{label} = {_show(value)} is invalid: allowed: {shape} numbers') from None
    if cols is None:
        return array.ravel()
    if array.size != rows * cols:
        raise CalibrationFileError(f'{label} has {array.size} values: allowed: {rows * cols} ({shape})')
    return array.reshape(rows, cols)


def _well_conditioned(matrix: np.ndarray) -> bool:
    try:
        s = np.linalg.svd(matrix, compute_uv=False)
    except np.linalg.LinAlgError:
        return False
    return bool(s[0] > 0 and s[-1] > s[0] / _CONDITION_LIMIT)


def _check_plausible(width: int, height: int, K: np.ndarray, model: str, D: np.ndarray, R: np.ndarray,
                     P: np.ndarray):
    """Raise CalibrationFileError, naming the field and its allowed range, for a calibration no
    camera has (the bounds above): CameraInfo consumers would publish black or garbage images."""
    low, high = FOCAL_MIN_PER_SIDE * min(width, height), FOCAL_MAX_PER_SIDE * max(width, height)
    for label, M in (('K (camera_matrix)', K), ('P (projection_matrix)', P)):
        for name, value in (('fx', M[0, 0]), ('fy', M[1, 1])):
            if not low <= value <= high:
                raise CalibrationFileError(
                    f'{label} {name} = {value:.6g} is invalid: allowed: {low:.6g} to {high:.6g} px '
                    f'({FOCAL_MIN_PER_SIDE:g} x the smaller image side to {FOCAL_MAX_PER_SIDE:g} x the '
                    f'larger, of {width} x {height})')
        for name, value, side in (('cx', M[0, 2], width), ('cy', M[1, 2], height)):
            lo, hi = -PRINCIPAL_POINT_MARGIN * side, (1 + PRINCIPAL_POINT_MARGIN) * side
            if not lo <= value <= hi:
                raise CalibrationFileError(
                    f'{label} {name} = {value:.6g} is invalid: allowed: {lo:g} to {hi:g} px (within '
                    f'{PRINCIPAL_POINT_MARGIN:g} image size of the {width} x {height} image)')
        if abs(M[0, 1]) > MAX_SKEW_PER_FOCAL * M[0, 0]:
            raise CalibrationFileError(
                f'{label} skew = {M[0, 1]:.6g} is invalid: allowed: at most {MAX_SKEW_PER_FOCAL:g} x fx '
                f'= {MAX_SKEW_PER_FOCAL * M[0, 0]:.6g} in magnitude')
    corners = np.array([[0.0, 0.0], [width, 0.0], [0.0, height], [width, height]])
    rho = float(np.hypot((corners[:, 0] - K[0, 2]) / K[0, 0], (corners[:, 1] - K[1, 2]) / K[1, 1]).max())
    powers = _TERM_POWERS.get(model, _PLUMB_BOB_POWERS)
    for i, (value, n) in enumerate(zip(D, powers)):
        limit = MAX_DISTORTION_TERM / max(rho ** n, 1e-300)
        if abs(value) > limit:
            raise CalibrationFileError(
                f'D (distortion_coefficients) [{i}] = {value:.6g} is invalid: allowed: -{limit:.3g} to {limit:.3g} '
                f'(its term may scale the radius of the image corner, rho = {rho:.3g} focal lengths, by at most '
                f'{MAX_DISTORTION_TERM:g})')
    error = float(np.abs(R @ R.T - np.eye(3)).max())
    if error > ROTATION_TOLERANCE or not np.linalg.det(R) > 0:
        raise CalibrationFileError(
            f'R (rectification_matrix) = {np.round(R, 6).tolist()} is invalid: allowed: a rotation '
            f'(R R^T = I within {ROTATION_TOLERANCE:g} per element, det(R) = +1); here R R^T is off by '
            f'{error:.3g}, det(R) = {np.linalg.det(R):.6g}')


@dataclass(eq=False)
class CameraCalibration:
    """Intrinsics, distortion, rectification, projection, binning and ROI of one camera, as in
    CameraInfo. Validated on construction (CalibrationFileError): what it holds can be saved,
    loaded again and rectified with.

    ``load_warnings`` lists what loading a file assumed (for the caller to log), as the C++
    parsers' RCLCPP_WARNs; it is not part of the record (``==`` ignores it).
    """

    width: int
    height: int
    K: np.ndarray
    distortion_model: str
    D: np.ndarray
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    P: Optional[np.ndarray] = None
    camera_name: str = 'camera'
    binning_x: int = 0
    binning_y: int = 0
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)
    load_warnings: List[str] = field(default_factory=list, compare=False)

    def __post_init__(self):
        self.width = _integer('width (image_width)', self.width, 1, MAX_IMAGE_SIDE, ' (pixels)')
        self.height = _integer('height (image_height)', self.height, 1, MAX_IMAGE_SIDE, ' (pixels)')
        self.K = _as_matrix('K (camera_matrix)', self.K, 3, 3)
        self.D = _as_matrix('D (distortion_coefficients)', self.D, 1)
        self.R = _as_matrix('R (rectification_matrix)', self.R, 3, 3)
        if self.P is None:
            self.P = np.hstack([self.K, np.zeros((3, 1))])
        self.P = _as_matrix('P (projection_matrix)', self.P, 3, 4)
        self.roi = RegionOfInterest.from_value(self.roi)
        self.load_warnings = list(self.load_warnings)
        self.validate()

    def validate(self):
        """Raise CalibrationFileError unless this is a usable calibration."""
        for name, key in (('width', 'image_width'), ('height', 'image_height')):
            _integer(f'{name} ({key})', getattr(self, name), 1, MAX_IMAGE_SIDE, ' (pixels)')
        check_camera_name(self.camera_name)
        labels = {'K': 'camera_matrix', 'D': 'distortion_coefficients', 'R': 'rectification_matrix',
                  'P': 'projection_matrix'}
        for name, key in labels.items():
            if not np.all(np.isfinite(getattr(self, name))):
                raise CalibrationFileError(f'{name} ({key}) is invalid: allowed: finite numbers only')
        K, P = self.K, self.P
        if not (K[0, 0] > 0 and K[1, 1] > 0 and K[1, 0] == 0 and K[2].tolist() == [0.0, 0.0, 1.0]):
            raise CalibrationFileError(f'K (camera_matrix) = {K.tolist()} is invalid: allowed: '
                                       '[[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0')
        if not _well_conditioned(self.R):
            raise CalibrationFileError(f'R (rectification_matrix) = {self.R.tolist()} is invalid: '
                                       'allowed: an invertible 3 x 3 matrix (a rotation)')
        # Rectification maps invert P[:3, :3] R; a P that cannot be inverted is refused whether
        # or not anyone rectifies, so that every record saved also loads again. CameraInfo.msg's
        # form [fx' 0 cx' Tx; 0 fy' cy' Ty; 0 0 1 0] is invertible exactly when fx', fy' > 0
        # (upper triangular), which needs no conditioning threshold: f = 0.5 px, cx = 7e5 is fine.
        if not (P[0, 0] > 0 and P[1, 1] > 0 and P[1, 0] == 0 and P[2, :3].tolist() == [0.0, 0.0, 1.0]):
            raise CalibrationFileError(f'P (projection_matrix) = {P.tolist()} is unusable for rectification: '
                                       "allowed: [[fx', s, cx', Tx], [0, fy', cy', Ty], [0, 0, 1, Tz]] with "
                                       "fx', fy' > 0 (P[:3, :3] invertible)")
        model = self.distortion_model
        if model not in DISTORTION_COEFFICIENTS:
            raise CalibrationFileError(f'distortion_model = {_show(model)} is invalid: allowed: '
                                       f'{", ".join(DISTORTION_COEFFICIENTS)}')
        counts = DISTORTION_COEFFICIENTS[model]
        if self.D.size not in counts:
            raise CalibrationFileError(
                f'D (distortion_coefficients) has {self.D.size} values: allowed for {model}: '
                + ' or '.join(map(str, counts)))
        _check_plausible(self.width, self.height, K, model, self.D, self.R, P)
        _integer('binning_x', self.binning_x, 0, self.width, ' (0 and 1: no binning)')
        _integer('binning_y', self.binning_y, 0, self.height, ' (0 and 1: no binning)')
        roi = self.roi
        if not isinstance(roi, RegionOfInterest):
            raise CalibrationFileError(f'roi = {_show(roi)} is invalid: allowed: a RegionOfInterest')
        for key, high in (('x_offset', self.width), ('y_offset', self.height), ('height', self.height),
                          ('width', self.width)):
            _integer(f'roi.{key}', getattr(roi, key), 0, high, ' (pixels)')
        if not isinstance(roi.do_rectify, (bool, np.bool_)):
            raise CalibrationFileError(f'roi.do_rectify = {_show(roi.do_rectify)} is invalid: allowed: true or false')
        if not roi.is_full() and not (
                roi.width >= 1 and roi.height >= 1 and roi.x_offset + roi.width <= self.width
                and roi.y_offset + roi.height <= self.height):
            raise CalibrationFileError(
                f'roi = {roi.to_dict()} is invalid: allowed: all zero (the full image) or a region of at '
                f'least 1 x 1 pixels inside the {self.width} x {self.height} image')
        try:
            camera_from_calibration(model, K, self.D, self.width, self.height)
        except ValueError as exc:
            raise CalibrationFileError(str(exc)) from None

    def __eq__(self, other):
        if not isinstance(other, CameraCalibration):
            return NotImplemented
        return ((self.width, self.height, self.distortion_model, self.camera_name, self.binning_x,
                 self.binning_y, self.roi)
                == (other.width, other.height, other.distortion_model, other.camera_name, other.binning_x,
                    other.binning_y, other.roi)
                and all(np.array_equal(getattr(self, n), getattr(other, n)) for n in ('K', 'D', 'R', 'P')))

    __hash__ = None  # mutable, compared by value

    def camera(self) -> CameraModel:
        """The camera model this calibration describes (what the rectifier uses)."""
        return camera_from_calibration(self.distortion_model, self.K, self.D, self.width, self.height)

    @classmethod
    def from_solution(cls, solution: ZeroShotSolution, distortion_model: str = 'equidistant',
                      balance: float = 0.0, fov_scale: float = 1.0, camera_name: str = 'camera'):
        """The ROS record of a zero-shot solution: ``distortion_model`` coefficients fitted to the
        exact model, and P the rectified camera chosen by ``balance`` and ``fov_scale``.

        image_geometry and image_proc take an all-zero D as "no distortion" and then skip
        rectification, even for ``equidistant``, where zero coefficients still mean the fisheye
        law r = f theta. So if the fit of a distorting camera comes out exactly zero, the last
        coefficient is set to 1e-20, which keeps downstream rectifying and moves no pixel by
        more than 1e-18 px.

        Returns (calibration, fit).
        """
        if distortion_model not in DISTORTION_FITS:
            raise CalibrationFileError(f'distortion_model = {distortion_model!r} is invalid: '
                                       f'allowed: {", ".join(DISTORTION_MODELS)}')
        fit = DISTORTION_FITS[distortion_model](solution.camera)
        D = fit.D.copy()
        distorting = distortion_model == 'equidistant' or solution.omega != 0.0
        if distorting and not np.any(D):
            D[3 if distortion_model == 'equidistant' else 4] = NONZERO_EPSILON
        K = solution.K
        P = np.hstack([new_camera_matrix(solution.camera, balance, fov_scale), np.zeros((3, 1))])
        calibration = cls(solution.spec.width, solution.spec.height, K, distortion_model, D,
                          np.eye(3), P, camera_name)
        return calibration, fit

    def scaled(self, width: int, height: int) -> 'CameraCalibration':
        """The same camera at another full resolution (a resized or binned sensor mode of the
        same aspect ratio): K and P scaled; the roi mapped onto the new pixel grid (offsets
        rounded down, far edges up, so it still covers what it covered); binning factors kept,
        as they relate the sent image to whatever the full resolution is (one larger than the
        new size is refused)."""
        S = np.diag([width / self.width, height / self.height, 1.0])
        roi = self.roi
        if not roi.is_full():
            x0, y0 = roi.x_offset * width // self.width, roi.y_offset * height // self.height
            x1 = -(-(roi.x_offset + roi.width) * width // self.width)
            y1 = -(-(roi.y_offset + roi.height) * height // self.height)
            roi = RegionOfInterest(x0, y0, y1 - y0, x1 - x0, roi.do_rectify)
        return CameraCalibration(width, height, S @ self.K, self.distortion_model, self.D, self.R,
                                 S @ self.P, self.camera_name, self.binning_x, self.binning_y, roi)

    # --- YAML (parse_yml.cpp) -----------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {
            'image_width': int(self.width), 'image_height': int(self.height),
            'camera_name': self.camera_name,
            'camera_matrix': {'rows': 3, 'cols': 3, 'data': [float(x) for x in self.K.ravel()]},
            'distortion_model': self.distortion_model,
            'distortion_coefficients': {'rows': 1, 'cols': int(self.D.size),
                                        'data': [float(x) for x in self.D]},
            'rectification_matrix': {'rows': 3, 'cols': 3, 'data': [float(x) for x in self.R.ravel()]},
            'projection_matrix': {'rows': 3, 'cols': 4, 'data': [float(x) for x in self.P.ravel()]},
        }
        d.update(self._extra_fields())
        return d

    def _extra_fields(self) -> dict:
        """binning / roi, only when not the defaults (so the usual file is what C++ writes)."""
        extra = {}
        if self.binning_x or self.binning_y:
            extra.update(binning_x=int(self.binning_x), binning_y=int(self.binning_y))
        if not self.roi.is_full() or self.roi.do_rectify:
            extra['roi'] = self.roi.to_dict()
        return extra

    def to_yaml(self, comments: Sequence[str] = ()) -> str:
        """parse_yml.cpp's layout and key order: block mappings, flow-style data lists; numbers
        exact (shortest round-trip text); camera_name quoted, so that names like 123 or true
        stay strings for PyYAML too; then binning / roi if not the defaults. ``comments``: lines
        put first as ``# `` comments, which the readers skip (``comment_lines``)."""
        d = self.to_dict()
        lines = [f"image_width: {d['image_width']}", f"image_height: {d['image_height']}",
                 f'camera_name: "{self.camera_name}"']  # check_camera_name: nothing to escape
        for key in ('camera_matrix', 'distortion_model', 'distortion_coefficients',
                    'rectification_matrix', 'projection_matrix'):
            value = d[key]
            if isinstance(value, str):
                lines.append(f'{key}: {value}')
                continue
            data = ', '.join(_float_text(x) for x in value['data'])
            lines += [f'{key}:', f"  rows: {value['rows']}", f"  cols: {value['cols']}",
                      f'  data: [{data}]']
        for key in ('binning_x', 'binning_y'):
            if key in d:
                lines.append(f'{key}: {d[key]}')
        if 'roi' in d:
            lines.append('roi:')
            lines += [f'  {key}: {str(value).lower()}' for key, value in d['roi'].items()]
        return '\n'.join(comment_lines(comments) + lines) + '\n'

    @classmethod
    def from_yaml_text(cls, text: str) -> 'CameraCalibration':
        """Parse a calibration YAML document (CalibrationFileError if it is not a valid one)."""
        _check_text('YAML', text)
        try:
            d = yaml.load(text, Loader=_YamlLoader)
        except CalibrationFileError:
            raise
        except yaml.MarkedYAMLError as exc:
            mark = exc.problem_mark or exc.context_mark
            where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark else ''
            raise CalibrationFileError(f'invalid YAML: {exc.problem or exc.context}{where}') from None
        except yaml.YAMLError as exc:
            raise CalibrationFileError(f'invalid YAML: {exc}') from None
        except RecursionError:  # the depth cap should come first; never a traceback regardless
            raise CalibrationFileError(f'invalid YAML: nested too deeply: allowed: {MAX_YAML_DEPTH} levels') from None
        if not isinstance(d, dict):
            raise CalibrationFileError(
                f'not a camera calibration file: the document is {_show(d)}: allowed: a mapping with '
                f'{", ".join(_YAML_KEYS)}')
        return cls.from_dict(d)

    @classmethod
    def from_dict(cls, d: dict) -> 'CameraCalibration':
        """A calibration from a parsed YAML mapping: values as text (yaml-cpp's view, what
        ``from_yaml_text`` gives) or as Python numbers (``yaml.safe_load``, ``to_dict``)."""
        if not isinstance(d, dict):
            raise CalibrationFileError(f'not a camera calibration file: {_show(d)}: allowed: a mapping')
        warnings = []

        def required(key):
            if key not in d:
                raise CalibrationFileError(f'{key} is missing (not a camera calibration file): allowed: a '
                                           f'mapping with {", ".join(_YAML_KEYS)}')
            return d[key]

        width = _integer('image_width', required('image_width'), 1, MAX_IMAGE_SIDE, ' (pixels)')
        height = _integer('image_height', required('image_height'), 1, MAX_IMAGE_SIDE, ' (pixels)')
        camera_name = UNKNOWN_CAMERA_NAME
        if 'camera_name' in d:
            camera_name = _file_camera_name(d['camera_name'], warnings)
        K = _yaml_matrix('camera_matrix', required('camera_matrix'), 3, 3)
        R = _yaml_matrix('rectification_matrix', required('rectification_matrix'), 3, 3)
        P = _yaml_matrix('projection_matrix', required('projection_matrix'), 3, 4)
        if 'distortion_model' in d:
            model = d['distortion_model']
            if not isinstance(model, str) or model not in DISTORTION_COEFFICIENTS:
                raise CalibrationFileError(f'distortion_model = {_show(model)} is invalid: allowed: '
                                           f'{", ".join(DISTORTION_COEFFICIENTS)}')
        else:
            model = 'plumb_bob'
            warnings.append('distortion_model is missing: assuming plumb_bob (as camera_calibration_parsers does); '
                            'if the coefficients are of another model, add its distortion_model line to the file')
        D = _yaml_matrix('distortion_coefficients', required('distortion_coefficients'), None, None)
        binning_x = _integer('binning_x', d.get('binning_x', 0), 0, width, ' (0 and 1: no binning)')
        binning_y = _integer('binning_y', d.get('binning_y', 0), 0, height, ' (0 and 1: no binning)')
        roi = RegionOfInterest.from_value(d['roi']) if 'roi' in d else RegionOfInterest()
        try:
            return cls(width, height, K, model, D, R, P, camera_name, binning_x, binning_y, roi, warnings)
        except CalibrationFileError as exc:  # the file's own key names, for the one who edits it
            raise CalibrationFileError(_file_vocabulary(str(exc))) from None

    # --- INI (parse_ini.cpp) ------------------------------------------------------------------
    def to_ini(self, precision: Optional[int] = None, comments: Sequence[str] = ()) -> str:
        """parse_ini.cpp's writeCalibrationIni layout, character for character. Its numbers are
        ``std::fixed`` with 5 decimals (``precision=5`` gives exactly its bytes); by default
        they are exact (shortest round-trip text), which its reader (``operator>>``) reads too.
        ``comments``: lines put first as ``# `` comments, which its reader skips.

        Like writeCalibrationIni, only plumb_bob with 5 coefficients can be written; camera
        names ``image`` and ``externals`` would read back as those sections."""
        if self.distortion_model != 'plumb_bob' or self.D.size != 5:
            raise CalibrationFileError(
                f'distortion_model = {self.distortion_model!r} with {self.D.size} coefficients cannot be '
                'written as INI: allowed: plumb_bob with 5 coefficients (camera_calibration_parsers\' INI); '
                'save as .yaml')
        if self.camera_name in _INI_RESERVED:
            raise CalibrationFileError(f'camera_name = {self.camera_name!r} cannot be written as INI: allowed: '
                                       'any name but image and externals (INI section names); save as .yaml')
        number = _float_text if precision is None else (lambda x: f'{float(x):.{int(precision)}f}')

        def matrix(m):  # SimpleMatrix operator<<: "v v v \n" per row
            return ''.join(''.join(f'{number(v)} ' for v in row) + '\n' for row in np.atleast_2d(m))

        text = ''.join(line + '\n' for line in comment_lines(comments))
        text += f'# Camera intrinsics\n\n[image]\n\nwidth\n{self.width}\n\nheight\n{self.height}\n\n'
        extra = self._extra_fields()
        for key in ('binning_x', 'binning_y'):
            if key in extra:
                text += f'{key}\n{extra[key]}\n\n'
        if 'roi' in extra:
            roi = extra['roi']
            text += 'roi\n' + ' '.join(str(int(roi[key])) for key in _ROI_KEYS) + '\n\n'
        text += f'[{self.camera_name}]\n\n'
        text += 'camera matrix\n' + matrix(self.K)
        text += '\ndistortion\n' + matrix(self.D)
        text += '\n\nrectification\n' + matrix(self.R)
        text += '\nprojection\n' + matrix(self.P)
        return text

    @classmethod
    def from_ini_text(cls, text: str) -> 'CameraCalibration':
        """Parse camera_calibration_parsers' INI (CalibrationFileError if it is not a valid one)."""
        _check_text('INI', text)
        return _parse_ini(cls, text)

    # --- files --------------------------------------------------------------------------------
    def file_text(self, path: str, comments: Sequence[str] = ()) -> str:
        """The content ``save(path, comments)`` writes: YAML or INI by the extension of ``path``."""
        return self.to_ini(comments=comments) if _format_of(path) == 'ini' else self.to_yaml(comments)

    def save(self, path: str, comments: Sequence[str] = ()):
        """Write this calibration to ``path`` (YAML or INI by its extension), ``comments`` first as
        ``# `` lines that camera_calibration_parsers and ``load`` skip, all or nothing:
        the content is built first, then ``atomic_file.write_atomically`` replaces the file (old
        or new, never a mix; symlinks written through; the mode kept; a read-only file refused).
        Raises CalibrationSaveError (an OSError) naming the target, never the temporary file;
        the target is then unchanged.
        """
        path = os.fspath(path)
        try:
            data = self.file_text(path, comments).encode('utf-8')
        except CalibrationFileError as exc:
            raise CalibrationSaveError(path, str(exc)) from None
        write_atomically(path, data, CalibrationSaveError)

    @classmethod
    def load(cls, path: str) -> 'CameraCalibration':
        """Read a calibration file (YAML or INI by its extension, as readCalibration does).
        Raises CalibrationFileError (one line naming ``path`` and the field); what loading
        assumed is in ``load_warnings``."""
        path = os.fspath(path)
        fmt = _format_of(path)
        try:
            data = read_capped(path, MAX_FILE_BYTES, 'a camera calibration file (about 1 kB)')
        except InputFileError as exc:
            raise CalibrationFileError(str(exc)) from None
        try:
            text = data.decode('utf-8-sig')
        except UnicodeDecodeError as exc:
            raise CalibrationFileError(f'{path}: not UTF-8 text (byte {exc.start}): not a camera '
                                       'calibration file') from None
        try:
            return cls.from_ini_text(text) if fmt == 'ini' else cls.from_yaml_text(text)
        except CalibrationFileError as exc:
            raise CalibrationFileError(f'{path}: {exc}') from None


def comment_lines(comments: Sequence[str]) -> List[str]:
    """``comments`` as ``# `` lines, each on one line (line breaks and runs of blanks made one
    space), which both file formats' readers skip: YAML comments, and parse_ini.cpp skips every
    line whose first non-blank character is '#'."""
    return ['# ' + ' '.join(str(comment).split()) for comment in comments]


_YAML_KEYS = ('image_width', 'image_height', 'camera_name', 'camera_matrix', 'distortion_model',
              'distortion_coefficients', 'rectification_matrix', 'projection_matrix')


def _file_vocabulary(message: str) -> str:
    """A record's field names as the file names them, in a message about a file."""
    for name, key in (('K', 'camera_matrix'), ('D', 'distortion_coefficients'), ('R', 'rectification_matrix'),
                      ('P', 'projection_matrix'), ('width', 'image_width'), ('height', 'image_height')):
        message = message.replace(f'{name} ({key})', key)
    return message


def _file_camera_name(value, warnings: List[str]) -> str:
    """A file's camera_name: kept if camera_info_manager could use it; otherwise the
    calibration still loads (camera_info_manager only compares the name, and warns) with
    camera_name 'unknown' and a warning, so that every name a record holds can be saved again."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        value = str(value)  # yaml.safe_load of an unquoted 123
    if not isinstance(value, str):
        raise CalibrationFileError(f'camera_name = {_show(value)} is invalid: allowed: a string')
    try:
        return check_camera_name(value)
    except CalibrationFileError as exc:
        warnings.append(f'{exc}; using camera_name {UNKNOWN_CAMERA_NAME!r}')
        return UNKNOWN_CAMERA_NAME


def _yaml_matrix(key: str, m, rows: Optional[int], cols: Optional[int]) -> np.ndarray:
    """parse_yml.cpp's SimpleMatrix {rows, cols, data}: rows and cols fixed (None: the
    distortion vector, any rows x cols), data exactly rows * cols finite numbers."""
    if not isinstance(m, dict):
        raise CalibrationFileError(f'{key} = {_show(m)} is invalid: allowed: a mapping with rows, cols and data')
    size = {}
    for name, fixed in (('rows', rows), ('cols', cols)):
        if name not in m:
            raise CalibrationFileError(f'{key}.{name} is missing: allowed: {fixed if fixed else "an integer"}')
        if fixed is None:
            size[name] = _integer(f'{key}.{name}', m[name], 0, MAX_DISTORTION_VALUES)
        elif _integer(f'{key}.{name}', m[name], 0, 1 << 31) != fixed:
            raise CalibrationFileError(f'{key}.{name} = {_show(m[name])} is invalid: allowed: {fixed}')
        else:
            size[name] = fixed
    count = size['rows'] * size['cols']
    if count > MAX_DISTORTION_VALUES:
        raise CalibrationFileError(f'{key} has rows x cols = {count} values: allowed: at most {MAX_DISTORTION_VALUES}')
    data = m.get('data')
    if not isinstance(data, list):
        raise CalibrationFileError(f'{key}.data = {_show(data)} is invalid: allowed: a list of {count} numbers')
    if len(data) != count:
        raise CalibrationFileError(f'{key}.data has {len(data)} values: allowed: {count} '
                                   f'(rows {size["rows"]} x cols {size["cols"]})')
    values = [_file_number(f'{key}.data[{i}]', v) for i, v in enumerate(data)]
    return np.array(values, dtype=float).reshape(size['rows'], size['cols']) if rows else np.array(values)


class _YamlLoader(yaml.BaseLoader):
    """yaml-cpp's view of a document: no tags resolved or constructed (every scalar a string,
    converted per field as yaml-cpp's ``as<T>()`` does, so ``.inf`` or ``true`` is never a
    number), nesting capped (PyYAML's composer recurses), duplicate keys refused."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_document(self):
        node = super().compose_document()
        sizes = {}

        def expanded(n):  # values under n with aliases expanded; each node counted once
            if id(n) not in sizes:
                sizes[id(n)] = MAX_YAML_VALUES + 1  # a cycle (PyYAML refuses them first) counts as too many
                children = (n.value if isinstance(n, yaml.SequenceNode) else
                            [x for pair in n.value for x in pair] if isinstance(n, yaml.MappingNode) else [])
                total = 1
                for child in children:
                    total += expanded(child)
                    if total > MAX_YAML_VALUES:
                        break
                sizes[id(n)] = total
            return sizes[id(n)]
        if node is not None and expanded(node) > MAX_YAML_VALUES:
            raise CalibrationFileError(f'invalid YAML: its aliases expand to more than {MAX_YAML_VALUES} values: '
                                       'allowed: a camera calibration file (about 50 values)')
        return node

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise CalibrationFileError(f'invalid YAML: nested too deeply: allowed: {MAX_YAML_DEPTH} levels')
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    if key_node.value in seen:
                        raise CalibrationFileError(
                            f'{_show(key_node.value)} appears twice (line {key_node.start_mark.line + 1}): '
                            'allowed: each key once')
                    seen.add(key_node.value)
        return super().construct_mapping(node, deep)


def _format_of(path: str) -> str:
    ext = os.path.splitext(os.fspath(path))[1]
    if ext not in FORMATS:
        raise CalibrationFileError(f'{path}: unrecognized format {ext!r}: allowed: .ini, .yml or .yaml '
                                   '(camera_calibration_parsers)')
    return FORMATS[ext]


# --- INI parsing -------------------------------------------------------------------------------

_INI_MATRICES = (('camera matrix', 3, 3), ('distortion', 1, None), ('rectification', 3, 3), ('projection', 3, 4))


def _parse_ini(cls, text: str) -> CameraCalibration:
    """parse_ini.cpp's reader: lines trimmed, blank and '#' / ';' lines skipped, a line with '['
    and ']' starts a section; ``[image]`` holds ``width`` / ``height`` (the line after each key),
    ``[externals]`` is ignored, any other section is the camera's (its name in the brackets)
    with ``camera matrix``, ``distortion``, ``rectification`` and ``projection`` followed by
    their rows. Stricter where the C++ reader would load garbage: exact row lengths, numbers
    only, one camera section."""
    sections = []  # (header, line number, [(line number, line)])
    for number, raw in enumerate(text.split('\n'), start=1):
        line = raw.strip()
        if not line or line[0] in '#;':
            continue
        if '[' in line and ']' in line:
            if not (line[0] == '[' and line[-1] == ']'):
                raise CalibrationFileError(f'line {number}: section header {_show(line)} is invalid: allowed: '
                                           '[image], [externals] or [<camera_name>]')
            sections.append((line[1:-1], number, []))
        elif not sections:
            raise CalibrationFileError(f'line {number}: {_show(line)} is outside a section: allowed: [image] '
                                       'and [<camera_name>] sections (not a camera calibration file)')
        else:
            sections[-1][2].append((number, line))
    image = [s for s in sections if s[0] == 'image']
    cameras = [s for s in sections if s[0] not in _INI_RESERVED]
    if len(image) != 1:
        raise CalibrationFileError(('the [image] section is missing' if not image else
                                    f'the [image] section appears {len(image)} times')
                                   + ': allowed: one (not a camera calibration file)')
    if len(cameras) != 1:
        raise CalibrationFileError(f'{len(cameras)} camera sections: allowed: one [<camera_name>] camera section')
    _, image_line, image_lines = image[0]
    name, camera_line, camera_lines = cameras[0]

    def value_after(key, lines, section_line, section):
        keys = [i for i, (_, line) in enumerate(lines) if line == key]  # std::find: the first
        if not keys:
            return None
        i = keys[0]
        if i + 1 >= len(lines):
            raise CalibrationFileError(f'[{section}] {key} (line {lines[i][0]}) has no value after it: '
                                       'allowed: its value on the next line')
        return lines[i + 1]

    def image_integer(key, low, high, what, default=None):
        found = value_after(key, image_lines, image_line, 'image')
        if found is None:
            if default is None:
                raise CalibrationFileError(f'[image] {key} is missing: allowed: {key} and its value on the next line')
            return default
        return _integer(f'[image] {key} (line {found[0]})', found[1], low, high, what)

    width = image_integer('width', 1, MAX_IMAGE_SIDE, ' (pixels)')
    height = image_integer('height', 1, MAX_IMAGE_SIDE, ' (pixels)')
    binning_x = image_integer('binning_x', 0, width, ' (0 and 1: no binning)', 0)
    binning_y = image_integer('binning_y', 0, height, ' (0 and 1: no binning)', 0)
    roi = RegionOfInterest()
    found = value_after('roi', image_lines, image_line, 'image')
    if found is not None:
        tokens = found[1].split()
        if len(tokens) != 5:
            raise CalibrationFileError(f'[image] roi (line {found[0]}) has {len(tokens)} values: allowed: 5 '
                                       f'({" ".join(_ROI_KEYS)}, do_rectify 0 or 1)')
        values = {key: _integer(f'[image] roi {key} (line {found[0]})', token, 0, MAX_IMAGE_SIDE, ' (pixels)')
                  for key, token in zip(_ROI_KEYS[:4], tokens)}
        values['do_rectify'] = bool(_integer(f'[image] roi do_rectify (line {found[0]})', tokens[4], 0, 1))
        roi = RegionOfInterest(**values)

    warnings = []
    camera_name = _file_camera_name(name, warnings)
    matrices = {}
    for key, rows, cols in _INI_MATRICES:
        keys = [i for i, (_, line) in enumerate(camera_lines) if line == key]
        if not keys:
            raise CalibrationFileError(f'[{name}] (line {camera_line}): {key} is missing: allowed: '
                                       f'{key} and its rows on the next lines')
        start = keys[0] + 1
        block = camera_lines[start:start + rows]
        if len(block) < rows:
            raise CalibrationFileError(f'[{name}] {key} has {len(block)} rows: allowed: {rows}')
        values = []
        for number, line in block:
            tokens = line.split()
            allowed = (5, 8) if cols is None else (cols,)
            if len(tokens) not in allowed:
                raise CalibrationFileError(f'[{name}] {key} line {number} has {len(tokens)} numbers: allowed: '
                                           + ' or '.join(map(str, allowed)))
            values += [_file_number(f'[{name}] {key} line {number} value {j + 1}', token)
                       for j, token in enumerate(tokens)]
        matrices[key] = np.array(values)
    D = matrices['distortion']
    model = 'plumb_bob' if D.size == 5 else 'rational_polynomial'  # parse_ini.cpp: by the count
    try:
        return cls(width, height, matrices['camera matrix'], model, D, matrices['rectification'],
                   matrices['projection'], camera_name, binning_x, binning_y, roi, warnings)
    except CalibrationFileError as exc:
        message = str(exc)
        for name_, key in (('K (camera_matrix)', 'camera matrix'), ('D (distortion_coefficients)', 'distortion'),
                           ('R (rectification_matrix)', 'rectification'), ('P (projection_matrix)', 'projection'),
                           ('width (image_width)', 'width'), ('height (image_height)', 'height')):
            message = message.replace(name_, f'{key} ({name_.split()[0]})')
        raise CalibrationFileError(message) from None


# --- camera_info_url ---------------------------------------------------------------------------

_URL_ALLOWED = ('allowed: file:///absolute/path, package://package/path, a plain path or empty '
                f'(= {DEFAULT_CAMERA_INFO_URL}), with variables ${{NAME}} and ${{ROS_HOME}}, '
                'to a .yaml, .yml or .ini file')


def ros_home() -> str:
    """$ROS_HOME, or ~/.ros as camera_info_manager and rcl use when it is unset or empty
    (``~`` expanded in both)."""
    return os.path.expanduser(os.environ.get('ROS_HOME') or os.path.join('~', '.ros'))


def _substitute(url: str, camera_name: str) -> str:
    """camera_info_manager's resolveURL: ``${NAME}`` and ``${ROS_HOME}``; a '$' not followed by
    '{' stays; any other ``${`` is an error here (resolveURL logs it and keeps going)."""
    out, rest = [], 0
    while True:
        dollar = url.find('$', rest)
        if dollar < 0:
            out.append(url[rest:])
            return ''.join(out)
        out.append(url[rest:dollar])
        if url.startswith('${NAME}', dollar):
            out.append(camera_name)
            rest = dollar + len('${NAME}')
        elif url.startswith('${ROS_HOME}', dollar):
            out.append(ros_home())
            rest = dollar + len('${ROS_HOME}')
        elif url.startswith('${', dollar):
            end = url.find('}', dollar)
            variable = url[dollar:end + 1] if end > 0 else url[dollar:dollar + 12]
            raise CalibrationFileError(f'camera_info_url = {_show(url, 80)} is invalid: unknown variable '
                                       f'{variable}: {_URL_ALLOWED}')
        else:
            out.append('$')
            rest = dollar + 1


def resolve_camera_info_url(url: str, camera_name: str = 'camera') -> str:
    """Local path of a camera_info_manager URL, as camera_info_manager resolves it.

    ``${NAME}`` is the camera name (which must pass camera_info_manager's name rule, as it goes
    into the path) and ``${ROS_HOME}`` $ROS_HOME or ~/.ros. An empty URL is the default
    ``file://${ROS_HOME}/camera_info/${NAME}.yaml``, for loading and saving alike.
    ``file:///abs/path`` (scheme in any case, path taken verbatim), ``package://pkg/rel/path``
    (the share directory of ``pkg`` in AMENT_PREFIX_PATH, as ament_index finds it) and plain
    paths are accepted; other schemes, ``flash:///`` (unsupported there too) and unknown
    variables raise CalibrationFileError naming camera_info_url.
    """
    if not isinstance(url, str):
        raise CalibrationFileError(f'camera_info_url = {_show(url)} is invalid: {_URL_ALLOWED}')
    check_camera_name(camera_name)
    given = url
    resolved = _substitute(url or DEFAULT_CAMERA_INFO_URL, camera_name)

    def invalid(why):
        return CalibrationFileError(f'camera_info_url = {_show(given, 80)} is invalid: {why}: {_URL_ALLOWED}')

    lower = resolved.lower()
    if lower.startswith('file:'):
        if not lower.startswith('file:///'):
            raise invalid('a file URL needs an absolute path (file:///...)')
        path = resolved[len('file://'):]
    elif lower.startswith('package:'):
        package, rel = '', ''
        if lower.startswith('package://'):
            package, _, rel = resolved[len('package://'):].partition('/')
        if not package or not rel:
            raise invalid('a package URL is package://package/path')
        for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
            if prefix and os.path.exists(os.path.join(prefix, 'share', 'ament_index', 'resource_index',
                                                      'packages', package)):
                path = os.path.join(prefix, 'share', package, rel)
                break
        else:
            raise CalibrationFileError(f'camera_info_url = {_show(given, 80)} is invalid: package {package!r} not '
                                       'found in AMENT_PREFIX_PATH')
    elif lower.startswith('flash:'):
        raise invalid('flash:/// URLs are not supported (nor by camera_info_manager)')
    elif re.match(r'[A-Za-z][A-Za-z0-9+.-]*://', resolved):
        raise invalid(f'scheme {resolved.split(":", 1)[0]!r} is not supported')
    else:
        path = resolved
    if os.path.splitext(path)[1] not in FORMATS:
        raise CalibrationFileError(f'camera_info_url = {_show(given, 80)} is invalid: {path!r} is not a '
                                   'calibration file name: allowed: a .yaml, .yml or .ini file')
    return path


def json_safe(value):
    """``value`` with numpy types made Python and NaN / inf made None, for strict JSON."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if hasattr(value, 'tolist'):
        return json_safe(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def spec_record(spec) -> dict:
    """What the spec sheet gave, as a record's ``spec``: the FOVs in degrees and the image circle
    (``circle_diameter`` px, ``circle_fov`` degrees) when given."""
    record = dict(spec.given())
    if getattr(spec, 'circle_diameter', None) is not None:
        record.update(circle_diameter=spec.circle_diameter, circle_fov=spec.circle_fov)
    return record


def solution_summary(solution: ZeroShotSolution, calibration: CameraCalibration, fit) -> dict:
    """The record of a solve (the CLI's ``--json``, the node's start-up log). Strict JSON: a
    predicted FOV whose edge pixels see no ray (outside a fisheye's image circle) is None."""
    fovs = solution.predicted_fovs()
    return json_safe({
        'width': solution.spec.width, 'height': solution.spec.height,
        'spec': spec_record(solution.spec),
        'model': solution.projection.name, 'omega': solution.omega, 'f': solution.f,
        'cx': solution.camera.cx, 'cy': solution.camera.cy,
        'K': calibration.K.tolist(),
        'distortion_model': calibration.distortion_model, 'D': calibration.D.tolist(),
        'fit_error_px': fit.max_error_px,
        'P': calibration.P.tolist(),
        'hfov': fovs['hfov'], 'vfov': fovs['vfov'], 'dfov': fovs['dfov'],
        'root_found': solution.root_found,
        'dfov_residuals': solution.dfov_residuals,
        # what the spec left open and was assumed (one FOV: the lens shape of real lenses), or None
        'assumption': getattr(solution, 'assumption', None),
    })


def _fovs_past_circle(summary: dict) -> set:
    """The predicted FOVs whose edge pixels lie outside the spec's image circle (centred on the
    principal point): there no light reaches, and the figure is the lens model continued into the
    dark, not something the camera sees (a 187-degree circular fisheye's "hfov" of 250 degrees)."""
    diameter = summary['spec'].get('circle_diameter')
    if diameter is None:
        return set()
    centre = np.array([summary['cx'], summary['cy']])
    edges = fov_edge_pixels(summary['width'], summary['height'], *centre)
    return {name for name, pair in zip(FOV_NAMES, edges) if np.hypot(*(pair - centre).T).max() > diameter / 2 + 1.0}


def _fov_line(summary: dict) -> str:
    past = _fovs_past_circle(summary)
    values = ', '.join(f"{k[0]} {'-' if summary[k] is None else format(summary[k], '.3f')}{'*' if k in past else ''}"
                       for k in FOV_NAMES)
    notes = ['predicted']
    if None in (summary[k] for k in FOV_NAMES):
        notes.append('- : no ray')
    if past:
        notes.append('*: past the image circle: nothing is imaged there, this is the lens model continued into the dark')
    return f"FOV       {values} deg ({'; '.join(notes)})"


def summary_text(summary: dict) -> str:
    """A readable block of a ``solution_summary`` (CLI output, node start-up log)."""
    spec = ', '.join(f'{k} {v:g} px' if k == 'circle_diameter' else f'{k} {v:g} deg'
                     for k, v in summary['spec'].items())
    K = summary['K']
    note = stand_in_note(summary['distortion_model'], summary['D'])
    lines = [
        f"camera    {summary['width']} x {summary['height']} px" + (f', {spec}' if spec else ''),
        f"model     {summary['model']}" + (
            '  (no barrel-distortion root: w* = 0, mean perspective focal)'
            if not summary['root_found'] and summary['omega'] == 0 and len(summary['spec']) > 1 else ''),
        'omega     ' + ('- (not the paper\'s model)' if summary['omega'] is None else f"{summary['omega']:.9g} (1/px)"),
        f"f         {summary['f']:.4f} px",
        f"K         [[{K[0][0]:.4f}, 0, {K[0][2]:.2f}], [0, {K[1][1]:.4f}, {K[1][2]:.2f}], [0, 0, 1]]",
        f"D         {summary['distortion_model']} [{', '.join(f'{d:.9g}' for d in summary['D'])}]"
        + (f' ({note})' if note else ''),
        f"fit error {summary['fit_error_px']:.2g} px (max over the image)",
        _fov_line(summary),
    ]
    for name, res in summary['dfov_residuals'].items():
        lines.append(f"  dfov residual {name:13s} {res:+.3f} deg" + ('  <- chosen' if name == summary['model'] else ''))
    if summary.get('assumption'):
        lines.append(f"assumed   {summary['assumption']}")
    return '\n'.join(lines)
