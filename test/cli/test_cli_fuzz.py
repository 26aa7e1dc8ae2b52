"""Property test of the zeroshot-calib command line: argv generated from the parser itself.

Every subcommand gets random flags (taken from its argparse actions) with random values (valid
ones, nan / inf / -1 / huge / text / paths that do not exist or are directories), and
``solve --batch`` random CSV files (BOMs, comments, blank lines, good / misspelt / duplicate
headers, short and long rows, path-like names). Whatever the input:

- the exit status is 0, 1 or 2 (1 only for a --batch run with failed rows);
- stderr never holds a Python traceback or an "internal error", and every line of it is one
  ``zeroshot-calib...`` message; with status 2 it is exactly one line (the error);
- no Python warning is emitted (a real run would print it as extra stderr lines);
- --json output and --batch lines are strict JSON; --yaml-dir files stay inside the directory.

main() runs in-process (fast); a few runs go through a real subprocess. The number of cases per
surface is printed at the end (``-s``); ZEROSHOT_FUZZ_SCALE multiplies it (default 1).
"""
import argparse
import contextlib
import io
import json
import os
import subprocess
import sys
import warnings
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fuzz_settings import examples
from zeroshot_calib_ros.cli import build_parser, main
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration

CASES = Counter()
STATUSES = Counter()
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope='module', autouse=True)
def report_counts():
    yield
    print('\nfuzz cases per surface: ' + ', '.join(f'{k} {v}' for k, v in sorted(CASES.items()))
          + f' (total {sum(CASES.values())}); exit statuses: '
          + ', '.join(f'{k} {v}' for k, v in sorted(STATUSES.items())))


# -- files the generated command lines point at --------------------------------------------------

@pytest.fixture(scope='module')
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp('fuzz')
    inp, out = root / 'in', root / 'out'
    inp.mkdir()
    out.mkdir()
    image = np.zeros((36, 64, 3), np.uint8)
    image[::4] = 255
    cv2.imwrite(str(inp / 'img.png'), image)
    cv2.imwrite(str(inp / 'square.png'), np.zeros((40, 40), np.uint8))
    (inp / 'garbage.png').write_bytes(b'\x89PNG not really')
    (inp / 'empty.png').write_bytes(b'')
    good = CameraCalibration(64, 36, [[30, 0, 32], [0, 30, 18], [0, 0, 1]], 'equidistant', [0.01, 0, 0, 0])
    good.save(str(inp / 'calib.yaml'))
    CameraCalibration(128, 72, good.K * [[2], [2], [1]], 'equidistant', [0.01, 0, 0, 0]).save(str(inp / 'calib2x.yaml'))
    (inp / 'inf.yaml').write_text('image_width: .inf\nimage_height: 36\n')
    (inp / 'list.yaml').write_text('- 1\n- 2\n')
    (inp / 'broken.yaml').write_text('image_width: [\n')
    sys.path.insert(0, str(Path(__file__).parent))
    from test_calibration import TRUE, synthetic_corners
    synthetic_corners(TRUE, 3).save(str(inp / 'corners.json'))
    CameraCalibration(TRUE.width, TRUE.height, [[300, 0, 400], [0, 300, 250], [0, 0, 1]], 'equidistant',
                      [-0.5, 0, 0, 0]).save(str(inp / 'turns.yaml'))
    CameraCalibration(TRUE.width, TRUE.height, [[300, 0, 404], [0, 300, 258], [0, 0, 1]], 'equidistant',
                      [0.02, 0, 0, 0]).save(str(inp / 'true_size.yaml'))
    (inp / 'cams.csv').write_text('name,width,height,hfov,vfov,dfov\nw1,1920,1080,118,69,\n')
    (inp / 'dir').mkdir()
    not_dir = inp / 'plainfile'
    not_dir.write_text('')
    inputs = [str(p) for p in sorted(inp.iterdir())] + [str(not_dir / 'below'), str(inp / 'missing.png'),
                                                         '', '-', 'x' * 300]
    outputs = [str(out / name) for name in ('o.png', 'o.jpg', 'o.tiff', 'o.xyz', 'o', 'o.exr', 'o.PNG',
                                            'c.yaml', 'c.json', 'sub/deeper/o.png', 'ydir', '.hidden.png')]
    outputs += [str(not_dir / 'below.png'), str(out), str(inp / 'dir'), '', 'x' * 300 + '.png']
    return {'root': root, 'in': inp, 'out': out, 'inputs': inputs, 'outputs': outputs,
            'image': str(inp / 'img.png'), 'corners': str(inp / 'corners.json')}


