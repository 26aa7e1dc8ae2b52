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
from scenes import soft_rim
from zeroshot_calib_ros.core.estimation.refine import refine_from_images
from zeroshot_calib_ros.core.estimation.terms import CIRCLE_CENTRE_SIGMA, FovTerm, ImageCircleTerm
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, PinholeCamera
from zeroshot_calib_ros.core.lens.wide_fov import WideFovCamera
from zeroshot_calib_ros.core.lines.image_region import (ImageCircle, combine_circles, default_margin_px,
                                                         find_image_circle, find_image_region)
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


@pytest.mark.parametrize('frame', ['4:3', '16:9 clipping the circle'])
@pytest.mark.parametrize('fade_px', [12, 20, 30])
def test_a_soft_rim_states_a_radius_uncertainty_that_spans_it(fade_px, frame):
    """A rim whose light fades over many pixels has no one radius: the spec's circle may be
    anywhere across the fade. The stated 2-sigma radius uncertainty reaches both ends of it
    (a rim this soft, 19 px off the diameter a spec gives, was stated +- 3.9 px before), also
    when the frame clips the circle at the top and bottom (profiles leaving the image)."""
    outer = 220.0
    size = dict(width=640, height=480, cx=322.0, cy=238.0) if frame == '4:3' else \
        dict(width=640, height=360, cx=321.0, cy=178.0)
    circle = find_image_circle(soft_rim(fade_px, radius=outer, **size))
    assert circle is not None and outer - fade_px <= circle.radius <= outer, circle
    reach = max(outer - circle.radius, circle.radius - (outer - fade_px))
    assert 2 * circle.radius_uncertainty_px >= reach, (circle, reach)
    assert circle.radius_uncertainty_px == pytest.approx(math.hypot(circle.radius_sigma_px, circle.edge_sigma_px))
    assert circle.edge_sigma_px <= 0.5 * fade_px  # and no wider than the fade itself


def test_a_sharp_rim_keeps_its_sub_pixel_radius_uncertainty():
    circle = find_image_circle(soft_rim(0))
    assert circle is not None and abs(circle.radius - 220.0) < 0.5
    assert circle.edge_sigma_px == 0 and circle.radius_uncertainty_px < 0.5


def test_the_softest_rim_seen_is_the_combined_circles_edge_uncertainty():
    """Averaging images shrinks where the steepest fall lies, not how soft the lens's rim is."""
    a = ImageCircle(100.0, 50.0, 200.0, 0.5, 0.5, edge_sigma_px=2.0)
    b = ImageCircle(100.0, 50.0, 200.0, 0.5, 0.5, edge_sigma_px=5.0)
    both = combine_circles([a, b, None])
    assert both.edge_sigma_px == 5.0 and both.radius_sigma_px < 0.5
    assert both.radius_uncertainty_px == pytest.approx(math.hypot(both.radius_sigma_px, 5.0))
    assert a.scaled(2.0).edge_sigma_px == 4.0


def test_a_soft_rim_widens_the_circle_fov_evidence_and_the_agreement_with_a_given_diameter():
    """The circle term's FOV sigma and the agreement of a spec's diameter follow the radius
    uncertainty (soft rim included), not only where the steepest fall lies."""
    from zeroshot_calib_ros.core.estimation.refine import circle_diameter_agrees, circle_term
    sharp = ImageCircle(CIRCULAR.cx, CIRCULAR.cy, CIRCULAR.circle_radius, 0.3, 0.3)
    soft = ImageCircle(CIRCULAR.cx, CIRCULAR.cy, CIRCULAR.circle_radius, 0.3, 0.3, edge_sigma_px=6.0)
    given = 2 * CIRCULAR.circle_radius + 19.0
    assert not circle_diameter_agrees(given, sharp) and circle_diameter_agrees(given, soft)
    spec = CameraSpec(640, 480, circle_diameter=2 * CIRCULAR.circle_radius, circle_fov=190.0)
    terms = [circle_term(spec, c, 640, 1.0, CIRCULAR) for c in (sharp, soft)]
    assert len(terms[0].sigma) == len(terms[1].sigma) == 3
    assert terms[1].sigma[2] > 3 * terms[0].sigma[2]
    # both parts of the radius's uncertainty, in quadrature (as radius_uncertainty_px says)
    both = ImageCircle(CIRCULAR.cx, CIRCULAR.cy, CIRCULAR.circle_radius, 0.3, 3.0, edge_sigma_px=3.0)
    direct = ImageCircleTerm(both.cx, both.cy, both.radius, 0.3, math.hypot(3.0, 3.0), 640, 190.0, 1.0, CIRCULAR)
    assert circle_term(spec, both, 640, 1.0, CIRCULAR).sigma[2] == pytest.approx(direct.sigma[2])


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


