"""Physically absurd calibrations are refused, with the field and its allowed range, wherever a
calibration comes from (CameraCalibration: files, the CLI, the node's set_camera_info); every
calibration the project ships, tests with, or solves from a preset still loads."""
import glob
from pathlib import Path

import numpy as np
import pytest

from zeroshot_calib_ros.cli import main
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import (DISTORTION_MODELS, CalibrationFileError,
                                                               CameraCalibration)
from zeroshot_calib_ros.core.zeroshot.presets import get_preset, load_presets

REPO = Path(__file__).resolve().parents[3]
K = [[880.0, 0.0, 955.0], [0.0, 880.0, 545.0], [0.0, 0.0, 1.0]]
D = [0.05, -0.004, -0.001, 0.0002]
P = [[700.0, 0.0, 955.0, 0.0], [0.0, 700.0, 545.0, 0.0], [0.0, 0.0, 1.0, 0.0]]


def record(K=K, D=D, R=np.eye(3), P=P, model='equidistant'):
    return dict(width=1920, height=1080, K=np.array(K, float), distortion_model=model, D=np.array(D, float),
                R=np.array(R, float), P=np.array(P, float))


def with_entry(matrix, i, j, value):
    m = np.array(matrix, float)
    m[i, j] = value
    return m


ABSURD = {
    'fx 1e-300': (record(K=with_entry(K, 0, 0, 1e-300)), ['K (camera_matrix) fx', '10.8 to 1.92e+08']),
    'fx 1e300': (record(K=with_entry(K, 0, 0, 1e300)), ['K (camera_matrix) fx', '10.8 to 1.92e+08']),
    'fy 1e300': (record(K=with_entry(K, 1, 1, 1e300)), ['K (camera_matrix) fy', '10.8 to 1.92e+08']),
    'D 1e300': (record(D=[0.05, 1e300, 0.0, 0.0]), ['D (distortion_coefficients) [1]', 'allowed: -', 'rho = ']),
    'skew 1e9': (record(K=with_entry(K, 0, 1, 1e9)), ['K (camera_matrix) skew', 'at most 0.1 x fx']),
    'skew -1e9': (record(K=with_entry(K, 0, 1, -1e9)), ['K (camera_matrix) skew', 'in magnitude']),
    # the principal point near the top-left corner: D is bounded at the FARTHEST corner (1920x1080,
    # rho 2.35: k4 at most 1e6 / rho^8 = 1.08e3), not at the nearest (rho 0.16, which allows ~2e12)
    'D k4 1e4, cx, cy 100': (record(K=[[880.0, 0.0, 100.0], [0.0, 880.0, 100.0], [0.0, 0.0, 1.0]],
                                    D=[0.0, 0.0, 0.0, 1e4]),
                             ['D (distortion_coefficients) [3]', 'allowed: -1.08e+03', 'rho = 2.35']),
    'cx 1e12': (record(K=with_entry(K, 0, 2, 1e12)), ['K (camera_matrix) cx', '-1920 to 3840']),
    'cy -2e3': (record(K=with_entry(K, 1, 2, -2e3)), ['K (camera_matrix) cy', '-1080 to 2160']),
    'R 5 I': (record(R=5 * np.eye(3)), ['R (rectification_matrix)', 'a rotation', 'det(R) = +1']),
    'R a reflection': (record(R=np.diag([1.0, 1.0, -1.0])), ['R (rectification_matrix)', 'a rotation']),
    'P fx 1e300': (record(P=with_entry(P, 0, 0, 1e300)), ['P (projection_matrix) fx', '10.8 to 1.92e+08']),
    'P cx 1e12': (record(P=with_entry(P, 0, 2, 1e12)), ['P (projection_matrix) cx', '-1920 to 3840']),
    'P skew 1e9': (record(P=with_entry(P, 0, 1, 1e9)), ['P (projection_matrix) skew']),
}


@pytest.mark.parametrize('case', ABSURD)
def test_absurd_calibrations_are_refused_naming_the_field_and_range(case):
    fields, words = ABSURD[case]
    with pytest.raises(CalibrationFileError) as info:
        CameraCalibration(**fields)
    message = str(info.value)
    assert '\n' not in message and 'allowed' in message
    assert all(w in message for w in words), message


def test_a_rotation_rounded_as_cameracalibrator_writes_it_and_a_stereo_R_are_accepted():
    import cv2
    R = cv2.Rodrigues(np.radians([1.0, 5.0, 0.5]))[0]
    CameraCalibration(**record(R=np.round(R, 6)))
    CameraCalibration(**record(R=R, model='plumb_bob', D=[-0.1, 0.05, 0.001, 0.0, -0.01]))


def calibration_files():
    found = sorted(glob.glob(str(REPO / 'config' / '*.yaml')) + glob.glob(str(REPO / 'test' / 'data' / '**' / '*.yaml'),
                                                                          recursive=True))
    shared = REPO.parent / 'shared' / 'data'
    for root in (shared, Path('/work/shared/data')):
        found += sorted(glob.glob(str(root / '**' / '*.yaml'), recursive=True) +
                        glob.glob(str(root / '**' / '*.ini'), recursive=True))
    return [f for f in found if 'image_width' in Path(f).read_text(errors='replace') or f.endswith('.ini')]


def test_every_calibration_file_of_the_project_still_loads():
    files = calibration_files()
    for path in files:
        CameraCalibration.load(path)
    print(f'{len(files)} calibration files load: {files}')


def test_every_preset_solves_to_a_valid_record_of_every_model():
    specs = [get_preset(name) for name in load_presets()]
    specs += [CameraSpec(1920, 1080, hfov, None) for hfov in (0.05, 3, 60, 250, 359.9)]
    specs += [CameraSpec(100000, 1, 359.9, None), CameraSpec(3, 8, 359.9, None)]
    for spec in specs:
        solution = solve_zero_shot(spec)
        for model in DISTORTION_MODELS:
            CameraCalibration.from_solution(solution, model)


def test_cli_refuses_an_absurd_calibration_file_in_one_line(tmp_path, capsys):
    path = tmp_path / 'bad.yaml'
    good = CameraCalibration(**record())
    path.write_text(good.to_yaml().replace('data: [880.0', 'data: [1e+300', 1))
    assert 'data: [1e+300' in path.read_text()
    image = tmp_path / 'img.png'
    import cv2
    cv2.imwrite(str(image), np.zeros((1080, 1920), np.uint8))
    status = main(['rectify', str(image), '-o', str(tmp_path / 'out.png'), '--calibration', str(path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert 'fx' in err[0] and '10.8 to 1.92e+08' in err[0] and 'Traceback' not in err[0]
