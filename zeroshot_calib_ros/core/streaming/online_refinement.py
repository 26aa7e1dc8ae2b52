"""Refinement of the calibration in force from the frames a camera streams (the node's ``refine``).

``OnlineRefiner(spec, interval)`` is offered frames (numpy images and a time) from the frame
callback; it keeps at most one every ``interval`` seconds, and only while its worker is idle.
The check is a comparison of two numbers; a frame that is not kept is not copied (a kept one is
copied unless the caller says its buffer is immutable, as rclpy's serialized ``bytes`` are).

Line detection (``core.lines.detect.find_edges`` and ``curves_from_edges``) and the fit with its gate
(``core.estimation.refine.refine_camera``) run in a **worker process** (``python -c`` running
``worker_main``) at nice ``WORKER_NICE`` and SCHED_IDLE with one OpenCV / BLAS thread: in the node's process
even a low-priority thread would hold the GIL for most of a fit (tens of seconds of numpy and
SciPy at 1080p) and the executor thread would lose frames. Frames go to the worker through its
stdin (written by a sender thread, so the caller never waits on the pipe), results come back on
its stdout (read by a reader thread). The worker accumulates the curves of the last
``max_frames`` kept frames (inside the image circle when one is seen, leaving out what stays put from
frame to frame: the robot's own body), detects with the current estimate (zero-shot's, the camera given as
``initial``, or the last one it offered), and after every frame fits all of them; the gate of
``refine_camera`` (zero-shot the reference, whatever ``initial`` is) decides. The first accepted
camera is a result (``take_result``). The refiner then goes on: a later fit is offered only when
the gate accepts it too and its uncertainty is at most ``IMPROVEMENT`` times the last offered
camera's (each adoption is a new calibration for every consumer, so a small gain does not make
one), and after ``FINISH_AFTER`` frames without such a fit it is finished: it keeps no more
frames and its worker exits (no core is kept busy for a calibration that no longer improves).

States (``status.state``): ``collecting`` (the gate refused so far, fewer than ``max_frames``
frames seen), ``insufficient`` (``max_frames`` frames seen and still refused: the window slides
on, newest frames replacing the oldest), ``refined`` (a camera was offered; the reason says
what the newest fit did, and ``finished`` is set once the refiner stops), ``error`` (the last
frame failed in the worker, which goes on), ``failed`` (the worker is gone: no more refinement)
and ``stopped``. ``reason`` says why, in the gate's words.

ROS-free: the node (``zeroshot_calib_ros.ros.node``) owns one while ``refine`` is true.
"""
from __future__ import annotations

import dataclasses
import os
import pickle
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..estimation.terms import FOV_TOLERANCE_DEG
from ..lens.fitting import DISTORTION_FITS
from ..lens.models import KannalaBrandtCamera
from ..zeroshot.spec import CameraSpec
from ..ros_formats.calibration_file import CameraCalibration
from ..ros_formats.rectify import principal_point_camera_matrix

DEFAULT_INTERVAL = 2.0
"""Seconds between kept frames (the node's ``refine_interval``)."""
MAX_FRAMES = 8
"""Kept frames whose curves the fit uses (the newest)."""
IMPROVEMENT = 0.7
"""After a first refined camera, a later fit is offered when its uncertainty is at most this
fraction of the last offered camera's."""
FINISH_AFTER = 2 * MAX_FRAMES
"""Frames after the last offered camera without a better one, after which the refiner finishes."""
WORKER_NICE = 19
"""Niceness of the worker process (with SCHED_IDLE where Linux has it); ZEROSHOT_CALIB_REFINE_NICE
overrides it (0..19; below 19 the normal policy)."""
NICE_ENV = 'ZEROSHOT_CALIB_REFINE_NICE'
STATES = ('collecting', 'insufficient', 'refined', 'error', 'failed', 'stopped')
_LENGTH = struct.Struct('>Q')


