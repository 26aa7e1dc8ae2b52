"""The refined camera's zoom (core/estimation/zoom.py): what straight lines cannot see, taken from
the FOV statements as far as the camera's shape is known at each one's edge.

Evidence is synthetic (``test_refine``'s random straight segments, 0.3 px noise) seen through an
image circle, the line benchmark's nuisance: lines only inside it, FOVs stated beyond it. The
reference is the known camera, over the pixels inside the circle.
"""
import math

import numpy as np

from test_refine import Curve, best_rotation_rms, line_curves
from zeroshot_calib_ros.core.estimation.refine import refine_camera
from zeroshot_calib_ros.core.estimation.terms import FovTerm
from zeroshot_calib_ros.core.estimation.uncertainty import pixel_grid
from zeroshot_calib_ros.core.estimation.zoom import _statements, rezoom, statement_shape_covariance, zoomed_camera
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis
from zeroshot_calib_ros.core.lines.image_region import ImageCircle
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

ACTION_CAMERA = KannalaBrandtCamera(454.1, 454.1, 478.3, 275.3, 960, 540, [0.01375, -0.02275, 0.01938, -0.00621])
"""A 121 x 68-degree action camera of the line benchmark (16:9, 960 x 540)."""


def _behind_an_image_circle(truth, radius, seed, per_view=25):
    """(spec, curves, circle, pixels inside it): the lens seen through an image circle of
    ``radius`` px about its principal point (the line benchmark's nuisance), lines only inside it,
    and a spec that states hfov / vfov / dfov (beyond the circle) and the FOV across the circle."""
    circle = ImageCircle(truth.cx, truth.cy, radius, 0.2, 0.2, 360.0, 2000, 4)
    fovs = fields_of_view_through_axis(truth)
    ray = truth.unproject(np.array([[truth.cx + radius, truth.cy]]))[0]
    circle_fov = 2 * math.degrees(math.atan2(math.hypot(ray[0], ray[1]), ray[2]))
    spec = CameraSpec(truth.width, truth.height, hfov=fovs['hfov'], vfov=fovs['vfov'], dfov=fovs['dfov'],
                      circle_diameter=2 * radius, circle_fov=circle_fov)
    rng = np.random.default_rng(seed)

    def keep(px):
        return np.hypot(px[:, 0] - circle.cx, px[:, 1] - circle.cy) < radius - 25
    curves = [Curve(c, v) for v in range(4)
              for c in line_curves(truth, rng, per_view, keep=keep, max_angle=math.radians(60))]
    grid = pixel_grid(truth.width, truth.height)
    inside = grid[np.hypot(grid[:, 0] - circle.cx, grid[:, 1] - circle.cy) <= radius]
    return spec, curves, circle, inside


def test_lines_inside_an_image_circle_take_the_zoom_from_the_fovs_they_reach():
    """Lines only inside an image circle (0.47 of the height) of the action camera: they fix the
    shape up to the zoom inside the circle; beyond it the shape is the prior's extrapolation. The
    zoom fitted to hfov and dfov out there put the refined camera 3-4x further from the truth than
    zero-shot (0.75-0.82 px against 0.22 inside the circle); weighed by the shape's own
    uncertainty at each FOV's edge, the circle's FOV and vfov (which the lines nearly reach) set it,
    and the camera is 3x nearer the truth than zero-shot."""
    for seed in (1, 2, 4):
        spec, curves, circle, inside = _behind_an_image_circle(ACTION_CAMERA, 253.8, seed)
        result = refine_camera(spec, curves, image_circle=circle)
        zero_shot = best_rotation_rms(result.zero_shot_camera, ACTION_CAMERA, pixels=inside)
        assert best_rotation_rms(result.refined_camera, ACTION_CAMERA, pixels=inside) < 0.5 * zero_shot
        assert result.accepted, result.reason


def test_a_fov_beyond_the_lines_states_the_zoom_with_the_shapes_uncertainty_there():
    """``statement_shape_covariance``: on the fit of lines inside the image circle, the circle's
    FOV (at the lines' edge) is stated through a shape known to hundredths of a degree, hfov and
    dfov (60 and 69 degrees off-axis, far past the last line) through the shape prior's
    extrapolation: degrees (4.8 and 7.1)."""
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    seen = {}
    real = refine_module.statement_shape_covariance

    def spy(problem, x, jacobian, floor_px, statements, *args):
        seen['statements'] = statements
        seen['C'] = real(problem, x, jacobian, floor_px, statements, *args)
        return seen['C']
    spec, curves, circle, _ = _behind_an_image_circle(ACTION_CAMERA, 253.8, 1)
    refine_module.statement_shape_covariance = spy
    try:
        refine_camera(spec, curves, image_circle=circle)
    finally:
        refine_module.statement_shape_covariance = real
    fov, circle_term = seen['statements']
    assert fov.keys == ('hfov', 'vfov', 'dfov') and circle_term.circle_fov is not None
    sigma = np.sqrt(np.diag(seen['C']))   # hfov, vfov, dfov, circle cx, cy, circle FOV
    # the lines and priors alone: the FOVs' own statements would pin the shape at their edges to
    # about their tolerance (1 degree) and hide how little the lines know there
    assert sigma[5] < 0.1 and sigma[2] > 3.0 and sigma[0] > 2.0


