"""Straight-line evidence (core/lines/detect.py) on scenes rendered through known wide cameras
(test/scenes.py: ray cast through the camera, with the straight 3-D segments as ground truth) and
on the shared real fisheye images against their authors' calibration.

The references are independent of the detector: the true camera's own great-circle fit of a
curve's pixels (unproject, the plane through the origin, project back), and the renderer's
ground-truth segments projected through the true camera. ROS-free.
"""
import glob
import os

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

import scenes
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
from zeroshot_calib_ros.core.lens.wide_fov import WideFovCamera
from zeroshot_calib_ros.core.lines.detect import Curve, detect_curves, draw_curves, make_views
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.zeroshot.solver import solve_zero_shot
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

REAL = os.path.join(os.path.dirname(__file__), '..', '..', '..', '..', 'shared', 'data', 'ros_fisheye_800x503')

# A 150-degree lens on a 1280x720 sensor, principal point 20 px right and 15 px up of the centre.
KB = KannalaBrandtCamera(480.0, 480.0, 660.0, 345.0, 1280, 720, [0.02, -0.01, 0.003, -0.0005])
# Beyond 180 degrees: 204 x 153 degrees on 960x720 (equidistant, off-centre).
WIDE = WideFovCamera(270.0, 488.0, 352.0, 960, 720, omega=1 / 270.0)


def great_circle_rms(camera, points):
    """RMS pixel distance of points from the image of the plane through the origin fitted to
    their rays under ``camera`` (each ray moved onto the plane and projected)."""
    rays = camera.unproject(points)
    normal = np.linalg.svd(rays, full_matrices=False)[2][-1]
    on = rays - (rays @ normal)[:, None] * normal
    px = camera.project(on / np.linalg.norm(on, axis=1, keepdims=True))
    return float(np.sqrt(np.mean(np.sum((px - points) ** 2, axis=1))))


class Scored:
    """Detected curves against a rendering: per curve the true residual and whether it lies on
    ground truth or on a curved distractor; per ground-truth segment whether it was found."""

    def __init__(self, camera, rendering, curves, min_px=80.0, min_contrast=30.0):
        self.curves = curves
        self.residual = np.array([great_circle_rms(camera, c.points) for c in curves])
        gt, seg = scenes.sample_segments(camera, rendering.segments, 1.0)
        ok = np.isfinite(gt).all(axis=1)
        gt, seg = gt[ok], seg[ok]
        tree = cKDTree(gt)
        self.on_gt = np.array([np.mean(tree.query(c.points, distance_upper_bound=1.5)[0] < 1.5)
                               for c in curves]) >= 0.8
        h, w = rendering.curved_mask.shape
        self.on_curved = np.array([np.mean(rendering.curved_mask[
            np.clip(np.round(c.points[:, 1]).astype(int), 0, h - 1),
            np.clip(np.round(c.points[:, 0]).astype(int), 0, w - 1)]) for c in curves]) >= 0.5
        # well-resolved ground truth: long, and contrasted both next to the edge and 3 px away
        # (so not one of a bundle of lines a few pixels apart)
        length = np.bincount(seg, minlength=len(rendering.segments))
        far = scenes.segment_contrast(rendering.clean, camera, rendering.segments, offset_px=3.0)
        self.wanted = (length >= min_px) & (rendering.contrast >= min_contrast) & (far >= min_contrast)
        points = np.concatenate([c.points for c in curves]) if curves else np.zeros((0, 2))
        d = cKDTree(points).query(gt, distance_upper_bound=1.5)[0] if len(points) else np.full(len(gt), np.inf)
        covered = np.bincount(seg, weights=np.isfinite(d), minlength=len(rendering.segments))
        self.found = covered / np.maximum(length, 1) >= 0.5
        # how far the points are from the true edges (ground truth sampled every 0.05 px)
        fine, _ = scenes.sample_segments(camera, rendering.segments, 0.05)
        fine = fine[np.isfinite(fine).all(axis=1)]
        d = cKDTree(fine).query(points, distance_upper_bound=1.5)[0] if len(points) else np.zeros(0)
        self.point_error = d[np.isfinite(d)]

    @property
    def recall(self):
        return float(np.mean(self.found[self.wanted]))


