"""What `zeroshot-calib` tells a user beyond the numbers (docs/cli_output.md): the stand-in D
coefficient explained where it is printed and in the file, `rectify`'s summary line, progress of
`calibrate` and `evaluate` on a terminal, plain names beside the paper's in `evaluate`, the
warnings of a calibration file read, and optional tab completion.

(`refine` / `calibrate` whose result is not adopted, exit status 3 and the file comment:
test_cli_refine.py and test_cli_calibrate_checks.py.)"""
import importlib
import io
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

import zeroshot_calib_ros.cli as cli
import zeroshot_calib_ros.cli.output as cli_output
from cli_run import RecordedComputation, result_differences, run_main
from test_calibration import TRUE, spec_of, synthetic_corners
from zeroshot_calib_ros.core import CameraCalibration, CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import NONZERO_EPSILON

REPO = Path(__file__).resolve().parents[2]
PURE_FISHEYE = ['--width', '1920', '--height', '1080', '--circle-diameter', '1000', '--circle-fov', '200']
"""A spec whose camera follows r = f theta exactly: its ROS D is [0, 0, 0, 1e-20] (the stand-in)."""


# -- the stand-in coefficient 1e-20 ------------------------------------------------------------------

def test_the_stand_in_coefficient_is_explained_on_the_D_line_and_in_the_file(tmp_path, capsys):
    """D = [0, 0, 0, 1e-20]: the D line says the lens follows r = f theta, that 1e-20 stands for 0
    and why it is there; the file written says it in a # comment its readers skip."""
    out_yaml = tmp_path / 'camera.yaml'
    status, out, err = run_main(['solve', *PURE_FISHEYE, '--yaml', str(out_yaml)], capsys)
    assert status == 0, err
    d_line = next(line for line in out.splitlines() if line.startswith('D '))
    assert d_line.startswith('D         equidistant [0, 0, 0, 1e-20] (')
    for words in ('r = f * theta', '1e-20 stands for 0', 'image_proc', 'would not rectify', 'moves no pixel'):
        assert words in d_line, d_line
    text = out_yaml.read_text()
    comments = [line for line in text.splitlines() if line.startswith('#')]
    assert len(comments) == 1 and comments[0].startswith('# distortion_coefficients: no correction: ')
    assert '1e-20 stands for 0' in comments[0]
    assert yaml.safe_load(text)['distortion_coefficients']['data'] == [0.0, 0.0, 0.0, NONZERO_EPSILON]
    assert CameraCalibration.load(str(out_yaml)).D.tolist() == [0.0, 0.0, 0.0, NONZERO_EPSILON]


def test_an_ordinary_D_gets_no_note_and_the_file_no_comment(tmp_path, capsys):
    out_yaml = tmp_path / 'camera.yaml'
    status, out, err = run_main(['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69',
                                 '--yaml', str(out_yaml)], capsys)
    assert status == 0, err
    d_line = next(line for line in out.splitlines() if line.startswith('D '))
    assert d_line.endswith(']') and 'stands for' not in d_line
    assert '#' not in out_yaml.read_text()


# -- rectify's summary line --------------------------------------------------------------------------

@pytest.fixture
def image(tmp_path):
    path = tmp_path / 'in.png'
    cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 255, (360, 640, 3)).astype(np.uint8))
    return path


def test_rectify_prints_one_line_with_the_camera_and_the_output(image, tmp_path, capsys):
    """One stdout line (OUT is a file: stdout carries nothing else) naming the output file and size,
    the rectified camera P, the model, where the camera comes from and K's f and principal point:
    those of `solve` for the same spec."""
    out = tmp_path / 'out.png'
    spec = ['--hfov', '118', '--vfov', '69']
    status, printed, err = run_main(['rectify', str(image), '-o', str(out), *spec], capsys)
    assert status == 0 and err == []
    status, solved, _ = run_main(['solve', '--width', '640', '--height', '360', *spec, '--json'], capsys)
    record = json.loads(solved)
    K, P = record['K'], record['P']
    assert printed.count('\n') == 1
    assert printed.strip() == (
        f'wrote {out}: 640x360 pinhole image (f {P[0][0]:.2f} px, principal point ({P[0][2]:.1f}, {P[1][2]:.1f})) '
        f'from {image}; camera: {record["model"]}, zero-shot from hfov 118, vfov 69 deg, '
        f'K f {K[0][0]:.2f} px, principal point ({K[0][2]:.1f}, {K[1][2]:.1f})')
    assert cv2.imread(str(out)).shape == (360, 640, 3)


