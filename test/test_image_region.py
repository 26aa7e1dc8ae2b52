"""The valid image region (core/lines/image_region.py) and the image circle as evidence
(core/estimation/terms.py's ImageCircleTerm), on renders with the nuisances of real fisheye
photos (test/scenes.py's Nuisances: a vignetted image circle whose surround is dark but not
black, noisy and glowing, a vehicle body part at the bottom, blur, noise, JPEG).

The truth is the renderer's: the image circle is the camera's ``circle_radius`` about its
principal point. ROS-free.
"""
import math

import cv2
import numpy as np
import pytest

import scenes
from zeroshot_calib_ros.core.estimation.refine import refine_from_images
from zeroshot_calib_ros.core.estimation.terms import CIRCLE_CENTRE_SIGMA, FovTerm, ImageCircleTerm
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, PinholeCamera
from zeroshot_calib_ros.core.lens.wide_fov import WideFovCamera
from zeroshot_calib_ros.core.lines.image_region import (ImageCircle, combine_circles, find_image_circle,
                                                         find_image_region)
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec


def circular_camera(width, height, radius, cx, cy, fov_deg=190.0):
    """An equidistant-like wide camera whose ray at fov_deg / 2 lands on ``radius`` px, with that
    image circle."""
    probe = WideFovCamera(100.0, cx, cy, width, height, omega=1 / 100.0)
    theta = math.radians(fov_deg / 2)
    edge = probe.project(np.array([[math.sin(theta), 0.0, math.cos(theta)]]))[0]
    f = 100.0 * radius / (edge[0] - cx)
    return WideFovCamera(f, cx, cy, width, height, omega=1 / f, circle_radius=radius)


# a 190-degree circular fisheye on 4:3, the circle inside the frame, off-centre
CIRCULAR = circular_camera(640, 480, 220.0, 326.0, 236.0)
# a 190-degree lens on a 16:9 sensor: the frame clips the circle at the top and bottom
CLIPPED = circular_camera(640, 360, 250.0, 317.0, 183.0)


def render(camera, scene, seed, nuisances=scenes.ALL_NUISANCES, **kwargs):
    return scenes.render(camera, scene, seed=seed, pose='random', nuisances=nuisances, **kwargs)[0]


def assert_circle_near(found, camera, tolerance_px):
    assert found is not None
    errors = (found.cx - camera.cx, found.cy - camera.cy, found.radius - camera.circle_radius)
    assert max(abs(e) for e in errors) < tolerance_px, errors


@pytest.mark.parametrize('scene, seed', [('room', 1), ('street', 2), ('corridor', 1)])
def test_the_circle_of_a_190_degree_circular_lens_is_found_within_a_pixel(scene, seed):
    image = render(CIRCULAR, scene, seed)
    # the surround is not black: what a pure-black test (<= 3) would have missed
    outside = np.hypot(*np.meshgrid(np.arange(640) - CIRCULAR.cx, np.arange(480) - CIRCULAR.cy)) > 230
    assert np.median(image[outside]) > 8
    region = find_image_region(image)
    assert_circle_near(region.circle, CIRCULAR, 1.0)
    assert 0 < region.circle.centre_sigma_px < 1 and 0 < region.circle.radius_sigma_px < 1
    # the usable region stops inside the circle, by the margin
    yy, xx = np.nonzero(region.mask)
    assert np.max(np.hypot(xx - CIRCULAR.cx, yy - CIRCULAR.cy)) < CIRCULAR.circle_radius - region.margin_px + 1.5
    assert region.margin_px >= 4


@pytest.mark.parametrize('scene, seed', [('room', 1), ('street', 1), ('street', 2), ('corridor', 2)])
def test_a_circle_clipped_by_a_16_9_frame_fits_from_its_side_arcs(scene, seed):
    assert 2 * CLIPPED.circle_radius > CLIPPED.height  # clipped at the top and bottom
    image = render(CLIPPED, scene, seed)
    assert_circle_near(find_image_circle(image), CLIPPED, 1.5)


def test_no_circle_in_rectilinear_full_frame_or_dark_images():
    rectilinear = PinholeCamera(400.0, 400.0, 320.0, 240.0, 640, 480)
    full_frame = KannalaBrandtCamera(210.0, 210.0, 327.0, 176.0, 640, 360, [0.02, -0.01, 0.003, -0.0005])
    cases = {
        'rectilinear room': scenes.render(rectilinear, 'room', seed=1)[0],
        'rectilinear street, JPEG and noise': scenes.render(
            rectilinear, 'street', seed=2, nuisances=scenes.Nuisances(circle=False, noise=2.0, jpeg_quality=75))[0],
        'full-frame fisheye corridor': scenes.render(full_frame, 'corridor', seed=2)[0],
        'full-frame fisheye with a vehicle': scenes.render(
            full_frame, 'street', seed=3, nuisances=scenes.Nuisances(circle=False, vehicle=True))[0],
        'dark room (night)': scenes.render(full_frame, 'room', seed=1, exposure=40.0)[0],
        'dark rectilinear street': scenes.render(rectilinear, 'street', seed=1, exposure=30.0)[0],
    }
    # a dark floor touching the border: a textured, noisy dark lower half under a lit wall
    rng = np.random.default_rng(3)
    floor = np.full((480, 640), 150.0)
    floor[300:] = 12.0
    floor[100:200, 200:300] = 60.0
    cases['dark floor'] = np.clip(cv2.GaussianBlur(floor, (0, 0), 1.0) + rng.normal(0, 3, floor.shape), 0,
                                  255).astype(np.uint8)
    for name, image in cases.items():
        region = find_image_region(image)
        assert region.circle is None, (name, region.circle)
        # all usable, but for the black (<= 3) regions a dark image has at its border
        assert region.usable_fraction > (0.9 if 'dark' in name else 0.97), (name, region.usable_fraction)


