"""The zeroshot-calib command line, as a user without ROS runs it: cli/command.py, the shared
options of cli/arguments.py, and the verbs whose own test files do not cover them (solve,
rectify, evaluate)."""
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from paper_table2 import load_table2
from cli_run import run_main
from zeroshot_calib_ros.cli import main

SUMMARY_KEYS = {'width', 'height', 'model', 'omega', 'f', 'cx', 'cy', 'K', 'distortion_model', 'D',
                'fit_error_px', 'hfov', 'vfov', 'dfov'}


def test_solve_prints_a_readable_summary(capsys):
    assert main(['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69']) == 0
    out = capsys.readouterr().out
    assert 'f         875.9867 px' in out and 'equidistant' in out


def test_solve_json(capsys):
    assert main(['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69', '--json']) == 0
    record = json.loads(capsys.readouterr().out)
    assert SUMMARY_KEYS <= set(record)
    assert record['distortion_model'] == 'equidistant' and len(record['D']) == 4
    assert record['f'] == pytest.approx(876.0, abs=0.05) and record['omega'] == pytest.approx(0.001019, abs=5e-7)
    assert np.array(record['K']).shape == (3, 3)
    assert record['hfov'] == pytest.approx(118) and record['vfov'] == pytest.approx(69)


def test_solve_writes_yaml(tmp_path, capsys):
    path = tmp_path / 'cam.yaml'
    assert main(['solve', '--width', '1280', '--height', '720', '--hfov', '130', '--vfov', '73',
                 '--camera-name', 'm2026', '--yaml', str(path)]) == 0
    data = yaml.safe_load(path.read_text())
    assert data['camera_name'] == 'm2026' and data['image_width'] == 1280


def test_batch_reports_bad_rows_and_goes_on(tmp_path, capsys):
    csv_path = tmp_path / 'cams.csv'
    csv_path.write_text('name,width,height,hfov,vfov,dfov\n'
                        'w1,1920,1080,118,69,\n'
                        'broken,1920,1080,-5,69,\n'
                        'c905,1280,720,63.1,,\n'
                        'typo,1280,72O,90,60,\n')
    yaml_dir = tmp_path / 'yaml'
    assert main(['solve', '--batch', str(csv_path), '--yaml-dir', str(yaml_dir)]) == 1
    out, err = capsys.readouterr()
    lines = [json.loads(line) for line in out.splitlines()]
    assert [r['name'] for r in lines] == ['w1', 'broken', 'c905', 'typo']
    assert 'error' not in lines[0] and lines[0]['f'] == pytest.approx(876.0, abs=0.05)
    assert lines[1]['row'] == 2 and 'hfov = -5.0' in lines[1]['error']
    # one FOV: the lens shape of real lenses of that FOV, said in the record (a narrow lens: nearly a pinhole)
    assert lines[2]['f'] == pytest.approx(1042.3, rel=0.01) and lines[2]['assumption'].startswith('one FOV')
    assert lines[2]['assumption'] in lines[2]['warning']
    assert "height = '72O'" in lines[3]['error']
    assert not yaml_dir.exists(), 'no file is written while a row fails (so a fixed rerun gives the whole set)'
    assert 'no files written' in err


def test_rectify_an_image_file(tmp_path):
    src, dst = tmp_path / 'in.png', tmp_path / 'out.png'
    cv2.imwrite(str(src), np.full((360, 640, 3), 200, np.uint8))
    assert main(['rectify', str(src), '-o', str(dst), '--hfov', '118', '--vfov', '69', '--balance', '1']) == 0
    out = cv2.imread(str(dst))
    assert out.shape == (360, 640, 3) and out[180, 320].tolist() == [200, 200, 200]
    assert out[0, 320].tolist() == [0, 0, 0]  # balance 1 keeps the whole width: black above the top edge
    assert main(['rectify', str(src), '-o', str(dst), '--width', '1000', '--height', '1000', '--hfov', '90']) == 2


@pytest.mark.parametrize('args, message', [
    (['--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', 'nan'], 'vfov = nan is invalid'),
    (['--width', '0', '--height', '1080', '--hfov', '118'], 'width = 0 is invalid'),
    (['--width', '1920', '--height', '1080'], 'at least one of hfov, vfov, dfov'),
    # a value not given is named as missing, not as "= None" (which reads as a value given)
    (['--width', '748', '--height', '480', '--circle-fov', '185'],
     'circle_diameter is not given: the circular-fisheye form needs both'),
    (['--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69', '--balance', '2'],
     'balance = 2.0 is invalid: allowed: 0 to 1'),
])
def test_errors_exit_2_with_one_line_and_no_traceback(args, message):
    run = subprocess.run([sys.executable, '-m', 'zeroshot_calib_ros.cli', 'solve', *args],
                         capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2])
    assert run.returncode == 2
    assert run.stdout == ''
    assert len(run.stderr.strip().splitlines()) == 1 and message in run.stderr
    assert 'Traceback' not in run.stderr


# -- hardening: each test below failed on the CLI before the change it covers --------------------

HERO9 = 'w1,1920,1080,118,69,\n'  # the paper's Table 2: f = 876.0 px for the GoPro HERO9 (W1)




def one_line_error(status, err, *words):
    assert status == 2, err
    assert len(err) == 1 and err[0].startswith('zeroshot-calib'), err
    for word in words:
        assert word in err[0], (word, err)


