"""Camera presets: the packaged table, the loader, and `zeroshot-calib presets` / `solve --preset`."""
import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from paper_table2 import load_table2
from zeroshot_calib_ros.cli import main
from zeroshot_calib_ros.core import CameraSpec, SpecError, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.zeroshot.presets import (PRESETS_FILE, PresetError, get_preset, get_preset_entry,
                                             load_presets, parse_presets)

REPO = Path(__file__).resolve().parents[3]
PRESETS = load_presets()
TABLE2_PRESETS = {  # Table 2 row -> preset (L6013R1 and L6013R2 are two units of one model)
    'C905': 'logitech_c905', 'C922': 'logitech_c922', 'Hero9(N)': 'gopro_hero9_narrow',
    'Hero9(L)': 'gopro_hero9_linear', 'Hero9(W1)': 'gopro_hero9_wide', 'Hero9(W2)': 'gopro_hero9_wide_4x3',
    'SNP-6321': 'snp_6321', 'L6013R1': 'l6013r', 'L6013R2': 'l6013r', 'M2025-LE': 'axis_m2025_le',
    'M2026-LE': 'axis_m2026_le',
}


def test_the_table_is_packaged_next_to_the_code():
    path = REPO / 'zeroshot_calib_ros' / Path(*PRESETS_FILE)
    assert path.is_file()
    assert load_presets(str(path)) == PRESETS


@pytest.mark.parametrize('name', list(PRESETS))
def test_every_preset_loads_solves_and_names_its_source(name):
    preset = PRESETS[name]
    assert preset.source.strip() and preset.description.strip()
    assert re.fullmatch(r'[a-z0-9_]+', name)
    solution = solve_zero_shot(preset.spec)
    assert math.isfinite(solution.f) and solution.f > 0 and np.all(np.isfinite(solution.K))
    calibration, fit = CameraCalibration.from_solution(solution)
    assert fit.max_error_px < 0.5 and calibration.width == preset.spec.width
    assert get_preset(name) == preset.spec


def test_the_papers_cameras_are_there_with_table2_values():
    for row in load_table2():
        spec = PRESETS[TABLE2_PRESETS[row['camera']]].spec
        assert (spec.width, spec.height, spec.hfov, spec.vfov) == \
            (row['width'], row['height'], row['hfov'], row['vfov']), row['camera']
        assert 'Table 2' in PRESETS[TABLE2_PRESETS[row['camera']]].source
    # Hero9(W1) solves to the paper's numbers.
    solution = solve_zero_shot(get_preset('gopro_hero9_wide'))
    assert round(solution.omega, 6) == 0.001019 and solution.f == pytest.approx(876.0, abs=0.05)


def test_names_are_forgiving_and_unknown_names_suggest_close_ones():
    assert get_preset('GoPro-HERO9-Wide') == get_preset('gopro_hero9_wide')
    assert get_preset_entry(' Logitech C920 ').name == 'logitech_c920'
    with pytest.raises(SpecError) as err:
        get_preset('gopro_hero9_wid')
    assert err.value.field == 'preset' and 'gopro_hero9_wide' in str(err.value)
    with pytest.raises(SpecError, match='logitech_c920'):
        get_preset('c920')


def test_malformed_tables_are_refused_with_the_line(tmp_path):
    header = 'name,width,height,hfov,vfov,dfov,circle_diameter,circle_fov,description,source\n'
    with pytest.raises(PresetError, match=':3: cam has no source'):
        parse_presets('# comment\n' + header + 'cam,1280,720,90,60,,,,a camera,\n')
    with pytest.raises(PresetError, match='dfov'):
        parse_presets(header + 'cam,1280,720,90,60,50,,,a camera,somewhere\n')
    with pytest.raises(PresetError, match='duplicate'):
        parse_presets(header + 'cam,1280,720,90,,,,,a,b\nCAM,1280,720,90,,,,,a,b\n')
    path = tmp_path / 'p.csv'
    path.write_text(header + 'fish,1920,1080,,,,1080,190,a circular fisheye,somewhere\n')
    spec = load_presets(str(path))['fish'].spec
    assert spec.circle_diameter == 1080 and spec.circle_fov == 190


