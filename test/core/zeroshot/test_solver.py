"""The zero-shot solver against the paper's Table 2 and its degenerate cases."""
import math

import numpy as np
import pytest

from paper_table2 import load_table2
from zeroshot_calib_ros.core import CameraSpec, NoConvergence, SpecError, ZeroShotCamera, solve_zero_shot
from zeroshot_calib_ros.core.lens.projections import PROJECTIONS

TABLE2 = load_table2()
ROOT_ROWS = [r for r in TABLE2 if r['omega']]

# Printed values that contradict the paper's own equations; the solver is not bent to them.
# C922: Table 2 prints w* = 0, but its spec (hfov 70.42, vfov 43.3 at 1280x720) has a barrel root
#   w* = 1.59e-5; its f* = 907.0 matches ours (906.95). Eq. 7 prints vfov 43.4 but its value
#   906.9431 is what 43.3 gives (43.4 gives 904.6).
# M2025-LE / M2026-LE: the printed f* (648.8 / 568.8) is not what eq. 24 gives for the printed
#   w* (648.3 / 565.6); our f* agrees with eq. 24 at the printed w*.
W_PRINTED_AS_ZERO = {'C922'}
F_INCONSISTENT_WITH_EQ24 = {'M2025-LE', 'M2026-LE'}


def _tan_half(deg):
    return math.tan(math.radians(deg) / 2)


def _spec(row):
    return CameraSpec(int(row['width']), int(row['height']), row['hfov'], row['vfov'])


@pytest.mark.parametrize('row', TABLE2, ids=[r['camera'] for r in TABLE2])
def test_perspective_focals_match_table2(row):
    assert row['width'] / 2 / _tan_half(row['hfov']) == pytest.approx(row['fx_tilde'], abs=0.051)
    if row['vfov']:
        assert row['height'] / 2 / _tan_half(row['vfov']) == pytest.approx(row['fy_tilde'], abs=0.051)


@pytest.mark.parametrize('row', TABLE2, ids=[r['camera'] for r in TABLE2])
def test_zero_shot_matches_table2(row):
    # lens_prior=False: the paper's reading of one FOV (C905), a pinhole; two FOVs never use the prior
    solution = solve_zero_shot(_spec(row), lens_prior=False)
    if row['camera'] in W_PRINTED_AS_ZERO:
        assert 0 < solution.omega < 2e-5
    else:
        assert round(solution.omega, 6) == pytest.approx(row['omega'], abs=1e-12)
    if row['camera'] in F_INCONSISTENT_WITH_EQ24:
        W = row['width']
        w = row['omega']
        f_eq24 = math.tan(w * W / 2) / (w * _tan_half(row['hfov']))
        assert abs(row['f_star'] - f_eq24) > 0.3, 'the printed f* would then be consistent'
        assert solution.f == pytest.approx(f_eq24, abs=0.2)
    else:
        assert solution.f == pytest.approx(row['f_star'], abs=0.1)
    assert solution.camera.cx == row['width'] / 2 and solution.camera.cy == row['height'] / 2


@pytest.mark.parametrize('row', ROOT_ROWS, ids=[r['camera'] for r in ROOT_ROWS])
def test_root_is_exact_to_machine_precision(row):
    """At w* both FOVs give the same undistorted focal length (eqs. 24-25) to ~1 ulp."""
    solution = solve_zero_shot(_spec(row))
    fx, fy = solution.focal_estimates['hfov'], solution.focal_estimates['vfov']
    assert abs(fx - fy) <= 1e-12 * fx
    omega = solution.omega
    proj = PROJECTIONS['equidistant']
    W, H = row['width'], row['height']
    j = _tan_half(row['vfov']) / _tan_half(row['hfov']) - math.tan(omega * H / 2) / math.tan(omega * W / 2)
    step = np.spacing(omega)
    j_next = _tan_half(row['vfov']) / _tan_half(row['hfov']) - \
        proj.undistort_radius(H / 2, omega + 4 * step) / proj.undistort_radius(W / 2, omega + 4 * step)
    assert abs(j) <= abs(j_next - j) + 1e-15