# -- values --------------------------------------------------------------------------------------

NASTY = ['nan', 'NaN', 'inf', '-inf', '-1', '0', '-0', '1e309', '1e400', '99999999999', '100001',
         '1e-320', 'abc', '', ' ', '1,5', '0x10', '1_000', '١٢٠', '--', '-h', '1920.0', '1920.5', '\x00']
PLAUSIBLE = ['1', '2', '0.5', '1920', '1080', '640', '360', '64', '36', '90', '118', '69', '133', '150',
             '179.9', '180', '200', '206', '359.9', '360', '8x6', '0.05', '3']

values = st.one_of(
    st.sampled_from(NASTY + PLAUSIBLE),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10 ** 12, 10 ** 12).map(str),
    st.text(max_size=12),
)

OUTPUT_OPTIONS = {'-o', '--output', '--yaml', '--save-corners', '--yaml-dir'}
INPUT_OPTIONS = {'--batch', '--calibration', '--corners', '--spec-from', '--single'}


def _subparsers():
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return parser, action.choices


PARSER, SUBPARSERS = _subparsers()


def _options(command):
    """[(option string, takes a value, choices)] of a subcommand, from its parser."""
    found = []
    for action in SUBPARSERS[command]._actions:
        if not action.option_strings or isinstance(action, argparse._HelpAction):
            continue
        takes_value = action.nargs != 0
        for option in action.option_strings:
            found.append((option, takes_value, action.choices))
    return found


@st.composite
def flag(draw, command, files):
    option, takes_value, choices = draw(st.sampled_from(_options(command)))
    if not takes_value:
        return [option]
    if choices is not None and draw(st.booleans()):
        value = str(draw(st.sampled_from(list(choices))))
    elif option in OUTPUT_OPTIONS:
        value = draw(st.sampled_from(files['outputs']))
    elif option in INPUT_OPTIONS and draw(st.integers(0, 3)):
        value = draw(st.sampled_from(files['inputs']))
    elif draw(st.booleans()):
        value = draw(st.sampled_from(PLAUSIBLE))
    else:
        value = draw(values)
    if draw(st.integers(0, 9)) == 0:
        return [f'{option}={value}'] if option.startswith('--') else [option + value]
    return [option, value]


@st.composite
def argv_for(draw, command, files, base):
    """``command`` + a valid base (sometimes dropped or cut) + 0..5 random flags."""
    args = list(base)
    if draw(st.integers(0, 4)) == 0:
        args = args[:draw(st.integers(0, len(args)))]
    for _ in range(draw(st.integers(0, 4))):
        extra = draw(flag(command, files))
        at = draw(st.integers(0, len(args)))
        args[at:at] = extra
    return [command, *args]


# -- batch CSV files -----------------------------------------------------------------------------

HEADERS = ['name,width,height,hfov,vfov,dfov', 'name,width,height,hfvo,vfov,dfov', 'Name, WIDTH ,height,hfov',
           'width,height,hfov,vfov,name', 'name,width,height,hfov,vfov,dfov,circle_diameter,circle_fov',
           'name,width,width,hfov', 'name,width,height,hfov,', 'name', 'nmae,widht,heigth,hfov',
           'name,width,height,hfov,vfov,dfov,description', '"name","width","height","hfov"']
NAMES = ['w1', 'c905', '../../etc/evil', '/abs/path', 'a/b', 'a_b', 'A_B', '..', '.', '', ' ', 'x' * 300,
         'カメラ', 'con', 'nul\x01', 'a\\b', '"quoted, name"', 'tab\tname', '#notcomment', 'é' * 200]


