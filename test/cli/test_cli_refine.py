"""`zeroshot-calib refine`: the spec plus straight lines in ordinary images, as a user runs it.

Images are rendered (test/scenes.py) through a known Kannala-Brandt camera with an off-centre
principal point, so the refined camera is checked against the truth; bad input (images of two
sizes, a black image, an image without straight lines, two different cameras) gives the
zero-shot camera with `accepted: false` and the reason (exit status 3, one line on stderr, and a
comment in the file written), or one error line, never a traceback.
"""
import json

import cv2
import numpy as np
import pytest

from cli_run import RecordedComputation, same_result
from pictures import sheet_panels
from scenes import dense_rms, render, soft_rim
from zeroshot_calib_ros.cli import main
from zeroshot_calib_ros.core import CameraCalibration, CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis

TRUE = KannalaBrandtCamera(210.0, 210.0, 327.0, 176.0, 640, 360, np.array([0.02, -0.01, 0.003, -0.0005]))
SPEC_FLAGS = ['--hfov', '172', '--vfov', '97', '--dfov', '198']  # TRUE's FOVs, rounded to 1 degree
SOLVE_KEYS = {'width', 'height', 'model', 'omega', 'f', 'cx', 'cy', 'K', 'distortion_model', 'D', 'fit_error_px',
              'hfov', 'vfov', 'dfov', 'P', 'warning'}
REFINEMENT_KEYS = {'accepted', 'reason', 'images_used', 'lines_used', 'line_residual_px_before',
                   'line_residual_px_after', 'coverage', 'principal_point_shift_px', 'curves_static',
                   'curves_bowed'}


@pytest.fixture(scope='module')
def views(tmp_path_factory):
    directory = tmp_path_factory.mktemp('views')
    paths = []
    for i, (scene, seed) in enumerate([('room', 1), ('corridor', 2), ('street', 3)]):
        image, _ = render(TRUE, scene, seed=seed)
        path = directory / f'view{i}.png'
        cv2.imwrite(str(path), image)
        paths.append(str(path))
    return paths


def run(capsys, *argv):
    status = main(['refine', *argv])
    out, err = capsys.readouterr()
    return status, out, err


NOT_REFINED = 3
"""The documented exit status of a refine that ran but was not adopted (--help, README)."""


def status_of(record):
    """The exit status a refine with this --json record must have: 0 refined, 3 not."""
    return 0 if record['refinement']['accepted'] else NOT_REFINED