@pytest.fixture(scope='module')
def room():
    return scenes.render_scene(KB, 'room', seed=1)


@pytest.fixture(scope='module')
def street():
    return scenes.render_scene(KB, 'street', seed=1)


@pytest.fixture(scope='module')
def kb_views():
    return make_views(KB)


@pytest.fixture(scope='module')
def room_curves(room, kb_views):
    return detect_curves(room.image, KB, views=kb_views)


def zero_shot_of(camera, width, height):
    """The spec-sheet camera of a lens: zero-shot from its hfov and vfov rounded to 1 degree."""
    fov = camera.fields_of_view()
    return solve_zero_shot(CameraSpec(width, height, hfov=round(fov['hfov']), vfov=round(fov['vfov']))).camera


def dense_error_px(estimate, truth):
    u, v = np.meshgrid(np.linspace(0, truth.width - 1, 33), np.linspace(0, truth.height - 1, 19))
    pix = np.stack([u.ravel(), v.ravel()], axis=1)
    return float(np.sqrt(np.nanmean(np.sum((estimate.project(truth.unproject(pix)) - pix) ** 2, axis=1))))


# ----------------------------------------------------------------------------- the renderer


def test_rendered_edges_lie_where_the_camera_projects_the_segments(room):
    """The fixture's own check: across high-contrast ground-truth edges of the noise-free image,
    the 50 % crossing is where ``camera.project`` puts the 3-D segment (ray casting through
    ``unproject`` and anti-aliasing agree with the model to a small fraction of a pixel)."""
    img = room.clean
    crossings = []
    for i in np.nonzero((room.contrast >= 40))[0]:
        px = scenes.segment_pixels(KB, room.segments[i], 3.0)
        if len(px) < 12:
            continue
        t = np.gradient(px, axis=0)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        n = np.stack([-t[:, 1], t[:, 0]], axis=1)
        s = np.arange(-3.0, 3.001, 0.05)
        for k in range(3, len(px) - 3):  # away from the ends (corners)
            q = px[k][None, :] + s[:, None] * n[k][None, :]
            if not ((q >= 1).all() and (q[:, 0] <= KB.width - 2).all() and (q[:, 1] <= KB.height - 2).all()):
                continue
            prof = cv2.remap(img, q[:, 0].astype(np.float32).reshape(1, -1), q[:, 1].astype(np.float32).reshape(1, -1),
                             cv2.INTER_LINEAR).ravel()
            a, b = prof[0], prof[-1]
            if abs(b - a) < 30:
                continue
            f = (prof - a) / (b - a)
            j = np.nonzero((f[:-1] < 0.5) & (f[1:] >= 0.5))[0]
            if len(j) == 1:
                j = j[0]
                crossings.append(s[j] + (0.5 - f[j]) / (f[j + 1] - f[j]) * 0.05)
    crossings = np.abs(np.array(crossings))
    assert len(crossings) > 1000
    assert np.median(crossings) < 0.08, np.median(crossings)
    assert np.percentile(crossings, 90) < 0.2, np.percentile(crossings, 90)


# ----------------------------------------------------------------------------- detection, true camera


def test_curves_lie_on_great_circles_of_the_true_camera(room, room_curves):
    """Every curve is meant to image one straight 3-D line, so the true camera's rays of its
    points fit one plane through the origin: to a tenth of a pixel typically, under half a pixel
    for all but curved-distractor pieces; and nearly all curves lie on ground-truth edges."""
    sc = Scored(KB, room, room_curves)
    assert len(room_curves) >= 80
    assert np.median(sc.residual) < 0.15, np.median(sc.residual)
    assert np.mean(sc.residual < 0.5) >= 0.95, np.sort(sc.residual)[-10:]
    assert np.all(sc.residual[sc.on_gt] < 0.5), np.sort(sc.residual[sc.on_gt])[-5:]
    assert np.mean(sc.on_gt) >= 0.95
    # sub-pixel points: a twentieth of a pixel from the true edges (median)
    assert np.median(sc.point_error) < 0.08, np.median(sc.point_error)


