"""A spec sheet with one FOV: the lens shape of real lenses of that FOV (core/zeroshot/lens_prior.py),
never a pinhole for a fisheye, continuous through 180 degrees, with an error bar that carries the
spread of lens shapes the spec leaves open, and says what it assumed.

The real-data tests use ../shared/data/lens_profiles_dev.csv (ZEROSHOT_SHARED_DATA may name
another copy of ../shared/data) and skip, saying so, when it is missing: the shipped table is the
build script's output, and on the held-out split (camera models the table was not built from)
the medians meet their targets and the error bars are honest for every kind of input."""
import importlib.util
import json
import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_run import run_main
from zeroshot_calib_ros.core.estimation.uncertainty import problem_uncertainty, zero_shot_problem, \
    zero_shot_uncertainty
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis
from zeroshot_calib_ros.core.zeroshot.lens_prior import LensPriorError, packaged_lens_prior, parse_lens_prior
from zeroshot_calib_ros.core.zeroshot.solver import solve_zero_shot
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

REPO = Path(__file__).resolve().parents[3]
DATA = Path(os.environ.get('ZEROSHOT_SHARED_DATA', REPO.parent / 'shared' / 'data'))
PROFILES = DATA / 'lens_profiles_dev.csv'
needs_data = pytest.mark.skipif(not PROFILES.is_file(),
                                reason=f'the shared real data set is missing: {PROFILES} (set ZEROSHOT_SHARED_DATA)')
TABLE = REPO / 'zeroshot_calib_ros' / 'data' / 'lens_prior.csv'

T265 = (848, 800)
"""Intel RealSense T265: 848 x 800, "163 +- 5 degrees"; its calibration has f of about 285 px."""


def pinhole_focal(spec, name):
    return spec.half_extents()[name] / math.tan(math.radians(spec.given()[name]) / 2)


# -- one FOV: a real lens' shape, never a pinhole for a fisheye ---------------------------------------

@pytest.mark.parametrize('size, fov', [
    (T265, {'dfov': 163.0}), ((1920, 1080), {'hfov': 118.0}), (T265, {'dfov': 179.0}),
    ((1920, 1080), {'dfov': 150.0}), ((1440, 1920), {'vfov': 122.0}),  # a portrait image's long side
])
def test_one_fov_fisheye_is_never_a_pinhole(size, fov):
    """The old answer to one FOV was a pinhole (T265 dfov 163: f = 87 px; 1920 x 1080 hfov 118:
    577 px against 876 with the vfov). Now: a fisheye's law (a = w f near 1) and an f far above
    the pinhole's, which reproduces the given FOV exactly."""
    spec = CameraSpec(*size, **fov)
    solution = solve_zero_shot(spec)
    (name, deg), = fov.items()
    assert solution.camera.a > 0.6
    assert solution.f > 1.5 * pinhole_focal(spec, name)
    assert fields_of_view_through_axis(solution.camera)[name] == pytest.approx(deg, abs=1e-6)
    assert solution.lens_shape is not None and solution.assumption.startswith(f'one FOV ({name} {deg:g} deg)')


def test_hero9_wide_hfov_alone_is_near_its_two_fov_answer():
    """1920 x 1080, hfov 118 (GoPro HERO9 wide; Table 2: f* = 876.0 from hfov + vfov, f_gt 873.6):
    577 px as a pinhole, now within 4 % of the two-FOV answer."""
    one = solve_zero_shot(CameraSpec(1920, 1080, hfov=118))
    two = solve_zero_shot(CameraSpec(1920, 1080, hfov=118, vfov=69))
    assert one.f == pytest.approx(two.f, rel=0.04)


