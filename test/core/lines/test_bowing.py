"""Curves that bow toward the principal point (core/lines/bowing.py): a vehicle's bonnet or a body's
edge seen in one frame is no line of a wide lens, whole or in the short pieces a detector finds it
in; the lines of a fisheye, and the slight inward bow of a nearly rectilinear lens's lines, are
kept; refine leaves such curves out before the fit can bend toward them. ROS-free."""
import json
import math

import cv2
import numpy as np
import pytest

import scenes
from cli_run import run_main
from test_refine import TRUTH, Curve, best_rotation_rms, line_curves, spec_of
from zeroshot_calib_ros.core.estimation.refine import refine_camera, refine_from_images
from zeroshot_calib_ros.core.estimation.uncertainty import pixel_grid
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, PinholeCamera
from zeroshot_calib_ros.core.lines.bowing import (BOW_CURVATURE_FLOOR, bow_toward, bows_the_wrong_way,
                                                  predicted_line)
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

W, H = TRUTH.width, TRUTH.height


def bonnet(cx=W / 2, bottom=H - 120, half_width=0.3 * W, radius=1.5 * W / 2, n=40, a0=0.0, a1=1.0):
    """An arc below the centre whose middle bulges up, toward the principal point: the edge of a
    bonnet (radius of curvature ``radius`` px), from fraction ``a0`` to ``a1`` of its run."""
    half_angle = math.asin(half_width / radius)
    t = np.linspace(-half_angle + 2 * half_angle * a0, -half_angle + 2 * half_angle * a1, n)
    centre_y = bottom + radius
    return np.stack([cx + radius * np.sin(t), centre_y - radius * np.cos(t)], axis=1)


def test_bow_of_an_arc_is_its_sagitta_signed_toward_the_centre():
    # a circle of radius R through a chord of half-length c bows by R - sqrt(R^2 - c^2)
    arc = bonnet(half_width=300, radius=900)
    bow, se, half = bow_toward(arc, (W / 2, H / 2))
    sagitta = 900 - math.sqrt(900 ** 2 - 300 ** 2)
    assert half == pytest.approx(300, rel=1e-6)
    assert bow == pytest.approx(sagitta, rel=0.05)
    # seen from below (the centre on the other side of the chord) the same arc bows away
    assert bow_toward(arc, (W / 2, H + 2000))[0] == pytest.approx(-bow)
    assert se < 0.02 * bow


def test_the_lines_of_a_fisheye_bow_away_and_are_all_kept():
    rng = np.random.default_rng(3)
    lines = line_curves(TRUTH, rng, 200, noise=0.3)
    bows = [bow_toward(c, (TRUTH.cx, TRUTH.cy))[0] for c in lines]
    assert np.median(bows) < -1.0  # they do bow, away from the centre (positive is toward it)
    assert not bows_the_wrong_way(lines, TRUTH, W).any()
    # judged by a plausible camera that is not the truth (zero-shot's error): still all kept
    other = KannalaBrandtCamera(436.0, 436.0, 664.0, 383.0, W, H, [0.02, -0.006, 0.001, 0.0])
    assert not bows_the_wrong_way(lines, other, W).any()


def test_predicted_line_is_the_lines_image_at_the_points_places():
    rng = np.random.default_rng(5)
    for line in line_curves(TRUTH, rng, 5, noise=0.0):
        assert np.abs(predicted_line(line, TRUTH) - line).max() < 1e-6
        shifted = line + np.array([0.0, 1.0]) * np.linspace(-1, 1, len(line))[:, None] ** 2
        assert np.abs(predicted_line(shifted, TRUTH) - line).max() > 0.1


@pytest.mark.parametrize('piece', [(0.0, 1.0), (0.0, 0.3), (0.35, 0.65), (0.7, 1.0)])
def test_a_bonnet_is_flagged_whole_and_in_the_short_pieces_a_detector_finds_it_in(piece):
    rng = np.random.default_rng(11)
    arc = bonnet(a0=piece[0], a1=piece[1], n=40) + rng.normal(0, 0.3, (40, 2))
    assert bows_the_wrong_way([arc], TRUTH, W).all()


