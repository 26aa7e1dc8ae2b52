"""The refiner's life cycle in the node, without ROS: whether a refiner runs (``refine`` on and a
calibration from the spec or an earlier refinement), when it is started, restarted or stopped,
the frames offered to it, what it says, and its /diagnostics values.

The node (``zeroshot_calib_ros/ros/node.py``) gives ``log(level, text)`` and ``due(key)`` (its
throttle) and adopts the refinements ``poll`` returns (``calibration_cycle``)."""
from __future__ import annotations

from typing import Callable, Optional

from ..zeroshot.spec import CameraSpec, SpecError
from .calibration_cycle import REFINABLE_SOURCES
from .diagnostics import refine_values
from .image_frames import ActiveCalibration, FrameSkipped, image_array
from .node_parameters import number_in_range


def refine_settings(values: dict) -> tuple:
    """(refine, refine_interval) checked, else SpecError naming the allowed values."""
    if not isinstance(values['refine'], bool):
        raise SpecError('refine', values['refine'], 'true or false')
    return values['refine'], number_in_range('refine_interval', values['refine_interval'], 0.1, 3600.0)


def _online_refiner(spec, interval, initial, reference_uncertainty_px):
    # imported here: its worker process, pickling and Kannala-Brandt fitting are not what a
    # node with refine off (the default) should import before its first CameraInfo
    from .online_refinement import OnlineRefiner

    return OnlineRefiner(spec, interval, initial=initial, reference_uncertainty_px=reference_uncertainty_px)


class RefinementControl:
    """``refiner``: an online_refinement.OnlineRefiner while one runs (``make_refiner(spec,
    interval, initial, reference_uncertainty_px)`` starts one); ``off``: why none runs."""

    def __init__(self, refine: bool, interval: float, log: Callable[[str, str], None],
                 due: Callable[[str], bool], make_refiner=_online_refiner):
        self.refine, self.interval = refine, interval
        self.refiner = None
        self.off = 'refine is false'  # why no refiner runs (diagnostics)
        self._logged = None
        self._log, self._due, self._make_refiner = log, due, make_refiner

    def configure(self, refine: bool, interval: float):
        """New ``refine`` / ``refine_interval`` values (``follow`` then starts or stops the refiner)."""
        self.refine, self.interval = refine, interval
        if self.refiner is not None:
            self.refiner.interval = interval

    def follow(self, active: ActiveCalibration, spec: CameraSpec, refined: Optional[tuple]):
        """Start, keep or stop the refiner for ``active`` (the newest calibration): only one from
        the spec or an earlier refinement is refined; a refiner whose basis is replaced by another
        kind of calibration is stopped (what it found is discarded), one whose spec changed restarts.
        ``refined``: (camera, uncertainty px) of the last refinement adopted, the start and the
        bar of a refiner of a refined calibration."""
        refiner = self.refiner
        if not self.refine:
            why = 'refine is false'
        elif active.source not in REFINABLE_SOURCES:
            why = (f'the calibration from {active.source} is not refined (only one from the spec or an '
                   'earlier refinement)')
        else:
            why = None
        if why is not None:
            if refiner is not None:
                before = refiner.status
                refiner.stop(why)
                self.refiner = None
                self._log('info', f'refinement stopped ({before.state}, {before.frames_kept} frame(s) taken; '
                          f'what it found is discarded): {why}')
            elif self.refine and why != self.off:
                self._log('info', f'refine: {why}')
            self.off = why
            return
        if refiner is not None:
            if active.source == 'refined':
                return  # its own result, or a change of rectification only
            if refiner.spec == spec and refiner.status.state not in ('failed', 'stopped'):
                return  # re-solved from the same spec: the evidence still holds
            refiner.stop('the spec changed')
        initial, reference = refined if active.source == 'refined' and refined else (None, None)
        self.refiner = self._make_refiner(spec, self.interval, initial, reference)
        self._logged = None
        self._log('info',
                  f'refine: sampling one frame every {self.interval:g} s (worker pid {self.refiner.pid}, '
                  f'low priority); refining the calibration from {active.source} (generation {active.generation})')

    def offer(self, data, width: int, height: int, step: int, encoding: str, is_bigendian: bool, copy: bool,
              now: float) -> bool:
        """A frame: whether the refiner took it (else a comparison: not due)."""
        refiner = self.refiner
        if not refiner.due(now):
            return False
        try:
            image = image_array(data, width, height, step, encoding, is_bigendian)
        except FrameSkipped:
            return False  # already counted as skipped by the frame's own checks, or an encoding it cannot read
        return refiner.offer(image, now, copy=copy)

    def poll(self):
        """Housekeeping: log the refiner's state changes; the accepted refinement, if any."""
        refiner = self.refiner
        if refiner is None:
            return None
        status = refiner.status
        key = (status.state, status.frames_processed)
        if status.state == 'failed':  # the worker is gone: said once, with what to do
            if self._logged != 'failed':
                self._logged = 'failed'
                self._log('warning',
                          f'refine: failed after {status.frames_processed} frame(s): {status.reason}; no more refinement '
                          '(the calibration in force stays); set refine to false and true to restart it')
        elif key != self._logged and status.frames_processed:
            self._logged = key
            text = (f'refine: {status.state} after {status.frames_processed} frame(s): {status.lines} lines, '
                    f'coverage {100 * status.coverage:.0f} %: {status.reason}')
            if status.state == 'error':
                if self._due('refine_error'):  # a frame the worker cannot use: at most one line every few s
                    self._log('warning', text)
            else:
                self._log('info', text)
        return refiner.take_result()

    def diagnostics(self) -> dict:
        """The ``refine_*`` values of /diagnostics."""
        refiner = self.refiner
        return refine_values(refiner.status.values() if refiner is not None else None, self.off)

    def shutdown(self):
        refiner = self.refiner
        if refiner is not None:
            refiner.stop('the node is shutting down')
            refiner.join(3.0)
