"""CameraInfoModel: C++ image_geometry's PinholeCameraModel without ROS, checked against cv2.

References are built independently of the class: raw / rectified pixel pairs come from rays
projected with cv2.projectPoints / cv2.fisheye.projectPoints and with P, binned / ROI'd K and P
are written out by hand as fromCameraInfo computes them, and maps come straight from
cv2.(fisheye.)initUndistortRectifyMap.
"""
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.ros_formats.camera_info_model import POINT_CRITERIA, CameraInfoModel
from zeroshot_calib_ros.core.lens.models import camera_from_calibration
from zeroshot_calib_ros.core.ros_formats.rectify import Rectifier, rectification_maps

W, H = 1280, 720
K_PIN = np.array([[800.0, 0.0, 652.3], [0.0, 795.0, 361.7], [0.0, 0.0, 1.0]])
DISTORTIONS = {
    'plumb_bob': [-0.3, 0.12, 0.001, -0.0005, -0.02],
    'rational_polynomial': [0.4, -0.1, 0.0008, -0.0004, 0.01, 0.7, -0.05, 0.03],
    'equidistant': [0.05, -0.01, 0.002, -0.0003],
}
R_STEREO, _ = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))
P_NEW = np.array([[700.0, 0.0, 640.0, 0.0], [0.0, 700.0, 360.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
TOL_PX = 1e-6


def camera_info(model='plumb_bob', D=None, K=K_PIN, R=R_STEREO, P=P_NEW, width=W, height=H,
                binning=(0, 0), roi=(0, 0, 0, 0), do_rectify=False):
    """A duck-typed sensor_msgs/CameraInfo (flat k, d, r, p as rclpy has them)."""
    D = DISTORTIONS[model] if D is None else D
    return SimpleNamespace(
        header=SimpleNamespace(frame_id='camera_optical'), width=width, height=height,
        distortion_model=model, d=list(D), k=np.asarray(K, float).ravel(),
        r=np.asarray(R, float).ravel(), p=np.asarray(P, float).ravel(),
        binning_x=binning[0], binning_y=binning[1],
        roi=SimpleNamespace(x_offset=roi[0], y_offset=roi[1], width=roi[2], height=roi[3],
                            do_rectify=do_rectify))


def project_raw(model, K, D, rays_cam):
    """Raw pixels of camera-frame rays: cv2's own forward model, the reference."""
    obj = np.ascontiguousarray(rays_cam, float).reshape(-1, 1, 3)
    if model == 'equidistant':
        px, _ = cv2.fisheye.projectPoints(obj, np.zeros(3), np.zeros(3), K, np.asarray(D, float))
    else:
        px, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), K, np.asarray(D, float))
    return px.reshape(-1, 2)


def reference_pairs(model, K, D, R, P, size, n=4000, seed=0):
    """(raw, rect) pixel pairs: random rectified pixels, their rays through P^-1, into the
    camera frame by R^T, then through cv2's distortion; only pairs seen inside the raw image."""
    rng = np.random.default_rng(seed)
    rect = rng.uniform([0, 0], size, (n, 2))
    rays_rect = np.c_[rect, np.ones(n)] @ np.linalg.inv(P[:3, :3]).T
    raw = project_raw(model, K, D, rays_rect @ R)  # (R^T r)^T = r^T R
    inside = np.all((raw >= 0) & (raw <= np.array(size) - 1), axis=1)
    return raw[inside], rect[inside]


def solve_hero9():
    return CameraCalibration.from_solution(solve_zero_shot(CameraSpec(1920, 1080, hfov=118, vfov=69)))[0]


@pytest.fixture(scope='module')
def hero9():
    return solve_hero9()


# -- points against cv2 -----------------------------------------------------------------

@pytest.mark.parametrize('model', sorted(DISTORTIONS))
def test_rectify_and_unrectify_points_match_cv2_to_1e6_px(model):
    cam = CameraInfoModel(camera_info(model))
    raw, rect = reference_pairs(model, K_PIN, DISTORTIONS[model], R_STEREO, P_NEW, (W, H))
    assert len(raw) > 2000
    err_rect = np.abs(cam.rectify_points(raw) - rect).max()
    err_unrect = np.abs(cam.unrectify_points(rect) - raw).max()
    print(f'{model}: rectify_points max error {err_rect:.2e} px, unrectify_points {err_unrect:.2e} px '
          f'({len(raw)} points)')
    assert err_rect <= TOL_PX and err_unrect <= TOL_PX
    assert np.abs(cam.rectify_point(raw[0]) - rect[0]).max() <= TOL_PX
    assert np.abs(cam.unrectify_point(rect[0]) - raw[0]).max() <= TOL_PX
    assert cam.rectify_point(raw[0]).shape == (2,)


@pytest.mark.parametrize('model', sorted(DISTORTIONS))
def test_point_criteria_none_is_the_cpp_call_with_opencvs_default_iterations(model):
    """point_criteria=None is exactly cv::(fisheye::)undistortPoints(src, dst, K, D, R, P)."""
    cam = CameraInfoModel(camera_info(model), point_criteria=None)
    raw, rect = reference_pairs(model, K_PIN, DISTORTIONS[model], R_STEREO, P_NEW, (W, H))
    D = np.asarray(DISTORTIONS[model])
    undistort = cv2.fisheye.undistortPoints if model == 'equidistant' else cv2.undistortPoints
    cpp = undistort(raw.reshape(-1, 1, 2), K_PIN, D, R=R_STEREO, P=P_NEW).reshape(-1, 2)
    assert np.array_equal(cam.rectify_points(raw), cpp)
    err_cpp = np.abs(cpp - rect).max()
    print(f'{model}: OpenCV default iterations (C++ image_geometry) max error {err_cpp:.2e} px')
    if model != 'equidistant':  # 5 fixed-point iterations: visibly off at the corners
        assert err_cpp > 1e-2


def test_project_3d_to_pixel_and_pixel_to_ray_match_cv2_with_stereo_baseline():
    """A right stereo camera (Tx = -fx B): u = (fx x + Tx) / z + cx, the ray has z = 1."""
    P = P_NEW.copy()
    P[0, 3] = -700.0 * 0.12
    P[1, 3] = 3.5
    cam = CameraInfoModel(camera_info('plumb_bob', P=P))
    rng = np.random.default_rng(3)
    xyz = np.c_[rng.uniform(-2, 2, (1000, 2)), rng.uniform(0.5, 20, 1000)]
    t = np.array([P[0, 3] / P[0, 0], P[1, 3] / P[1, 1], 0.0])
    ref, _ = cv2.projectPoints(xyz.reshape(-1, 1, 3), np.zeros(3), t, P[:3, :3], None)
    err_proj = np.abs(cam.project_3d_to_pixel(xyz) - ref.reshape(-1, 2)).max()

    uv = rng.uniform([0, 0], [W, H], (1000, 2))
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), P[:3, :3], None).reshape(-1, 2) - t[:2]
    rays = cam.project_pixel_to_3d_ray(uv)
    err_ray_px = np.abs((rays[:, :2] - xy) * [P[0, 0], P[1, 1]]).max()
    print(f'project_3d_to_pixel max error {err_proj:.2e} px, project_pixel_to_3d_ray {err_ray_px:.2e} px')
    assert err_proj <= TOL_PX and err_ray_px <= TOL_PX
    assert np.all(rays[:, 2] == 1.0)
    unit = cam.project_pixel_to_3d_ray(uv, normalize=True)
    assert np.allclose(np.linalg.norm(unit, axis=1), 1.0)
    assert np.allclose(unit / unit[:, 2:], rays)
    # Rays of z = 1 project back to their pixel: only there does C++ subtract Tx consistently.
    assert np.abs(cam.project_3d_to_pixel(rays) - uv).max() <= TOL_PX
    assert cam.project_3d_to_pixel(xyz[0]).shape == (2,)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.Tx, cam.Ty) == (700.0, 700.0, 640.0, 360.0, P[0, 3], 3.5)