def test_the_slight_inward_bow_of_a_nearly_rectilinear_lens_is_allowed():
    # a phone's ultra-wide corrected in software: its lines bow inward near the corners, by a
    # curvature well under the image width's (radius of curvature 3 widths here); judged against
    # a distortion-free pinhole, they are kept, while an arc of radius half the width is not
    rng = np.random.default_rng(2)
    pinhole = PinholeCamera(500.0, 500.0, W / 2, H / 2, W, H)
    gentle = [bonnet(radius=3.0 * W, half_width=0.25 * W) + rng.normal(0, 0.2, (40, 2)) for _ in range(5)]
    tight = bonnet(radius=0.5 * W, half_width=0.2 * W) + rng.normal(0, 0.2, (40, 2))
    assert not bows_the_wrong_way(gentle, pinhole, W).any()
    assert bows_the_wrong_way([tight], pinhole, W).all()
    # the allowance is a curvature (radius of curvature W / BOW_CURVATURE_FLOOR beyond the
    # prediction): the same shape at twice the resolution is judged the same
    assert bows_the_wrong_way([tight * 2], PinholeCamera(1000.0, 1000.0, W, H, 2 * W, 2 * H), 2 * W).all()
    at = W / BOW_CURVATURE_FLOOR
    assert not bows_the_wrong_way([bonnet(radius=1.3 * at, half_width=0.25 * W)], pinhole, W).any()
    assert bows_the_wrong_way([bonnet(radius=0.7 * at, half_width=0.25 * W)], pinhole, W).all()


def test_noisy_short_curves_are_not_flagged_for_their_noise():
    rng = np.random.default_rng(9)
    short = [np.stack([np.linspace(600, 640, 10), np.full(10, 700.0)], axis=1) + rng.normal(0, 1.0, (10, 2))
             for _ in range(400)]
    pinhole = PinholeCamera(500.0, 500.0, W / 2, H / 2, W, H)
    # three standard errors estimated from 10 points (7 degrees of freedom) pass by chance about
    # once in a hundred: at most 2 %, where a test of the bow alone would flag nearly half
    assert bows_the_wrong_way(short, pinhole, W).sum() <= 8


def test_refine_leaves_out_a_bonnet_seen_in_one_frame():
    # one frame: 14 scene lines, and a bonnet at the bottom found in six pieces (more curves than
    # the lines near it): without the bow test the fit bends the camera to straighten it
    rng = np.random.default_rng(21)
    lines = [Curve(c, 0) for c in line_curves(TRUTH, rng, 14, noise=0.2)]
    pieces = [Curve(bonnet(a0=k / 6, a1=(k + 1) / 6, n=20, radius=0.6 * W) + rng.normal(0, 0.2, (20, 2)), 0)
              for k in range(6)]
    curves = lines + pieces
    result = refine_camera(spec_of(TRUTH), curves)
    assert result.curves_bowed == 6
    assert not result.used[len(lines):].any()
    assert result.used[:len(lines)].sum() >= 12
    assert result.refined_camera is not None
    zero_shot = best_rotation_rms(result.zero_shot_camera, TRUTH)
    assert best_rotation_rms(result.camera, TRUTH) <= zero_shot + 0.3
    assert best_rotation_rms(result.refined_camera, TRUTH) < max(zero_shot, 1.0)


# A 116 x 68-degree action camera (a lens profile's Kannala-Brandt camera at 960 x 540) seen
# through a vignetted image circle 64 degrees across, with a vehicle's bonnet at the bottom
ACTION_CAMERA = KannalaBrandtCamera(462.48, 462.57, 484.40, 274.30, 960, 540, [-0.144544, 0.435628, -0.417918, 0.151617])
CIRCLE_RADIUS = 0.47 * 540