@st.composite
def csv_text(draw):
    lines = []
    if draw(st.booleans()):
        lines.append(draw(st.sampled_from(HEADERS)))
    for _ in range(draw(st.integers(0, 6))):
        kind = draw(st.integers(0, 9))
        if kind == 0:
            lines.append('# ' + draw(st.text(max_size=10)))
        elif kind == 1:
            lines.append(draw(st.sampled_from(['', '   ', '\t'])))
        else:
            cells = [draw(st.sampled_from(NAMES) | st.text(max_size=8))]
            cells += [draw(st.sampled_from(NASTY + PLAUSIBLE) | values) for _ in range(draw(st.integers(0, 8)))]
            if draw(st.integers(0, 2)) == 0:  # a realistic row
                cells = [cells[0], draw(st.sampled_from(['1920', '1280', '848', '1920.0', '640'])),
                         draw(st.sampled_from(['1080', '720', '800', '480'])),
                         draw(st.sampled_from(['118', '63.1', '206', '90', '', '360'])),
                         draw(st.sampled_from(['69', '', '172', '60'])), draw(st.sampled_from(['', '133', '100']))]
            lines.append(','.join(c.replace('\n', ' ').replace('\r', ' ') for c in cells))
    newline = draw(st.sampled_from(['\n', '\r\n']))
    text = newline.join(lines) + (newline if draw(st.booleans()) else '')
    if draw(st.integers(0, 3)) == 0:
        text = '\ufeff' + text
    data = text.encode('utf-8')
    if draw(st.integers(0, 15)) == 0:
        data += b'\xff\xfe'
    return data


# -- running and the invariants ------------------------------------------------------------------

def run(argv):
    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stdout(out), \
            contextlib.redirect_stderr(err):
        warnings.simplefilter('always')
        try:
            status = main(argv)
        except SystemExit as exc:
            status = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    return status, out.getvalue(), err.getvalue(), [str(w.message) for w in caught]


def strict_json(text):
    def reject(constant):
        raise ValueError(f'not strict JSON: {constant}')
    return json.loads(text, parse_constant=reject)


PROGRESS = ('zeroshot-calib: refine round ', 'zeroshot-calib: calibrate: ', 'zeroshot-calib: evaluate: ')
"""The progress lines --progress asks for (one per step where stderr is not a terminal)."""
NOT_ADOPTED = ('zeroshot-calib: not refined: ', 'zeroshot-calib: board fit not adopted: ')
"""The one line of exit status 3: refine / calibrate ran but did not adopt their result."""


def check(argv, status, out, err, caught, batch=False):
    STATUSES[status] += 1
    where = f'argv={argv!r}\nstatus={status}\nstderr={err!r}\nstdout={out[:400]!r}'
    assert status in (0, 1, 2, 3), where
    assert status != 1 or batch, where
    assert status != 3 or argv[:1] in (['refine'], ['calibrate']), where
    assert 'Traceback' not in err and 'internal error' not in err, where
    assert not caught, f'{where}\nwarnings={caught}'
    lines = [line for line in err.splitlines() if not line.startswith(PROGRESS)]
    assert all(line.startswith('zeroshot-calib') for line in lines), where
    if status == 2:
        assert len(lines) == 1 and ': error: ' in lines[0], where
    assert (status == 3) == any(line.startswith(NOT_ADOPTED) for line in lines), where
    if status in (0, 1, 3) and ('--json' in argv or batch) and out.strip() and '-h' not in argv and '--help' not in argv:
        for line in (out.splitlines() if batch else [out]):
            strict_json(line)


SOLVE_BASE = ['--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69']


@given(data=st.data())
@examples(150)
def test_solve(files, data):
    base = data.draw(st.sampled_from([SOLVE_BASE, SOLVE_BASE + ['--json'], ['--preset', 'gopro_hero9_wide'],
                                      ['--width', '848', '--height', '800', '--hfov', '206', '--json'], []]))
    argv = data.draw(argv_for('solve', files, base))
    batch = '--batch' in argv or any(a.startswith('--batch=') for a in argv)
    CASES['solve (--batch given as a flag)' if batch else 'solve'] += 1
    check(argv, *run(argv), batch=batch)


