"""Calibration files: camera_calibration_parsers layout (YAML and INI), round trips, URLs as
camera_info_manager resolves them, binning / roi, hostile content, the zero-D rule.

References are the C++ sources of ros-perception/image_common: camera_calibration_parsers
parse_yml.cpp / parse_ini.cpp / parse.cpp and camera_info_manager.cpp. Samples below are written
by hand from their emitters and format strings, not from our own output."""
import time
import os
import re

import numpy as np
import pytest
import yaml

from zeroshot_calib_ros.core import CameraSpec, KannalaBrandtCamera, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import (DEFAULT_CAMERA_INFO_URL, CalibrationFileError,
                                                      CalibrationSaveError, CameraCalibration,
                                                      RegionOfInterest, resolve_camera_info_url)
from zeroshot_calib_ros.core.zeroshot.spec import MAX_IMAGE_SIDE

# parse_yml.cpp writeCalibrationYml: the order of its emitter calls.
KEYS = ['image_width', 'image_height', 'camera_name', 'camera_matrix', 'distortion_model',
        'distortion_coefficients', 'rectification_matrix', 'projection_matrix']

# What yaml-cpp's emitter writes for camera_calibration_parsers (integral doubles as 0 / 1).
YAML_FROM_CPP = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [430.15433, 0, 311.71014, 0, 430.32836, 221.97534, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.36311, 0.13207, -0.00124, -0.00041, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [327.59024, 0, 309.54893, 0, 0, 369.58835, 219.31734, 0, 0, 0, 1, 0]
"""

# parse_ini.cpp writeCalibrationIni, character by character: precision(5), std::fixed, each
# matrix row "v v v \n" (SimpleMatrix operator<<), "\ndistortion\n", "\n\nrectification\n",
# "\nprojection\n".
INI_FROM_CPP = ('# Camera intrinsics\n\n'
                '[image]\n\n'
                'width\n640\n\n'
                'height\n480\n\n'
                '[narrow_stereo]\n\n'
                'camera matrix\n'
                '430.15433 0.00000 311.71014 \n'
                '0.00000 430.32836 221.97534 \n'
                '0.00000 0.00000 1.00000 \n'
                '\ndistortion\n'
                '-0.36311 0.13207 -0.00124 -0.00041 0.00000 \n'
                '\n\nrectification\n'
                '1.00000 0.00000 0.00000 \n'
                '0.00000 1.00000 0.00000 \n'
                '0.00000 0.00000 1.00000 \n'
                '\nprojection\n'
                '327.59024 0.00000 309.54893 0.00000 \n'
                '0.00000 369.58835 219.31734 0.00000 \n'
                '0.00000 0.00000 1.00000 0.00000 \n')

SAMPLE_K = [[430.15433, 0, 311.71014], [0, 430.32836, 221.97534], [0, 0, 1]]
SAMPLE_D = [-0.36311, 0.13207, -0.00124, -0.00041, 0.0]
SAMPLE_P = [[327.59024, 0, 309.54893, 0], [0, 369.58835, 219.31734, 0], [0, 0, 1, 0]]


def sample(**changes):
    values = dict(width=640, height=480, K=SAMPLE_K, distortion_model='plumb_bob', D=SAMPLE_D,
                  R=np.eye(3), P=SAMPLE_P, camera_name='narrow_stereo')
    values.update(changes)
    return CameraCalibration(**values)


def one_line_error(excinfo):
    message = str(excinfo.value)
    assert len(message.splitlines()) == 1, message
    return message


def test_yaml_has_camera_calibration_parsers_layout_and_round_trips(tmp_path):
    solution = solve_zero_shot(CameraSpec(1920, 1080, 118, 69))
    calibration, fit = CameraCalibration.from_solution(solution, camera_name='hero9')
    path = tmp_path / 'hero9.yaml'
    calibration.save(str(path))
    data = yaml.safe_load(path.read_text())
    assert list(data) == KEYS  # no binning / roi keys when they have their defaults
    assert data['camera_name'] == 'hero9'
    assert data['distortion_model'] == 'equidistant'
    assert data['camera_matrix'] == {'rows': 3, 'cols': 3, 'data': solution.K.ravel().tolist()}
    assert data['distortion_coefficients']['cols'] == 4
    assert data['projection_matrix']['rows'] == 3 and data['projection_matrix']['cols'] == 4
    loaded = CameraCalibration.load(str(path))
    for name in ('K', 'D', 'R', 'P'):
        assert np.array_equal(getattr(loaded, name), getattr(calibration, name))
    assert loaded == calibration and loaded.load_warnings == []
    assert isinstance(loaded.camera(), KannalaBrandtCamera)
    assert os.listdir(tmp_path) == ['hero9.yaml']


def test_yaml_written_by_camera_calibration_parsers_loads():
    calibration = CameraCalibration.from_yaml_text(YAML_FROM_CPP)
    assert (calibration.width, calibration.height, calibration.camera_name) == (640, 480, 'narrow_stereo')
    assert calibration.K.tolist() == SAMPLE_K and calibration.D.tolist() == SAMPLE_D
    assert calibration.P.tolist() == SAMPLE_P and calibration.R.tolist() == np.eye(3).tolist()
    assert calibration.binning_x == calibration.binning_y == 0 and calibration.roi == RegionOfInterest()
    assert calibration.load_warnings == []


def test_tiny_coefficients_are_yaml_floats_for_pyyaml_too():
    """PyYAML (YAML 1.1, what Python ROS tools load calibrations with) reads 1e-20 as a string;
    1.0e-20 is a float for it and for yaml-cpp."""
    solution = solve_zero_shot(CameraSpec(1280, 720, 90, 60))
    solution.camera.omega = 1.0 / solution.camera.f
    calibration, _ = CameraCalibration.from_solution(solution)
    data = yaml.safe_load(calibration.to_yaml())
    values = [v for key in KEYS[3:] if isinstance(data[key], dict) for v in data[key]['data']]
    assert all(isinstance(v, float) for v in values), values
    assert data['distortion_coefficients']['data'] == calibration.D.tolist()


def test_all_zero_fit_of_a_distorting_lens_keeps_downstream_rectifying():
    """An exact equidistant lens (w f = 1) fits k1..k4 = 0, which image_proc would read as
    'no distortion'; the record carries a 1e-20 instead."""
    solution = solve_zero_shot(CameraSpec(1280, 720, 90, 60))
    camera = solution.camera
    camera.omega = 1.0 / camera.f  # make it the pure r = f theta law
    calibration, fit = CameraCalibration.from_solution(solution)
    assert np.all(np.abs(fit.D) < 1e-12)
    assert np.any(calibration.D != 0) and np.abs(calibration.D).max() <= 1e-20


def test_undistorted_pinhole_keeps_zero_plumb_bob():
    solution = solve_zero_shot(CameraSpec(1280, 720, hfov=63.1), lens_prior=False)  # a pinhole
    calibration, _ = CameraCalibration.from_solution(solution, 'plumb_bob')
    assert calibration.D.tolist() == [0.0] * 5


@pytest.mark.parametrize('text, match', [
    ('image_width: 10\n', 'image_height is missing'),
    ('- 1\n- 2\n', 'not a camera calibration file'),
    ('{{{', 'invalid YAML'),
])
def test_bad_files_are_reported(tmp_path, text, match):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(CalibrationFileError, match=match) as excinfo:
        CameraCalibration.load(str(path))
    assert str(path) in one_line_error(excinfo)


def test_non_finite_or_unknown_model_is_refused():
    with pytest.raises(CalibrationFileError, match='finite'):
        CameraCalibration(640, 480, np.diag([500, 500, 1.0]), 'plumb_bob', [np.nan, 0, 0, 0, 0])
    with pytest.raises(CalibrationFileError, match="distortion_model = 'fancy'"):
        CameraCalibration(640, 480, np.diag([500, 500, 1.0]), 'fancy', [0, 0, 0, 0, 0])


# --- camera_info_url -------------------------------------------------------------------------

def test_camera_info_urls(tmp_path, monkeypatch):
    monkeypatch.setenv('ROS_HOME', str(tmp_path / 'roshome'))
    # camera_info_manager: an empty URL is file://${ROS_HOME}/camera_info/${NAME}.yaml
    assert DEFAULT_CAMERA_INFO_URL == 'file://${ROS_HOME}/camera_info/${NAME}.yaml'
    assert resolve_camera_info_url('', 'front') == str(tmp_path / 'roshome' / 'camera_info' / 'front.yaml')
    assert resolve_camera_info_url('file:///tmp/${NAME}.yaml', 'front') == '/tmp/front.yaml'
    assert resolve_camera_info_url('FILE:///tmp/${NAME}.yaml', 'front') == '/tmp/front.yaml'  # iequals
    assert resolve_camera_info_url('file://${ROS_HOME}/c.ini') == str(tmp_path / 'roshome' / 'c.ini')
    # camera_info_manager takes the path after file:// verbatim (no percent-decoding)
    assert resolve_camera_info_url('file:///tmp/a%20b.yaml') == '/tmp/a%20b.yaml'
    # a '$' without '{' is kept, as resolveURL does
    assert resolve_camera_info_url('/a/$b.yaml') == '/a/$b.yaml'
    assert resolve_camera_info_url('/a/b.yaml') == '/a/b.yaml'
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages').mkdir(parents=True)
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'mypkg').touch()
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    assert resolve_camera_info_url('package://mypkg/calib/cam.yaml') == str(tmp_path / 'share/mypkg/calib/cam.yaml')
    assert resolve_camera_info_url('package://mypkg/${NAME}.yml', 'c1') == str(tmp_path / 'share/mypkg/c1.yml')
    with pytest.raises(CalibrationFileError, match='package .nopkg. not found'):
        resolve_camera_info_url('package://nopkg/x.yaml')


def test_ros_home_defaults_to_home_dot_ros(tmp_path, monkeypatch):
    monkeypatch.delenv('ROS_HOME', raising=False)
    monkeypatch.setenv('HOME', str(tmp_path))
    assert resolve_camera_info_url('', 'cam') == str(tmp_path / '.ros' / 'camera_info' / 'cam.yaml')
    monkeypatch.setenv('ROS_HOME', '~/elsewhere')  # expanded
    assert resolve_camera_info_url('${ROS_HOME}/x.yaml') == str(tmp_path / 'elsewhere' / 'x.yaml')


@pytest.mark.parametrize('url, match', [
    ('http://example.com/x.yaml', 'allowed: file:///'),
    ('file:///tmp/${HOME}.yaml', r'unknown variable \$\{HOME\}'),
    ('file:///tmp/${NAME.yaml', r'unknown variable'),
    ('file://relative/x.yaml', 'file:///'),          # parseURL wants file:/// (an absolute path)
    ('flash:///x.yaml', 'not supported'),
    ('package://mypkg', 'package://package/path'),  # no path after the package
    ('package:///x.yaml', 'package://package/path'),
    ('/tmp/x.txt', r'allowed: a \.yaml, \.yml or \.ini file'),
])
def test_bad_camera_info_urls_name_the_parameter(url, match):
    with pytest.raises(CalibrationFileError, match=match) as excinfo:
        resolve_camera_info_url(url, 'cam')
    assert one_line_error(excinfo).startswith('camera_info_url = ')


@pytest.mark.parametrize('name', ['', 'a-b', 'a b', '../etc', 'a/b', 'a\nb', 'caméra', 'x' * 201, 7])
def test_camera_name_follows_camera_info_manager(name):
    """setCameraName: not empty; only alphanumerics and '_' (ASCII, C locale isalnum)."""
    with pytest.raises(CalibrationFileError, match='camera_name') as excinfo:
        resolve_camera_info_url('file:///tmp/${NAME}.yaml', name)
    one_line_error(excinfo)
    with pytest.raises(CalibrationFileError, match='camera_name') as excinfo:
        sample(camera_name=name)
    one_line_error(excinfo)


@pytest.mark.parametrize('name', ['front_left2', '123', 'true', 'null', '1_000', '0x1F', 'Yes', '_'])
@pytest.mark.parametrize('suffix', ['.yaml', '.ini'])
def test_every_accepted_camera_name_round_trips(tmp_path, name, suffix):
    path = tmp_path / f'cam{suffix}'
    sample(camera_name=name).save(str(path))
    assert CameraCalibration.load(str(path)).camera_name == name
    if suffix == '.yaml':
        assert yaml.safe_load(path.read_text())['camera_name'] == name  # quoted for PyYAML too


def test_file_camera_names_camera_info_manager_cannot_use_load_with_a_warning():
    text = YAML_FROM_CPP.replace('camera_name: narrow_stereo', 'camera_name: "narrow stereo/left"')
    calibration = CameraCalibration.from_yaml_text(text)
    assert calibration.camera_name == 'unknown'
    assert len(calibration.load_warnings) == 1 and 'camera_name' in calibration.load_warnings[0]
    # parse_yml.cpp: no camera_name key -> "unknown", silently
    missing = CameraCalibration.from_yaml_text(YAML_FROM_CPP.replace('camera_name: narrow_stereo\n', ''))
    assert missing.camera_name == 'unknown' and missing.load_warnings == []


# --- distortion_model missing ---------------------------------------------------------------

def test_missing_distortion_model_is_plumb_bob_with_a_warning(tmp_path):
    path = tmp_path / 'old.yaml'
    path.write_text(YAML_FROM_CPP.replace('distortion_model: plumb_bob\n', ''))
    calibration = CameraCalibration.load(str(path))
    assert calibration.distortion_model == 'plumb_bob' and calibration.D.tolist() == SAMPLE_D
    assert len(calibration.load_warnings) == 1
    assert 'distortion_model' in calibration.load_warnings[0] and 'plumb_bob' in calibration.load_warnings[0]


# --- INI ------------------------------------------------------------------------------------

def test_ini_written_by_camera_calibration_parsers_loads(tmp_path):
    path = tmp_path / 'ost.ini'
    path.write_text(INI_FROM_CPP)
    calibration = CameraCalibration.load(str(path))
    assert calibration == sample()
    assert calibration.distortion_model == 'plumb_bob'  # parse_ini.cpp: 5 coefficients
    assert calibration.load_warnings == []


def test_ini_writer_reproduces_the_cpp_writer_byte_for_byte():
    assert sample().to_ini(precision=5) == INI_FROM_CPP


def test_ini_full_precision_round_trip_keeps_the_cpp_layout(tmp_path):
    solution = solve_zero_shot(CameraSpec(1280, 720, 100, 62))
    calibration, _ = CameraCalibration.from_solution(solution, 'plumb_bob', balance=0.3, camera_name='c1')
    path = tmp_path / 'c1.ini'
    calibration.save(str(path))
    text = path.read_text()
    lines = text.split('\n')
    # the skeleton of parse_ini.cpp's writer, numbers aside
    numeric = [bool(re.match(r'-?[0-9]', line)) for line in lines]
    skeleton = ['#' if is_number else line for line, is_number in zip(lines, numeric)]
    assert skeleton == ['# Camera intrinsics', '', '[image]', '', 'width', '#', '', 'height', '#', '',
                        '[c1]', '', 'camera matrix', '#', '#', '#', '', 'distortion', '#', '', '',
                        'rectification', '#', '#', '#', '', 'projection', '#', '#', '#', '']
    # matrix rows end in a space (SimpleMatrix operator<<), width and height do not
    assert [line.endswith(' ') for line, is_number in zip(lines, numeric) if is_number] == [False] * 2 + [True] * 10
    loaded = CameraCalibration.load(str(path))
    assert loaded == calibration
    assert np.array_equal(loaded.P, calibration.P) and np.array_equal(loaded.D, calibration.D)


def test_ini_with_eight_coefficients_is_rational_polynomial():
    """parse_ini.cpp: an 8-value distortion row means rational_polynomial."""
    text = INI_FROM_CPP.replace('-0.36311 0.13207 -0.00124 -0.00041 0.00000 \n',
                                '-0.36311 0.13207 -0.00124 -0.00041 0.00000 0.1 0.2 0.3\n')
    calibration = CameraCalibration.from_ini_text(text)
    assert calibration.distortion_model == 'rational_polynomial' and calibration.D.size == 8


def test_ini_holds_only_what_the_cpp_writer_writes(tmp_path):
    """writeCalibrationIni refuses anything but plumb_bob with 5 coefficients; '[image]' and
    '[externals]' are not camera sections, so those camera names cannot be written either."""
    solution = solve_zero_shot(CameraSpec(1920, 1080, 118, 69))
    fisheye, _ = CameraCalibration.from_solution(solution)  # equidistant
    for calibration, match in [(fisheye, 'plumb_bob'), (sample(camera_name='image'), 'camera_name'),
                               (sample(camera_name='externals'), 'camera_name')]:
        path = tmp_path / 'x.ini'
        with pytest.raises(CalibrationSaveError, match=match) as excinfo:
            calibration.save(str(path))
        assert isinstance(excinfo.value, OSError) and isinstance(excinfo.value, CalibrationFileError)
        assert str(path) in one_line_error(excinfo)
        assert os.listdir(tmp_path) == []


@pytest.mark.parametrize('suffix', ['.txt', '', '.YAML', '.json'])
def test_format_follows_the_extension_as_read_and_write_calibration(tmp_path, suffix):
    """parse.cpp: '.ini' -> INI, '.yml' / '.yaml' -> YAML, anything else refused."""
    path = tmp_path / f'cam{suffix}'
    with pytest.raises(CalibrationSaveError, match='allowed: .ini, .yml or .yaml'):
        sample().save(str(path))
    assert os.listdir(tmp_path) == []
    path.write_text(YAML_FROM_CPP)
    with pytest.raises(CalibrationFileError, match='allowed: .ini, .yml or .yaml'):
        CameraCalibration.load(str(path))


def test_yml_extension_is_yaml(tmp_path):
    path = tmp_path / 'cam.yml'
    sample().save(str(path))
    assert yaml.safe_load(path.read_text())['camera_name'] == 'narrow_stereo'
    assert CameraCalibration.load(str(path)) == sample()


# --- binning and roi -------------------------------------------------------------------------

def test_binning_and_roi_default_to_the_full_unbinned_image():
    calibration = sample()
    assert calibration.binning_x == calibration.binning_y == 0
    assert calibration.roi == RegionOfInterest(0, 0, 0, 0, False) and calibration.roi.is_full()


@pytest.mark.parametrize('suffix', ['.yaml', '.ini'])
def test_binning_and_roi_round_trip_after_the_standard_keys(tmp_path, suffix):
    roi = RegionOfInterest(x_offset=10, y_offset=20, height=300, width=400, do_rectify=True)
    calibration = sample(binning_x=2, binning_y=4, roi=roi)
    path = tmp_path / f'cam{suffix}'
    calibration.save(str(path))
    loaded = CameraCalibration.load(str(path))
    assert loaded == calibration
    assert (loaded.binning_x, loaded.binning_y, loaded.roi) == (2, 4, roi)
    if suffix == '.yaml':
        data = yaml.safe_load(path.read_text())
        assert list(data) == KEYS + ['binning_x', 'binning_y', 'roi']
        assert data['roi'] == {'x_offset': 10, 'y_offset': 20, 'height': 300, 'width': 400, 'do_rectify': True}
    else:
        # parse_ini.cpp's parse_image_section looks only for the lines 'width' and 'height'
        # (std::find) and takes the line after each; extra keys in [image] are ignored by it.
        lines = [line.strip() for line in path.read_text().split('\n') if line.strip()]
        image = lines[lines.index('[image]'):lines.index('[narrow_stereo]')]
        assert image[image.index('width') + 1] == '640' and image[image.index('height') + 1] == '480'
        assert image.count('width') == 1 and image.count('height') == 1


@pytest.mark.parametrize('changes, match', [
    (dict(binning_x=-1), 'binning_x'),
    (dict(binning_y=481), 'binning_y'),
    (dict(binning_x=True), 'binning_x'),
    (dict(binning_x=2.0), 'binning_x'),
    (dict(roi=RegionOfInterest(600, 0, 10, 41)), 'roi'),      # x_offset + width > 640
    (dict(roi=RegionOfInterest(0, 470, 11, 10)), 'roi'),      # y_offset + height > 480
    (dict(roi=RegionOfInterest(0, 0, 10, 0)), 'roi'),         # half empty
    (dict(roi=RegionOfInterest(5, 5, 0, 0)), 'roi'),          # empty, not at the origin
    (dict(roi=RegionOfInterest(-1, 0, 10, 10)), 'roi'),
    (dict(roi=RegionOfInterest(0, 0, 10, 10, do_rectify='yes')), 'do_rectify'),
])
def test_bad_binning_or_roi_is_refused(changes, match):
    with pytest.raises(CalibrationFileError, match=match) as excinfo:
        sample(**changes)
    one_line_error(excinfo)


def test_scaled_calibration_scales_intrinsics_only():
    solution = solve_zero_shot(CameraSpec(1920, 1080, 118, 69))
    calibration, _ = CameraCalibration.from_solution(solution)
    half = calibration.scaled(960, 540)
    assert half.K[0, 0] == pytest.approx(calibration.K[0, 0] / 2)
    assert half.K[:2, 2].tolist() == [480, 270]
    assert np.array_equal(half.D, calibration.D)
    assert half.P[0, 0] == pytest.approx(calibration.P[0, 0] / 2)
    assert half.roi.is_full() and half.binning_x == 0


def test_scaled_keeps_binning_and_maps_the_roi_onto_the_new_pixel_grid():
    roi = RegionOfInterest(x_offset=101, y_offset=50, height=201, width=300, do_rectify=True)
    calibration = sample(binning_x=2, binning_y=2, roi=roi)
    half = calibration.scaled(320, 240)
    assert (half.binning_x, half.binning_y) == (2, 2)
    # offsets rounded down, far edges rounded up: the region still covers what it covered
    assert half.roi == RegionOfInterest(x_offset=50, y_offset=25, height=101, width=151, do_rectify=True)
    assert calibration.scaled(1280, 960).roi == RegionOfInterest(202, 100, 402, 600, True)
    with pytest.raises(CalibrationFileError, match='binning_x'):
        sample(binning_x=64).scaled(32, 24)


# --- hostile / mistaken content --------------------------------------------------------------

def _set(text, old, new):
    assert old in text
    return text.replace(old, new, 1)


K_LINE = 'data: [430.15433, 0, 311.71014, 0, 430.32836, 221.97534, 0, 0, 1]'
D_LINE = 'data: [-0.36311, 0.13207, -0.00124, -0.00041, 0]'
P_LINE = 'data: [327.59024, 0, 309.54893, 0, 0, 369.58835, 219.31734, 0, 0, 0, 1, 0]'

HOSTILE_YAML = [
    ('width inf', _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: .inf'), 'image_width'),
    ('width -inf', _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: -.inf'), 'image_width'),
    ('width nan', _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: .nan'), 'image_width'),
    ('width fraction', _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: 1280.9'), 'image_width'),
    ('width negative', _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: -640'), 'image_width'),
    ('width zero', _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: 0'), 'image_width'),
    ('width huge', _set(YAML_FROM_CPP, 'image_width: 640', f'image_width: {MAX_IMAGE_SIDE + 1}'), 'image_width'),
    ('width 5000 digits', _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: ' + '9' * 5000), 'image_width'),
    ('height string', _set(YAML_FROM_CPP, 'image_height: 480', 'image_height: tall'), 'image_height'),
    ('height bool', _set(YAML_FROM_CPP, 'image_height: 480', 'image_height: true'), 'image_height'),
    ('height list', _set(YAML_FROM_CPP, 'image_height: 480', 'image_height: [480]'), 'image_height'),
    ('height null', _set(YAML_FROM_CPP, 'image_height: 480', 'image_height:'), 'image_height'),
    ('K nan', _set(YAML_FROM_CPP, K_LINE, K_LINE.replace('430.15433', '.nan')), 'camera_matrix'),
    ('K 1e999', _set(YAML_FROM_CPP, K_LINE, K_LINE.replace('430.15433', '1e999')), 'camera_matrix'),
    ('K string', _set(YAML_FROM_CPP, K_LINE, K_LINE.replace('430.15433', 'abc')), 'camera_matrix'),
    ('K nested', _set(YAML_FROM_CPP, K_LINE, K_LINE.replace('430.15433', '[1, 2]')), 'camera_matrix'),
    ('K 8 values', _set(YAML_FROM_CPP, K_LINE, K_LINE.replace('0, 0, 1]', '0, 1]')), 'camera_matrix'),
    ('K rows 4', _set(YAML_FROM_CPP, 'rows: 3', 'rows: 4'), 'camera_matrix'),
    ('K zero focal', _set(YAML_FROM_CPP, K_LINE, K_LINE.replace('430.15433', '0')), 'camera_matrix'),
    ('K not a mapping', _set(YAML_FROM_CPP, 'camera_matrix:\n  rows: 3\n  cols: 3\n  ' + K_LINE,
                             'camera_matrix: 5'), 'camera_matrix'),
    ('K data mapping', _set(YAML_FROM_CPP, K_LINE, 'data: {a: 1}'), 'camera_matrix'),
    ('D inf', _set(YAML_FROM_CPP, D_LINE, D_LINE.replace('0.13207', '-.inf')), 'distortion_coefficients'),
    ('D count', _set(YAML_FROM_CPP, 'cols: 5', 'cols: 7'), 'distortion_coefficients'),
    ('D 3 values', _set(_set(YAML_FROM_CPP, 'cols: 5', 'cols: 3'), D_LINE, 'data: [1, 2, 3]'),
     'distortion_coefficients'),
    ('D huge', _set(YAML_FROM_CPP, 'cols: 5', 'cols: 100000000'), 'distortion_coefficients'),
    ('model unknown', _set(YAML_FROM_CPP, 'distortion_model: plumb_bob', 'distortion_model: fancy'),
     'distortion_model'),
    ('model list', _set(YAML_FROM_CPP, 'distortion_model: plumb_bob', 'distortion_model: [a]'),
     'distortion_model'),
    ('R nan', _set(YAML_FROM_CPP, 'data: [1, 0, 0, 0, 1, 0, 0, 0, 1]', 'data: [1, 0, 0, 0, .NaN, 0, 0, 0, 1]'),
     'rectification_matrix'),
    ('R singular', _set(YAML_FROM_CPP, 'data: [1, 0, 0, 0, 1, 0, 0, 0, 1]', 'data: [0, 0, 0, 0, 0, 0, 0, 0, 0]'),
     'rectification_matrix'),
    ('P zeros', _set(YAML_FROM_CPP, P_LINE, 'data: [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]'), 'projection_matrix'),
    ('P singular', _set(YAML_FROM_CPP, P_LINE, P_LINE.replace('0, 0, 1, 0]', '0, 0, 0, 0]')), 'projection_matrix'),
    ('P negative focal', _set(YAML_FROM_CPP, P_LINE, P_LINE.replace('327.59024', '-327.59024')),
     'projection_matrix'),
    ('P inf', _set(YAML_FROM_CPP, P_LINE, P_LINE.replace('309.54893', '.inf')), 'projection_matrix'),
    ('P 11 values', _set(YAML_FROM_CPP, P_LINE, P_LINE.replace(', 1, 0]', ', 1]')), 'projection_matrix'),
    ('missing P', YAML_FROM_CPP.split('projection_matrix')[0], 'projection_matrix is missing'),
    ('duplicate key', YAML_FROM_CPP + 'image_width: 1280\n', 'image_width'),
    ('nested 100000', 'image_width: ' + '[' * 100_000 + ']' * 100_000, 'nested'),
    ('nested mappings', 'a: ' + '{b: ' * 100_000 + '1' + '}' * 100_000, 'nested'),
    ('python tag', _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: !!python/object/apply:os.system ["true"]'),
     'image_width'),
    ('two documents', YAML_FROM_CPP + '---\n' + YAML_FROM_CPP, 'invalid YAML'),
    ('top-level list', '[1, 2, 3]', 'not a camera calibration file'),
    ('top-level scalar', 'hello', 'not a camera calibration file'),
    ('empty', '', 'not a camera calibration file'),
    ('roi outside', YAML_FROM_CPP + 'roi: {x_offset: 600, y_offset: 0, height: 10, width: 100, '
                                    'do_rectify: false}\n', 'roi'),
    ('roi typo', YAML_FROM_CPP + 'roi: {x_ofset: 1}\n', 'roi'),
    ('roi do_rectify', YAML_FROM_CPP + 'roi: {do_rectify: maybe}\n', 'do_rectify'),
    ('binning negative', YAML_FROM_CPP + 'binning_x: -2\n', 'binning_x'),
    ('binning fraction', YAML_FROM_CPP + 'binning_y: 1.5\n', 'binning_y'),
]


@pytest.mark.parametrize('label, text, field', HOSTILE_YAML, ids=[case[0] for case in HOSTILE_YAML])
def test_hostile_yaml_names_the_field_on_one_line(tmp_path, label, text, field):
    path = tmp_path / 'cam.yaml'
    path.write_text(text)
    with pytest.raises(CalibrationFileError) as excinfo:
        CameraCalibration.load(str(path))
    message = one_line_error(excinfo)
    assert field in message and str(path) in message
    if label.startswith(('width', 'height')):
        assert f'from 1 to {MAX_IMAGE_SIDE}' in message


def test_tags_construct_nothing():
    """Tags are neither resolved nor constructed (yaml-cpp's view): a tagged extra key is just data."""
    text = YAML_FROM_CPP + 'x: !!python/object/apply:os.system ["exit 3"]\n'
    assert CameraCalibration.from_yaml_text(text) == sample()


def test_integral_widths_and_quoted_numbers_are_numbers():
    """yaml-cpp converts a scalar whatever its quoting; so do we."""
    text = _set(YAML_FROM_CPP, 'image_width: 640', 'image_width: "640"')
    assert CameraCalibration.from_yaml_text(text).width == 640


@pytest.mark.parametrize('data', [bytes(range(256)), b'\xff\xfe\x00\x00garbage', b'\x00' * 64,
                                  b'image_width: 640\n\x00\x01\x02', os.urandom(4096)])
@pytest.mark.parametrize('suffix', ['.yaml', '.ini'])
def test_binary_garbage_is_a_calibration_file_error(tmp_path, data, suffix):
    path = tmp_path / f'cam{suffix}'
    path.write_bytes(data)
    with pytest.raises(CalibrationFileError) as excinfo:
        CameraCalibration.load(str(path))
    assert str(path) in one_line_error(excinfo)


def test_oversized_files_are_refused_without_reading_them_whole(tmp_path):
    path = tmp_path / 'cam.yaml'
    path.write_text(YAML_FROM_CPP + '#' * (2 << 20) + '\n')
    with pytest.raises(CalibrationFileError, match='larger than') as excinfo:
        CameraCalibration.load(str(path))
    one_line_error(excinfo)


def test_unreadable_paths_are_calibration_file_errors(tmp_path):
    with pytest.raises(CalibrationFileError, match='cannot read'):
        CameraCalibration.load(str(tmp_path / 'missing.yaml'))
    (tmp_path / 'dir.yaml').mkdir()
    with pytest.raises(CalibrationFileError, match='cannot read') as excinfo:
        CameraCalibration.load(str(tmp_path / 'dir.yaml'))
    one_line_error(excinfo)


def _ini_with(old, new):
    return _set(INI_FROM_CPP, old, new)


HOSTILE_INI = [
    ('no image section', INI_FROM_CPP.replace('[image]\n\nwidth\n640\n\nheight\n480\n\n', ''), '[image]'),
    ('no width', _ini_with('width\n640\n', ''), 'width'),
    ('width fraction', _ini_with('width\n640\n', 'width\n640.5\n'), 'width'),
    ('width huge', _ini_with('width\n640\n', 'width\n99999999999999999999\n'), 'width'),
    ('width last line', INI_FROM_CPP.replace('[image]\n\nwidth\n640\n\nheight\n480\n\n', '')
     + '[image]\nheight\n480\nwidth\n', 'width'),
    ('no camera section', INI_FROM_CPP.split('[narrow_stereo]')[0], 'camera section'),
    ('two camera sections', INI_FROM_CPP + INI_FROM_CPP.split('\n[image]')[0].replace('# Camera intrinsics', '')
     + INI_FROM_CPP[INI_FROM_CPP.index('[narrow_stereo]'):].replace('[narrow_stereo]', '[other]'), 'camera section'),
    ('no projection', INI_FROM_CPP.split('\nprojection')[0], 'projection'),
    ('short K row', _ini_with('0.00000 430.32836 221.97534 \n', '0.00000 430.32836\n'), 'camera matrix'),
    ('long K row', _ini_with('0.00000 430.32836 221.97534 \n', '0.00000 430.32836 221.97534 5\n'), 'camera matrix'),
    ('K inf', _ini_with('430.15433 0.00000', 'inf 0.00000'), 'camera matrix'),
    ('K text', _ini_with('430.15433 0.00000', 'abc 0.00000'), 'camera matrix'),
    ('K rows missing', INI_FROM_CPP.split('0.00000 0.00000 1.00000 \n\ndistortion')[0], 'camera matrix'),
    ('D four values', _ini_with('-0.36311 0.13207 -0.00124 -0.00041 0.00000 ', '-0.36311 0.13207 -0.00124 -0.00041'),
     'distortion'),
    ('D six values', _ini_with('-0.00041 0.00000 ', '-0.00041 0.00000 7 '), 'distortion'),
    ('R nan', _ini_with('\n1.00000 0.00000 0.00000 \n', '\nnan 0.00000 0.00000 \n'), 'rectification'),
    ('P singular', _ini_with('0.00000 0.00000 1.00000 0.00000 \n', '0.00000 0.00000 0.00000 0.00000 \n'),
     'projection'),
    ('P negative focal', _ini_with('327.59024', '-327.59024'), 'projection'),
    ('content before a section', 'width\n640\n' + INI_FROM_CPP, 'section'),
    ('bad header', _ini_with('[narrow_stereo]', 'x[narrow_stereo]'), 'section'),
    ('empty', '', '[image]'),
    ('comments only', '# nothing\n; here\n', '[image]'),
]


@pytest.mark.parametrize('label, text, field', HOSTILE_INI, ids=[case[0] for case in HOSTILE_INI])
def test_hostile_ini_names_the_field_on_one_line(tmp_path, label, text, field):
    path = tmp_path / 'cam.ini'
    path.write_text(text)
    with pytest.raises(CalibrationFileError) as excinfo:
        CameraCalibration.load(str(path))
    message = one_line_error(excinfo)
    assert field in message and str(path) in message


@pytest.mark.parametrize('P, rectify_irrelevant', [
    (np.zeros((3, 4)), True),
    (np.hstack([np.diag([500.0, 500.0, 0.0]), np.zeros((3, 1))]), True),
    (np.hstack([np.diag([-500.0, 500.0, 1.0]), np.zeros((3, 1))]), True),
    (np.hstack([np.diag([500.0, 0.0, 1.0]), np.zeros((3, 1))]), True),
])
def test_a_projection_unusable_for_rectification_is_always_refused(P, rectify_irrelevant):
    """CameraCalibration has no rectify switch: what it holds can always be saved and loaded."""
    with pytest.raises(CalibrationFileError, match=r'P \(projection_matrix\)') as excinfo:
        sample(P=P)
    one_line_error(excinfo)


@pytest.mark.parametrize('changes, field', [
    (dict(width=0), 'width'), (dict(width=MAX_IMAGE_SIDE + 1), 'width'), (dict(height=480.0), 'height'),
    (dict(height=True), 'height'), (dict(K=np.zeros(8)), 'K'), (dict(K='abc'), 'K'),
    (dict(K=[[500, 0, 320], [0, 500, 240], [0, 0, 2]]), 'K'), (dict(D=[0, 0, 0]), 'D'),
    (dict(R=np.ones((2, 2))), 'R'), (dict(P=np.eye(3)), 'P'), (dict(distortion_model=None), 'distortion_model'),
])
def test_bad_constructor_arguments_name_the_field(changes, field):
    with pytest.raises(CalibrationFileError, match=field) as excinfo:
        sample(**changes)
    one_line_error(excinfo)


def _laughs(levels=9):
    """'Billion laughs': a few hundred bytes of YAML whose aliases stand for 9**levels strings."""
    names = 'abcdefghijklmnop'
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for previous, name in zip(names, names[1:levels]):
        lines.append(f'{name}: &{name} [' + ','.join([f'*{previous}'] * 9) + ']')
    return '\n'.join(lines) + f'\nimage_width: *{names[levels - 1]}\n'


def test_a_yaml_alias_bomb_is_refused_at_once(tmp_path):
    path = tmp_path / 'bomb.yaml'
    path.write_text(_laughs())
    start = time.monotonic()
    with pytest.raises(CalibrationFileError, match='aliases expand') as excinfo:
        CameraCalibration.load(str(path))
    assert str(path) in one_line_error(excinfo)
    assert time.monotonic() - start < 2.0
    small = _laughs(2).replace('image_width: *b', 'image_width: 1')  # 90 values: aliases as such are fine
    with pytest.raises(CalibrationFileError, match='image_height is missing'):
        CameraCalibration.from_yaml_text(small)


def test_messages_show_huge_nested_values_in_bounded_time():
    """A value that is small in memory (shared lists) but huge written out, given to from_dict."""
    value = ['lol'] * 9
    for _ in range(8):
        value = [value] * 9
    start = time.monotonic()
    with pytest.raises(CalibrationFileError, match='image_width') as excinfo:
        CameraCalibration.from_dict({'image_width': value})
    assert len(one_line_error(excinfo)) < 300 and time.monotonic() - start < 2.0


def test_package_urls_take_the_first_prefix_that_has_the_package(tmp_path, monkeypatch):
    """Overlay workspaces: AMENT_PREFIX_PATH lists the overlay first; the first prefix whose
    ament index has the package wins (as ament_index's get_package_share_directory)."""
    prefixes = [tmp_path / name for name in ('empty', 'overlay', 'underlay')]
    for prefix in prefixes[1:]:
        index = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
        index.mkdir(parents=True)
        (index / 'mypkg').touch()
    prefixes[0].mkdir()
    monkeypatch.setenv('AMENT_PREFIX_PATH', os.pathsep.join(map(str, prefixes)))
    assert resolve_camera_info_url('package://mypkg/calib/cam.yaml') == str(prefixes[1] / 'share/mypkg/calib/cam.yaml')
    monkeypatch.setenv('AMENT_PREFIX_PATH', os.pathsep.join(map(str, prefixes[::-1])))
    assert resolve_camera_info_url('package://mypkg/calib/cam.yaml') == str(prefixes[2] / 'share/mypkg/calib/cam.yaml')
