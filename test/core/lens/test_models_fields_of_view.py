"""CameraModel.fields_of_view: half-angles on each side of the principal point, so FOVs past
180 degrees are not folded back (the angle between two rays never exceeds 180)."""
import math

import numpy as np
import pytest

from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, PinholeCamera, PlumbBobCamera


def equidistant(w, h, f, cx=None, cy=None):
    return KannalaBrandtCamera(f, f, w / 2 if cx is None else cx, h / 2 if cy is None else cy, w, h, np.zeros(4))


@pytest.mark.parametrize('half_deg', [30.0, 59.0, 89.0, 91.0, 103.0, 120.0, 170.0])
def test_equidistant_law_fovs_are_twice_the_edge_angle(half_deg):
    w, h = 848, 800
    f = (w / 2) / math.radians(half_deg)  # r = f theta
    fovs = equidistant(w, h, f).fields_of_view()
    assert fovs['hfov'] == pytest.approx(2 * half_deg, abs=1e-9)
    assert fovs['vfov'] == pytest.approx(2 * math.degrees((h / 2) / f), abs=1e-9)
    diagonal_half = math.degrees(math.hypot(w, h) / 2 / f)
    if diagonal_half < 180:
        assert fovs['dfov'] == pytest.approx(2 * diagonal_half, abs=1e-9)
    else:  # the corners would be more than 180 degrees off-axis: no ray
        assert math.isnan(fovs['dfov'])


def test_off_centre_principal_point_sums_both_sides():
    w, h, f = 800, 600, 200.0
    cx, cy = 500.0, 250.0
    fovs = equidistant(w, h, f, cx, cy).fields_of_view()
    assert fovs['hfov'] == pytest.approx(math.degrees((cx + (w - cx)) / f), abs=1e-9)
    assert fovs['vfov'] == pytest.approx(math.degrees((cy + (h - cy)) / f), abs=1e-9)


def test_pinhole_matches_atan_formula():
    w, h, f = 640, 480, 400.0
    fovs = PinholeCamera(f, f, 300.0, 200.0, w, h).fields_of_view()
    assert fovs['hfov'] == pytest.approx(math.degrees(math.atan(300 / f) + math.atan(340 / f)), abs=1e-9)
    assert fovs['vfov'] == pytest.approx(math.degrees(math.atan(200 / f) + math.atan(280 / f)), abs=1e-9)
    diag = math.degrees(math.atan(math.hypot(320, 240) / f)) * 2
    assert PinholeCamera(f, f, 320, 240, w, h).fields_of_view()['dfov'] == pytest.approx(diag, abs=1e-9)


def test_principal_point_outside_the_image_subtracts():
    w, h, f = 400, 300, 300.0
    fovs = PinholeCamera(f, f, -100.0, 150.0, w, h).fields_of_view()
    assert fovs['hfov'] == pytest.approx(math.degrees(math.atan(500 / f) - math.atan(100 / f)), abs=1e-9)


def test_no_ray_at_an_edge_is_nan():
    camera = KannalaBrandtCamera(300, 300, 400, 250, 800, 500, [-0.5, 0, 0, 0])  # turns back at 163 px
    fovs = camera.fields_of_view()
    assert math.isnan(fovs['hfov']) and math.isnan(fovs['vfov'])


def test_plumb_bob_below_180_unchanged():
    camera = PlumbBobCamera(500, 500, 330, 235, 640, 480, [-0.2, 0.05, 0.001, -0.002, 0.0])
    w, h, cx, cy = 640, 480, 330.0, 235.0
    r = camera.unproject(np.array([[0, cy], [w, cy], [cx, 0], [cx, h], [0, 0], [w, h]], float))
    plain = [math.degrees(math.acos(np.clip(np.dot(r[i], r[i + 1]), -1, 1))) for i in (0, 2, 4)]
    got = camera.fields_of_view()
    assert [got['hfov'], got['vfov'], got['dfov']] == pytest.approx(plain, abs=1e-6)