def test_most_long_straight_edges_are_found(room, street, room_curves, kb_views):
    """Nearly every well-resolved ground-truth segment (>= 80 px long, contrast >= 30 grey
    levels) is covered over at least half its length by detected points, in a room and in a
    street (long lines are found across several views and merged)."""
    sc_room = Scored(KB, room, room_curves)
    street_curves = detect_curves(street.image, KB, views=kb_views)
    sc_street = Scored(KB, street, street_curves)
    assert sc_room.wanted.sum() >= 50 and sc_street.wanted.sum() >= 40
    assert sc_room.recall >= 0.9, sc_room.recall
    assert sc_street.recall >= 0.85, sc_street.recall
    assert np.mean(sc_street.residual < 0.5) >= 0.95
    # long edges come out long: some curves span most of a wall
    assert max(c.length_px for c in room_curves) > 600


def test_curved_distractors_are_not_returned_as_lines(room, room_curves):
    """Circles, rings, wheels and foliage give (almost) no curves: on a wall covered with them
    and nothing straight, at most two curves come back, and each is visibly not straight under
    the true camera (its residual several times that of the room's real lines), which is what
    the estimator's robust fit rejects. In the room the few curves off the ground truth lie on
    the curved things (a rug's rings), with the same large residual."""
    sc_room = Scored(KB, room, room_curves)
    typical = float(np.median(sc_room.residual[sc_room.on_gt]))
    total = sum(c.length_px for c in room_curves)
    off = ~sc_room.on_gt
    assert off.sum() <= 0.05 * len(room_curves)
    assert np.all(sc_room.on_curved[off])
    assert np.all(sc_room.residual[off] > 3 * typical), (sc_room.residual[off], typical)
    for seed in (0,):
        wall = scenes.render_scene(KB, scenes.curves_only_scene(seed), seed=seed)
        assert len(wall.segments) == 0
        curves = detect_curves(wall.image, KB)
        assert len(curves) <= 2, [round(c.length_px) for c in curves]
        assert sum(c.length_px for c in curves) <= 0.02 * total
        for c in curves:
            assert great_circle_rms(KB, c.points) > 3 * typical


def test_a_wrong_estimate_still_finds_the_lines(room, room_curves):
    """Detection through the zero-shot camera of the lens (its rounded FOVs only: centred, the
    wrong shape, ~25 px RMS from the truth) finds the same lines with the same accuracy under
    the true camera: the points are raw-image measurements, the estimate only decides where to
    look."""
    zs = zero_shot_of(KB, 1280, 720)
    assert dense_error_px(zs, KB) > 15
    curves = detect_curves(room.image, zs)
    sc = Scored(KB, room, curves)
    assert np.median(sc.residual) < 0.15
    assert np.mean(sc.residual < 0.5) >= 0.95
    assert np.mean(sc.on_gt) >= 0.95
    assert sc.recall >= 0.85, sc.recall
    assert np.median(sc.point_error) < 0.08, np.median(sc.point_error)
    # the same edges: most points found with the true camera are found with the wrong one
    ref = np.concatenate([c.points for c in room_curves])
    d = cKDTree(np.concatenate([c.points for c in curves])).query(ref)[0]
    assert np.mean(d < 1.0) >= 0.8


def test_lines_beyond_90_degrees_off_axis_of_a_lens_beyond_180(kb_views):
    """A 204-degree lens: views are made past 90 degrees off-axis, and lines seen there (behind
    the image plane of a pinhole) are found, straight under the true camera, also with a wrong
    estimate (3 % focal length, the law's shape, a centred principal point)."""
    views = make_views(WIDE)
    assert max(v.off_axis_deg for v in views.views) > 120
    r = scenes.render_scene(WIDE, 'room', pose='random', seed=2)
    wrong = WideFovCamera(270.0 * 1.03, 480.0, 360.0, 960, 720, omega=0.97 / (270.0 * 1.03))
    for camera in (WIDE, wrong):
        curves = detect_curves(r.image, camera)
        sc = Scored(WIDE, r, curves)
        off_axis = np.array([np.degrees(np.max(np.arccos(np.clip(WIDE.unproject(c.points)[:, 2], -1, 1))))
                             for c in curves])
        assert np.sum(off_axis > 95) >= 10, np.sort(off_axis)[-10:]
        assert np.mean(sc.residual < 0.5) >= 0.95
        assert np.median(sc.residual[off_axis > 95]) < 0.2
        assert sc.recall >= 0.85, sc.recall