def test_t265_diagonal_163():
    """T265 with `--dfov 163`: the pinhole gave 87 px, the real camera is about 285 px. Its 163
    degrees are the FOV of its image circle (`--circle-diameter 800 --circle-fov 163` gives 281 px),
    not of the image diagonal (its calibration puts the corners about 117 degrees off-axis); a lens
    whose diagonal sees 163 degrees is narrower, and the answer is the typical one of those: a
    fisheye between the circle reading and the pure equidistant law across the diagonal (410 px)."""
    circle = solve_zero_shot(CameraSpec(*T265, circle_diameter=800, circle_fov=163))
    assert circle.f == pytest.approx(281.2, abs=0.1)
    solution = solve_zero_shot(CameraSpec(*T265, dfov=163))
    pure_law = math.hypot(*T265) / 2 / math.radians(163 / 2)
    assert circle.f < solution.f < pure_law and solution.camera.a > 0.8
    assert 0.75 * 285 < solution.f < 1.4 * 285


@pytest.mark.parametrize('size, name', [(T265, 'dfov'), ((1920, 1080), 'hfov'), ((1920, 1080), 'dfov'),
                                        ((1920, 1080), 'vfov')])
def test_one_fov_is_continuous_through_180(size, name):
    """dfov 179 gave f = 5.1 px (a pinhole that nearly reaches 90 degrees), dfov 181 369 px (the
    wide model's pure law): a factor of 70. Now one family on both sides: the paper's camera below,
    the wide model from 180 on, the same law and a (interpolated in the table between FOV nodes):
    f moves by less than 2.5 % per half degree anywhere from 170 to 190, by less than 1 % across 180
    itself, and 179 and 181 are within 1.5 %."""
    degrees = np.arange(170.0, 190.01, 0.5)
    solutions = [solve_zero_shot(CameraSpec(*size, **{name: float(d)})) for d in degrees]
    f = np.array([s.f for s in solutions])
    steps = np.abs(np.diff(f)) / f[:-1]
    assert np.max(steps) < 0.025
    assert max(steps[np.searchsorted(degrees, 179.5)], steps[np.searchsorted(degrees, 180.0)]) < 0.01
    f179, f181 = (solutions[int(np.argmin(np.abs(degrees - d)))].f for d in (179, 181))
    assert abs(f181 - f179) / f179 < 0.015
    for d, s in zip(degrees, solutions):
        assert fields_of_view_through_axis(s.camera)[name] == pytest.approx(d, abs=1e-6)


@pytest.mark.parametrize('size, hfov', [((1280, 720), 63.1), ((1920, 1080), 40.0), ((1920, 1080), 80.0)])
def test_narrow_one_fov_stays_pinhole_like(size, hfov):
    """Narrow lenses (the paper's C905: 1280 x 720, hfov 63.1, f_gt 1062.3) keep nearly the
    pinhole's focal length: within 1.5 % of it, and never further from the truth's side."""
    spec = CameraSpec(*size, hfov=hfov)
    solution = solve_zero_shot(spec)
    assert solution.f == pytest.approx(pinhole_focal(spec, 'hfov'), rel=0.015)
    assert solution.f >= pinhole_focal(spec, 'hfov') * 0.999  # real lenses barrel, never pincushion, here


@pytest.mark.parametrize('fovs', [dict(hfov=118, vfov=69), dict(hfov=118, vfov=69, dfov=133.5),
                                  dict(hfov=118, dfov=133.5), dict(hfov=200, vfov=110),
                                  dict(circle_diameter=1000, circle_fov=200, hfov=230)])
def test_two_fovs_or_more_never_use_the_prior(fovs):
    """h + v (and any pair) determine the lens: the solution is the one without the prior, to the bit."""
    spec = CameraSpec(1920, 1080, **fovs)
    with_prior, without = solve_zero_shot(spec), solve_zero_shot(spec, lens_prior=False)
    assert (with_prior.f, with_prior.omega, with_prior.projection.name) == (without.f, without.omega,
                                                                          without.projection.name)
    assert with_prior.lens_shape is None and with_prior.assumption is None


@pytest.mark.parametrize('projection', ['equisolid', 'stereographic', 'orthographic', 'wide-equisolid',
                                        'wide-stereographic', 'wide', 'wide-equidistant'])
