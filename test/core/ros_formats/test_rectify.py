"""Rectification: OpenCV's meaning of balance / fov_scale, exact maps, straight lines."""
import cv2
import numpy as np
import pytest

from synthetic import find_corners, line_residuals, render_checkerboard
from zeroshot_calib_ros.core import CameraSpec, KannalaBrandtCamera, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.lens.fitting import fit_kannala_brandt
from zeroshot_calib_ros.core.streaming.image_frames import ENCODINGS, ActiveCalibration, image_array
from zeroshot_calib_ros.core.ros_formats.rectify import (Rectifier, map_format_for, new_camera_matrix,
                                                     pads_to_four_channels, principal_point_camera_matrix,
                                                     rectification_maps)

def convert_maps(maps, to):
    """``maps`` as 'float' (two CV_32FC1) or 'fixed' (CV_16SC2 + CV_16UC1), as cv2.convertMaps gives them."""
    if (maps[0].dtype == np.float32) == (to == 'float'):
        return maps
    return tuple(cv2.convertMaps(maps[0], maps[1], cv2.CV_32FC1 if to == 'float' else cv2.CV_16SC2))


FLOAT_MAP_TOLERANCE_PX = 1e-3  # float32 steps are 1.2e-4 px at 1024-2048 px (measured: 2.4e-4)

HERO9_W1 = CameraSpec(1920, 1080, 118, 69)


GRID = [(b, s) for b in (0.0, 0.5, 1.0) for s in (0.5, 1.0, 2.0)] + [(0.5, 1.3), (0.2, 0.8)]
SPECS = {'hero9-w1': HERO9_W1, 'c922': CameraSpec(1280, 720, 70.42, 43.3), 'm2026': CameraSpec(1280, 720, 130, 73)}


@pytest.mark.parametrize('balance, fov_scale', GRID)
@pytest.mark.parametrize('name', SPECS)
def test_every_P_means_what_opencv_means(name, balance, fov_scale):
    """P of the rectified camera, wherever it is made (new_camera_matrix; the CameraInfo /
    calibration file record, CameraCalibration.from_solution; the node's run-time change of
    balance / fov_scale, ActiveCalibration.with_rectification), is what
    cv2.fisheye.estimateNewCameraMatrixForUndistortRectify gives for the same K, D, balance
    and fov_scale."""
    spec = SPECS[name]
    solution = solve_zero_shot(spec)
    D = fit_kannala_brandt(solution.camera).D
    theirs = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
        solution.K, D, (spec.width, spec.height), np.eye(3), balance=balance, fov_scale=fov_scale)
    ours = new_camera_matrix(solution.camera, balance, fov_scale)
    np.testing.assert_allclose(ours, theirs, atol=2e-3)
    calibration, _ = CameraCalibration.from_solution(solution, 'equidistant', balance, fov_scale)
    np.testing.assert_allclose(calibration.P[:, :3], theirs, atol=2e-3)
    assert np.all(calibration.P[:, 3] == 0)
    default, _ = CameraCalibration.from_solution(solution)  # balance 0, fov_scale 1
    changed = ActiveCalibration(default, solution.camera, 'spec').with_rectification(
        balance, fov_scale, build_maps=False)
    np.testing.assert_allclose(changed.calibration.P[:, :3], theirs, atol=2e-3)
    np.testing.assert_array_equal(changed.calibration.K, default.K)