def batch(tmp_path, text, *extra, encoding='utf-8'):
    path = tmp_path / 'cams.csv'
    path.write_bytes(text.encode(encoding) if isinstance(text, str) else text)
    return ['solve', '--batch', str(path), *extra]


def test_batch_misspelt_header_column_is_an_error_before_any_output(tmp_path, capsys):
    status, out, err = run_main(batch(tmp_path, 'name,width,height,hfvo,vfov,dfov\n' + HERO9), capsys)
    one_line_error(status, err, "'hfvo'", 'hfov', 'circle_fov')
    assert out == ''


@pytest.mark.parametrize('text', [
    'name,width,height,hfov,vfov,dfov\n' + HERO9,
    '\ufeffname,width,height,hfov,vfov,dfov\n' + HERO9,                     # UTF-8 BOM (Excel)
    '# cameras\n\nname,width,height,hfov,vfov,dfov\n# the HERO9\n\n' + HERO9,  # comments, blanks
    HERO9,                                                                   # no header: positional
    '\ufeff' + HERO9,
    'w1,1920.0,1080.0,118,69,\n',                                            # integral floats
    'Name, Width ,height,hfov,vfov\r\nw1,1920,1080,118,69\r\n',              # case, spaces, CRLF
    'width,height,hfov,vfov,name\n1920,1080,118,69,w1\n',                    # any column order
])
def test_batch_reads_headers_boms_comments_and_positional_rows(tmp_path, capsys, text):
    status, out, err = run_main(batch(tmp_path, text), capsys)
    assert status == 0, err
    records = [json.loads(line) for line in out.splitlines()]
    assert len(records) == 1 and records[0]['name'] == 'w1'
    assert records[0]['f'] == pytest.approx(876.0, abs=0.05)


def test_batch_row_errors_non_integral_size_and_extra_cells(tmp_path, capsys):
    text = ('name,width,height,hfov,vfov,dfov\n'
            'half,1920.5,1080,118,69,\n'
            'extra,1920,1080,118,69,,7\n' + HERO9)
    status, out, err = run_main(batch(tmp_path, text), capsys)
    assert status == 1
    half, extra, ok = [json.loads(line) for line in out.splitlines()]
    assert 'width = 1920.5' in half['error'] and half['row'] == 1 and half['line'] == 2
    assert '7 cells' in extra['error'] and '6 columns' in extra['error']
    assert ok['f'] == pytest.approx(876.0, abs=0.05)


@pytest.mark.parametrize('text', ['', '\n\n', '# only a comment\n', '\ufeff', 'name,width,height,hfov\n'])
def test_batch_without_camera_rows_is_an_error(tmp_path, capsys, text):
    status, out, err = run_main(batch(tmp_path, text), capsys)
    one_line_error(status, err, 'no camera rows')
    assert out == ''


def test_batch_not_utf8_is_one_line(tmp_path, capsys):
    status, out, err = run_main(batch(tmp_path, b'name,width\n\xff\xfe,1\n'), capsys)
    one_line_error(status, err, 'UTF-8')


def test_batch_yaml_names_stay_inside_the_directory(tmp_path, capsys):
    text = ('name,width,height,hfov,vfov\n'
            '../../etc/evil,1920,1080,118,69\n'
            f'{tmp_path / "abs"},1920,1080,118,69\n'
            f'{"x" * 300},1920,1080,118,69\n'   # used to abort the whole batch
            f'{"y" * 200},1920,1080,118,69\n'   # the longest camera_name: a shortened file name
            'w1,1920,1080,118,69\n'
            'w1,1280,720,63.1,\n'              # the same file: an error, not an overwrite
            'Cam_1,1920,1080,118,69\n'
            'CAM_1,1920,1080,118,69\n'          # the same file on a case-insensitive file system
            'last,1920,1080,118,69\n')
    out_dir = tmp_path / 'a' / 'out'  # ../../etc/evil would escape to tmp_path / 'etc'
    status, out, err = run_main(batch(tmp_path, text, '--yaml-dir', str(out_dir)), capsys)
    assert status == 1
    records = [json.loads(line) for line in out.splitlines()]
    assert [r['name'] for r in records] == ['../../etc/evil', str(tmp_path / 'abs'), 'x' * 300, 'y' * 200,
                                            'w1', 'w1', 'Cam_1', 'CAM_1', 'last']
    failed = [r['name'] for r in records if 'error' in r]
    assert failed == ['w1', 'CAM_1']  # only the collisions: any other name gives a safe file
    assert 'w1.yaml' in records[5]['error'] and 'row 5' in records[5]['error']
    assert "'Cam_1'" in records[7]['error']
    assert not out_dir.exists()  # a row failed: no file written
    text = text.replace('w1,1280,720,63.1,\n', '').replace('CAM_1,1920,1080,118,69\n', '')
    status, out, err = run_main(batch(tmp_path, text, '--yaml-dir', str(out_dir)), capsys)
    assert status == 0, err
    records = [json.loads(line) for line in out.splitlines()]
    written = sorted(p.name for p in out_dir.iterdir())
    assert len(written) == 7 and all(len(n) <= 105 for n in written)
    for record in records:
        if 'yaml' in record:
            path = Path(record['yaml']).resolve()
            assert path.parent == out_dir.resolve() and path.is_file()
            # camera_info_manager's name rule (letters, digits, _): the row name made to fit it
            camera_name = yaml.safe_load(path.read_text())['camera_name']
            assert camera_name == record['camera_name'] and re.fullmatch(r'[A-Za-z0-9_]{1,200}', camera_name)
            assert camera_name == re.sub(r'[^A-Za-z0-9_]', '_', record['name'])[:200]
    assert not (tmp_path / 'etc').exists() and not (tmp_path / 'abs.yaml').exists()