def test_refine_recovers_the_true_camera_and_writes_it(views, capsys, tmp_path):
    fovs = fields_of_view_through_axis(TRUE)
    assert [round(fovs[k]) for k in ('hfov', 'vfov', 'dfov')] == [172, 97, 198]
    yaml_path = tmp_path / 'refined.yaml'
    debug = tmp_path / 'debug.png'
    status, out, err = run(capsys, *views, *SPEC_FLAGS, '--json', '--yaml', str(yaml_path),
                           '--debug-image', str(debug))
    assert status == 0, err
    record = json.loads(out)
    assert SOLVE_KEYS <= set(record) and REFINEMENT_KEYS == set(record['refinement'])
    assert record['refinement']['accepted'] is True, record['refinement']['reason']
    # every key of `solve --json` when accepted too: the refined camera's error bar, no assumption
    assert main(['solve', '--width', '640', '--height', '360', *SPEC_FLAGS, '--json']) == 0
    solved = json.loads(capsys.readouterr()[0])
    assert set(solved) <= set(record), set(solved) - set(record)
    assert record['assumption'] is None and record['uncertainty_over'] == 'image'
    assert record['uncertainty'] and record['uncertainty'] != solved['uncertainty']
    assert record['refinement']['images_used'] == 3
    assert '#' not in yaml_path.read_text()  # refined: no "not refined" comment
    refined = CameraCalibration.load(str(yaml_path))
    camera = KannalaBrandtCamera(refined.K[0, 0], refined.K[1, 1], refined.K[0, 2], refined.K[1, 2], 640, 360,
                                 refined.D)
    zero_shot = solve_zero_shot(CameraSpec(640, 360, hfov=172, vfov=97, dfov=198)).camera
    assert abs(camera.cx - TRUE.cx) < 2 and abs(camera.cy - TRUE.cy) < 2  # zero-shot: the centre, 8 px off
    # P keeps the refined principal point (image_proc shows the scene around the optical axis);
    # OpenCV's rule would centre P on the mean of the edges, off this 172-degree image
    np.testing.assert_allclose(refined.P[:2, 2], refined.K[:2, 2])
    np.testing.assert_allclose(record['P'], refined.P)
    assert record['f'] == pytest.approx(TRUE.fx, rel=0.01)
    assert dense_rms(camera, TRUE) < 1.0 < dense_rms(zero_shot, TRUE)
    assert 0 < record['uncertainty_px'] < 5
    picture = cv2.imread(str(debug))
    panels = sheet_panels(picture, 360 / 640)  # the contact sheet: a panel per view (test_calibration_report.py)
    assert len(panels) == 3
    # the views are grey: green pixels on the first panel are the used curves drawn over the first
    # image (at least one of its straight lines, ~100 px each), which a user checks by eye
    x, y, w, h = panels[0]
    top = picture[y:y + h, x:x + w].astype(int)
    green = (top[..., 1] > 150) & (top[..., 0] < 80) & (top[..., 2] < 80)
    assert green.sum() > 300 * (w / 640) ** 2


def test_refine_text_output_names_every_file_it_wrote(capsys, tmp_path):
    """Each file written gets its `wrote` line, refined or not (the picture to look at first included)."""
    path = tmp_path / 'black.png'
    cv2.imwrite(str(path), np.zeros((360, 640), np.uint8))
    files = [tmp_path / name for name in ('camera.yaml', 'debug.png', 'report.png')]
    status, out, err = run(capsys, str(path), *SPEC_FLAGS, '--yaml', str(files[0]), '--debug-image', str(files[1]),
                           '--report', str(files[2]))
    assert status == NOT_REFINED, err
    for written in files:
        assert written.is_file() and f'wrote {written}' in out.splitlines(), out
    # each flag alone: its own line, and no other
    for flag, written in zip(('--yaml', '--debug-image', '--report'), files):
        written.unlink()
        status, out, err = run(capsys, str(path), *SPEC_FLAGS, flag, str(written))
        assert status == NOT_REFINED, err
        assert [line for line in out.splitlines() if line.startswith('wrote')] == [f'wrote {written}'], out


def test_refine_text_output_says_what_it_decided(capsys, tmp_path):
    path = tmp_path / 'black.png'
    cv2.imwrite(str(path), np.zeros((360, 640), np.uint8))
    status, out, err = run(capsys, str(path), *SPEC_FLAGS)
    assert status == NOT_REFINED, err
    lines = out.splitlines()
    assert lines[-1].startswith('refined   no: ') and len(lines[-1]) > len('refined   no: ')
    assert any(line.startswith('error bar ') for line in lines)
    assert not any(line.startswith('left out') for line in lines)  # nothing was left out: not said