def test_a_batch_row_with_a_fov_no_lens_has_is_refused_naming_the_fov(tmp_path):
    """Found by the fuzz run: hfov 1e-320 (a BOM before the name) overflowed its focal length with
    numpy warnings and was refused as "K (camera_matrix) is invalid"; the row's error names the
    FOV and its range, with no warning."""
    path = tmp_path / 'cams.csv'
    path.write_bytes(b'\xef\xbb\xbfw1,1,5,1e-320\nw2,640,480,90\n')
    status, out, err, caught = run(['solve', '--batch', str(path)])
    assert status == 1 and not caught, (err, caught)
    first, second = [strict_json(line) for line in out.splitlines()]
    assert first['name'] == 'w1' and first['error'].startswith('hfov = 1e-320 is invalid: allowed: degrees, at least 0.01')
    assert 'error' not in second and second['name'] == 'w2'


@given(data=st.data(), text=csv_text())
@examples(150)
def test_solve_batch(files, data, text):
    CASES['solve --batch (generated CSV)'] += 1
    number = CASES['solve --batch (generated CSV)']
    path = files['root'] / f'batch{number}.csv'
    path.write_bytes(text)
    yaml_dir = files['root'] / f'batch{number}' / 'yaml'
    argv = ['solve', '--batch', str(path)]
    if data.draw(st.booleans()):
        argv += ['--yaml-dir', str(yaml_dir)]
    extra = data.draw(st.lists(st.sampled_from([['--json'], ['--model', 'wide'], ['--model', 'auto'],
                                                ['--distortion-model', 'plumb_bob'], ['--balance', '1'],
                                                ['--balance', 'nan'], ['--method', 'newton'],
                                                ['--hfov', '90'], ['--camera-name', 'x']]), max_size=2))
    argv += [a for e in extra for a in e]
    status, out, err, caught = run(argv)
    check(argv, status, out, err, caught, batch=True)
    records = [strict_json(line) for line in out.splitlines()]
    if status == 2:
        assert out == '', (argv, out)
    assert (status == 1) == any('error' in r for r in records) or status == 2, (argv, out, err)
    for record in records:
        if 'yaml' in record:
            written = Path(record['yaml']).resolve()
            assert written.parent == yaml_dir.resolve() and written.is_file(), record['yaml']
            assert len(written.name.encode()) <= 120
    if yaml_dir.exists():
        assert len(list(yaml_dir.iterdir())) == sum('yaml' in r for r in records)
        assert not [p for p in (files['root'] / f'batch{number}').iterdir() if p.name != 'yaml']


@given(data=st.data())
@examples(25)
def test_presets(files, data):
    CASES['presets'] += 1
    argv = data.draw(argv_for('presets', files, data.draw(st.sampled_from([[], ['--json']]))))
    check(argv, *run(argv))


@given(data=st.data())
@examples(100)
def test_rectify(files, data):
    CASES['rectify'] += 1
    image = data.draw(st.sampled_from([files['image']] * 4 + files['inputs']))
    out = data.draw(st.sampled_from([str(files['out'] / 'r.png')] * 3 + files['outputs']))
    base = data.draw(st.sampled_from([[image, '-o', out, '--hfov', '118', '--vfov', '69'],
                                      [image, '-o', out, '--calibration', str(files['in'] / 'calib.yaml')],
                                      [image, '-o', out, '--calibration', str(files['in'] / 'calib2x.yaml')],
                                      [image, '-o', out, '--preset', 'gopro_hero9_wide'],
                                      [image, '-o', out]]))
    argv = data.draw(argv_for('rectify', files, base))
    check(argv, *run(argv))


@given(data=st.data())
@examples(20)
def test_calibrate(files, data):
    CASES['calibrate'] += 1
    base = data.draw(st.sampled_from([['--corners', files['corners'], '--hfov', '150'],
                                      ['--corners', files['corners'], '--json'],
                                      ['--corners', files['corners'], '--single', 'view-01.png', '--hfov', '150']]))
    argv = data.draw(argv_for('calibrate', files, base))
    check(argv, *run(argv))