def test_batch_failed_write_is_that_rows_error_and_the_rest_go_on(tmp_path, capsys):
    not_a_dir = tmp_path / 'file'
    not_a_dir.write_text('')
    status, out, err = run_main(batch(tmp_path, HERO9 + 'c905,1280,720,63.1,,\n', '--yaml-dir',
                                      str(not_a_dir / 'sub')), capsys)
    assert status == 1
    records = [json.loads(line) for line in out.splitlines()]
    assert [r['name'] for r in records] == ['w1', 'c905']
    assert all('cannot write' in r['error'] for r in records)


@pytest.mark.parametrize('extra, option', [
    (['--hfov', '100'], '--hfov'), (['--width', '640'], '--width'), (['--yaml', 'x.yaml'], '--yaml'),
    (['--preset', 'gopro_hero9_wide'], '--preset'), (['--camera-name', 'x'], '--camera-name'),
    (['--circle-fov', '190'], '--circle-fov'),
])
def test_batch_rejects_options_it_cannot_honour(tmp_path, capsys, extra, option):
    status, out, err = run_main(batch(tmp_path, HERO9, *extra), capsys)
    one_line_error(status, err, option, '--batch')
    assert out == ''


def test_yaml_dir_needs_batch(tmp_path, capsys):
    status, out, err = run_main(['solve', '--width', '1920', '--height', '1080', '--hfov', '118',
                                 '--yaml-dir', str(tmp_path)], capsys)
    one_line_error(status, err, '--yaml-dir', '--batch')


def test_fit_warning_plumb_bob_on_a_fisheye(capsys):
    args = ['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69']
    status, out, err = run_main(args + ['--distortion-model', 'plumb_bob', '--json'], capsys)
    assert status == 0
    record = json.loads(out)
    assert record['fit_error_px'] > 5  # a polynomial in tan(theta) cannot follow a 118-degree fisheye
    assert len(record['warning']) == 1 and 'plumb_bob' in record['warning'][0]
    assert len(err) == 1 and err[0].startswith('zeroshot-calib: warning:')
    assert 'plumb_bob' in err[0] and '--distortion-model equidistant' in err[0] and ' px' in err[0]
    status, out, err = run_main(args + ['--json'], capsys)
    assert status == 0 and err == [] and json.loads(out)['warning'] == []
    status, out, err = run_main(args + ['--distortion-model', 'plumb_bob'], capsys)  # text output
    assert status == 0 and len(err) == 1 and 'warning' in err[0]


def test_fit_warning_wide_lens_equidistant(capsys):
    status, out, err = run_main(['solve', '--width', '848', '--height', '800', '--hfov', '206',
                                 '--vfov', '172', '--json'], capsys)
    assert status == 0 and len(err) == 2 and 'equidistant' in err[0]
    assert json.loads(out)['warning'] and json.loads(out)['fit_error_px'] > 10
    # issue 13: this near-square 206 x 172 degree spec (zero-shot f 838 px, true ~289) is
    # ill-conditioned, and says so with its uncertainty
    assert err[1].startswith('zeroshot-calib: warning: ill-conditioned spec (848x800, hfov 206, vfov 172)')
    assert json.loads(out)['uncertainty_px'] > 0.01 * 848 and err[1][len('zeroshot-calib: warning: '):] in \
        json.loads(out)['warning']


def test_fit_warning_threshold_is_the_core_constant():
    from zeroshot_calib_ros.core.lens.fitting import FIT_WARNING_PX
    assert FIT_WARNING_PX == 0.5


def test_version(capsys):
    from zeroshot_calib_ros import __version__
    status, out, err = run_main(['--version'], capsys)
    assert status == 0 and out.strip() == f'zeroshot-calib {__version__}'


@pytest.mark.parametrize('args, words', [
    (['solve', '--hfov', 'abc'], ['--hfov', "'abc'"]),
    (['solve', '--model', 'nope'], ['--model', 'equidistant']),
    (['frobnicate'], ['frobnicate']),
    ([], ['command']),
])
def test_usage_errors_are_one_line(capsys, args, words):
    status, out, err = run_main(args, capsys)
    one_line_error(status, err, *words)


@pytest.fixture
def small_image(tmp_path):
    path = tmp_path / 'in.png'
    cv2.imwrite(str(path), np.full((360, 640, 3), 200, np.uint8))
    return path


def test_rectify_unsupported_output_extension(tmp_path, capsys, small_image):
    for name in ('out.xyz', 'out', 'out.exr'):
        status, out, err = run_main(['rectify', str(small_image), '-o', str(tmp_path / name),
                                     '--hfov', '118', '--vfov', '69'], capsys)
        one_line_error(status, err, name, '.png')
        assert not (tmp_path / name).exists()


