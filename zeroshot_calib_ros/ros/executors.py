"""Which rclpy executor spins the node: rclpy's default SingleThreadedExecutor, or its
EventsExecutor (``rclpy.experimental``, written in C++), chosen with the environment variable
ZEROSHOT_CALIB_EXECUTOR (``single``, the default, or ``events``).

Whatever spins the node, work from other threads (the map builder's finished maps) reaches the
executor thread through ``executor.create_task``, which both executors take from any thread;
the EventsExecutor refuses guard conditions.

The EventsExecutor of rclpy 7.1 (ROS 2 Jazzy) is spun with ``spin_once`` in a loop: its
``spin()`` kept a core busy and never ran a timer in our tests (rclpy 7.1.6, the ros-rclpy wheel).
"""
from __future__ import annotations

import os
import signal
from typing import Optional, Tuple

EXECUTOR_ENV = 'ZEROSHOT_CALIB_EXECUTOR'
"""'single' (the default: rclpy's SingleThreadedExecutor) or 'events' (rclpy's EventsExecutor)."""
EXECUTORS = ('single', 'events')
_NAMES = {'single': 'SingleThreadedExecutor', 'events': 'EventsExecutor (rclpy.experimental)'}
SPIN_ONCE_TIMEOUT = 1.0
"""Seconds an EventsExecutor's spin_once waits for work before the loop checks the context again."""


def executor_choice(environ=os.environ) -> Tuple[str, str]:
    """(the executor asked for: 'single' or 'events', why when it is not the default)."""
    wanted = environ.get(EXECUTOR_ENV, '').strip().lower()
    if wanted in ('', 'single', 'default'):
        return 'single', ''
    if wanted == 'events':
        return 'events', f'{EXECUTOR_ENV}=events'
    return 'single', (f'{EXECUTOR_ENV}={wanted!r} is none of {", ".join(EXECUTORS)}: the default, '
                      'single, is used')


def _single_threaded_executor(context=None):
    """rclpy's SingleThreadedExecutor, whose ``__del__`` survives a Ctrl-C inside ``__init__``.

    rclpy 7.1's ``Executor.__del__`` reads ``self._sigint_gc``, which ``__init__`` sets last: a
    SIGINT that lands earlier left a half-built executor whose collection printed "Exception
    ignored ... AttributeError" with a traceback on the user's Ctrl-C. A class-level None gives
    ``__del__`` something to read; a finished ``__init__`` overrides it as before."""
    import rclpy.executors

    class SingleThreadedExecutor(rclpy.executors.SingleThreadedExecutor):
        _sigint_gc = None

    return SingleThreadedExecutor(context=context)


def create_executor(choice: str, context=None) -> Tuple[object, str, str]:
    """(executor, 'single' or 'events', why) for ``choice``; the default executor when this
    rclpy has no EventsExecutor (said in ``why``)."""
    why = ''
    if choice == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError as exc:
            why = f'{EXECUTOR_ENV}=events, but this rclpy has no EventsExecutor ({exc}): the default is used'
        else:
            return EventsExecutor(context=context), 'events', f'{EXECUTOR_ENV}=events'
    return _single_threaded_executor(context), 'single', why


def executor_text(name: str, why: str = '') -> str:
    """How the start-up log and /diagnostics name the executor in use."""
    return _NAMES.get(name, name) + (f' ({why})' if why else '')


def spin(executor, name: str, context: Optional[object] = None):
    """Spin until the context is shut down (Ctrl-C: KeyboardInterrupt or
    ExternalShutdownException, as rclpy.spin raises them)."""
    if name != 'events':
        executor.spin()
        return
    import rclpy

    context = context or rclpy.get_default_context()
    # Ctrl-C: the EventsExecutor stops a spin_once that waits (its own signal handling), but
    # Python's handler would raise KeyboardInterrupt inside whatever callback runs (a frame being
    # remapped: logged as a fatal callback error). Here it only ends the loop once that callback
    # is done.
    interrupted = []
    previous = {}
    for signum in (signal.SIGINT, signal.SIGTERM):
        try:
            previous[signum] = signal.signal(signum, lambda number, frame: interrupted.append(number))
        except ValueError:  # not the main thread: Python's handlers cannot be set
            pass
    try:
        while context.ok() and not interrupted:
            executor.spin_once(timeout_sec=SPIN_ONCE_TIMEOUT)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if interrupted:
        raise KeyboardInterrupt
