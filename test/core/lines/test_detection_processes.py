"""Several images' curves found in worker processes (``zeroshot-calib refine`` passes the
machine's cores): the same result as in one process, the workers really used and always ended,
errors raised in the caller, and a caller's script not run again in the workers."""
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import scenes
from zeroshot_calib_ros.core.estimation.refine import refine_from_images
from zeroshot_calib_ros.core.estimation.zero_shot import zero_shot_start
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
from zeroshot_calib_ros.core.lines import detection_processes as dp
from zeroshot_calib_ros.core.lines.detection_processes import DetectionProcesses, WorkerFailed
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

ROOT = Path(__file__).resolve().parents[3]
TRUTH = KannalaBrandtCamera(330.0, 330.0, 322.0, 236.0, 640, 480, [0.02, -0.01, 0.004, -0.001])


def spec_of(camera):
    from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis
    return CameraSpec(width=camera.width, height=camera.height, **fields_of_view_through_axis(camera))


@pytest.fixture(scope='module')
def frames():
    scene = scenes.make_scene('room', 7)
    return [scenes.render(TRUTH, scene, pose=scenes.random_pose(scene, 40 + k), seed=40 + k)[0] for k in range(3)]


def alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is gone for every purpose but its entry: it is reaped by its parent's wait
    with open(f'/proc/{pid}/stat') as stat:
        return stat.read().split(') ')[-1][0] != 'Z'


def working_detection_worker(pid):
    """Whether ``pid`` is a detection worker that has imported OpenCV (its libraries are mapped)."""
    try:
        with open(f'/proc/{pid}/cmdline', 'rb') as cmdline:
            if b'detection_processes' not in cmdline.read():
                return False
        with open(f'/proc/{pid}/maps') as maps:
            return 'cv2' in maps.read()
    except OSError:
        return False


def children_of(parent):
    """The pids whose parent is ``parent`` (from /proc)."""
    found = []
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                with open(f'/proc/{entry}/stat') as stat:
                    fields = stat.read().rsplit(') ', 1)[-1].split()
            except OSError:
                continue
            if int(fields[1]) == parent:
                found.append(int(entry))
    return found


@pytest.fixture
def started(monkeypatch):
    """The pids of every worker process started, recorded in this process."""
    pids = []
    start = DetectionProcesses._start

    def recording(self):
        start(self)
        pids.extend(self.pids)

    monkeypatch.setattr(DetectionProcesses, '_start', recording)
    return pids


def test_images_detected_in_worker_processes_give_what_one_process_gives(frames, started):
    """An image's curves found in a worker process are the ones found in the caller (to a
    millionth of a pixel: the last digits move with the BLAS in use, numpy 1.26's OpenBLAS on an
    AMD EPYC from run to run), and after the fits (there at 1e-8 of f) the user gets the same
    decision, lines and camera."""
    spec = spec_of(TRUTH)
    look = zero_shot_start(spec, TRUTH.width, TRUTH.height)
    jobs = [((frame, look.detection_camera, look.camera, None, k), {}) for k, frame in enumerate(frames)]
    here = [dp.detect_image(*args) for args, _ in jobs]
    with DetectionProcesses(2) as workers:
        there = list(workers.map('detect_image', jobs))
    assert [[(c.image, c.points.shape) for c in found[2]] for found in there] == \
        [[(c.image, c.points.shape) for c in found[2]] for found in here]
    for found_there, found_here in zip(there, here):
        for a, b in zip(found_there[2], found_here[2]):
            np.testing.assert_allclose(a.points, b.points, rtol=0, atol=1e-6)
    started.clear()
    alone = refine_from_images(spec, frames, workers=1)
    assert not started
    shared = refine_from_images(spec, frames, workers=2)
    assert len(started) == 2 and os.getpid() not in started, 'the images were not detected in two processes'
    assert shared.accepted == alone.accepted and abs(shared.lines_used - alone.lines_used) <= 2
    np.testing.assert_allclose(shared.camera.K, alone.camera.K, rtol=1e-6)
    np.testing.assert_allclose(shared.camera.D, alone.camera.D, rtol=0, atol=1e-6)
    assert shared.uncertainty_px == pytest.approx(alone.uncertainty_px, rel=1e-4)
    assert alone.lines_used >= 8 and {c.image for c in alone.curves} == {0, 1, 2}
    assert not any(alive(pid) for pid in started), 'a worker process outlived the call'


