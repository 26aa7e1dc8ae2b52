"""The error bars and the gate's probability (core/estimation/uncertainty.py) against closed
forms and dense numpy references: a focal error's one-dimensional answer, the zoom left out,
the systematic floor's covariance, the clustered covariance's floors, the ill-conditioned
warning's scale."""
import math

import numpy as np
import pytest

from zeroshot_calib_ros.core.estimation.parameters import KannalaBrandtLayout
from zeroshot_calib_ros.core.estimation.uncertainty import pixel_grid, probability_other_is_better
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera

CENTRED = KannalaBrandtCamera(500.0, 500.0, 640.0, 400.0, 1280, 800, [0.02, -0.01, 0.003, -0.0005])
"""A radial lens whose principal point is the grid's centre: a change of f moves every pixel
radially by df / f (p - c), which no rotation of the camera undoes (the rotation fields of a
lens symmetric about the grid's centre are orthogonal to the radial field)."""


@pytest.mark.parametrize('margin_fraction', [0.0, 0.3])
def test_gate_probability_of_a_focal_error_is_the_one_dimensional_closed_form(margin_fraction):
    """The gate's chance that zero-shot is nearer the truth (``probability_other_is_better``),
    against the exact answer of a one-dimensional case: the posterior spreads f alone (sigma s),
    the other camera is the estimate with f + D. With R = sqrt(mean |p - c|^2) / f over the grid,
    the truth with f + delta is nearer the other by more than m px RMS exactly when
    |delta - D| R < |delta| R - m, i.e. delta > (D + m / R) / 2: the probability is
    Phi(-(D + m / R) / (2 s)) (exact for m = 0; for m > 0 the gate's |e| ~ its RMS
    linearisation is within 0.01 here, where D = 2 s). The distance and spread returned are D R
    and s R."""
    layout = KannalaBrandtLayout(CENTRED, 0)
    x = layout.x_from(CENTRED)
    s, D = 1.5, 3.0
    cov = np.diag([s * s, 0.0, 0.0])
    other = KannalaBrandtCamera(CENTRED.fx + D, CENTRED.fy + D, CENTRED.cx, CENTRED.cy, 1280, 800, CENTRED.D)
    px = pixel_grid(1280, 800)
    R = math.sqrt(np.mean(np.sum((px - [640.0, 400.0]) ** 2, axis=1))) / CENTRED.fx
    m = margin_fraction * s * R
    p, rms_d, u = probability_other_is_better(layout, x, cov, other, m)
    assert rms_d == pytest.approx(D * R, rel=1e-4)
    assert u == pytest.approx(s * R, rel=1e-4)
    expected = 0.5 * math.erfc((D + m / R) / (2 * s) / math.sqrt(2.0))  # Phi(-(D + m / R) / (2 s))
    assert p == pytest.approx(expected, abs=0.01 if m else 1e-4)


def test_gate_after_zoom_ignores_a_camera_that_differs_by_a_zoom_alone():
    """``after_zoom``: both cameras are fitted to the same FOVs, so a difference along the zoom
    (r -> (s x, s y, z), which lines cannot see) is not a reason to prefer either: a camera that
    IS the estimate zoomed by 0.5 % is at (nearly) zero distance off the zoom, and at its full
    distance without ``after_zoom``."""
    layout = KannalaBrandtLayout(CENTRED, 0)
    x = layout.x_from(CENTRED)
    cov = np.diag([1.0, 4.0, 4.0])
    s = 1.005

    class Zoomed:
        """The estimate looking through the zoom: project(r) = estimate.project(s x, s y, z)."""
        width, height = CENTRED.width, CENTRED.height

        def project(self, rays):
            return CENTRED.project(np.asarray(rays) * [s, s, 1.0])

    rays = CENTRED.unproject(pixel_grid(1280, 800))
    full = math.sqrt(np.mean(np.sum((Zoomed().project(rays) - CENTRED.project(rays)) ** 2, axis=1)))
    assert full > 0.5
    _, without, _ = probability_other_is_better(layout, x, cov, Zoomed(), 0.0, after_zoom=False)
    assert without == pytest.approx(full, rel=0.05)  # a zoom is not a rotation either
    _, off_zoom, _ = probability_other_is_better(layout, x, cov, Zoomed(), 0.0, after_zoom=True)
    assert off_zoom < 0.01 * full


def _line_problem(noise, sigma=0.3, seed=3):
    """A problem of 12 straight lines seen through test_refine's TRUTH (``noise`` px), the spec's
    FOVs and the principal-point prior, at the true camera; its whitened Jacobian there, and the
    curve of each straightness residual (its x and y), from the curves' sizes."""
    from test_refine import TRUTH, line_curves, spec_of
    from zeroshot_calib_ros.core.estimation.problem import Problem
    from zeroshot_calib_ros.core.estimation.terms import FovTerm, PrincipalPointPrior
    from zeroshot_calib_ros.core.lines.straightness import StraightnessTerm
    curves = line_curves(TRUTH, np.random.default_rng(seed), 12, noise=noise)
    layout = KannalaBrandtLayout(TRUTH, 2)
    term = StraightnessTerm(curves, sigma=sigma, loss=None)
    problem = Problem(layout, [term, FovTerm.from_spec(spec_of(TRUTH)), PrincipalPointPrior(TRUTH.width, TRUTH.height)])
    x = layout.x_from(TRUTH)
    cluster = np.repeat(np.arange(len(curves)), [2 * len(c) for c in curves])
    return problem, x, problem.jacobian(x), term, cluster


