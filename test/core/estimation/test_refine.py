"""The estimator of issue 13 (core/lines/straightness.py, core/estimation/): straight lines seen
through known cameras, the spec's FOVs as soft priors, the uncertainty and the quality gate.

Evidence is synthetic and exact: random straight 3-D segments around a known Kannala-Brandt
camera (a made-up wide lens, 150 degrees across, principal point 14 px / 9 px off the centre),
projected through it, with 0.3 px Gaussian noise per coordinate, plus curved arcs (wheels) that
no camera straightens. References: the known camera, closed forms (equidistant FOVs, the pinhole
image of a line, d pixel / d f), and scipy's own robust loss.
"""
import math
import re

import numpy as np
import pytest
from scipy.optimize import least_squares

from zeroshot_calib_ros.core.estimation.parameters import KannalaBrandtLayout
from zeroshot_calib_ros.core.estimation.problem import Problem, robust_factor
from zeroshot_calib_ros.core.estimation.refine import refine_camera, refine_from_images, zero_shot_camera
from zeroshot_calib_ros.core.estimation.terms import FovTerm, PrincipalPointPrior
from zeroshot_calib_ros.core.estimation.zero_shot import zero_shot_start
from zeroshot_calib_ros.core.estimation.uncertainty import (Uncertainty, covariance, displacement, pixel_grid, pixel_rms,
                                                            problem_uncertainty, rms_over_circle, systematic_covariance,
                                                            zero_shot_uncertainty, zoom_field)
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, PinholeCamera
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis
from zeroshot_calib_ros.core.lines.image_region import ImageCircle
from zeroshot_calib_ros.core.lines.straightness import StraightnessTerm, smallest_eigenvectors
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

W, H = 1280, 800
TRUTH = KannalaBrandtCamera(430.0, 430.0, 654.0, 391.0, W, H, [0.035, -0.012, 0.003, -0.0004])


class Curve:
    def __init__(self, points, image, straight=True):
        self.points, self.image, self.straight = points, image, straight