@pytest.mark.parametrize('row', ROOT_ROWS, ids=[r['camera'] for r in ROOT_ROWS])
def test_paper_newton_agrees_with_bracketed_root(row):
    exact = solve_zero_shot(_spec(row))
    newton = solve_zero_shot(_spec(row), method='newton')
    assert newton.omega == pytest.approx(exact.omega, rel=1e-10)
    assert newton.f == pytest.approx(exact.f, rel=1e-10)
    assert newton.iterations > 30  # gamma = 0.1 converges linearly: ~230 steps to 1e-12


def test_paper_newton_fails_where_its_start_is_past_the_pole():
    """w0 = 1e-4 assumes images narrower than pi / 1e-4 = 31416 px: wider, w0 * W/2 > pi/2 and the
    start is already beyond G_w^-1's pole, so the iteration has no valid start, while the
    bracketed solver still finds the root (a 40000 px wide gigapixel camera)."""
    spec = CameraSpec(40000, 30000, 100, 80)
    exact = solve_zero_shot(spec)
    assert exact.root_found and exact.omega * 40000 / 2 < math.pi / 2 < 1e-4 * 40000 / 2
    with pytest.raises(NoConvergence, match='Newton left the valid range'):
        solve_zero_shot(spec, method='newton')


def test_no_barrel_root_gives_zero_omega_and_mean_focal():
    """Hero9(L): tan(vfov/2)/tan(hfov/2) >= H/W, pincushion-like: w* = 0, f = mean perspective focal."""
    spec = CameraSpec(1920, 1080, 92, 61)
    assert _tan_half(61) / _tan_half(92) >= 1080 / 1920
    solution = solve_zero_shot(spec)
    fx, fy = 960 / _tan_half(92), 540 / _tan_half(61)
    assert solution.omega == 0 and not solution.root_found
    assert solution.f == pytest.approx((fx + fy) / 2, rel=1e-14)
    assert solution.f == pytest.approx(921.9, abs=0.05)


def test_exactly_undistorted_spec_gives_pinhole():
    f = 1000.0
    spec = CameraSpec(1280, 720, math.degrees(2 * math.atan(640 / f)), math.degrees(2 * math.atan(360 / f)))
    solution = solve_zero_shot(spec)
    assert solution.omega == pytest.approx(0, abs=1e-12)
    assert solution.f == pytest.approx(f, rel=1e-9)


def test_hfov_alone_is_perspective():
    """The paper's reading of one FOV (its C905 row), kept as lens_prior=False; by default the
    lens shape comes from real lenses of that FOV (test/core/zeroshot/test_lens_prior.py)."""
    solution = solve_zero_shot(CameraSpec(1280, 720, hfov=63.1), lens_prior=False)
    assert solution.omega == 0 and solution.f == pytest.approx(1042.3, abs=0.05)


@pytest.mark.parametrize('row', TABLE2[2:], ids=[r['camera'] for r in TABLE2[2:]])
def test_portrait_equals_transposed_landscape(row):
    landscape = solve_zero_shot(_spec(row))
    portrait = solve_zero_shot(CameraSpec(int(row['height']), int(row['width']), row['vfov'], row['hfov']))
    assert portrait.omega == landscape.omega and portrait.f == landscape.f
    assert (portrait.camera.cx, portrait.camera.cy) == (row['height'] / 2, row['width'] / 2)


def test_square_sensor_with_equal_fovs_needs_dfov():
    with pytest.raises(SpecError, match='give dfov') as err:
        solve_zero_shot(CameraSpec(1000, 1000, 120, 120))
    assert err.value.field == 'dfov'
    # With the diagonal it is determined: hfov + dfov.
    truth = ZeroShotCamera(500.0, 500, 500, 1000, 1000, omega=1 / 600)
    fov = truth.fields_of_view()
    solution = solve_zero_shot(CameraSpec(1000, 1000, fov['hfov'], fov['vfov'], fov['dfov']),
                               projection='equidistant')
    assert solution.omega == pytest.approx(1 / 600, rel=1e-9)


@pytest.mark.parametrize('fov_field', ['hfov', 'vfov'])
def test_fov_at_or_beyond_180_is_refused_with_the_limit(fov_field):
    kwargs = {'hfov': 100, 'vfov': 60, fov_field: 180}
    if fov_field == 'vfov':
        kwargs['hfov'] = 185
        kwargs['vfov'] = 100
        fov_field = 'hfov'
    with pytest.raises(SpecError, match='less than 180 degrees') as err:
        solve_zero_shot(CameraSpec(1920, 1080, **kwargs), projection='equidistant')
    assert err.value.field == fov_field