@pytest.mark.parametrize('given, meaning', [
    (['--hfov', '118'], 'hfov 118 deg alone (taken as the angle across the image width, edge to edge through the '
                        'centre; lens shape assumed from real lenses of that FOV)'),
    (['--dfov', '150'], 'dfov 150 deg alone (taken as the angle across the image diagonal, corner to corner; '
                        'lens shape assumed from real lenses of that FOV)'),
    (['--circle-diameter', '300', '--circle-fov', '190'],
     'circle 300 px across 190 deg alone (the pure equidistant law assumed across the circle)'),
])
def test_rectify_says_what_a_single_fov_was_taken_to_mean(image, tmp_path, capsys, given, meaning):
    status, printed, err = run_main(['rectify', str(image), '-o', str(tmp_path / 'out.png'), *given], capsys)
    assert status == 0
    assert f'zero-shot from {meaning}, K f ' in printed
    assert len(err) == 1 and err[0].startswith('zeroshot-calib: warning: ')  # the details, as `solve` warns


def test_rectify_with_a_calibration_file_names_it_and_its_model(image, tmp_path, capsys):
    calib = tmp_path / 'cam.yaml'
    status, _, _ = run_main(['solve', '--width', '1280', '--height', '720', '--hfov', '118', '--vfov', '69',
                             '--yaml', str(calib)], capsys)
    status, printed, err = run_main(['rectify', str(image), '-o', str(tmp_path / 'out.png'),
                                     '--calibration', str(calib)], capsys)
    assert status == 0, err
    loaded = CameraCalibration.load(str(calib))
    assert (f'camera: equidistant, from {calib} (for 1280x720, scaled), K f {loaded.K[0, 0] / 2:.2f} px, '
            f'principal point ({loaded.K[0, 2] / 2:.1f}, {loaded.K[1, 2] / 2:.1f})') in printed


def test_a_calibration_file_without_distortion_model_is_warned_about(image, tmp_path, capsys):
    """camera_calibration_parsers reads such a file as plumb_bob; so does rectify, and it says so
    (before, it assumed silently), naming the option, the file and what to do."""
    calibration, _ = CameraCalibration.from_solution(solve_zero_shot(CameraSpec(640, 360, 118, 69)), 'plumb_bob')
    text = calibration.to_yaml().replace('distortion_model: plumb_bob\n', '')
    calib = tmp_path / 'old.yaml'
    calib.write_text(text)
    status, _, err = run_main(['rectify', str(image), '-o', str(tmp_path / 'out.png'), '--calibration', str(calib)],
                              capsys)
    assert status == 0
    assert err == [f'zeroshot-calib: warning: --calibration {calib}: distortion_model is missing: assuming plumb_bob '
                   '(as camera_calibration_parsers does); if the coefficients are of another model, add its '
                   'distortion_model line to the file']


# -- progress of calibrate and evaluate ----------------------------------------------------------------

@pytest.fixture(scope='module')
def corners_file(tmp_path_factory):
    path = tmp_path_factory.mktemp('corners') / 'corners.json'
    synthetic_corners(TRUE, 4, noise=0.1, seed=12).save(str(path))
    return path


def spec_flags():
    spec = spec_of(TRUE)
    return ['--hfov', repr(spec.hfov), '--vfov', repr(spec.vfov)]


COMMANDS = {
    'calibrate': lambda corners: ['calibrate', '--corners', str(corners), *spec_flags()],
    'evaluate': lambda corners: ['evaluate', '--corners', str(corners), *spec_flags(), '--runs', '1'],
}
COMPUTATION = {  # what each command computes, with a progress callback: (module, name)
    'calibrate': lambda: (importlib.import_module('zeroshot_calib_ros.core.estimation.board_fit'), 'fit_board'),
    'evaluate': lambda: (importlib.import_module('zeroshot_calib_ros.cli.evaluate'), 'evaluate'),
}