def test_a_precise_measurement_outweighs_a_loose_one_in_every_coordinate():
    """Inverse-variance weights (1 / sigma^2: 100 to 1 here), each of cx, cy and the radius from its own
    measurements."""
    precise = ImageCircle(100.0, 60.0, 200.0, 0.1, 0.1)
    loose = ImageCircle(104.0, 52.0, 210.0, 1.0, 1.0)
    both = combine_circles([loose, precise])
    assert abs(both.cx - 100.0) < 0.1 and abs(both.cy - 60.0) < 0.1 and abs(both.radius - 200.0) < 0.15
    assert combine_circles([precise, loose]).cy == pytest.approx(both.cy)


def test_a_margin_given_overrides_the_default():
    image = render(CIRCULAR, 'room', 1)
    default = find_image_region(image)
    wide = find_image_region(image, margin_px=default.margin_px + 20.0)
    assert wide.margin_px == pytest.approx(default.margin_px + 20.0)
    yy, xx = np.nonzero(wide.mask)
    assert np.max(np.hypot(xx - wide.circle.cx, yy - wide.circle.cy)) < wide.circle.radius - wide.margin_px + 1.5
    assert wide.mask.sum() < default.mask.sum()
    # the black borders too
    boxed, _ = scenes.render(PinholeCamera(300.0, 300.0, 320.0, 240.0, 640, 480), 'room', seed=1)
    boxed = boxed.copy()
    boxed[:60] = 0
    assert not find_image_region(boxed, margin_px=30.0).mask[:60 + 29].any()


def test_a_less_precisely_measured_circle_leaves_a_wider_margin():
    """Where the boundary is uncertain, the usable region stops three sigmas (of the radius and of
    the centre) further inside: no point of the boundary's blur gets in."""
    sharp = ImageCircle(320.0, 240.0, 220.0, 0.2, 0.2)
    vague = ImageCircle(320.0, 240.0, 220.0, 2.0, 3.0)
    widened = default_margin_px(640, 480, vague) - default_margin_px(640, 480, sharp)
    assert widened >= 3 * (3.0 - 0.2) + 3 * (2.0 - 0.2) - 1e-9
    assert default_margin_px(640, 480, sharp) > default_margin_px(640, 480)


def test_a_small_circle_on_a_wide_frame_is_found():
    """A circular fisheye whose circle spans 70 % of a 16:9 frame's height: its radius is under a
    quarter of the width but over a quarter of the height (the shorter side), and it is an image circle."""
    small = circular_camera(640, 360, 126.0, 322.0, 178.0)
    assert 0.25 * 360 < small.circle_radius < 0.25 * 640
    # (no vehicle: the renderer would paint the body below so small a circle, outside it, where no lens images)
    plain = scenes.Nuisances(circle=True, vehicle=False, blur=0.6, noise=2.0, jpeg_quality=80)
    assert_circle_near(find_image_circle(render(small, 'room', 1, nuisances=plain)), small, 1.0)


def test_the_measured_circle_states_the_circle_fov_of_binned_images_when_the_spec_agrees():
    """A spec sheet for the full resolution (1280 x 960) and binned images (640 x 480): its circle
    diameter scaled to the images agrees with the measured circle, which then states the circle FOV;
    a spec diameter that disagrees leaves the measurement only the principal point."""
    from zeroshot_calib_ros.core.estimation.refine import circle_term
    measured = ImageCircle(CIRCULAR.cx, CIRCULAR.cy, CIRCULAR.circle_radius, 0.3, 0.3)
    agrees = CameraSpec(1280, 960, circle_diameter=4 * CIRCULAR.circle_radius, circle_fov=190.0)
    term = circle_term(agrees, measured, 640, 1.0, CIRCULAR)
    assert term.circle_fov == 190.0 and np.allclose(term.residuals(CIRCULAR), 0.0, atol=0.05)
    disagrees = CameraSpec(1280, 960, circle_diameter=4 * CIRCULAR.circle_radius - 60, circle_fov=190.0)
    assert circle_term(disagrees, measured, 640, 1.0, CIRCULAR).circle_fov is None
    assert len(circle_term(disagrees, measured, 640, 1.0, CIRCULAR).residuals(CIRCULAR)) == 2


