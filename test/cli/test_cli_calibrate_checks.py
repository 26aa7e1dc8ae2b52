"""`zeroshot-calib calibrate` never gives a confident wrong answer: a spec the corners contradict is
not adopted (nor called agreeing; exit status 3, and the file written says so), duplicate views
count once, the board's square size is checked, a plumb_bob file is never written for a lens
plumb_bob cannot represent, and the rectified camera P it writes keeps the scene centred.

The real-data tests use ../shared/data/ros_fisheye_800x503 (a lens of about 180 x 104 degrees, f
about 290-305 px; ZEROSHOT_SHARED_DATA may name another copy of ../shared/data) and skip, saying
so, when it is missing."""
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from cli_run import RecordedComputation, run_main, run_main_alone
from zeroshot_calib_ros.core import CameraCalibration

REPO = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get('ZEROSHOT_SHARED_DATA', REPO.parent / 'shared' / 'data')) / 'ros_fisheye_800x503'
needs_data = pytest.mark.skipif(not (DATA / 'left-0000.png').is_file(),
                                reason=f'the shared real data set is missing: {DATA}')
RIGHT_SPEC = ['--hfov', '180.8', '--vfov', '103.5']
"""The FOVs of the authors' calibration (ost.yaml read as Kannala-Brandt): 180.81 x 103.52 degrees."""




NOT_ADOPTED = 3
"""The documented exit status of a calibrate whose board fit was not adopted (--help, README)."""


def calibrate_json(capsys, *args, status=0):
    got, out, err = run_main(['calibrate', *args, '--json'], capsys)
    assert got == status, err
    return json.loads(out), err


def spec_line(out):
    return next(line for line in out.splitlines() if line.startswith('spec'))


# -- 1 and 2: a spec the corners contradict ----------------------------------------------------------

@pytest.fixture(scope='module')
def right_spec_on_one_view():
    """(JSON record, stderr lines) of calibrate --json on left-0000 with the authors' FOVs: checked
    by the next test, and the image alone of test_copies_of_one_view_count_once_and_do_not_shrink_the_error_bar."""
    status, out, err = run_main_alone(['calibrate', str(DATA / 'left-0000.png'), *RIGHT_SPEC, '--json'])
    assert status == 0, err
    return json.loads(out), err


@needs_data
def test_the_right_spec_on_one_real_view_is_adopted_and_agrees(right_spec_on_one_view):
    """The guard of the contradiction test: the authors' FOVs on left-0000 are adopted, agree, and
    give f within 6 % of the authors' 290 px (one view)."""
    record, err = right_spec_on_one_view
    assert record['accepted'] is True and record['fit']['spec_agrees'] is True
    assert record['warning'] == [] and not any('contradict' in line for line in err)
    assert record['f'] == pytest.approx(290.0, rel=0.06)
    assert record['uncertainty_px'] is not None and 0 < record['uncertainty_px'] < 10


@needs_data
@pytest.mark.parametrize('spec', [['--hfov', '60', '--vfov', '40'], ['--hfov', '180.8', '--vfov', '10']],
                         ids=['60x40', '180.8x10'])