def test_a_refused_refinement_says_so_in_the_file_on_stderr_and_in_its_exit_status(capsys, tmp_path):
    """Not refined (a black image has no lines): the file written under the requested name holds
    the zero-shot camera and says so in a # comment, which camera_calibration_parsers and PyYAML
    skip (the file loads as the zero-shot calibration); one stderr line says so too, naming the
    file; the exit status is 3 (documented in --help); --json keeps accepted: false."""
    import yaml
    path = tmp_path / 'black.png'
    cv2.imwrite(str(path), np.zeros((360, 640), np.uint8))
    out_yaml = tmp_path / 'camera.yaml'
    status, out, err = run(capsys, str(path), *SPEC_FLAGS, '--json', '--yaml', str(out_yaml))
    assert status == NOT_REFINED, err
    record = json.loads(out)
    assert record['refinement']['accepted'] is False
    reason = record['refinement']['reason']
    text = out_yaml.read_text()
    assert text.splitlines()[0] == f'# not refined: {reason}; this is the zero-shot camera from the spec'
    body = '\n'.join(line for line in text.splitlines() if not line.startswith('#'))
    assert yaml.safe_load(text) == yaml.safe_load(body)
    zero_shot, _ = CameraCalibration.from_solution(solve_zero_shot(CameraSpec(640, 360, hfov=172, vfov=97, dfov=198)))
    loaded = CameraCalibration.load(str(out_yaml))
    assert np.array_equal(loaded.K, zero_shot.K) and np.array_equal(loaded.D, zero_shot.D)
    assert [line for line in err.splitlines() if 'not refined' in line] == [
        f'zeroshot-calib: not refined: {reason}; {out_yaml} holds the zero-shot camera from the spec (exit status 3)']
    # without --yaml the line says which camera was printed
    status, out, err = run(capsys, str(path), *SPEC_FLAGS)
    assert status == NOT_REFINED
    assert err.strip().splitlines()[-1] == (f'zeroshot-calib: not refined: {reason}; the camera printed is the '
                                            'zero-shot camera from the spec (exit status 3)')
    with pytest.raises(SystemExit):
        main(['refine', '--help'])
    assert '3 refine / calibrate ran but did not adopt their result' in ' '.join(capsys.readouterr()[0].split())


def test_images_of_two_sizes_are_one_error_line(views, capsys, tmp_path):
    small = tmp_path / 'small.png'
    cv2.imwrite(str(small), np.zeros((180, 320), np.uint8))
    status, out, err = run(capsys, views[0], str(small), *SPEC_FLAGS)
    assert status == 2 and out == ''
    assert err.strip() == ('zeroshot-calib: error: the images have different sizes (320x180, 640x360): '
                           'allowed: images of one camera, one size')


def test_no_spec_is_one_error_line(views, capsys):
    status, out, err = run(capsys, views[0])
    assert status == 2 and len(err.strip().splitlines()) == 1 and '--hfov' in err


@pytest.mark.parametrize('kind', ['black', 'no straight lines'])
def test_images_without_lines_give_the_zero_shot_camera_and_the_reason(capsys, tmp_path, kind):
    if kind == 'black':
        image = np.zeros((360, 640), np.uint8)
    else:  # smooth blobs and circles: edges, none straight
        rng = np.random.default_rng(5)
        image = cv2.GaussianBlur(rng.integers(0, 256, (360, 640)).astype(np.uint8), (0, 0), 6)
        for _ in range(12):
            cv2.circle(image, (int(rng.integers(0, 640)), int(rng.integers(0, 360))), int(rng.integers(10, 80)),
                       int(rng.integers(0, 256)), 3, cv2.LINE_AA)
    path = tmp_path / 'image.png'
    cv2.imwrite(str(path), image)
    status, out, err = run(capsys, str(path), *SPEC_FLAGS, '--json')
    assert status == NOT_REFINED, err
    record = json.loads(out)
    assert record['refinement']['accepted'] is False and record['refinement']['reason']
    solution = solve_zero_shot(CameraSpec(640, 360, hfov=172, vfov=97, dfov=198))
    assert record['f'] == pytest.approx(solution.f) and record['omega'] == pytest.approx(solution.omega)
    # the camera returned is zero-shot's, so is the error bar: what `solve` reports for the spec
    assert main(['solve', '--width', '640', '--height', '360', *SPEC_FLAGS, '--json']) == 0
    solved = json.loads(capsys.readouterr()[0])
    assert record['uncertainty_px'] == pytest.approx(solved['uncertainty_px'])
    # every key of `solve --json` (docs/cli.md), with solve's values for the error bar and the
    # assumption: a client reads them without asking what the verdict was
    assert set(solved) <= set(record), set(solved) - set(record)
    for key in ('assumption', 'uncertainty', 'uncertainty_over', 'uncertainty_lens_shape_px'):
        assert record[key] == solved[key], key