def test_hero9_equidistant_points_and_the_python_image_geometry_error(hero9):
    """Our calibration: exact against cv2.fisheye; read as plumb_bob (what Python image_geometry
    does) the same points are off by tens to hundreds of pixels."""
    cam = CameraInfoModel.from_calibration(hero9.to_dict())
    raw, rect = reference_pairs('equidistant', hero9.K, hero9.D, hero9.R, hero9.P, (1920, 1080), seed=9)
    err_rect = np.abs(cam.rectify_points(raw) - rect).max()
    err_unrect = np.abs(cam.unrectify_points(rect) - raw).max()
    as_plumb_bob = cv2.undistortPoints(raw.reshape(-1, 1, 2), hero9.K, hero9.D, R=hero9.R,
                                       P=hero9.P).reshape(-1, 2)
    wrong = np.linalg.norm(as_plumb_bob - rect, axis=1)
    print(f'HERO9 equidistant: rectify max error {err_rect:.2e} px, unrectify {err_unrect:.2e} px; '
          f'read as plumb_bob: median {np.median(wrong):.1f} px, max {wrong.max():.1f} px')
    assert err_rect <= TOL_PX and err_unrect <= TOL_PX
    assert np.median(wrong) > 10.0


# -- binning and ROI ------------------------------------------------------------------------