@pytest.mark.parametrize('command', COMMANDS)
def test_progress_is_shown_on_a_terminal_and_silent_on_a_pipe_or_with_json(command, corners_file, capsys,
                                                                          monkeypatch):
    """As `refine`: on a terminal, without --json, one progress line on stderr rewritten in place;
    nothing when stderr is not a terminal or with --json; --progress shows it anywhere, a line per
    step; the result is the same either way."""
    argv = COMMANDS[command](corners_file)
    status, quiet, err = run_main(argv + ['--json'], capsys)
    assert status == 0 and not any(line.startswith(f'zeroshot-calib: {command}:') for line in err), err
    # this run's computation is recorded (run as usual, its reports kept) and replayed in the runs
    # below: what they check is the CLI's printing, which runs each time (cli_run.RecordedComputation)
    computation = RecordedComputation(monkeypatch, *COMPUTATION[command]())
    computation.record()
    status, shown, err = run_main(argv + ['--json', '--progress'], capsys)
    assert len(computation.calls) == 1, f'the CLI ran {computation.name} once, where the test records it'
    steps = [line for line in err if line.startswith(f'zeroshot-calib: {command}: ')]
    assert status == 0 and len(steps) >= 2 and not any('\r' in line for line in err), err
    # two real runs of the computation: with Ubuntu 24.04's numpy 1.26 they differ in the last digits
    # run to run (cli_run.same_result), by up to 1e-3 where a solver stops at its evaluation limit
    # a little elsewhere; a progress callback that changed the computation would move it further
    differences = result_differences(json.loads(shown), json.loads(quiet), rel=1e-2)
    assert not differences, differences
    computation.replay()
    status, text, err = run_main(argv, capsys)
    assert status == 0 and not any(line.startswith(f'zeroshot-calib: {command}:') for line in err)
    monkeypatch.setattr(cli_output, '_is_terminal', lambda stream: True)
    status, _, err = run_main(argv + ['--json'], capsys)
    assert status == 0 and not any(f'zeroshot-calib: {command}:' in line for line in err)
    status = cli.main(argv)
    text_on_terminal, err = capsys.readouterr()  # raw: run_main's splitlines would split at \r
    assert status == 0
    assert err.startswith(f'\rzeroshot-calib: {command}: ') and err.count('\r') >= 2, err
    assert err.split('\n')[1:] in ([''], [])  # the line is ended once, before anything else is said
    assert labels(text_on_terminal) == labels(text)
    assert computation.replayed == 3


@pytest.mark.parametrize('command', COMMANDS)
def test_the_progress_line_ends_before_the_result_and_the_warnings(command, corners_file, monkeypatch):
    """On a terminal stdout and stderr share the screen: the result and any warning start on a
    line of their own, never after the progress line (a spec that calibrate warns about: hfov and
    vfov 10 degrees off the lens's)."""
    spec = spec_of(TRUE)
    argv = [a for a in COMMANDS[command](corners_file)]
    argv[argv.index('--hfov') + 1] = repr(spec.hfov - 10)
    argv[argv.index('--vfov') + 1] = repr(spec.vfov + 10)
    screen = io.StringIO()
    monkeypatch.setattr(cli_output, '_is_terminal', lambda stream: True)
    monkeypatch.setattr(sys, 'stdout', screen)
    monkeypatch.setattr(sys, 'stderr', screen)
    status = cli.main(argv)
    text = screen.getvalue()
    assert status in (0, 3) and '\r' in text, text
    assert command == 'evaluate' or 'zeroshot-calib: warning: ' in text, text  # evaluate warns of nothing here
    for line in text.split('\n'):
        shown = line.split('\r')[-1]  # what a terminal shows of a line rewritten in place
        if '\r' in line:
            assert shown.startswith(f'zeroshot-calib: {command}: ') and 'warning' not in shown, line
            assert not any(word in shown for word in ('data ', 'camera ', 'Table ')), line
    first = 'data     ' if command == 'evaluate' else 'camera    '
    assert f'\n{first}' in text


def labels(text):
    """Each line of a text output with its numbers blanked (they move in the last digits between
    runs on OpenCV 4.6), but its time and note lines (see same_result)."""
    return [re.sub(r'-?\d+(\.\d+)?(e-?\d+)?', '#', line) for line in text.splitlines()
            if not line.startswith(('time ', 'note '))]


