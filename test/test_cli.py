"""The zeroshot-calib command line, as a user without ROS runs it."""
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

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
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r['name'] for r in lines] == ['w1', 'broken', 'c905', 'typo']
    assert 'error' not in lines[0] and lines[0]['f'] == pytest.approx(876.0, abs=0.05)
    assert lines[1]['row'] == 2 and 'hfov = -5.0' in lines[1]['error']
    assert lines[2]['omega'] == 0
    assert "height = '72O'" in lines[3]['error']
    assert sorted(p.name for p in yaml_dir.iterdir()) == ['c905.yaml', 'w1.yaml']


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
    (['--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69', '--balance', '2'],
     'balance = 2.0 is invalid: allowed: 0 to 1'),
])
def test_errors_exit_2_with_one_line_and_no_traceback(args, message):
    run = subprocess.run([sys.executable, '-m', 'zeroshot_calib_ros.cli', 'solve', *args],
                         capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    assert run.returncode == 2
    assert run.stdout == ''
    assert len(run.stderr.strip().splitlines()) == 1 and message in run.stderr
    assert 'Traceback' not in run.stderr
