"""Generated corners files (what `--corners FILE` and `--save-corners` exchange): any JSON value,
valid files with one field mutated, arbitrary bytes. Loading either gives a usable CornerSet
(finite corners inside the image, the declared board) or one CornersError line naming the file
and the field; never another exception. What `save` writes loads back unchanged."""
import json
import math
import os
from collections import Counter

import numpy as np
import pytest
from hypothesis import given, strategies as st

from fuzz_settings import examples
from zeroshot_calib_ros.core.checkerboard.corners import CORNERS_FORMAT, CORNERS_VERSION, Board, CornersError, CornerSet

CASES = Counter()


@pytest.fixture(scope='module', autouse=True)
def report_counts():
    yield
    print('\ncorners-file fuzz cases: ' + ', '.join(f'{k} {v}' for k, v in sorted(CASES.items()))
          + f' (total {sum(CASES.values())}); 0 tracebacks')


def valid_file(cols=4, rows=3):
    rng = np.random.default_rng(cols * 10 + rows)
    return {'format': CORNERS_FORMAT, 'version': CORNERS_VERSION, 'image_width': 640, 'image_height': 480,
            'board': {'cols': cols, 'rows': rows, 'square': 0.05},
            'images': [{'name': f'view-{k}.png', 'corners': rng.uniform(10, 470, (cols * rows, 2)).tolist()}
                       for k in range(2)]}


def _containers(children):
    return st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=8), children, max_size=5)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12), _containers, max_leaves=25)
NASTY = [None, True, 0, -1, 1.5, 2**64, float('nan'), float('inf'), '', '8', [], {}, [1.0], [[1.0, 2.0]],
         'x' * 10000, [float('nan'), 1.0], [1e308, 1e308], [-5.0, 3.0]]


def paths_of(value, prefix=()):
    """Every path (tuple of keys / indices) into a JSON value."""
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from paths_of(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value[:6]):
            yield from paths_of(v, prefix + (i,))


def check_load(path):
    try:
        corners = CornerSet.load(str(path))
    except CornersError as exc:
        message = str(exc)
        assert '\n' not in message and str(path) in message, message
        return 'refused'
    assert isinstance(corners.board, Board) and corners.corners.shape == (len(corners), corners.board.count, 2)
    assert np.all(np.isfinite(corners.corners))
    assert np.all(corners.corners >= -0.5) and np.all(corners.corners[..., 0] <= corners.width - 0.5)
    assert np.all(corners.corners[..., 1] <= corners.height - 0.5)
    assert isinstance(corners.width, int) and isinstance(corners.height, int) and corners.width > 0
    return 'loaded'


@examples(150)
@given(value=json_values)
def test_any_json_value(tmp_path_factory, value):
    CASES['any JSON value'] += 1
    path = tmp_path_factory.mktemp('c') / 'corners.json'
    path.write_text(json.dumps(value))
    check_load(path)


@examples(300)
@given(data=st.data())
def test_valid_files_with_one_field_mutated(tmp_path_factory, data):
    CASES['one field mutated'] += 1
    record = valid_file(*data.draw(st.sampled_from([(4, 3), (3, 4), (3, 2)])))
    where = data.draw(st.sampled_from(list(paths_of(record))[1:]))
    new = data.draw(st.sampled_from(NASTY) | json_values)
    parent = record
    for key in where[:-1]:
        parent = parent[key]
    if data.draw(st.booleans()) and isinstance(parent, dict):
        del parent[where[-1]]
    else:
        parent[where[-1]] = new
    path = tmp_path_factory.mktemp('c') / 'corners.json'
    path.write_text(json.dumps(record))
    check_load(path)


@examples(100)
@given(blob=st.binary(max_size=300))
def test_arbitrary_bytes(tmp_path_factory, blob):
    CASES['arbitrary bytes'] += 1
    path = tmp_path_factory.mktemp('c') / 'corners.json'
    path.write_bytes(blob)
    check_load(path)


def test_the_unmutated_files_load(tmp_path):
    for size in [(4, 3), (3, 4), (3, 2)]:
        path = tmp_path / f'{size}.json'
        path.write_text(json.dumps(valid_file(*size)))
        assert check_load(path) == 'loaded'


def test_saved_files_load_back_unchanged(tmp_path):
    record = valid_file()
    original = CornerSet.from_dict(record)
    path = tmp_path / 'out' / 'corners.json'
    original.save(str(path))
    loaded = CornerSet.load(str(path))
    assert loaded.names == original.names and np.array_equal(loaded.corners, original.corners)
    assert (loaded.width, loaded.height, loaded.board) == (original.width, original.height, original.board)
    assert sorted(os.listdir(path.parent)) == ['corners.json']  # no temporary file left
    assert math.isfinite(json.loads(path.read_text())['board']['square'])