def test_a_forced_law_follows_the_prior_lens(projection):
    """Another law than the table's (equidistant): the a whose camera through the same FOV follows
    the table's camera closest: the same lens within 1 % of the width, the FOV exact."""
    spec = CameraSpec(1920, 1080, hfov=118)
    reference = solve_zero_shot(spec).camera
    camera = solve_zero_shot(spec, projection).camera
    assert camera.projection.name.endswith(projection.split('-')[-1]) or projection == 'wide'
    assert fields_of_view_through_axis(camera)['hfov'] == pytest.approx(118, abs=1e-6)
    u, v = np.meshgrid(np.linspace(0, 1920, 17), np.linspace(0, 1080, 9))
    rays = reference.unproject(np.stack([u.ravel(), v.ravel()], -1))
    moved = np.linalg.norm(camera.project(rays) - reference.project(rays), axis=-1)
    assert np.sqrt(np.mean(moved ** 2)) < 0.01 * 1920


def test_portrait_one_fov_is_the_transposed_landscape():
    landscape = solve_zero_shot(CameraSpec(1920, 1080, hfov=118))
    portrait = solve_zero_shot(CameraSpec(1080, 1920, vfov=118))
    assert portrait.f == pytest.approx(landscape.f, rel=1e-12) and portrait.omega == pytest.approx(landscape.omega)
    assert portrait.lens_shape.side == landscape.lens_shape.side == 'long_side'
    # a square image: hfov and vfov are the same extent, and give the same camera
    across, up = (solve_zero_shot(CameraSpec(1000, 1000, **{name: 150.0})) for name in ('hfov', 'vfov'))
    assert across.f == up.f and across.omega == up.omega


@pytest.mark.parametrize('portrait_fov, landscape_fov', [('hfov', 'vfov'), ('vfov', 'hfov'), ('dfov', 'dfov')])
def test_every_fov_of_a_portrait_image_is_that_of_the_transposed_landscape(portrait_fov, landscape_fov):
    """A portrait image's hfov spans its short side: it is the landscape image's vfov (the same
    lens turned), looked up at the same aspect ratio; its dfov is the landscape dfov."""
    for deg in (100.0, 150.0):
        portrait = solve_zero_shot(CameraSpec(1080, 1920, **{portrait_fov: deg}))
        landscape = solve_zero_shot(CameraSpec(1920, 1080, **{landscape_fov: deg}))
        assert portrait.lens_shape.side == landscape.lens_shape.side
        assert (portrait.lens_shape.a, portrait.lens_shape.a_low, portrait.lens_shape.a_high) == \
            (landscape.lens_shape.a, landscape.lens_shape.a_low, landscape.lens_shape.a_high)
        assert portrait.f == pytest.approx(landscape.f, rel=1e-12)


def test_lens_prior_false_is_the_papers_reading():
    """The paper's reading of one FOV stays available: a pinhole below 180, the pure law from 180."""
    assert solve_zero_shot(CameraSpec(1280, 720, hfov=63.1), lens_prior=False).omega == 0
    wide = solve_zero_shot(CameraSpec(*T265, dfov=181), lens_prior=False)
    assert wide.camera.a == 1.0 and wide.lens_shape is None


# -- the error bar and what was assumed ----------------------------------------------------------

def test_one_fov_error_bar_carries_the_spread_of_lens_shapes():
    """One FOV: uncertainty_px = the FOV tolerance's part (f and the principal point) and the spread
    of real lens shapes of that FOV, in quadrature; the spread dominates for a fisheye."""
    spec = CameraSpec(1920, 1080, hfov=118)
    u = zero_shot_uncertainty(spec)
    assert u.lens_shape_px is not None and u.lens_shape_px > u.fov_part_px > 0
    assert u.rms_px == pytest.approx(math.hypot(u.lens_shape_px, u.fov_part_px), rel=1e-12)
    assert 'spread of real lens shapes' in u.reason and u.warning is None


def test_two_fov_error_bar_is_unchanged():
    """h + v: the Laplace approximation under the FOVs and the priors, nothing added (README: 10.54 px)."""
    spec = CameraSpec(1920, 1080, hfov=118, vfov=69)
    u = zero_shot_uncertainty(spec)
    problem, x = zero_shot_problem(spec)
    assert u.lens_shape_px is None and u.rms_px == problem_uncertainty(problem, x).rms_px
    assert u.rms_px == pytest.approx(10.54, abs=0.005)