def test_calibrate_reports_each_image_searched_for_the_board(tmp_path, capsys):
    paths = []
    for k in range(2):
        paths.append(tmp_path / f'img-{k}.png')
        cv2.imwrite(str(paths[-1]), np.full((120, 160), 128, np.uint8))
    status, _, err = run_main(['calibrate', *map(str, paths), '--progress'], capsys)
    assert status == 2
    assert err[:2] == ['zeroshot-calib: calibrate: finding the board in image 1/2 (img-0.png), found in 0 so far',
                       'zeroshot-calib: calibrate: finding the board in image 2/2 (img-1.png), found in 0 so far']
    assert err[-1].startswith('zeroshot-calib: error: board 8x6')


# -- evaluate: plain names beside the paper's ----------------------------------------------------------

def test_evaluate_gives_every_column_a_plain_name(corners_file, capsys, monkeypatch):
    """Every column of both tables (the paper's names) is listed with a plain name beside it, and
    so are eps and eps_gen (eps_fit); the JSON has the same plain names (of the same evaluation:
    the text run's is recorded and replayed to the JSON run, cli_run.RecordedComputation)."""
    argv = COMMANDS['evaluate'](corners_file)
    computation = RecordedComputation(monkeypatch, *COMPUTATION['evaluate']())
    computation.record()
    status, out, err = run_main(argv, capsys)
    assert status == 0, err
    computation.replay(progress=False)
    lines = out.splitlines()
    key = lines[lines.index("Key to the columns (the paper's name: in plain words)") + 1:]
    key = {line.split('  ')[1].strip(): line.split('  ', 2)[-1].strip() for line in key[:key.index('')]}
    headers = [line for line in lines if line.startswith('camera ')]
    assert len(headers) == 2
    columns = [c for c in headers[0].split()[2:]] + ['OpenCV fisheye']
    columns = [c for c in columns if c not in ('OpenCV', 'fisheye')]
    for column in columns + ['FC_eq.d.(1)', 'Zhang(1)', 'FC_eq.d.(1)+ZS', 'Zhang(N)', 'OpenCV fisheye(1)',
                             'OpenCV fisheye(N)', 'ZS', 'eps', 'eps_gen (eps_fit)']:
        assert key.get(column), (column, key)
    assert key['FC_eq.d.(1)+ZS'] == "checkerboard fit of the paper's fisheye model, 1 image, from zero-shot"
    assert key['Zhang(N)'].endswith(', all 4 images') and key['ZS'].endswith('(no image used)')
    status, out, _ = run_main(argv + ['--json'], capsys)
    assert computation.replayed == 1
    record = json.loads(out)
    assert record['table4']['fc+zs']['plain_name'] == key['FC_eq.d.(1)+ZS']
    assert record['table3']['fc']['plain_name'] == key['FC_eq.d.']


# -- tab completion ------------------------------------------------------------------------------------

def completions(env_extra, line):
    """The completions argcomplete's shell hook gets for ``line`` (None: it printed none and the
    command ran as usual)."""
    env = dict(os.environ, _ARGCOMPLETE='1', COMP_LINE=line, COMP_POINT=str(len(line)), _ARGCOMPLETE_IFS='\n',
               PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get('PYTHONPATH')])))
    env.update(env_extra)
    with tempfile.TemporaryDirectory() as directory:
        env['_ARGCOMPLETE_STDOUT_FILENAME'] = os.path.join(directory, 'completions')
        result = subprocess.run([sys.executable, '-m', 'zeroshot_calib_ros.cli'], env=env, capture_output=True,
                                text=True, timeout=120)
        path = Path(env['_ARGCOMPLETE_STDOUT_FILENAME'])
        text = path.read_text() if path.exists() else ''
    return result, text


def test_tab_completion_when_argcomplete_is_installed():
    pytest.importorskip('argcomplete')
    result, text = completions({}, 'zeroshot-calib ref')
    assert result.returncode == 0 and text.split() == ['refine'], (result.stderr, text)


def test_without_argcomplete_completion_requests_do_not_break_the_command(tmp_path):
    """argcomplete is no dependency: a shell asking for completions without it installed gets the
    command's ordinary behaviour (here: the usage error for a missing command)."""
    blocker = tmp_path / 'argcomplete.py'
    blocker.write_text('raise ImportError("not installed")\n')
    env = {'PYTHONPATH': os.pathsep.join([str(tmp_path), str(REPO)])}
    result, text = completions(env, 'zeroshot-calib ref')
    assert text == '' and result.returncode == 2 and 'the following arguments are required' in result.stderr