@dataclass
class RefineStatus:
    """What the refiner knows now (the node's /diagnostics ``refine_*`` values)."""

    state: str = 'collecting'
    reason: str = 'no frame yet'
    frames_kept: int = 0
    frames_processed: int = 0
    frames_used: int = 0
    """Frames whose curves the last fit had (at most ``max_frames``)."""
    lines: int = 0
    """Curves the last fit used (straight under one camera)."""
    curves: int = 0
    """Curves detected in the frames of the last fit."""
    coverage: float = 0.0
    residual_px_before: Optional[float] = None
    """RMS of the used curves' points from their lines under zero-shot (px)."""
    residual_px: Optional[float] = None
    """The same under the fitted camera (px)."""
    uncertainty_px: Optional[float] = None
    """Of the camera the gate chose (the refined one when accepted)."""
    zero_shot_uncertainty_px: Optional[float] = None
    principal_point_shift_px: float = 0.0
    seconds: float = 0.0
    """Worker time (detection + fit) of the last frame."""
    cameras_offered: int = 0
    """Refined cameras offered so far (each one better than the last by ``IMPROVEMENT``)."""
    finished: bool = False
    """Refined, and ``FINISH_AFTER`` frames without a better fit since: no more frames taken."""

    def values(self) -> dict:
        """Display strings per field (for /diagnostics)."""
        def text(v):
            if v is None:
                return ''
            return f'{v:.4g}' if isinstance(v, float) else str(v)
        return {k: text(v) for k, v in dataclasses.asdict(self).items()}


@dataclass
class RefinedCamera:
    """An accepted refinement: the camera (at the size of the frames) and the numbers behind it."""

    camera: KannalaBrandtCamera
    status: RefineStatus
    initial: Optional[KannalaBrandtCamera] = field(default=None, repr=False)


def refined_calibration(camera: KannalaBrandtCamera, width: int, height: int, balance: float = 0.0,
                        fov_scale: float = 1.0, camera_name: str = 'camera') -> CameraCalibration:
    """The ROS record (``equidistant``, P chosen by ``balance`` and ``fov_scale``) of a refined
    camera, at ``width`` x ``height`` (the calibration's size; the camera is scaled to it)."""
    return refined_calibration_and_fit(camera, width, height, balance, fov_scale, camera_name)[0]


def refined_calibration_and_fit(camera: KannalaBrandtCamera, width: int, height: int, balance: float = 0.0,
                                fov_scale: float = 1.0, camera_name: str = 'camera',
                                distortion_model: str = 'equidistant'):
    """(ROS record, fit error px) of a refined camera in ``distortion_model`` (the node's
    parameter): ``equidistant`` is the refined camera itself (error 0); ``plumb_bob`` is fitted
    to it with the zero-shot fitting code (``core/lens/fitting.py``), whose maximum image
    error over the image is returned. P is chosen by ``balance`` and ``fov_scale`` for the
    published model; the camera is scaled to ``width`` x ``height`` (the calibration's size)."""
    if (camera.width, camera.height) != (width, height):
        camera = camera.scaled(width, height)
    error = 0.0
    if distortion_model != 'equidistant':
        if distortion_model not in DISTORTION_FITS:
            raise ValueError(f'distortion_model = {distortion_model!r} is invalid: allowed: '
                             + ', '.join(DISTORTION_FITS))
        fit = DISTORTION_FITS[distortion_model](camera)
        camera, error = fit.camera, float(fit.max_error_px)
    D = camera.D if distortion_model == 'equidistant' else fit.D
    # P's principal point is the refined camera's own, as camera_calibration writes P for a
    # fisheye: OpenCV's rule centres P on the mean of the undistorted edge midpoints, which for a
    # lens near 180 degrees follows whichever edge is nearer 90 degrees (a principal point 1 px
    # off-centre can put P's off the image, and image_rect would show one side of the scene)
    P = np.hstack([principal_point_camera_matrix(camera, balance, fov_scale), np.zeros((3, 1))])
    return (CameraCalibration(width, height, camera.K, distortion_model, D, np.eye(3), P, camera_name),
            error)


def _camera_tuple(camera: Optional[KannalaBrandtCamera]):
    if camera is None:
        return None
    return (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height, list(camera.D))


def _camera_from(values) -> Optional[KannalaBrandtCamera]:
    return None if values is None else KannalaBrandtCamera(*values)


def _send(stream, message: dict, payload=None):
    data = pickle.dumps(message, protocol=4)
    stream.write(_LENGTH.pack(len(data)))
    stream.write(data)
    if payload is not None:
        stream.write(payload)  # a large write goes to os.write directly, without the GIL
    stream.flush()


def _read_exactly(stream, n: int) -> Optional[bytearray]:
    buffer = bytearray(n)
    view = memoryview(buffer)
    got = 0
    while got < n:
        k = stream.readinto(view[got:])
        if not k:
            return None
        got += k
    return buffer