def _opencv_new_camera_matrix(K, D, size, balance, fov_scale, typo):
    """cv2.fisheye.estimateNewCameraMatrixForUndistortRectify (R = I, same size) line by line,
    on cv2.fisheye.undistortPoints: as fixed upstream (opencv/opencv#22604, in OpenCV 5.0) or,
    ``typo``, as OpenCV 4.6 has it (the centre's x scaled by fx / fy instead of its y,
    opencv/opencv#22537). Which one the installed OpenCV is gets checked against cv2 itself."""
    w, h = size
    edges = np.array([[[w // 2, 0]], [[w, h // 2]], [[w // 2, h]], [[0, h // 2]]], np.float64)
    pts = cv2.fisheye.undistortPoints(edges, K, D).reshape(-1, 2)
    cn = pts.mean(axis=0)
    aspect = K[0, 0] / K[1, 1]
    cn[0 if typo else 1] *= aspect
    pts[:, 1] *= aspect
    (minx, miny), (maxx, maxy) = pts.min(axis=0), pts.max(axis=0)
    focals = [w * 0.5 / (cn[0] - minx), w * 0.5 / (maxx - cn[0]),
              h * 0.5 * aspect / (cn[1] - miny), h * 0.5 * aspect / (maxy - cn[1])]
    f = (balance * min(focals) + (1.0 - balance) * max(focals)) / fov_scale
    c = -cn * f + np.array([w, h * aspect]) * 0.5
    return np.array([[f, 0.0, c[0]], [0.0, f / aspect, c[1] / aspect], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize('balance, fov_scale', GRID)
def test_P_of_an_off_centre_kannala_brandt_camera_is_opencvs(balance, fov_scale):
    """A calibration file's camera (principal point off the centre, fx != fy): P is OpenCV's
    for the same K, D. OpenCV 4.6 (Ubuntu 24.04's) has a typo there that shifts P's principal
    point by 0.25 px for this camera (opencv/opencv#22537); P follows the fixed OpenCV (5.0)."""
    K = np.array([[610.0, 0.0, 655.3], [0.0, 604.0, 349.1], [0.0, 0.0, 1.0]])
    D = np.array([0.05, -0.012, 0.004, -0.0007]).reshape(4, 1)
    camera = KannalaBrandtCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], 1280, 720, D)
    theirs = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
        K, D, (1280, 720), np.eye(3), balance=balance, fov_scale=fov_scale)
    fixed = _opencv_new_camera_matrix(K, D, (1280, 720), balance, fov_scale, typo=False)
    typo = _opencv_new_camera_matrix(K, D, (1280, 720), balance, fov_scale, typo=True)
    assert np.abs(fixed - typo).max() > 0.1  # this camera tells the two apart
    opencv_is_fixed = np.abs(theirs - fixed).max() < 1e-6
    assert opencv_is_fixed or np.abs(theirs - typo).max() < 1e-6  # the port is line for line OpenCV's
    if int(cv2.__version__.split('.')[0]) >= 5:
        assert opencv_is_fixed
    np.testing.assert_allclose(new_camera_matrix(camera, balance, fov_scale), fixed, atol=1e-6)
    if opencv_is_fixed:
        np.testing.assert_allclose(new_camera_matrix(camera, balance, fov_scale), theirs, atol=1e-6)


@pytest.mark.parametrize('balance, fov_scale', GRID)
@pytest.mark.parametrize('name', SPECS)
def test_P_on_the_principal_point_is_opencvs_for_a_centred_camera(name, balance, fov_scale):
    """principal_point_camera_matrix (the P `calibrate` writes) of a camera centred in its image:
    what cv2.fisheye.estimateNewCameraMatrixForUndistortRectify gives for its K, D."""
    spec = SPECS[name]
    solution = solve_zero_shot(spec)
    D = fit_kannala_brandt(solution.camera).D
    theirs = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
        solution.K, D, (spec.width, spec.height), np.eye(3), balance=balance, fov_scale=fov_scale)
    np.testing.assert_allclose(principal_point_camera_matrix(solution.camera, balance, fov_scale), theirs, atol=2e-3)


WIDE_OFF_CENTRE = KannalaBrandtCamera(210.0, 210.0, 327.0, 176.0, 640, 360, np.array([0.02, -0.01, 0.003, -0.0005]))
"""A 172 x 97 degree lens whose principal point is (7, -4) px off the image centre."""


@pytest.mark.parametrize('balance', [0.0, 0.5, 1.0])
def test_P_on_the_principal_point_of_an_off_centre_wide_lens(balance):
    """For a wide lens off-centre by a few px, OpenCV's rule (the mean of the undistorted edge
    midpoints, dominated by whichever edge is nearer 90 degrees) puts P's principal point outside
    the image; principal_point_camera_matrix keeps the camera's, as ROS camera_calibration does
    for a fisheye, and balance keeps its meaning: at 0 every edge midpoint of the raw image lands
    on or beyond the rectified image's edge (no black border there), at 1 all are inside, one on
    the edge; fov_scale divides the focal length."""
    camera = WIDE_OFF_CENTRE
    assert abs(new_camera_matrix(camera, balance)[0, 2] - 320) > 50  # what this replaces, for calibrate
    P = principal_point_camera_matrix(camera, balance)
    np.testing.assert_allclose(P[:2, 2], [camera.cx, camera.cy], atol=1e-12)
    w, h = camera.width, camera.height
    rays = camera.unproject(np.array([[w // 2, 0], [w, h // 2], [w // 2, h], [0, h // 2]], float))
    (_, top), (right, _), (_, bottom), (left, _) = (rays[:, :2] / rays[:, 2:]) @ P[:2, :2].T + P[:2, 2]
    beyond = np.array([-left, right - w, -top, bottom - h])
    if balance == 0.0:
        assert beyond.min() > -1e-6, beyond
    elif balance == 1.0:
        assert beyond.max() < 1e-6 and np.abs(beyond).min() < 1e-6, beyond
    np.testing.assert_allclose(principal_point_camera_matrix(camera, balance, 2.0)[0, 0], P[0, 0] / 2, rtol=1e-12)


def test_balance_and_fov_scale_are_checked():
    camera = solve_zero_shot(HERO9_W1).camera
    with pytest.raises(ValueError, match='balance = 1.5 is invalid: allowed: 0 to 1'):
        new_camera_matrix(camera, 1.5)
    with pytest.raises(ValueError, match='fov_scale = 0.0 is invalid'):
        new_camera_matrix(camera, 0.0, 0.0)


@pytest.mark.parametrize('map_format', ['fixed', 'float'])
def test_maps_agree_with_opencv_fisheye_maps_to_fixed_point_precision(map_format):
    """Our maps from the exact model, in either format, against cv2.fisheye's from the KB fit:
    fixed point within half a 1/32 px cell per axis (its rounding), float within the fit."""
    solution = solve_zero_shot(HERO9_W1)
    D = fit_kannala_brandt(solution.camera).D
    rectifier = Rectifier(solution.camera, balance=0.5)
    mx, my = cv2.fisheye.initUndistortRectifyMap(solution.K, D, np.eye(3), rectifier.P, (1920, 1080),
                                                 cv2.CV_32FC1)
    maps = rectification_maps(solution.camera, rectifier.P, (1920, 1080), map_format=map_format)
    if map_format == 'fixed':
        assert maps[0].dtype == np.int16 and maps[0].shape == (1080, 1920, 2) and maps[1].dtype == np.uint16
        ox, oy = cv2.convertMaps(maps[0], maps[1], cv2.CV_32FC1)
        tolerance = 1 / 64 + 1e-3
    else:
        assert maps[0].dtype == maps[1].dtype == np.float32 and maps[0].shape == (1080, 1920)
        ox, oy = maps
        tolerance = FLOAT_MAP_TOLERANCE_PX
    inside = (mx > 0) & (mx < 1919) & (my > 0) & (my < 1079)
    assert inside.mean() > 0.9
    assert np.abs(ox - mx)[inside].max() <= tolerance
    assert np.abs(oy - my)[inside].max() <= tolerance


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


@pytest.mark.parametrize('encoding', list(ENCODINGS))
def test_every_encoding_is_rectified_channel_by_channel_as_opencv_remaps_it(encoding):
    """Each supported encoding, as the node receives it (message bytes with row padding, through
    image_array) and rectifies it (ActiveCalibration of a calibration file, balance 1 so there is
    a border): the WHOLE image equals cv2.remap of every channel on its own, with the maps of
    cv2.fisheye.initUndistortRectifyMap for the file's K, D, P (in the rectifier's format: fixed
    point as image_proc's, or float where OpenCV remaps that encoding faster): channels in their order, 16 bits kept, float images NaN where no pixel was
    seen (image_proc), other types 0. Textures differ in every channel and use the whole range."""
    from opencv_reference import textured_image
    w, h = 192, 108
    dtype, channels = ENCODINGS[encoding]
    calibration, _ = CameraCalibration.from_solution(solve_zero_shot(CameraSpec(w, h, 118, 69)), balance=1.0)
    _, rectifier = ActiveCalibration(calibration, calibration.camera(), 'file', rectify=True).for_size(w, h)
    image = textured_image(w, h, channels, dtype, seed=len(encoding), smooth=False)
    row = w * channels * dtype.itemsize
    step = row + 2 * dtype.itemsize
    data = np.zeros((h, step), np.uint8)
    data[:, :row] = image.reshape(h, -1).view(np.uint8)
    out = rectifier.rectify(image_array(data.tobytes(), w, h, step, encoding))

    mx, my = cv2.fisheye.initUndistortRectifyMap(calibration.K, calibration.D.reshape(4, 1), np.eye(3),
                                                 calibration.P[:3, :3], (w, h), cv2.CV_32FC1)
    # in the format the rectifier remapped with (the faster on this OpenCV: map_format_for)
    assert rectifier.map_format == map_format_for(cv2.INTER_LINEAR)
    map1, map2 = convert_maps((mx, my), rectifier.map_format)
    border = float('nan') if dtype.kind == 'f' else 0
    planes = [image] if channels == 1 else [np.ascontiguousarray(image[..., c]) for c in range(channels)]
    expected = [cv2.remap(p, map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=border)
                for p in planes]
    expected = expected[0] if channels == 1 else np.stack(expected, axis=-1)
    assert out.dtype == dtype and out.shape == expected.shape
    np.testing.assert_array_equal(out, expected)  # NaN where NaN is expected, nowhere else
    unseen = (mx < -1) | (mx > w) | (my < -1) | (my > h)
    assert unseen.mean() > 0.05  # there is a border
    if dtype.kind == 'f':
        seen = (mx > 1) & (mx < w - 2) & (my > 1) & (my < h - 2)
        assert np.isnan(out[unseen]).all() and not np.isnan(out[seen]).any()
    else:
        assert (out[unseen] == 0).all()
        assert out.max() > 0.9 * np.iinfo(dtype).max  # the whole range survives (16 bits not cut to 8)


def test_interpolation_values_are_opencvs_remap_flags():
    """image_proc's interpolation numbers rectify as cv2.remap with OpenCV's flag of that name
    (the module maps them without importing cv2)."""
    camera = solve_zero_shot(CameraSpec(160, 90, 118, 69)).camera
    image = np.random.default_rng(3).integers(0, 256, (90, 160), dtype=np.uint8)
    flags = {0: cv2.INTER_NEAREST, 1: cv2.INTER_LINEAR, 2: cv2.INTER_CUBIC, 4: cv2.INTER_LANCZOS4}
    for value, flag in flags.items():
        rectifier = Rectifier(camera, interpolation=value)
        expected = cv2.remap(image, rectifier.map1, rectifier.map2, flag, borderMode=cv2.BORDER_CONSTANT,
                             borderValue=0)
        assert np.array_equal(rectifier.rectify(image), expected), value


def test_map_format_follows_the_measured_table():
    """Float maps where OpenCV's remap runs faster with them (nearest always; linear from OpenCV
    4.11, 3-channel images padded to 4 there), fixed point elsewhere, whatever the encoding;
    the rectifier builds its OpenCV's choice."""
    new, old = (5, 0), (4, 6)
    assert [map_format_for(1, v) for v in (new, (4, 11), old)] == ['float', 'float', 'fixed']
    assert [map_format_for(0, v) for v in (new, old)] == ['float'] * 2
    assert [map_format_for(i, v) for i in (2, 4) for v in (new, old)] == ['fixed'] * 4
    assert [pads_to_four_channels(c, 1, new) for c in (1, 3, 4)] == [False, True, False]
    assert pads_to_four_channels(3, 1, (4, 11)) and not pads_to_four_channels(3, 1, old)
    assert not any(pads_to_four_channels(3, i, new) for i in (0, 2, 4))
    version = tuple(int(x) for x in cv2.__version__.split('.')[:2])
    camera = solve_zero_shot(CameraSpec(160, 90, 118, 69)).camera
    assert Rectifier(camera).map_format == ('float' if version >= (4, 11) else 'fixed')
    assert Rectifier(camera, interpolation=0).map_format == 'float'
    assert Rectifier(camera, interpolation=2).map_format == 'fixed'


@pytest.mark.parametrize('version', [(5, 0), (4, 6)])
@pytest.mark.parametrize('dtype', [np.uint8, np.uint16])
def test_three_channel_frames_padded_to_four_reuse_their_buffers_and_stay_exact(version, dtype):
    """Where 3-channel images are remapped as 4 (OpenCV 4.11+, linear), every frame equals
    cv2.remap of the 3-channel image with the same maps, the two 4-channel working frames are
    allocated once for a stream (no allocation per frame) and follow a change of depth;
    on OpenCV 4.6's rule nothing is padded and no working frame is held. Two threads rectifying
    at once never share working frames (each result is its own image's)."""
    camera = solve_zero_shot(CameraSpec(192, 108, 118, 69)).camera
    rectifier = Rectifier(camera, balance=1.0)
    rectifier._version = version
    rng = np.random.default_rng(7)
    top = np.iinfo(dtype).max
    images = [rng.integers(0, top, (108, 192, 3)).astype(dtype) for _ in range(4)]
    expected = [cv2.remap(i, rectifier.map1, rectifier.map2, rectifier.interpolation,
                          borderMode=cv2.BORDER_CONSTANT) for i in images]
    padded = version >= (4, 11)
    held = None
    for image, want in zip(images, expected):
        out = np.empty_like(image)
        assert rectifier.rectify(image, out=out) is out
        np.testing.assert_array_equal(out, want)
        buffers = [id(a) for pair in rectifier._four_channel_buffers for a in pair]
        held = held or buffers
        assert buffers == held and len(buffers) == (2 if padded else 0)
    assert rectifier.frame_buffer_nbytes == (2 * 108 * 192 * 4 * np.dtype(dtype).itemsize if padded else 0)
    if not padded:
        return
    # mono frames in between leave the working frames alone; a deeper frame gets its own
    np.testing.assert_array_equal(rectifier.rectify(images[0][..., 0].copy()),
                                  cv2.remap(images[0][..., 0].copy(), rectifier.map1, rectifier.map2, 1,
                                            borderMode=cv2.BORDER_CONSTANT))
    other = (images[1].astype(np.uint32) * 3 // 2).astype(np.uint16 if dtype == np.uint8 else np.uint8)
    np.testing.assert_array_equal(rectifier.rectify(other), cv2.remap(other, rectifier.map1, rectifier.map2, 1,
                                                                      borderMode=cv2.BORDER_CONSTANT))
    assert rectifier._four_channel_buffers[0][0].dtype == other.dtype
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(lambda k: rectifier.rectify(images[k % 4]), range(200)))
    for k, result in enumerate(results):
        np.testing.assert_array_equal(result, expected[k % 4])


@pytest.mark.parametrize('version', [(5, 0), (4, 6)])
def test_a_stream_that_changes_encoding_is_rectified_with_one_set_of_maps(version):
    """bgr8, mono8, bgra8, bgr8 frames through one rectifier (either OpenCV's rule): each output
    equals cv2.remap with the exact maps in the one format that OpenCV's remap is fastest with
    (rounded to 1/32 px where that is fixed point); no frame converts the maps."""
    camera = solve_zero_shot(CameraSpec(192, 108, 118, 69)).camera
    rectifier = Rectifier(camera, balance=1.0)
    rectifier._version = version  # the rule of that OpenCV release (the remap below is this one's)
    exact = rectification_maps(camera, rectifier.P, rectifier.size, map_format='float')
    expected_maps = convert_maps(exact, rectifier.map_format)
    maps_before = rectifier.map1
    rng = np.random.default_rng(5)
    for channels in (3, 1, 4, 3):
        image = rng.integers(0, 256, (108, 192, channels) if channels > 1 else (108, 192), dtype=np.uint8)
        out = rectifier.rectify(image)
        assert rectifier.map1 is maps_before
        np.testing.assert_array_equal(out, cv2.remap(image, *expected_maps, cv2.INTER_LINEAR,
                                                     borderMode=cv2.BORDER_CONSTANT))


def test_idle_remap_benchmark_sample_times_the_remap_after_every_kind_of_wait(capsys):
    """benchmarks/idle_remap.py on one tiny frame per encoding (results/idle_remap.md is its run
    at 1080p and 4K): a row per order and encoding with a time after each wait, in the header's order."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'benchmarks'))
    import idle_remap
    idle_remap.main(['--sizes', '96x54', '--rounds', '2'])
    out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.startswith('| order |'))
    assert [c.strip() for c in header.strip('|').split('|')[3:]] == [
        'back to back', 'sleep 33 ms', 'spin 33 ms', 'sleep 33 ms, read 64 MB', 'sleep 33 ms, spin 3 ms']
    rows = [[c.strip() for c in line.strip('|').split('|')] for line in out.splitlines() if '| 96x54 |' in line]
    assert [(r[0], r[2]) for r in rows] == [('blocks', 'bgr8'), ('interleaved', 'bgr8'),
                                            ('blocks', 'mono8'), ('interleaved', 'mono8')]
    assert all(len(r) == 8 and all(float(x) > 0 for x in r[3:]) for r in rows)


def test_remap_kernels_benchmark_sample_reports_every_candidate_and_the_rule_in_force(capsys):
    """benchmarks/remap_kernels.py on one tiny frame per encoding (the results file is its full
    sweep): a row per candidate, the Rectifier's own call among them, and the rule this OpenCV
    gets (float maps and padding from 4.11, fixed point and no padding before)."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'benchmarks'))
    import remap_kernels
    remap_kernels.main(['--sizes', '96x54', '--rounds', '2', '--paced-rounds', '1'])
    out = capsys.readouterr().out
    rows = {tuple(c.strip() for c in line.strip('|').split('|')[1:3]) for line in out.splitlines()
            if line.startswith('| 96x54')}
    three = {'3 ch, fixed maps', '3 ch, float maps', 'padded to 4, float maps', 'padded to 4, fixed maps',
             'Rectifier.rectify'}
    assert rows == {('bgr8', c) for c in three} | {('bgr16', c) for c in three} | \
        {('mono8', c) for c in ('1 ch, fixed maps', '1 ch, float maps', 'Rectifier.rectify')}
    new = tuple(int(x) for x in cv2.__version__.split('.')[:2]) >= (4, 11)
    assert (f'The Rectifier here: {"float" if new else "fixed"} maps; 3 channels padded to 4: '
            f'{"yes" if new else "no"}.') in out
