"""The straightness term's edge cases (core/lines/straightness.py): points a camera gives no ray
cost a large finite residual and make a curve infinitely far from straight, and the noise
estimate counts one degree of freedom a point less two a curve, checked against closed forms
and known synthetic truth."""
import math

import numpy as np
import pytest

from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera, PinholeCamera
from zeroshot_calib_ros.core.lines.straightness import INVALID_PX, StraightnessTerm


LENS_TURNING_BACK = KannalaBrandtCamera(300.0, 300.0, 500.0, 500.0, 1000, 1000, [-0.3, 0.0, 0.0, 0.0])
"""k1 = -0.3: theta_d peaks at theta = 1.05 rad, so no pixel beyond ~211 px from the principal
point has a ray."""


def _crossing_and_inside():
    """A curve that leaves the lens's domain (some points without a ray) and a vertical line
    through the principal point (a line's image through a radial lens: residual ~0)."""
    x = np.linspace(380.0, 760.0, 20)
    crossing = np.stack([x, 520.0 + 0.1 * (x - 380.0)], axis=1)
    inside = np.stack([np.full(10, 500.0), np.linspace(350.0, 650.0, 10)], axis=1)
    return [crossing, inside]


@pytest.mark.parametrize('invalid_px', [None, 7.5])
def test_points_without_a_ray_cost_invalid_px_per_coordinate(invalid_px):
    """A lens whose polynomial turns back (k1 = -0.3: no ray beyond ~211 px from the principal
    point): the points of a curve out there have no ray, and the residuals a solver sees for them
    are ``invalid_px`` per coordinate (default ``INVALID_PX``), a large finite cost, not zero
    (zero would reward a camera for losing the rays of the points it cannot straighten); the
    points with a ray keep finite residuals (a line through the principal point, its own ~0),
    and the RMS is infinite."""
    camera = LENS_TURNING_BACK
    curves = _crossing_and_inside()
    crossing = curves[0]
    no_ray = ~np.all(np.isfinite(camera.unproject(np.concatenate(curves))), axis=1)
    assert 3 <= no_ray.sum() < len(crossing) - 3  # the case's premise: some points, not all, of one curve
    term = StraightnessTerm(curves) if invalid_px is None else StraightnessTerm(curves, invalid_px=invalid_px)
    expected = INVALID_PX if invalid_px is None else invalid_px
    r = term.residuals(camera).reshape(-1, 2)
    assert np.all(r[no_ray] == expected)
    assert np.all(np.isfinite(r[~no_ray]))
    # a line through the principal point images straight through it: its own residuals stay ~0
    assert np.all(np.abs(r[len(crossing):]) < 1e-6)
    assert term.rms(camera) == math.inf


def test_a_curve_with_a_point_without_a_ray_has_an_infinite_rms():
    """``curve_rms``: a curve one of whose points has no ray under the camera is infinitely far
    from straight (the line fit's robust rounds then reject it as an outlier), not the RMS of its
    other points; a curve whose points all have rays keeps its own RMS (~0 for a line through
    the principal point)."""
    term = StraightnessTerm(_crossing_and_inside())
    rms = term.curve_rms(LENS_TURNING_BACK)
    assert rms[0] == math.inf
    assert rms[1] < 1e-6


def test_noise_estimate_of_short_lines_is_unbiased():
    """The noise sigma of the line points (``fit.estimate_sigma``, from ``noise_dof``: one degree
    of freedom a point, less two a curve for its plane), for 400 short lines of 5 points under a
    pinhole with 0.3 px Gaussian noise per coordinate, at the true camera: 0.3 px within 5 %
    (a count of one dof a curve would say 0.26 px: the error bars and the robust rejection then
    trust the lines 13 % too much)."""
    from zeroshot_calib_ros.core.estimation.fit import estimate_sigma
    camera = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    rng = np.random.default_rng(21)
    curves = []
    for _ in range(400):
        start = rng.uniform([80.0, 80.0], [560.0, 400.0])
        angle = rng.uniform(0.0, math.pi)
        t = np.arange(5)[:, None] * 20.0
        curves.append(start + t * [math.cos(angle), math.sin(angle)] + rng.normal(0.0, 0.3, (5, 2)))
    term = StraightnessTerm(curves)
    assert estimate_sigma(term, camera, 0, floor=0.0) == pytest.approx(0.3, rel=0.05)
