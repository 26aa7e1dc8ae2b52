"""`--report OUT.png` (solve, refine, calibrate) and `refine --debug-image`, read as a user reads
them: the panels are there and drawn on, the error map is brighter (a higher error) where the
calibration is less certain, the verdict is written in its colour, the contact sheet has one
panel per image showing that image; a bad --report path is one error line before any work.

The pictures are found by what a user sees (the panel frames, the label bars, the colour map of
the colour bar), with the layout constants of core/report (test/pictures.py). Modules tested here:
core/report/calibration_report.py, canvas.py, debug_sheet.py, synthetic.py (the solve report's preview).
"""
import json
import math

import cv2
import numpy as np
import pytest

import pictures
from cli_run import run_main
from scenes import render
from test_cli_refine import SPEC_FLAGS, TRUE
from zeroshot_calib_ros.core.estimation.uncertainty import uncertainty_map, zero_shot_uncertainty
from zeroshot_calib_ros.core.report import canvas, debug_sheet
from zeroshot_calib_ros.core.zeroshot.solver import solve_zero_shot
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

def exact(image, colour):
    return int(np.sum(np.all(image == np.array(colour), axis=2)))


def near(image, colour, tolerance=35):
    """Pixels within ``tolerance`` of ``colour`` on every channel: text in that colour (its
    anti-aliased strokes, whatever font this OpenCV draws with), not its blend with the paper."""
    return int(np.sum(np.all(np.abs(image.astype(int) - np.array(colour)) <= tolerance, axis=2)))


def verdict(picture):
    """'accepted' / 'refused' / None: the colour the verdict is written in."""
    green, red = near(picture, canvas.GREEN), near(picture, canvas.RED)
    if green > 30 and red == 0:
        return 'accepted'
    if red > 30 and green == 0:
        return 'refused'
    return None if green == red == 0 else (green, red)


def read(path):
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert image is not None and image.ndim == 3 and image.shape[2] == 3, path
    return image


def one_error_line(status, err, *words):
    assert status == 2 and len(err) == 1 and err[0].startswith('zeroshot-calib: error: '), err
    for word in words:
        assert word in err[0], err


# -- solve ------------------------------------------------------------------------------------------

def test_solve_report_has_the_lens_curve_the_error_map_and_a_rectified_preview(tmp_path, capsys):
    path = tmp_path / 'report.png'
    status, out, err = run_main(['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69',
                                 '--report', str(path)], capsys)
    assert status == 0, err
    assert f'wrote {path}' in out
    image = read(path)
    assert image.shape[1] == 1440 and 400 < image.shape[0] < 900
    panels = pictures.report_panels(image)
    assert [len(panels[c]) for c in range(3)] == [1, 1, 1], panels
    tops = {p[0][1] for p in panels.values()}
    assert len(tops) == 1, 'the three panels side by side'
    lens, errors, preview = (panels[c][0] for c in range(3))
    for rect in (lens, errors, preview):
        assert pictures.is_drawn_on(pictures.region(image, rect))
    # the lens curve and the two FOVs of the spec, marked against it
    assert exact(pictures.region(image, lens), canvas.BLUE) > 300
    assert exact(pictures.region(image, lens), canvas.ORANGE) > 60
    # the error map fills most of its panel's width (the colour bar beside it)
    index, (x, y, w, h) = pictures.error_map(image, errors)
    assert w > 0.6 * errors[2] and abs(w / h - 1920 / 1080) < 0.05
    # the title, above the panels: nothing accepted or refused, so neither verdict colour
    title = image[:lens[1]]
    assert pictures.is_drawn_on(title, 0.005)
    assert verdict(title) is None


