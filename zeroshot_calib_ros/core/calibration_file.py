"""Calibration records: what a ROS CameraInfo carries, as camera_calibration_parsers YAML.

The YAML layout is the one camera_calibration_parsers reads and writes and camera_info_manager
loads from ``camera_info_url`` (file:// or package://), so a file written here can be given to
any ROS camera driver.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Optional
from urllib.parse import unquote, urlparse

import numpy as np
import yaml

from .camera_models import CameraModel, camera_from_calibration
from .fitting import DISTORTION_FITS
from .rectify import new_camera_matrix
from .solver import ZeroShotSolution

DISTORTION_MODELS = tuple(DISTORTION_FITS)
NONZERO_EPSILON = 1e-20
"""Stand-in for an exact-zero coefficient of a distorting model (see ``CameraCalibration.from_solution``)."""


class CalibrationFileError(ValueError):
    """A calibration file or URL cannot be used; the message says which and why."""


@dataclass
class CameraCalibration:
    """Intrinsics, distortion, rectification and projection of one camera, as in CameraInfo."""

    width: int
    height: int
    K: np.ndarray
    distortion_model: str
    D: np.ndarray
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    P: Optional[np.ndarray] = None
    camera_name: str = 'camera'

    def __post_init__(self):
        self.K = np.asarray(self.K, dtype=float).reshape(3, 3)
        self.D = np.asarray(self.D, dtype=float).ravel()
        self.R = np.asarray(self.R, dtype=float).reshape(3, 3)
        if self.P is None:
            self.P = np.hstack([self.K, np.zeros((3, 1))])
        self.P = np.asarray(self.P, dtype=float).reshape(3, 4)
        self.validate()

    def validate(self):
        """Raise CalibrationFileError unless this is a usable calibration."""
        for name in ('width', 'height'):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value <= 0:
                raise CalibrationFileError(f'{name} = {value!r} is invalid: allowed: a positive integer')
        for name in ('K', 'D', 'R', 'P'):
            if not np.all(np.isfinite(getattr(self, name))):
                raise CalibrationFileError(f'{name} is invalid: allowed: finite numbers only')
        if not (self.K[0, 0] > 0 and self.K[1, 1] > 0):
            raise CalibrationFileError(f'K = {self.K.tolist()} is invalid: allowed: positive fx and fy')
        try:
            camera_from_calibration(self.distortion_model, self.K, self.D, self.width, self.height)
        except ValueError as exc:
            raise CalibrationFileError(str(exc)) from None

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
        """The calibration for a binned / resized image of the same aspect ratio."""
        sx, sy = width / self.width, height / self.height
        S = np.diag([sx, sy, 1.0])
        return CameraCalibration(width, height, S @ self.K, self.distortion_model, self.D, self.R,
                                 S @ self.P, self.camera_name)

    def to_dict(self) -> dict:
        return {
            'image_width': int(self.width), 'image_height': int(self.height),
            'camera_name': self.camera_name,
            'camera_matrix': {'rows': 3, 'cols': 3, 'data': [float(x) for x in self.K.ravel()]},
            'distortion_model': self.distortion_model,
            'distortion_coefficients': {'rows': 1, 'cols': int(self.D.size),
                                        'data': [float(x) for x in self.D]},
            'rectification_matrix': {'rows': 3, 'cols': 3, 'data': [float(x) for x in self.R.ravel()]},
            'projection_matrix': {'rows': 3, 'cols': 4, 'data': [float(x) for x in self.P.ravel()]},
        }

    def to_yaml(self) -> str:
        """camera_calibration_parsers' layout: block mappings, flow-style data lists."""
        d = self.to_dict()
        lines = [f"image_width: {d['image_width']}", f"image_height: {d['image_height']}",
                 f"camera_name: {yaml.safe_dump(d['camera_name'], default_style=None).splitlines()[0]}"]
        for key in ('camera_matrix', 'distortion_model', 'distortion_coefficients',
                    'rectification_matrix', 'projection_matrix'):
            value = d[key]
            if isinstance(value, str):
                lines.append(f'{key}: {value}')
                continue
            data = ', '.join(repr(float(x)) for x in value['data'])
            lines += [f'{key}:', f"  rows: {value['rows']}", f"  cols: {value['cols']}",
                      f'  data: [{data}]']
        return '\n'.join(lines) + '\n'

    def save(self, path: str):
        directory = os.path.dirname(os.path.abspath(path))
        os.makedirs(directory, exist_ok=True)
        tmp = f'{path}.tmp{os.getpid()}'
        with open(tmp, 'w') as f:
            f.write(self.to_yaml())
        os.replace(tmp, path)  # atomic: a crash mid-write never leaves half a calibration

    @classmethod
    def from_dict(cls, d: dict) -> 'CameraCalibration':
        try:
            def matrix(key, rows, cols):
                m = d[key]
                data = np.asarray(m['data'], dtype=float)
                if data.size != rows * cols:
                    raise CalibrationFileError(f'{key} has {data.size} values, allowed: {rows * cols}')
                return data.reshape(rows, cols)
            D = np.asarray(d['distortion_coefficients']['data'], dtype=float)
            return cls(int(d['image_width']), int(d['image_height']), matrix('camera_matrix', 3, 3),
                       str(d['distortion_model']), D, matrix('rectification_matrix', 3, 3),
                       matrix('projection_matrix', 3, 4), str(d.get('camera_name', 'camera')))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, CalibrationFileError):
                raise
            raise CalibrationFileError(f'not a camera calibration file: {type(exc).__name__}: {exc}') from None

    @classmethod
    def load(cls, path: str) -> 'CameraCalibration':
        try:
            with open(path) as f:
                d = yaml.safe_load(f)
        except (OSError, yaml.YAMLError) as exc:
            raise CalibrationFileError(f'cannot read {path}: {exc}') from None
        if not isinstance(d, dict):
            raise CalibrationFileError(f'{path} is not a camera calibration file')
        return cls.from_dict(d)


