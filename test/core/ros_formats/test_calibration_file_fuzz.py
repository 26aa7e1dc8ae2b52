"""Property tests: whatever a calibration file contains, loading it raises CalibrationFileError
with a one-line message, or gives a valid calibration that saves and loads again unchanged.
Nothing else escapes (no OverflowError, RecursionError, UnicodeDecodeError, ...).

Each test counts the documents it generated and prints the count (``pytest -s`` / ``-rA``)."""
import copy
import os
import tempfile

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings, strategies as st

from zeroshot_calib_ros.core.ros_formats.calibration_file import (CalibrationFileError, CameraCalibration,
                                                      RegionOfInterest)

from fuzz_settings import share
from test_calibration_file import INI_FROM_CPP, YAML_FROM_CPP

SETTINGS = dict(deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])

# Values a hand-edited or hostile file puts where a number, a name or a mapping goes.
NASTY = ['.inf', '-.inf', '.nan', 'nan', 'inf', '1e999', '-1', '0', '1280.9', '1280.0', '9' * 5000, 'abc',
         '~', 'null', 'true', '[]', '{}', '[1, [2, [3]]]', '{a: 1}', '"x\\ny"', "'", '"', '&a 1', '*a', '!!str 5',
         '!!python/object/apply:os.system ["true"]', '0x10', '1_000', '+5', '- 1', ': :', '%TAG', '@', '`',
         '\t', '\x00', '\ufeff', '\u2028', '[' * 200, '{' * 200, 'a' * 300]
NASTY_INI = ['[image]', '[externals]', '[x]', '[]', 'width', 'height', 'camera matrix', 'distortion',
             'rectification', 'projection', 'roi', 'binning_x', 'nan', 'inf', '1e999', '-1', '0 0 0', 'abc',
             '1 2 3 4 5 6 7 8 9', '# comment', '; comment', '', '\x00', '0.5', '99999999999999999999']


def _check(load, *args):
    """Run ``load``; only CalibrationFileError (one line) may escape; a success must round-trip."""
    try:
        calibration = load(*args)
    except CalibrationFileError as exc:
        message = str(exc)
        assert message and len(message.splitlines()) == 1, message
        return 'refused'
    assert isinstance(calibration, CameraCalibration)
    for warning in calibration.load_warnings:
        assert len(warning.splitlines()) == 1
    assert CameraCalibration.from_yaml_text(calibration.to_yaml()) == calibration
    try:
        ini = calibration.to_ini()
    except CalibrationFileError:
        pass  # not plumb_bob with 5 coefficients: INI cannot hold it (as writeCalibrationIni)
    else:
        assert CameraCalibration.from_ini_text(ini) == calibration
    return 'loaded'


scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(allow_nan=True, allow_infinity=True),
                    st.text(max_size=20), st.sampled_from(NASTY))
keys = st.one_of(st.sampled_from(['image_width', 'image_height', 'camera_name', 'camera_matrix', 'distortion_model',
                                  'distortion_coefficients', 'rectification_matrix', 'projection_matrix', 'rows',
                                  'cols', 'data', 'roi', 'binning_x', 'binning_y', 'x_offset', 'do_rectify']),
                 st.text(max_size=10))
documents = st.recursive(scalars, lambda children: st.one_of(
    st.lists(children, max_size=14), st.dictionaries(keys, children, max_size=10)), max_leaves=25)


VALID = yaml.safe_load(YAML_FROM_CPP)


def _valid_dict():
    return copy.deepcopy(VALID)


@st.composite
def mutated_dicts(draw):
    """A valid calibration with a few fields (at any depth) replaced, removed or added."""
    d = _valid_dict()
    for _ in range(draw(st.integers(1, 4))):
        key = draw(st.sampled_from(sorted(d) + ['roi', 'binning_x', 'binning_y']))
        action = draw(st.sampled_from(['replace', 'delete', 'inner']))
        if action == 'delete':
            d.pop(key, None)
        elif action == 'inner' and isinstance(d.get(key), dict):
            inner = d[key]
            sub = draw(st.sampled_from(sorted(inner) + ['extra']))
            if sub == 'data' and isinstance(inner.get('data'), list) and inner['data'] and draw(st.booleans()):
                i = draw(st.integers(0, len(inner['data']) - 1))
                inner['data'][i] = draw(documents)
            else:
                inner[sub] = draw(documents)
        else:
            d[key] = draw(documents)
    return d


@st.composite
def mutated_texts(draw, base, pool):
    """``base`` with lines replaced, deleted, duplicated or cut, or tokens swapped for nasty ones."""
    lines = base.split('\n')
    for _ in range(draw(st.integers(1, 5))):
        i = draw(st.integers(0, len(lines) - 1))
        action = draw(st.sampled_from(['token', 'line', 'delete', 'duplicate', 'cut', 'insert', 'indent']))
        if action == 'token':
            tokens = lines[i].split(' ')
            j = draw(st.integers(0, len(tokens) - 1))
            tokens[j] = draw(st.one_of(st.sampled_from(pool), st.text(max_size=8)))
            lines[i] = ' '.join(tokens)
        elif action == 'line':
            lines[i] = draw(st.one_of(st.sampled_from(pool), st.text(max_size=30)))
        elif action == 'delete':
            del lines[i]
        elif action == 'duplicate':
            lines.insert(i, lines[i])
        elif action == 'cut':
            lines[i] = lines[i][:draw(st.integers(0, len(lines[i])))]
        elif action == 'insert':
            lines.insert(i, draw(st.sampled_from(pool)))
        else:
            lines[i] = draw(st.sampled_from([' ', '  ', '\t', ''])) + lines[i].lstrip()
        if not lines:
            lines = ['']
    text = '\n'.join(lines)
    if draw(st.integers(0, 9)) == 0:
        text = text[:draw(st.integers(0, len(text)))]
    return text