@pytest.fixture(scope='module')
def bonnet_frame():
    """One rendered frame of ACTION_CAMERA in a room, through its image circle, with a bonnet at
    the bottom, blur, noise and JPEG; and its spec (the camera's FOVs and the circle's)."""
    scene = scenes.make_scene('room', 4)
    nuisances = scenes.Nuisances(circle_radius=CIRCLE_RADIUS, vehicle=True, blur=0.6, noise=2.0, jpeg_quality=80)
    image, _ = scenes.render(ACTION_CAMERA, scene, pose=scenes.random_pose(scene, 40), seed=40, nuisances=nuisances)
    edge = ACTION_CAMERA.unproject(np.array([[ACTION_CAMERA.cx + CIRCLE_RADIUS, ACTION_CAMERA.cy]]))[0]
    circle_fov = 2 * math.degrees(math.atan2(math.hypot(edge[0], edge[1]), edge[2]))
    fovs = fields_of_view_through_axis(ACTION_CAMERA)
    spec = CameraSpec(960, 540, **fovs, circle_diameter=2 * CIRCLE_RADIUS, circle_fov=circle_fov)
    return image, spec


def test_a_bonnet_in_one_rendered_frame_does_not_make_refine_worse_than_zero_shot(bonnet_frame):
    # most of this frame's curves are on the bonnet: taken as lines they bent the camera 12 px
    # (24.6 px at 1920) off inside the circle, and that camera was accepted
    image, spec = bonnet_frame
    result = refine_from_images(spec, [image])
    assert result.curves_bowed >= 3
    inside = pixel_grid(960, 540, (65, 37))
    inside = inside[np.hypot(inside[:, 0] - ACTION_CAMERA.cx, inside[:, 1] - ACTION_CAMERA.cy) <= CIRCLE_RADIUS]
    zero_shot = best_rotation_rms(result.zero_shot_camera, ACTION_CAMERA, pixels=inside)
    returned = best_rotation_rms(result.camera, ACTION_CAMERA, pixels=inside)
    assert returned <= zero_shot + 0.15, (returned, zero_shot, result.reason)  # 0.3 px at 1920


def test_the_cli_says_how_many_curves_bowed_the_wrong_way(bonnet_frame, tmp_path, capsys):
    image, spec = bonnet_frame
    path = str(tmp_path / 'bonnet.png')
    cv2.imwrite(path, image)
    flags = ['--hfov', f'{spec.hfov:.2f}', '--vfov', f'{spec.vfov:.2f}',
             '--dfov', f'{spec.dfov:.2f}', '--circle-fov', f'{spec.circle_fov:.2f}']
    status, out, err = run_main(['refine', path, *flags], capsys)
    assert status in (0, 3), err
    bowed = [line for line in out.splitlines() if line.startswith('left out') and 'bowing toward' in line]
    assert len(bowed) == 1, out
    count = int(bowed[0].split()[2])
    assert count >= 3
    status, out, err = run_main(['refine', path, *flags, '--json'], capsys)
    assert json.loads(out)['refinement']['curves_bowed'] == count


def test_the_side_is_taken_from_the_principal_point_not_the_image_centre():
    # a principal point far left of the image centre: an arc between the two, bulging left toward
    # the principal point, bows the wrong way (judged from the image centre it would bow away)
    camera = PinholeCamera(500.0, 500.0, 0.3 * W, H / 2, W, H)
    t = np.linspace(-0.4, 0.4, 40)
    radius = 0.5 * W
    arc = np.stack([0.42 * W + radius * (1 - np.cos(t)), H / 2 + radius * np.sin(t)], axis=1)
    assert arc[:, 0].min() > camera.cx and arc[:, 0].max() < W / 2
    assert bows_the_wrong_way([arc], camera, W).all()