def test_rectify_missing_or_unreadable_input(tmp_path, capsys):
    garbage = tmp_path / 'garbage.png'
    garbage.write_bytes(b'not an image')
    for path in (tmp_path / 'missing.png', garbage, tmp_path):
        status, out, err = run_main(['rectify', str(path), '-o', str(tmp_path / 'o.png'), '--hfov', '90'],
                                    capsys)
        one_line_error(status, err, 'cannot read image')
        if path == garbage:  # what it would have to be
            assert 'allowed: an image file (PNG, JPEG' in ''.join(err), err
    status, out, err = run_main(['rectify', str(garbage), '-o', str(tmp_path / 'no' / 'dir' / 'o.png'),
                                 '--hfov', '90'], capsys)
    one_line_error(status, err, 'directory')


def write_hero9_yaml(tmp_path, capsys, name='hero9.yaml', width=1920, height=1080):
    path = tmp_path / name
    assert main(['solve', '--width', str(width), '--height', str(height), '--hfov', '118', '--vfov', '69',
                 '--yaml', str(path)]) == 0
    capsys.readouterr()
    return path


def test_rectify_with_a_calibration_file_scales_to_the_image(tmp_path, capsys):
    calib = write_hero9_yaml(tmp_path, capsys)
    image = np.zeros((270, 480), np.uint8)  # a quarter of 1920x1080: same aspect
    image[::10, :] = 255
    src = tmp_path / 'in.png'
    cv2.imwrite(str(src), image)
    a, b = tmp_path / 'a.png', tmp_path / 'b.png'
    assert run_main(['rectify', str(src), '-o', str(a), '--calibration', str(calib)], capsys)[0] == 0
    assert run_main(['rectify', str(src), '-o', str(b), '--hfov', '118', '--vfov', '69'], capsys)[0] == 0
    # the file's equidistant fit reproduces the exact model to < 0.001 px: the same rectified image
    diff = np.abs(cv2.imread(str(a), 0).astype(int) - cv2.imread(str(b), 0).astype(int))
    assert np.mean(diff) < 1.0
    other = tmp_path / 'other.png'
    cv2.imwrite(str(other), np.zeros((480, 640), np.uint8))
    status, out, err = run_main(['rectify', str(other), '-o', str(a), '--calibration', str(calib)], capsys)
    one_line_error(status, err, '640x480', '1920x1080')
    status, out, err = run_main(['rectify', str(src), '-o', str(a), '--calibration', str(calib),
                                 '--hfov', '100'], capsys)
    one_line_error(status, err, '--hfov', '--calibration')


def test_rectify_with_a_preset(tmp_path, capsys, small_image):
    out = tmp_path / 'out.png'
    status, _, err = run_main(['rectify', str(small_image), '-o', str(out), '--preset', 'gopro_hero9_wide'],
                              capsys)
    assert status == 0, err
    assert cv2.imread(str(out)).shape == (360, 640, 3)
    status, _, err = run_main(['rectify', str(small_image), '-o', str(out), '--preset', 'no_such_cam'],
                              capsys)
    one_line_error(status, err, 'preset')


def test_rectify_bad_calibration_file_is_one_line(tmp_path, capsys, small_image):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('image_width: .inf\nimage_height: 360\n')
    status, out, err = run_main(['rectify', str(small_image), '-o', str(tmp_path / 'o.png'),
                                 '--calibration', str(bad)], capsys)
    one_line_error(status, err, 'bad.yaml')


def corners_file(tmp_path):
    from test_calibration import TRUE, synthetic_corners
    path = tmp_path / 'corners.json'
    synthetic_corners(TRUE, 3).save(str(path))
    return path, TRUE.width, TRUE.height


def test_evaluate_spec_from_a_lens_that_turns_back_says_where(tmp_path, capsys):
    from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
    corners, w, h = corners_file(tmp_path)
    # theta_d = theta (1 - 0.5 theta^2) peaks at theta = sqrt(2/3): radius 300 * 0.5443 = 163.3 px,
    # short of the 400 px to the left and right edges
    calib = tmp_path / 'turns.yaml'
    CameraCalibration(w, h, [[300, 0, w / 2], [0, 300, h / 2], [0, 0, 1]], 'equidistant',
                      [-0.5, 0, 0, 0]).save(str(calib))
    status, out, err = run_main(['evaluate', '--corners', str(corners), '--spec-from', str(calib)], capsys)
    one_line_error(status, err, 'turns back at 163 px from the principal point', 'before the image edge')
    assert 'nan' not in err[0]


def test_evaluate_spec_from_an_infinite_size_is_one_line(tmp_path, capsys):
    corners, w, h = corners_file(tmp_path)
    calib = tmp_path / 'inf.yaml'
    calib.write_text(f'image_width: .inf\nimage_height: {h}\ncamera_matrix: {{rows: 3, cols: 3, data: '
                     f'[300, 0, 400, 0, 300, 250, 0, 0, 1]}}\ndistortion_model: equidistant\n'
                     'distortion_coefficients: {rows: 1, cols: 4, data: [0, 0, 0, 0]}\n'
                     'rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n'
                     'projection_matrix: {rows: 3, cols: 4, data: [300, 0, 400, 0, 0, 300, 250, 0, 0, 0, 1, 0]}\n')
    status, out, err = run_main(['evaluate', '--corners', str(corners), '--spec-from', str(calib)], capsys)
    one_line_error(status, err, 'inf.yaml')


