"""Calibration files: camera_calibration_parsers layout, round trips, URLs, the zero-D rule."""
import os

import numpy as np
import pytest
import yaml

from zeroshot_calib_ros.core import CameraSpec, KannalaBrandtCamera, solve_zero_shot
from zeroshot_calib_ros.core.calibration_file import (CalibrationFileError, CameraCalibration,
                                                      resolve_camera_info_url)

KEYS = ['image_width', 'image_height', 'camera_name', 'camera_matrix', 'distortion_model',
        'distortion_coefficients', 'rectification_matrix', 'projection_matrix']


def test_yaml_has_camera_calibration_parsers_layout_and_round_trips(tmp_path):
    solution = solve_zero_shot(CameraSpec(1920, 1080, 118, 69))
    calibration, fit = CameraCalibration.from_solution(solution, camera_name='hero9')
    path = tmp_path / 'hero9.yaml'
    calibration.save(str(path))
    data = yaml.safe_load(path.read_text())
    assert list(data) == KEYS
    assert data['distortion_model'] == 'equidistant'
    assert data['camera_matrix'] == {'rows': 3, 'cols': 3, 'data': solution.K.ravel().tolist()}
    assert data['distortion_coefficients']['cols'] == 4
    assert data['projection_matrix']['rows'] == 3 and data['projection_matrix']['cols'] == 4
    loaded = CameraCalibration.load(str(path))
    for name in ('K', 'D', 'R', 'P'):
        assert np.array_equal(getattr(loaded, name), getattr(calibration, name))
    assert isinstance(loaded.camera(), KannalaBrandtCamera)
    assert not [p for p in os.listdir(tmp_path) if '.tmp' in p]


def test_all_zero_fit_of_a_distorting_lens_keeps_downstream_rectifying():
    """An exact equidistant lens (w f = 1) fits k1..k4 = 0, which image_proc would read as
    'no distortion'; the record carries a 1e-20 instead."""
    solution = solve_zero_shot(CameraSpec(1280, 720, 90, 60))
    camera = solution.camera
    camera.omega = 1.0 / camera.f  # make it the pure r = f theta law
    calibration, fit = CameraCalibration.from_solution(solution)
    assert np.all(np.abs(fit.D) < 1e-12)
    assert np.any(calibration.D != 0) and np.abs(calibration.D).max() <= 1e-20


def test_undistorted_pinhole_keeps_zero_plumb_bob():
    solution = solve_zero_shot(CameraSpec(1280, 720, hfov=63.1))
    calibration, _ = CameraCalibration.from_solution(solution, 'plumb_bob')
    assert calibration.D.tolist() == [0.0] * 5


@pytest.mark.parametrize('text, match', [
    ('image_width: 10\n', 'not a camera calibration file'),
    ('- 1\n- 2\n', 'not a camera calibration file'),
    ('{{{', 'cannot read'),
])
def test_bad_files_are_reported(tmp_path, text, match):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(CalibrationFileError, match=match):
        CameraCalibration.load(str(path))


def test_non_finite_or_unknown_model_is_refused():
    with pytest.raises(CalibrationFileError, match='finite'):
        CameraCalibration(640, 480, np.diag([500, 500, 1.0]), 'plumb_bob', [np.nan, 0, 0, 0, 0])
    with pytest.raises(CalibrationFileError, match="distortion_model = 'fancy'"):
        CameraCalibration(640, 480, np.diag([500, 500, 1.0]), 'fancy', [0, 0, 0, 0, 0])


def test_camera_info_urls(tmp_path, monkeypatch):
    assert resolve_camera_info_url('') is None
    assert resolve_camera_info_url('file:///tmp/${NAME}.yaml', 'front') == '/tmp/front.yaml'
    assert resolve_camera_info_url('/a/b.yaml') == '/a/b.yaml'
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages').mkdir(parents=True)
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'mypkg').touch()
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    assert resolve_camera_info_url('package://mypkg/calib/cam.yaml') == str(tmp_path / 'share/mypkg/calib/cam.yaml')
    with pytest.raises(CalibrationFileError, match='package .nopkg. not found'):
        resolve_camera_info_url('package://nopkg/x.yaml')
    with pytest.raises(CalibrationFileError, match='allowed: file://'):
        resolve_camera_info_url('http://example.com/x.yaml')


def test_scaled_calibration_scales_intrinsics_only():
    solution = solve_zero_shot(CameraSpec(1920, 1080, 118, 69))
    calibration, _ = CameraCalibration.from_solution(solution)
    half = calibration.scaled(960, 540)
    assert half.K[0, 0] == pytest.approx(calibration.K[0, 0] / 2)
    assert half.K[:2, 2].tolist() == [480, 270]
    assert np.array_equal(half.D, calibration.D)
    assert half.P[0, 0] == pytest.approx(calibration.P[0, 0] / 2)
