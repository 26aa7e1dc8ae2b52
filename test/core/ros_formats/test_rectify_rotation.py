"""The rectification rotation R of a calibration is honoured as OpenCV (and so image_proc,
through image_geometry's initUndistortRectifyMap with K, D, R, P) honours it: the rectified
pixel (u, v) shows the raw camera's ray R^T P^-1 (u, v, 1). Checked against OpenCV's own maps
for a 5-degree stereo-like R, for equidistant and plumb_bob, in the core and via the CLI.
"""
import cv2
import numpy as np
import pytest

from zeroshot_calib_ros.cli import main
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.streaming.image_frames import ActiveCalibration

FIXED_TOLERANCE_PX = 1 / 64 + 1e-3
"""Fixed-point maps are 1/32 px cells: within half a cell per axis of OpenCV's float maps."""
FLOAT_TOLERANCE_PX = 2e-3
"""Float maps: float32 rounding of positions up to ~1300 px (1.2e-4 px) and of the model's own
evaluation; OpenCV's maps are float32 too."""


def rotation(degrees, axis):
    rvec = np.radians(degrees) * np.asarray(axis, float) / np.linalg.norm(axis)
    return cv2.Rodrigues(rvec)[0]


R5 = rotation(5.0, [0.2, 1.0, 0.1])  # a stereo rectification turns mostly about y

CALIBRATIONS = {
    'equidistant': dict(K=[[640.0, 0, 652.0], [0, 640.0, 355.0], [0, 0, 1]], distortion_model='equidistant',
                        D=[0.03, -0.01, 0.002, -0.0004]),
    'plumb_bob': dict(K=[[900.0, 0, 645.0], [0, 905.0, 362.0], [0, 0, 1]], distortion_model='plumb_bob',
                      D=[-0.12, 0.05, 0.0005, -0.0003, -0.01]),
}
P_RECT = np.array([[560.0, 0, 640.0, 0], [0, 560.0, 360.0, 0], [0, 0, 1, 0]])


def calibration(model, R=R5):
    c = CALIBRATIONS[model]
    return CameraCalibration(1280, 720, np.array(c['K']), c['distortion_model'], np.array(c['D']), R, P_RECT)


def opencv_maps(cal, P=None):
    """OpenCV's maps for the calibration (with another P when given)."""
    init = cv2.fisheye.initUndistortRectifyMap if cal.distortion_model == 'equidistant' \
        else cv2.initUndistortRectifyMap
    return init(cal.K, cal.D, cal.R, cal.P if P is None else P, (cal.width, cal.height), cv2.CV_32FC1)


def as_float(rectifier):
    if rectifier.map1.dtype == np.float32:
        return rectifier.map1, rectifier.map2, FLOAT_TOLERANCE_PX
    mx, my = cv2.convertMaps(rectifier.map1, rectifier.map2, cv2.CV_32FC1)
    return mx, my, FIXED_TOLERANCE_PX


@pytest.mark.parametrize('model', CALIBRATIONS)
def test_maps_of_a_rotated_calibration_are_opencvs(model):
    cal = calibration(model)
    _, rectifier = ActiveCalibration(cal, cal.camera(), 'test', rectify=True).for_size(1280, 720)
    ox, oy, tolerance = as_float(rectifier)
    mx, my = opencv_maps(cal)
    inside = (mx > 0) & (mx < 1279) & (my > 0) & (my < 719)
    assert inside.mean() > 0.4  # most of the rectified image sees the raw one
    assert np.abs(ox - mx)[inside].max() <= tolerance
    assert np.abs(oy - my)[inside].max() <= tolerance
    # and R matters: the identity's maps are tens of pixels away
    ix, iy = opencv_maps(calibration(model, np.eye(3)))
    assert np.median(np.hypot(ix - mx, iy - my)[inside]) > 20


def smooth_image(width=1280, height=720):
    """A low-frequency texture: interpolation in 1/32 px steps changes it by well under a grey level."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    value = 127 + 60 * np.sin(x / 37.0) * np.cos(y / 29.0) + 50 * np.sin((x + 2 * y) / 83.0)
    return np.clip(value, 0, 255).astype(np.uint8)


def rectified_by_cli(tmp_path, cal, *options):
    """(raw image, `zeroshot-calib rectify --calibration` of it as float) for ``cal`` saved to a file."""
    cal_path = tmp_path / 'cal.yaml'
    cal.save(str(cal_path))
    src, dst = tmp_path / 'raw.png', tmp_path / 'rect.png'
    image = smooth_image()
    cv2.imwrite(str(src), image)
    assert main(['rectify', str(src), '-o', str(dst), '--calibration', str(cal_path), *options]) == 0
    return image, cv2.imread(str(dst), cv2.IMREAD_UNCHANGED).astype(float)


@pytest.mark.parametrize('model', CALIBRATIONS)
def test_cli_rectify_with_a_rotated_calibration_is_opencvs(tmp_path, model):
    cal = calibration(model)
    image, ours = rectified_by_cli(tmp_path, cal)
    mx, my = opencv_maps(cal)
    reference = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT).astype(float)
    inside = (mx > 1) & (mx < 1278) & (my > 1) & (my < 718)
    # the texture's steepest slope is ~3.4 grey levels a pixel: 1/64 px moves it < 0.1; rounding 0.5
    assert np.abs(ours - reference)[inside].max() <= 2
    unrotated = cv2.remap(image, *opencv_maps(calibration(model, np.eye(3))), cv2.INTER_LINEAR).astype(float)
    assert np.abs(unrotated - reference)[inside].mean() > 10


@pytest.mark.parametrize('model', CALIBRATIONS)
def test_cli_rectify_with_a_rotated_calibration_and_a_chosen_p_keeps_r(tmp_path, model):
    """--balance / --fov-scale choose another P for a calibration file (its principal point the
    calibrated camera's own, as calibrate writes it); its R still applies (image_proc with that
    P would rotate the same way)."""
    from zeroshot_calib_ros.core.ros_formats.rectify import principal_point_camera_matrix
    cal = calibration(model)
    image, ours = rectified_by_cli(tmp_path, cal, '--balance', '0.3', '--fov-scale', '1.0')
    mx, my = opencv_maps(cal, P=principal_point_camera_matrix(cal.camera(), 0.3, 1.0))
    reference = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT).astype(float)
    inside = (mx > 1) & (mx < 1278) & (my > 1) & (my < 718)
    assert inside.mean() > 0.5
    assert np.abs(ours - reference)[inside].max() <= 2