def test_evaluate_spec_from_keeps_fovs_over_180_degrees(tmp_path):
    import argparse
    import math
    from zeroshot_calib_ros.cli import evaluate as cli
    from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
    w, h = 848, 800
    f = (w / 2) / math.radians(103)  # the equidistant law r = f theta: 103 degrees at the side edges
    calib = tmp_path / 'wide.yaml'
    CameraCalibration(w, h, [[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], 'equidistant', [0, 0, 0, 0]).save(str(calib))
    args = argparse.Namespace(spec_from=str(calib), spec_from_model=None, hfov=None, vfov=None, dfov=None)
    spec = cli._evaluation_spec(args, argparse.Namespace(width=w, height=h))[0]
    assert spec.hfov == pytest.approx(206.0, abs=1e-6)
    assert spec.vfov == pytest.approx(2 * math.degrees((h / 2) / f), abs=1e-6)


# -- issue 11: what the CLI prints, against OpenCV / closed forms / the paper ----------------------

def solve_json(capsys, *args):
    status, out, err = run_main(['solve', *args, '--json'], capsys)
    assert status == 0, err
    return json.loads(out), err


def opencv_rectified(image, K, D, balance, fov_scale):
    """What image_proc-style tools make of K, D: cv2.fisheye's new camera matrix and maps.
    Returns (rectified image, float maps x, y)."""
    h, w = image.shape[:2]
    K, D = np.asarray(K, float), np.asarray(D, float).reshape(4, 1)
    P = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, (w, h), np.eye(3), balance=balance,
                                                              fov_scale=fov_scale)
    mx, my = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), P, (w, h), cv2.CV_32FC1)
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0), mx, my


@pytest.mark.parametrize('source', ['spec', 'calibration'])
@pytest.mark.parametrize('balance, fov_scale', [(0.5, 0.6), (0.5, 1.7), (1.0, 1.4)])
def test_rectify_fov_scale_and_balance_give_opencvs_rectified_image(tmp_path, capsys, source, balance, fov_scale):
    """`rectify --balance B --fov-scale S` of a textured image is what cv2.fisheye makes of the
    camera's K, D with the same B, S (estimateNewCameraMatrixForUndistortRectify +
    initUndistortRectifyMap + remap): within the valid interior no pixel differs by more than
    1 grey level (the 1/64-px map agreement), against 40 and more with S ignored."""
    from opencv_reference import textured_image
    w, h = 640, 360
    image = textured_image(w, h, 3, seed=3)
    src, dst = tmp_path / 'in.png', tmp_path / 'out.png'
    cv2.imwrite(str(src), image)
    spec = ['--width', str(w), '--height', str(h), '--hfov', '118', '--vfov', '69']
    record, _ = solve_json(capsys, *spec, '--yaml', str(tmp_path / 'cam.yaml'))
    camera = ['--hfov', '118', '--vfov', '69'] if source == 'spec' else ['--calibration', str(tmp_path / 'cam.yaml')]
    status, _, err = run_main(['rectify', str(src), '-o', str(dst), *camera, '--balance', str(balance),
                               '--fov-scale', str(fov_scale)], capsys)
    assert status == 0, err
    out = cv2.imread(str(dst), cv2.IMREAD_UNCHANGED).astype(int)
    expected, mx, my = opencv_rectified(image, record['K'], record['D'], balance, fov_scale)
    valid = (mx >= 1) & (mx <= w - 2) & (my >= 1) & (my <= h - 2)
    assert valid.mean() > 0.4
    diff = np.abs(out - expected.astype(int))[valid]
    assert np.median(diff) == 0 and diff.max() <= 1, (np.median(diff), diff.max())


BALANCES, FOV_SCALES = (0.0, 0.5, 1.0), (0.5, 1.0, 2.0)


@pytest.mark.parametrize('balance', BALANCES)
@pytest.mark.parametrize('fov_scale', FOV_SCALES)
@pytest.mark.parametrize('spec', [(1920, 1080, 118, 69), (1280, 720, 70.42, 43.3), (1920, 1440, 122, 94)],
                         ids=['hero9-w1', 'c922', 'hero9-w2'])
def test_solve_json_P_is_opencvs_new_camera_matrix(capsys, spec, balance, fov_scale):
    """`solve --json --balance B --fov-scale S` prints as P (3x4, last column 0) what
    cv2.fisheye.estimateNewCameraMatrixForUndistortRectify gives for its own K, D, B and S."""
    width, height, hfov, vfov = spec
    record, _ = solve_json(capsys, '--width', str(width), '--height', str(height), '--hfov', str(hfov),
                           '--vfov', str(vfov), '--balance', str(balance), '--fov-scale', str(fov_scale))
    P = np.array(record['P'])
    expected = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
        np.array(record['K']), np.array(record['D']).reshape(4, 1), (width, height), np.eye(3),
        balance=balance, fov_scale=fov_scale)
    assert P.shape == (3, 4) and np.all(P[:, 3] == 0)
    np.testing.assert_allclose(P[:, :3], expected, atol=3e-3)


