"""Curves that stay put across frames (core/lines/static_curves.py): the vehicle's or robot's own
body in view is left out of the refinement; the scene's lines, which move with the camera, are
kept; a camera that did not move keeps everything. ROS-free."""
import json
import math

import cv2
import numpy as np
import pytest

import scenes
from cli_run import run_main
from pictures import sheet_panels
from test_image_region import CIRCULAR, dense_error_px, render
from zeroshot_calib_ros.core.estimation.refine import refine_from_images
from zeroshot_calib_ros.core.lines.detect import Curve
from zeroshot_calib_ros.core.lines.static_curves import image_gradients, same_edge_share, static_curves
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

W, H = 640, 480


def arc(cx, cy, r, a0, a1, n=60):
    t = np.linspace(a0, a1, n)
    return np.stack([cx + r * np.cos(t), cy + r * np.sin(t)], axis=1)


def segment(x0, y0, x1, y1, n=40):
    return np.stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n)], axis=1)


def stroke(canvas, points, value, width=3):
    """A ``width``-px stroke of ``value`` beside ``points``: the curve is its edge, as detectors find it."""
    tangent = np.gradient(points, axis=0)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1) / np.linalg.norm(tangent, axis=1, keepdims=True)
    shifted = points + normal * (width / 2 + 0.5)
    cv2.polylines(canvas, [np.round(shifted).astype(np.int32).reshape(-1, 1, 2)], False, value, width)


def draw(curves, count, seed=0):
    """Frames (grey, noisy) with every curve of each frame the edge of a bright stroke."""
    rng = np.random.default_rng(seed + 100)
    images = []
    for image in range(count):
        canvas = np.clip(rng.normal(90, 3, (H, W)), 0, 255).astype(np.uint8)
        for c in curves:
            if c.image == image:
                stroke(canvas, c.points, 200)
        images.append(canvas)
    return images


def frames_with_a_body(count=3, jitter=0.3, seed=0):
    """``count`` frames, each: the body's arc at the same pixels (sub-pixel detector noise) and four
    scene lines that move with the camera; (curves, images)."""
    rng = np.random.default_rng(seed)
    curves = []
    for image in range(count):
        body = arc(320, 700, 330, math.radians(235), math.radians(305)) + rng.normal(0, jitter, (60, 2))
        curves.append(Curve(body, image=image))
        for k in range(4):
            x0, y0 = rng.uniform(40, 600), rng.uniform(40, 300)
            angle = rng.uniform(0, math.pi)
            curves.append(Curve(segment(x0, y0, x0 + 150 * math.cos(angle), y0 + 150 * math.sin(angle)), image=image))
    return curves, draw(curves, count, seed)


def test_the_body_that_stays_put_is_found_in_every_frame_and_the_moving_lines_are_kept():
    curves, images = frames_with_a_body()
    static = static_curves(curves, images)
    bodies = np.array([k % 5 == 0 for k in range(len(curves))])
    np.testing.assert_array_equal(static, bodies)


def test_gradients_made_ahead_are_the_ones_used_and_give_the_same_verdicts():
    """refine makes each image's gradients in its detection threads and hands them over: the
    verdicts must be those static_curves reaches on its own, and the handed-over gradients must be
    the ones sampled (an image whose gradients are all zero shows no edge: its body is not found
    there, so with two frames nothing is static)."""
    curves, images = frames_with_a_body()
    ahead = {k: image_gradients(image) for k, image in enumerate(images)}
    np.testing.assert_array_equal(static_curves(curves, images, dict(ahead)), static_curves(curves, images))
    two = [c for c in curves if c.image < 2]
    assert static_curves(two, images[:2]).any()
    blank = {0: ahead[0], 1: np.zeros_like(ahead[1])}
    assert not static_curves(two, images[:2], blank).any()


def test_the_body_is_found_where_the_detector_saw_only_part_of_it_in_the_other_frames():
    """The detector breaks a rim into different pieces in every frame: the edge is compared, not the pieces."""
    curves, images = frames_with_a_body()
    pieces = [Curve(c.points[:20] if c.image == 0 else c.points[30:], image=c.image) if k % 5 == 0 else c
              for k, c in enumerate(curves)]
    assert static_curves(pieces, images).sum() == 3