def resolve_camera_info_url(url: str, camera_name: str = 'camera') -> Optional[str]:
    """Local path of a camera_info_manager URL, or None for an empty URL.

    Supports ``file:///abs/path.yaml``, ``package://pkg/rel/path.yaml`` (looked up in the share
    directories of AMENT_PREFIX_PATH, as ament_index does) and plain paths; ``${NAME}`` is
    replaced by the camera name, as camera_info_manager does.
    """
    if not url:
        return None
    url = url.replace('${NAME}', camera_name)
    parsed = urlparse(url)
    if parsed.scheme == 'file':
        return unquote(parsed.netloc + parsed.path)
    if parsed.scheme == 'package':
        package, rel = parsed.netloc, parsed.path.lstrip('/')
        for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
            if prefix and os.path.exists(os.path.join(prefix, 'share', 'ament_index', 'resource_index',
                                                      'packages', package)):
                return os.path.join(prefix, 'share', package, rel)
        raise CalibrationFileError(f'camera_info_url = {url!r} is invalid: package {package!r} not found '
                                   'in AMENT_PREFIX_PATH')
    if parsed.scheme in ('',):
        return url
    raise CalibrationFileError(f'camera_info_url = {url!r} is invalid: allowed: file://, package:// or a path')


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


def solution_summary(solution: ZeroShotSolution, calibration: CameraCalibration, fit) -> dict:
    """The record of a solve (the CLI's ``--json``, the node's start-up log). Strict JSON: a
    predicted FOV whose edge pixels see no ray (outside a fisheye's image circle) is None."""
    fovs = solution.predicted_fovs()
    spec = dict(solution.spec.given())
    if getattr(solution.spec, 'circle_diameter', None) is not None:
        spec.update(circle_diameter=solution.spec.circle_diameter, circle_fov=solution.spec.circle_fov)
    return json_safe({
        'width': solution.spec.width, 'height': solution.spec.height,
        'spec': spec,
        'model': solution.projection.name, 'omega': solution.omega, 'f': solution.f,
        'cx': solution.camera.cx, 'cy': solution.camera.cy,
        'K': calibration.K.tolist(),
        'distortion_model': calibration.distortion_model, 'D': calibration.D.tolist(),
        'fit_error_px': fit.max_error_px,
        'P': calibration.P.tolist(),
        'hfov': fovs['hfov'], 'vfov': fovs['vfov'], 'dfov': fovs['dfov'],
        'root_found': solution.root_found,
        'dfov_residuals': solution.dfov_residuals,
    })


def summary_text(summary: dict) -> str:
    """A readable block of a ``solution_summary`` (CLI output, node start-up log)."""
    spec = ', '.join(f'{k} {v:g} px' if k == 'circle_diameter' else f'{k} {v:g} deg'
                     for k, v in summary['spec'].items())
    K = summary['K']
    lines = [
        f"camera    {summary['width']} x {summary['height']} px, {spec}",
        f"model     {summary['model']}" + (
            '  (no barrel-distortion root: w* = 0, mean perspective focal)'
            if not summary['root_found'] and summary['omega'] == 0 and len(summary['spec']) > 1 else ''),
        f"omega     {summary['omega']:.9g} (1/px)",
        f"f         {summary['f']:.4f} px",
        f"K         [[{K[0][0]:.4f}, 0, {K[0][2]:.2f}], [0, {K[1][1]:.4f}, {K[1][2]:.2f}], [0, 0, 1]]",
        f"D         {summary['distortion_model']} [{', '.join(f'{d:.9g}' for d in summary['D'])}]",
        f"fit error {summary['fit_error_px']:.2g} px (max over the image)",
        'FOV       ' + ', '.join(f"{k[0]} {'-' if summary[k] is None else format(summary[k], '.3f')}"
                                 for k in ('hfov', 'vfov', 'dfov')) + ' deg (predicted; - : no ray)',
    ]
    for name, res in summary['dfov_residuals'].items():
        lines.append(f"  dfov residual {name:13s} {res:+.3f} deg" + ('  <- chosen' if name == summary['model'] else ''))
    return '\n'.join(lines)