def test_circle_alone_has_an_error_bar_over_its_circle():
    """The circle form alone (the pure law assumed) had no error bar; now one over the image
    circle, with the spread of real lens shapes of that FOV, and the solution says what it assumed."""
    spec = CameraSpec(*T265, circle_diameter=800, circle_fov=163)
    solution = solve_zero_shot(spec)
    u = zero_shot_uncertainty(spec, solution=solution)
    assert u.rms_px is not None and u.lens_shape_px is not None and math.isfinite(u.rms_px)
    assert solution.assumption.startswith('circle only: the pure equidistant law is assumed')


def test_solve_says_what_it_assumed(capsys):
    """Text: an `assumed` line and the error bar's parts; stderr: the same as a warning; --json:
    `assumption`, the warning, and `uncertainty_lens_shape_px`."""
    status, out, err = run_main(['solve', '--width', '848', '--height', '800', '--dfov', '163'], capsys)
    assert status == 0
    assumed = next(line for line in out.splitlines() if line.startswith('assumed'))
    assert 'one FOV (dfov 163 deg): lens shape from the' in assumed and 'real lenses' in assumed
    assert 'give a second FOV or refine from images' in assumed
    assert any('spread of real lens shapes of that FOV' in line for line in out.splitlines()
               if line.startswith('error bar'))
    # what the number is: after the best rotation (a principal point error is mostly one; a user
    # comparing raw pixels of a camera whose principal point is off saw several times the bar)
    assert any('of the 1-sigma pixel error after the best rotation, FOVs +- 1 deg' in line
               for line in out.splitlines() if line.startswith('error bar'))
    assert err == ['zeroshot-calib: warning: ' + assumed.split(None, 1)[1]]
    status, out, err = run_main(['solve', '--width', '848', '--height', '800', '--dfov', '163', '--json'], capsys)
    record = json.loads(out)
    assert record['assumption'] == assumed.split(None, 1)[1] and record['warning'] == [record['assumption']]
    assert 0 < record['uncertainty_lens_shape_px'] <= record['uncertainty_px']
    status, out, err = run_main(['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69',
                                 '--json'], capsys)
    record = json.loads(out)
    assert record['assumption'] is None and record['uncertainty_lens_shape_px'] is None and err == []


def test_a_forced_wide_law_follows_the_prior_lens_across_the_short_side():
    """vfov alone (the short side; the paper's laws put a 16:9 image's corners past 90 degrees
    here, so only the wide ones): the forced law follows the table's lens over the whole image,
    out to its corners (within 1 % of the width, as across the long side)."""
    spec = CameraSpec(1920, 1080, vfov=100)
    reference = solve_zero_shot(spec).camera
    u, v = np.meshgrid(np.linspace(0, 1920, 17), np.linspace(0, 1080, 9))
    rays = reference.unproject(np.stack([u.ravel(), v.ravel()], -1))
    for projection in ('wide-equisolid', 'wide-stereographic'):
        camera = solve_zero_shot(spec, projection).camera
        assert fields_of_view_through_axis(camera)['vfov'] == pytest.approx(100, abs=1e-6)
        moved = np.linalg.norm(camera.project(rays) - reference.project(rays), axis=-1)
        assert np.sqrt(np.mean(moved ** 2)) < 0.01 * 1920, projection


def test_the_node_reads_one_fov_as_the_cli_does():
    """The node solves its spec as `solve` does: one FOV gets the lens shape of real lenses of that
    FOV (never the pinhole), and the summary it logs at start-up says what was assumed."""
    from zeroshot_calib_ros.core.ros_formats.calibration_file import summary_text
    from zeroshot_calib_ros.core.streaming.node_parameters import PARAMETERS, Settings, solve_from_settings
    values = {name: parameter.default for name, parameter in PARAMETERS.items()}
    values.update(width=848, height=800, hfov=0.0, vfov=0.0, dfov=163.0, circle_diameter=0.0, circle_fov=0.0,
                  preset='')
    settings = Settings.from_values(values)
    assert settings.spec == CameraSpec(*T265, dfov=163)
    active, summary = solve_from_settings(settings, 0, build_maps=False)
    cli = solve_zero_shot(CameraSpec(*T265, dfov=163))
    assert summary['f'] == cli.f and summary['f'] > 1.5 * pinhole_focal(settings.spec, 'dfov')
    assert summary['assumption'] == cli.assumption and cli.assumption.startswith('one FOV (dfov 163 deg)')
    assert f"assumed   {cli.assumption}" in summary_text(summary).splitlines()