def test_batch_without_header_is_the_single_camera_solve(tmp_path, capsys):
    """Rows without a header are name,width,height,hfov,vfov,dfov (README): each gives exactly
    the record of `solve --json` with those flags; the HERO9 W1 row gives Table 2's f* = 876.0."""
    rows = [('w1', '1920', '1080', '118', '69', ''), ('c905', '1280', '720', '63.1', '', ''),
            ('m2026', '1280', '720', '130', '73', ''), ('w1-dfov', '1920', '1080', '118', '69', '133.5'),
            ('v-and-d', '1280', '720', '', '73', '140'), ('d-only', '1280', '720', '', '', '100')]
    status, out, err = run_main(batch(tmp_path, ''.join(','.join(r) + '\n' for r in rows)), capsys)
    assert status == 0, err
    records = [json.loads(line) for line in out.splitlines()]
    assert [r['name'] for r in records] == [r[0] for r in rows]
    for row, record in zip(rows, records):
        flags = [f'--{key}' if i else None for i, key in enumerate(('name', 'width', 'height', 'hfov', 'vfov', 'dfov'))]
        args = [x for flag, cell in zip(flags[1:], row[1:]) if cell for x in (flag, cell)]
        single, _ = solve_json(capsys, *args)
        for key in ('width', 'height', 'spec', 'model', 'omega', 'f', 'K', 'D', 'P', 'fit_error_px'):
            assert record[key] == single[key], (row, key)
    assert records[0]['f'] == pytest.approx(876.0, abs=0.05)  # the paper's Table 2, Hero9(W1)
    assert records[3]['spec'] == {'hfov': 118.0, 'vfov': 69.0, 'dfov': 133.5}


def test_solve_circle_is_the_closed_form_equidistant_circle(capsys):
    """`--circle-diameter 1000 --circle-fov 200` (README's example): an equidistant circular
    fisheye, r = f theta, so f = (D / 2) / (F / 2 in radians) = 286.48 px; its ROS equidistant
    model is exact (D = 0): cv2.fisheye.projectPoints puts rays at r = f theta (up to 89 degrees:
    OpenCV takes theta = atan(r / z), which cannot pass 90), on the way to 500 px at 100."""
    record, err = solve_json(capsys, '--width', '1920', '--height', '1080', '--circle-diameter', '1000',
                             '--circle-fov', '200')
    f = 500 / math.radians(100)
    assert record['model'] == 'wide-equidistant' and record['spec'] == {'circle_diameter': 1000.0, 'circle_fov': 200.0}
    assert record['f'] == pytest.approx(f, rel=1e-12) and (record['cx'], record['cy']) == (960, 540)
    np.testing.assert_allclose(record['K'], [[f, 0, 960], [0, f, 540], [0, 0, 1]], rtol=1e-12)
    assert record['distortion_model'] == 'equidistant' and np.abs(record['D']).max() < 1e-12
    # the one warning says what the circle alone leaves open: the pure law is assumed
    assert record['fit_error_px'] < 1e-9 and record['warning'] == [record['assumption']]
    assert err == [f"zeroshot-calib: warning: {record['assumption']}"] and 'pure equidistant law' in err[0]
    theta = np.radians([89.0, 60.0, 30.0, 89.0])
    phi = np.radians([0.0, 45.0, 120.0, 200.0])
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    pixels = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.array(record['K']),
                                       np.array(record['D']).reshape(4, 1))[0].reshape(-1, 2)
    radius = np.hypot(pixels[:, 0] - 960, pixels[:, 1] - 540)
    np.testing.assert_allclose(radius, f * theta, rtol=1e-9)


README_PLUMB_BOB_WARNING = (
    'zeroshot-calib: warning: the ROS plumb_bob fit of the solved camera is off by up to 7.2 px in the image '
    '(fit error; warning above 0.5 px), so tools that rectify with its D coefficients are that far off: use '
    '--distortion-model equidistant (fit error 0.00015 px)')


def test_solve_plumb_bob_on_the_hero9_gives_the_readmes_warning_and_its_error_is_real(capsys):
    """README: `--distortion-model plumb_bob` for the 118-degree HERO9 is 5 coefficients off by
    7.2 px, with that warning line on stderr. The 7.2 px is checked with cv2.projectPoints on
    the printed K, D against the exact camera (the paper's model, f 876.0, w* 0.001019)."""
    record, err = solve_json(capsys, '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69',
                             '--distortion-model', 'plumb_bob')
    assert record['distortion_model'] == 'plumb_bob' and len(record['D']) == 5
    assert record['fit_error_px'] == pytest.approx(7.2, abs=0.05)
    assert err == [README_PLUMB_BOB_WARNING] and record['warning'] == [README_PLUMB_BOB_WARNING.split(': warning: ')[1]]
    # independent: every pixel of the image as the paper's model sees it (r_d = atan(w f tan theta) / w),
    # through cv2.projectPoints with the printed plumb_bob K, D
    from zeroshot_calib_ros.core import ZeroShotCamera
    exact = ZeroShotCamera(record['f'], 960, 540, 1920, 1080, record['omega'])
    u, v = np.meshgrid(np.linspace(0, 1920, 97), np.linspace(0, 1080, 55))
    pixels = np.stack([u.ravel(), v.ravel()], -1)
    r_d = np.hypot(pixels[:, 0] - 960, pixels[:, 1] - 540)
    w = record['omega']
    tan_theta = np.tan(w * r_d) / (w * record['f'])  # eq. (G_w^-1): r_u = tan(w r_d) / w, tan(theta) = r_u / f
    scale = np.divide(tan_theta, r_d, out=np.full_like(r_d, 1 / record['f']), where=r_d > 0)
    xy = (pixels - [960, 540]) * scale[:, None]
    assert np.allclose(exact.undistort(pixels), xy, atol=1e-9)  # the same law as our model
    projected = cv2.projectPoints(np.c_[xy, np.ones(len(xy))].reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                  np.array(record['K']), np.array(record['D']))[0].reshape(-1, 2)
    worst = np.abs(np.hypot(*(projected - pixels).T)).max()
    assert worst == pytest.approx(record['fit_error_px'], rel=0.02)