def test_a_spec_the_corners_contradict_is_never_accepted_nor_said_to_agree(tmp_path, capsys, monkeypatch, spec):
    """A 60 x 40 degree spec (or 180.8 x 10) on one view of the 180-degree lens: not accepted, the
    JSON's warning and the text say the corners contradict the spec, no error bar is claimed for
    the camera written (the spec it comes from is contradicted), exit status 3 as any refused result
    (`accepted: false`, the zero-shot camera written, as the gate's refusals), and the file and one
    stderr line say that it holds the zero-shot camera."""
    from zeroshot_calib_ros.core.estimation import board_fit
    out_yaml = tmp_path / 'camera.yaml'
    # this run's board fit is recorded and replayed to the text run below, which asks for the same
    # one: the two check what the CLI says of it (cli_run.RecordedComputation)
    fit = RecordedComputation(monkeypatch, board_fit, 'fit_board')
    fit.record()
    record, err = calibrate_json(capsys, str(DATA / 'left-0000.png'), *spec, '--yaml', str(out_yaml),
                                 status=NOT_ADOPTED)
    assert len(fit.calls) == 1
    fit.replay(progress=False)
    assert record['accepted'] is False
    assert record['fit']['spec_agrees'] is False
    assert any('contradict' in w for w in record['warning']), record['warning']
    assert any('contradict' in line for line in err)
    assert 'contradict' in record['reason']
    assert record['uncertainty_px'] is None
    assert out_yaml.is_file()
    first = out_yaml.read_text().splitlines()[0]
    assert first.startswith('# board fit not adopted: the corners contradict the spec')
    assert first.endswith('; this is the zero-shot camera from the spec')
    notices = [line for line in err if line.startswith('zeroshot-calib: board fit not adopted: ')]
    assert len(notices) == 1 and 'contradict' in notices[0]
    assert notices[0].endswith(f'{out_yaml} holds the zero-shot camera from the spec (exit status 3)')
    status, out, _ = run_main(['calibrate', str(DATA / 'left-0000.png'), *spec], capsys)
    assert status == NOT_ADOPTED and fit.replayed == 1
    assert 'agrees' not in spec_line(out) and 'DISAGREES' in spec_line(out)
    assert next(x for x in out.splitlines() if x.startswith('method')).startswith('method    zero-shot kept')
    assert 'error bar -' in out


# -- 3: duplicate views ------------------------------------------------------------------------------

@needs_data
def test_copies_of_one_view_count_once_and_do_not_shrink_the_error_bar(tmp_path, capsys, right_spec_on_one_view):
    """Five copies of left-0000.png (other names, same pixels), and the same path given twice:
    one view, a note naming the copies, the same uncertainty as the image alone."""
    alone, _ = right_spec_on_one_view
    copies = []
    for k in range(5):
        copies.append(tmp_path / f'copy-{k}.png')
        shutil.copyfile(DATA / 'left-0000.png', copies[-1])
    record, _ = calibrate_json(capsys, *map(str, copies), *RIGHT_SPEC)
    assert record['images'] == 1
    assert len(record['duplicate_views']) == 4
    assert any('duplicate' in n and 'once' in n for n in record['notes'])
    # to 1e-4: with Ubuntu 24.04's numpy 1.26 on an AVX-512 CPU two runs differ by up to 1e-3 (a view counted
    # five times would shrink the error bar by about sqrt(5))
    assert record['uncertainty_px'] == pytest.approx(alone['uncertainty_px'], rel=1e-2)
    twice, _ = calibrate_json(capsys, str(DATA / 'left-0000.png'), str(DATA / 'left-0000.png'), *RIGHT_SPEC)
    assert twice['images'] == 1 and twice['uncertainty_px'] == pytest.approx(alone['uncertainty_px'], rel=1e-2)


def test_duplicate_views_count_once_in_fc_eq_d_too(tmp_path, capsys):
    """Without a spec (FC_eq.d.): a corners file with one view under three names is one view, the
    same camera as that view alone."""
    from test_board_fit import TRUTH, board_views
    from zeroshot_calib_ros.core.checkerboard.corners import CornerSet
    corners, _ = board_views(TRUTH, 2, seed=3, noise=0.2)
    c = corners.corners
    tripled = CornerSet(corners.width, corners.height, corners.board, ['a.png', 'b.png', 'c.png', 'd.png'],
                        np.array([c[0], c[0], c[0], c[1]]))
    single = CornerSet(corners.width, corners.height, corners.board, ['a.png', 'd.png'], np.array([c[0], c[1]]))
    tripled.save(str(tmp_path / 'tripled.json'))
    single.save(str(tmp_path / 'single.json'))
    record, _ = calibrate_json(capsys, '--corners', str(tmp_path / 'tripled.json'))
    expected, _ = calibrate_json(capsys, '--corners', str(tmp_path / 'single.json'))
    assert record['images'] == 2 and record['image_names'] == ['a.png', 'd.png']
    assert [d['image'] for d in record['duplicate_views']] == ['b.png', 'c.png']
    assert record['f'] == pytest.approx(expected['f'], rel=1e-4)  # runs differ by ~1e-6 on numpy 1.26 + AVX-512


