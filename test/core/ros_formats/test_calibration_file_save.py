"""Safe saves: all or nothing, through symlinks, permission modes kept, clear errors that name
the target (never the temporary file), nothing left behind; a kill -9 loop."""
import errno
import multiprocessing
import os
import random
import stat
import subprocess
import sys
import time

import numpy as np
import pytest

from zeroshot_calib_ros.core import atomic_file
from zeroshot_calib_ros.core.ros_formats.calibration_file import (CalibrationFileError, CalibrationSaveError,
                                                      CameraCalibration, RegionOfInterest)

from test_calibration_file import sample


@pytest.fixture(params=['unnamed', 'named'])
def temp_file(request, monkeypatch):
    """Both ways a save can stage its content: an unnamed O_TMPFILE file that gets a name only
    once complete (Linux), and the named temporary file used where the kernel or file system
    cannot give one."""
    if request.param == 'unnamed':
        assert atomic_file._open_unnamed(os.getcwd(), 0o600)[0] is not None or sys.platform != 'linux'
    else:
        monkeypatch.setattr(atomic_file, '_open_unnamed', lambda directory, mode: (None, None))
    return request.param


def leftovers(directory, keep=()):
    return sorted(name for name in os.listdir(directory) if name not in keep)


def test_symlinked_target_is_written_through(tmp_path, temp_file):
    real_dir = tmp_path / 'real'
    real_dir.mkdir()
    real = real_dir / 'cam.yaml'
    sample(camera_name='old').save(str(real))
    os.chmod(real, 0o640)
    link = tmp_path / 'link.yaml'
    link.symlink_to(real)
    sample(camera_name='new').save(str(link))
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert CameraCalibration.load(str(real)).camera_name == 'new'
    assert stat.S_IMODE(os.stat(real).st_mode) == 0o640
    assert leftovers(tmp_path) == ['link.yaml', 'real'] and leftovers(real_dir) == ['cam.yaml']


def test_dangling_symlink_creates_its_target(tmp_path):
    link = tmp_path / 'cam.yaml'
    link.symlink_to(tmp_path / 'target.yaml')
    sample().save(str(link))
    assert link.is_symlink() and CameraCalibration.load(str(tmp_path / 'target.yaml')) == sample()


def test_symlink_loop_is_refused(tmp_path):
    (tmp_path / 'a.yaml').symlink_to(tmp_path / 'b.yaml')
    (tmp_path / 'b.yaml').symlink_to(tmp_path / 'a.yaml')
    with pytest.raises(CalibrationSaveError):
        sample().save(str(tmp_path / 'a.yaml'))
    assert leftovers(tmp_path) == ['a.yaml', 'b.yaml']


def test_existing_mode_is_kept_and_new_files_follow_the_umask(tmp_path, temp_file):
    path = tmp_path / 'cam.yaml'
    path.write_text('old')
    os.chmod(path, 0o604)
    sample().save(str(path))
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o604
    old = os.umask(0o027)
    try:
        sample().save(str(tmp_path / 'new.ini'))
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / 'new.ini').st_mode) == 0o640  # 0666 & ~umask, as open()


def test_read_only_file_is_refused_and_kept(tmp_path):
    """Renaming over a 0444 file would work (it needs only the directory), but a read-only
    calibration is someone's 'do not overwrite'; camera_info_manager's ofstream fails on it."""
    path = tmp_path / 'cam.yaml'
    sample(camera_name='frozen').save(str(path))
    os.chmod(path, 0o444)
    before = path.read_bytes()
    with pytest.raises(CalibrationSaveError, match='read-only') as excinfo:
        sample().save(str(path))
    error = excinfo.value
    assert isinstance(error, OSError) and isinstance(error, CalibrationFileError)
    assert error.errno == errno.EACCES and str(path) in str(error) and len(str(error).splitlines()) == 1
    assert path.read_bytes() == before and stat.S_IMODE(os.stat(path).st_mode) == 0o444
    assert leftovers(tmp_path) == ['cam.yaml']