# -- docs/cli_output.md's examples -------------------------------------------------------------------

DOC = (REPO / 'docs' / 'cli_output.md').read_text()
SHARED = Path(os.environ.get('ZEROSHOT_SHARED_DATA', REPO.parent / 'shared' / 'data'))


def test_the_documented_D_line_is_what_solve_prints(capsys):
    command = 'zeroshot-calib solve ' + ' '.join(PURE_FISHEYE)
    assert f'```sh\n{command}\n```\n```\nD ' in DOC
    documented = DOC.split(f'{command}\n```\n```\n', 1)[1].split('\n', 1)[0]
    status, out, _ = run_main(command.split()[1:], capsys)
    assert status == 0 and documented in out.splitlines()


@pytest.mark.skipif(not (SHARED / 'ros_fisheye_800x503' / 'left-0000.png').is_file(),
                    reason=f'the shared real data set is missing: {SHARED}')
def test_the_documented_principal_points_of_P_on_the_shared_set(tmp_path, capsys):
    """docs/cli_output.md: FC_eq.d. on the 24 images, K's principal point (399.1, 271.8) is P's;
    OpenCV's rule would give (279.0, 386.5). To 0.5 px (the last digit moves with the OpenCV
    version's corner detection) and 3 px."""
    from zeroshot_calib_ros.core.ros_formats.rectify import new_camera_matrix
    assert "zeroshot-calib calibrate '../shared/data/ros_fisheye_800x503/left-*.png' --yaml camera.yaml" in DOC
    out_yaml = tmp_path / 'camera.yaml'
    status, _, err = run_main(['calibrate', str(SHARED / 'ros_fisheye_800x503' / 'left-*.png'), '--yaml',
                               str(out_yaml)], capsys)
    assert status == 0, err
    calibration = CameraCalibration.load(str(out_yaml))
    np.testing.assert_allclose(calibration.P[:2, 2], [399.1, 271.8], atol=0.5)
    np.testing.assert_allclose(calibration.K[:2, 2], calibration.P[:2, 2], atol=1e-9)
    np.testing.assert_allclose(new_camera_matrix(calibration.camera())[:2, 2], [279.0, 386.5], atol=3)
    assert 'principal\npoint (399.1, 271.8)) OpenCV\'s rule gave P\'s principal point (279.0, 386.5)' in DOC


def test_the_top_level_help_lists_every_exit_status(capsys):
    """`zeroshot-calib --help` (docs/cli_output.md): what 0, 1, 2 and 3 mean."""
    status, out, _ = run_main(['--help'], capsys)
    text = ' '.join(out.split())
    assert status == 0
    assert all(code in text for code in ('0 done', '1 some --batch rows failed', '2 bad input', '3 refine / calibrate'))
    assert 'did not adopt' in text and 'zero-shot camera' in text


def test_the_progress_line_fits_the_terminal(monkeypatch):
    """A progress line longer than the terminal is wide wraps, and the next ``\\r`` rewrites only
    its last row, leaving the others on the screen: the line is cut to the terminal's width (a
    real terminal of 60 columns; a stream without its own terminal takes ``COLUMNS``)."""
    import fcntl
    import pty
    import struct
    import termios
    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack('HHHH', 24, 60, 0, 0))
    with os.fdopen(follower, 'w') as terminal:
        line = cli_output.ProgressLine(terminal, 'refine')
        assert line.in_place
        for k in range(3):
            line(f'round {k + 1} of 2: detection, image 1 of 4, 200 lines; current estimate f 367.7 px, '
                 'principal point (378.6, 224.9) px')
        line.close()
    chunks = []
    while True:  # one read may return part of what was written (it did once, on a busy machine)
        try:
            chunk = os.read(leader, 4096)
        except OSError:  # EIO: the terminal's other end is closed and all it held was read
            break
        if not chunk:
            break
        chunks.append(chunk)
    shown = b''.join(chunks).decode()
    os.close(leader)
    rows = shown.replace('\r\n', '\n').split('\r')[1:]
    assert len(rows) == 3 and all(0 < len(row.rstrip('\n')) <= 59 for row in rows), rows
    assert rows[0].startswith('zeroshot-calib: refine round 1 of 2')

    class Screen(io.StringIO):
        def isatty(self):
            return True
    monkeypatch.setenv('COLUMNS', '40')
    screen = Screen()
    line = cli_output.ProgressLine(screen, 'refine')
    line('x' * 100)
    line('short')
    assert screen.getvalue() == '\r' + 'zeroshot-calib: refine ' + 'x' * 16 + '\r' + 'zeroshot-calib: refine short'.ljust(39)