def test_a_refused_refinement_of_one_fov_warns_of_the_lens_shape_assumed_as_solve_does(capsys, tmp_path):
    """One FOV and images that refine nothing: the camera returned is zero-shot's, whose lens shape is
    assumed from real lenses of that FOV; refine warns of it on stderr and in --json as solve does
    (a user given only the refusal had no word that the shape was a guess)."""
    path = tmp_path / 'black.png'
    cv2.imwrite(str(path), np.zeros((360, 640), np.uint8))
    status, out, err = run(capsys, str(path), '--hfov', '172', '--json')
    assert status == NOT_REFINED, err
    assert main(['solve', '--width', '640', '--height', '360', '--hfov', '172', '--json']) == 0
    solved = json.loads(capsys.readouterr()[0])
    assumption = solved['assumption']
    assert assumption and assumption.startswith('one FOV (hfov 172 deg)') and assumption in solved['warning']
    assert assumption in json.loads(out)['warning'] and f'warning: {assumption}' in err, err


def test_images_of_two_cameras_are_not_adopted(views, capsys, tmp_path):
    other = KannalaBrandtCamera(260.0, 260.0, 300.0, 190.0, 640, 360, np.array([-0.05, 0.01, 0.0, 0.0]))
    paths = list(views[:2])
    for i, (scene, seed) in enumerate([('room', 7), ('street', 8)]):
        image, _ = render(other, scene, seed=seed)
        path = tmp_path / f'other{i}.png'
        cv2.imwrite(str(path), image)
        paths.append(str(path))
    status, out, err = run(capsys, *paths, *SPEC_FLAGS, '--json')
    assert status == NOT_REFINED, err
    record = json.loads(out)
    refinement = record['refinement']
    # the words: the images disagree with one another (not the lines with the spec, which
    # is how the FOV check that catches it would put it)
    assert refinement['accepted'] is False, refinement
    assert refinement['reason'].startswith('disagreement between images'), refinement['reason']
    # the reason names the files, as given, not their positions in the list
    named = [p for p in paths if p in refinement['reason']]
    assert named and set(named) <= set(paths[2:]), refinement['reason']
    zero_shot = solve_zero_shot(CameraSpec(640, 360, hfov=172, vfov=97, dfov=198))
    assert record['f'] == pytest.approx(zero_shot.f) and record['cx'] == 320 and record['cy'] == 180


def circular_190(width=640, height=480, radius=220.0, cx=326.0, cy=236.0):
    """A 190-degree circular fisheye: its ray at 95 degrees lands on the image circle."""
    from zeroshot_calib_ros.core.lens.wide_fov import WideFovCamera
    probe = WideFovCamera(100.0, cx, cy, width, height, omega=1 / 100.0)
    edge = probe.project(np.array([[np.sin(np.radians(95)), 0.0, np.cos(np.radians(95))]]))[0]
    f = 100.0 * radius / (edge[0] - cx)
    return WideFovCamera(f, cx, cy, width, height, omega=1 / f, circle_radius=radius)


@pytest.fixture(scope='module')
def circular_view(tmp_path_factory):
    """A 190-degree circular fisheye's photo: vignetted circle, noisy glowing surround, a vehicle
    body part at the bottom, blur, noise, JPEG."""
    from scenes import ALL_NUISANCES
    image, _ = render(circular_190(), 'corridor', pose='random', seed=1, nuisances=ALL_NUISANCES)
    path = tmp_path_factory.mktemp('circular') / 'circular.png'
    cv2.imwrite(str(path), image)
    return str(path)