# ----------------------------------------------------------------------------- the shared real images


def _authors_camera():
    cal = CameraCalibration.load(os.path.join(REAL, 'ost.yaml'))
    K = cal.K  # its distortion_model says plumb_bob, but the 4 coefficients are Kannala-Brandt's
    return KannalaBrandtCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], cal.width, cal.height, cal.D)


@pytest.mark.skipif(not os.path.isfile(os.path.join(REAL, 'ost.yaml')),
                    reason='../shared/data/ros_fisheye_800x503 (real fisheye images and their ost.yaml) is absent')
def test_real_fisheye_curves_are_straight_under_the_authors_calibration():
    """On the real 800x503 fisheye images (a 180-degree lens in an office), curves are found all
    over the image (ceiling grid, windows, desks, the board's edges), and under the authors' own
    Kannala-Brandt calibration nearly all of them are straight to a fraction of a pixel; with
    the zero-shot camera of the same lens as the estimate, as many are found and as straight."""
    camera = _authors_camera()
    views = make_views(camera)
    files = sorted(glob.glob(os.path.join(REAL, 'left-*.png')))
    assert len(files) >= 20
    residuals = []
    for f in files[0:24:12]:
        img = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        curves = detect_curves(img, camera, image_id=os.path.basename(f), views=views)
        assert len(curves) >= 100
        assert all(c.image == os.path.basename(f) for c in curves)
        res = np.array([great_circle_rms(camera, c.points) for c in curves])
        residuals.append(res)
        assert np.mean(res < 0.5) >= 0.85, np.mean(res < 0.5)
        pts = np.concatenate([c.points for c in curves])
        # spread over the image, not only its centre
        r = np.hypot(pts[:, 0] - camera.cx, pts[:, 1] - camera.cy)
        assert np.mean(r > 250) > 0.2
    res = np.concatenate(residuals)
    assert np.median(res) < 0.25, np.median(res)
    zs = zero_shot_of(camera, 800, 503)
    img = cv2.imread(files[0], cv2.IMREAD_GRAYSCALE)
    curves = detect_curves(img, zs)
    res_zs = np.array([great_circle_rms(camera, c.points) for c in curves])
    assert len(curves) >= 0.8 * len(residuals[0])
    assert np.mean(res_zs < 0.5) >= 0.85
    assert np.median(res_zs) < 0.25


# ----------------------------------------------------------------------------- views and inputs


def test_views_cover_the_whole_image(kb_views):
    """Every pixel of the image is seen by at least one view (and most by two: neighbours
    overlap, so a line crossing a view's border is found whole in the next one)."""
    for camera, views in ((KB, kb_views), (WIDE, make_views(WIDE))):
        seen = np.zeros((camera.height, camera.width), np.int32)
        for v in views.views:
            hit = np.zeros_like(seen)
            x = np.round(v.map_x[v.inside]).astype(int)
            y = np.round(v.map_y[v.inside]).astype(int)
            hit[y, x] = 1
            hit = cv2.dilate(hit.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.int32)
            seen += hit
        border = 3
        inner = seen[border:-border, border:-border]
        assert np.mean(inner >= 1) > 0.995, np.mean(inner >= 1)
        assert np.mean(inner >= 2) > 0.5