def test_systematic_floor_is_the_covariance_of_noise_sigma2_plus_floor2_bow_and_s():
    """``systematic_covariance``: with every curve allowed a systematic error of ``floor`` px RMS
    in each of its modes, a curve's residual noise is sigma^2 I + floor^2 B_c B_c^T; the
    covariance must be the generalised-least-squares one, (J_c^T Sigma_c^-1 J_c summed + the
    priors' J^T J)^-1 in whitened units (Sigma_c = I + (floor / sigma)^2 B_c B_c^T), computed
    here with the dense matrix inverted by numpy (no Woodbury identity)."""
    from zeroshot_calib_ros.core.estimation.uncertainty import systematic_covariance
    problem, x, J, term, cluster = _line_problem(noise=0.3)
    floor = 0.12
    cov, reason = systematic_covariance(problem, x, J, floor)
    n = len(cluster)
    B = term.systematic_modes()
    e2 = (floor / term.sigma) ** 2
    Sigma = np.eye(n)
    for c in range(cluster.max() + 1):
        rows = np.flatnonzero(cluster == c)
        Sigma[np.ix_(rows, rows)] += e2 * B[rows] @ B[rows].T
    Js, Jp = J[:n], J[n:]
    expected = np.linalg.inv(Js.T @ np.linalg.solve(Sigma, Js) + Jp.T @ Jp)
    sd = np.sqrt(np.diag(expected))
    np.testing.assert_allclose(cov / np.outer(sd, sd), expected / np.outer(sd, sd), rtol=0, atol=1e-6)
    assert 'bow and S of 0.12 px' in reason


@pytest.mark.parametrize('noise', [0.0, 0.6])
def test_clustered_covariance_is_never_narrower_than_laplace_nor_than_the_sandwich(noise):
    """``clustered_covariance``: lines whose noise is below the stated sigma (exact lines, sigma
    0.3) make the cluster-robust sandwich narrower than the Laplace covariance: it must then be the
    Laplace covariance (no direction more certain than Laplace says); with noise twice sigma it
    must be at least the sandwich H^-1 (sum_c g_c g_c^T + priors' J^T J) H^-1, computed here with
    numpy from the whitened residuals and the curves (never narrower than Laplace either)."""
    from zeroshot_calib_ros.core.estimation.uncertainty import clustered_covariance
    problem, x, J, term, cluster = _line_problem(noise=noise)
    cov, _ = clustered_covariance(problem, x, J)
    H_inv = np.linalg.inv(J.T @ J)
    n = len(cluster)
    r = problem.whitened(x)[:n]
    g = np.array([J[:n][cluster == c].T @ r[cluster == c] for c in range(cluster.max() + 1)])
    sandwich = H_inv @ (g.T @ g + J[n:].T @ J[n:]) @ H_inv
    sd = np.sqrt(np.diag(H_inv))
    unit = np.outer(sd, sd)
    for narrower in (H_inv, sandwich):
        assert np.linalg.eigvalsh((cov - narrower) / unit).min() > -1e-7
    if noise == 0.0:
        np.testing.assert_allclose(cov / unit, H_inv / unit, rtol=0, atol=1e-6)
    else:
        assert np.trace(cov / unit) > 1.5 * np.trace(H_inv / unit)


def test_ill_conditioned_warning_is_against_the_width_not_the_height():
    """The ill-conditioned warning is raised when the part of the zero-shot error bar from the
    FOV tolerance and the priors exceeds ``ILL_CONDITIONED_FRACTION`` (1.5 %) of the image WIDTH.
    A narrow 16:9 lens (1920 x 1080, hfov 18, vfov 10.2, dfov 20.6: about 1.3 % of the width,
    i.e. between 1.5 % of the height and 1.5 % of the width) is not warned about; without dfov
    (about 1.75 %, above 1.5 % of the width) it is."""
    from zeroshot_calib_ros.core.estimation.uncertainty import ILL_CONDITIONED_FRACTION, zero_shot_uncertainty
    from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec
    W, H = 1920, 1080
    between = zero_shot_uncertainty(CameraSpec(W, H, hfov=18, vfov=10.2, dfov=20.6))
    assert ILL_CONDITIONED_FRACTION * H < between.fov_part_px < ILL_CONDITIONED_FRACTION * W  # the case's premise
    assert between.warning is None
    above = zero_shot_uncertainty(CameraSpec(W, H, hfov=18, vfov=10.2))
    assert above.fov_part_px > ILL_CONDITIONED_FRACTION * W
    assert above.warning and 'ill-conditioned' in above.warning