# -- 4: the square size ------------------------------------------------------------------------------

@pytest.mark.parametrize('square', ['1e300', '0', '-0.1', 'nan', 'inf', '1e-9', '108'])
def test_an_insane_square_size_is_one_line_naming_the_option(tmp_path, capsys, square):
    status, out, err = run_main(['calibrate', str(tmp_path / 'none.png'), '--square', square], capsys)
    assert status == 2 and out == '' and len(err) == 1, err
    assert err[0].startswith('zeroshot-calib: error: --square') and 'metres' in err[0] and 'allowed' in err[0]


# -- 5: plumb_bob on a lens it cannot represent ------------------------------------------------------

@needs_data
@pytest.mark.parametrize('spec', [RIGHT_SPEC, []], ids=['spec-as-evidence', 'no-spec'])
def test_plumb_bob_is_refused_for_a_180_degree_lens_and_nothing_is_written(tmp_path, capsys, spec):
    out_yaml = tmp_path / 'camera.yaml'
    status, out, err = run_main(['calibrate', str(DATA / 'left-0000.png'), *spec, '--distortion-model',
                                 'plumb_bob', '--yaml', str(out_yaml)], capsys)
    assert status == 2 and out == '' and len(err) == 1, err
    assert '--distortion-model plumb_bob' in err[0] and 'equidistant' in err[0] and 'nan' not in err[0]
    assert not out_yaml.exists()


def test_a_board_fit_not_adopted_is_said_in_an_ini_file_its_readers_skip(tmp_path, capsys):
    """A lens of about 75 degrees with a spec its corners contradict (40 x 25 degrees), written as
    INI (plumb_bob): exit status 3, the file's first line a # comment saying it holds the zero-shot
    camera, which camera_calibration_parsers' INI reader skips (lines starting with '#'; our
    reader follows it): the file loads as the zero-shot camera of the spec."""
    from test_board_fit import board_views
    from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
    narrow = KannalaBrandtCamera(520.0, 520.0, 402.0, 248.0, 800, 500, [0.02, -0.01, 0.0, 0.0])
    corners, _ = board_views(narrow, 3, seed=4, distance=(0.3, 0.5), noise=0.2)
    corners.save(str(tmp_path / 'narrow.json'))
    out_ini = tmp_path / 'camera.ini'
    record, err = calibrate_json(capsys, '--corners', str(tmp_path / 'narrow.json'), '--hfov', '40', '--vfov', '25',
                                 '--distortion-model', 'plumb_bob', '--yaml', str(out_ini), status=NOT_ADOPTED)
    assert record['accepted'] is False
    lines = out_ini.read_text().splitlines()
    assert lines[0].startswith('# board fit not adopted: ') and lines[0].endswith('zero-shot camera from the spec')
    assert lines[1] == '# Camera intrinsics'  # then camera_calibration_parsers' own layout
    loaded = CameraCalibration.load(str(out_ini))
    assert loaded.distortion_model == 'plumb_bob'
    np.testing.assert_allclose(loaded.K, record['K'], rtol=1e-12)
    np.testing.assert_allclose(loaded.D, record['D'], rtol=1e-12)
    assert any(line.startswith('zeroshot-calib: board fit not adopted: ') for line in err)