def test_inputs():
    """Wrong sizes are refused with the sizes named; black, flat and noise images give no
    curves; colour images give the curves of their grey version; curves carry their image id."""
    cam = KannalaBrandtCamera(240.0, 240.0, 330.0, 172.0, 640, 360, [0.02, -0.01, 0.003, -0.0005])
    with pytest.raises(ValueError, match='640x360'):
        detect_curves(np.zeros((480, 640), np.uint8), cam)
    assert detect_curves(np.zeros((360, 640), np.uint8), cam) == []
    assert detect_curves(np.full((360, 640), 128, np.uint8), cam) == []
    noise = np.random.default_rng(0).integers(0, 256, (360, 640)).astype(np.uint8)
    assert len(detect_curves(noise, cam)) <= 1
    with pytest.raises(TypeError, match='tolerance_px'):
        detect_curves(noise, cam, tolerance=3)
    r = scenes.render_scene(cam, 'corridor', seed=3, colour=True)
    assert r.image.shape == (360, 640, 3)
    views = make_views(cam)
    colour = detect_curves(r.image, cam, image_id=7, views=views)
    grey = detect_curves(cv2.cvtColor(r.image, cv2.COLOR_BGR2GRAY), cam, image_id=7, views=views)
    assert len(colour) >= 20 and len(colour) == len(grey)
    assert all(isinstance(c, Curve) and c.image == 7 for c in colour)
    for a, b in zip(colour, grey):  # the same curves; threaded sums may differ in the last bits (1e-13 px seen)
        np.testing.assert_allclose(a.points, b.points, rtol=0, atol=1e-9)
        assert a.points.dtype == np.float64 and a.points.shape[1] == 2
    # a mask keeps curves out of the masked part
    mask = np.ones((360, 640), bool)
    mask[:, 320:] = False
    masked = detect_curves(r.image, cam, views=views, mask=mask)
    assert len(masked) >= 5
    assert max(float(c.points[:, 0].max()) for c in masked) < 320
    with pytest.raises(ValueError, match='another camera'):
        detect_curves(r.image, KannalaBrandtCamera(250.0, 250.0, 320.0, 180.0, 640, 360, [0, 0, 0, 0]), views=views)


def circular_190(width=640, height=480, radius=220.0, cx=326.0, cy=236.0):
    """A 190-degree circular fisheye: its ray at 95 degrees lands on the image circle."""
    probe = WideFovCamera(100.0, cx, cy, width, height, omega=1 / 100.0)
    edge = probe.project(np.array([[np.sin(np.radians(95)), 0.0, np.cos(np.radians(95))]]))[0]
    f = 100.0 * radius / (edge[0] - cx)
    return WideFovCamera(f, cx, cy, width, height, omega=1 / f, circle_radius=radius)


def test_the_boundary_of_a_vignetted_image_circle_is_never_a_curve():
    """A circular fisheye's surround is dark but not black (vignetting fall-off, a glow, noise):
    its boundary, a long gently curved edge, must not come out as a straight line (it used to,
    with only pure-black surrounds left out). Lines inside the circle are still found."""
    truth = circular_190()
    image, _ = scenes.render(truth, 'room', seed=1, pose='random', nuisances=scenes.Nuisances())
    from zeroshot_calib_ros.core.estimation.refine import zero_shot_camera
    camera = zero_shot_camera(CameraSpec(640, 480, circle_diameter=440.0, circle_fov=190.0), 640, 480)
    curves = detect_curves(image, camera)
    assert len(curves) >= 20
    on_boundary = [c for c in curves
                   if np.mean(np.abs(np.hypot(c.points[:, 0] - truth.cx, c.points[:, 1] - truth.cy)
                                     - truth.circle_radius) < 4.0) > 0.2]
    assert on_boundary == [], [(len(c.points), round(c.length_px)) for c in on_boundary]


def test_debug_image_draws_used_and_rejected_curves(room, room_curves):
    used, rejected = room_curves[:20], room_curves[20:40]
    out = draw_curves(room.image, used, rejected)
    assert out.shape == room.image.shape + (3,) and out.dtype == np.uint8
    def colour_at(curves):
        p = np.round(np.concatenate([c.points[2:-2] for c in curves])).astype(int)
        return out[p[:, 1], p[:, 0]].astype(int)
    g = colour_at(used)
    r = colour_at(rejected)
    assert np.mean((g[:, 1] > 150) & (g[:, 2] < 100)) > 0.8   # green
    assert np.mean((r[:, 2] > 150) & (r[:, 1] < 100)) > 0.8   # red
    # away from the curves (their points, the lines between points less than 6 px apart, and
    # the mark at each first point) the image is unchanged
    near = np.zeros(room.image.shape, np.uint8)
    for c in room_curves[:40]:
        p = c.points
        t = np.linspace(0, 1, 8)[None, :, None]
        close = np.hypot(*np.diff(p, axis=0).T) <= 6.0
        segs = (p[:-1][close][:, None, :] * (1 - t) + p[1:][close][:, None, :] * t).reshape(-1, 2)
        q = np.round(np.concatenate([p, segs])).astype(int)
        near[np.clip(q[:, 1], 0, 719), np.clip(q[:, 0], 0, 1279)] = 1
    near = cv2.dilate(near, np.ones((7, 7), np.uint8)) > 0
    grey = cv2.cvtColor(room.image, cv2.COLOR_GRAY2BGR)
    np.testing.assert_array_equal(out[~near], grey[~near])
    assert np.any(out[near] != grey[near])