def test_cli_lists_the_presets(capsys):
    assert main(['presets']) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in PRESETS) and 'Table 2' in out
    assert main(['presets', '--json']) == 0
    records = json.loads(capsys.readouterr().out)
    assert [r['name'] for r in records] == list(PRESETS)
    assert all(r['source'] for r in records)


def test_cli_solve_with_a_preset_and_overrides(capsys):
    assert main(['solve', '--preset', 'gopro_hero9_wide', '--json']) == 0
    record = json.loads(capsys.readouterr().out)
    assert record['f'] == pytest.approx(876.0, abs=0.05) and (record['width'], record['height']) == (1920, 1080)
    # An explicit flag overrides that field only.
    assert main(['solve', '--preset', 'gopro_hero9_wide', '--hfov', '122', '--json']) == 0
    record = json.loads(capsys.readouterr().out)
    assert record['spec'] == {'hfov': 122.0, 'vfov': 69.0}
    assert record['f'] == pytest.approx(solve_zero_shot(CameraSpec(1920, 1080, 122, 69)).f, rel=1e-12)
    assert main(['solve', '--preset', 'rpi_camera_v3_wide', '--width', '2304', '--height', '1296',
                 '--json']) == 0
    record = json.loads(capsys.readouterr().out)
    assert (record['width'], record['height']) == (2304, 1296)
    assert record['spec'] == {'hfov': 102.0, 'vfov': 67.0, 'dfov': 120.0}