TABLE2_ROOTS = [r for r in load_table2() if r['omega']]


@pytest.mark.parametrize('row', TABLE2_ROOTS, ids=[r['camera'] for r in TABLE2_ROOTS])
def test_solve_method_newton_agrees_with_the_default_and_the_paper(capsys, row):
    """`--method newton` (the paper's damped Newton) gives the bracketed solver's f and w to
    1e-10 and the paper's printed w* on every Table 2 camera with a barrel root."""
    args = ['--width', str(int(row['width'])), '--height', str(int(row['height'])), '--hfov', str(row['hfov']),
            '--vfov', str(row['vfov'])]
    default, _ = solve_json(capsys, *args)
    newton, _ = solve_json(capsys, *args, '--method', 'newton')
    assert newton['omega'] == pytest.approx(default['omega'], rel=1e-10)
    assert newton['f'] == pytest.approx(default['f'], rel=1e-10)
    assert round(newton['omega'], 6) == pytest.approx(row['omega'], abs=1e-12)


def test_solve_method_newton_is_the_papers_iteration(capsys):
    """The Newton iteration starts at w0 = 1e-4 (paper), beyond G_w^-1's pole for a 40000 px
    wide image, so there `--method newton` fails in one line while the default finds the root."""
    args = ['solve', '--width', '40000', '--height', '30000', '--hfov', '100', '--vfov', '80']
    status, out, err = run_main(args + ['--method', 'newton'], capsys)
    one_line_error(status, err, 'Newton left the valid range')
    status, out, err = run_main(args + ['--json'], capsys)
    assert status == 0 and json.loads(out)['root_found']


# -- issue 13: calibrate with the spec as evidence (--spec-as, --fov-tolerance) --------------------

def board_with_spec_corners(tmp_path):
    """Corners of a known Kannala-Brandt fisheye (test_board_fit.TRUTH), 3 views, 0.2 px noise,
    and its true FOVs as the spec."""
    from test_board_fit import TRUTH, board_views, true_spec
    corners, _ = board_views(TRUTH, 3, seed=3, noise=0.2)
    path = tmp_path / 'kb_corners.json'
    corners.save(str(path))
    spec = true_spec()
    return path, ['--hfov', repr(spec.hfov), '--vfov', repr(spec.vfov)]


def test_calibrate_with_a_spec_uses_it_as_evidence_by_default(tmp_path, capsys):
    """`calibrate --single IMG --hfov --vfov` (no --spec-as): the MAP fit, a Kannala-Brandt camera
    written as ROS equidistant with an error bar. Its printed K and D, through OpenCV alone
    (PnP + cv2.fisheye.projectPoints), reproduce the printed eq.-20 error on all images, and the
    camera is the truth's (f within 1 %, principal point within 4 px, zero-shot's being 8.5 px
    off: the truth's is 6 px off the centre on both axes). view-00: the view whose MAP
    the gate adopts with boards that may bend (board_fit.BOARD_BEND; the other two keep zero-shot,
    which test_calibrate_says_when_the_gate_keeps_zero_shot_and_writes_that_camera covers)."""
    from opencv_reference import board_points, eq20_squared_errors, rms
    from test_board_fit import BOARD, TRUTH
    from zeroshot_calib_ros.core.checkerboard.corners import CornerSet
    path, spec_args = board_with_spec_corners(tmp_path)
    status, out, err = run_main(['calibrate', '--corners', str(path), '--single', 'view-00.png', *spec_args,
                                 '--json'], capsys)
    assert status == 0, err
    record = json.loads(out)
    assert record['spec_as'] == 'evidence' and record['method'].startswith('MAP')
    assert record['distortion_model'] == 'equidistant' and record['fit_error_px'] == 0.0
    assert record['f'] == pytest.approx(TRUTH.fx, rel=0.01)
    assert math.hypot(record['cx'] - TRUTH.cx, record['cy'] - TRUTH.cy) < 4.0
    assert record['uncertainty_px'] == record['fit']['uncertainty_px'] and 0 < record['uncertainty_px'] < 10
    corners = CornerSet.load(str(path))
    eps = rms(eq20_squared_errors('equidistant', record['K'], record['D'],
                                  board_points(BOARD.cols, BOARD.rows, BOARD.square), corners.corners))
    assert record['eps_all_px'] == pytest.approx(eps, abs=2e-3)
    status, out, err = run_main(['calibrate', '--corners', str(path), '--single', 'view-00.png', *spec_args], capsys)
    lines = out.splitlines()
    assert status == 0 and any(x.startswith('method    MAP') and 'spec as evidence' in x for x in lines)
    assert f"error bar {record['uncertainty_px']:.2f} px" in out and 'agrees' in out