@pytest.mark.skipif(not os.path.isfile(os.path.join(REAL, 'ost.yaml')),
                    reason='../shared/data/ros_fisheye_800x503 (real fisheye images and their ost.yaml) is absent')
def test_refinement_on_the_real_images_is_not_worse_than_zero_shot_or_is_refused_with_a_reason():
    """Refinement from 2 of the real images (their straight lines only; the board's edges are
    lines like any other, its geometry is not used), the spec's hfov / vfov taken from the
    authors' ost.yaml as benchmarks/paper_table4.py does. Against ost.yaml (RMS over a 33 x 19
    grid after the best rotation, at 1920 px wide): an accepted camera is not worse than zero-shot
    by more than 0.3 px; a refusal keeps the zero-shot camera and its error bar, with a reason."""
    from zeroshot_calib_ros.core.estimation.refine import refine_from_images
    from zeroshot_calib_ros.core.estimation.uncertainty import pixel_grid
    from scipy.optimize import least_squares
    authors = _authors_camera()
    fovs = authors.fields_of_view()
    spec = CameraSpec(authors.width, authors.height, hfov=fovs['hfov'], vfov=fovs['vfov'])
    files = sorted(glob.glob(os.path.join(REAL, 'left-*.png')))
    images = [cv2.imread(files[int(i)], cv2.IMREAD_GRAYSCALE) for i in np.linspace(0, len(files) - 1, 2).round()]
    result = refine_from_images(spec, images)
    pixels = pixel_grid(authors.width, authors.height)
    rays = authors.unproject(pixels)
    ok = np.all(np.isfinite(rays), axis=1)
    pixels, rays = pixels[ok], rays[ok]

    def error_at_1920(camera):
        def rotated(w):
            a = np.linalg.norm(w)
            k = w / a if a > 0 else np.zeros(3)
            K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            R = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
            return (np.nan_to_num(camera.project(rays @ R.T), nan=1e4) - pixels).ravel()
        fit = least_squares(rotated, np.zeros(3))
        return float(np.sqrt(2 * fit.cost / len(pixels))) * 1920 / authors.width

    zero_shot = error_at_1920(result.zero_shot_camera)
    if result.accepted:
        assert error_at_1920(result.camera) <= zero_shot + 0.3, result.reason
    else:
        assert result.reason and not result.reason.startswith('accepted')
        assert np.allclose(result.camera.K, result.zero_shot_camera.K)
        assert np.allclose(result.camera.D, result.zero_shot_camera.D)
        assert result.uncertainty_px == result.zero_shot_uncertainty_px