def test_circle_fov_alone_measures_the_circle_diameter_in_the_images(circular_view, capsys):
    truth = circular_190()
    status, out, err = run(capsys, circular_view, '--circle-fov', '190', '--json')
    record = json.loads(out)
    assert status == status_of(record), err
    circle = record['image_circle']
    assert abs(circle['diameter'] - 2 * truth.circle_radius) < 2.0
    assert abs(circle['cx'] - truth.cx) < 1.5 and abs(circle['cy'] - truth.cy) < 1.5
    assert circle['measured_from'] == 1 and circle['diameter_used'] == 'measured'
    assert 0 < circle['diameter_sigma_px'] < 2
    assert record['refinement']['reason']
    # the camera given (refined or zero-shot's) puts the 190-degree circle on the circle in the image
    K, D = np.array(record['K']), np.array(record['D'])
    camera = KannalaBrandtCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], 640, 480, D)
    edge = camera.project(np.array([[np.sin(np.radians(95)), 0.0, np.cos(np.radians(95))]]))[0]
    assert abs((edge[0] - camera.cx) - circle['diameter'] / 2) < 0.03 * circle['diameter'] / 2, (edge, circle)
    # the error bar says what it is over: the image circle for zero-shot of a circle-only spec (as
    # `solve` says), the refined camera's own domain otherwise
    if not record['refinement']['accepted']:
        assert main(['solve', '--width', '640', '--height', '480', '--circle-fov', '190',
                     '--circle-diameter', str(circle['diameter']), '--json']) == 0
        solved = json.loads(capsys.readouterr()[0])
        assert record['uncertainty_over'] == solved['uncertainty_over'] == 'image circle'
        assert record['uncertainty_px'] == pytest.approx(solved['uncertainty_px'], rel=1e-6)
    else:
        assert record['uncertainty_over'] in ('image', 'image circle')


def test_a_refused_circular_fisheye_states_zero_shots_error_bar_over_its_circle(capsys, tmp_path):
    """No lines through a circle-only spec: zero-shot is returned, and its error bar is `solve`'s,
    over the image circle, said so in --json and in the text's error bar line."""
    path = tmp_path / 'black.png'
    cv2.imwrite(str(path), np.zeros((480, 640), np.uint8))
    spec = ['--circle-fov', '190', '--circle-diameter', '460']
    status, out, err = run(capsys, str(path), *spec, '--json')
    assert status == NOT_REFINED, err
    record = json.loads(out)
    assert main(['solve', '--width', '640', '--height', '480', *spec, '--json']) == 0
    solved = json.loads(capsys.readouterr()[0])
    assert set(solved) <= set(record), set(solved) - set(record)
    for key in ('assumption', 'uncertainty', 'uncertainty_over', 'uncertainty_lens_shape_px'):
        assert record[key] == solved[key], key
    assert record['uncertainty_over'] == 'image circle' and record['assumption']
    status, text, err = run(capsys, str(path), *spec)
    assert status == NOT_REFINED and 'error bar' in text and 'RMS over the image circle of' in text, text


def test_a_given_circle_diameter_that_disagrees_with_the_images_is_warned_about(circular_view, capsys):
    status, out, err = run(capsys, circular_view, '--circle-fov', '190', '--circle-diameter', '400')
    assert status == (0 if 'refined   yes' in out else NOT_REFINED), err
    circle_line = [line for line in out.splitlines() if line.startswith('circle ')]
    assert len(circle_line) == 1 and 'diameter 44' in circle_line[0], out
    warnings = [line for line in err.splitlines() if '--circle-diameter 400' in line]
    assert len(warnings) == 1 and warnings[0].startswith('zeroshot-calib: warning: ') and 'differs' in warnings[0]


