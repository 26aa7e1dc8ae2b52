"""The detector's options and limits (core/lines/detect.py) as a user sets them: merging across
gaps, the shortest curve returned, the gradient floor, and a circular fisheye searched inside
its image circle; against OpenCV's own gradient and rendered truth."""
import numpy as np
import pytest

import scenes
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
from zeroshot_calib_ros.core.lines.detect import DEFAULTS, EdgePoints, curves_from_edges, detect_curves, make_views

KB = KannalaBrandtCamera(480.0, 480.0, 660.0, 345.0, 1280, 720, [0.02, -0.01, 0.003, -0.0005])
SMALL = KannalaBrandtCamera(240.0, 240.0, 330.0, 172.0, 640, 360, [0.02, -0.01, 0.003, -0.0005])


def _row_piece(x0, x1, y):
    """Edge points every 2 px along the row y from x0 to x1: through a radial lens with its
    principal point on that row, the image of a straight 3-D line (their rays share a plane
    through the optical axis)."""
    x = np.arange(x0, x1 + 1e-9, 2.0)
    return np.stack([x, np.full_like(x, y)], axis=1)


def test_a_short_piece_beyond_a_gap_wider_than_its_length_is_not_merged():
    """Merging across a gap: at most ``gap_ratio`` (1.5) times the SHORTER side. Two pieces on
    one great circle of the camera (a row through its principal point): 300 px, a gap of 70 px,
    then 40 px. 70 > 1.5 x 40, so they stay two curves (a short piece across a wide gap may be
    a chance alignment of another thing); across a 50 px gap (< 60) they are one curve."""
    y = KB.cy
    options = dict(DEFAULTS, min_length_px=30.0)

    def curves(gap):
        a = _row_piece(700.0, 1000.0, y)
        b = _row_piece(1000.0 + gap, 1040.0 + gap, y)
        points = np.concatenate([a, b])
        seg = np.r_[np.zeros(len(a), int), np.ones(len(b), int)]
        edges = EdgePoints((KB.width, KB.height), [(0, (points, np.full(len(points), 60.0), seg))], options)
        return curves_from_edges(edges, KB)

    apart = curves(70.0)
    assert sorted(round(c.length_px) for c in apart) == [40, 300]
    joined = curves(50.0)
    assert len(joined) == 1 and joined[0].points[:, 0].min() == 700.0 and joined[0].points[:, 0].max() == 1090.0


@pytest.fixture(scope='module')
def corridor():
    return scenes.render_scene(SMALL, 'corridor', seed=3).image, make_views(SMALL)


def _path_length(points):
    return float(np.sum(np.hypot(*np.diff(points, axis=0).T)))


def test_min_length_option_is_the_shortest_curve_returned(corridor):
    """``min_length_px`` (an option of ``detect_curves``): no curve shorter than it along its
    points is returned; a shorter minimum than the default (4 % of the diagonal, 29 px here)
    returns the short curves the default leaves out, a longer one only the long curves."""
    image, views = corridor
    default = detect_curves(image, SMALL, views=views)
    short = detect_curves(image, SMALL, views=views, min_length_px=12.0)
    long = detect_curves(image, SMALL, views=views, min_length_px=80.0)
    floor = 0.04 * np.hypot(640, 360)
    assert min(_path_length(c.points) for c in default) >= floor - 1e-6
    assert len(short) > len(default) and min(_path_length(c.points) for c in short) < floor
    assert all(_path_length(c.points) >= 12.0 - 1e-6 for c in short)
    assert long and len(long) < len(default)
    assert all(_path_length(c.points) >= 80.0 - 1e-6 for c in long)


def test_min_gradient_is_a_floor_under_every_curves_edge_strength(corridor):
    """``min_gradient`` (grey levels per pixel at the edge, smoothed image): points weaker than it
    are dropped whatever their segment's median, so with min_gradient = 25 only the strong edges
    of a rendered corridor remain: every curve's strength (median gradient at its points) is at
    least 25, and OpenCV's own gradient of the image smoothed the same way (Sobel / 8 on the
    Gaussian sigma 0.7; 3x3 averaging reads edges lower, 0.5-0.9 of ours) is at least half that
    at the points; the default (4) returns weaker curves too."""
    import cv2
    image, views = corridor
    default = detect_curves(image, SMALL, views=views)
    strong = detect_curves(image, SMALL, views=views, min_gradient=25.0)
    assert any(c.strength < 25.0 for c in default)  # the case's premise: weak edges exist
    assert strong and len(strong) < len(default)
    assert all(c.strength >= 25.0 for c in strong)
    smooth = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 0.7)
    magnitude = np.hypot(cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)) / 8
    for c in strong:
        p = c.points.astype(np.float32)
        at = cv2.remap(magnitude, p[:, 0].reshape(1, -1), p[:, 1].reshape(1, -1), cv2.INTER_LINEAR)
        assert np.median(at) >= 0.5 * 25.0


def test_a_circular_fisheye_camera_is_searched_inside_its_image_circle():
    """``detect_curves`` through a circular fisheye camera that knows its image circle (a
    ``WideFovCamera`` with ``circle_radius``, as ``solve_zero_shot`` gives for the circle form):
    the views keep the pixels inside the circle, so the room's lines there are found (at least
    20 curves, straight under the true camera to half a pixel, none outside the circle)."""
    from test_detect import circular_190, great_circle_rms
    truth = circular_190()
    image, _ = scenes.render(truth, 'room', seed=1, pose='random')
    curves = detect_curves(image, truth)
    assert len(curves) >= 20
    for c in curves:
        assert np.all(np.hypot(c.points[:, 0] - truth.cx, c.points[:, 1] - truth.cy) < truth.circle_radius)
    assert np.median([great_circle_rms(truth, c.points) for c in curves]) < 0.5