BINNING, ROI = (2, 2), (320, 180, 1280, 720)  # the central 1280 x 720 of 1920 x 1080, binned 2x


def hand_reduced(K, P, x_offset, y_offset, bx, by):
    """K_ and P_ as fromCameraInfo writes them: shift by the ROI offset, then scale by 1 / binning."""
    K, P = np.array(K, float), np.array(P, float)
    K[0, 2] -= x_offset
    K[1, 2] -= y_offset
    P[0, 2] -= x_offset
    P[1, 2] -= y_offset
    K[0, 0] /= bx
    K[0, 2] /= bx
    K[1, 1] /= by
    K[1, 2] /= by
    P[0, 0] /= bx
    P[0, 2] /= bx
    P[0, 3] /= bx
    P[1, 1] /= by
    P[1, 2] /= by
    P[1, 3] /= by
    return K, P


@pytest.mark.parametrize('model', ['equidistant', 'plumb_bob'])
def test_binning_and_roi_give_image_geometrys_K_P_points_and_maps(hero9, model):
    if model == 'equidistant':
        K, D, R, P = hero9.K, hero9.D, hero9.R, hero9.P.copy()
    else:
        K, D, R = hero9.K, np.array([-0.2, 0.05, 0.0005, -0.0003, -0.005]), R_STEREO
        P = np.hstack([K * [[0.9], [0.9], [1]], np.zeros((3, 1))])
    P_tx = P.copy()
    P_tx[0, 3], P_tx[1, 3] = -20.0, 6.0  # Tx, Ty: scaled by the binning too
    cam_tx = CameraInfoModel(camera_info(model, D=D, K=K, R=R, P=P_tx, width=1920, height=1080,
                                         binning=BINNING, roi=ROI))
    K_tx, P_tx_ = hand_reduced(K, P_tx, ROI[0], ROI[1], *BINNING)
    assert np.array_equal(cam_tx.K, K_tx) and np.array_equal(cam_tx.P, P_tx_)
    assert np.array_equal(cam_tx.full_K, K) and np.array_equal(cam_tx.full_P, P_tx)
    assert (cam_tx.fx, cam_tx.cx, cam_tx.Tx, cam_tx.Ty) == (P_tx_[0, 0], P_tx_[0, 2], -10.0, 3.0)

    # Tx = 0 from here: rectifyPoint ignores Tx while unrectifyPoint subtracts it (module docstring).
    cam = CameraInfoModel(camera_info(model, D=D, K=K, R=R, P=P, width=1920, height=1080,
                                      binning=BINNING, roi=ROI))
    K_, P_ = hand_reduced(K, P, ROI[0], ROI[1], *BINNING)
    assert np.array_equal(cam.K, K_) and np.array_equal(cam.P, P_)
    assert cam.full_resolution == (1920, 1080)
    assert cam.raw_image_size == cam.reduced_resolution == (640, 360)
    assert cam.raw_roi == cam.rectified_roi == ROI

    # Points of the reduced image: the cv2 calls C++ rectifyPoint / unrectifyPoint make with K_, P_.
    raw, rect = reference_pairs(model, K_, D, R, P_, (640, 360), seed=4)
    assert len(raw) > 1000
    err = max(np.abs(cam.rectify_points(raw) - rect).max(), np.abs(cam.unrectify_points(rect) - raw).max())
    print(f'{model} binning 2 + roi: max point error {err:.2e} px')
    assert err <= TOL_PX

    # Maps: the full binned map, cropped to the binned ROI, integer part shifted.
    init = cv2.fisheye.initUndistortRectifyMap if model == 'equidistant' else cv2.initUndistortRectifyMap
    K_b, P_b = hand_reduced(K, P, 0, 0, *BINNING)
    full1, full2 = init(K_b, D, R, P_b, (960, 540), cv2.CV_16SC2)
    x, y = ROI[0] // 2, ROI[1] // 2
    ref1 = full1[y:y + 360, x:x + 640] - np.array([x, y], np.int16)
    ref2 = full2[y:y + 360, x:x + 640]
    map1, map2 = cam.rectification_maps()
    assert np.array_equal(map1, ref1) and np.array_equal(map2, ref2)
    assert all(np.array_equal(a, b) for a, b in zip(cam.rectification_maps(full=True), (full1, full2)))

    rng = np.random.default_rng(5)
    raw_img = rng.integers(0, 256, (360, 640, 3), dtype=np.uint8)
    assert np.array_equal(cam.rectify_image(raw_img), cv2.remap(raw_img, ref1, ref2, cv2.INTER_LINEAR))

    # The maps and the points describe the same camera: map each rectified pixel to raw, rectify it back.
    mx, my = cv2.convertMaps(map1, map2, cv2.CV_32FC1)
    grid = np.stack(np.meshgrid(np.arange(0, 640, 7.0), np.arange(0, 360, 7.0)), -1).reshape(-1, 2)
    col, row = grid[:, 0].astype(int), grid[:, 1].astype(int)
    src = np.c_[mx[row, col], my[row, col]]
    seen = np.all((src >= 0) & (src <= [639, 359]), axis=1)
    back = cam.rectify_points(src[seen])
    assert np.abs(back - grid[seen]).max() < 0.1  # the maps' 1/32 px fixed point, magnified by P / K

    # Full <-> reduced pixel coordinates.
    uv = np.array([[10.0, 20.0], [639.0, 359.0]])
    assert np.array_equal(cam.to_full_resolution(uv), uv * 2 + [ROI[0], ROI[1]])
    assert np.array_equal(cam.to_reduced_resolution(cam.to_full_resolution(uv)), uv)