def test_saving_onto_a_directory_leaves_nothing_behind(tmp_path):
    target = tmp_path / 'cam.yaml'
    target.mkdir()
    with pytest.raises(CalibrationSaveError, match='directory') as excinfo:
        sample().save(str(target))
    assert excinfo.value.errno == errno.EISDIR and str(target) in str(excinfo.value)
    assert leftovers(tmp_path) == ['cam.yaml'] and os.listdir(target) == []


def test_missing_parent_directories_are_created(tmp_path):
    path = tmp_path / 'a' / 'b' / 'cam.yaml'
    sample().save(str(path))
    assert CameraCalibration.load(str(path)) == sample()


@pytest.mark.parametrize('temp_file, failing',
                         [('unnamed', 'link'), *[(kind, failing) for kind in ('unnamed', 'named')
                                                 for failing in ('write', 'fsync', 'replace', 'fchmod')]],
                         indirect=['temp_file'])
def test_a_failure_mid_save_keeps_the_old_file_and_removes_the_temp(tmp_path, monkeypatch, failing, temp_file):
    path = tmp_path / 'cam.yaml'
    sample(camera_name='old').save(str(path))
    before = path.read_bytes()

    def broken(*args, **kwargs):
        raise OSError(errno.ENOSPC, 'No space left on device')

    monkeypatch.setattr(os, failing, broken)
    with pytest.raises(CalibrationSaveError) as excinfo:
        sample(camera_name='new').save(str(path))
    monkeypatch.undo()
    message = str(excinfo.value)
    assert message == f'cannot save {path}: No space left on device'  # the target, not the temp
    assert excinfo.value.strerror == 'No space left on device' and excinfo.value.errno == errno.ENOSPC
    assert path.read_bytes() == before and leftovers(tmp_path) == ['cam.yaml']


def test_an_unwritable_directory_names_the_target(tmp_path, monkeypatch, temp_file):
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, 'Permission denied')

    real_open = os.open

    def open_refusing_tmpfile(path, flags, *args, **kwargs):
        if flags & getattr(os, 'O_TMPFILE', 0) == getattr(os, 'O_TMPFILE', -1):
            refuse()
        return real_open(path, flags, *args, **kwargs)

    # as for a non-root user in a 0555 directory (root may write anywhere)
    monkeypatch.setattr(tempfile, 'mkstemp', refuse)
    monkeypatch.setattr(os, 'open', open_refusing_tmpfile)
    with pytest.raises(CalibrationSaveError, match='Permission denied') as excinfo:
        sample().save(str(tmp_path / 'cam.yaml'))
    assert str(tmp_path / 'cam.yaml') in str(excinfo.value) and excinfo.value.errno == errno.EACCES


def test_callers_catching_oserror_still_catch_save_errors(tmp_path):
    """ros/node.py and cli/output.py catch OSError around save() and print exc.strerror."""
    solution_like = sample()
    try:
        solution_like.save(str(tmp_path / 'cam.txt'))
    except OSError as exc:
        assert 'allowed: .ini, .yml or .yaml' in exc.strerror
    else:
        pytest.fail('no error')


def _dead_pid():
    child = subprocess.Popen([sys.executable, '-c', 'pass'])
    child.wait()
    return child.pid


def test_temps_of_dead_writers_are_swept_and_live_ones_kept(tmp_path):
    path = tmp_path / 'cam.yaml'
    dead, live = _dead_pid(), os.getppid()
    stale = f'.cam.yaml.tmp-{dead}-abc_1234'
    in_progress = f'.cam.yaml.tmp-{live}-abcd1234'
    mine = f'.cam.yaml.tmp-{os.getpid()}-abcd1234'
    other_target = f'.other.yaml.tmp-{dead}-abcd1234'
    unrelated = '.cam.yaml.tmp-nopid'
    for name in (stale, in_progress, mine, other_target, unrelated):
        (tmp_path / name).write_text('x')
    sample().save(str(path))
    assert leftovers(tmp_path) == sorted(['cam.yaml', in_progress, mine, other_target, unrelated])