def test_detection_in_parallel_threads_finds_the_same_curves():
    """`refine` detects its images in threads at once: the curves are those of one at a time (to
    floating-point rounding: a threaded BLAS may sum in another order)."""
    from concurrent.futures import ThreadPoolExecutor
    camera = KannalaBrandtCamera(210.0, 210.0, 327.0, 176.0, 640, 360, np.array([0.02, -0.01, 0.003, -0.0005]))
    images = [scenes.render(camera, scene, seed=seed)[0] for scene, seed in (('room', 1), ('street', 3))] * 2
    views = make_views(camera)
    serial = [detect_curves(im, camera, image_id=i, views=views) for i, im in enumerate(images)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        parallel = list(pool.map(lambda item: detect_curves(item[1], camera, image_id=item[0], views=views),
                                 enumerate(images)))
    for a, b in zip(serial, parallel):
        assert len(a) == len(b) and all(np.allclose(p.points, q.points, rtol=0, atol=1e-9) for p, q in zip(a, b))


def test_max_curves_keeps_the_longest(room, room_curves, kb_views):
    """max_curves = N: the N longest curves of the image (longest first), not the first N found."""
    lengths = sorted((c.length_px for c in room_curves), reverse=True)
    assert len(lengths) > 12
    few = detect_curves(room.image, KB, views=kb_views, max_curves=6)
    assert [c.length_px for c in few] == pytest.approx(lengths[:6], abs=1e-9)


def test_detect_curves_is_find_edges_then_curves_from_edges(room, kb_views):
    """The two halves a second refinement round uses separately give what detect_curves gives,
    and curves made again under the same camera from the kept edge points are the same curves."""
    from zeroshot_calib_ros.core.lines.detect import curves_from_edges, find_edges
    image, camera = room.image, KB
    whole = detect_curves(image, camera, image_id=3, views=kb_views)
    edges = find_edges(image, camera, views=kb_views)
    halves = curves_from_edges(edges, camera, image_id=3)
    again = curves_from_edges(edges, camera, image_id=3)
    assert len(whole) == len(halves) == len(again) > 10
    for a, b, c in zip(whole, halves, again):
        # halves and again: the same edges, the same arithmetic, the same curves to the bit; whole
        # searched the image again: to 1e-6 px (with Ubuntu 24.04's numpy 1.26 on an AVX-512 CPU
        # two searches of one image differ in the last digits: its SIMD kernels round by alignment)
        assert np.array_equal(b.points, c.points)
        assert a.points.shape == b.points.shape and np.allclose(a.points, b.points, rtol=0, atol=1e-6)
        assert a.image == b.image == 3
    with pytest.raises(ValueError, match='edges are of a'):
        curves_from_edges(edges, camera.scaled(camera.width // 2, camera.height // 2))


def test_nearest_distances_are_the_same_by_tree_as_by_brute_force():
    """Merging asks, where two pieces overlap, how far each point of one is from the other's
    nearest point; large pairs go to a k-d tree, small ones to brute force: the distances (and so
    the merge decisions) must not depend on which, nor on the order of the points."""
    from zeroshot_calib_ros.core.lines import detect as detect_module
    rng = np.random.default_rng(3)
    mine = rng.uniform(0, 200, (300, 2))
    theirs = np.cumsum(rng.uniform(0, 1.5, (400, 2)), axis=0)  # a curve-like walk
    truth = np.array([np.min(np.hypot(*(theirs - p).T)) for p in mine])
    assert len(mine) * len(theirs) > detect_module.NEAREST_BRUTE_PAIRS  # the tree path
    np.testing.assert_allclose(detect_module._nearest_distances(mine, theirs), truth, rtol=0, atol=1e-12)
    small = detect_module._nearest_distances(mine[:5], theirs[:20])  # the brute-force path
    np.testing.assert_allclose(small, [np.min(np.hypot(*(theirs[:20] - p).T)) for p in mine[:5]], atol=1e-12)
    shuffled = rng.permutation(len(theirs))
    np.testing.assert_array_equal(detect_module._nearest_distances(mine, theirs[shuffled]),
                                  detect_module._nearest_distances(mine, theirs))


def test_nearest_distances_by_sweep_are_brute_forces_to_the_last_bit():
    """Above NEAREST_BRUTE_PAIRS the distances come from a sweep along one axis; merge decisions
    compare them with thresholds and with each other, so they must be brute force's numbers
    exactly, for curves along either axis, duplicated points, ties and a far-away piece."""
    from zeroshot_calib_ros.core.lines import detect as detect_module

    def brute(mine, theirs):
        return np.sqrt(np.min(np.sum((mine[:, None, :] - theirs[None, :, :]) ** 2, axis=2), axis=1))

    rng = np.random.default_rng(11)
    curve = np.cumsum(rng.uniform(-0.5, 2.0, (400, 2)), axis=0) + 300
    vertical = np.stack([100 + rng.normal(0, 0.2, 500), np.arange(500) * 2.0], axis=1)
    grid = np.round(rng.uniform(0, 40, (300, 2)))  # many equal distances
    cases = [(curve[rng.integers(0, 400, 150)] + rng.normal(0, 0.4, (150, 2)), curve),
             (curve[:, ::-1] + 0.3, curve[:, ::-1].copy()),
             (np.stack([np.full(200, 101.0), rng.uniform(0, 1000, 200)], axis=1), vertical),
             (np.round(rng.uniform(0, 40, (100, 2))), grid),
             (curve[:100] + 500.0, curve),                       # a piece far from the cluster
             (np.repeat(curve[:20], 10, axis=0), np.repeat(curve, 2, axis=0))]
    for mine, theirs in cases:
        assert len(mine) * len(theirs) > detect_module.NEAREST_BRUTE_PAIRS  # the sweep
        np.testing.assert_array_equal(detect_module._nearest_distances(mine, theirs), brute(mine, theirs))


def test_group_medians_are_numpys_medians_per_group():
    """Pieces trim their outliers by per-segment medians of residuals: every group's median must
    be the middle of its sorted values (np.median's; a NaN sorts last, as in np.sort), for runs
    of groups (points of segments) and for groups in any order, with empty groups, NaN values,
    ties and one group much longer than the others."""

    def middle(v):
        s = np.sort(v)
        return 0.5 * (s[(len(s) - 1) // 2] + s[len(s) // 2]) if len(s) else np.nan

    from zeroshot_calib_ros.core.lines.detect import _group_median
    rng = np.random.default_rng(5)
    for trial in range(60):
        n_groups = int(rng.integers(1, 40))
        sizes = rng.integers(0, 30, n_groups)
        if trial % 3 == 0:
            sizes[rng.integers(0, n_groups)] = 900  # a long segment among short ones
        group = np.repeat(np.arange(n_groups), sizes)
        values = rng.normal(0, 1, len(group))
        if trial % 4 == 1:
            values = np.round(values * 2) / 2  # ties
        if trial % 5 == 2 and len(values):
            values[rng.integers(0, len(values), 3)] = np.nan
        if trial % 2:
            shuffled = rng.permutation(len(group))
            group, values = group[shuffled], values[shuffled]
        expected = np.array([middle(values[group == g]) for g in range(n_groups)])
        if not np.isnan(values).any():
            np.testing.assert_array_equal(expected, [np.median(values[group == g]) if (group == g).any() else np.nan
                                                     for g in range(n_groups)])
        np.testing.assert_array_equal(_group_median(values, group, n_groups), expected)


def test_views_made_in_threads_are_the_views_made_in_one(kb_views):
    """refine makes the views in its workers' threads: the same views, in the same order, with the
    same maps (the detector then sees the same pixels)."""
    threaded = make_views(KB, workers=2)
    assert [v.index for v in threaded.views] == list(range(len(kb_views.views))) and len(threaded) == len(kb_views)
    for one, many in zip(kb_views.views, threaded.views):
        assert (one.f, one.size, one.scale, one.off_axis_deg) == (many.f, many.size, many.scale, many.off_axis_deg)
        for name in ('R', 'direction', 'map_x', 'map_y', 'inside'):
            np.testing.assert_array_equal(getattr(one, name), getattr(many, name))


def test_pixels_outside_a_view_take_the_nearest_inside_pixel():
    """A view's maps repeat, outside the image, the nearest pixel inside (no artificial edge for
    the segment detector); both maps of a view share one search: every pixel's source is inside,
    an inside pixel is its own, and none is farther than the nearest inside pixel by more than the
    distance transform's approximation (a few percent)."""
    from zeroshot_calib_ros.core.lines.detect import _nearest_inside
    yy, xx = np.mgrid[0:40, 0:50]
    inside = ((xx - 22) ** 2 + (yy - 18) ** 2 <= 12 ** 2) | ((xx > 40) & (yy > 30))
    source = _nearest_inside(inside)
    flat = inside.ravel()
    assert flat[source].all()
    np.testing.assert_array_equal(source[flat], np.flatnonzero(flat))
    sy, sx = np.divmod(source, 50)
    inside_yx = np.argwhere(inside)
    nearest = np.sqrt(((np.stack([yy.ravel(), xx.ravel()], 1)[:, None, :] - inside_yx[None]) ** 2).sum(2).min(1))
    assert np.all(np.hypot(sy - yy.ravel(), sx - xx.ravel()) <= nearest * 1.05 + 0.5)
    assert _nearest_inside(np.zeros((5, 5), bool)) is None