# -- the table, read here on its own --------------------------------------------------------------

def _table_rows():
    """{(side, aspect or None, fov): (a, a_low, a_high, lenses)} of the shipped CSV, and its
    'Training set: N lenses' count."""
    import csv
    lines = TABLE.read_text().splitlines()
    total = next(int(line.split(':')[1].split()[0].replace(',', '')) for line in lines
                 if line.startswith('# Training set:'))
    rows = {}
    for row in csv.DictReader(line for line in lines if not line.startswith('#')):
        aspect = float(row['aspect']) if row['aspect'] else None
        rows[(row['side'], aspect, float(row['fov_deg']))] = tuple(
            float(row[k]) for k in ('a', 'a_low', 'a_high', 'lenses'))
    return rows, total


@pytest.mark.parametrize('size, fov, row', [
    ((1920, 1080), dict(hfov=120.0), ('long_side', None, 120.0)),
    ((1000, 1000), dict(vfov=150.0), ('long_side', None, 150.0)),  # a square image: the long side
    ((1920, 1080), dict(vfov=100.0), ('short_side', 1.778, 100.0)),
    ((1080, 1920), dict(hfov=100.0), ('short_side', 1.778, 100.0)),  # portrait: long / short is 16:9 too
    ((1440, 1080), dict(dfov=150.0), ('diagonal', 1.333, 150.0)),
    ((2592, 1080), dict(vfov=60.0), ('short_side', 2.4, 60.0)),
])
def test_a_spec_at_a_table_node_gets_that_rows_shape(size, fov, row):
    """At a node of the table (its FOV and aspect ratio, long / short side) the shape is that
    row's a and its 16th / 84th percentiles (to 0.1 %: the aspects are printed to 3 decimals,
    16/9 is 1.7778 and interpolated a hair off the 1.778 node)."""
    rows, _ = _table_rows()
    a, a_low, a_high, _ = rows[row]
    shape = solve_zero_shot(CameraSpec(*size, **fov)).lens_shape
    assert shape.side == row[0]
    assert (shape.a, shape.a_low, shape.a_high) == pytest.approx((a, a_low, a_high), rel=1e-3)
    assert shape.a_low <= shape.a <= shape.a_high


def test_between_nodes_the_table_is_interpolated_in_log_a_over_fov_and_log_aspect():
    """1920 x 1200 (16:10, between the 4:3 and 16:9 nodes) and an FOV between two FOV nodes:
    a is the bilinear interpolation of log a in FOV and in log aspect."""
    rows, _ = _table_rows()
    x = (math.log(1.6) - math.log(1.333)) / (math.log(1.778) - math.log(1.333))
    for column in range(3):
        log_a = {}
        for aspect in (1.333, 1.778):
            log_a[aspect] = 0.5 * (math.log(rows[('short_side', aspect, 100.0)][column]) +
                                   math.log(rows[('short_side', aspect, 102.5)][column]))
        expected = math.exp((1 - x) * log_a[1.333] + x * log_a[1.778])
        shape = solve_zero_shot(CameraSpec(1920, 1200, vfov=101.25)).lens_shape
        assert (shape.a, shape.a_low, shape.a_high)[column] == pytest.approx(expected, rel=1e-3), column