def test_the_allowance_follows_the_bow_the_lens_itself_gives_a_line():
    # a short equidistant fisheye bows its lines strongly (curvature up to 4 widths): every line is
    # kept; a straight pixel chord where this lens must bow a line so much is no line of it
    camera = KannalaBrandtCamera(300.0, 300.0, 640.0, 400.0, W, H, [0.0, 0.0, 0.0, 0.0])
    rng = np.random.default_rng(4)
    lines = line_curves(camera, rng, 100, noise=0.2)
    assert not bows_the_wrong_way(lines, camera, W).any()
    strong = []
    for line in lines:
        bow, _, half = bow_toward(line, (camera.cx, camera.cy))
        if -bow * 2 * W / half ** 2 > 2.5:
            chord = np.linspace(line[0], line[-1], len(line)) + rng.normal(0, 0.2, line.shape)
            strong.append(chord)
    assert len(strong) >= 20
    assert bows_the_wrong_way(strong, camera, W).all()


def test_too_few_points_are_not_judged():
    rng = np.random.default_rng(1)
    for n, judged in ((7, False), (8, True)):
        arc = bonnet(radius=0.5 * W, half_width=0.2 * W, n=n) + rng.normal(0, 0.2, (n, 2))
        assert bows_the_wrong_way([arc], TRUTH, W)[0] == judged


def test_predicted_line_keeps_the_curves_ends():
    rng = np.random.default_rng(6)
    for line in line_curves(TRUTH, rng, 5, noise=0.0):
        shifted = line + np.array([0.0, 3.0]) * (1 - np.linspace(-1, 1, len(line))[:, None] ** 2)
        assert np.abs(predicted_line(shifted, TRUTH)[[0, -1]] - shifted[[0, -1]]).max() < 1e-6


def test_curves_are_judged_against_zero_shot_even_from_another_start(monkeypatch):
    import zeroshot_calib_ros.core.estimation.refine as refine_module
    judged = []
    real = refine_module.bows_the_wrong_way
    monkeypatch.setattr(refine_module, 'bows_the_wrong_way', lambda k, c, w: judged.append(c) or real(k, c, w))
    rng = np.random.default_rng(21)
    curves = [Curve(c, 0) for c in line_curves(TRUTH, rng, 14, noise=0.2)]
    start = KannalaBrandtCamera(445.0, 445.0, 660.0, 380.0, W, H, [0.02, -0.006, 0.001, 0.0])
    result = refine_camera(spec_of(TRUTH), curves, initial=start)
    assert judged and all(c is result.zero_shot_camera for c in judged)


def _bonnet_pieces(rng, image, count=6):
    return [Curve(bonnet(a0=k / count, a1=(k + 1) / count, n=20, radius=0.6 * W) + rng.normal(0, 0.2, (20, 2)), image)
            for k in range(count)]


def test_the_bowed_curves_leave_their_images_with_them_and_are_counted_as_rejected():
    # the bonnet alone in image 0, the lines in image 1: only image 1 is used
    rng = np.random.default_rng(21)
    pieces = _bonnet_pieces(rng, 0)
    lines = [Curve(c, 1) for c in line_curves(TRUTH, rng, 14, noise=0.2)]
    result = refine_camera(spec_of(TRUTH), pieces + lines)
    assert result.curves_bowed == 6 and not result.used[:6].any()
    assert result.images_used == 1
    assert result.curves_rejected == result.curves_bowed + (len(lines) - result.lines_used)
    # refused before any fit (too few lines): the bowed curves are still the rejected ones
    few = refine_camera(spec_of(TRUTH), _bonnet_pieces(rng, 0) + lines[:2])
    assert not few.accepted and few.reason.startswith('too few lines')
    assert few.curves_bowed == 6 and few.curves_rejected == 6


def test_the_cli_reports_the_bowed_count_not_every_rejected_curve(bonnet_frame, tmp_path, capsys, monkeypatch):
    import zeroshot_calib_ros.core.estimation.refine as refine_module
    image, spec = bonnet_frame
    path = str(tmp_path / 'bonnet.png')
    cv2.imwrite(path, image)
    real = refine_module.refine_from_images

    def fewer_bowed(*args, **kwargs):
        result = real(*args, **kwargs)
        result.curves_bowed, result.curves_rejected = 3, result.curves_rejected + 4
        return result

    monkeypatch.setattr(refine_module, 'refine_from_images', fewer_bowed)
    flags = ['--hfov', f'{spec.hfov:.2f}', '--vfov', f'{spec.vfov:.2f}', '--dfov', f'{spec.dfov:.2f}',
             '--circle-fov', f'{spec.circle_fov:.2f}']
    status, out, err = run_main(['refine', path, *flags], capsys)
    assert any(line.startswith('left out  3 curves bowing toward') for line in out.splitlines()), out
    status, out, err = run_main(['refine', path, *flags, '--json'], capsys)
    assert json.loads(out)['refinement']['curves_bowed'] == 3