def test_no_more_workers_than_images_and_none_for_one_image(frames, started):
    refine_from_images(spec_of(TRUTH), frames[:2], rounds=1, workers=8)
    assert len(started) == 2
    started.clear()
    refine_from_images(spec_of(TRUTH), frames[:1], rounds=1, workers=8)
    assert not started


def test_each_round_and_progress_see_the_images_in_order(frames, started):
    reports = []
    result = refine_from_images(spec_of(TRUTH), frames, workers=2, progress=reports.append)
    detections = [r for r in reports if r.stage == 'detection']
    rounds = sorted({r.round for r in detections})
    for number in rounds:
        done = [r.frames_done for r in detections if r.round == number]
        assert done == [1, 2, 3]
    assert len(rounds) == len([r for r in reports if r.stage == 'fit']) and result.lines_used > 0


def test_a_detection_error_in_a_worker_is_raised_in_the_caller_and_the_workers_end(frames, started):
    with pytest.raises(TypeError, match='unknown option.*no_such_option'):
        refine_from_images(spec_of(TRUTH), frames, workers=2, no_such_option=1)
    assert len(started) == 2 and not any(alive(pid) for pid in started)


def test_an_error_in_the_callers_progress_ends_the_workers_at_once(frames, started):
    def fail(report):
        raise KeyboardInterrupt  # a Ctrl-C landing in the middle of detection

    with pytest.raises(KeyboardInterrupt):
        refine_from_images(spec_of(TRUTH), frames, workers=2, progress=fail)
    assert started and not any(alive(pid) for pid in started)


def test_a_worker_that_dies_is_an_error_naming_it_not_a_hang():
    with DetectionProcesses(1) as workers:
        workers._start()
        pid, = workers.pids
        os.kill(pid, 9)
        with pytest.raises(WorkerFailed, match='ended without answering.*-9'):
            list(workers.map('curves_from_edges', [((None, TRUTH, 0), {})] * 3))


def test_only_the_listed_jobs_run():
    with pytest.raises(ValueError, match="unknown job 'exec': allowed: detect_image, curves_from_edges"):
        list(DetectionProcesses(1).map('exec', [((), {})]))