def test_two_frames_are_enough_and_one_is_not():
    curves, images = frames_with_a_body(count=2)
    assert static_curves(curves, images).sum() == 2
    one = [c for c in curves if c.image == 0]
    assert not static_curves(one, images[:1]).any()


def test_a_line_that_moved_by_a_few_pixels_is_not_static():
    curves, _ = frames_with_a_body(count=2)
    line = segment(100, 100, 400, 160)
    moved = line + [0.0, 8.0]
    curves += [Curve(line, image=0), Curve(moved, image=1)]
    static = static_curves(curves, draw(curves, 2))
    assert not static[-2:].any() and static.sum() == 2


def test_a_camera_that_did_not_move_keeps_every_curve():
    """The same scene in every frame (a fixed camera): the curves are the scene's."""
    rng = np.random.default_rng(3)
    scene = [segment(*rng.uniform(40, 440, 4)) for _ in range(6)]
    curves = [Curve(p + rng.normal(0, 0.2, p.shape), image=i) for i in range(3) for p in scene]
    assert not static_curves(curves, draw(curves, 3)).any()


def test_a_body_hidden_in_some_frames_is_static_where_it_is_seen_in_three_quarters_of_the_others():
    curves, _ = frames_with_a_body(count=5)
    # the body hidden in frame 4 (something passes in front): frames 0-3 see it in 3 of their 4 others
    hidden_once = [c for k, c in enumerate(curves) if not (k % 5 == 0 and c.image == 4)]
    static = static_curves(hidden_once, draw(hidden_once, 5))
    assert static.sum() == 4 and all(hidden_once[i].image < 4 for i in np.nonzero(static)[0])
    # hidden in frames 3 and 4: seen in 2 of 4 others, as often as two frames share a scene line by chance
    hidden_twice = [c for k, c in enumerate(curves) if not (k % 5 == 0 and c.image >= 3)]
    assert not static_curves(hidden_twice, draw(hidden_twice, 5)).any()


def test_a_scene_line_two_of_three_frames_share_by_chance_is_kept():
    curves, _ = frames_with_a_body(count=3)
    shared = segment(372, 222, 371, 263)
    curves += [Curve(shared, image=0), Curve(shared + 0.3, image=1)]
    static = static_curves(curves, draw(curves, 3))
    assert not static[-2:].any() and static.sum() == 3


def test_a_faint_texture_where_a_strong_edge_was_is_not_the_same_edge():
    curves, images = frames_with_a_body(count=2)
    without_body = [c for k, c in enumerate(curves) if not (k % 5 == 0 and c.image == 1)]
    faint = draw(without_body, 2)[1]
    stroke(faint, curves[0].points, 100)
    assert static_curves(without_body, [images[0], faint]).sum() == 0