def test_black_and_blown_out_borders_are_left_out():
    image, _ = scenes.render(PinholeCamera(300.0, 300.0, 320.0, 240.0, 640, 480), 'room', seed=1)
    image = image.copy()
    image[:60] = 0            # letterbox bars
    image[-60:] = 0
    image[:, -40:] = 255      # a blown-out strip
    region = find_image_region(image)
    assert region.circle is None
    assert not region.mask[:60 + 4].any() and not region.mask[-60 - 4:].any()
    assert not region.mask[:, -40 - 4:].any()
    assert region.mask[240, 320] and region.mask[100:380, 10:590].mean() > 0.95


def test_measurements_of_several_images_are_combined():
    a = ImageCircle(100.0, 50.0, 200.0, 0.5, 0.5)
    b = ImageCircle(101.0, 50.0, 200.0, 0.5, 0.5)
    both = combine_circles([a, None, b])
    assert both.images == 2 and both.cx == pytest.approx(100.5) and both.radius == pytest.approx(200.0)
    # two measurements 1 px apart with sigmas 0.5: more scatter than the sigmas allow, so the
    # combined sigma is wider than the 0.35 px two agreeing measurements would give
    assert both.centre_sigma_px > 0.5 / math.sqrt(2) + 0.1
    assert combine_circles([None, None]) is None and combine_circles([a]) is a


def test_image_circle_term_states_the_principal_point_and_the_circle_fov():
    camera = circular_camera(640, 480, 220.0, 326.0, 236.0)
    term = ImageCircleTerm(326.0, 236.0, 220.0, 0.3, 0.3, 640, circle_fov=190.0, tolerance_deg=1.0,
                           reference=camera)
    assert np.allclose(term.residuals(camera), 0.0, atol=1e-6)
    assert term.sigma[0] == pytest.approx(math.hypot(0.3, CIRCLE_CENTRE_SIGMA * 640))
    assert 1.0 < term.sigma[2] < 1.1   # the FOV tolerance, widened a little by the radius's 0.3 px
    moved = WideFovCamera(camera.f, camera.cx + 3, camera.cy, 640, 480, omega=camera.omega, circle_radius=220.0)
    assert term.residuals(moved)[0] == pytest.approx(3.0)
    wider = WideFovCamera(camera.f * 0.97, camera.cx, camera.cy, 640, 480, omega=camera.omega / 0.97)
    assert term.residuals(wider)[2] > 2.0   # a shorter focal length sees more across the same circle
    centre_only = ImageCircleTerm(326.0, 236.0, 220.0, 0.3, 0.3, 640)
    assert len(centre_only.residuals(camera)) == 2
    # the spec's circle FOV is left to the measured circle; a spec with nothing else has no FovTerm
    spec = CameraSpec(640, 480, circle_diameter=440.0, circle_fov=190.0)
    assert FovTerm.from_spec(spec, leave_out=('circle',)) is None
    assert FovTerm.from_spec(CameraSpec(640, 480, hfov=200, circle_diameter=440.0, circle_fov=190.0),
                             leave_out=('circle',)).keys == ('hfov',)


def dense_error_px(camera, truth, max_deg=93.0):
    """RMS pixel distance between ``camera``'s and the truth's images of rays up to max_deg off
    axis (inside the image circle), no rotation."""
    theta, phi = np.meshgrid(np.radians(np.linspace(0, max_deg, 32)), np.linspace(0, 2 * np.pi, 24, endpoint=False))
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum((camera.project(rays) - truth.project(rays)) ** 2, axis=1))))


def test_refining_a_circular_render_with_nuisances_is_not_worse_than_zero_shot():
    images = [render(CIRCULAR, 'room', 1), render(CIRCULAR, 'corridor', 1)]
    regions = [find_image_region(im) for im in images]
    circle = combine_circles([r.circle for r in regions])
    spec = CameraSpec(640, 480, circle_diameter=circle.diameter, circle_fov=190.0)
    result = refine_from_images(spec, images, regions=regions)
    assert result.image_circle == circle and result.circle_measured_in == 2
    zero_shot = dense_error_px(result.zero_shot_camera, CIRCULAR)
    assert zero_shot > 4  # zero-shot puts the principal point at the image centre, 7 px off
    if result.accepted:
        assert dense_error_px(result.camera, CIRCULAR) < zero_shot, result.reason
    else:
        assert result.camera is result.zero_shot_camera, result.reason
    # the fit itself, refused or not, has the principal point of the circle and the lines
    fitted = result.refined_camera
    assert math.hypot(fitted.cx - CIRCULAR.cx, fitted.cy - CIRCULAR.cy) < 1.5
    assert dense_error_px(fitted, CIRCULAR) < zero_shot