def _receive(stream) -> Optional[dict]:
    head = _read_exactly(stream, _LENGTH.size)
    if head is None:
        return None
    data = _read_exactly(stream, _LENGTH.unpack(head)[0])
    return None if data is None else pickle.loads(bytes(data))


def worker_command() -> list:
    # `python -c` puts the working directory first on sys.path: removed, so that the worker runs
    # the package the node runs (PYTHONPATH), not a source tree the node was started in
    return [sys.executable, '-c', 'import sys; del sys.path[0]; '
            'from zeroshot_calib_ros.core.streaming.online_refinement import worker_main; worker_main()']


class OnlineRefiner:
    """Samples frames and refines the camera of ``spec`` in a worker process (module docstring).

    ``initial``: the camera to start from (an earlier refinement); zero-shot's otherwise.
    ``reference_uncertainty_px``: the uncertainty of ``initial`` when it is the calibration in
    force (an earlier refiner's result): a fit is then offered only at ``IMPROVEMENT`` times it,
    as if this refiner had offered ``initial`` (the rule holds across restarts).
    ``command``: the worker's argv (tests give a broken one)."""

    def __init__(self, spec: CameraSpec, interval: float = DEFAULT_INTERVAL,
                 initial: Optional[KannalaBrandtCamera] = None, fov_tolerance_deg: float = FOV_TOLERANCE_DEG,
                 max_frames: int = MAX_FRAMES, finish_after: int = FINISH_AFTER,
                 command: Optional[Sequence[str]] = None, reference_uncertainty_px: Optional[float] = None):
        self.spec = spec
        self.interval = float(interval)
        self.initial = initial
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._status = RefineStatus()
        self._result: Optional[RefinedCamera] = None
        self._busy = False  # a kept frame is on its way to or in the worker
        self._last_kept: Optional[float] = None
        self._slot = None  # (array, time) the sender writes next
        self._closed = False
        self._done = False  # refined, failed or stopped: no more frames
        self._ender = None  # the thread that ends the worker after stop()
        env = dict(os.environ)
        package_root = str(Path(__file__).resolve().parents[3])
        env['PYTHONPATH'] = package_root + (os.pathsep + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
        for name in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
            env.setdefault(name, '1')
        try:
            self._process = subprocess.Popen(list(command) if command else worker_command(), stdin=subprocess.PIPE,
                                             stdout=subprocess.PIPE, env=env, close_fds=True)
        except OSError as exc:
            self._process = None
            self._closed = self._done = True
            self._status.state, self._status.reason = 'failed', f'cannot start the refinement worker: {exc}'
            return
        _lower_priority(self._process.pid)  # at once, before the worker imports anything
        self._start_message = {'kind': 'start', 'spec': spec, 'fov_tolerance_deg': float(fov_tolerance_deg),
                               'initial': _camera_tuple(initial), 'max_frames': int(max_frames),
                               'reference_uncertainty_px': (None if reference_uncertainty_px is None
                                                            else float(reference_uncertainty_px)),
                               'finish_after': int(finish_after)}
        self._sender = threading.Thread(target=self._send_loop, name='refine_sender', daemon=True)
        self._reader = threading.Thread(target=self._read_loop, name='refine_reader', daemon=True)
        self._sender.start()
        self._reader.start()

    # --- the caller's side (the frame callback) --------------------------------------------
    def due(self, t: float) -> bool:
        """Whether a frame at time ``t`` (seconds, any monotonic clock) would be kept."""
        return not (self._done or self._busy) and (self._last_kept is None or t - self._last_kept >= self.interval)

    def offer(self, image: np.ndarray, t: float, copy: bool = True) -> bool:
        """Keep ``image`` (grey or colour, 8 or 16 bit) if due; returns whether it was kept.
        ``copy=False``: the buffer is immutable (it is then held, not copied)."""
        if not self.due(t):
            return False
        array = np.array(image, copy=True, order='C') if copy else np.ascontiguousarray(image)
        with self._wake:
            if self._done:
                return False
            self._busy = True
            self._last_kept = t
            self._slot = (array, t)
            self._status.frames_kept += 1
            self._wake.notify()
        return True

    @property
    def status(self) -> RefineStatus:
        with self._lock:
            return dataclasses.replace(self._status)

    def take_result(self) -> Optional[RefinedCamera]:
        """The newest refined camera not taken yet, once (None when there is none)."""
        with self._lock:
            result, self._result = self._result, None
            return result

    def stop(self, reason: str = 'stopped', timeout: float = 2.0):
        """Stop refining at once (the state becomes ``stopped`` unless it was refined or failed;
        no frame is taken after) and end the worker in the background: its input is closed, it is
        given ``timeout`` seconds to exit (it may be in the middle of a fit), then killed. Returns
        without waiting (the caller is the node's executor thread); ``join`` waits for the end."""
        with self._wake:
            if self._closed:
                return
            self._closed = self._done = True
            if self._status.state not in ('refined', 'failed'):
                self._status.state, self._status.reason = 'stopped', reason
            self._wake.notify()
        if self._process is None:
            return
        self._ender = threading.Thread(target=self._end_worker, args=(timeout,), name='refine_stop', daemon=True)
        self._ender.start()

    def join(self, timeout: Optional[float] = None) -> bool:
        """Wait until a stopped refiner's worker and threads have ended; whether they have."""
        ender = self._ender
        if ender is not None:
            ender.join(timeout)
            return not ender.is_alive()
        return self._process is None or self._process.poll() is not None

    def _end_worker(self, timeout: float):
        # closing the input waits for a frame being written, and a worker starved of CPU (SCHED_IDLE
        # on a busy machine) may not read it for long: the close runs on its own, and the kill
        # follows the timeout whether it has returned or not (the kill breaks the pipe, ending it)
        closer = threading.Thread(target=self._close_input, name='refine_close', daemon=True)
        closer.start()
        try:
            self._process.wait(timeout)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        closer.join(timeout)
        self._sender.join(timeout)
        self._reader.join(timeout)

    def _close_input(self):
        try:
            self._process.stdin.close()
        except (OSError, ValueError):
            pass

    @property
    def pid(self) -> Optional[int]:
        return None if self._process is None else self._process.pid

    # --- threads ------------------------------------------------------------------------
    def _fail(self, reason: str):
        with self._wake:
            self._done = True
            self._busy = False
            # refined before or not: no more refinement, and said so (unless finished: then its
            # worker exits as it should)
            if not self._closed and not self._status.finished:
                self._status.state, self._status.reason = 'failed', reason
            self._wake.notify()

    def _exit_text(self) -> str:
        try:
            code = self._process.wait(2.0)
        except subprocess.TimeoutExpired:
            return 'the worker stopped answering'
        return f'the refinement worker exited (code {code})'

    def _send_loop(self):
        stream = self._process.stdin
        try:
            _send(stream, self._start_message)
            while True:
                with self._wake:
                    while self._slot is None and not self._done:
                        self._wake.wait()
                    if self._done:  # refined, failed or stopped: the worker may go
                        break
                    (array, t), self._slot = self._slot, None
                header = {'kind': 'frame', 't': t, 'shape': array.shape, 'dtype': array.dtype.str,
                          'nbytes': array.nbytes}
                _send(stream, header, memoryview(array).cast('B'))
                del array
        except (OSError, ValueError) as exc:  # the worker is gone
            if not self._closed:
                self._fail(f'{self._exit_text()}: {exc}')
            return
        try:
            stream.close()  # end of input: the worker exits
        except (OSError, ValueError):
            pass

    def _read_loop(self):
        stream = self._process.stdout
        while True:
            try:
                message = _receive(stream)
            except Exception as exc:  # noqa: BLE001 (garbage on the pipe: the worker is broken)
                message = None
                why = f'unreadable answer from the worker: {exc!r}'
            else:
                why = None
            if message is None:
                if not self._closed:
                    self._fail(why or self._exit_text())
                return
            status = RefineStatus(**message['status'])
            with self._wake:
                status.frames_kept = self._status.frames_kept
                self._status = status
                if message.get('camera') is not None:  # the newest replaces one not taken yet
                    self._result = RefinedCamera(_camera_from(message['camera']), dataclasses.replace(status),
                                                 self.initial)
                if status.finished:
                    self._done = True
                    self._wake.notify()  # the sender ends the worker's input: it exits
                self._busy = False


# --- the worker process ---------------------------------------------------------------------

def _lower_priority(pid: int):
    """Niceness WORKER_NICE (or ZEROSHOT_CALIB_REFINE_NICE) for process ``pid``, and at 19 Linux's
    SCHED_IDLE policy: it then runs only on a core nothing else wants (a waking stream thread
    preempts it at once)."""
    try:
        nice = max(0, min(19, int(os.environ.get(NICE_ENV, WORKER_NICE))))
    except ValueError:
        nice = WORKER_NICE
    try:
        os.setpriority(os.PRIO_PROCESS, pid, nice)
    except (AttributeError, OSError):
        pass
    if nice == 19 and hasattr(os, 'SCHED_IDLE'):
        try:
            os.sched_setscheduler(pid, os.SCHED_IDLE, os.sched_param(0))
        except OSError:
            pass


class _Worker:
    """The worker's state: the spec, the current estimate and the curves of the newest frames."""

    def __init__(self, start: dict):
        from ..estimation.refine import refine_from_frames  # noqa: F401 (imports SciPy once, here)
        from ..zeroshot.solver import solve_zero_shot
        self.spec: CameraSpec = start['spec']
        self.tolerance = start['fov_tolerance_deg']
        self.initial = _camera_from(start['initial'])
        self.max_frames = max(1, int(start['max_frames']))
        self.finish_after = max(1, int(start.get('finish_after', FINISH_AFTER)))
        self.solution = solve_zero_shot(self.spec, 'auto')
        self.start = None  # the spec's ZeroShotStart at the frames' size: made once per size
        self.frames = []  # each kept frame's _KeptFrame, oldest first
        self.count = 0
        self.size = None
        self.camera = None  # the estimate detections use
        self.offered = None  # (camera, uncertainty px) of the last camera offered
        # the calibration in force (an earlier refiner's result) and its uncertainty: the reference
        # of the IMPROVEMENT rule from the first frame on
        self.reference = start.get('reference_uncertainty_px')
        if self.initial is None:
            self.reference = None
        self.offers = 0
        self.since_offer = 0

    def frame(self, image: np.ndarray) -> dict:
        from ..estimation.refine import refine_from_frames
        from ..estimation.zero_shot import zero_shot_start
        from ..lines.detect import curves_from_edges, find_edges
        from ..lines.image_region import combine_circles, find_image_region
        import cv2
        start = time.monotonic()
        height, width = image.shape[:2]
        resized = ''
        if self.size is not None and (width, height) != self.size:
            spec = self.spec
            if abs(width * spec.height - height * spec.width) > 0.01 * spec.width * spec.height:
                raise ValueError(f'images are {width}x{height} but the spec is {spec.width}x{spec.height}: '
                                 'not the same aspect ratio')
            resized = self._follow_size(width, height)
        if self.start is None or (self.start.width, self.start.height) != (width, height):
            self.start = zero_shot_start(self.spec, width, height, self.tolerance, self.solution)
        camera = self.camera
        if camera is None:
            camera = (self.initial.scaled(width, height) if self.initial is not None else
                      self.start.camera)
        if self.offered is None and self.reference is not None:  # the calibration in force
            self.offered = (camera, self.reference)
        # as refine_from_images: the detector kept inside the image circle, the circle as evidence,
        # and what stays put from frame to frame (the robot's own body) left out
        region = find_image_region(image)
        # the zero-shot camera looks with its FOVs rounded (ZeroShotStart.detection_camera), so that
        # the lines found do not hang on the spec's last digits; the curves are made under it exactly
        look = self.start.detection_camera if camera is self.start.camera else camera
        curves = curves_from_edges(find_edges(image, look, region=region), camera, image_id=self.count + 1)
        kept = _KeptFrame(self.count + 1, curves,
                          image if image.ndim == 2 else cv2.cvtColor(image[..., :3], cv2.COLOR_BGR2GRAY),
                          region.circle)
        frames = (self.frames + [kept])[-self.max_frames:]
        every = [c for frame in frames for c in frame.curves]
        start_from = self.offered[0] if self.offered else (camera if self.initial is not None else None)
        result = refine_from_frames(self.spec, every, {frame.image_id: frame.grey for frame in frames}, width, height,
                                    self.tolerance, initial=start_from, solution=self.start,
                                    image_circle=combine_circles([f.circle for f in frames]))
        self.camera, self.size, self.frames = camera, (width, height), frames  # the frame is evidence now
        self.count += 1
        reason, offer = result.reason, result.accepted
        if self.offered is not None:
            new, old = result.uncertainty_px, self.offered[1]
            if offer and not (new is not None and old is not None and new <= IMPROVEMENT * old):
                offer = False
                reason = (f'the newest fit ({px_text(new)} px uncertainty) is not better than the camera in use '
                          f'({px_text(old)} px) by {100 * (1 - IMPROVEMENT):.0f} %')
            elif not offer:
                reason = f'the newest fit is not adopted: {reason}'
        if offer:
            self.offered = (result.camera, result.uncertainty_px)
            self.offers += 1
            self.since_offer = 0
            self.camera = result.camera  # later frames are detected with it (the frames' size)
        elif self.offered is not None:
            self.since_offer += 1
        finished = self.offered is not None and self.since_offer >= self.finish_after
        if result.spec_warnings:  # the spec against the frames: said whatever the verdict
            reason = f'{reason}; warning: {"; ".join(result.spec_warnings)}'
        if resized:
            reason = f'{resized}; {reason}'
        if finished:
            reason = (f'finished: {self.since_offer} frames since the camera in use without a fit better by '
                      f'{100 * (1 - IMPROVEMENT):.0f} % ({reason})')
        if self.offered is not None and (self.offers or self.reference is None):
            state = 'refined'
        elif self.offered is not None:
            state = 'collecting'  # the calibration in force is an earlier refinement: no better fit yet
        else:
            state = 'insufficient' if len(self.frames) >= self.max_frames else 'collecting'
        status = RefineStatus(
            state, reason, 0, self.count, len(self.frames), result.lines_used, len(every),
            float(result.coverage), result.line_residual_px_before, result.line_residual_px_after,
            result.uncertainty_px, result.zero_shot_uncertainty_px, float(result.principal_point_shift_px),
            time.monotonic() - start, self.offers, finished)
        return {'status': dataclasses.asdict(status), 'camera': _camera_tuple(result.camera) if offer else None}


    def _follow_size(self, width: int, height: int) -> str:
        """Frames of another size than the ones before (a camera that changed its mode, or one
        odd frame first): sampling restarts at the new size (curves are in pixels of their
        frame), the camera in use and its uncertainty scaled to it; what the reason says."""
        old = self.size
        scale = width / old[0]
        if self.camera is not None:
            self.camera = self.camera.scaled(width, height)
        if self.offered is not None:
            camera, uncertainty = self.offered
            self.offered = (camera.scaled(width, height), None if uncertainty is None else uncertainty * scale)
        if self.reference is not None:
            self.reference *= scale
        self.frames = []
        return (f'the frames are {width}x{height} now, {old[0]}x{old[1]} before: sampling restarted '
                f'at {width}x{height}')


@dataclasses.dataclass
class _KeptFrame:
    """What the worker keeps of a frame: its curves, its grey image (what stays put across frames
    is found in the frames themselves) and the image circle seen in it."""
    image_id: int
    curves: list
    grey: np.ndarray
    circle: object


def px_text(value) -> str:
    """A pixel figure for a log line or reason ('?' when there is none)."""
    return '?' if value is None else f'{value:.3g}'


def worker_main():
    """The worker process: reads 'start' then frames on stdin, answers each frame on stdout."""
    out = os.fdopen(os.dup(1), 'wb')
    os.dup2(2, 1)  # whatever a library prints goes to stderr, never into the answers
    sys.stdout = sys.stderr
    stdin = sys.stdin.buffer
    import cv2
    cv2.setNumThreads(1)
    start = _receive(stdin)
    if start is None or start.get('kind') != 'start':
        return
    worker = _Worker(start)
    processed = 0
    while True:
        header = _receive(stdin)
        if header is None:
            return
        data = _read_exactly(stdin, header['nbytes'])
        if data is None:
            return
        image = np.frombuffer(data, dtype=np.dtype(header['dtype'])).reshape(header['shape'])
        processed += 1
        try:
            answer = worker.frame(image)
        except Exception as exc:  # noqa: BLE001 (one bad frame: said, and the worker goes on)
            status = RefineStatus('error', f'frame {processed}: {type(exc).__name__}: {exc}', 0, processed)
            answer = {'status': dataclasses.asdict(status), 'camera': None}
        answer['status']['frames_processed'] = processed
        del image, data
        _send(out, answer)