def test_a_print_in_a_worker_does_not_corrupt_its_answers(tmp_path):
    """A worker's stdout is stderr: what a library prints there cannot break the stream of answers."""
    code = textwrap.dedent('''
        import sys
        from zeroshot_calib_ros.core.lines import detection_processes as dp
        dp.JOBS['chatty'] = lambda value: print('a library talking', value) or value * 2
        dp._main()
    ''')
    worker = subprocess.Popen([sys.executable, '-c', code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    for value in (1, 2):
        dp._send(worker.stdin, ('chatty', (value,), {}))
    dp._send(worker.stdin, ('chatty', ('x', 'too many'), {}))
    answers = [dp._receive(worker.stdout) for _ in range(3)]
    worker.stdin.close()
    assert worker.wait(20) == 0
    assert answers[:2] == [(True, 2), (True, 4)]
    assert answers[2][0] is False and isinstance(answers[2][1], TypeError)
    assert b'a library talking 1' in worker.stderr.read()


def test_a_script_without_a_main_guard_runs_once(tmp_path, frames):
    """Worker processes are fresh interpreters, not multiprocessing's spawn, which runs the caller's
    ``__main__`` again: a user's script that calls refine at its top level runs once, and ends."""
    import cv2
    paths = []
    for k, frame in enumerate(frames[:2]):
        paths.append(str(tmp_path / f'frame{k}.png'))
        cv2.imwrite(paths[-1], frame)
    marker = tmp_path / 'ran.txt'
    script = tmp_path / 'calibrate.py'
    script.write_text(textwrap.dedent(f'''
        import cv2
        from zeroshot_calib_ros.core import CameraSpec
        from zeroshot_calib_ros.core.estimation.refine import refine_from_images
        spec = CameraSpec(**{dict(spec_of(TRUTH).given())!r}, width=640, height=480)
        result = refine_from_images(spec, [cv2.imread(p, 0) for p in {paths!r}], rounds=1, workers=2)
        with open({str(marker)!r}, 'a') as out:
            out.write(f'ran {{result.lines_used}}\\n')
    '''))
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert done.returncode == 0, done.stderr
    lines = marker.read_text().splitlines()
    assert len(lines) == 1 and int(lines[0].split()[1]) > 0


def test_workers_import_this_checkout_whatever_the_callers_path(frames, started, monkeypatch, tmp_path):
    """A worker imports the package the caller imported (its parent directory first on the
    worker's PYTHONPATH), even when the caller found it by a path the environment does not have."""
    # a user's PYTHONPATH with another zeroshot_calib_ros on it (an older install, a colcon
    # overlay): the workers must still import the caller's, so the caller's root comes first
    other = tmp_path / 'other' / 'zeroshot_calib_ros'
    other.mkdir(parents=True)
    (other / '__init__.py').write_text("raise ImportError('another zeroshot_calib_ros was imported')\n")
    monkeypatch.setenv('PYTHONPATH', str(other.parent))
    monkeypatch.chdir(tmp_path)  # not the checkout: `python -m` would find the package there
    result = refine_from_images(spec_of(TRUTH), frames[:2], rounds=1, workers=2)
    assert len(started) == 2 and result.lines_used > 0


def test_ctrl_c_during_the_cli_refine_ends_it_and_its_workers_without_a_traceback(tmp_path, frames):
    """A Ctrl-C at the terminal (SIGINT to the foreground process group) while `zeroshot-calib refine`
    detects several images: exit status 130, no traceback, and no worker process left behind (the
    workers are in a session of their own: the caller stops them)."""
    import signal
    import time
    import cv2
    paths = []
    for k, frame in enumerate(frames * 3):  # nine frames: the workers are still at work when the signal comes
        paths.append(str(tmp_path / f'frame{k}.png'))
        cv2.imwrite(paths[-1], frame)
    fov = dict(spec_of(TRUTH).given())
    run = subprocess.Popen([sys.executable, '-m', 'zeroshot_calib_ros.cli', 'refine', *paths,
                            '--hfov', f"{fov['hfov']:.3f}", '--vfov', f"{fov['vfov']:.3f}"],
                           env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, start_new_session=True,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    # Not the first child seen: an import may run a short-lived helper (ldconfig), and a SIGINT
    # during the CLI's imports is Python's own traceback. Wait until both detection workers have
    # loaded OpenCV: they are at work, where a worker in the terminal's process group would get
    # the Ctrl-C too.
    children, deadline = [], time.monotonic() + 120
    while len(children) < 2 and run.poll() is None and time.monotonic() < deadline:
        children = [pid for pid in children_of(run.pid) if working_detection_worker(pid)]
        time.sleep(0.01)
    assert len(children) == 2, 'refine ended before its two worker processes were seen at work'
    # a worker in the terminal's session would get the Ctrl-C too, and die with or without a
    # traceback depending on whether it was in Python or in OpenCV at that moment
    assert all(os.getsid(pid) == pid for pid in children), 'a worker is not in a session of its own'
    os.killpg(run.pid, signal.SIGINT)
    out, err = run.communicate(timeout=60)
    assert run.returncode == 130 and 'Traceback' not in err, err
    time.sleep(0.5)
    assert not any(alive(pid) for pid in children), 'a worker process outlived a Ctrl-C'


@pytest.fixture(scope='module')
def edges(frames):
    """The edge points of the first frame (their curves take a worker a while to make)."""
    return dp.detect_image(frames[0], TRUTH, TRUTH)[1]


def test_answers_come_in_the_order_of_the_jobs_and_two_run_at_once(edges, monkeypatch):
    """``map`` answers job k with job k's result even when later, quicker jobs end first, and
    keeps every worker busy (two workers: two jobs at the same time)."""
    from zeroshot_calib_ros.core.lines.detect import EdgePoints
    running, peak = [0], [0]
    run = DetectionProcesses._run

    def counting(self, job):
        running[0] += 1
        peak[0] = max(peak[0], running[0])
        try:
            return run(self, job)
        finally:
            running[0] -= 1

    monkeypatch.setattr(DetectionProcesses, '_run', counting)
    empty = EdgePoints(image_size=edges.image_size, per_view=[], options=edges.options)
    with DetectionProcesses(2) as workers:
        answers = list(workers.map('curves_from_edges', [((edges, TRUTH, 0), {})] + [((empty, TRUTH, 1), {})] * 6))
    assert peak[0] == 2, 'the jobs did not run two at a time'
    assert len(answers[0]) >= 5 and answers[1:] == [[]] * 6, 'an answer came in the place of another job'


def test_an_error_in_one_job_leaves_the_workers_ready_for_the_next(edges):
    """A job's error is raised in the caller with its own type, and the worker that raised it
    takes the next job (one worker: were it lost, the next map would wait forever)."""
    import threading
    with DetectionProcesses(1) as workers:
        wrong_size = KannalaBrandtCamera(330.0, 330.0, 322.0, 236.0, 320, 240, [0, 0, 0, 0])
        with pytest.raises(ValueError, match='edges are of a 640x480 image but the camera is 320x240'):
            list(workers.map('curves_from_edges', [((edges, wrong_size, 0), {})]))
        answers = []
        later = threading.Thread(target=lambda: answers.extend(workers.map('curves_from_edges', [((edges, TRUTH, 0), {})])),
                                 daemon=True)
        later.start()
        later.join(30)
        assert answers and len(answers[0]) >= 5, 'the worker was not given the next job after an error'


def test_an_error_that_cannot_travel_back_is_a_runtime_error_naming_it():
    """An exception a worker cannot pickle (a library's own class, say) reaches the caller as a
    RuntimeError with its type and message, not as a dead worker."""
    import io

    class LocalError(Exception):  # a local class cannot be pickled
        pass

    def fail():
        raise LocalError('the detector could not go on')

    read, write = io.BytesIO(), io.BytesIO()
    dp._send(read, ('fail', (), {}))
    read.seek(0)
    dp.serve(read, write, jobs={'fail': fail})
    write.seek(0)
    ok, error = dp._receive(write)
    assert ok is False and type(error) is RuntimeError and str(error) == 'LocalError: the detector could not go on'


def test_close_lets_idle_workers_end_by_themselves_and_kill_stops_busy_ones(edges, frames):
    """``close()``: a worker whose input is closed exits with status 0 (not killed after
    ``STOP_SECONDS``); an error or a Ctrl-C in the ``with`` block kills the workers at once (-9),
    without waiting for the jobs under way."""
    workers = DetectionProcesses(2)
    list(workers.map('curves_from_edges', [((edges, TRUTH, 0), {})] * 2))
    processes = list(workers._workers)
    workers.close()
    assert [p.returncode for p in processes] == [0, 0]

    with pytest.raises(KeyboardInterrupt):
        with DetectionProcesses(2) as workers:
            for _ in workers.map('detect_image', [((frame, TRUTH, TRUTH, None, 0), {}) for frame in frames * 4]):
                processes = list(workers._workers)
                raise KeyboardInterrupt
    assert [p.returncode for p in processes] == [-9, -9]


def test_a_script_whose_workers_died_still_ends(tmp_path, edges):
    """After the workers die, no thread is left waiting for a worker once the caller has closed
    them: the caller's script ends (a waiting thread of the pool would keep the interpreter from
    exiting)."""
    script = tmp_path / 'died.py'
    script.write_text(textwrap.dedent('''
        import os, pickle, sys
        from zeroshot_calib_ros.core.lines.detection_processes import DetectionProcesses, WorkerFailed
        edges, camera = pickle.load(open(sys.argv[1], 'rb'))
        workers = DetectionProcesses(2)
        list(workers.map('curves_from_edges', [((edges, camera, 0), {})] * 2))
        for pid in workers.pids:
            os.kill(pid, 9)
        try:
            list(workers.map('curves_from_edges', [((edges, camera, 0), {})] * 8))
        except WorkerFailed as error:
            print('failed:', error)
        workers.close()
        print('closed')
    '''))
    data = tmp_path / 'edges.pickle'
    data.write_bytes(__import__('pickle').dumps((edges, TRUTH)))
    done = subprocess.run([sys.executable, str(script), str(data)], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert done.returncode == 0, done.stderr
    assert 'failed: a detection worker process ended without answering (exit status -9)' in done.stdout
    assert done.stdout.rstrip().endswith('closed')


def test_detect_image_looks_with_one_camera_and_makes_curves_under_the_other(monkeypatch):
    """``detect_image``: the edge points are looked for with ``look`` (zero-shot's rounded FOVs),
    the curves made under ``camera`` (the current estimate), in the image's own region."""
    from zeroshot_calib_ros.core.lines import detect
    from zeroshot_calib_ros.core.lines.image_region import ImageRegion
    look, camera = object(), object()
    region = ImageRegion(np.ones((4, 4), bool))
    calls = []
    monkeypatch.setattr(detect, 'find_edges', lambda image, cam, views=None, region=None, **kw:
                        calls.append(('edges', cam, region)) or 'edge points')
    monkeypatch.setattr(detect, 'curves_from_edges', lambda edges, cam, image_id=None:
                        calls.append(('curves', cam, edges, image_id)) or ['curve'])
    answer = dp.detect_image(np.zeros((4, 4), np.uint8), look, camera, region, 7)
    assert answer == (region, 'edge points', ['curve'], None)
    assert calls == [('edges', look, region), ('curves', camera, 'edge points', 7)]


def test_workers_closed_can_be_started_again(edges):
    """A ``DetectionProcesses`` used again after ``close()`` starts new workers and answers (it
    does not fail on the closed pool's stop signal)."""
    from zeroshot_calib_ros.core.lines.detect import EdgePoints
    empty = EdgePoints(image_size=edges.image_size, per_view=[], options=edges.options)
    workers = DetectionProcesses(1)
    try:
        assert list(workers.map('curves_from_edges', [((empty, TRUTH, 0), {})])) == [[]]
        first = workers.pids
        workers.close()
        assert list(workers.map('curves_from_edges', [((empty, TRUTH, 0), {})] * 2)) == [[], []]
        assert workers.pids != first
    finally:
        workers.close()


def test_close_kills_a_worker_that_does_not_end_in_time_and_reaps_it(monkeypatch):
    """A worker still busy ``STOP_SECONDS`` after its input was closed is killed, and waited for
    (no zombie left), and both its pipes are closed (no file descriptors left open)."""
    monkeypatch.setattr(dp, 'STOP_SECONDS', 0.0)  # a worker still starting up is not done yet
    workers = DetectionProcesses(2)
    workers._start()
    processes = list(workers._workers)
    workers.close()
    assert [p.returncode for p in processes] == [-9, -9]
    assert all(p.stdin.closed and p.stdout.closed for p in processes)
    assert not any(alive(p.pid) for p in processes)