def _rotation(rng, spread_deg):
    w = np.radians(rng.normal(0, spread_deg, 3))
    angle = np.linalg.norm(w)
    k = w / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def line_curves(camera, rng, count, noise=0.3, keep=None, max_angle=None, min_len=0.1, step_px=10.0):
    """``count`` curves of random 3-D segments seen by ``camera``: each segment passes 1-4 m
    from the camera in a random direction inside the field, its visible run sampled every
    ``step_px`` and perturbed by ``noise`` px. ``keep(pixels)`` -> mask limits where points may be."""
    max_angle = camera.max_field_angle() if max_angle is None else max_angle
    curves = []
    while len(curves) < count:
        theta = math.acos(rng.uniform(math.cos(max_angle), 1.0))
        phi = rng.uniform(0, 2 * math.pi)
        centre = rng.uniform(1.0, 4.0) * np.array([math.sin(theta) * math.cos(phi),
                                                   math.sin(theta) * math.sin(phi), math.cos(theta)])
        direction = rng.normal(size=3)
        direction -= direction @ centre / (centre @ centre) * centre
        direction /= np.linalg.norm(direction)
        t = np.linspace(-6, 6, 3000)
        rays = centre[None] + t[:, None] * direction[None]
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        off = np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2])
        px = camera.project(rays)
        ok = (off < max_angle) & np.all(np.isfinite(px), axis=1) & (px[:, 0] > 2) & (px[:, 0] < camera.width - 2) \
            & (px[:, 1] > 2) & (px[:, 1] < camera.height - 2)
        if keep is not None:
            ok &= keep(px)
        idx = np.nonzero(ok)[0]
        if idx.size < 10:
            continue
        run = max(np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1), key=len)
        pts = px[run]
        arc = np.r_[0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
        if arc[-1] < min_len * camera.width:
            continue
        s = np.linspace(0, arc[-1], int(min(40, max(8, arc[-1] / step_px))))
        pts = np.stack([np.interp(s, arc, pts[:, 0]), np.interp(s, arc, pts[:, 1])], axis=1)
        # resample exactly on the line's image: project the rays of the interpolated points' parameters
        tt = np.interp(s, arc, t[run])
        rq = centre[None] + tt[:, None] * direction[None]
        pts = camera.project(rq / np.linalg.norm(rq, axis=1, keepdims=True))
        curves.append(pts + rng.normal(0, noise, pts.shape))
    return curves


def arcs(rng, count, noise=0.3):
    """Curved distractors: arcs of circles 80-200 px in radius, 100-170 degrees long."""
    out = []
    for _ in range(count):
        r = rng.uniform(80, 200)
        c = np.array([rng.uniform(0.3, 0.7) * W, rng.uniform(0.3, 0.7) * H])
        a0 = rng.uniform(0, 2 * math.pi)
        a = np.linspace(a0, a0 + rng.uniform(1.7, 3.0), 30)
        out.append(c + r * np.stack([np.cos(a), np.sin(a)], axis=1) + rng.normal(0, noise, (30, 2)))
    return out


def best_rotation_rms(estimate, truth, grid=(33, 19), pixels=None):
    """RMS pixel distance over a grid (or over ``pixels``) between the truth's pixels and the
    estimate's projection of the truth's rays after the best rotation (Gauss-Newton on the pixels)."""
    pixels = pixel_grid(truth.width, truth.height, grid) if pixels is None else pixels
    rays = truth.unproject(pixels)

    def rot(w):
        a = np.linalg.norm(w)
        if a == 0:
            return np.eye(3)
        k = w / a
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K

    fit = least_squares(lambda w: (estimate.project(rays @ rot(w).T) - pixels).ravel(), np.zeros(3))
    return math.sqrt(2 * fit.cost / len(pixels))


def spec_of(camera):
    return CameraSpec(camera.width, camera.height, **fields_of_view_through_axis(camera))


def views(camera, rng, per_view, n_views=4, arcs_per_view=2, **kwargs):
    curves = []
    for v in range(n_views):
        curves += [Curve(c, v) for c in line_curves(camera, rng, per_view, **kwargs)]
        curves += [Curve(c, v, straight=False) for c in arcs(rng, arcs_per_view)]
    return curves


@pytest.fixture(scope='module')
def refined():
    rng = np.random.default_rng(7)
    curves = views(TRUTH, rng, 10)
    return curves, refine_camera(spec_of(TRUTH), curves)


# --------------------------------------------------------------------------------- straightness

def test_straightness_of_a_pinhole_is_the_distance_to_the_image_line():
    """Under a pinhole a 3-D line images to a straight line, so the residual of each point must be
    its perpendicular distance to the total-least-squares line through the curve's pixels."""
    rng = np.random.default_rng(1)
    camera = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    curves = line_curves(camera, rng, 12, noise=0.5, max_angle=math.radians(35))
    term = StraightnessTerm(curves)
    ours = np.linalg.norm(term.point_residuals(camera), axis=1)
    reference = []
    for c in curves:
        centred = c - c.mean(axis=0)
        normal = np.linalg.svd(centred)[2][-1]
        reference.append(np.abs(centred @ normal))
    reference = np.concatenate(reference)
    # (the plane through the rays is not exactly the pixel-space line: equal to a few 1e-4 px)
    assert np.sqrt(np.mean(ours ** 2)) == pytest.approx(np.sqrt(np.mean(reference ** 2)), rel=5e-4)
    assert np.max(np.abs(ours - reference)) < 0.003


def test_straightness_is_zero_for_the_true_camera_and_the_noise_for_noisy_points():
    rng = np.random.default_rng(2)
    exact = line_curves(TRUTH, rng, 20, noise=0.0)
    assert StraightnessTerm(exact).rms(TRUTH) < 1e-6
    noisy = [c + rng.normal(0, 0.3, c.shape) for c in exact]
    # the perpendicular component of 2-D noise of 0.3 px per coordinate, less the line's 2 dof
    n = sum(len(c) for c in noisy)
    expected = 0.3 * math.sqrt((n - 2 * len(noisy)) / n)
    assert StraightnessTerm(noisy).rms(TRUTH) == pytest.approx(expected, rel=0.08)
    wrong = KannalaBrandtCamera(430.0, 430.0, 654.0, 391.0, W, H, [0.0, 0.0, 0.0, 0.0])
    assert StraightnessTerm(exact).rms(wrong) > 1.0


def test_straightness_beyond_180_degrees():
    """A 220-degree equidistant lens: line points whose rays point backwards (z < 0) have a
    residual like any other, zero under the true camera."""
    camera = KannalaBrandtCamera(300.0, 300.0, 500.0, 500.0, 1000, 1000, [0.0, 0.0, 0.0, 0.0])
    assert math.degrees(camera.unproject(np.array([[0.0, 500.0]]))[0] @ [0, 0, 1] * 0 + 2 * 500 / 300) > 190
    rng = np.random.default_rng(3)
    curves = line_curves(camera, rng, 15, noise=0.0, max_angle=math.radians(110))
    rays = camera.unproject(np.concatenate(curves))
    assert np.sum(rays[:, 2] < 0) > 20
    assert StraightnessTerm(curves).rms(camera) < 1e-6
    zoomed = KannalaBrandtCamera(315.0, 315.0, 500.0, 500.0, 1000, 1000, [0.0, 0.0, 0.0, 0.0])
    assert StraightnessTerm(curves).rms(zoomed) > 0.5


# ---------------------------------------------------------------------------------------- terms

def test_fov_term_uses_the_spec_definition_through_the_axis():
    """Equidistant lens (theta_d = theta): hfov = W / f radians across the principal point's row,
    also past 180 degrees; the circle FOV = diameter / f."""
    camera = KannalaBrandtCamera(300.0, 300.0, 500.0, 400.0, 1000, 800, [0.0, 0.0, 0.0, 0.0])
    term = FovTerm({'hfov': 190.0, 'vfov': 150.0, 'circle': 180.0}, 1000, 800, 1.0, circle_diameter=960.0)
    hfov, vfov, circle = term.residuals(camera) + term.given
    assert hfov == pytest.approx(math.degrees(1000 / 300), abs=1e-6)   # 191 degrees
    assert vfov == pytest.approx(math.degrees(800 / 300), abs=1e-6)
    assert circle == pytest.approx(math.degrees(960 / 300), abs=1e-6)  # 183 degrees


def test_robust_loss_matches_scipys():
    """The per-term robust loss (residuals rewritten so that plain least squares minimises
    sum rho) gives the same fit as scipy's own soft_l1 / cauchy on a line with outliers."""
    rng = np.random.default_rng(4)
    x = np.linspace(0, 10, 60)
    y = 2.0 * x + 1.0 + rng.normal(0, 0.2, x.size)
    y[::9] += 15.0
    for loss in ('soft_l1', 'cauchy'):
        c = 0.6

        def corrected(p):
            r = (p[0] * x + p[1] - y) / 0.2
            return r * robust_factor(r * r, loss, c / 0.2)

        ours = least_squares(corrected, [0.0, 0.0]).x
        theirs = least_squares(lambda p: p[0] * x + p[1] - y, [0.0, 0.0], loss=loss, f_scale=c).x
        assert np.allclose(ours, theirs, atol=1e-5)


# ---------------------------------------------------------------------------------- uncertainty

def test_pixel_rms_over_an_off_centre_circle_is_the_closed_form_over_its_pixels():
    """Variance s^2 on f alone over the grid pixels inside a circle centred off the image's
    centre (a circular fisheye's image circle is seldom centred): the RMS over exactly those
    pixels, which ``rms_over_circle`` gives again from the error bar itself."""
    layout = KannalaBrandtLayout(TRUTH, 0)
    x = layout.x_from(TRUTH)
    s = 2.0
    cov = np.diag([s * s, 0.0, 0.0])
    centre, radius = (W / 2.0 + 90.0, H / 2.0 - 60.0), 300.0
    px = pixel_grid(W, H)
    inside = px[np.hypot(px[:, 0] - centre[0], px[:, 1] - centre[1]) <= radius]
    assert np.array_equal(pixel_grid(W, H, circle_radius=radius, circle_centre=centre), inside)
    r2 = (inside[:, 0] - TRUTH.cx) ** 2 + (inside[:, 1] - TRUTH.cy) ** 2
    expected = s * math.sqrt(np.mean(r2)) / TRUTH.fx
    assert pixel_rms(layout, x, cov, after_rotation=False, circle_radius=radius,
                     circle_centre=centre) == pytest.approx(expected, rel=1e-4)
    u = Uncertainty(pixel_rms(layout, x, cov), covariance=cov, layout=layout, x=x)
    assert rms_over_circle(u, radius, centre) == pytest.approx(
        pixel_rms(layout, x, cov, circle_radius=radius, circle_centre=centre), rel=1e-9)
    assert rms_over_circle(u, 10 * W) == pytest.approx(u.rms_px, rel=1e-9)  # a circle around everything
    problem = Problem(layout, [PrincipalPointPrior(W, H), FovTerm({'hfov': 150.0}, W, H)])
    bar = problem_uncertainty(problem, x, circle_radius=radius, circle_centre=centre)
    assert (bar.circle_radius, bar.circle_centre) == (radius, centre)  # what its error map is drawn over


FISHEYE_187 = KannalaBrandtCamera(337.0, 337.0, 543.3, 377.6, 1032, 778, [0.000519, -0.006295, 0.001031, -0.000622])
"""A real 187 x 134-degree fisheye's calibration (OCamCalib's sample "Fisheye1", our chessboard fit)."""
FISHEYE_CIRCLE = ImageCircle(547.9, 352.1, 516.4, 0.5, 0.5, 180.0, 500, 2)
"""Its image circle as the images show it: off the image's centre, the corners outside."""


def test_a_circular_fisheyes_dark_corners_do_not_decide_the_gate():
    """A 187 x 134-degree fisheye (a real camera's calibration, 1032 x 778) whose image circle,
    seen in the images, leaves the corners dark: noisy lines (1 px) inside the circle. The fit
    may choose order 3, whose camera parts from the order-4 one only in the dark corners, past
    every line, where the covariance grows without bound too: tens of px over the whole image.
    Compared with zero-shot over the circle seen (what is imaged), the refined camera, 4x nearer
    the truth there, is adopted; its error bar over the whole image stays honest."""
    grid = pixel_grid(FISHEYE_187.width, FISHEYE_187.height)
    inside = grid[np.hypot(grid[:, 0] - FISHEYE_CIRCLE.cx, grid[:, 1] - FISHEYE_CIRCLE.cy) <= FISHEYE_CIRCLE.radius]

    def error(camera):  # RMS inside the circle after the best rotation
        return best_rotation_rms(camera, FISHEYE_187, pixels=inside)

    for seed in (1, 4):
        spec, curves, circle, _ = _fisheye_behind_its_circle(seed)
        result = refine_camera(spec, curves, image_circle=circle)
        assert result.accepted, result.reason
        assert error(result.camera) < 0.35 * error(result.zero_shot_camera)
        assert error(result.camera) < 2 * result.uncertainty_px
        # the two bars the reason compares are those over the circle seen (off the image's centre)
        refined_px, zero_shot_px = _circle_pair(result.reason)
        centre = (circle.cx, circle.cy)
        for stated, bar in ((refined_px, result.refined_uncertainty), (zero_shot_px, result.zero_shot_uncertainty)):
            assert stated == pytest.approx(rms_over_circle(bar, circle.radius, centre), rel=0.006)
        if result.order < 4:  # a lower order's bias is measured where the images show something
            assert result.refined_uncertainty.reason.endswith('(inside the image circle seen)')


def _circle_pair(reason):
    """(refined, zero-shot) px of the reason's "over the image circle seen: X px against Y px"."""
    found = re.search(r'over the image circle seen: ([\d.]+) px against ([\d.]+) px', reason)
    assert found, reason
    return float(found.group(1)), float(found.group(2))


def _fisheye_behind_its_circle(seed, factor=1):
    """The 187 x 134-degree fisheye's spec (hfov, vfov), 25 noisy (1 px) lines per view in 4 views
    inside its circle, and the circle, in images ``factor`` times the spec's size (a sensor mode,
    a resized stream: the same camera scaled)."""
    truth, circle = FISHEYE_187, FISHEYE_CIRCLE
    fovs = fields_of_view_through_axis(truth)
    spec = CameraSpec(truth.width, truth.height, hfov=fovs['hfov'], vfov=fovs['vfov'])

    def keep(px):
        return np.hypot(px[:, 0] - circle.cx, px[:, 1] - circle.cy) < circle.radius - 10
    rng = np.random.default_rng(seed)
    curves = [Curve(factor * c, v) for v in range(4)
              for c in line_curves(truth, rng, 25, noise=1.0, keep=keep, max_angle=math.radians(100))]
    return spec, curves, circle.scaled(factor), (truth.width * factor, truth.height * factor)


def test_images_at_twice_the_specs_size_compare_the_same_bars_in_their_own_pixels():
    """The fisheye behind its circle seen in images twice the spec's size (a sensor mode, a
    resized stream): the same decision, and the two bars the gate compares over the circle seen
    are twice those at the spec's size (zero-shot's is stated at the spec's size and scaled)."""
    spec, curves, circle, _ = _fisheye_behind_its_circle(1)
    at_spec = refine_camera(spec, curves, image_circle=circle)
    spec, curves, circle, (width, height) = _fisheye_behind_its_circle(1, factor=2)
    doubled = refine_camera(spec, curves, width, height, image_circle=circle)
    assert at_spec.accepted and doubled.accepted, (at_spec.reason, doubled.reason)
    for one, two in zip(_circle_pair(at_spec.reason), _circle_pair(doubled.reason)):
        assert two == pytest.approx(2 * one, rel=0.02)


def test_the_gate_weighs_zero_shot_over_the_circle_seen(monkeypatch):
    """The chance that zero-shot is the nearer camera is taken over the image circle seen, with its
    own centre (off the image's), not over the image or a centred circle."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    calls = []
    real = refine_module.probability_other_is_better

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)
    monkeypatch.setattr(refine_module, 'probability_other_is_better', spy)
    spec, curves, circle, _ = _fisheye_behind_its_circle(1)
    refine_camera(spec, curves, image_circle=circle)
    assert calls and all(c['circle_radius'] == circle.radius and c['circle_centre'] == (circle.cx, circle.cy)
                         for c in calls)


@pytest.mark.parametrize('p_better, gain, accepted', [
    (0.009, 0.001, True),   # within 1 %: accepted however little better the held-out curves are
    (0.03, 0.001, False),   # 1-5 %, held-out curves hardly better: the posterior alone (a misfit?)
    (0.03, 0.049, False),
    (0.03, 0.051, True),    # 1-5 %, confirmed by held-out curves explained at least 5 % better
    (0.049, 0.3, True),
    (0.051, 0.3, False),    # past 5 %: refused however well held-out curves are explained
])
def test_a_held_out_gain_confirms_a_fit_the_posterior_leaves_in_doubt(monkeypatch, refined, p_better, gain,
                                                                       accepted):
    """The chance that zero-shot is the better camera may be up to 5 % (instead of 1 %) when the
    held-out curves, which the fit did not see, are explained with an RMS at least 5 % lower than
    under zero-shot; a posterior too narrow for a lens the model misfits is not confirmed so."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    real = refine_module.probability_other_is_better

    def probability(*args, **kwargs):
        _, distance, spread = real(*args, **kwargs)
        return p_better, distance, spread
    monkeypatch.setattr(refine_module, 'probability_other_is_better', probability)
    monkeypatch.setattr(refine_module, '_held_out', lambda *args: (0.2, 0.2 * (1.0 - gain)))
    curves, _ = refined
    result = refine_camera(spec_of(TRUTH), curves)
    assert result.accepted is accepted, result.reason
    if not accepted:
        assert result.reason.startswith('the lines do not rule out zero-shot'), result.reason
        # the chance to two digits and what is allowed: "1 %" against a limit of 1 % read as a contradiction
        allowed = 5 if gain >= 0.05 else 1
        assert f'(probability {100 * p_better:.2g} % that it is better by' in result.reason, result.reason
        assert f', at most {allowed} % allowed); zero-shot kept' in result.reason, result.reason


@pytest.mark.parametrize('gain, accepted', [(0.001, False), (0.049, False), (0.051, True), (0.3, True)])
def test_with_one_fov_a_fit_is_kept_only_when_held_out_curves_confirm_it(monkeypatch, refined, gain, accepted):
    """With one FOV the lens shape is the lines' alone and the zoom follows it through that FOV's
    edge: lines that err together bend the shape and move the zoom where the posterior cannot see
    it (a real 93-degree camera given hfov alone was accepted 59 px from its calibration with a
    9 px error bar, its held-out curves 1.2 % better explained). There the fit is kept only when
    the held-out curves are explained at least 5 % better, however sure the posterior is; zero-shot
    is returned otherwise, with its own error bar."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    real = refine_module.probability_other_is_better

    def probability(*args, **kwargs):
        _, distance, spread = real(*args, **kwargs)
        return 1e-6, distance, spread
    monkeypatch.setattr(refine_module, 'probability_other_is_better', probability)
    monkeypatch.setattr(refine_module, '_held_out', lambda *args: (0.2, 0.2 * (1.0 - gain)))
    curves, _ = refined
    spec = CameraSpec(W, H, hfov=round(fields_of_view_through_axis(TRUTH)['hfov'], 1))
    result = refine_camera(spec, curves)
    assert result.accepted is accepted, result.reason
    if not accepted:
        assert result.reason.startswith(f'held-out lines are explained only {100 * gain:.1f} % better'), result.reason
        assert 'one FOV' in result.reason and result.camera is result.zero_shot_camera
        assert result.reason.endswith('give a second FOV (vfov or dfov) from the spec sheet, or images whose '
                                      'straight edges reach further across the image'), result.reason
        assert result.uncertainty_px == result.zero_shot_uncertainty_px


def test_with_one_fov_and_lines_short_of_its_edges_the_error_bar_counts_the_guessed_shape():
    """hfov alone, lines only in the middle 55 % of the image: the edges the zoom is taken at are
    held by the shape prior alone, around zero-shot's guess from real lenses of that FOV. Counted
    at 2 % of the radius, the bar called that shape known: this lens was accepted 31.6 px from the
    truth (zero-shot 15.3) at 4.2 times its bar. Counted at ``ONE_CONSTRAINT_SHAPE_SPREAD`` the gate
    keeps zero-shot, and whatever is returned lies within twice the bar it states."""
    truth = KannalaBrandtCamera(430.0, 430.0, 654.0, 391.0, W, H, [-0.05, 0.01, 0.0, 0.0])
    spec = CameraSpec(W, H, hfov=round(fields_of_view_through_axis(truth)['hfov'], 1))
    rng = np.random.default_rng(3)
    reach = 0.55 * math.hypot(W / 2, H / 2)
    curves = []
    for v in range(4):
        curves += [Curve(c, v) for c in line_curves(
            truth, rng, 10, keep=lambda px: np.hypot(px[:, 0] - W / 2, px[:, 1] - H / 2) < reach)]
    result = refine_camera(spec, curves)
    rays = truth.unproject(pixel_grid(W, H))
    rays = rays[np.all(np.isfinite(rays), axis=1)]

    def error(camera):
        d = displacement(truth, camera, rays)
        return float(np.sqrt(np.nanmean(np.sum(d * d, axis=1))))
    assert error(result.camera) <= error(result.zero_shot_camera) + 0.2, result.reason  # 0.3 px at 1920
    assert error(result.camera) <= 2 * result.uncertainty_px, (error(result.camera), result.uncertainty_px)


def test_pixel_rms_of_a_focal_variance_is_the_closed_form():
    """Variance s^2 on f alone: each pixel moves by theta_d s = (r / f) s, r its distance from
    the principal point, so the RMS over the grid is s sqrt(mean(r^2)) / f."""
    layout = KannalaBrandtLayout(TRUTH, 0)
    x = layout.x_from(TRUTH)
    s = 2.0
    cov = np.diag([s * s, 0.0, 0.0])
    px = pixel_grid(W, H)
    r2 = (px[:, 0] - TRUTH.cx) ** 2 + (px[:, 1] - TRUTH.cy) ** 2
    expected = s * math.sqrt(np.mean(r2)) / TRUTH.fx
    assert pixel_rms(layout, x, cov, after_rotation=False) == pytest.approx(expected, rel=1e-4)
    # a principal-point shift is almost a rotation: what the best rotation leaves is much smaller
    pp = np.diag([0.0, 25.0, 25.0])
    assert pixel_rms(layout, x, pp, after_rotation=True) < 0.5 * pixel_rms(layout, x, pp, after_rotation=False)


def test_covariance_is_none_when_the_evidence_does_not_determine_the_camera():
    """Three FOVs and a principal-point prior are five numbers for seven parameters: no
    covariance, and the reason, instead of a number."""
    layout = KannalaBrandtLayout(TRUTH, 4)
    fovs = fields_of_view_through_axis(TRUTH)
    problem = Problem(layout, [FovTerm(fovs, W, H), PrincipalPointPrior(W, H)])
    cov, reason = covariance(problem.jacobian(layout.x_from(TRUTH)))
    assert cov is None and 'does not determine' in reason
    problem.terms.append(StraightnessTerm(line_curves(TRUTH, np.random.default_rng(8), 20)))
    cov, _ = covariance(problem.jacobian(layout.x_from(TRUTH)))
    assert cov is not None and np.all(np.linalg.eigvalsh(cov) > 0)


def test_ill_conditioned_near_square_spec_warns():
    """The issue's example: 848 x 800, 206 x 172 degrees, no dfov (zero-shot f 838 px against 289)."""
    bad = zero_shot_uncertainty(CameraSpec(848, 800, hfov=206, vfov=172))
    good = zero_shot_uncertainty(CameraSpec(1920, 1080, hfov=118, vfov=69, dfov=133))
    assert bad.warning and 'ill-conditioned' in bad.warning and f'{bad.rms_px:.3g}' in bad.warning
    assert good.warning is None
    assert bad.rms_px / 848 > 3 * good.rms_px / 1920


# ---------------------------------------------------------------------------------- refinement

def test_refined_camera_recovers_the_truth(refined):
    curves, result = refined
    assert result.accepted, result.reason
    camera = result.camera
    assert best_rotation_rms(camera, TRUTH) < 1.0
    assert math.hypot(camera.cx - TRUTH.cx, camera.cy - TRUTH.cy) < 3.0
    # zero-shot (principal point at the centre, the paper's law) is several pixels off
    assert best_rotation_rms(result.zero_shot_camera, TRUTH) > 3.0
    used = np.array([u for c, u in zip(curves, result.used) if c.straight])
    arcs_used = [u for c, u in zip(curves, result.used) if not c.straight]
    assert len(arcs_used) == 8 and not any(arcs_used) and used.mean() > 0.9
    assert result.lines_used >= 30 and result.images_used == 4
    assert result.line_residual_px_after < 0.35 < result.line_residual_px_before


def test_uncertainty_is_honest(refined):
    """True error within 2x the reported uncertainty, refined and zero-shot."""
    _, result = refined
    assert best_rotation_rms(result.camera, TRUTH) <= 2 * result.uncertainty_px
    assert best_rotation_rms(result.zero_shot_camera, TRUTH) <= 2 * result.zero_shot_uncertainty_px
    assert result.uncertainty_px < result.zero_shot_uncertainty_px


def test_too_few_lines_keep_zero_shot():
    rng = np.random.default_rng(5)
    curves = [Curve(c, 0) for c in line_curves(TRUTH, rng, 5)]
    result = refine_camera(spec_of(TRUTH), curves)
    assert not result.accepted and result.reason.startswith('too few lines')
    zs = zero_shot_camera(spec_of(TRUTH), W, H)
    assert np.allclose(result.camera.K, zs.K) and np.allclose(result.camera.D, zs.D)
    assert result.uncertainty_px == result.zero_shot_uncertainty_px


def test_lines_only_near_the_centre_keep_zero_shot():
    rng = np.random.default_rng(6)
    near = lambda px: np.hypot(px[:, 0] - W / 2, px[:, 1] - H / 2) < 0.3 * math.hypot(W / 2, H / 2)  # noqa: E731
    curves = [Curve(c, i % 4) for i, c in enumerate(line_curves(TRUTH, rng, 30, keep=near, min_len=0.05))]
    result = refine_camera(spec_of(TRUTH), curves)
    assert not result.accepted and 'near the centre' in result.reason


def test_images_of_different_sizes_are_refused():
    spec = spec_of(TRUTH)
    with pytest.raises(ValueError, match='different sizes'):
        refine_from_images(spec, [np.zeros((H, W), np.uint8), np.zeros((H // 2, W // 2), np.uint8)])


def test_images_of_two_cameras_are_refused_as_disagreeing():
    """Two images of the true lens and two of another (same spec, principal point 54 px away):
    no camera straightens all four, each pair alone is straight: refused, zero-shot kept."""
    rng = np.random.default_rng(11)
    other = KannalaBrandtCamera(430.0, 430.0, 600.0, 391.0, W, H, TRUTH.D)
    curves = views(TRUTH, rng, 10, n_views=2)
    for c in views(other, rng, 10, n_views=2):
        curves.append(Curve(c.points, c.image + 2, c.straight))
    names = ['true_a.png', 'true_b.png', 'other_a.png', 'other_b.png']
    result = refine_camera(spec_of(TRUTH), curves, image_names=names)
    assert not result.accepted and result.reason.startswith('disagreement between images')
    assert np.allclose(result.camera.K, result.zero_shot_camera.K)
    # the reason names an image by the name given for it, never by its position
    assert any(name in result.reason for name in names), result.reason
    assert not re.search(r'image\(?s?\)? \d', result.reason), result.reason
    # what differs is named: here the principal point, quoted against the others'
    assert 'differs most, in its principal point (' in result.reason, result.reason


def test_an_image_whose_lines_ask_for_another_lens_shape_is_said_so():
    """Two images of the true lens and two of a lens of the same centre and spec but another
    distortion: what the reason names is the lens shape, not a principal point that agrees."""
    rng = np.random.default_rng(11)
    other = KannalaBrandtCamera(430.0, 430.0, TRUTH.cx, TRUTH.cy, W, H, [0.12, -0.03, 0.003, -0.0004])
    curves = views(TRUTH, rng, 10, n_views=2)
    curves += [Curve(c.points, c.image + 2, c.straight) for c in views(other, rng, 10, n_views=2)]
    result = refine_camera(spec_of(TRUTH), curves, image_names=['a1.png', 'a2.png', 'b1.png', 'b2.png'])
    assert not result.accepted
    assert 'differs most, in the lens shape (distortion) its lines ask for' in result.reason, result.reason


@pytest.mark.parametrize('seed', range(100, 108))
def test_images_of_two_cameras_never_give_a_camera_worse_than_zero_shot_for_either(seed):
    """Two images each of two cameras of one spec (principal points 54 px apart: a stereo pair,
    two units of one model): the camera returned is never farther from either camera than
    zero-shot is by more than 0.5 px at 1920 wide. A camera fitted to all four lies between the
    two and explains held-out lines better than zero-shot; what refuses it is an image whose
    lines it straightens worse than zero-shot does (seeds 100 and 105 were accepted 1.4 to 4.7 px
    worse without that check). Seed 104 is accepted 0.39 px worse for the second camera: its
    camera is nearly zero-shot's, and straightens every image's lines at least as well (0.64 to
    0.99 of zero-shot's RMS): the lines cannot tell, so the tolerance is 0.5 px, not the gate's
    0.3."""
    rng = np.random.default_rng(seed)
    other = KannalaBrandtCamera(430.0, 430.0, 600.0, 391.0, W, H, TRUTH.D)
    curves = views(TRUTH, rng, 10, n_views=2)
    curves += [Curve(c.points, c.image + 2, c.straight) for c in views(other, rng, 10, n_views=2)]
    result = refine_camera(spec_of(TRUTH), curves, image_names=['a1.png', 'a2.png', 'b1.png', 'b2.png'])
    margin = 0.5 * W / 1920
    for camera in (TRUTH, other):
        returned, zero_shot = best_rotation_rms(result.camera, camera), best_rotation_rms(result.zero_shot_camera, camera)
        assert returned <= zero_shot + margin, result.reason
    if not result.accepted:
        assert result.reason.startswith('disagreement between images'), result.reason
        assert re.search(r'image [ab][12]\.png ', result.reason), result.reason  # named by its file
        assert np.allclose(result.camera.K, result.zero_shot_camera.K)


def _shifted_to_ratio(term, images, image, ratio):
    """TRUTH with its principal point moved right until it straightens ``image``'s curves of
    ``term`` ``ratio`` times worse (RMS) than TRUTH does."""
    mask = np.array([i == image for i in images])
    sub = term.subset(mask)
    base = sub.rms(TRUTH)
    lo, hi = 0.0, 60.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        camera = KannalaBrandtCamera(TRUTH.fx, TRUTH.fy, TRUTH.cx + mid, TRUTH.cy, W, H, TRUTH.D)
        lo, hi = (mid, hi) if sub.rms(camera) < ratio * base else (lo, mid)
    return KannalaBrandtCamera(TRUTH.fx, TRUTH.fy, TRUTH.cx + hi, TRUTH.cy, W, H, TRUTH.D)


@pytest.mark.parametrize('ratio, per_image, refused', [
    (1.2, (10, 10), True),      # past MAX_IMAGE_WORSE (1.1): images of two cameras
    (1.05, (10, 10), False),    # within it: one camera's images, straightened alike to a few %
    (1.2, (10, 5), True),       # an image with MIN_IMAGE_LINES curves is judged
    (1.2, (10, 4), False),      # one with fewer is not (too few to say)
    (1.2, (10,), False),        # nor one image alone (the held-out test judges it)
])
def test_an_image_straightened_worse_than_by_zero_shot_refuses_the_camera(ratio, per_image, refused):
    """``_image_straightened_worse``: the camera fitted to all the images is refused when it
    straightens one image's lines more than 1.1 times worse (RMS) than zero-shot does, among at
    least two images of at least 5 curves each, and the reason names the worst image's file."""
    from zeroshot_calib_ros.core.estimation.refine import _image_straightened_worse
    rng = np.random.default_rng(3)
    points, images = [], []
    for image, count in enumerate(per_image):
        for c in line_curves(TRUTH, rng, count):
            points.append(c)
            images.append(image)
    term = StraightnessTerm(points, sigma=0.3)
    last = len(per_image) - 1
    refined = _shifted_to_ratio(term, images, last, ratio)
    names = ['first.png', 'second.png']
    reason = _image_straightened_worse(term, images, refined, TRUTH, names)
    if refused:
        assert reason is not None and reason.startswith('disagreement between images'), reason
        assert re.search(r'image (first|second)\.png worse than zero-shot does', reason), reason  # by its file
    else:
        assert reason is None, reason


def test_a_curve_one_camera_cannot_unproject_does_not_decide_the_per_image_check():
    """A point the refined camera has no ray for (one of 25,000 in a rendered phone lens's room:
    its inverse missed the root) made that image's RMS infinite and refused a camera 4 px nearer
    the truth than zero-shot: the check compares the curves both cameras unproject."""
    from zeroshot_calib_ros.core.estimation.refine import _image_straightened_worse
    rng = np.random.default_rng(3)
    points, images = [], []
    for image in (0, 1):
        for c in line_curves(TRUTH, rng, 10):
            points.append(c)
            images.append(image)
    points[-1] = np.vstack([points[-1], [[TRUTH.cx + 1000.0, TRUTH.cy]]])  # past the true lens's last ray
    term = StraightnessTerm(points, sigma=0.3)
    equidistant = KannalaBrandtCamera(TRUTH.fx, TRUTH.fy, TRUTH.cx, TRUTH.cy, W, H, [0.0, 0.0, 0.0, 0.0])
    assert not np.isfinite(term.rms(TRUTH)) and np.isfinite(term.rms(equidistant))
    # the true camera straightens both images' lines better than the equidistant one
    assert _image_straightened_worse(term, images, TRUTH, equidistant, ['a.png', 'b.png']) is None


def test_the_image_that_differs_is_named_past_one_that_determines_no_camera_alone(monkeypatch):
    """Two images of the true lens, one whose curves alone determine no camera (its covariance is
    None: passed over, it cannot disagree) and two of another camera (principal point 54 px away):
    the image named as differing most is the one named when that image is not there at all, not
    the image that stands at its place in the list of all images."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    rng = np.random.default_rng(13)
    other = KannalaBrandtCamera(430.0, 430.0, 600.0, 391.0, W, H, TRUTH.D)
    true = views(TRUTH, rng, 10, n_views=2)
    few = [Curve(c, 2) for c in line_curves(TRUTH, rng, 6)]
    others = [Curve(c.points, c.image + 3, c.straight) for c in views(other, rng, 10, n_views=2)]
    names = ['true_a.png', 'true_b.png', 'few_lines.png', 'other_a.png', 'other_b.png']
    without = re.findall(r'image (\S+) differs most',
                         refine_camera(spec_of(TRUTH), true + others, image_names=names).reason)
    assert without and without[0].startswith('other_'), without
    real = refine_module.problem_uncertainty
    alone = []

    def few_lines_alone_determine_nothing(problem, x, *args, **kwargs):
        if len(problem.terms[0]) == len(few) and not any(isinstance(t, FovTerm) for t in problem.terms):
            alone.append(True)
            return Uncertainty(None, 'this image alone does not determine the parameters')
        return real(problem, x, *args, **kwargs)

    monkeypatch.setattr(refine_module, 'problem_uncertainty', few_lines_alone_determine_nothing)
    result = refine_camera(spec_of(TRUTH), true + few + others, image_names=names)  # in the order of the names
    assert alone, 'few_lines.png was never fitted alone: the test does not reach its case'
    assert not result.accepted
    assert f'image {without[0]} differs most' in result.reason, result.reason


def test_an_image_whose_curves_are_mostly_not_straight_is_named():
    """Image 0's curves are mostly arcs while image 1's are lines: refused as a disagreement
    between images that names image 0 by its file (the first image: position 0 is a name too)."""
    rng = np.random.default_rng(5)
    curves = [Curve(c.points, 1, c.straight) for c in views(TRUTH, rng, 16, n_views=1, arcs_per_view=0)]
    curves += [Curve(c, 0, straight=False) for c in arcs(rng, 8)]
    curves += [Curve(c, 0) for c in line_curves(TRUTH, rng, 2)]
    result = refine_camera(spec_of(TRUTH), curves, image_names=['arcs.png', 'lines.png'])
    assert not result.accepted
    assert result.reason.startswith('disagreement between images: most curves of image(s) arcs.png are not '
                                    'straight'), result.reason


def test_an_image_is_labelled_by_its_name_or_else_its_id():
    from zeroshot_calib_ros.core.estimation.refine import _image_label
    names = ['a.png', 'b.png']
    assert [_image_label(names, i) for i in (0, 1, np.int64(1))] == ['a.png', 'b.png', 'b.png']
    assert _image_label(names, 2) == '2' and _image_label(None, 0) == '0' and _image_label(names, 'f3') == 'f3'


def test_images_without_lines_keep_zero_shot():
    black = np.zeros((H, W), np.uint8)
    result = refine_from_images(spec_of(TRUTH), [black, black])
    assert not result.accepted and result.reason.startswith('too few lines')
    assert np.allclose(result.camera.K, zero_shot_camera(spec_of(TRUTH), W, H).K)


def test_lines_that_agree_with_zero_shot_keep_it_with_its_error_bar():
    """A few noisy lines (2 px) imaged through the zero-shot camera itself: the fit wanders
    within its spread and cannot tell zero-shot is worse, so zero-shot is kept, and the error
    bar reported is the zero-shot camera's own (the FOV tolerance's), not the fit's: by the
    held-out lines where they say so, else by the comparison of the two error bars (a seed of
    each is among these)."""
    spec = spec_of(TRUTH)
    zs = zero_shot_camera(spec, W, H)
    reasons = []
    for seed in range(4):
        curves = views(zs, np.random.default_rng(seed), 4, noise=2.0, arcs_per_view=0)
        result = refine_camera(spec, curves)
        assert not result.accepted, result.reason
        assert np.allclose(result.camera.K, zs.K) and np.allclose(result.camera.D, zs.D)
        assert result.uncertainty_px == pytest.approx(zero_shot_uncertainty(spec).rms_px)
        reasons.append(result.reason.split(':')[0])
    assert 'the lines do not rule out zero-shot' in reasons and 'held-out lines are not explained better' in reasons



def test_the_held_out_curves_do_not_depend_on_the_order_of_the_images():
    """The gate's held-out curves are the same whatever order the images come in (a user's
    glob, a node's frames): the decision and the held-out figures with them. One image: every
    ``HOLD_OUT_EVERY``-th of its curves, from the third."""
    from zeroshot_calib_ros.core.estimation.refine import HOLD_OUT_EVERY, _curve_lengths, _hold_out_split
    from zeroshot_calib_ros.core.lines.straightness import StraightnessTerm
    # each curve's own length, whatever curve comes before it
    pair = [np.array([[0.0, 0.0], [3.0, 4.0], [6.0, 8.0]]), np.array([[100.0, 0.0], [100.0, 3.0], [100.0, 7.0]])]
    assert _curve_lengths(StraightnessTerm(pair)).tolist() == pytest.approx([10.0, 7.0])
    assert _curve_lengths(StraightnessTerm(pair[::-1])).tolist() == pytest.approx([7.0, 10.0])
    lengths = np.linspace(300.0, 40.0, 23)
    assert np.flatnonzero(_hold_out_split([0] * 23, lengths)).tolist() == list(range(2, 23, HOLD_OUT_EVERY))

    # the place in its image's list first, then the longest: not the length alone, nor the shortest first
    assert np.flatnonzero(_hold_out_split(list('abcdef'), [10, 60, 30, 20, 40, 50])).tolist() == [4]
    assert np.flatnonzero(_hold_out_split(['a'] * 3 + ['b'] * 3, [100, 90, 80, 20, 10, 5])).tolist() == [1]
    assert np.flatnonzero(_hold_out_split([0] * 6, [10, 60, 30, 20, 40, 50])).tolist() == [2]

    rng = np.random.default_rng(5)
    blocks = {image: rng.uniform(30, 400, size) for image, size in (('a', 9), ('b', 14), ('c', 6))}
    for image in blocks:
        blocks[image] = -np.sort(-blocks[image])  # each image's curves longest first, as detected
    held_sets = []
    for order in (('a', 'b', 'c'), ('c', 'a', 'b'), ('b', 'c', 'a')):
        images = [image for image in order for _ in blocks[image]]
        places = [place for image in order for place in range(len(blocks[image]))]
        held = _hold_out_split(images, np.concatenate([blocks[image] for image in order]))
        held_sets.append({(images[k], places[k]) for k in np.flatnonzero(held)})
    assert held_sets[0] == held_sets[1] == held_sets[2] and len(held_sets[0]) == len(range(2, 29, HOLD_OUT_EVERY))

    every = views(TRUTH, np.random.default_rng(7), 10)
    lines = {0: 7, 1: 10, 2: 9, 3: 8}  # images of different line counts: a rotation of them moves the split
    curves = [c for v in range(4) for c in [c for c in every if c.image == v and c.straight][:lines[v]]
              + [c for c in every if c.image == v and not c.straight]]
    forward = refine_camera(spec_of(TRUTH), curves)
    backward = refine_camera(spec_of(TRUTH), [c for v in (3, 2, 1, 0) for c in curves if c.image == v])
    assert forward.accepted == backward.accepted and forward.lines_used == backward.lines_used
    assert backward.held_out_px_before == pytest.approx(forward.held_out_px_before, rel=1e-6)
    assert backward.held_out_px_after == pytest.approx(forward.held_out_px_after, rel=1e-3)

def test_smallest_eigenvectors_match_numpy():
    """The adjugate iteration against numpy's eigh, on scatters of rays near a plane (long and
    short arcs, noise up to longer than the arc) and on degenerate ones (one ray, no ray)."""
    rng = np.random.default_rng(3)
    scatters = []
    for k in range(300):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        e1 = np.cross(n, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        t = rng.uniform(-1, 1, 12) * rng.choice([1e-4, 0.01, 1.0])
        noise = rng.normal(0, rng.choice([0.0, 1e-5, 1e-3]), (12, 1))
        rays = np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2 + noise * n
        scatters.append(rays.T @ rays)
    scatters += [np.outer([0.0, 0.6, 0.8], [0.0, 0.6, 0.8]), np.zeros((3, 3))]
    S = np.array(scatters)
    v = smallest_eigenvectors(S)
    w, V = np.linalg.eigh(S)
    assert np.allclose(np.linalg.norm(v, axis=1), 1.0)
    # the eigenvector where the smallest eigenvalue is simple; an eigenvector of it in any case
    simple = w[:, 1] - w[:, 0] > 1e-9 * np.maximum(w[:, 2], 1e-300)
    assert np.all(np.abs(np.sum(v[simple] * V[simple, :, 0], axis=1)) > 1 - 1e-12)
    residual = np.einsum('cij,cj->ci', S, v) - w[:, :1] * v
    assert np.all(np.linalg.norm(residual, axis=1) <= 1e-9 * np.maximum(w[:, 2], 1e-12))


def test_zoom_field_of_a_pinhole_is_the_offset_from_the_principal_point():
    """r -> (s x, s y, z) through a pinhole moves pixel u by d u / d s = u - c (closed form)."""
    camera = PinholeCamera(500.0, 500.0, 330.0, 250.0, 640, 480)
    pixels = pixel_grid(640, 480)
    field = zoom_field(camera, camera.unproject(pixels)).reshape(-1, 2)
    assert np.allclose(field, pixels - [330.0, 250.0], atol=1e-3)


def test_systematic_floor_only_widens_the_covariance(refined):
    """A floor of 0 is the Laplace covariance; a floor > 0 is at least as wide in every
    direction, and much wider where the lines speak only through small curvatures."""
    from zeroshot_calib_ros.core.estimation.fit import fit_lines
    from zeroshot_calib_ros.core.estimation.terms import ShapePrior
    curves, _ = refined
    spec = spec_of(TRUTH)
    zs = zero_shot_camera(spec, W, H)
    term = StraightnessTerm([c.points for c in curves if c.straight], sigma=0.3)
    priors = [FovTerm.from_spec(spec), PrincipalPointPrior(W, H), ShapePrior(zs, zs.max_field_angle(), 0.02)]
    fit = fit_lines(term, priors, zs)
    J = fit.problem.jacobian(fit.solution.x)
    laplace, _ = covariance(J)
    zero, _ = systematic_covariance(fit.problem, fit.solution.x, J, 0.0)
    assert np.allclose(zero, laplace, rtol=1e-6, atol=0)
    wide, _ = systematic_covariance(fit.problem, fit.solution.x, J, 0.3)
    scale = np.sqrt(np.diag(laplace))
    difference = (wide - laplace) / np.outer(scale, scale)
    assert np.linalg.eigvalsh(0.5 * (difference + difference.T)).min() > -1e-9
    assert np.trace(difference) > 0.5


def test_rezoom_finds_the_zoom_the_fovs_ask_for():
    """FOVs of the true camera composed with the zoom r -> (s x, s y, z), s = 1.006, computed
    from its own rays (the angle between the zoomed rays of the edge pixels): ``rezoom`` of the
    true camera meets them, and projects every ray as the zoomed camera does."""
    from zeroshot_calib_ros.core.estimation.refine import rezoom
    s = 1.006

    def zoomed_ray(pixel):
        r = TRUTH.unproject(np.array([pixel], float))[0] * [1 / s, 1 / s, 1.0]
        return r / np.linalg.norm(r)

    def angle(a, b):  # through the optical axis when the two rays' off-axis angles exceed 180 degrees
        ra, rb = zoomed_ray(a), zoomed_ray(b)
        between = math.degrees(math.acos(np.clip(ra @ rb, -1, 1)))
        off = sum(math.degrees(math.atan2(math.hypot(r[0], r[1]), r[2])) for r in (ra, rb))
        return 360.0 - between if off > 180.0 else between

    cx, cy = TRUTH.cx, TRUTH.cy
    fovs = {'hfov': angle((0, cy), (W, cy)), 'vfov': angle((cx, 0), (cx, H)), 'dfov': angle((0, 0), (W, H))}
    term = FovTerm(fovs, W, H, 1.0)
    assert np.abs(term.residuals(TRUTH)).max() > 0.3  # the unzoomed camera misses them
    out = rezoom(TRUTH, term)
    assert np.abs(term.residuals(out)).max() < 0.02
    rays = TRUTH.unproject(pixel_grid(W, H))
    rays = rays[np.all(np.isfinite(rays), axis=1)] * [1 / s, 1 / s, 1.0]
    expected = TRUTH.project(rays * [s, s, 1.0])
    assert np.max(np.linalg.norm(out.project(rays) - expected, axis=1)) < 0.05


def test_one_camera_with_a_wrong_spec_is_the_spec_disagreeing_not_the_images():
    """Four views of the true lens and a spec whose hfov and dfov are 6 degrees wider than the
    lens's (fields_of_view_through_axis of the known camera): the images agree with one another,
    the spec does not, and the reason must say so, not blame the images (the FOVs pull each
    image's camera towards the wrong spec by a different amount; the consistency test between
    images must not take that for two cameras). Zero-shot kept."""
    fovs = fields_of_view_through_axis(TRUTH)
    spec = CameraSpec(W, H, hfov=fovs['hfov'] + 6, vfov=fovs['vfov'], dfov=fovs['dfov'] + 6)
    result = refine_camera(spec, views(TRUTH, np.random.default_rng(4), 10))
    assert not result.accepted
    assert result.reason.startswith('disagreement between the lines and the spec'), result.reason
    assert np.allclose(result.camera.K, result.zero_shot_camera.K)
    # the lines' FOV follows the spec given (they hardly fix the scale): the user is sent to the
    # spec sheet, not invited to give that FOV back
    assert 'deg); check the spec sheet' in result.reason and 'would not be a measurement' in result.reason


@pytest.mark.parametrize('deviation, order', [([0, 0, 0, 0], 0), ([0.004, 0, 0, 0], 1), ([0.004, -0.002, 0, 0], 2)])
def test_the_line_fit_frees_only_the_shape_terms_the_lines_pay_for(deviation, order):
    """The order choice (AIC): noise-free lines of a camera whose shape departs from zero-shot's
    in its first n terms only: the fit keeps order n (every further term buys nothing and costs
    the penalty; one term fewer leaves the lines bent)."""
    from zeroshot_calib_ros.core.estimation.fit import fit_lines
    from zeroshot_calib_ros.core.estimation.terms import ShapePrior
    zs = zero_shot_camera(spec_of(TRUTH), W, H)
    camera = KannalaBrandtCamera(zs.fx, zs.fy, zs.cx, zs.cy, W, H, zs.D + np.array(deviation))
    spec = spec_of(camera)
    rng = np.random.default_rng(1)
    term = StraightnessTerm([c for _ in range(4) for c in line_curves(camera, rng, 10, noise=0.0)], sigma=0.3)
    priors = [FovTerm.from_spec(spec), PrincipalPointPrior(W, H), ShapePrior(zs, zs.max_field_angle(), 0.02)]
    fit = fit_lines(term, priors, zs)
    assert fit.order == order, fit.bic
    assert best_rotation_rms(fit.camera, camera) < 0.05


def test_coverage_counts_the_cells_of_the_8_by_6_grid_the_points_touch():
    """The refinement's coverage: the fraction of an 8 x 6 grid's cells (8 columns across the
    width, 6 rows down the height) that the points touch; reach: farthest point from the centre
    over the half-diagonal."""
    from zeroshot_calib_ros.core.estimation.refine import COVERAGE_GRID, coverage_of
    assert COVERAGE_GRID == (8, 6)
    t = np.linspace(0.0, 1.0, 20001)
    # the diagonal from corner to corner crosses 8 + 6 - gcd(8, 6) = 12 cells
    diagonal = np.stack([t * W, t * H], axis=1)
    assert coverage_of(diagonal, W, H) == (pytest.approx(12 / 48), pytest.approx(1.0))
    # a vertical run down the top half of the first column: rows 0-2 of 6
    column = np.stack([np.full_like(t, 0.5 * W / 8), t * (H / 2 - 1)], axis=1)
    assert coverage_of(column, W, H)[0] == pytest.approx(3 / 48)
    # a horizontal run across the left half of the last row: columns 0-3 of 8
    row = np.stack([t * (W / 2 - 1), np.full_like(t, H - 1.0)], axis=1)
    assert coverage_of(row, W, H)[0] == pytest.approx(4 / 48)
    # the centre of each cell of the bottom-right quarter: 4 x 3 cells
    centres = np.array([[(i + 0.5) * W / 8, (j + 0.5) * H / 6] for i in range(4, 8) for j in range(3, 6)])
    coverage, reach = coverage_of(centres, W, H)
    assert coverage == pytest.approx(12 / 48)
    assert reach == pytest.approx(math.hypot(3.5 * W / 8, 2.5 * H / 6) / math.hypot(W / 2, H / 2))
    assert coverage_of(np.empty((0, 2)), W, H) == (0.0, 0.0)


@pytest.mark.parametrize('factor', [0.5, 2.0])
def test_zero_shot_error_bar_of_frames_at_another_size_is_in_their_pixels(factor):
    """Frames at another size than the spec's (a binned or resized mode): the zero-shot error bar
    the refinement reports (and gates against) is in the frames' pixels: the same as the error
    bar of the same lens specified at the frames' size (an independent computation)."""
    spec = spec_of(TRUTH)
    width, height = int(W * factor), int(H * factor)
    at_spec_size = zero_shot_uncertainty(spec).rms_px
    at_frame_size = zero_shot_uncertainty(CameraSpec(width, height, **spec.given())).rms_px
    assert at_frame_size == pytest.approx(factor * at_spec_size, rel=0.02)  # pixels scale with the size
    result = refine_camera(spec, [], width, height)
    assert not result.accepted
    assert result.zero_shot_uncertainty_px == pytest.approx(at_frame_size, rel=0.02)
    assert result.uncertainty_px == result.zero_shot_uncertainty_px


def test_refine_from_images_makes_curves_again_under_the_refined_camera(monkeypatch):
    """refine_from_images: the edge points are looked for once per image, with zero-shot's camera
    of the spec's FOVs rounded (where to look); the first round's curves are made of them under zero-shot's camera, the second
    round's of the same edge points under the camera the first fit gave, which also starts the
    second fit."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    from zeroshot_calib_ros.core.lines import detect as detect_module
    spec = spec_of(TRUTH)
    zs = zero_shot_camera(spec, W, H)
    looked_with, curves_under, started_from = [], [], []

    def find_edges(image, camera, views=None, **kwargs):
        looked_with.append(camera)
        return object()

    def curves_from_edges(edges, camera, image_id=None):
        curves_under.append((edges, camera, image_id))
        return []

    def fit(spec, curves, width, height, tolerance, initial=None, solution=None, image_circle=None, image_names=None):
        started_from.append(initial)
        return refine_module.Refinement(TRUTH, True, 'accepted', 1.0, 3.0, 0, 0, None, None, 0.0, 0.0,
                                        zero_shot_camera=zs)
    monkeypatch.setattr(detect_module, 'find_edges', find_edges)
    monkeypatch.setattr(detect_module, 'curves_from_edges', curves_from_edges)
    monkeypatch.setattr(detect_module, 'make_views', lambda camera, **kw: None)
    monkeypatch.setattr(refine_module, 'refine_camera', fit)
    refine_from_images(spec, [np.zeros((H, W), np.uint8)] * 2, rounds=2)
    assert len(looked_with) == 2  # with zero-shot's camera of the spec's FOVs rounded (where to look)
    look = zero_shot_start(spec, W, H).detection_camera
    assert all(np.allclose(c.K, look.K) and np.allclose(c.D, look.D) for c in looked_with)
    assert len(curves_under) == 4
    first, second = curves_under[:2], curves_under[2:]
    assert all(np.allclose(c.K, zs.K) and np.allclose(c.D, zs.D) for _, c, _ in first)
    assert all(c is TRUTH for _, c, _ in second)
    assert [e for e, _, _ in second] == [e for e, _, _ in first] and first[0][0] is not first[1][0]
    assert [i for _, _, i in curves_under] == [0, 1, 0, 1]
    assert started_from == [None, TRUTH]



def test_each_round_fits_the_curves_it_made_and_no_earlier_rounds(monkeypatch):
    """refine_from_images: a round's fit gets that round's curves of every image, once each (not
    the earlier rounds' curves besides), and the static-curve gradients of every image."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    from zeroshot_calib_ros.core.lines import detect as detect_module
    from zeroshot_calib_ros.core.lines.static_curves import image_gradients
    spec = spec_of(TRUTH)
    zs = zero_shot_camera(spec, W, H)
    made, fitted = [], []

    def curves_from_edges(edges, camera, image_id=None):
        made.append(f'curve {len(made)} of image {image_id}')
        return [made[-1]]

    def fit(spec, curves, images, width, height, tolerance, initial=None, solution=None, image_circle=None,
            gradients=None, image_names=None):
        fitted.append((list(curves), dict(gradients)))
        return refine_module.Refinement(TRUTH, True, 'accepted', 1.0, 3.0, 0, 0, None, None, 0.0, 0.0,
                                        zero_shot_camera=zs)
    monkeypatch.setattr(detect_module, 'find_edges', lambda image, camera, views=None, **kw: object())
    monkeypatch.setattr(detect_module, 'curves_from_edges', curves_from_edges)
    monkeypatch.setattr(detect_module, 'make_views', lambda camera, **kw: None)
    monkeypatch.setattr(refine_module, 'refine_from_frames', fit)
    rng = np.random.default_rng(3)
    images = [rng.integers(0, 255, (H, W), dtype=np.uint8) for _ in range(2)]
    refine_from_images(spec, images, rounds=3)
    assert [curves for curves, _ in fitted] == [
        ['curve 0 of image 0', 'curve 1 of image 1'], ['curve 2 of image 0', 'curve 3 of image 1'],
        ['curve 4 of image 0', 'curve 5 of image 1']]
    for _, gradients in fitted:
        assert sorted(gradients) == [0, 1]
        assert all(np.array_equal(gradients[k], image_gradients(image)) for k, image in enumerate(images))


def scripted_rounds(monkeypatch, decisions):
    """refine_from_images with detection stubbed out and ``refine_from_frames`` answering round k
    with a camera of its own (fx = 400 + k), accepted as ``decisions[k]`` says; returns the list
    of the fits' ``image_circle`` arguments."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    from zeroshot_calib_ros.core.lines import detect as detect_module
    circles = []

    def fit(spec, curves, images, width, height, tolerance, initial=None, solution=None, image_circle=None,
            gradients=None, image_names=None):
        k = len(circles)
        circles.append(image_circle)
        camera = KannalaBrandtCamera(400.0 + k, 400.0 + k, W / 2, H / 2, W, H, [0, 0, 0, 0])
        return refine_module.Refinement(camera, decisions[k], f'round {k}', 1.0, 3.0, 0, 0, None, None, 0.0, 0.0)
    monkeypatch.setattr(detect_module, 'find_edges', lambda image, camera, views=None, **kw: object())
    monkeypatch.setattr(detect_module, 'curves_from_edges', lambda edges, camera, image_id=None: [])
    monkeypatch.setattr(detect_module, 'make_views', lambda camera, **kw: None)
    monkeypatch.setattr(refine_module, 'refine_from_frames', fit)
    return circles


def test_no_more_rounds_than_asked_and_at_least_one(monkeypatch):
    """``rounds`` fits in all while each is accepted; ``rounds`` = 0 still fits once."""
    images = [np.zeros((H, W), np.uint8)]
    for rounds, fits in ((0, 1), (1, 1), (3, 3)):
        circles = scripted_rounds(monkeypatch, [True] * 5)
        result = refine_from_images(spec_of(TRUTH), images, rounds=rounds)
        assert len(circles) == fits and result.reason == f'round {fits - 1}'


def test_a_refused_later_round_keeps_the_accepted_camera_before_it(monkeypatch):
    """A round the gate refuses ends the rounds and is not returned when an earlier round was
    accepted: the user gets the last accepted camera, not zero-shot's; a refused first round is
    returned (it holds zero-shot's camera and the reason)."""
    images = [np.zeros((H, W), np.uint8)]
    scripted_rounds(monkeypatch, [True, False, True])
    result = refine_from_images(spec_of(TRUTH), images, rounds=3)
    assert result.accepted and result.reason == 'round 0' and result.camera.fx == 400.0
    circles = scripted_rounds(monkeypatch, [False, True])
    result = refine_from_images(spec_of(TRUTH), images, rounds=2)
    assert len(circles) == 1 and not result.accepted and result.reason == 'round 0'


def test_the_image_circle_seen_is_evidence_only_when_asked(monkeypatch):
    """``use_image_circle=False``: the fit is given no image circle, and the result still reports
    the circle measured (and in how many images); True: the fit gets it."""
    from zeroshot_calib_ros.core.lines.image_region import ImageRegion
    circle = ImageCircle(W / 2 + 3.0, H / 2 - 2.0, 390.0, 0.4, 0.6)
    regions = [ImageRegion(np.ones((H, W), bool), circle), ImageRegion(np.ones((H, W), bool), None)]
    images = [np.zeros((H, W), np.uint8)] * 2
    for use, given in ((False, None), (True, circle)):
        circles = scripted_rounds(monkeypatch, [True, True])
        result = refine_from_images(spec_of(TRUTH), images, regions=regions, use_image_circle=use)
        assert circles == [given, given]
        assert result.image_circle == circle and result.circle_measured_in == 1


def test_jacobian_in_threads_is_the_jacobian_in_one_thread():
    """``jacobian_threads``: the columns computed in several threads (what ``refine --workers``
    uses on a multi-core machine) are the same numbers as in one thread, so a user's result does
    not depend on the machine's cores; and the threads are really used."""
    import threading
    from zeroshot_calib_ros.core.estimation.problem import jacobian_threads
    rng = np.random.default_rng(5)
    term = StraightnessTerm(line_curves(TRUTH, rng, 40))
    seen = set()

    class Recording(FovTerm):
        def residuals(self, camera):
            seen.add(threading.get_ident())
            return super().residuals(camera)

    spec = spec_of(TRUTH)
    layout = KannalaBrandtLayout(zero_shot_camera(spec, W, H), 4)
    problem = Problem(layout, [term, Recording(dict(spec.given()), W, H)])
    x = layout.x_from(zero_shot_camera(spec, W, H)) * (1 + 1e-3)
    alone = problem.jacobian(x)
    assert seen == {threading.get_ident()}
    seen.clear()
    with jacobian_threads(2):
        threaded = problem.jacobian(x)
    assert np.array_equal(threaded, alone)
    assert seen and threading.get_ident() not in seen
    # outside the block: one thread again
    seen.clear()
    assert np.array_equal(problem.jacobian(x), alone) and seen == {threading.get_ident()}


@pytest.mark.parametrize('threads', [2, 3])
def test_jacobian_threads_computes_that_many_columns_at_once(threads):
    """``jacobian_threads(n)`` evaluates n columns at the same time (what makes ``refine`` use the
    machine's cores), not one after another in one helper thread: each of n threads, at its first
    evaluation, waits at a barrier that only n threads arriving together pass. The threads end
    with the block."""
    import threading
    from zeroshot_calib_ros.core.estimation.problem import jacobian_threads
    caller = threading.get_ident()
    barrier, met, lock = threading.Barrier(threads, timeout=20), set(), threading.Lock()

    class Meeting(FovTerm):
        def residuals(self, camera):
            me = threading.get_ident()
            with lock:
                first = me != caller and me not in met
                met.add(me)
            if first:
                barrier.wait()  # BrokenBarrierError after the timeout unless n threads run at once
            return super().residuals(camera)

    spec = spec_of(TRUTH)
    layout = KannalaBrandtLayout(zero_shot_camera(spec, W, H), 4)
    problem = Problem(layout, [StraightnessTerm(line_curves(TRUTH, np.random.default_rng(5), 10)),
                               Meeting(dict(spec.given()), W, H)])
    x = layout.x_from(zero_shot_camera(spec, W, H))
    assert x.size > threads
    with jacobian_threads(threads):
        J = problem.jacobian(x)
    workers = met - {caller}
    assert len(workers) == threads and np.all(np.isfinite(J))
    # the block's threads end with it (a long-running caller is left no idle threads)
    assert not workers & {t.ident for t in threading.enumerate()}


def test_refine_from_images_fits_in_its_workers(monkeypatch):
    """``refine_from_images(workers=n)`` (``zeroshot-calib refine`` passes the machine's cores) also
    computes its fits' Jacobians in worker threads, not only the detection; with one worker
    everything runs in the calling thread. (One image: it is detected in this process, where the
    detector's stand-ins below apply.)"""
    import threading
    from zeroshot_calib_ros.core.estimation import problem as problem_module
    from zeroshot_calib_ros.core.lines import detect as detect_module
    rng = np.random.default_rng(11)
    curves = {0: [Curve(p, 0) for p in line_curves(TRUTH, rng, 24)]}
    monkeypatch.setattr(detect_module, 'find_edges', lambda image, camera, views=None, **kw: object())
    monkeypatch.setattr(detect_module, 'curves_from_edges', lambda edges, camera, image_id=None: curves[image_id])
    monkeypatch.setattr(detect_module, 'make_views', lambda camera, **kw: None)
    evaluate, threads = problem_module.Problem._evaluate, []

    def recording(self, x, robust):
        threads.append(threading.get_ident())
        return evaluate(self, x, robust)

    monkeypatch.setattr(problem_module.Problem, '_evaluate', recording)
    images = [np.zeros((H, W), np.uint8)]
    result = refine_from_images(spec_of(TRUTH), images, rounds=1, workers=2)
    assert result.lines_used > 0 and threads
    assert set(threads) - {threading.get_ident()}, 'every Jacobian column was computed in the calling thread'
    threads.clear()
    refine_from_images(spec_of(TRUTH), images, rounds=1, workers=1)
    assert threads and set(threads) == {threading.get_ident()}


def test_refine_from_images_detects_each_image_with_the_options_given():
    """Detection options given to ``refine_from_images`` (here ``max_curves``) are the detector's,
    and each image's curves are found in that image: a blank frame beside a rendered room gives
    none, the room at most ``max_curves``."""
    import scenes
    small = TRUTH.scaled(480, 300)
    room = scenes.render(small, 'room', seed=1)[0]
    blank = np.full_like(room, 128)
    result = refine_from_images(spec_of(small), [blank, room], rounds=1, max_curves=4)
    found = result.curves + result.static_curves
    assert found and {c.image for c in found} == {1}
    assert len(found) <= 4


def test_straightness_residuals_remembered_are_those_computed():
    """Terms made from one another by subset share the point residuals already computed for a
    camera: each gets the numbers it would compute itself (any order of curves, subsets of
    subsets, a pickled copy), and a Kannala-Brandt camera of another class is another key."""
    from zeroshot_calib_ros.core.estimation.parameters import TabulatedKannalaBrandtCamera
    rng = np.random.default_rng(5)
    camera = KannalaBrandtCamera(600.0, 600.0, 640.0, 400.0, 1280, 800, [0.02, -0.01, 0.003, -0.0005])
    curves = []
    for _ in range(12):
        a, b = rng.uniform([100, 100], [1180, 700], size=(2, 2))
        t = np.linspace(0.0, 1.0, int(rng.integers(8, 20)))[:, None]
        curves.append(a + t * (b - a) + rng.normal(0.0, 0.3, size=(len(t), 2)))
    term = StraightnessTerm(curves)
    whole = term.point_residuals(camera)
    assert np.array_equal(whole, StraightnessTerm(curves)._point_residuals(camera), equal_nan=True)
    order = rng.permutation(len(curves))
    for sub in (term.subset(order), term.subset(order[:5]), term.with_sigma(2.0),
                term.subset(order).subset(np.arange(len(curves)) % 2 == 0)):
        alone = StraightnessTerm(sub.curves)._point_residuals(camera)
        assert np.array_equal(sub.point_residuals(camera), alone, equal_nan=True)
    tabulated = TabulatedKannalaBrandtCamera(camera.fx, camera.fy, camera.cx, camera.cy, camera.width,
                                             camera.height, camera.D)
    assert np.array_equal(term.subset(order[:5]).point_residuals(tabulated),
                          StraightnessTerm([curves[i] for i in order[:5]])._point_residuals(tabulated), equal_nan=True)
    import pickle
    copy = pickle.loads(pickle.dumps(term))
    assert np.array_equal(copy.point_residuals(camera), whole, equal_nan=True)


def test_a_library_callers_refine_camera_runs_openblas_in_one_thread(monkeypatch):
    """refine_camera called directly (not through refine_from_frames) solves with one OpenBLAS
    thread too, and gives the caller's count back."""
    from openblas_threads import assert_solves_use_one_openblas_thread
    curves = views(TRUTH, np.random.default_rng(7), 6, n_views=2)
    assert_solves_use_one_openblas_thread(monkeypatch, lambda: refine_camera(spec_of(TRUTH), curves))


def test_the_fit_runs_openblas_in_one_thread_and_gives_the_threads_back():
    """refine's fits run every OpenBLAS in one thread (threads waiting for busy cores made each SVD
    of the Jacobian ten times slower); nested and overlapping blocks keep it at one until the
    last ends, which restores what the process had."""
    import threading
    from zeroshot_calib_ros.core.estimation.problem import one_blas_thread, openblas_thread_controls
    blas = np.show_config(mode='dicts')['Build Dependencies']['blas']['name'].lower()
    controls = openblas_thread_controls()
    if 'openblas' in blas:
        assert controls, 'numpy uses OpenBLAS, but no OpenBLAS thread control was found'
    if not controls:
        pytest.skip('no OpenBLAS in this process')
    before = [get() for get, _ in controls]
    try:
        for _, put in controls:
            put(3)
        # a single-threaded build (OpenCV's own old copy on some systems) stays at one: nothing to do there
        controls = [(get, put) for get, put in controls if get() == 3]
        if 'openblas' in blas:
            assert controls, "numpy's OpenBLAS does not take a thread count"
        entered, leave = threading.Event(), threading.Event()

        def other_fit():
            with one_blas_thread():
                entered.set()
                leave.wait(10)

        with one_blas_thread():
            assert [get() for get, _ in controls] == [1] * len(controls)
            worker = threading.Thread(target=other_fit)
            worker.start()
            assert entered.wait(10)
        assert [get() for get, _ in controls] == [1] * len(controls)  # the other fit still runs
        leave.set()
        worker.join(10)
        assert [get() for get, _ in controls] == [3] * len(controls)
    finally:
        for (_, put), count in zip(openblas_thread_controls(), before):
            put(count)


@pytest.mark.parametrize('radius, fovs, past', [
    (282.0, {'hfov': 206.3, 'vfov': 141.0}, ['hfov']),   # OCamCalib's 748 x 480 fisheye: clipped top and bottom
    (282.0, {'dfov': 218.0}, ['dfov']),
    (230.0, {'vfov': 150.0}, ['vfov']),                   # the circle inside the image on every side
    (370.0, {'hfov': 200.0}, ['hfov']),                  # off-centre: only the left edge (383.6 px away) is past
    (460.0, {'hfov': 200.0, 'vfov': 150.0, 'dfov': 230.0}, []),   # a full-frame fisheye: its corners lit
])
def test_the_fovs_stated_across_pixels_past_the_image_circle_are_named(radius, fovs, past):
    """``fovs_past_image_circle`` / ``dark_fov_warning``: a FOV is measured to the image's edges (hfov:
    left and right, vfov: top and bottom, dfov: the corners) through the principal point, the circle's
    centre; an edge farther from it than the circle's radius (and its margin) is past the circle, in
    the dark. One warning line names each such FOV with its value and where its edges are, and says
    what to give instead (circle_fov), or what states the scale when circle_fov is given."""
    from zeroshot_calib_ros.core.estimation.refine import dark_fov_warning, fovs_past_image_circle
    circle = ImageCircle(383.6, 239.4, radius, 0.3, 0.5)
    spec = CameraSpec(748, 480, **fovs)
    assert fovs_past_image_circle(spec, circle, 748, 480) == past
    text = dark_fov_warning(spec, circle, 748, 480)
    assert (text is None) == (not past)
    if past:
        for name in past:
            assert f'{name} {fovs[name]:g} (to the ' in text
        assert '\n' not in text and 'give that as circle_fov' in text and f'({2 * radius:.0f} px across)' in text
        with_circle = CameraSpec(748, 480, circle_diameter=2 * radius, circle_fov=178.7, **fovs)
        assert 'circle_fov) states the scale where light is' in dark_fov_warning(with_circle, circle, 748, 480)
    # at half the spec's size (binned images), the same circle measured at half the size
    half = ImageCircle(383.6 / 2, 239.4 / 2, radius / 2, 0.3, 0.5)
    assert fovs_past_image_circle(spec, half, 374, 240) == past
    assert dark_fov_warning(spec, None, 748, 480) is None


def test_an_edge_within_the_rims_uncertainty_is_not_past_the_circle():
    """An hfov whose edges lie on the measured rim, within 3 sigmas of its radius, is not warned
    about (the rim's fade is the measurement's own doubt), 4 sigmas out it is."""
    from zeroshot_calib_ros.core.estimation.refine import fovs_past_image_circle
    spec = CameraSpec(640, 480, hfov=185.0)
    sigma = 2.0  # radius_uncertainty_px of a rim measured to 2 px
    on_rim = ImageCircle(320.0, 240.0, 320.0 - 2.9 * sigma, 0.3, sigma)
    assert fovs_past_image_circle(spec, on_rim, 640, 480) == []
    beyond = ImageCircle(320.0, 240.0, 320.0 - 3.1 * sigma, 0.3, sigma)
    assert fovs_past_image_circle(spec, beyond, 640, 480) == ['hfov']


EUROC_TURNED = [0.9413667673048535, -2.842075242672644, 4.432877808560697, -2.2882789278181583]
"""k1..k4 of the camera a real 752 x 480 camera's one photo was fitted with (EuRoC's, hfov 93 alone):
its lens curve turns back at 57 degrees, short of the image's corners."""


def test_a_camera_without_rays_for_pixels_zero_shot_images_is_named():
    """``_pixels_without_rays``: the grid pixels the reference (zero-shot) has a ray for and the
    camera has none for (its lens curve turns back inside the image) are counted, with the angle
    where the curve turns; none inside an image circle that ends before it; a camera with rays
    everywhere is fine."""
    from zeroshot_calib_ros.core.estimation.refine import _pixels_without_rays
    turned = KannalaBrandtCamera(371.6, 371.6, 403.2, 234.0, 752, 480, EUROC_TURNED)
    reference = zero_shot_camera(CameraSpec(752, 480, hfov=93.0), 752, 480)
    reason = _pixels_without_rays(turned, reference, 752, 480)
    assert reason is not None and 'turns back at 57 degrees' in reason, reason
    lost = int(reason.split('no ray for ')[1].split(' of ')[0])
    assert 2 <= lost < 20, reason  # the two corners farthest from its principal point, not the image
    assert _pixels_without_rays(reference, reference, 752, 480) is None
    # only what the reference images counts: a pixel neither has a ray for is nobody's loss
    assert _pixels_without_rays(turned, turned, 752, 480) is None
    # inside a circle of 300 px about the principal point every pixel has a ray
    assert _pixels_without_rays(turned, reference, 752, 480, (300.0, (403.2, 234.0))) is None


def test_a_lens_curve_turning_back_past_90_degrees_is_said_to_turn_back_there():
    """A fisheye fit whose curve turns back at 120 degrees off-axis, short of the corners a 190-degree
    zero-shot images: the reason names that angle, not the model's end at 180 degrees."""
    from zeroshot_calib_ros.core.estimation.refine import _pixels_without_rays
    turned = KannalaBrandtCamera(250.0, 250.0, 376.0, 240.0, 752, 480, [-0.076, 0.0, 0.0, 0.0])
    assert math.degrees(turned.theta_max) == pytest.approx(120.0, abs=0.5)
    reason = _pixels_without_rays(turned, zero_shot_camera(CameraSpec(752, 480, hfov=190.0), 752, 480), 752, 480)
    assert reason is not None and '(its lens curve turns back at 120 degrees off-axis)' in reason, reason


def test_refine_refuses_a_fit_whose_lens_curve_turns_back_inside_the_image(monkeypatch):
    """A fit that straightens the lines with a lens curve turning back short of the corners (where no
    line held it) is refused, with the zero-shot camera returned, whatever the other checks say."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    real = refine_module.fit_lines

    def turned_back(*args, **kwargs):
        fit = real(*args, **kwargs)
        fit.camera = KannalaBrandtCamera(fit.camera.fx, fit.camera.fy, fit.camera.cx, fit.camera.cy, W, H,
                                         [0.9, -2.8, 4.4, -2.3])
        return fit
    monkeypatch.setattr(refine_module, 'fit_lines', turned_back)
    monkeypatch.setattr(refine_module, 'REZOOM', False)
    rng = np.random.default_rng(7)
    result = refine_camera(spec_of(TRUTH), views(TRUTH, rng, 10))
    assert not result.accepted and 'has no ray for' in result.reason, result.reason
    assert result.camera is result.zero_shot_camera


@pytest.mark.parametrize('circle, fovs, past', [
    # only the corner far from an off-centre circle is dark: dfov is measured to both corners
    ((300.0, 200.0, 420.0, 0.5), {'dfov': 230.0}, ['dfov']),
    # a rim measured exactly (no uncertainty) keeps a floor of 1 px: 0.8 px out is on the rim
    ((300.0, 240.0, 339.2, 0.0), {'hfov': 185.0}, []),
    # the edges are the FOV's own: x = 0 and x = W (1.8 px out here, past the 1.5 px margin)
    ((300.0, 240.0, 338.2, 0.5), {'hfov': 185.0}, ['hfov']),
    # measured through the principal point (the circle's centre), not the image's centre row
    ((320.0, 100.0, 330.0, 0.5), {'hfov': 185.0}, []),
])
def test_a_fov_is_past_the_circle_where_its_own_edges_are(circle, fovs, past):
    """``fovs_past_image_circle`` on a 640 x 480 image: each FOV's edges where the spec measures it
    (through the principal point, to x = 0 and x = W, y = 0 and y = H, the corners), against the
    circle's radius plus max(1 px, 3 sigmas)."""
    from zeroshot_calib_ros.core.estimation.refine import fovs_past_image_circle
    cx, cy, radius, sigma = circle
    spec = CameraSpec(640, 480, **fovs)
    assert fovs_past_image_circle(spec, ImageCircle(cx, cy, radius, 0.3, sigma), 640, 480) == past


@pytest.mark.parametrize('cx, cy, radius, fovs, words', [
    (320.0, 240.0, 300.0, {'hfov': 185.0}, 'hfov 185 (to the left and right edges)'),
    (350.0, 240.0, 320.0, {'hfov': 185.0}, 'hfov 185 (to the left edge)'),     # x = 0 is 350 px out, W 290
    (290.0, 240.0, 320.0, {'hfov': 185.0}, 'hfov 185 (to the right edge)'),
    (320.0, 260.0, 255.0, {'vfov': 185.0}, 'vfov 185 (to the top edge)'),
    (320.0, 220.0, 255.0, {'vfov': 185.0}, 'vfov 185 (to the bottom edge)'),
    (320.0, 260.0, 395.0, {'dfov': 230.0}, 'dfov 230 (to the top-left corner)'),
    (320.0, 220.0, 395.0, {'dfov': 230.0}, 'dfov 230 (to the bottom-right corner)'),
    (320.0, 240.0, 380.0, {'dfov': 230.0}, 'dfov 230 (to the corners)'),
])
def test_the_dark_fov_warning_names_the_edges_that_are_past_the_circle(cx, cy, radius, fovs, words):
    """A circle seen off the image's centre can end before one edge and reach past the other (a real
    1032 x 778 fisheye: its circle, centred at x 546.7, passes the right edge): the warning names the
    edge that is dark, not both."""
    from zeroshot_calib_ros.core.estimation.refine import dark_fov_warning
    warning = dark_fov_warning(CameraSpec(640, 480, **fovs), ImageCircle(cx, cy, radius, 0.3, 0.5), 640, 480)
    assert warning is not None and warning.startswith(words + ':'), warning


def test_the_dark_fov_warning_speaks_of_one_fov_or_several():
    from zeroshot_calib_ros.core.estimation.refine import dark_fov_warning
    circle = ImageCircle(383.6, 239.4, 282.0, 0.3, 0.5)
    one = dark_fov_warning(CameraSpec(748, 480, hfov=206.3), circle, 748, 480)
    assert 'ends before it reaches them' in one and 'the scale it gives' in one, one
    two = dark_fov_warning(CameraSpec(748, 480, hfov=206.3, dfov=218.0), circle, 748, 480)
    assert two.startswith('hfov 206.3 (to the left and right edges), dfov 218 (to the corners): ')
    assert 'ends before they reach them' in two and 'the scale they give' in two, two


def test_images_of_another_size_than_the_spec_are_judged_at_their_own_size():
    """The spec of a 1280 x 960 mode, images binned to 640 x 480 with the circle measured in them:
    a full-frame fisheye's circle (420 px of radius there) lights every edge and corner, so no FOV
    is past it (judged at the spec's size, against a circle measured at half of it, every FOV was)."""
    spec = CameraSpec(1280, 960, hfov=200.0, vfov=150.0, dfov=230.0)
    result = refine_camera(spec, [], 640, 480, image_circle=ImageCircle(320.0, 240.0, 420.0, 0.3, 0.5))
    assert result.spec_warnings == [] and not result.accepted
    small = refine_camera(spec, [], 640, 480, image_circle=ImageCircle(320.0, 240.0, 260.0, 0.3, 0.5))
    assert len(small.spec_warnings) == 1 and small.spec_warnings[0].startswith('hfov 200 (to the left and right')


def test_a_camera_whose_curve_turns_back_just_past_a_corner_is_named():
    """The grid reaches the image's corners, pixel (W, H) included: a camera whose lens curve turns
    back 0.3 px short of the far corner (and still has a ray at (W - 1, H - 1)) is named."""
    from zeroshot_calib_ros.core.estimation.refine import _pixels_without_rays
    camera = KannalaBrandtCamera(371.6, 371.6, 362.111, 231.135, 752, 480, EUROC_TURNED)
    reference = zero_shot_camera(CameraSpec(752, 480, hfov=93.0), 752, 480)
    assert np.all(np.isfinite(camera.unproject(np.array([[751.0, 479.0]]))))
    reason = _pixels_without_rays(camera, reference, 752, 480)
    assert reason is not None and 'no ray for 1 of 627 grid pixels' in reason, reason


def test_a_camera_that_ends_at_180_degrees_short_of_pixels_is_not_said_to_turn_back():
    """A lens curve that rises all the way to 180 degrees but ends there short of pixels zero-shot
    images (a focal too short for the image) does not turn back: the reason says where it ends."""
    from zeroshot_calib_ros.core.estimation.refine import _pixels_without_rays
    reference = zero_shot_camera(CameraSpec(752, 480, hfov=93.0), 752, 480)
    short = KannalaBrandtCamera(100.0, 100.0, 376.0, 240.0, 752, 480, [0.0, 0.0, 0.0, 0.0])
    assert short.theta_max == pytest.approx(np.pi)
    reason = _pixels_without_rays(short, reference, 752, 480)
    assert reason is not None and 'turns back' not in reason, reason
    assert 'ends at 180 degrees off-axis' in reason, reason


def test_the_camera_returned_is_the_one_checked_for_rays_and_over_the_circle_seen(monkeypatch):
    """The check judges the camera refine would return (after the zoom is taken from the FOVs), and
    over the image circle seen when one is (nothing outside it is imaged)."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    turned = [0.9, -2.8, 4.4, -2.3]
    monkeypatch.setattr(refine_module, 'rezoom', lambda camera, *args, **kwargs: KannalaBrandtCamera(
        camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height, turned))
    rng = np.random.default_rng(7)
    result = refine_camera(spec_of(TRUTH), views(TRUTH, rng, 10))
    assert not result.accepted and 'has no ray for' in result.reason, result.reason
    monkeypatch.undo()
    seen = []
    real = refine_module._pixels_without_rays

    def spy(camera, reference, width, height, circle=None):
        seen.append(circle)
        return real(camera, reference, width, height, circle)
    monkeypatch.setattr(refine_module, '_pixels_without_rays', spy)
    circle = ImageCircle(TRUTH.cx + 3.0, TRUTH.cy - 2.0, 0.45 * W, 0.3, 0.5)
    refine_camera(spec_of(TRUTH), views(TRUTH, np.random.default_rng(7), 10), image_circle=circle)
    assert seen == [(circle.radius, (circle.cx, circle.cy))], seen
