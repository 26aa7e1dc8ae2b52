"""Every file the command line reads, as an attacker or a careless user gives it: YAML alias bombs,
devices, FIFOs, oversized files, images declaring more pixels than the budget, truncated or
corrupt images, images with NaN / inf, duplicates; CSV rows with odd line breaks; numbers in
notations other than ASCII decimals; options checked before any computation. Each case must end
quickly with one line naming the file or option, status 2, and no output file written."""
import json
import os
import resource
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from zeroshot_calib_ros.cli import main
MAX_IMAGE_PIXELS = 50_000_000  # the stated budget (--help, errors)

REPO = Path(__file__).resolve().parents[2]
ENTRY = 'import sys; from zeroshot_calib_ros.cli import main; sys.exit(main(sys.argv[1:]))'
MEMORY_LIMIT = 1536 << 20
"""Address space allowed to a CLI process in these tests (imports need a few hundred MB)."""


def alias_bomb(levels=9):
    """A 'billion laughs' YAML document: a few hundred bytes whose aliases expand to 9**levels strings."""
    names = 'abcdefghijklmnop'
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for previous, name in zip(names, names[1:levels]):
        lines.append(f'{name}: &{name} [' + ','.join([f'*{previous}'] * 9) + ']')
    lines.append(f'image_width: *{names[levels - 1]}')
    return '\n'.join(lines) + '\n'