def test_plumb_bob_where_it_can_represent_the_lens_reports_a_real_fit_error(tmp_path, capsys):
    """A lens of about 75 degrees (no spec, and with its spec as evidence): plumb_bob stays allowed
    and its fit error is a number."""
    from test_board_fit import board_views
    from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
    from zeroshot_calib_ros.core.estimation.terms import FovTerm
    narrow = KannalaBrandtCamera(520.0, 520.0, 402.0, 248.0, 800, 500, [0.02, -0.01, 0.0, 0.0])
    corners, _ = board_views(narrow, 3, seed=4, distance=(0.3, 0.5), noise=0.2)
    corners.save(str(tmp_path / 'narrow.json'))
    fovs = FovTerm({'hfov': 1.0, 'vfov': 1.0}, 800, 500).predicted(narrow)
    for spec in ([], ['--hfov', repr(fovs['hfov']), '--vfov', repr(fovs['vfov'])]):
        record, _ = calibrate_json(capsys, '--corners', str(tmp_path / 'narrow.json'), *spec,
                                   '--distortion-model', 'plumb_bob')
        assert record['distortion_model'] == 'plumb_bob'
        assert math.isfinite(record['fit_error_px']) and any(d != 0 for d in record['D'])


class _LinearLayout:
    """A 'camera' that is the parameter vector itself: the costs below have closed forms."""

    def camera(self, x):
        return np.asarray(x, float)

    def steps(self, x):
        return np.full(len(x), 1e-6)


class _Offset:
    """Residuals camera - target (a Gaussian term), as corner and FOV terms present them."""
    group, loss, loss_scale = 1, None, 1.0

    def __init__(self, name, target, sigma=1.0, keys=None):
        self.name, self.target, self.sigma = name, np.asarray(target, float), sigma
        self.keys = keys

    def residuals(self, camera):
        return camera - self.target


@pytest.mark.parametrize('keys', [('hfov', 'vfov'), ('dfov',)])
@pytest.mark.parametrize('ratio', [25.5, 40.0])
def test_the_contradiction_statistic_is_the_likelihood_ratio_against_its_chi2_quantile(keys, ratio):
    """Wilks' test as the docstring states it, on a problem with closed-form costs: corners at a,
    the spec at b with tolerance s: the best cost without the spec is 0, with it
    |a - b|^2 / (2 (1 + s^2)), so the ratio (twice the difference) is |a - b|^2 / (1 + s^2); the
    threshold is the chi^2 quantile 1 - 1e-6 for one degree per FOV: 2 ln(1e6) = 27.63 for two
    FOVs (closed form), 23.93 for one. A ratio of 25.5 contradicts one FOV but not two."""
    from zeroshot_calib_ros.core.estimation.board_fit import spec_contradiction
    from zeroshot_calib_ros.core.estimation.problem import Problem
    n, tolerance = len(keys), 5.0
    a = np.zeros(n)
    b = np.full(n, math.sqrt(ratio * (1 + tolerance ** 2) / n))
    fov = _Offset('fov', b, sigma=1.0, keys=keys)
    problem = Problem(_LinearLayout(), [_Offset('corners', a), fov])
    got, threshold = spec_contradiction(problem, np.zeros(n), fov, tolerance)
    assert got == pytest.approx(ratio, rel=1e-6)
    assert threshold == pytest.approx(2 * math.log(1e6) if n == 2 else 23.928, abs=1e-3)
    assert fov.sigma == 1.0  # the MAP's own FOV term is left as it was
    contradicted = got > threshold
    assert contradicted == (ratio == 40.0 or n == 1)


# -- 6: the rectified camera P -----------------------------------------------------------------------

def rectified_pixel(calibration, pixel):
    """Where the raw image's ``pixel`` lands in the image rectified with the file's P (R = I)."""
    ray = calibration.camera().unproject(np.asarray(pixel, float))
    p = calibration.P[:, :3] @ (ray / ray[2])
    return p[:2] / p[2]