def test_the_reach_of_the_lines_is_measured_to_the_image_circle_at_any_image_size():
    """Nothing is imaged beyond the image circle: lines reaching 80 % of the way to it reach 80 %,
    whether the circle is the spec's (at full resolution, the images binned) or measured."""
    from zeroshot_calib_ros.core.estimation.refine import refine_camera
    r = CIRCULAR.circle_radius
    curves = []
    for k in range(10):  # short radial lines on one side (too few cells to fit), out to 0.8 r from the centre
        a = 0.02 * (k - 4.5)
        end = np.array([320 + 0.8 * r * math.cos(a), 240 + 0.8 * r * math.sin(a)])
        start = np.array([320 + 0.6 * r * math.cos(a), 240 + 0.6 * r * math.sin(a)])
        curves.append(np.linspace(start, end, 12))
    full = CameraSpec(1280, 960, circle_diameter=4 * r, circle_fov=190.0)
    binned = refine_camera(full, curves, 640, 480)
    assert binned.reach == pytest.approx(0.8, abs=0.01), binned.reason
    measured = ImageCircle(320.0, 240.0, r, 0.3, 0.3)
    assert refine_camera(CameraSpec(640, 480, hfov=200.0), curves, image_circle=measured).reach == \
        pytest.approx(0.8, abs=0.01)


def test_each_image_is_searched_inside_its_own_region():
    """regions[i] is images[i]'s: a region that leaves out all of the second image gives no curve of
    it; the circle is measured in the first image only."""
    from zeroshot_calib_ros.core.lines.image_region import ImageRegion
    images = [render(CIRCULAR, 'room', 1), render(CIRCULAR, 'corridor', 1)]
    first = find_image_region(images[0])
    regions = [first, ImageRegion(np.zeros((480, 640), bool))]
    spec = CameraSpec(640, 480, circle_diameter=first.circle.diameter, circle_fov=190.0)
    result = refine_from_images(spec, images, regions=regions, rounds=1)
    assert result.curves and {c.image for c in result.curves} == {0}
    assert result.circle_measured_in == 1 and result.image_circle == first.circle


def test_a_dark_region_bounded_by_an_arc_on_one_side_only_is_not_an_image_circle():
    """A shadow or a night sky at one side of an ordinary photo, its edge an arc of a circle whose
    centre is near the middle: the boundary is seen on one side only, so it is not an image circle
    (which the frame clips, if at all, on opposite sides); the image stays usable."""
    rng = np.random.default_rng(7)
    scene = cv2.GaussianBlur(rng.uniform(90, 210, (480, 640)), (0, 0), 4.0)
    for _ in range(15):
        x, y = rng.integers(0, 600), rng.integers(0, 440)
        cv2.rectangle(scene, (int(x), int(y)), (int(x + rng.integers(20, 120)), int(y + rng.integers(20, 120))),
                      float(rng.uniform(60, 240)), -1)
    yy, xx = np.mgrid[:480, :640]
    shadow = np.hypot(xx - 200.0, yy - 240.0) > 315.0   # right of an arc from (405, 0) via (515, 240) to (405, 479)
    scene[shadow] = 12.0
    image = np.clip(cv2.GaussianBlur(scene, (0, 0), 1.0) + rng.normal(0, 2.0, scene.shape), 0, 255).astype(np.uint8)
    region = find_image_region(image)
    assert region.circle is None, region.circle
    assert region.usable_fraction > 0.97


def test_the_measured_circle_is_evidence_of_the_principal_point():
    """The lines of one view and the image circle measured in it: a circle measured elsewhere (its
    centre moved by 5 px) moves the refined principal point towards it."""
    from zeroshot_calib_ros.core.estimation.refine import refine_camera, zero_shot_camera
    from zeroshot_calib_ros.core.lines.detect import detect_curves
    spec = CameraSpec(640, 480, circle_diameter=2 * CIRCULAR.circle_radius, circle_fov=190.0)
    image = render(CIRCULAR, 'room', 1)
    curves = detect_curves(image, zero_shot_camera(spec, 640, 480))
    points = []
    for dx in (0.0, 5.0):
        circle = ImageCircle(CIRCULAR.cx + dx, CIRCULAR.cy, CIRCULAR.circle_radius, 0.3, 0.3)
        fitted = refine_camera(spec, curves, image_circle=circle).refined_camera
        assert fitted is not None
        points.append((fitted.cx, fitted.cy))
    assert points[1][0] - points[0][0] > 1.0, points
