"""Curves of several images found in worker processes: both cores of a small machine at work.

Threads cannot do it: the detector's merging of pieces into curves is Python that holds the GIL,
so two threads take as long as one (four 1080p frames: 0.33 s of curves per frame in one thread,
the same wall time in two). A worker is a fresh interpreter started as
``python -m zeroshot_calib_ros.core.lines.detection_processes``, never a fork (a fork of a process
with BLAS and OpenCV threads may deadlock) and never multiprocessing's spawn (which runs the
caller's ``__main__`` again: a user's script without a ``__main__`` guard would run twice).
Jobs and results travel as pickles over the worker's stdin and stdout; the worker's own stdout
is stderr (a library's print cannot corrupt the stream). Workers start in a session of their
own, so that a Ctrl-C at the terminal reaches the caller alone, which stops them.

``detect_image`` is the per-image work, the same function in a worker and in the caller's own
thread, so the curves are the same wherever they are found. Imports ``detect``, ``image_region``
and ``static_curves`` only.
"""
from __future__ import annotations

import os
import pickle
import queue
import struct
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Iterable, Iterator, List, Optional

STOP_SECONDS = 5.0
"""How long ``close`` waits for a worker to finish its job before killing it."""


def detect_image(image, look, camera, region=None, image_id=None, gradients: bool = False, views=None,
                 **options):
    """One image's first detection: (region, edges, curves, gradients or None).

    ``region``: the image's ``ImageRegion``, found here when None. ``look``: the camera the edge
    points are looked for with (its views: ``views`` if made already); ``camera``: the camera the
    curves are made under. ``gradients``: also return ``static_curves.image_gradients(image)``."""
    from .detect import curves_from_edges, find_edges
    from .image_region import find_image_region
    from .static_curves import image_gradients
    if region is None:
        region = find_image_region(image)
    edges = find_edges(image, look, views=views, region=region, **options)
    curves = curves_from_edges(edges, camera, image_id=image_id)
    return region, edges, curves, image_gradients(image) if gradients else None


def _curves_from_edges(edges, camera, image_id=None):
    from .detect import curves_from_edges
    return curves_from_edges(edges, camera, image_id=image_id)


JOBS = {'detect_image': detect_image, 'curves_from_edges': _curves_from_edges}
"""What a worker runs, by name (a worker runs nothing else)."""


def _send(stream, value) -> None:
    data = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(struct.pack('<Q', len(data)))
    stream.write(data)
    stream.flush()


def _receive(stream):
    """The next pickle on ``stream``, or raise EOFError at its end."""
    head = stream.read(8)
    if len(head) < 8:
        raise EOFError
    size, = struct.unpack('<Q', head)
    data = stream.read(size)
    if len(data) < size:
        raise EOFError
    return pickle.loads(data)


class WorkerFailed(RuntimeError):
    """A worker process ended without answering (killed, out of memory)."""


class DetectionProcesses:
    """``processes`` worker processes running ``JOBS`` (``map``: in order, as many at once as there
    are workers). Started on first use; ``close`` (or the ``with`` block's end) ends them."""

    def __init__(self, processes: int):
        if processes < 1:
            raise ValueError(f'processes = {processes} is invalid: allowed: 1 or more')
        self.processes = int(processes)
        self._workers: List[subprocess.Popen] = []
        self._idle: 'queue.Queue[subprocess.Popen]' = queue.Queue()

    def __enter__(self) -> 'DetectionProcesses':
        return self

    def __exit__(self, kind, *exc) -> None:
        self.close(kill=kind is not None)  # an error or a Ctrl-C: stop at once, not after the jobs

    @property
    def pids(self) -> List[int]:
        return [w.pid for w in self._workers]

    def _start(self) -> None:
        root = str(Path(__file__).resolve().parents[3])  # where zeroshot_calib_ros is imported from
        path = os.environ.get('PYTHONPATH')
        env = dict(os.environ, PYTHONPATH=root if not path else root + os.pathsep + path)
        # each worker has one core: a BLAS or OpenCV thread pool per worker would only contend
        env.update(OPENBLAS_NUM_THREADS='1', OMP_NUM_THREADS='1')
        for _ in range(self.processes):
            worker = subprocess.Popen([sys.executable, '-m', __name__], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, env=env, start_new_session=True)
            self._workers.append(worker)
            self._idle.put(worker)

    def _run(self, job):
        worker = self._idle.get()
        if worker is None:  # closed: let the next waiting job see it too
            self._idle.put(None)
            raise WorkerFailed('the detection worker processes were stopped')
        try:
            _send(worker.stdin, job)
            ok, value = _receive(worker.stdout)
        except (EOFError, OSError, pickle.UnpicklingError):
            # not put back: the caller gets this error in its turn, and its close() stops the
            # jobs still waiting for a worker
            try:
                status = worker.wait(STOP_SECONDS)
            except subprocess.TimeoutExpired:
                status = 'none yet'
            raise WorkerFailed(f'a detection worker process ended without answering (exit status {status})') from None
        self._idle.put(worker)
        if not ok:
            raise value
        return value

    def map(self, name: str, jobs: Iterable[tuple]) -> Iterator:
        """``JOBS[name](*args, **kwargs)`` for each ``(args, kwargs)`` of ``jobs``, in order."""
        if name not in JOBS:
            raise ValueError(f'unknown job {name!r}: allowed: {", ".join(JOBS)}')
        if not self._workers:
            self._idle = queue.Queue()
            self._start()
        jobs = [(name, args, kwargs) for args, kwargs in jobs]
        # one thread per worker, each waiting for its worker's answer; not waited for when the
        # caller stops early (an error, a Ctrl-C): close() ends the workers, and so those waits
        pool = ThreadPoolExecutor(max_workers=self.processes, thread_name_prefix='detection')
        try:
            yield from pool.map(self._run, jobs)
        finally:
            pool.shutdown(wait=False, cancel_futures=True)

    def close(self, kill: bool = False) -> None:
        """End the workers: their input closed (a worker exits when its job is done), killed
        after ``STOP_SECONDS``, or at once with ``kill``."""
        for worker in self._workers:
            try:
                if kill:
                    worker.kill()
                worker.stdin.close()
            except OSError:
                pass
        for worker in self._workers:
            try:
                worker.wait(STOP_SECONDS)
            except subprocess.TimeoutExpired:
                worker.kill()
                worker.wait()
            worker.stdout.close()
        self._workers = []
        self._idle.put(None)  # a job still waiting for a worker fails instead of waiting forever


def serve(read, write, jobs: Optional[dict] = None) -> None:
    """A worker's loop: run each job read, write ``(True, result)`` or ``(False, exception)``,
    until its input ends."""
    jobs = JOBS if jobs is None else jobs
    while True:
        try:
            name, args, kwargs = _receive(read)
        except EOFError:
            return
        try:
            answer = (True, jobs[name](*args, **kwargs))
        except Exception as error:  # the caller raises it, with the worker's traceback lost
            try:
                pickle.dumps(error)
            except Exception:
                error = RuntimeError(f'{type(error).__name__}: {error}')
            answer = (False, error)
        try:
            _send(write, answer)
        except BrokenPipeError:
            return


def _main() -> None:
    out = os.fdopen(os.dup(sys.stdout.fileno()), 'wb')
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # a print in a worker goes to stderr
    import cv2
    cv2.setNumThreads(1)
    serve(sys.stdin.buffer, out)


if __name__ == '__main__':
    _main()