def png_declaring(width, height):
    """A valid 1-bit greyscale PNG of width x height, all black: a few hundred kB on disk, but
    width x height bytes once OpenCV decodes it to 8 bits."""
    def chunk(kind, data):
        return struct.pack('>I', len(data)) + kind + data + struct.pack('>I', zlib.crc32(kind + data))
    row = b'\0' * (1 + (width + 7) // 8)
    compressor = zlib.compressobj(9)
    idat = b''.join(compressor.compress(row) for _ in range(height)) + compressor.flush()
    return (b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', width, height, 1, 0, 0, 0, 0))
            + chunk(b'IDAT', idat) + chunk(b'IEND', b''))


def run_process(argv, timeout=60):
    """The CLI in its own process with at most MEMORY_LIMIT of address space: (status, stderr
    lines, seconds). A hang fails the test by its timeout."""
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    start = time.monotonic()
    done = subprocess.run([sys.executable, '-c', ENTRY, *map(str, argv)], capture_output=True, text=True,
                          cwd=REPO, timeout=timeout, preexec_fn=limit)
    return done.returncode, done.stderr.splitlines(), time.monotonic() - start


def one_line_error(status, err, *words):
    assert status == 2, err
    assert len(err) == 1 and err[0].startswith('zeroshot-calib: error: '), err
    assert 'internal error' not in err[0] and 'Traceback' not in err[0], err
    for word in words:
        assert word in err[0], (word, err)


def run(capsys, *argv):
    try:
        status = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's usage errors
        status = exc.code
    out, err = capsys.readouterr()
    return status, out, err.splitlines()


@pytest.fixture(scope='module')
def chessboard_dir(tmp_path_factory):
    return tmp_path_factory.mktemp('files')


# --- 1. YAML alias bombs ----------------------------------------------------------------------------

@pytest.mark.parametrize('command', ['rectify', 'evaluate'])
def test_a_yaml_alias_bomb_is_refused_quickly_in_bounded_memory(tmp_path, command):
    bomb = tmp_path / 'bomb.yaml'
    bomb.write_text(alias_bomb())
    assert len(bomb.read_bytes()) < 1000
    if command == 'rectify':
        image = tmp_path / 'in.png'
        cv2.imwrite(str(image), np.zeros((90, 160), np.uint8))
        argv = ['rectify', image, '-o', tmp_path / 'out.png', '--calibration', bomb]
    else:
        from zeroshot_calib_ros.core.checkerboard.corners import CornerSet, parse_board
        grid = np.stack(np.meshgrid(np.arange(8) * 10.0 + 40, np.arange(6) * 10.0 + 20), -1).reshape(-1, 2)
        corners = tmp_path / 'corners.json'
        CornerSet(160, 90, parse_board('8x6', 0.1), ['a.png'], grid[None]).save(str(corners))
        argv = ['evaluate', '--corners', corners, '--spec-from', bomb]
    status, err, seconds = run_process(argv)
    one_line_error(status, err, str(bomb))
    assert 'alias' in err[0] or 'image_width' in err[0], err
    assert not (tmp_path / 'out.png').exists()
    assert seconds < 20, seconds


# --- 2. devices, FIFOs, oversized files -------------------------------------------------------------

def _fifo(tmp_path, name):
    path = tmp_path / name
    os.mkfifo(path)
    return path


def _special_files(tmp_path, name, oversized_bytes):
    big = tmp_path / f'big_{name}'
    with open(big, 'wb') as f:
        f.truncate(oversized_bytes)
    return {'device': Path('/dev/zero'), 'fifo': _fifo(tmp_path, name), 'oversized': big}


@pytest.mark.parametrize('kind', ['device', 'fifo', 'oversized'])
def test_calibrate_corners_that_are_not_a_regular_file_of_a_sane_size(tmp_path, kind):
    path = _special_files(tmp_path, 'corners.json', 300 << 20)[kind]
    status, err, seconds = run_process(['calibrate', '--corners', path], timeout=30)
    one_line_error(status, err, str(path))
    assert seconds < 20


@pytest.mark.parametrize('kind', ['device', 'fifo', 'oversized'])
def test_solve_batch_that_is_not_a_regular_file_of_a_sane_size(tmp_path, kind):
    path = _special_files(tmp_path, 'cams.csv', 300 << 20)[kind]
    status, err, seconds = run_process(['solve', '--batch', path], timeout=30)
    one_line_error(status, err, str(path))
    assert seconds < 20


@pytest.mark.parametrize('kind', ['device', 'fifo', 'directory'])
def test_read_capped_refuses_what_is_not_a_regular_file_without_reading_it(tmp_path, kind):
    """Every file input goes through read_capped: a device, a FIFO or a directory is named as such
    and refused before a byte is read (a device read up to the cap would take seconds and memory,
    a FIFO without a writer would block)."""
    from zeroshot_calib_ros.core.file_input import InputFileError, read_capped
    path = {'device': Path('/dev/zero'), 'fifo': _fifo(tmp_path, 'x.yaml'), 'directory': tmp_path}[kind]
    start = time.monotonic()
    with pytest.raises(InputFileError) as info:
        read_capped(path, 256 << 20, 'a calibration file')
    words = {'device': 'a device', 'fifo': 'a FIFO', 'directory': 'a directory'}[kind]
    assert str(info.value) == f'cannot read {path}: it is {words}, not a regular file: allowed: a calibration file'
    assert time.monotonic() - start < 0.5


@pytest.mark.parametrize('kind', ['device', 'fifo'])
def test_calibration_and_image_inputs_that_are_not_regular_files(tmp_path, kind):
    calibration = _special_files(tmp_path, 'cam.yaml', 0)[kind]
    image = tmp_path / 'in.png'
    cv2.imwrite(str(image), np.zeros((90, 160), np.uint8))
    status, err, _ = run_process(['rectify', image, '-o', tmp_path / 'out.png', '--calibration', calibration],
                                 timeout=30)
    one_line_error(status, err, str(calibration))
    special = Path('/dev/zero') if kind == 'device' else _fifo(tmp_path, 'img.png')
    for argv in (['rectify', special, '-o', tmp_path / 'out.png', '--hfov', '100'],
                 ['refine', special, '--hfov', '100'],
                 ['calibrate', special]):
        status, err, _ = run_process(argv, timeout=30)
        one_line_error(status, err, str(special))


# --- 3. solve --batch: rows are CSV records ----------------------------------------------------------

@pytest.mark.parametrize('separator', ['\x0c', '\x85', '\u2028', '\x1c', '\r'])
def test_batch_rows_end_only_at_newlines(tmp_path, capsys, separator):
    """A character that str.splitlines() takes as a line end is part of the row: no second camera
    is made of the rest of the row (here the row is malformed: its name or a number has it)."""
    path = tmp_path / 'cams.csv'
    path.write_text(f'name,width,height,hfov,vfov\nw1,1920,1080,118,69\nbad{separator}w2,1920,1080,118,69\n',
                    encoding='utf-8', newline='')
    yaml_dir = tmp_path / 'out'
    status, out, err = run(capsys, 'solve', '--batch', path, '--yaml-dir', yaml_dir)
    records = [json.loads(line) for line in out.splitlines()]
    names = [r['name'] for r in records]
    assert 'w2' not in names and len(records) == 2, records
    assert status == 1 and 'error' in records[1] and records[1]['line'] == 3
    assert not yaml_dir.exists() or list(yaml_dir.iterdir()) == []


def test_batch_quoted_cell_with_a_newline_is_one_cell(tmp_path, capsys):
    """What spreadsheets write: the quoted name spans two lines; no camera 'line"' is made of its
    second half, and the line numbers of the rows after it stay right."""
    path = tmp_path / 'cams.csv'
    path.write_text('name,width,height,hfov,vfov\nw1,1920,1080,118,69\n"two\nline",1920,1080,118,69\n'
                    'w3,1280,720,90,-1\n', newline='')
    yaml_dir = tmp_path / 'out'
    status, out, err = run(capsys, 'solve', '--batch', path, '--yaml-dir', yaml_dir)
    records = [json.loads(line) for line in out.splitlines()]
    assert [r['name'] for r in records] == ['w1', 'two\nline', 'w3'], records
    assert 'error' not in records[1] and records[2]['line'] == 5 and 'vfov' in records[2]['error']
    assert status == 1


def test_batch_unbalanced_quote_is_a_bad_row_with_its_line_number(tmp_path, capsys):
    path = tmp_path / 'cams.csv'
    path.write_text('w1,1920,1080,118,69\n"w2,1920,1080,118,69\n')
    status, out, err = run(capsys, 'solve', '--batch', path)
    records = [json.loads(line) for line in out.splitlines()]
    assert status == 1 and len(records) == 2 and records[1]['line'] == 2 and 'line 2' in records[1]['error']


def test_batch_writes_no_yaml_file_when_any_row_is_bad(tmp_path, capsys):
    path = tmp_path / 'cams.csv'
    path.write_text('w1,1920,1080,118,69\nbroken,1920,1080,-5,69\n')
    yaml_dir = tmp_path / 'out'
    status, out, err = run(capsys, 'solve', '--batch', path, '--yaml-dir', yaml_dir)
    assert status == 1
    assert not yaml_dir.exists() or list(yaml_dir.iterdir()) == []
    assert any('no files written' in line or 'not written' in line for line in err), err


def test_batch_crlf_rows_and_quoted_commas_still_work(tmp_path, capsys):
    path = tmp_path / 'cams.csv'
    path.write_bytes(b'name,width,height,hfov,vfov\r\n"hero, wide",1920,1080,118,69\r\nc2,1280,720,90,60\r\n')
    yaml_dir = tmp_path / 'out'
    status, out, err = run(capsys, 'solve', '--batch', path, '--yaml-dir', yaml_dir)
    assert status == 0, err
    assert [json.loads(line)['name'] for line in out.splitlines()] == ['hero, wide', 'c2']
    assert sorted(p.name for p in yaml_dir.iterdir()) == ['c2.yaml', 'hero__wide.yaml']


# --- 4. the pixel budget ----------------------------------------------------------------------------

@pytest.fixture(scope='module')
def huge_png(tmp_path_factory):
    path = tmp_path_factory.mktemp('huge') / 'huge.png'
    path.write_bytes(png_declaring(20000, 20000))
    assert path.stat().st_size < 1 << 20
    return path


@pytest.mark.parametrize('command', ['rectify', 'refine', 'calibrate'])
def test_an_image_above_the_pixel_budget_is_refused_before_decoding(tmp_path, huge_png, command):
    argv = {'rectify': ['rectify', huge_png, '-o', tmp_path / 'out.png', '--hfov', '100'],
            'refine': ['refine', huge_png, '--hfov', '100', '--yaml', tmp_path / 'out.yaml'],
            'calibrate': ['calibrate', huge_png]}[command]
    status, err, seconds = run_process(argv, timeout=60)
    one_line_error(status, err, str(huge_png), '20000x20000', f'{MAX_IMAGE_PIXELS // 1000000} megapixels')
    assert seconds < 15, seconds
    assert list(tmp_path.iterdir()) == []


def test_help_states_the_pixel_budget(capsys):
    with pytest.raises(SystemExit):
        main(['refine', '--help'])
    assert f'{MAX_IMAGE_PIXELS // 1000000} megapixels' in ' '.join(capsys.readouterr().out.split())


# --- 5. refine: bad images, outputs only after success, duplicates ------------------------------------

def _lines_image(width=320, height=240):
    image = np.full((height, width), 40, np.uint8)
    for x in range(20, width, 40):
        cv2.line(image, (x, 0), (x, height - 1), 220, 2)
    return image


@pytest.mark.parametrize('bad', [np.inf, np.nan])
def test_refine_float_image_with_inf_or_nan_names_the_file(tmp_path, capsys, bad):
    image = _lines_image().astype(np.float32)
    image[5, 5] = bad
    path = tmp_path / 'float.tiff'
    assert cv2.imwrite(str(path), image)
    status, out, err = run(capsys, 'refine', path, '--hfov', '100', '--yaml', tmp_path / 'out.yaml')
    one_line_error(status, err, str(path), 'NaN')
    assert not (tmp_path / 'out.yaml').exists()


def test_refine_writes_no_output_when_the_debug_image_fails(tmp_path, capsys):
    path = tmp_path / 'thin.png'
    cv2.imwrite(str(path), np.tile(np.arange(0, 240, dtype=np.uint8)[:, None], (1, 1)))
    # the FOV across the 240-px side: one FOV takes a real lens' shape, and 100 degrees across the
    # 1-px side would be a lens whose corners see nothing (the ROS fit refuses it before any file)
    status, out, err = run(capsys, 'refine', path, '--vfov', '100', '--yaml', tmp_path / 'out.yaml',
                           '--debug-image', tmp_path / 'debug.png')
    one_line_error(status, err, str(path), '1x240', 'at least 32 px')
    assert not (tmp_path / 'out.yaml').exists() and not (tmp_path / 'debug.png').exists()


def _jpeg(tmp_path, name='photo.jpg'):
    path = tmp_path / name
    assert cv2.imwrite(str(path), cv2.cvtColor(_lines_image(), cv2.COLOR_GRAY2BGR))
    return path


@pytest.mark.parametrize('damage', ['truncated', 'corrupt'])
@pytest.mark.parametrize('command', ['refine', 'rectify'])
def test_a_damaged_jpeg_is_refused_naming_the_file(tmp_path, capsys, damage, command):
    path = _jpeg(tmp_path)
    data = path.read_bytes()
    if damage == 'truncated':
        data = data[:len(data) * 2 // 3]
    else:  # a marker where entropy-coded data should be
        middle = len(data) // 2
        data = data[:middle] + b'\xff\xd3\xff\xd0' * 8 + data[middle + 32:]
    path.write_bytes(data)
    out_file = tmp_path / 'out.yaml'
    argv = (['refine', path, '--hfov', '100', '--yaml', out_file] if command == 'refine' else
            ['rectify', path, '-o', tmp_path / 'out.png', '--hfov', '100'])
    status, out, err = run(capsys, *argv)
    one_line_error(status, err, str(path))
    assert not out_file.exists() and not (tmp_path / 'out.png').exists()


def test_the_same_image_twice_counts_once(tmp_path, capsys):
    path = _jpeg(tmp_path)
    copy = tmp_path / 'copy.jpg'
    copy.write_bytes(path.read_bytes())
    status, out, err = run(capsys, 'refine', path, path, copy, '--hfov', '100', '--json')
    assert status == 0, err
    record = json.loads(out)
    assert record['refinement']['images_used'] <= 1
    assert any('once' in line and str(copy) in line for line in err), err


# --- 6. numbers and options --------------------------------------------------------------------------

@pytest.mark.parametrize('option, text', [('--width', '1_920'), ('--hfov', '1_18'), ('--width', '١٩٢٠'),
                                          ('--width', '１９２０'), ('--hfov', '١١٨'), ('--hfov', ' 118'),
                                          ('--height', '1080 ')])
def test_numbers_are_ascii_decimals_only(capsys, option, text):
    argv = {'--width': '1920', '--height': '1080', '--hfov': '118'}
    argv[option] = text
    status, out, err = run(capsys, 'solve', *[x for kv in argv.items() for x in kv], '--vfov', '69')
    assert status == 2 and len(err) == 1 and option in err[0], err


def test_batch_cells_are_ascii_decimals_only(tmp_path, capsys):
    path = tmp_path / 'cams.csv'
    path.write_text('w1,1_920,1080,118,69\nw2,1920,1080,１１８,69\n')
    status, out, err = run(capsys, 'solve', '--batch', path)
    assert status == 1
    assert all('error' in json.loads(line) for line in out.splitlines())


@pytest.mark.parametrize('extra, word', [(['--balance', 'nan'], '--balance'), (['--fov-scale', '0'], '--fov-scale'),
                                         (['--yaml', 'out.txt'], '--yaml'), (['--fov-tolerance', '-1'],
                                                                             '--fov-tolerance')])
def test_options_are_checked_before_any_computation(tmp_path, capsys, monkeypatch, extra, word):
    """Checked before the fit: the fit is replaced by one that fails the test if it runs."""
    from zeroshot_calib_ros.cli import refine, solve

    def no_fit(*args, **kwargs):
        raise AssertionError('computed before checking the options')
    for verb in (solve, refine):
        monkeypatch.setattr(verb, 'solve_zero_shot', no_fit)
    monkeypatch.chdir(tmp_path)
    status, out, err = run(capsys, 'solve', '--width', '1920', '--height', '1080', '--hfov', '118', *extra)
    one_line_error(status, err, word)
    image = tmp_path / 'in.png'
    cv2.imwrite(str(image), _lines_image())
    status, out, err = run(capsys, 'refine', image, '--hfov', '100', *extra)
    one_line_error(status, err, word)


# --- 7. presets at another aspect ratio ---------------------------------------------------------------

def test_solve_refuses_a_preset_at_another_aspect_ratio(capsys):
    status, out, err = run(capsys, 'solve', '--preset', 'gopro_hero9_wide', '--width', '1440', '--height', '1080')
    one_line_error(status, err, 'gopro_hero9_wide', '1920x1080')
    status, out, err = run(capsys, 'solve', '--preset', 'gopro_hero9_wide', '--width', '1280', '--height', '720',
                           '--json')
    assert status == 0 and json.loads(out)['width'] == 1280


@pytest.mark.parametrize('command', ['refine', 'rectify'])
def test_an_empty_image_file_is_refused_as_empty(tmp_path, capsys, command):
    """An empty file (a photo whose copy failed): one line saying so, not OpenCV's assertion about
    its buffer."""
    path = tmp_path / 'empty.png'
    path.write_bytes(b'')
    argv = (['refine', path, '--hfov', '100'] if command == 'refine' else
            ['rectify', path, '-o', tmp_path / 'out.png', '--hfov', '100'])
    status, out, err = run(capsys, *argv)
    one_line_error(status, err, str(path))
    assert 'the file is empty' in err[0] and 'OpenCV' not in err[0] and 'Assertion' not in err[0], err


def test_a_debug_image_opencv_cannot_write_names_its_option(tmp_path, capsys):
    """`refine --debug-image out.txt`: the error names --debug-image (the option given), not -o, and
    the formats allowed; nothing is computed or written."""
    path = _jpeg(tmp_path)
    debug = tmp_path / 'out.txt'
    status, out, err = run(capsys, 'refine', path, '--hfov', '100', '--debug-image', debug)
    one_line_error(status, err, f'--debug-image {debug}', 'allowed: ', '.png')
    assert ' -o ' not in err[0] and not debug.exists(), err