def _run(name, test):
    count = {'loaded': 0, 'refused': 0}
    test(count)
    total = sum(count.values())
    print(f'\n{name}: {total} generated cases ({count["loaded"]} loaded and round-tripped, '
          f'{count["refused"]} refused with CalibrationFileError)')
    return count


def test_random_yaml_documents():
    @settings(max_examples=share(500), **SETTINGS)
    @given(documents)
    def check(count, document):
        text = yaml.safe_dump(document, allow_unicode=True)
        count[_check(CameraCalibration.from_yaml_text, text)] += 1
        if isinstance(document, dict):  # the same values as Python objects
            count[_check(CameraCalibration.from_dict, document)] += 1

    count = _run('random YAML documents', lambda c: check(c))
    assert count['refused'] >= share(500)


def test_mutated_yaml_mappings():
    @settings(max_examples=share(400), **SETTINGS)
    @given(mutated_dicts())
    def check(count, d):
        count[_check(CameraCalibration.from_yaml_text, yaml.safe_dump(d, allow_unicode=True))] += 1
        count[_check(CameraCalibration.from_dict, d)] += 1

    count = _run('mutated YAML mappings', lambda c: check(c))
    assert count['loaded'] > 0 and count['refused'] > 0


@pytest.mark.parametrize('label, parse, sample, nasty', [
    ('mutated YAML texts', CameraCalibration.from_yaml_text, YAML_FROM_CPP, NASTY),
    ('mutated INI texts', CameraCalibration.from_ini_text, INI_FROM_CPP, NASTY_INI)])
def test_mutated_texts(label, parse, sample, nasty):
    @settings(max_examples=share(1000), **SETTINGS)
    @given(mutated_texts(sample, nasty))
    def check(count, text):
        count[_check(parse, text)] += 1

    count = _run(label, lambda c: check(c))
    assert count['loaded'] > 0 and count['refused'] > 0


def test_random_bytes_as_files():
    with tempfile.TemporaryDirectory() as directory:
        @settings(max_examples=share(200), **SETTINGS)
        @given(st.binary(max_size=2048), st.sampled_from(['.yaml', '.yml', '.ini']))
        def check(count, data, suffix):
            path = os.path.join(directory, f'cam{suffix}')
            with open(path, 'wb') as f:
                f.write(data)
            count[_check(CameraCalibration.load, path)] += 1

        _run('random bytes as files', lambda c: check(c))


finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@st.composite
def valid_calibrations(draw):
    """Any calibration a camera can have (calibration_file's plausibility bounds: focal lengths
    from 0.01 x the smaller side to 1e5 x the larger, principal point within one image size of
    the image, |skew| <= 0.1 fx, each distortion term <= 1e6 at the image corner), drawn well
    inside them: f from 0.5 x the larger side, the principal point at most half an image outside,
    |D| <= 1 (rho <= 4.3 focal lengths: every term below 1e5)."""
    width, height = draw(st.integers(1, 5000)), draw(st.integers(1, 5000))
    side = max(width, height)

    def focal():
        return draw(st.floats(0.5, 1e4)) * side

    def pinhole():
        fx, fy = focal(), focal()
        skew = draw(st.floats(-0.1, 0.1)) * fx
        return fx, fy, skew, draw(st.floats(-0.5, 1.5)) * width, draw(st.floats(-0.5, 1.5)) * height

    fx, fy, skew, cx, cy = pinhole()
    K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]
    model = draw(st.sampled_from(['plumb_bob', 'equidistant', 'rational_polynomial']))
    D = draw(st.lists(st.floats(-1, 1), min_size=5 if model == 'plumb_bob' else 4 if model == 'equidistant' else 8,
                      max_size=5 if model == 'plumb_bob' else 4 if model == 'equidistant' else 8))
    px, py, pskew, pcx, pcy = pinhole()
    P = [[px, pskew, pcx, draw(finite)], [0, py, pcy, 0], [0, 0, 1, 0]]
    x0, y0 = draw(st.integers(0, width - 1)), draw(st.integers(0, height - 1))
    roi = draw(st.one_of(st.just(RegionOfInterest()), st.builds(
        RegionOfInterest, st.just(x0), st.just(y0), st.integers(1, height - y0), st.integers(1, width - x0),
        st.booleans())))
    name = draw(st.from_regex(r'[A-Za-z0-9_]{1,12}', fullmatch=True))
    return CameraCalibration(width, height, K, model, D, np.eye(3), P, name,
                             draw(st.integers(0, min(width, 16))), draw(st.integers(0, min(height, 16))), roi)


def test_valid_calibrations_save_and_load_unchanged():
    with tempfile.TemporaryDirectory() as directory:
        @settings(max_examples=share(100), **SETTINGS)
        @given(valid_calibrations(), st.sampled_from(['.yaml', '.ini']))
        def check(count, calibration, suffix):
            path = os.path.join(directory, f'cam{suffix}')
            try:
                calibration.save(path)
            except CalibrationFileError:
                assert suffix == '.ini' and calibration.distortion_model != 'plumb_bob'
                count['refused'] += 1
                return
            assert CameraCalibration.load(path) == calibration
            count['loaded'] += 1
            assert set(os.listdir(directory)) <= {'cam.yaml', 'cam.ini'}  # no temporary files

        count = _run('valid calibrations saved and loaded', lambda c: check(c))
        assert count['loaded'] > 0.4 * share(100)  # about 2 in 3: the ini format takes plumb_bob only