def test_the_assumption_says_how_many_real_lenses_weigh_in():
    """Where many real lenses have about that FOV the text gives their number and the table's
    total; where few do (a 2.4:1 image's vfov of 110: 4 lenses) it says the nearest were used."""
    rows, total = _table_rows()
    lenses = rows[('long_side', None, 120.0)][3]
    text = solve_zero_shot(CameraSpec(1920, 1080, hfov=120)).assumption
    assert f'the {lenses:,.0f} real lenses of about that FOV among {total:,} calibrations' in text, text
    assert rows[('short_side', 2.4, 110.0)][3] < 5
    text = solve_zero_shot(CameraSpec(2592, 1080, vfov=110)).assumption
    assert f'the nearest real lenses (few of {total:,} calibrations have that FOV)' in text, text


def _camera_through(make, pixel, half_angle):
    """make(f) whose ray at ``pixel`` is ``half_angle`` off-axis (bisection on f: a longer focal
    length narrows every ray)."""
    lo, hi = 1.0, 1e6
    for _ in range(200):
        f = math.sqrt(lo * hi)
        ray = make(f).unproject(np.array([pixel], dtype=float))[0]
        angle = math.atan2(math.hypot(ray[0], ray[1]), ray[2])
        if not math.isfinite(angle) or angle > half_angle:
            lo = f
        else:
            hi = f
    return make(math.sqrt(lo * hi))