def _writer(path, a, b, ready):
    a.save(path)
    ready.set()
    while True:
        b.save(path)
        a.save(path)


KILLS = 30


def test_kill_9_during_saves_leaves_a_or_b_and_no_temps(tmp_path, monkeypatch, temp_file):
    """A child saving A and B in a tight loop is SIGKILLed at random moments. Each time the file
    must be A or B completely. No code runs on SIGKILL, so a kill after the temporary file got
    its name and before the rename leaves that one file: with O_TMPFILE the content is written
    and fsynced unnamed and only the link-rename pair of system calls is exposed; with a named
    temporary file the whole write and fsync are. The next save of the target removes it."""
    a = sample(camera_name='calib_a')
    b = CameraCalibration(1280, 720, [[900.5, 0, 641.25], [0, 901.5, 359.75], [0, 0, 1]], 'equidistant',
                          [0.01, -0.002, 0.0003, -0.00004], np.eye(3),
                          [[700, 0, 640, 0], [0, 700, 360, 0], [0, 0, 1, 0]], 'calib_b', 2, 2,
                          RegionOfInterest(8, 4, 700, 1200, True))
    assert a.to_yaml() != b.to_yaml()
    path = str(tmp_path / 'cam.yaml')
    monkeypatch.setenv('OPENBLAS_NUM_THREADS', '1')
    context = multiprocessing.get_context('fork' if sys.platform == 'linux' else 'spawn')
    rng = random.Random(1234)
    seen = {'calib_a': 0, 'calib_b': 0}
    temps_after_kill = []
    for _ in range(KILLS):
        ready = context.Event()
        child = context.Process(target=_writer, args=(path, a, b, ready), daemon=True)
        child.start()
        assert ready.wait(30), 'the writer did not start'
        # let it get into the loop, then kill it at a random moment of a save
        os.sched_yield()
        time.sleep(rng.uniform(0.0, 0.03))
        child.kill()
        child.join(10)
        assert child.exitcode == -9
        loaded = CameraCalibration.load(path)
        assert loaded == a or loaded == b
        seen[loaded.camera_name] += 1
        temps = leftovers(tmp_path, keep=('cam.yaml',))
        assert len(temps) <= 1, temps  # only the killed writer's one in-flight file, never more
        temps_after_kill.append(len(temps))
    a.save(path)  # the next save sweeps the last killed writer's temporary file
    assert leftovers(tmp_path) == ['cam.yaml']
    print(f'\nkill -9 loop: {KILLS} kills; file was A {seen["calib_a"]} times, B {seen["calib_b"]} times, '
          f'never torn; {temp_file} temporary file: {sum(temps_after_kill)} kills left one (killed after it '
          'was named, before the rename), each removed by the next save; 0 left at the end')


def test_the_directory_is_fsynced_after_the_rename(tmp_path, monkeypatch, temp_file):
    """Durability: the content is fsynced before it replaces the target, and the directory
    holding the target after the rename (else a power cut can bring the old name back)."""
    path = tmp_path / 'cam.yaml'
    sample(camera_name='old').save(str(path))
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(('fsync', os.path.realpath(f'/proc/self/fd/{fd}')))
        return real_fsync(fd)

    def replace(src, dst, *args, **kwargs):
        events.append(('replace', str(dst)))
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, 'fsync', fsync)
    monkeypatch.setattr(os, 'replace', replace)
    sample(camera_name='new').save(str(path))
    monkeypatch.undo()
    kinds = [kind for kind, _ in events]
    assert kinds.count('replace') == 1, events
    renamed = kinds.index('replace')
    assert events[renamed] == ('replace', os.path.realpath(path)), events
    assert 'fsync' in kinds[:renamed], events  # the new content, before it gets the name
    assert ('fsync', os.path.realpath(tmp_path)) in events[renamed + 1:], events  # the directory, after the rename
    assert CameraCalibration.load(str(path)).camera_name == 'new'