def test_do_rectify_roi_is_the_inward_box_of_the_rectified_corners(hero9):
    cam = CameraInfoModel(camera_info('equidistant', D=hero9.D, K=hero9.K, R=hero9.R, P=hero9.P,
                                      width=1920, height=1080, binning=BINNING, roi=ROI, do_rectify=True))
    x, y, w, h = ROI
    corners = np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], float)
    tl, tr, br, bl = cv2.fisheye.undistortPoints(corners.reshape(-1, 1, 2), hero9.K, hero9.D, R=hero9.R,
                                                 P=hero9.P, criteria=POINT_CRITERIA).reshape(-1, 2)
    left, top = int(np.ceil(min(tl[0], bl[0]))), int(np.ceil(min(tl[1], tr[1])))
    right, bottom = int(np.floor(max(tr[0], br[0]))), int(np.floor(max(bl[1], br[1])))
    assert cam.rectified_roi == (left, top, right - left, bottom - top)
    assert cam.reduced_resolution == ((right - left) // 2, (bottom - top) // 2)
    assert cam.raw_image_size == (640, 360)  # the maps still crop the raw ROI, as in C++


# -- images -----------------------------------------------------------------------------------

@pytest.mark.parametrize('model', sorted(DISTORTIONS))
def test_rectify_image_is_cv2_remap_with_cv2_maps(model):
    cam = CameraInfoModel(camera_info(model))
    D = np.asarray(DISTORTIONS[model])
    init = cv2.fisheye.initUndistortRectifyMap if model == 'equidistant' else cv2.initUndistortRectifyMap
    map1, map2 = init(K_PIN, D, R_STEREO, P_NEW, (W, H), cv2.CV_16SC2)
    rng = np.random.default_rng(6)
    noise = rng.integers(0, 256, (H, W), dtype=np.uint8)
    for interpolation in (cv2.INTER_LINEAR, cv2.INTER_CUBIC, cv2.INTER_NEAREST):
        ours = cam.rectify_image(noise, interpolation)
        assert np.array_equal(ours, cv2.remap(noise, map1, map2, interpolation))
    assert np.std(ours) > 50  # textured, not a uniform image
    as_float = cam.rectify_image(noise.astype(np.float32))
    ref = cv2.remap(noise.astype(np.float32), map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=float('nan'))
    assert np.array_equal(np.isnan(as_float), np.isnan(ref)) and np.isnan(as_float).any()
    assert np.array_equal(as_float[~np.isnan(as_float)], ref[~np.isnan(ref)])


def test_rectify_image_against_our_rectifier_for_the_hero9_calibration(hero9):
    """Our Rectifier (image_rect of our node) computes maps from the exact Kannala-Brandt model,
    cv2.fisheye inverts the same polynomial. Our exact (float) maps lie within half a 1/32 px
    fixed-point step of image_geometry's; where the rectifier remaps with fixed-point maps
    (OpenCV before 4.11) both round, so they differ by one step where the exact value lies near
    a boundary; with float maps (OpenCV 4.11 and later) by less than half a step everywhere."""
    cam = CameraInfoModel.from_calibration(hero9)
    rectifier = Rectifier(camera_from_calibration(hero9.distortion_model, hero9.K, hero9.D, 1920, 1080),
                          P=hero9.P[:3, :3])
    ours = cv2.convertMaps(*cam.rectification_maps(), cv2.CV_32FC1)
    exact = rectification_maps(rectifier.camera, rectifier.P, rectifier.size, map_format='float')
    # exact (float) maps: within half a fixed-point step of image_geometry's everywhere
    exact_diff = np.maximum(np.abs(ours[0] - exact[0]), np.abs(ours[1] - exact[1]))
    assert exact_diff.max() <= 1 / 64 + 1e-4
    fixed = rectifier.map_format == 'fixed'
    # what frames are remapped with
    theirs = cv2.convertMaps(rectifier.map1, rectifier.map2, cv2.CV_32FC1) if fixed else (rectifier.map1, rectifier.map2)
    map_diff = np.maximum(np.abs(ours[0] - theirs[0]), np.abs(ours[1] - theirs[1]))
    rng = np.random.default_rng(7)
    noise = rng.integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    smooth = cv2.GaussianBlur(noise, (0, 0), 2.0)
    diff_noise = np.abs(cam.rectify_image(noise).astype(int) - rectifier.rectify(noise))
    diff_smooth = np.abs(cam.rectify_image(smooth).astype(int) - rectifier.rectify(smooth))
    print(f'HERO9 maps vs Rectifier: max {map_diff.max():.5f} px on {100 * (map_diff > 0).mean():.2f}% '
          f'of pixels; image max difference: noise {diff_noise.max()}, blurred noise {diff_smooth.max()} '
          f'(of 255; {100 * (diff_noise > 0).mean():.2f}% of noise pixels differ)')
    if fixed:
        assert map_diff.max() <= 1 / 32 + 1e-6 and (map_diff > 0).mean() < 0.01
        # One 1/32 px step in x and y moves a bilinear sample by at most 2 * 255 / 32, + 1 for rounding.
        assert diff_noise.max() <= 2 * 255 // 32 + 1 and (diff_noise > 0).mean() < 0.01
    else:
        assert np.array_equal(theirs[0], exact[0]) and np.array_equal(theirs[1], exact[1])
        # half a 1/32 px step in x and y: at most 2 * 255 / 64, + 1 for rounding
        assert diff_noise.max() <= 2 * 255 // 64 + 1
    assert diff_smooth.max() <= 2


def test_all_zero_or_empty_d_means_no_distortion_as_in_cpp():
    for D in ([0.0] * 5, []):
        cam = CameraInfoModel(camera_info('plumb_bob', D=D))
        uv = np.array([[10.0, 20.0], [700.5, 300.25]])
        assert not cam.has_distortion
        assert np.array_equal(cam.rectify_points(uv), uv) and np.array_equal(cam.unrectify_points(uv), uv)
        image = np.arange(W * H, dtype=np.uint32).reshape(H, W).astype(np.uint8)
        out = cam.rectify_image(image)
        assert np.array_equal(out, image) and out is not image
        assert cam.rectification_maps() is None
    # Equidistant too, although zero coefficients still mean r = f theta (see the module docstring).
    assert not CameraInfoModel(camera_info('equidistant', D=[0.0] * 4)).has_distortion


# -- construction and errors ------------------------------------------------------------------

def test_calibration_file_dict_yaml_and_message_give_the_same_model(hero9, tmp_path):
    path = tmp_path / 'hero9.yaml'
    hero9.save(str(path))
    from_msg = CameraInfoModel(camera_info('equidistant', D=hero9.D, K=hero9.K, R=hero9.R, P=hero9.P,
                                           width=1920, height=1080))
    for cam in (CameraInfoModel.from_calibration(str(path)), CameraInfoModel.from_calibration(path),
                CameraInfoModel.from_calibration(hero9.to_dict()), CameraInfoModel.from_calibration(hero9)):
        assert cam.distortion_model == 'equidistant' and cam.camera_name == 'camera'
        for name in ('K', 'D', 'R', 'P'):
            assert np.allclose(getattr(cam, name), getattr(from_msg, name), rtol=1e-15, atol=0), name
    roi = {'x_offset': 320, 'y_offset': 180, 'width': 1280, 'height': 720}
    binned = CameraInfoModel.from_calibration(hero9, binning_x=2, binning_y=2, roi=roi)
    assert np.array_equal(binned.K, hand_reduced(hero9.K, hero9.P, 320, 180, 2, 2)[0])
    assert from_msg.tf_frame == 'camera_optical'


def test_update_reports_changes_and_drops_cached_maps():
    info = camera_info('equidistant')
    cam = CameraInfoModel(info)
    maps = cam.rectification_maps()
    assert cam.update(info) is False and cam.rectification_maps() is maps
    changed = camera_info('equidistant', binning=(2, 2))
    assert cam.update(changed) is True and cam.rectification_maps()[0].shape == (H // 2, W // 2, 2)


@pytest.mark.parametrize('change, message', [
    (dict(model='fisheye', D=[0.1, 0, 0, 0]),
     "distortion_model = 'fisheye' is invalid: allowed: plumb_bob, rational_polynomial, equidistant"),
    (dict(model='equidistant', D=[0.1, 0, 0, 0, 0]),
     r"d has 5 values for distortion_model 'equidistant': allowed: 4 \(or 0: no distortion\)"),
    (dict(model='rational_polynomial', D=[0.1] * 5),
     "d has 5 values for distortion_model 'rational_polynomial': allowed: 8"),
    (dict(K=[[np.nan, 0, 640], [0, 800, 360], [0, 0, 1]]), 'k = .* is invalid: allowed: finite numbers only'),
    (dict(K=np.zeros((3, 3))), r'k = .* is invalid: allowed: fx = k\[0\] > 0'),
    (dict(P=np.zeros((3, 4))), r'p = .* is invalid: allowed: fx = p\[0\] > 0'),
    (dict(R=np.zeros((3, 3))), 'r = .* is invalid: allowed: a rotation matrix'),
    (dict(roi=(1000, 0, 500, 100)), 'roi.width = 500 is invalid: allowed: 1 to 280'),
    (dict(binning=(-1, 0)), 'binning_x = -1 is invalid: allowed: an integer >= 0'),
])
def test_bad_camera_info_is_one_line_naming_the_field(change, message):
    with pytest.raises(ValueError, match=message) as info:
        CameraInfoModel(camera_info(**change))
    assert '\n' not in str(info.value)


def test_bad_calibration_file_names_the_file_field(hero9):
    d = hero9.to_dict()
    k_inf = [float('inf')] + d['camera_matrix']['data'][1:]
    bad_k = dict(d, camera_matrix=dict(d['camera_matrix'], data=k_inf))
    bad_d = dict(d, distortion_coefficients={'rows': 1, 'cols': 5, 'data': [0.1] * 5})
    bad_model = dict(d, distortion_model='kannala_brandt')
    for bad, message in ((bad_k, 'camera_matrix = .* is invalid: allowed: finite numbers only'),
                         (bad_d, "distortion_coefficients has 5 values for distortion_model 'equidistant'"),
                         (bad_model, "distortion_model = 'kannala_brandt' is invalid: allowed: plumb_bob")):
        with pytest.raises(ValueError, match=message) as info:
            CameraInfoModel.from_calibration(bad)
        assert '\n' not in str(info.value)
    with pytest.raises(ValueError, match='projection_matrix has 9 values: allowed: 12'):
        CameraInfoModel.from_calibration(dict(d, projection_matrix=d['camera_matrix']))


def test_points_and_images_of_the_wrong_shape_are_refused():
    cam = CameraInfoModel(camera_info('equidistant'))
    with pytest.raises(ValueError, match=r'uv_raw has shape \(3,\): allowed: \(N, 2\)'):
        cam.rectify_points([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r'raw image shape = \(100, 100\) is invalid: allowed: \(720, 1280'):
        cam.rectify_image(np.zeros((100, 100), np.uint8))


def test_rclpy_field_types_are_read():
    """rclpy gives d as array.array and k, r, p as numpy arrays; roi fields as ints."""
    from array import array
    info = camera_info('equidistant')
    info.d = array('d', DISTORTIONS['equidistant'])
    assert np.array_equal(CameraInfoModel(info).D, DISTORTIONS['equidistant'])


def test_update_notices_a_change_of_p_alone():
    """A CameraInfo that differs only in P (balance / fov_scale changed upstream) is a change:
    update says so, and points and maps follow the new P."""
    info = camera_info('equidistant')
    cam = CameraInfoModel(info)
    maps = cam.rectification_maps()
    P2 = P_NEW.copy()
    P2[0, 0] = P2[1, 1] = 500.0
    assert cam.update(camera_info('equidistant', P=P2)) is True
    assert np.array_equal(cam.P, P2) and cam.fx == 500.0
    assert cam.rectification_maps() is not maps
    ray = cam.project_pixel_to_3d_ray([P2[0, 2] + 50.0, P2[1, 2]])
    assert ray[0] / ray[2] == pytest.approx(50.0 / 500.0, abs=1e-12)


def test_to_full_resolution_with_do_rectify_goes_through_the_rectified_roi(hero9):
    """With roi.do_rectify, reduced pixels are pixels of the rectified ROI: full = reduced *
    binning + the rectified ROI's corner (not the raw ROI's)."""
    cam = CameraInfoModel(camera_info('equidistant', D=hero9.D, K=hero9.K, R=hero9.R, P=hero9.P,
                                      width=1920, height=1080, binning=BINNING, roi=ROI, do_rectify=True))
    x, y, _, _ = cam.rectified_roi
    assert (x, y) != ROI[:2]  # the rectified corner differs from the raw one for this fisheye
    uv = np.array([[10.0, 20.0], [100.0, 50.0]])
    assert np.array_equal(cam.to_full_resolution(uv), uv * 2 + [x, y])
    assert np.array_equal(cam.to_reduced_resolution(cam.to_full_resolution(uv)), uv)