def test_calibrate_says_when_the_gate_keeps_zero_shot_and_writes_that_camera(tmp_path, capsys):
    """One small, far, central view of a camera that is the zero-shot camera of its own FOVs (the
    MAP alone moves away from it: test_board_fit's premise): `calibrate` writes the zero-shot
    camera (K within 1e-6 of it in the YAML), and says so where a user looks, the JSON's
    `accepted` / `method` / `model` and the text's method line, with the gate's reason, and where a
    script looks: exit status 3 (ran fine, result not adopted), not 0."""
    from test_board_fit import H, W, board_views, true_spec
    from zeroshot_calib_ros.core.estimation.refine import zero_shot_camera
    spec = true_spec()
    truth = zero_shot_camera(spec, W, H)
    corners, _ = board_views(truth, 1, seed=5, distance=(0.5, 0.55), spread=0.06, noise=0.3)
    path = tmp_path / 'far_corners.json'
    corners.save(str(path))
    spec_args = ['--hfov', repr(spec.hfov), '--vfov', repr(spec.vfov)]
    out_yaml = tmp_path / 'camera.yaml'
    status, out, err = run_main(['calibrate', '--corners', str(path), *spec_args, '--json', '--yaml', str(out_yaml)],
                                capsys)
    assert status == 3, err
    record = json.loads(out)
    assert record['accepted'] is False and record['reason'].startswith('zero-shot kept')
    assert record['method'].startswith('zero-shot kept') and record['model'].startswith('zero-shot')
    written = yaml.safe_load(out_yaml.read_text())
    assert np.allclose(np.reshape(written['camera_matrix']['data'], (3, 3)), truth.K, rtol=0, atol=1e-6)
    status, out, _ = run_main(['calibrate', '--corners', str(path), *spec_args], capsys)
    method = next(x for x in out.splitlines() if x.startswith('method'))
    assert status == 3 and 'zero-shot kept' in method and 'moved' not in method


def test_calibrate_spec_as_start_is_the_earlier_fc_zs(tmp_path, capsys):
    """`--spec-as start`: FC_eq.d. from the zero-shot camera, the same camera as the library's
    calibrate(corners, 'fc+zs'), with no error bar; the default differs from it."""
    from zeroshot_calib_ros.core.checkerboard.calibration import calibrate as library_calibrate
    from zeroshot_calib_ros.core.checkerboard.corners import CornerSet
    from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec
    path, spec_args = board_with_spec_corners(tmp_path)
    status, out, err = run_main(['calibrate', '--corners', str(path), '--single', 'view-01.png', *spec_args,
                                 '--spec-as', 'start', '--json'], capsys)
    assert status == 0, err
    record = json.loads(out)
    corners = CornerSet.load(str(path))
    spec = CameraSpec(corners.width, corners.height, hfov=float(spec_args[1]), vfov=float(spec_args[3]))
    expected = library_calibrate(corners, 'fc+zs', [1], spec)
    assert record['method'] == 'FC_eq.d.+ZS' and record['init'] == 'zero-shot' and record['spec_as'] == 'start'
    # the same fit to 1e-6: two runs of it differ by up to 1e-9 relative on OpenCV 4.6 (sums over
    # threads in the iterative solve); the default ends 5.9 px away
    assert record['f'] == pytest.approx(expected.camera.f, rel=1e-6)
    assert record['uncertainty_px'] is None
    status, out, _ = run_main(['calibrate', '--corners', str(path), '--single', 'view-01.png', *spec_args,
                               '--json'], capsys)
    assert abs(json.loads(out)['f'] - record['f']) > 1.0


def test_calibrate_fov_tolerance_moves_the_fit_and_bad_values_are_one_line(tmp_path, capsys):
    """--fov-tolerance is the FOVs' sigma: with the hfov given 3 degrees wide, a tight tolerance
    pulls the fitted hfov nearer the given one than the default; 0 and a --principal-point
    choice with the spec as evidence are one-line errors; --help says which mode is which."""
    path, spec_args = board_with_spec_corners(tmp_path)
    wide = ['--hfov', repr(float(spec_args[1]) + 3.0), '--vfov', spec_args[3]]
    fitted = {}
    for tol in ('1', '0.2'):
        status, out, err = run_main(['calibrate', '--corners', str(path), '--single', 'view-00.png', *wide,
                                     '--fov-tolerance', tol, '--json'], capsys)
        assert status == 0, err
        fitted[tol] = json.loads(out)['fit']['fovs_fitted']['hfov']
    given = float(wide[1])
    assert abs(fitted['0.2'] - given) < abs(fitted['1'] - given)
    status, _, err = run_main(['calibrate', '--corners', str(path), *spec_args, '--fov-tolerance', '0'], capsys)
    one_line_error(status, err, '--fov-tolerance')
    status, _, err = run_main(['calibrate', '--corners', str(path), *spec_args, '--principal-point', 'fixed'], capsys)
    one_line_error(status, err, '--spec-as start')
    status, out, _ = run_main(['calibrate', '--help'], capsys)
    text = ' '.join(out.split())
    assert status == 0 and '--spec-as {evidence,start}' in text
    assert 'evidence (default): MAP' in text and 'start: FC_eq.d. from the zero-shot camera' in text