@pytest.mark.parametrize('fade_px, given, warned', [(20, False, True), (0, False, False), (20, True, False)])
def test_a_measured_diameter_on_a_soft_rim_is_warned_about(tmp_path, capsys, fade_px, given, warned):
    """`--circle-fov` with the diameter measured on a rim whose light fades softly: one warning that
    the scale is put where the light falls steepest and that a spec's circle may be where it ends
    (real circular fisheyes: 3-4 % of the radius further out, 11-12 % of f); none on a sharp rim,
    none when the diameter is given."""
    from scenes import soft_rim
    path = tmp_path / 'rim.png'
    cv2.imwrite(str(path), soft_rim(fade_px))
    flags = ['--circle-fov', '185'] + (['--circle-diameter', '440'] if given else [])
    status, out, err = run(capsys, str(path), *flags)
    assert status in (0, NOT_REFINED), err
    lines = [line for line in err.splitlines() if 'rim fades softly' in line]
    assert len(lines) == (1 if warned else 0), err
    if warned:
        assert lines[0].startswith('zeroshot-calib: warning: ') and 'give --circle-diameter' in lines[0]


@pytest.mark.parametrize('flags, warned', [(['--hfov', '190'], 'hfov 190 (to the left and right edges)'),
                                            (['--dfov', '190'], 'dfov 190 (to the corners)'),
                                            (['--circle-fov', '190'], None)])
def test_a_fov_stated_across_the_dark_past_the_image_circle_is_warned_about(circular_view, capsys, flags, warned):
    """A circular fisheye's one figure (its FOV across the image circle) given as hfov or dfov: the
    edges those are measured to lie past the image circle seen, where nothing is imaged. One warning
    line on stderr and in --json says so, and to give circle_fov; none with --circle-fov. What it
    warns of (cli.md): given as hfov or dfov, the camera is tens of px from the truth inside its
    circle at many times its error bar (46 and 58 px, 14 and 11 times, measured); as circle_fov,
    within a px or two (0.83)."""
    from test_refine import best_rotation_rms
    from zeroshot_calib_ros.core.estimation.uncertainty import pixel_grid
    status, out, err = run(capsys, circular_view, *flags, '--json')
    assert status in (0, NOT_REFINED), err
    record = json.loads(out)
    truth = circular_190()
    K, D = np.array(record['K']), np.array(record['D'])
    camera = KannalaBrandtCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], 640, 480, D)
    inside = pixel_grid(640, 480, circle_radius=truth.circle_radius, circle_centre=(truth.cx, truth.cy))
    error = best_rotation_rms(camera, truth, pixels=inside)
    lines = [line for line in err.splitlines() if 'nothing is imaged there' in line]
    in_json = [w for w in record['warning'] if 'nothing is imaged there' in w]
    if warned is None:
        assert lines == [] and in_json == [], err
        assert error < 2.0
        return
    assert error > 20.0 and error > 5 * record['uncertainty_px'], (error, record['uncertainty_px'])
    assert len(lines) == 1 and lines[0].startswith('zeroshot-calib: warning: ' + warned), err
    assert 'give that as circle_fov (--circle-fov)' in lines[0] and '(440 px across)' in lines[0], lines[0]
    assert in_json == [lines[0][len('zeroshot-calib: warning: '):]]