def _rms_after_rotation(reference, other, pixels):
    """RMS over ``pixels`` of other's minus reference's pixel of the reference's rays, after the
    rotation of the rays that makes them agree best (least squares on a rotation vector)."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation
    rays = reference.unproject(pixels)
    rays = rays[np.all(np.isfinite(rays), axis=1)]
    target = reference.project(rays)

    def residual(w):
        d = other.project(rays @ Rotation.from_rotvec(w).as_matrix().T) - target
        return np.nan_to_num(d, nan=1e3).ravel()
    d = residual(least_squares(residual, np.zeros(3), x_scale=1e-3).x).reshape(-1, 2)
    return math.sqrt(float(np.mean(np.sum(d ** 2, axis=1))))


def _grid(width, height, circle_radius=None):
    u, v = np.meshgrid(np.linspace(0, width, 33), np.linspace(0, height, 19))
    pixels = np.stack([u.ravel(), v.ravel()], -1)
    if circle_radius is not None:
        pixels = pixels[np.hypot(pixels[:, 0] - width / 2, pixels[:, 1] - height / 2) <= circle_radius]
    return pixels


def test_the_lens_shape_spread_is_the_rms_of_the_two_percentile_cameras():
    """hfov 118 on 1920 x 1080: the spread is the root mean square, over the 33 x 19 grid and the
    two cameras through the same FOV at the 16th percentile of real lenses' a and at the 84th
    or the fisheye law (a = 1), whichever is wider, of their pixel displacement from the solved
    camera after the best rotation (built here from the definition: the paper's equidistant
    camera, omega = a / f, f by bisection)."""
    from zeroshot_calib_ros.core.lens.models import ZeroShotCamera
    spec = CameraSpec(1920, 1080, hfov=118)
    solution = solve_zero_shot(spec)
    shape = solution.lens_shape
    assert shape.a_low < shape.a < shape.a_high
    assert shape.spread == (shape.a_low, max(shape.a_high, 1.0))
    squares = []
    for a in (shape.a_low, max(shape.a_high, 1.0)):
        other = _camera_through(lambda f: ZeroShotCamera(f, 960, 540, 1920, 1080, a / f), (1920, 540),
                                math.radians(59))
        squares.append(_rms_after_rotation(solution.camera, other, _grid(1920, 1080)) ** 2)
    assert squares[0] > 0 and squares[1] > 0
    u = zero_shot_uncertainty(spec, solution=solution)
    assert u.lens_shape_px == pytest.approx(math.sqrt(sum(squares) / 2), rel=0.02)


def test_the_spread_reaches_the_fisheye_law_where_the_tables_84th_percentile_stops_short():
    """hfov 93 on 1920 x 1080: the table's 84th percentile is a nearly rectilinear lens (a about
    0.42), and robotics cameras of that FOV behind fisheye-law lenses (a = 1) lie far past it; the
    spread is the RMS of the cameras at the 16th percentile and at a = 1 (lens_prior.FISHEYE_LAW_A)."""
    from zeroshot_calib_ros.core.lens.models import ZeroShotCamera
    from zeroshot_calib_ros.core.zeroshot.lens_prior import FISHEYE_LAW_A
    assert FISHEYE_LAW_A == 1.0
    spec = CameraSpec(1920, 1080, hfov=93)
    solution = solve_zero_shot(spec)
    shape = solution.lens_shape
    assert shape.a_high < 0.6 and shape.spread == (shape.a_low, 1.0)
    squares = []
    for a in (shape.a_low, 1.0):
        other = _camera_through(lambda f: ZeroShotCamera(f, 960, 540, 1920, 1080, a / f), (1920, 540),
                                math.radians(46.5))
        squares.append(_rms_after_rotation(solution.camera, other, _grid(1920, 1080)) ** 2)
    u = zero_shot_uncertainty(spec, solution=solution)
    assert u.lens_shape_px == pytest.approx(math.sqrt(sum(squares) / 2), rel=0.02)


def test_the_circle_forms_spread_is_over_its_circle_from_lenses_across_its_side():
    """The circle alone (T265: 800 px across its 800-px height, 163 degrees): the spread of real
    lenses whose FOV of 163 degrees spans the image's short side, measured on the grid pixels
    inside the circle (nothing outside it is imaged)."""
    from zeroshot_calib_ros.core.lens.wide_fov import WideFovCamera
    spec = CameraSpec(*T265, circle_diameter=800, circle_fov=163)
    solution = solve_zero_shot(spec)
    rows, _ = _table_rows()
    nodes = sorted(a for (side, a, fov) in rows if side == 'short_side' and fov == 162.5)
    # 848 / 800 = 1.06: between the 1:1 and 4:3 nodes, a interpolated in log aspect and FOV
    x = math.log(1.06) / math.log(nodes[1])
    squares = []
    for column in (1, 2):
        log_a = [0.8 * math.log(rows[('short_side', n, 162.5)][column]) +
                 0.2 * math.log(rows[('short_side', n, 165.0)][column]) for n in nodes[:2]]
        a = math.exp((1 - x) * log_a[0] + x * log_a[1])
        other = _camera_through(lambda f: WideFovCamera(f, 424, 400, 848, 800, a / f, 'equidistant', 400.0),
                                (824, 400), math.radians(81.5))
        squares.append(_rms_after_rotation(solution.camera, other, _grid(848, 800, 400.0)) ** 2)
    u = zero_shot_uncertainty(spec, solution=solution)
    assert u.lens_shape_px == pytest.approx(math.sqrt(sum(squares) / 2), rel=0.02)


def test_one_fov_error_bar_frees_the_principal_point_under_its_prior():
    """One FOV: the FOV part of the error bar is the Laplace approximation of f AND the principal
    point (prior: 1.1 % of the width); the FOV adds evidence, so the principal point is no less
    certain than its prior says, and no more certain than zero."""
    from zeroshot_calib_ros.core.estimation.terms import PRINCIPAL_POINT_SIGMA
    spec = CameraSpec(1920, 1080, hfov=118)
    u = zero_shot_uncertainty(spec)
    names = list(u.names)
    for name in ('f', 'cx', 'cy'):
        variance = u.covariance[names.index(name), names.index(name)]
        assert variance > 0, name
        if name != 'f':
            assert math.sqrt(variance) <= PRINCIPAL_POINT_SIGMA * 1920 * (1 + 1e-9), name


# -- the table ------------------------------------------------------------------------------------

def test_the_table_is_small_and_says_where_it_comes_from():
    text = TABLE.read_text()
    assert len(text) < 64_000
    header = ''.join(line for line in text.splitlines(True) if line.startswith('#'))
    for words in ('gyroflow lens_profiles', 'CC0 1.0', 'held-out', 'square pixels', 'Rebuild:',
                  'benchmarks/build_lens_prior.py'):
        assert words in header, words
    prior = packaged_lens_prior()
    assert set(prior.tables) == {'long_side', 'short_side', 'diagonal'} and prior.total_lenses > 3000


@pytest.mark.parametrize('change, match', [
    (lambda t: t.replace('side,aspect,fov_deg', 'side,aspect,fov'), 'header'),
    (lambda t: '\n'.join(line for line in t.splitlines() if not line.startswith('diagonal')), 'no rows for diagonal'),
    (lambda t: t.replace('long_side,,100,', 'long_side,,100,x', 1), 'could not convert|invalid'),
    (lambda t: '\n'.join(line for line in t.splitlines() if 'Training set' not in line), 'lenses'),
])
def test_a_malformed_table_is_refused(change, match):
    with pytest.raises(LensPriorError, match=match):
        parse_lens_prior(change(TABLE.read_text()), 'lens_prior.csv')


# -- on real lenses (../shared/data) --------------------------------------------------------------

def _load(name):
    path = REPO / 'benchmarks' / f'{name}.py'
    spec = importlib.util.spec_from_file_location(f'{name}_for_test_lens_prior', path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@needs_data
def test_shipped_table_is_the_build_scripts_output():
    """benchmarks/build_lens_prior.py rebuilds the table from the CSV; the shipped one is its
    output (to the table's 4 digits: the same on numpy 1.26 and 2)."""
    build = _load('build_lens_prior')
    difference = build.tables_agree(TABLE.read_text(), build.build_table(PROFILES))
    assert difference is None, difference


@pytest.fixture(scope='module')
def bench():
    if not PROFILES.is_file():
        pytest.skip(f'the shared real data set is missing: {PROFILES} (set ZEROSHOT_SHARED_DATA)')
    return _load('lens_profiles')


@pytest.fixture(scope='module')
def held_out(bench):
    """The usable held-out profiles (camera models the table was not built from)."""
    profiles = [p for p in bench.load_profiles(PROFILES) if p.held_out]
    return [p for p in profiles if bench.ground_truth_problem(p.camera()) is None]


def _evaluate(bench, profiles, names, honesty):
    estimators = [e for e in bench.ESTIMATORS if e.name in names]
    assert len(estimators) == len(names)
    return [r for r in (bench.evaluate_profile(p, estimators, honesty) for p in profiles) if r.excluded is None]


def test_held_out_medians_meet_the_targets(bench, held_out):
    """Wide held-out lenses (hfov >= 100, all of them) at 1920 px: d only <= 20 px, h only <= 12 px
    (a pinhole: about 190 / 110); narrow ones (every third) no worse than the pinhole reading."""
    names = ['d only', 'h only', 'd only, no prior', 'h only, no prior']
    wide = [p for p in held_out if bench.fields_of_view_through_axis(p.camera())['hfov'] >= bench.WIDE_HFOV]
    narrow = [p for p in held_out if p not in wide][::3]
    assert len(wide) > 150 and len(narrow) > 250
    wide_records = _evaluate(bench, wide, names[:2], 'none')
    narrow_records = _evaluate(bench, narrow, names, 'none')

    def median(records, name):
        return float(np.median([r.rms[name] for r in records if name in r.rms]))
    assert median(wide_records, 'd only') <= 20.0
    assert median(wide_records, 'h only') <= 12.0
    assert median(narrow_records, 'd only') <= median(narrow_records, 'd only, no prior')
    assert median(narrow_records, 'h only') <= median(narrow_records, 'h only, no prior')


def test_error_bars_are_honest_for_every_kind_of_input(bench, held_out):
    """On every 20th held-out lens: the true error is at most twice uncertainty_px for >= 80 % of
    them, for h + v, h + v + d, d only, h only and the circle form alone (before: 48 % with one FOV);
    and the bars are not absurdly wide (median true / stated above 0.1)."""
    names = ['paper ZS', 'ours auto', 'd only', 'h only', 'circle']
    records = _evaluate(bench, held_out[::20], names, 'all')
    assert len(records) > 50
    for name in names:
        n, honest, ratio = bench.honesty(records, name)
        assert n >= 0.95 * len(records), name
        assert honest >= 0.8 and ratio > 0.1, (name, honest, ratio)