@needs_data
@pytest.mark.parametrize('spec', [[], RIGHT_SPEC], ids=['no-spec', 'spec-as-evidence'])
def test_P_is_centred_on_the_calibrated_principal_point_and_keeps_the_scene_centred(tmp_path, capsys, spec):
    """Ten images of the shared 180-degree lens, whose principal point is about 20 px below the
    image centre (the authors' ost.yaml: cy 273.9 in 503 rows). P is written as ROS
    camera_calibration writes a fisheye's: its principal point is K's (P used to be centred on the
    mean of the undistorted edge midpoints, which put it at (279, 386) for the FC_eq.d. camera:
    image_proc showed an off-centre view). So the raw image's centre lands within a few px of the
    rectified image's centre: the scene stays where it was."""
    out_yaml = tmp_path / 'camera.yaml'
    calibrate_json(capsys, str(DATA / 'left-000*.png'), *spec, '--yaml', str(out_yaml))
    calibration = CameraCalibration.load(str(out_yaml))
    K, P = calibration.K, calibration.P
    np.testing.assert_allclose(P[:2, 2], K[:2, 2], atol=1e-9)
    centre = np.array([calibration.width / 2, calibration.height / 2])
    assert abs(P[0, 2] - centre[0]) < 5 and abs(P[1, 2] - centre[1]) < 25, P  # K's own offset: ~20 px in y
    assert np.linalg.norm(rectified_pixel(calibration, centre) - centre) < 6


@pytest.mark.parametrize('spec', [False, True], ids=['no-spec', 'spec-as-evidence'])
def test_P_of_a_synthetic_off_centre_wide_lens_is_centred_on_its_principal_point(tmp_path, capsys, spec):
    """Four views of a 171 x 100 degree lens 6 px off the centre of its 800 x 500 image (OpenCV's
    rule would put P's principal point at x = 905, outside the image): P's principal point is the
    calibrated K's, and the raw image's centre stays within a few px of the rectified image's."""
    from test_board_fit import TRUTH, board_views, true_spec
    corners, _ = board_views(TRUTH, 4, seed=3, noise=0.2)
    corners.save(str(tmp_path / 'corners.json'))
    flags = []
    if spec:
        fovs = true_spec()
        flags = ['--hfov', repr(fovs.hfov), '--vfov', repr(fovs.vfov)]
    out_yaml = tmp_path / 'camera.yaml'
    got, out, err = run_main(['calibrate', '--corners', str(tmp_path / 'corners.json'), *flags, '--yaml',
                              str(out_yaml), '--json'], capsys)
    assert got in (0, NOT_ADOPTED), err
    calibration = CameraCalibration.load(str(out_yaml))
    np.testing.assert_allclose(calibration.P[:2, 2], calibration.K[:2, 2], atol=1e-9)
    centre = np.array([400.0, 250.0])
    assert np.linalg.norm(rectified_pixel(calibration, centre) - centre) < 8


@needs_data
@pytest.mark.parametrize('balance', [0.0, 1.0])
def test_balance_keeps_its_meaning_around_the_calibrated_principal_point(tmp_path, capsys, balance):
    """FC_eq.d. on the shared set (a 173 x 104 degree lens): with --balance 0 the rectified image
    shows no black border at the raw image's edge midpoints (each lands on or beyond the rectified
    image's edge), with --balance 1 all four are inside it, one on its edge."""
    out_yaml = tmp_path / 'camera.yaml'
    calibrate_json(capsys, str(DATA / 'left-000*.png'), '--balance', str(balance), '--yaml', str(out_yaml))
    calibration = CameraCalibration.load(str(out_yaml))
    w, h = calibration.width, calibration.height
    (_, top), (right, _), (_, bottom), (left, _) = [
        rectified_pixel(calibration, p) for p in ([w // 2, 0], [w, h // 2], [w // 2, h], [0, h // 2])]
    beyond = [-left, right - w, -top, bottom - h]  # > 0: beyond the rectified image's edge
    if balance == 0.0:
        assert min(beyond) > -0.5, beyond
    else:
        assert max(beyond) < 0.5 and min(abs(b) for b in beyond) < 0.5, beyond
