"""Rectification: OpenCV's meaning of balance / fov_scale, exact maps, straight lines."""
import cv2
import numpy as np
import pytest

from synthetic import find_corners, line_residuals, render_checkerboard
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.fitting import fit_kannala_brandt
from zeroshot_calib_ros.core.rectify import Rectifier, new_camera_matrix

HERO9_W1 = CameraSpec(1920, 1080, 118, 69)


@pytest.mark.parametrize('balance, fov_scale', [(0.0, 1.0), (1.0, 1.0), (0.5, 1.3), (0.2, 0.8)])
def test_new_camera_matrix_means_what_opencv_means(balance, fov_scale):
    solution = solve_zero_shot(HERO9_W1)
    D = fit_kannala_brandt(solution.camera).D
    ours = new_camera_matrix(solution.camera, balance, fov_scale)
    theirs = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
        solution.K, D, (1920, 1080), np.eye(3), balance=balance, fov_scale=fov_scale)
    assert np.abs(ours - theirs).max() < 1e-3


def test_balance_and_fov_scale_are_checked():
    camera = solve_zero_shot(HERO9_W1).camera
    with pytest.raises(ValueError, match='balance = 1.5 is invalid: allowed: 0 to 1'):
        new_camera_matrix(camera, 1.5)
    with pytest.raises(ValueError, match='fov_scale = 0.0 is invalid'):
        new_camera_matrix(camera, 0.0, 0.0)


def test_maps_agree_with_opencv_fisheye_maps_to_fixed_point_precision():
    solution = solve_zero_shot(HERO9_W1)
    D = fit_kannala_brandt(solution.camera).D
    rectifier = Rectifier(solution.camera, balance=0.5)
    assert rectifier.map1.dtype == np.int16 and rectifier.map1.shape == (1080, 1920, 2)
    mx, my = cv2.fisheye.initUndistortRectifyMap(solution.K, D, np.eye(3), rectifier.P, (1920, 1080),
                                                 cv2.CV_32FC1)
    ox, oy = cv2.convertMaps(rectifier.map1, rectifier.map2, cv2.CV_32FC1)
    inside = (mx > 0) & (mx < 1919) & (my > 0) & (my < 1079)
    assert inside.mean() > 0.9
    # 1/32 px fixed-point cells: rounding moves a point by at most half a cell per axis.
    assert np.abs(ox - mx)[inside].max() <= 1 / 64 + 1e-3
    assert np.abs(oy - my)[inside].max() <= 1 / 64 + 1e-3


def test_rectified_image_has_straight_lines():
    """A planar checkerboard rendered through the exact model: rectified, its rows and columns
    are straight and its corners sit where the new pinhole camera P puts them."""
    camera = solve_zero_shot(CameraSpec(960, 540, 118, 69)).camera
    image, plane_points = render_checkerboard(camera)
    raw = find_corners(image)
    assert raw is not None
    rectifier = Rectifier(camera, balance=1.0)
    rectified = rectifier.rectify(image, out=np.empty_like(image))
    corners = find_corners(rectified)
    assert corners is not None
    residual = line_residuals(corners)
    assert np.sqrt(np.mean(residual ** 2)) < 0.1 and residual.max() < 0.3  # measured 0.053 / 0.19
    expected = plane_points * rectifier.P[0, 0] + rectifier.P[:2, 2]
    assert np.sqrt(np.mean(np.sum((corners - expected) ** 2, axis=-1))) < 0.25  # measured 0.14
    assert line_residuals(raw).max() > 5  # the fisheye image bends them (measured 17.7)


def test_rectify_rejects_a_wrong_size_and_writes_in_place():
    camera = solve_zero_shot(CameraSpec(640, 360, 118, 69)).camera
    rectifier = Rectifier(camera)
    with pytest.raises(ValueError, match='640x360'):
        rectifier.rectify(np.zeros((100, 100), np.uint8))
    out = np.empty((360, 640, 3), np.uint8)
    result = rectifier.rectify(np.full((360, 640, 3), 7, np.uint8), out=out)
    assert result is out or np.shares_memory(result, out)
    assert out[180, 320].tolist() == [7, 7, 7]


@pytest.mark.parametrize('interpolation', [5, -1])
def test_interpolation_is_checked(interpolation):
    camera = solve_zero_shot(CameraSpec(64, 36, 118, 69)).camera
    with pytest.raises(ValueError, match='interpolation'):
        Rectifier(camera, interpolation=interpolation)