def lit_disc(width=640, height=480, cx=326.0, cy=236.0, radius=220.0, seed=0):
    """A circular fisheye's image of a featureless scene: a lit disc in a dark, noisy surround (no
    line to refine from)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:height, :width]
    image = np.where(np.hypot(xx - cx, yy - cy) <= radius, 150.0, 12.0) + rng.normal(0, 2, (height, width))
    return np.clip(cv2.GaussianBlur(image.astype(np.float32), (0, 0), 1.0), 0, 255).astype(np.uint8)


def test_a_fov_stated_across_the_dark_is_warned_about_when_refine_refuses_too(tmp_path, capsys):
    """The warning is about the spec, not the fit: said when no line is found and zero-shot is
    returned (refused: too few lines), on stderr and in --json."""
    path = tmp_path / 'disc.png'
    cv2.imwrite(str(path), lit_disc())
    status, out, err = run(capsys, str(path), '--dfov', '190', '--json')
    record = json.loads(out)
    assert status == NOT_REFINED and not record['refinement']['accepted'], err
    assert [w for w in record['warning'] if w.startswith('dfov 190 (to the corners)')], record['warning']
    assert len([line for line in err.splitlines() if 'nothing is imaged there' in line]) == 1, err


def test_a_spec_whose_fovs_are_all_imaged_is_not_warned_about_the_dark(views, capsys):
    """No image circle in the images (a full-frame lens): no FOV is past one."""
    status, out, err = run(capsys, *views[:2], *SPEC_FLAGS, '--json')
    assert status in (0, NOT_REFINED), err
    assert not any('nothing is imaged there' in w for w in json.loads(out)['warning']), err


def test_circle_fov_without_a_circle_in_the_images_is_one_error_line(views, capsys):
    status, out, err = run(capsys, views[0], '--circle-fov', '190')
    assert status == 2 and out == ''
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('zeroshot-calib: error: ') and '--circle-diameter' in lines[0]
    assert 'circle' in lines[0] and 'found' in lines[0]


@pytest.mark.parametrize('value', ['0', '-5', '400'])
def test_an_invalid_circle_fov_is_named_before_any_circle_is_looked_for(views, capsys, value):
    """A circle FOV out of range is the field the error names, whether or not the images show a
    circle (not "needs the image circle's diameter")."""
    status, out, err = run(capsys, views[0], '--circle-fov', value)
    assert status == 2 and out == ''
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('zeroshot-calib: error: circle_fov = '), lines
    assert 'allowed: degrees, at least 0.01 and less than' in lines[0], lines


def test_refine_reports_progress_to_its_callback_and_the_result_is_the_same(views):
    from zeroshot_calib_ros.core.estimation.refine import refine_from_images
    images = [cv2.imread(p, cv2.IMREAD_GRAYSCALE) for p in views[:2]]
    spec = CameraSpec(640, 360, hfov=172, vfov=97, dfov=198)
    reports = []
    with_callback = refine_from_images(spec, images, progress=reports.append)
    without = refine_from_images(spec, images)
    assert (with_callback.accepted, with_callback.reason) == (without.accepted, without.reason)
    # the same camera; not to the last digit: with Ubuntu 24.04's numpy 1.26 on a CPU with AVX-512,
    # two runs of the same refinement differ by 1e-6 to 1e-3 of f (its SIMD kernels round by alignment)
    np.testing.assert_allclose(with_callback.camera.K, without.camera.K, rtol=1e-2)
    np.testing.assert_allclose(with_callback.camera.D, without.camera.D, rtol=1e-2, atol=1e-4)
    stages = [(r.stage, r.round, r.frames_done) for r in reports]
    fits = [k for k, r in enumerate(reports) if r.stage == 'fit']
    # each round: one report per image, then one for the fit
    assert stages[:3] == [('detection', 1, 1), ('detection', 1, 2), ('fit', 1, 2)], stages
    assert len(fits) in (1, 2) and fits[-1] == len(reports) - 1
    assert all(r.frames == 2 and r.rounds == 2 for r in reports)
    assert 0 < reports[0].lines <= reports[1].lines  # curves so far in the round
    assert reports[2].lines > 0  # the lines the first fit used
    assert reports[-1].lines == without.lines_used and reports[-1].accepted == without.accepted
    assert reports[0].camera.fx > 0 and 0 < reports[0].camera.cx < 640 and 0 < reports[0].camera.cy < 360


def test_progress_is_silent_on_a_pipe_and_shown_with_the_flag(views, capsys, monkeypatch):
    status, quiet, err = run(capsys, *views[:2], *SPEC_FLAGS, '--json')
    assert status == 0, err
    assert 'refine round' not in err
    # the refinement of this run is recorded (run as usual, its reports kept) for the terminal runs below
    from zeroshot_calib_ros.core.estimation import refine as refine_module
    refinement = RecordedComputation(monkeypatch, refine_module, 'refine_from_images')
    refinement.record()
    status, shown, err = run(capsys, *views[:2], *SPEC_FLAGS, '--json', '--progress')
    assert status == 0, err
    assert len(refinement.calls) == 1, 'the CLI ran refine_from_images once, through its module'
    # progress changes nothing (to 1e-2: runs differ by up to 1e-3 with numpy 1.26 on AVX-512, cli_run.same_result)
    assert same_result(json.loads(shown), json.loads(quiet), rel=1e-2)
    lines = [line for line in err.splitlines() if line.startswith('zeroshot-calib: refine round ')]
    # not a terminal: one line per report, no carriage returns
    assert '\r' not in err and len(lines) >= 3, err
    assert lines[0].startswith('zeroshot-calib: refine round 1/2: 1/2 images, ') and 'lines found' in lines[0]
    assert 'f ' in lines[0] and 'principal point (' in lines[0]
    assert any('fitted' in line for line in lines)
    # a round's fit is not the verdict (a later round may return another): it passes or fails the gate
    fitted = [line for line in lines if 'fitted' in line]
    assert all(line.endswith(('(passes the gate)', '(fails the gate)')) for line in fitted), fitted
    # a terminal: shown without the flag, one line rewritten in place; --json keeps it quiet. What
    # is printed where is the CLI's; the refinement (its result, its reports) is the one above,
    # replayed: the same reports to whatever callback the CLI passes (test_refine_reports_progress_
    # to_its_callback_and_the_result_is_the_same: a callback changes nothing in it)
    refinement.replay()
    import zeroshot_calib_ros.cli.output as cli
    monkeypatch.setattr(cli, '_is_terminal', lambda stream: True)
    status, out, err = run(capsys, *views[:2], *SPEC_FLAGS, '--json')
    assert status == 0 and 'refine round' not in err, err
    status, out, err = run(capsys, *views[:2], *SPEC_FLAGS)
    assert status == 0, err
    assert err.startswith('\rzeroshot-calib: refine round 1/2: 1/2 images') and err.count('\r') >= 3, err
    assert '\n' in err and 'fitted' in err.split('\n')[0]
    assert refinement.replayed == 2


def test_a_soft_rim_is_measured_with_its_width_and_a_spec_diameter_across_it_is_not_warned_about(tmp_path, capsys):
    """A circular fisheye whose light fades to black over its last 20 px (as real ones do): the
    diameter the images give (near the middle of the fade) is printed with an uncertainty that
    reaches the rim's outer edge, so the spec's diameter of that outer edge is not said to
    disagree; one far off still is."""
    path = tmp_path / 'soft_rim.png'
    cv2.imwrite(str(path), soft_rim(20, radius=220.0))
    status, out, err = run(capsys, str(path), '--circle-fov', '190', '--circle-diameter', '440', '--json')
    circle = json.loads(out)['image_circle']
    assert 2 * circle['diameter_sigma_px'] >= 440 - circle['diameter'] > 0, circle
    assert 'differs' not in err, err
    status, out, err = run(capsys, str(path), '--circle-fov', '190', '--circle-diameter', '330', '--json')
    warnings = [line for line in err.splitlines() if '--circle-diameter 330' in line and 'differs' in line]
    assert len(warnings) == 1, err
    # the warning states the same uncertainty as the record (the rim's width included)
    sigma = json.loads(out)['image_circle']['diameter_sigma_px']
    assert f"{json.loads(out)['image_circle']['diameter']:.1f} +- {sigma:.1f} px" in warnings[0], (warnings, sigma)