def test_a_terminal_of_unknown_width_takes_columns_or_80(monkeypatch):
    """A pty whose size was never set says 0 columns (`script`, some CI runners): the line is cut
    to COLUMNS, else 80, not to nothing."""
    import pty
    leader, follower = pty.openpty()
    assert os.get_terminal_size(follower).columns == 0
    with os.fdopen(follower, 'w') as terminal:
        monkeypatch.setenv('COLUMNS', '50')
        assert cli_output._columns(terminal) == 50
        monkeypatch.delenv('COLUMNS')
        monkeypatch.setattr(cli_output.shutil, 'get_terminal_size', lambda: os.terminal_size((80, 24)))
        assert cli_output._columns(terminal) == 80
    os.close(leader)


def test_the_record_of_a_refined_camera_keeps_the_image_circle_of_the_spec():
    """A camera refined from a circle spec (`refine --circle-fov F`, the diameter measured) keeps
    the circle in its record's spec and on the text's camera line, as the zero-shot record does."""
    from types import SimpleNamespace
    spec = CameraSpec(748, 480, circle_diameter=564.5, circle_fov=178.7)
    args = SimpleNamespace(balance=0.0, fov_scale=1.0, camera_name='camera')
    from zeroshot_calib_ros.core.estimation.zero_shot import zero_shot_camera
    camera = zero_shot_camera(spec, 748, 480)
    summary, _ = cli_output.kannala_brandt_record(camera, spec, 'refined (Kannala-Brandt)', args)
    assert summary['spec'] == {'circle_diameter': 564.5, 'circle_fov': 178.7}
    from zeroshot_calib_ros.core.ros_formats.calibration_file import summary_text
    first = summary_text(summary).splitlines()[0]
    assert first == 'camera    748 x 480 px, circle_diameter 564.5 px, circle_fov 178.7 deg', first


def test_a_fov_is_marked_when_either_of_its_edges_is_past_the_circle_about_the_principal_point():
    """A refined camera's principal point is off the image's centre, and so is its image circle: a
    FOV is past the circle when either of its edges is (here the right one, 388 px out against a
    375 px radius; the left is inside at 360), measured from the principal point, not the image's
    centre (where both would be inside at 374)."""
    from zeroshot_calib_ros.core.ros_formats.calibration_file import _fovs_past_circle
    summary = {'spec': {'circle_diameter': 750.0}, 'cx': 360.0, 'cy': 240.0, 'width': 748, 'height': 480}
    assert _fovs_past_circle(summary) == {'hfov', 'dfov'}
    assert _fovs_past_circle(dict(summary, cx=374.0)) == {'dfov'}
    assert _fovs_past_circle(dict(summary, spec={})) == set()


def test_fovs_printed_across_the_dark_past_the_image_circle_are_marked(capsys):
    """A circular fisheye's predicted hfov and dfov run past its image circle into the dark corners,
    where the lens model only continues (a 560 px circle in a 748 x 480 image: h 250 degrees):
    the FOV line marks them and says why; the vfov, inside the circle, and every FOV of a camera
    whose circle covers the image, are not marked."""
    def fov_line(*spec):
        status, out, err = run_main(['solve', '--width', '748', '--height', '480', *spec], capsys)
        assert status == 0, err
        return next(line for line in out.splitlines() if line.startswith('FOV'))
    line = fov_line('--circle-diameter', '560', '--circle-fov', '187')
    assert re.match(r'FOV +h [\d.]+\*, v [\d.]+, d [\d.]+\* deg \(predicted; \*: past the image circle', line), line
    assert 'nothing is imaged there' in line, line
    for spec in (('--circle-diameter', '900', '--circle-fov', '187'), ('--hfov', '187')):
        assert '*' not in fov_line(*spec), fov_line(*spec)