def test_the_error_map_is_higher_at_the_corners_of_a_one_fov_solve(tmp_path, capsys):
    """One FOV pins the radius at one place only (W/2 at hfov/2): the lens shape is open, so the
    error is small at the principal point (a rotation absorbs it) and grows towards the corners,
    past the pinned radius; the colour bar of the picture tells which is higher."""
    path = tmp_path / 'one_fov.png'
    status, _, err = run_main(['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--report',
                               str(path)], capsys)
    assert status == 0, err
    image = read(path)
    panels = pictures.report_panels(image)
    index, (x, y, w, h) = pictures.error_map(image, panels[1][0])
    k = max(3, w // 40)  # patches about 50 image pixels across
    centre = index[h // 2 - k // 2:h // 2 + k // 2 + 1, w // 2 - k // 2:w // 2 + k // 2 + 1]
    corners = [index[:k, :k], index[:k, -k:], index[-k:, :k], index[-k:, -k:]]
    centre = np.median(centre[centre >= 0])
    for corner in corners:  # colour-bar places, 0 to 255: over a third of the bar higher
        assert np.median(corner[corner >= 0]) > centre + 90, (np.median(corner[corner >= 0]), centre)


@pytest.mark.parametrize('spec', [CameraSpec(1920, 1080, hfov=118, vfov=69), CameraSpec(1920, 1080, hfov=118),
                                  CameraSpec(1280, 960, circle_diameter=900, circle_fov=190)],
                         ids=['two FOVs', 'one FOV', 'circle'])
def test_the_error_map_is_uncertainty_px_pixel_by_pixel(spec):
    """The map's RMS over the grid is the error bar `solve` reports (uncertainty_px)."""
    u = zero_shot_uncertainty(spec, 1.0, solve_zero_shot(spec, 'auto'))
    emap = uncertainty_map(u)
    assert emap.rms_px == pytest.approx(u.rms_px, rel=1e-3)
    if spec.circle_diameter is not None:  # stated over the image circle only
        assert np.isnan(emap.sigma_px[0, 0]) and np.isfinite(emap.sigma_px[9, 16])


def test_the_board_fit_error_map_is_its_uncertainty_px():
    from test_board_fit import TRUTH, board_views, true_spec
    from zeroshot_calib_ros.core.estimation.board_fit import fit_board
    corners, _ = board_views(TRUTH, 3, seed=3, noise=0.2)
    fit = fit_board(corners, true_spec())
    emap = uncertainty_map(fit.uncertainty)
    assert fit.uncertainty_px is not None
    assert emap.rms_px == pytest.approx(fit.uncertainty_px, rel=0.02)


# -- bad --report: one line, before any work -----------------------------------------------------

@pytest.mark.parametrize('command', [
    ['solve', '--width', '1920', '--height', '1080', '--hfov', '118'],
    ['refine', 'no-such-image.png', '--hfov', '118'],
    ['calibrate', '--corners', 'no-such-corners.json', '--hfov', '118'],
], ids=['solve', 'refine', 'calibrate'])
@pytest.mark.parametrize('target, words', [
    ('report.jpg', ('--report', 'report.jpg', '.png')),
    ('report', ('--report', '.png')),
    ('no-such-directory/report.png', ('--report', 'does not exist')),
    ('.', ('--report', 'directory')),
], ids=['jpg', 'no extension', 'missing directory', 'a directory'])
def test_a_bad_report_path_is_one_error_line_before_any_work(tmp_path, capsys, monkeypatch, command, target, words):
    monkeypatch.chdir(tmp_path)
    yaml_path = tmp_path / 'out.yaml'
    status, out, err = run_main([*command, '--yaml', str(yaml_path), '--report', target], capsys)
    one_error_line(status, err, *words)
    assert out == '' and not yaml_path.exists()
    assert not any(p.suffix == '.png' for p in tmp_path.rglob('*'))


def test_report_cannot_be_combined_with_batch(tmp_path, capsys):
    csv = tmp_path / 'cameras.csv'
    csv.write_text('a,1920,1080,118,69\n')
    status, out, err = run_main(['solve', '--batch', str(csv), '--report', str(tmp_path / 'r.png')], capsys)
    one_error_line(status, err, '--report', '--batch')


# -- calibrate --------------------------------------------------------------------------------------

@pytest.fixture(scope='module')
def board_corners(tmp_path_factory):
    from test_board_fit import TRUTH, board_views, true_spec
    corners, _ = board_views(TRUTH, 3, seed=3, noise=0.2)
    path = tmp_path_factory.mktemp('corners') / 'kb_corners.json'
    corners.save(str(path))
    spec = true_spec()
    return path, ['--hfov', repr(spec.hfov), '--vfov', repr(spec.vfov)]


def _bars(panel_picture):
    """The filled bars of a bar chart: saturated, bright areas larger than any text."""
    hsv = cv2.cvtColor(panel_picture, cv2.COLOR_BGR2HSV)
    mask = ((hsv[..., 1] > 90) & (hsv[..., 2] > 90)).astype(np.uint8)
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4)
    return [s for s in stats[1:] if s[cv2.CC_STAT_AREA] > 1000]


def test_calibrate_report_adds_the_board_coverage_and_a_bar_per_image(board_corners, tmp_path, capsys):
    path, spec_args = board_corners
    report = tmp_path / 'calibrate.png'
    status, out, err = run_main(['calibrate', '--corners', str(path), *spec_args, '--json', '--report', str(report)],
                                capsys)
    assert status == 0, err
    record = json.loads(out)
    image = read(report)
    panels = pictures.report_panels(image)
    # two rows: lens | error map | preview, then coverage | the residuals across two columns
    assert [len(panels[c]) for c in range(3)] == [2, 2, 1], panels
    coverage, residuals = panels[0][1], panels[1][1]
    assert coverage[1] == residuals[1] > panels[0][0][1]
    for rect in (*panels[0], *panels[1], *panels[2]):
        assert pictures.is_drawn_on(pictures.region(image, rect))
    # the residual panel spans the second and third columns, with one bar per view
    residual_picture = image[residuals[1]:residuals[1] + residuals[3], residuals[0]:1440 - 16]
    bars = _bars(residual_picture)
    assert len(bars) == 3, [tuple(b) for b in bars]
    assert len({tuple(residual_picture[s[1] + s[3] // 2, s[0] + s[2] // 2]) for s in bars}) == 3  # a colour a view
    # each view's colour is on the coverage panel too
    cover = pictures.region(image, coverage)
    for s in bars:
        colour = residual_picture[s[1] + s[3] // 2, s[0] + s[2] // 2]
        assert exact(cover, colour) > 20
    # the verdict in its colour: accepted in green, or refused in red, as --json says
    title = image[:panels[0][0][1]]
    assert verdict(title) == ('accepted' if record['accepted'] else 'refused')


def test_calibrate_without_a_spec_has_no_error_map_and_no_fov_marks(board_corners, tmp_path, capsys):
    path, _ = board_corners
    report = tmp_path / 'fc.png'
    status, out, err = run_main(['calibrate', '--corners', str(path), '--single', 'view-00.png', '--report',
                                 str(report)], capsys)
    assert status == 0, err
    image = read(report)
    panels = pictures.report_panels(image)
    mask, _ = pictures.colormap_indices(pictures.region(image, panels[1][0]))
    assert mask.sum() < 50, 'FC_eq.d. states no error bar: nothing to map'
    assert exact(pictures.region(image, panels[0][0]), canvas.ORANGE) == 0, 'no spec: no FOV marks'
    # one view used of three: the other two bars are grey
    residuals = panels[1][1]
    bars = _bars(image[residuals[1]:residuals[1] + residuals[3], residuals[0]:1440 - 16])
    assert len(bars) == 1


# -- refine: the report and the contact sheet -------------------------------------------------------

@pytest.fixture(scope='module')
def views(tmp_path_factory):
    directory = tmp_path_factory.mktemp('views')
    paths, images = [], []
    for i, (scene, seed) in enumerate([('room', 1), ('corridor', 2), ('street', 3)]):
        image, _ = render(TRUE, scene, seed=seed)
        path = directory / f'view{i}.png'
        cv2.imwrite(str(path), image)
        paths.append(str(path))
        images.append(image)
    return paths, images


@pytest.fixture(scope='module')
def refined(views, tmp_path_factory):
    """One refine of the three views with --report and --debug-image, --json."""
    paths, _ = views
    directory = tmp_path_factory.mktemp('refined')
    report, sheet = directory / 'report.png', directory / 'debug.png'
    from zeroshot_calib_ros.cli import main
    import contextlib
    import io
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status = main(['refine', *paths, *SPEC_FLAGS, '--json', '--report', str(report), '--debug-image', str(sheet)])
    assert status == 0
    return json.loads(out.getvalue()), read(report), read(sheet)


def test_refine_report_shows_the_first_image_rectified_and_the_verdict(views, refined):
    record, image, _ = refined
    _, images = views
    assert record['refinement']['accepted'] is True, record['refinement']['reason']
    panels = pictures.report_panels(image)
    assert [len(panels[c]) for c in range(3)] == [1, 1, 1]
    for c in range(3):
        assert pictures.is_drawn_on(pictures.region(image, panels[c][0]))
    # the lens panel: the refined camera, the three FOVs of the spec marked
    lens = pictures.region(image, panels[0][0])
    assert exact(lens, canvas.BLUE) > 300 and exact(lens, canvas.ORANGE) > 90
    pictures.error_map(image, panels[1][0])
    assert verdict(image[:panels[0][0][1]]) == 'accepted'
    # the preview is rectified with the P written, around the refined principal point: not one
    # side of this 172-degree lens under a red "off the image" note (OpenCV's rule would be)
    assert exact(pictures.region(image, panels[2][0]), canvas.RED) == 0


def test_the_contact_sheet_has_a_labelled_panel_per_image_showing_it(views, refined):
    _, images = views
    record, _, sheet = refined
    h, w = images[0].shape[:2]
    panels = pictures.sheet_panels(sheet, h / w)
    assert len(panels) == 3
    for (x, y, pw, ph), image in zip(panels, images):  # in the order given
        picture = sheet[y:y + ph, x:x + pw]
        assert pictures.shows(picture, image) > 0.8
        # the curves the fit used, in green, on every image (each image has straight lines)
        green = (picture[..., 1] > 150) & (picture[..., 0] < 80) & (picture[..., 2] < 80)
        assert green.sum() > 100
    # with the verdict above them, in green for an accepted refinement
    assert verdict(sheet[:panels[0][1] - debug_sheet.LABEL_H]) == 'accepted'
    # and the total size stays reasonable
    assert sheet.shape[1] <= debug_sheet.MAX_WIDTH and sheet.shape[0] <= debug_sheet.MAX_HEIGHT


def test_a_refused_refine_says_so_in_red_on_both_pictures(tmp_path, capsys):
    path = tmp_path / 'black.png'
    cv2.imwrite(str(path), np.zeros((360, 640), np.uint8))
    report, sheet = tmp_path / 'report.png', tmp_path / 'debug.png'
    status, out, err = run_main(['refine', str(path), *SPEC_FLAGS, '--report', str(report), '--debug-image',
                                 str(sheet)], capsys)
    assert status == 3, err  # ran, but kept the zero-shot camera (docs/cli_output.md)
    assert out.splitlines()[-1] == f'wrote {report}'
    image = read(report)
    panels = pictures.report_panels(image)
    assert verdict(image[:panels[0][0][1]]) == 'refused'
    pictures.error_map(image, panels[1][0])  # zero-shot's error bar, mapped
    debug = read(sheet)
    sheet_panels = pictures.sheet_panels(debug, 360 / 640)
    assert len(sheet_panels) == 1
    assert verdict(debug[:sheet_panels[0][1] - debug_sheet.LABEL_H]) == 'refused'


def test_the_contact_sheet_scales_many_images_to_a_reasonable_size():
    """24 images of 800 x 503: every one gets a panel, the sheet stays within its bounds."""
    from types import SimpleNamespace
    from zeroshot_calib_ros.core.zeroshot.solver import solve_zero_shot
    rng = np.random.default_rng(0)
    images = [cv2.GaussianBlur(rng.integers(0, 256, (503, 800), dtype=np.uint8), (0, 0), 3) for _ in range(24)]
    camera = solve_zero_shot(CameraSpec(800, 503, hfov=180.81, vfov=103.52)).camera
    from zeroshot_calib_ros.core.estimation.refine import zero_shot_camera
    kb = zero_shot_camera(CameraSpec(800, 503, hfov=180.81, vfov=103.52), 800, 503)
    result = SimpleNamespace(curves=[], used=np.zeros(0, bool), static_curves=[], accepted=False,
                             reason='too few lines', camera=kb)
    sheet = debug_sheet.render_debug_sheet(images, [f'left-{i:04d}.png' for i in range(24)], result, camera).image
    assert sheet.shape[1] <= debug_sheet.MAX_WIDTH and sheet.shape[0] <= debug_sheet.MAX_HEIGHT
    panels = pictures.sheet_panels(sheet, 503 / 800)
    assert len(panels) == 24
    for (x, y, pw, ph), image in zip(panels, images):
        assert pictures.shows(sheet[y:y + ph, x:x + pw], image) > 0.9
    assert math.prod(sheet.shape[:2]) < 1600 * 2000


def test_the_concrete_commands_of_docs_report_md_run_and_write_their_pictures(tmp_path, capsys, monkeypatch):
    """docs/report.md's commands without placeholders, run as written (in an empty directory)."""
    import re
    import shlex
    from pathlib import Path
    text = (Path(__file__).resolve().parents[3] / 'docs' / 'report.md').read_text()
    blocks = re.findall(r'```\n(.*?)```', text, re.S)
    commands = [line for block in blocks for line in block.splitlines() if line.startswith('zeroshot-calib ')]
    concrete = [c for c in commands if not re.search(r'\bIMG\b|\bH\b|\bV\b|images/', c)]
    assert concrete, commands
    monkeypatch.chdir(tmp_path)
    for command in concrete:
        argv = shlex.split(command)[1:]
        status, out, err = run_main(argv, capsys)
        assert status == 0, (command, err)
        target = argv[argv.index('--report') + 1]
        assert (tmp_path / target).is_file() and f'wrote {target}' in out


@pytest.mark.parametrize('width', [752, 1280])
def test_the_contact_sheets_legend_is_never_cut_at_its_edge(width):
    """One 752 x 480 image makes a sheet 776 px wide, narrower than the legend's three entries in
    one row: the legend goes on in a second row instead of running off the sheet (its last entry
    read "left out: stayed put across the i"). Nothing is drawn in the right margin of the header."""
    from types import SimpleNamespace
    from zeroshot_calib_ros.core.estimation.refine import zero_shot_camera
    height = width * 480 // 752
    spec = CameraSpec(width, height, hfov=121.4, vfov=76.0)
    kb = zero_shot_camera(spec, width, height)
    image = np.full((height, width), 128, np.uint8)
    result = SimpleNamespace(curves=[], used=np.zeros(0, bool), static_curves=[], accepted=False,
                             reason='too few lines', camera=kb)
    sheet = debug_sheet.render_debug_sheet([image], ['left_fisheye_img_0.png'], result, kb).image
    panels = pictures.sheet_panels(sheet, height / width)
    header = sheet[:panels[0][1] - debug_sheet.LABEL_H]
    ink = np.any(header != np.array(canvas.PAPER, np.uint8), axis=2)
    columns = np.nonzero(ink.any(axis=0))[0]
    assert columns.max() < sheet.shape[1] - debug_sheet.MARGIN // 2, (columns.max(), sheet.shape[1])
    # all three entries are drawn: their strokes' colours are in the header
    for colour in (canvas.CURVE_USED, canvas.CURVE_REJECTED, canvas.CURVE_STATIC):
        assert np.all(header == np.array(colour, np.uint8), axis=2).sum() > 20, colour


def test_the_title_states_the_error_bar_as_the_cli_does_with_its_lens_shape_part():
    """The report's title line gives the error bar in the CLI's words (``error_bar_text``): after the
    best rotation, and for one FOV the spread of real lens shapes that is most of it (the title once
    read "FOVs +- 1 deg" alone for a bar 18.6 of whose 19.4 px were the lens shapes')."""
    from zeroshot_calib_ros.core.estimation.uncertainty import error_bar_text, zero_shot_uncertainty
    from zeroshot_calib_ros.core.report.calibration_report import ReportData, _title_lines
    from zeroshot_calib_ros.core.zeroshot.solver import solve_zero_shot
    from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec
    spec = CameraSpec(752, 480, hfov=93.1)
    solution = solve_zero_shot(spec)
    u = zero_shot_uncertainty(spec, solution=solution)
    assert u.lens_shape_px is not None and u.lens_shape_px > 0.5 * u.rms_px
    data = ReportData('solve', solution.camera, 'equidistant', None, '', spec, 1.0, u, u.rms_px, u.reason)
    text = ' '.join(line[0] for line in _title_lines(data, 1600))
    assert error_bar_text(u.rms_px, 1.0, 'image', u.lens_shape_px, '.3g') in text, text
    assert 'after the best rotation' in text and f'lens shapes of that FOV, {u.lens_shape_px:.3g} px of it' in text
    # images at twice the spec's size: the bar and its lens-shape part both in the images' pixels
    doubled = ReportData('refine', solution.camera, 'equidistant', False, 'x', spec, 1.0, u, 2 * u.rms_px, u.reason)
    text = ' '.join(line[0] for line in _title_lines(doubled, 1600))
    assert f'lens shapes of that FOV, {2 * u.lens_shape_px:.3g} px of it' in text, text