def test_corners_beyond_90_degrees_are_refused():
    with pytest.raises(SpecError, match='90 degrees or more off-axis'):
        solve_zero_shot(CameraSpec(1920, 1080, 175, 120), projection='equidistant')


@pytest.mark.parametrize('name', list(PROJECTIONS))
@pytest.mark.parametrize('pair', [('hfov', 'vfov'), ('hfov', 'dfov'), ('vfov', 'dfov')])
def test_any_pair_of_fovs_recovers_a_known_camera(name, pair):
    truth = ZeroShotCamera(700.0, 640, 360, 1280, 720, omega=0.0011, projection=PROJECTIONS[name])
    fov = truth.fields_of_view()
    spec = CameraSpec(1280, 720, **{k: fov[k] for k in pair})
    solution = solve_zero_shot(spec, projection=name)
    assert solution.omega == pytest.approx(0.0011, rel=1e-9)
    assert solution.f == pytest.approx(700.0, rel=1e-9)


@pytest.mark.parametrize('name', list(PROJECTIONS))
def test_dfov_selects_the_true_projection(name):
    truth = ZeroShotCamera(700.0, 640, 360, 1280, 720, omega=0.0012, projection=PROJECTIONS[name])
    fov = truth.fields_of_view()
    solution = solve_zero_shot(CameraSpec(1280, 720, fov['hfov'], fov['vfov'], fov['dfov']))
    assert solution.projection.name == name
    assert set(solution.dfov_residuals) == set(PROJECTIONS)
    assert abs(solution.dfov_residuals[name]) < 1e-9
    assert all(abs(r) > 1e-3 for n, r in solution.dfov_residuals.items() if n != name)
    forced = solve_zero_shot(CameraSpec(1280, 720, fov['hfov'], fov['vfov'], fov['dfov']),
                             projection='equisolid')
    assert forced.projection.name == 'equisolid'
    assert forced.dfov_residuals == solution.dfov_residuals


@pytest.mark.parametrize('kwargs, field, allowed', [
    (dict(width=0, height=720, hfov=90), 'width', 'from 1 to'),
    (dict(width=1280.5, height=720, hfov=90), 'width', 'from 1 to'),
    (dict(width=1280, height=-1, hfov=90), 'height', 'from 1 to'),
    (dict(width=1280, height='720', hfov=90), 'height', 'from 1 to'),
    (dict(width=1280, height=720, hfov=float('nan')), 'hfov', 'at least 0.01'),
    (dict(width=1280, height=720, hfov=0.0), 'hfov', 'at least 0.01'),
    # a FOV no lens has: its focal (1e320 px) overflowed into a calibration error about K
    (dict(width=1, height=5, hfov=1e-320), 'hfov', 'at least 0.01'),
    (dict(width=1280, height=720, hfov=90, dfov=0.009), 'dfov', 'at least 0.01'),
    (dict(width=1280, height=720, hfov=90, vfov=float('inf')), 'vfov', 'less than 360'),
    (dict(width=1280, height=720), 'hfov', 'at least one'),
    (dict(width=1280, height=720, circle_fov=185.0), 'circle_diameter', 'a value beside circle_fov'),
    (dict(width=1280, height=720, hfov=90, vfov=60, dfov=80), 'dfov', 'greater than hfov'),
    (dict(width=1000, height=1000, hfov=90, vfov=80), 'vfov', 'equal to hfov'),
])
def test_invalid_spec_names_field_value_and_range(kwargs, field, allowed):
    with pytest.raises(SpecError) as err:
        CameraSpec(**kwargs)
    assert err.value.field == field
    # a value given is quoted; half of the circle pair is said to be missing (not "= None")
    assert str(err.value).startswith(f'{field} is not given: ' if field.startswith('circle') else f'{field} = ')
    assert allowed in str(err.value)


def test_the_smallest_fov_the_message_allows_is_accepted():
    """"at least 0.01": 0.01 degrees itself is a spec (the boundary the refusal states)."""
    spec = CameraSpec(1280, 720, hfov=0.01)
    assert spec.hfov == 0.01


def test_unknown_projection_is_refused():
    with pytest.raises(SpecError, match='projection = .fisheye.* allowed: auto, equidistant'):
        solve_zero_shot(CameraSpec(1280, 720, 90, 60), projection='fisheye')