def test_edges_that_alternate_along_the_curve_are_a_texture_not_the_same_edge():
    own = np.full(40, 20.0)
    tiles = np.where(np.arange(40) // 5 % 2 == 0, 15.0, -15.0)  # a tiled floor's edges under it
    assert same_edge_share(own, tiles) == 0.5
    assert same_edge_share(own, -np.full(40, 8.0)) == 1.0  # the scene beside the body darker now
    assert same_edge_share(own, np.full(40, 4.0)) == 0.0  # too faint


def on_vehicle_rim(points, width, height, tolerance_px=10.0):
    """Share of ``points`` within ``tolerance_px`` of the rendered vehicle body's rim (test/scenes.py's
    ellipse: centre (0.5 w, 1.22 h), semi-axes 0.42 w, 0.36 h)."""
    ex, ey, a, b = 0.5 * width, 1.22 * height, 0.42 * width, 0.36 * height
    f = np.hypot((points[:, 0] - ex) / a, (points[:, 1] - ey) / b)
    return float(np.mean(np.abs(f - 1.0) * min(a, b) < tolerance_px))


@pytest.fixture(scope='module')
def vehicle_frames():
    """Three views of a 190-degree circular fisheye from a car, its bonnet in view at the bottom."""
    return [render(CIRCULAR, scene, seed) for scene, seed in (('room', 1), ('corridor', 1), ('corridor', 3))]


def test_refine_leaves_out_the_vehicle_body_seen_in_every_frame(vehicle_frames):
    """The bonnet's rim is found in every frame and left out; no curve the fit used lies on it; the
    principal point is the image circle's and the lines'."""
    spec = CameraSpec(W, H, circle_diameter=2 * CIRCULAR.circle_radius, circle_fov=190.0)
    result = refine_from_images(spec, vehicle_frames)
    assert len(result.static_curves) >= 3, 'the rim in each of the three frames'
    assert all(on_vehicle_rim(c.points, W, H) > 0.5 for c in result.static_curves)
    used = [c for c, ok in zip(result.curves, result.used) if ok]
    assert used and max(on_vehicle_rim(c.points, W, H) for c in used) < 0.5
    fitted = result.refined_camera
    assert math.hypot(fitted.cx - CIRCULAR.cx, fitted.cy - CIRCULAR.cy) < 1.5
    if result.accepted:
        assert dense_error_px(result.camera, CIRCULAR) < dense_error_px(result.zero_shot_camera, CIRCULAR)
    assert scenes.ALL_NUISANCES.vehicle


def test_the_cli_says_what_it_left_out_and_draws_it(vehicle_frames, tmp_path, capsys):
    paths = []
    for k, image in enumerate(vehicle_frames):
        paths.append(str(tmp_path / f'frame{k}.png'))
        cv2.imwrite(paths[-1], image)
    debug = str(tmp_path / 'debug.png')
    status, out, err = run_main(['refine', *paths, '--circle-fov', '190', '--debug-image', debug], capsys)
    assert status == (0 if 'refined   yes' in out else 3), err  # 3: ran, not refined (documented)
    left_out = [line for line in out.splitlines() if line.startswith('left out')]
    assert len(left_out) == 1 and "own body" in left_out[0], out
    assert 'stood still' in left_out[0] and 'give one image' in left_out[0], out  # what a still camera does
    assert int(left_out[0].split()[2]) >= 3
    canvas = cv2.imread(debug)
    panels = sheet_panels(canvas, H / W)  # the contact sheet: a panel per frame
    assert len(panels) == len(vehicle_frames)
    for x, y, w, h in panels:
        orange = np.all(np.abs(canvas[y:y + h, x:x + w].astype(int) - (0, 140, 255)) <= 40, axis=2)
        ys = np.nonzero(orange)[0]
        assert len(ys) > 50 * (w / W) and np.median(ys) > 0.8 * h  # drawn where the bonnet is, in each
    status, out, err = run_main(['refine', *paths, '--circle-fov', '190', '--json'], capsys)
    # the same count in --json as in the text
    record = json.loads(out)
    assert status == (0 if record['refinement']['accepted'] else 3)
    assert record['refinement']['curves_static'] == int(left_out[0].split()[2])


def test_curves_too_short_to_judge_are_kept_and_change_no_other_verdict():
    """Curves with fewer than three usable points (hand-made, or with NaN points) are not judged:
    they are kept, and every other curve is judged in its own image as without them. Here a
    scene line of frame 1 lies where frame 0 has only a faint texture: judged in frame 1 (its
    own), frame 0's edge is too faint to be the same edge, so the line is kept."""
    curves, _ = frames_with_a_body(count=2)
    line = Curve(segment(100, 380, 400, 330), image=1)
    ordered = [c for c in curves if c.image == 0] + [line] + [c for c in curves if c.image == 1]
    images = draw(ordered, 2)
    stroke(images[0], line.points, 100)
    verdict = static_curves(ordered, images)
    assert list(np.flatnonzero(verdict)) == [0, 6]  # the two bodies; the line (5) is not static
    short = [Curve(np.array([[50.0, 60.0], [58.0, 60.0]]), image=0),
             Curve(np.array([[70.0, 60.0], [np.nan, np.nan], [90.0, 60.0]]), image=1)]
    mixed = [short[0]] + ordered[:5] + [short[1]] + ordered[5:]
    got = static_curves(mixed, images)
    assert not got[0] and not got[6]
    np.testing.assert_array_equal(np.delete(got, [0, 6]), verdict)
    assert not static_curves(short, images).any()