def test_each_curve_is_judged_alone_whatever_lies_beside_it():
    # all curves are judged in one pass: a short curve, a degenerate one (one point repeated) and a
    # curve the camera cannot see (NaN rays) beside a bonnet leave its verdict, and theirs, alone
    rng = np.random.default_rng(8)
    arc = bonnet(radius=0.5 * W, half_width=0.2 * W) + rng.normal(0, 0.2, (40, 2))
    line = line_curves(TRUTH, rng, 1, noise=0.2)[0]
    short = arc[:5]
    same = np.repeat([[300.0, 200.0]], 12, axis=0)
    unseen = np.full((12, 2), np.nan)
    curves = [short, arc, same, line, unseen, arc[::-1]]
    assert bows_the_wrong_way(curves, TRUTH, W).tolist() == [False, True, False, False, False, True]
    assert bows_the_wrong_way(curves[::-1], TRUTH, W).tolist() == [True, False, False, False, True, False]


# A cinema camera with a 6 mm rectilinear-ish wide lens (a lens profile's camera at 960 x 506),
# seen through a vignetted image circle with a bonnet at the bottom whose edge curves as gently as
# the image is wide: its pieces curve inward by 0.7 to 1.0 image widths' curvature beyond what a
# line there would, under the floor the bow test had before, and a fit that took them was accepted
# 7 px worse than zero-shot (14.9 against 2.9 px at 1920)
WIDE_CINE = KannalaBrandtCamera(316.692, 317.095, 489.008, 252.200, 960, 506, [0.328212, 0.189701, -0.066741, 0.095334])


def test_a_bonnet_as_gentle_as_the_image_width_in_one_frame_does_not_make_refine_worse():
    radius = 0.47 * 506
    scene = scenes.make_scene('room', 207)
    nuisances = scenes.Nuisances(circle_radius=radius, vehicle=True, blur=0.6, noise=2.0, jpeg_quality=80)
    image, _ = scenes.render(WIDE_CINE, scene, pose=scenes.random_pose(scene, 2070), seed=2070, nuisances=nuisances)
    edge = WIDE_CINE.unproject(np.array([[WIDE_CINE.cx + radius, WIDE_CINE.cy]]))[0]
    spec = CameraSpec(960, 506, **fields_of_view_through_axis(WIDE_CINE), circle_diameter=2 * radius,
                      circle_fov=2 * math.degrees(math.atan2(math.hypot(edge[0], edge[1]), edge[2])))
    result = refine_from_images(spec, [image])
    inside = pixel_grid(960, 506, (65, 37))
    inside = inside[np.hypot(inside[:, 0] - WIDE_CINE.cx, inside[:, 1] - WIDE_CINE.cy) <= radius]
    zero_shot = best_rotation_rms(result.zero_shot_camera, WIDE_CINE, pixels=inside)
    returned = best_rotation_rms(result.camera, WIDE_CINE, pixels=inside)
    on_bonnet = np.array([np.mean(c.points[:, 1]) > WIDE_CINE.cy + 0.7 * radius for c in result.curves])
    # the bonnet's pieces left out (a short, noisy one may pass the test of its standard error)
    assert on_bonnet.sum() >= 3 and result.used[on_bonnet].sum() <= 1
    assert result.curves_bowed >= on_bonnet.sum() - 1
    assert returned <= zero_shot + 0.15, (returned, zero_shot, result.reason)  # 0.3 px at 1920