def _zoom_motion(camera, terms, step=1e-4):
    """d statements / d zoom at ``camera`` (``zoom._statements``' order)."""
    up, _ = zoomed_camera(camera, 1.0 + step)
    down, _ = zoomed_camera(camera, 1.0 - step)
    return (_statements(terms, up)[0] - _statements(terms, down)[0]) / (2 * step)


def test_rezoom_is_the_least_squares_zoom_in_the_statements_covariance():
    """``rezoom`` with FOVs 0.3-0.6 degrees off the camera's, a tolerance of 0.5 degree and a
    correlated shape covariance: the zoom it returns solves the weighted least squares normal
    equation z' W r = 0, W = (diag(tolerance^2) + C)^-1 (z: the statements' motion under the zoom),
    which neither the tolerance unsquared nor C's diagonal alone satisfy."""
    fovs = fields_of_view_through_axis(ACTION_CAMERA)
    term = FovTerm({'hfov': fovs['hfov'] + 0.4, 'vfov': fovs['vfov'] - 0.3, 'dfov': fovs['dfov'] + 0.6},
                   ACTION_CAMERA.width, ACTION_CAMERA.height, tolerance_deg=0.5)
    L = np.array([[0.8, 0.0, 0.0], [0.5, 0.3, 0.0], [-0.4, 0.6, 1.5]])
    shape = L @ L.T
    weight = np.linalg.inv(np.diag(np.full(3, 0.25)) + shape)
    out = rezoom(ACTION_CAMERA, term, shape_covariance=shape)
    assert out is not ACTION_CAMERA
    before = _zoom_motion(ACTION_CAMERA, [term]) @ weight @ _statements([term], ACTION_CAMERA)[0]
    after = _zoom_motion(out, [term]) @ weight @ _statements([term], out)[0]
    assert abs(after) < 1e-3 * abs(before)
    for wrong in (np.linalg.inv(np.diag(np.full(3, 0.5)) + shape), np.diag(1.0 / (0.25 + np.diag(shape)))):
        other = _zoom_motion(ACTION_CAMERA, [term]) @ wrong @ _statements([term], ACTION_CAMERA)[0]
        assert abs(_zoom_motion(out, [term]) @ wrong @ _statements([term], out)[0]) > 1e-2 * abs(other)


def test_the_shapes_covariance_at_the_fovs_does_not_hear_the_fovs_themselves(monkeypatch):
    """``statement_shape_covariance`` is the lines' and priors' alone: stating the circle's FOV
    five times more loosely (its tolerance is what whitens it in the fit) changes nothing of it,
    the circle's measured centre stays in it."""
    import copy
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    from zeroshot_calib_ros.core.estimation.problem import Problem
    from zeroshot_calib_ros.core.estimation.terms import ImageCircleTerm
    seen = {}
    real = refine_module.statement_shape_covariance

    def spy(*args):
        seen['args'] = args
        return real(*args)
    monkeypatch.setattr(refine_module, 'statement_shape_covariance', spy)
    spec, curves, circle, _ = _behind_an_image_circle(ACTION_CAMERA, 253.8, 1)
    refine_camera(spec, curves, image_circle=circle)
    problem, x, jacobian, floor, statements, *rest = seen['args']
    C = statement_shape_covariance(problem, x, jacobian, floor, statements, *rest)
    terms = []
    for t in problem.terms:
        if isinstance(t, ImageCircleTerm):
            t = copy.copy(t)
            t.sigma = np.asarray(t.sigma, dtype=float) * np.array([1.0, 1.0, 5.0])
        terms.append(t)
    loose = Problem(problem.layout, terms)
    C_loose = statement_shape_covariance(loose, x, loose.jacobian(x), floor, statements, *rest)
    assert np.allclose(C_loose, C, rtol=1e-6, atol=1e-12)
    # and the circle's centre is evidence in it: without the circle term at all, the centre is looser
    without = Problem(problem.layout, [t for t in problem.terms if not isinstance(t, ImageCircleTerm)])
    C_without = statement_shape_covariance(without, x, without.jacobian(x), floor, statements, *rest)
    assert C_without[3, 3] > 1.2 * C[3, 3]