# The cases of test_reliability.py::test_inconsistent_fov_triples_are_rejected_or_valid, each with
# its expected outcome (that test returns from its except branch before looking at must_reject),
# on the calls the node makes for them (node.solve_from_settings: solve_zero_shot, then
# CameraCalibration.from_solution with the node's defaults; rectify true builds the maps from P).
@pytest.mark.parametrize('fovs', [dict(hfov=118.0, vfov=69.0, dfov=100.0), dict(hfov=118.0, vfov=69.0, dfov=69.0),
                                  dict(hfov=118.0, dfov=118.0)], ids=['d-narrower', 'd-equals-v', 'd-equals-h'])
def test_a_diagonal_not_wider_than_hfov_is_rejected_naming_dfov(fovs):
    with pytest.raises(SpecError) as err:
        solve_zero_shot(CameraSpec(1920, 1080, **fovs))
    assert err.value.field == 'dfov'
    assert str(err.value) == (f"dfov = {fovs['dfov']} is invalid: the diagonal field of view must be the widest; "
                              'allowed: greater than hfov = 118 degrees')


def _node_calibration(solution):
    from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
    from zeroshot_calib_ros.core.streaming.image_frames import ActiveCalibration
    calibration, fit = CameraCalibration.from_solution(solution)
    ActiveCalibration(calibration, solution.camera, 'spec', rectify=True)  # maps built from P
    for value in (*calibration.K.ravel(), *calibration.D, *calibration.P.ravel()):
        assert math.isfinite(value)
    return calibration, fit


def test_a_pincushion_like_pair_is_accepted_as_the_mean_perspective_focal_and_warned_about():
    """hfov 90 / vfov 80 on 1920 x 1080 is pincushion-like: no barrel root, w = 0 and the mean
    of the two perspective focals (as the paper's Hero9(L) row); that camera misses both FOVs by
    more than the tolerance, which ``warnings`` says. (vfov wider than hfov on 16:9 is refused:
    the FOVs look swapped, test_spec_consistency.py.)"""
    solution = solve_zero_shot(CameraSpec(1920, 1080, 90.0, 80.0))
    assert solution.omega == 0 and not solution.root_found
    assert solution.f == pytest.approx((960 / _tan_half(90) + 540 / _tan_half(80)) / 2, rel=1e-14)
    calibration, fit = _node_calibration(solution)
    assert calibration.K[0, 0] == solution.f and fit.max_error_px < 0.05
    assert len(solution.warnings) == 1 and 'vfov: given 80 deg, the solved camera has' in solution.warnings[0]


def test_vfov_and_dfov_alone_with_no_root_are_accepted_as_the_mean_perspective_focal():
    """vfov 150 / dfov 151 on 1920 x 1080: no barrel root either; f is the mean of the vfov and
    dfov perspective focals (H/2 / tan(vfov/2), (diagonal/2) / tan(dfov/2))."""
    solution = solve_zero_shot(CameraSpec(1920, 1080, vfov=150.0, dfov=151.0))
    assert solution.omega == 0 and not solution.root_found
    f_v, f_d = 540 / _tan_half(150), math.hypot(960, 540) / _tan_half(151)
    assert solution.f == pytest.approx((f_v + f_d) / 2, rel=1e-12)
    _node_calibration(solution)


def test_a_wildly_wide_and_flat_triple_is_accepted_and_reproduces_hfov_and_vfov():
    """hfov 170 / vfov 20 / dfov 171: the corners are beyond 90 degrees, so auto takes the wide
    model; of the three laws the dfov picks stereographic (the diagonal cannot be met: the
    residuals say by how much), and the camera reproduces hfov and vfov exactly."""
    solution = solve_zero_shot(CameraSpec(1920, 1080, 170.0, 20.0, 171.0))
    assert solution.root_found and solution.projection.name == 'wide-stereographic'
    residuals = solution.dfov_residuals
    assert set(residuals) == {'wide-equidistant', 'wide-equisolid', 'wide-stereographic'}
    assert min(residuals, key=lambda k: abs(residuals[k])) == 'wide-stereographic'
    fovs = solution.camera.fields_of_view()
    assert fovs['hfov'] == pytest.approx(170.0, abs=1e-9) and fovs['vfov'] == pytest.approx(20.0, abs=1e-9)
    _node_calibration(solution)