def test_cli_preset_errors_are_one_line(capsys):
    assert main(['solve', '--preset', 'gopro_hero9_wid']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'did you mean gopro_hero9_wide' in err[0]
    assert main(['solve', '--preset', 'gopro_hero9_wide', '--batch', 'x.csv']) == 2
    assert main(['solve', '--hfov', '118']) == 2
    assert '--width and --height are required' in capsys.readouterr().err


def test_setup_py_installs_the_table():
    """The CSV must be package data, or an installed package has no presets."""
    setup = (REPO / 'setup.py').read_text()
    assert re.search(r"package_data\s*=\s*\{[^}]*(?:'zeroshot_calib_ros'|package_name)\s*:\s*\[[^\]]*"
                     r"['\"]data/(?:\*|camera_presets)\.csv['\"]", setup), \
        "setup.py needs package_data={'zeroshot_calib_ros': ['data/*.csv']}"


def test_spec_with_preset_overrides_field_by_field():
    from zeroshot_calib_ros.core.zeroshot.presets import spec_with_preset
    spec = spec_with_preset('gopro_hero9_wide', vfov=70.0, hfov=None)
    assert (spec.width, spec.height, spec.hfov, spec.vfov) == (1920, 1080, 118.0, 70.0)
    assert spec_with_preset(None, width=640, height=480, hfov=90.0) == spec_with_preset('', width=640,
                                                                                        height=480, hfov=90.0)


def test_a_preset_at_another_aspect_ratio_is_refused_everywhere(tmp_path, capsys):
    """A preset's FOVs belong to its aspect ratio: solve, refine and the node's parameters refuse
    another one (naming the preset's resolution); the same aspect ratio at another size is fine."""
    from zeroshot_calib_ros.core.streaming.node_parameters import PARAMETERS, Settings
    from zeroshot_calib_ros.core.zeroshot.presets import spec_with_preset
    with pytest.raises(SpecError, match='1920x1080'):
        spec_with_preset('gopro_hero9_wide', width=1440, height=1080)
    with pytest.raises(SpecError, match='1920x1080'):
        spec_with_preset('gopro_hero9_wide', width=1440)
    with pytest.raises(SpecError, match='1920x1080'):
        spec_with_preset('gopro_hero9_wide', height=1440)
    assert spec_with_preset('gopro_hero9_wide', width=1280, height=720).hfov == 118.0
    values = {name: parameter.default for name, parameter in PARAMETERS.items()}
    values.update(preset='gopro_hero9_wide', width=1440, height=1080)
    with pytest.raises(SpecError, match='1920x1080'):
        Settings.from_values(values)
    values.update(width=1280, height=720)
    assert Settings.from_values(values).spec.width == 1280
    assert main(['solve', '--preset', 'gopro_hero9_wide', '--width', '1440', '--height', '1080']) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and 'gopro_hero9_wide' in err[0] and '1920x1080' in err[0], err
    image = tmp_path / 'in.png'
    cv2.imwrite(str(image), np.zeros((1080, 1440), np.uint8))
    assert main(['refine', str(image), '--preset', 'gopro_hero9_wide']) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and 'gopro_hero9_wide' in err[0] and '1920x1080' in err[0], err


ROBOTICS = {  # name: (width, height, hfov, vfov, dfov, given, where the source is)
    'rpi_camera_v3_wide': (4608, 2592, 102, 67, 120, 'h+v+d', 'https://www.raspberrypi.com/documentation/accessories/camera.html'),
    'luxonis_oak_d_w_mono': (1280, 800, 127, 79.5, 150, 'h+v+d', 'https://docs.luxonis.com/hardware/products/oak-d-w'),
    'luxonis_oak_d_w_color': (4056, 3040, 95, 72, 120, 'h+v+d', 'https://docs.luxonis.com/hardware/products/oak-d-w'),
    'luxonis_ov9782_w': (1280, 800, 127, 79.5, 150, 'h+v+d', 'https://docs.luxonis.com/hardware/products/oak-ffc-ov9782-w'),
    'luxonis_oak_d_lr': (1920, 1200, 82, 56, 100, 'h+v+d', 'https://docs.luxonis.com/hardware/products/oak-d-lr'),
    'luxonis_oak_d_mono': (1280, 800, 72, 49, 81, 'h+v+d', 'https://docs.luxonis.com/hardware/products/oak-d'),
    'luxonis_oak_d_color': (4056, 3040, 69, 55, 81, 'h+v+d', 'https://docs.luxonis.com/hardware/products/oak-d'),
    'stereolabs_zed_hd2k': (2208, 1242, 76, 47, None, 'h+v', 'support.stereolabs.com'),
    'stereolabs_zed_hd1080': (1920, 1080, 69, 42, None, 'h+v', 'support.stereolabs.com'),
    'stereolabs_zed_hd720': (1280, 720, 85, 54, None, 'h+v', 'support.stereolabs.com'),
    'stereolabs_zed_vga': (672, 376, 87, 56, None, 'h+v', 'support.stereolabs.com'),
}


@pytest.mark.parametrize('name', list(ROBOTICS))
def test_robotics_presets_are_their_sheets_values_with_the_fovs_given_and_the_address(name):
    w, h, hfov, vfov, dfov, given, where = ROBOTICS[name]
    preset = PRESETS[name]
    assert (preset.spec.width, preset.spec.height, preset.spec.hfov, preset.spec.vfov, preset.spec.dfov) == \
        (w, h, hfov, vfov, dfov)
    assert preset.given == given and where in preset.source
    assert solve_zero_shot(preset.spec).warnings == []


def test_the_listing_says_which_fovs_each_sheet_gives(capsys):
    assert main(['presets', '--json']) == 0
    records = {r['name']: r for r in json.loads(capsys.readouterr().out)}
    assert records['logitech_c920']['given'] == 'd' and records['logitech_c905']['given'] == 'h'
    assert records['gopro_hero9_wide']['given'] == 'h+v' and records['rpi_camera_v3_wide']['given'] == 'h+v+d'
    assert all(r['given'] == PRESETS[n].given for n, r in records.items())
    assert main(['presets']) == 0
    lines = capsys.readouterr().out.splitlines()
    header = lines[0].split()
    assert header[header.index('circle') + 1] == 'given'
    row = next(line.split() for line in lines if line.startswith('luxonis_oak_d_w_mono '))
    assert row[header.index('given')] == 'h+v+d'