@given(data=st.data())
@examples(10)
def test_evaluate(files, data):
    CASES['evaluate'] += 1
    base = data.draw(st.sampled_from([
        ['--corners', files['corners'], '--hfov', '150', '--shots', '0'],
        ['--corners', files['corners'], '--spec-from', str(files['in'] / 'turns.yaml'), '--shots', '0'],
        ['--corners', files['corners'], '--spec-from', str(files['in'] / 'true_size.yaml'), '--runs', '1', '--json'],
        ['--corners', files['corners'], '--spec-from', str(files['in'] / 'inf.yaml')]]))
    argv = data.draw(argv_for('evaluate', files, base))
    if any(a in ('--shots', '--runs') or a.startswith(('--shots=', '--runs=')) for a in argv[-6:]):
        argv += ['--runs', '1']  # keep the slow single-shot table short
    check(argv, *run(argv))


@given(argv=st.lists(st.sampled_from(['--version', '-h', '--help', 'solve', 'presets', 'rectify', 'calibrate',
                                      'evaluate', 'frobnicate', '--json', '--', '-x', '']) | values, max_size=4))
@examples(60)
def test_top_level(argv):
    CASES['top level'] += 1
    check(argv, *run(argv))


# -- a few real processes: what a user's shell sees (OpenCV's own stderr output included) ----------

ENTRY = 'import sys; from zeroshot_calib_ros.cli import main; sys.exit(main())'  # the console script
INSTALLED = REPO / 'install' / 'zeroshot_calib_ros' / 'lib' / 'zeroshot_calib_ros' / 'zeroshot-calib'


def _installed_is_current():
    installed = list((REPO / 'install' / 'zeroshot_calib_ros' / 'lib').glob('python3*/site-packages/'
                                                                          'zeroshot_calib_ros/cli/command.py'))
    return INSTALLED.exists() and installed and installed[0].read_bytes() == (REPO / 'zeroshot_calib_ros' /
                                                                              'cli' / 'command.py').read_bytes()


def subprocess_cases(files):
    bad_csv = files['root'] / 'sub_bad.csv'
    bad_csv.write_bytes(b'\xef\xbb\xbfname,width,height,hfvo\nw1,1920,1080,118\n')
    return [
        (['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69',
          '--distortion-model', 'plumb_bob', '--json'], 0),
        (['solve', '--batch', str(bad_csv)], 2),
        (['rectify', files['image'], '-o', str(files['out'] / 'x.exr'), '--hfov', '118'], 2),
        (['rectify', str(files['in'] / 'missing.png'), '-o', str(files['out'] / 'x.png'), '--hfov', '118'], 2),
        (['rectify', str(files['in'] / 'garbage.png'), '-o', str(files['out'] / 'x.png'), '--hfov', '118'], 2),
        (['evaluate', '--corners', files['corners'], '--spec-from', str(files['in'] / 'inf.yaml')], 2),
        (['solve', '--hfov', 'nan'], 2),
        (['--version'], 0),
    ]


@pytest.mark.parametrize('launcher', ['console-entry', 'installed-script'])
def test_real_processes(files, launcher):
    if launcher == 'installed-script' and not _installed_is_current():
        pytest.skip('the colcon install tree is missing or older than cli/command.py (colcon build refreshes it)')
    prefix = [sys.executable, '-c', ENTRY] if launcher == 'console-entry' else [str(INSTALLED)]
    env = dict(os.environ)
    if launcher == 'installed-script':  # what sourcing install/setup.bash adds
        site = next((REPO / 'install' / 'zeroshot_calib_ros' / 'lib').glob('python3*/site-packages'))
        env['PYTHONPATH'] = os.pathsep.join([str(site)] + [p for p in [env.get('PYTHONPATH')] if p])
    for argv, expected in subprocess_cases(files):
        CASES[f'subprocess ({launcher})'] += 1
        done = subprocess.run(prefix + argv, capture_output=True, text=True, cwd=REPO, timeout=120, env=env)
        where = f'{argv}: {done.returncode} {done.stderr!r}'
        assert done.returncode == expected, where
        assert 'Traceback' not in done.stderr and '[ WARN' not in done.stderr, where
        lines = done.stderr.splitlines()
        assert all(line.startswith('zeroshot-calib') for line in lines), where
        if expected == 2:
            assert len(lines) == 1, where
