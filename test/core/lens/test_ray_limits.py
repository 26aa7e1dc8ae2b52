"""core/lens/ray_limits.py and RadialKannalaBrandtCamera: where a lens stops giving rays inside its
image, checked against the closed forms of the equidistant law and of a Kannala-Brandt polynomial
that turns back (theta_d = theta (1 + k1 theta^2) peaks at theta = 1 / sqrt(-3 k1))."""
import math

import numpy as np
import pytest

from zeroshot_calib_ros.core.lens.fitting import fit_plumb_bob
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, RadialKannalaBrandtCamera
from zeroshot_calib_ros.core.lens.ray_limits import edge_angle_deg, missing_fov, plumb_bob_refusal, ray_reach

K1_TURNING = -0.2
THETA_PEAK = 1 / math.sqrt(-3 * K1_TURNING)
THETA_D_PEAK = THETA_PEAK * (1 + K1_TURNING * THETA_PEAK ** 2)


def equidistant(f, width, height):
    return KannalaBrandtCamera(f, f, width / 2, height / 2, width, height, [0, 0, 0, 0])


def turning_back(f=300.0, width=800, height=400):
    """A lens whose curve peaks at f * THETA_D_PEAK = 258 px: beyond the left and right edges'
    400 px there is no ray, the top and bottom (200 px) have rays."""
    return KannalaBrandtCamera(f, f, width / 2, height / 2, width, height, [K1_TURNING, 0, 0, 0])


def test_the_edge_angle_of_an_equidistant_lens_is_its_corner_radius_over_f():
    camera = equidistant(500.0, 1280, 720)
    assert edge_angle_deg(camera) == pytest.approx(math.degrees(math.hypot(640, 360) / 500.0), rel=1e-9)


def test_a_border_pixel_without_a_ray_gives_no_edge_angle():
    assert math.isnan(edge_angle_deg(turning_back()))


def test_rays_reach_as_far_as_the_lens_curve_rises():
    camera = turning_back()
    assert ray_reach(camera, (0, 200)) == pytest.approx(300.0 * THETA_D_PEAK, rel=1e-6)
    assert ray_reach(camera, (400, 0)) == pytest.approx(200.0, rel=1e-9)  # the whole way: a ray at the edge


def test_plumb_bob_represents_a_lens_below_90_degrees_off_axis_only():
    narrow = equidistant(1000.0, 1280, 720)
    assert plumb_bob_refusal(narrow, 0.1) is None
    assert plumb_bob_refusal(narrow, math.nan) is not None  # a fit without a finite error
    wide = equidistant(300.0, 1280, 720)  # corner 734 px / 300 px: 140 degrees off-axis
    corner_deg = math.degrees(math.hypot(640, 360) / 300.0)
    assert plumb_bob_refusal(wide, 0.1).startswith(f'it sees {corner_deg:.1f} degrees off-axis at the image edge')
    assert 'projects through a pinhole' in plumb_bob_refusal(wide, 0.1)
    assert plumb_bob_refusal(turning_back(), 0.1).startswith('it has image pixels without a ray')


def test_a_missing_fov_names_the_edge_without_a_ray_and_how_far_rays_reach():
    camera = turning_back()
    fovs = camera.fields_of_view()
    assert math.isnan(fovs['hfov']) and math.isfinite(fovs['vfov'])
    missing = missing_fov(camera, fovs)
    assert (missing.fov, missing.side, missing.edge_distance_px) == ('hfov', 'left', 400.0)
    assert missing.reach_px == pytest.approx(300.0 * THETA_D_PEAK, rel=1e-6)
    normal = equidistant(500.0, 1280, 720)
    assert missing_fov(normal, normal.fields_of_view()) is None


def test_a_non_finite_fov_with_rays_at_both_edges_is_still_missing():
    camera = equidistant(500.0, 1280, 720)
    missing = missing_fov(camera, {'hfov': math.nan, 'vfov': 60.0})
    assert (missing.fov, missing.side, missing.reach_px) == ('hfov', None, None) and math.isnan(missing.value)


def test_the_radial_view_of_a_kannala_brandt_camera_is_the_same_lens():
    camera = KannalaBrandtCamera(420.0, 420.0, 645.0, 358.0, 1280, 720, [0.02, -0.01, 0.003, -0.0005])
    view = RadialKannalaBrandtCamera(camera)
    assert (view.f, view.cx, view.cy, view.width, view.height) == (420.0, 645.0, 358.0, 1280, 720)
    pixels = np.array([[0.0, 0.0], [1280.0, 720.0], [100.0, 600.0], [645.0, 358.0]])
    np.testing.assert_allclose(view.unproject(pixels), camera.unproject(pixels), atol=1e-12)
    rays = camera.unproject(pixels)
    np.testing.assert_allclose(view.project(rays), pixels, atol=1e-9)
    # its ROS plumb_bob fit is the Kannala-Brandt camera's (which the fit also takes as it is)
    np.testing.assert_allclose(fit_plumb_bob(view).D, fit_plumb_bob(camera).D, rtol=1e-9, atol=1e-12)
