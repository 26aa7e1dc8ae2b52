"""The refiner's life cycle in the node without DDS or a worker process
(core/streaming/refinement_control.py): a refiner runs only with refine on and for a calibration
from the spec or an earlier refinement, restarts when the spec changes, is stopped (its findings
discarded) when a file or set_camera_info calibration comes, and says a failure once."""
from types import SimpleNamespace

import numpy as np
import pytest

from zeroshot_calib_ros.core import CameraSpec
from zeroshot_calib_ros.core.streaming.refinement_control import RefinementControl, refine_settings
from zeroshot_calib_ros.core.zeroshot.spec import SpecError

SPEC = CameraSpec(640, 360, 118, 69)


class FakeRefiner:
    """What the node uses of an OnlineRefiner, without its worker process."""

    def __init__(self, spec, interval, initial, reference):
        self.spec, self.interval, self.initial, self.reference = spec, interval, initial, reference
        self.pid = 4242
        self.stopped = None
        self.offered = []
        self.result = None
        self.status = SimpleNamespace(state='sampling', frames_kept=0, frames_processed=0, reason='', lines=0,
                                      coverage=0.0, values=lambda: dict(
                                          state=self.status.state, reason=self.status.reason,
                                          frames_processed=self.status.frames_processed, cameras_offered=0,
                                          lines=0, coverage='', residual_px='', uncertainty_px='',
                                          zero_shot_uncertainty_px=''))

    def stop(self, why):
        self.stopped = why
        self.status = SimpleNamespace(**{**vars(self.status), 'state': 'stopped'})  # a status is a snapshot

    def due(self, now):
        return True

    def offer(self, image, now, copy):
        self.offered.append((image.shape, copy))
        return True

    def take_result(self):
        result, self.result = self.result, None
        return result


def calibration(source, generation=0):
    return SimpleNamespace(source=source, generation=generation)


def control(refine=True, due=lambda key: True):
    logged, made = [], []

    def make(spec, interval, initial, reference):
        made.append(FakeRefiner(spec, interval, initial, reference))
        return made[-1]
    c = RefinementControl(refine, 2.0, lambda level, text: logged.append((level, text)), due, make_refiner=make)
    return c, logged, made


def test_refine_off_runs_no_refiner_and_says_why_in_diagnostics():
    c, logged, made = control(refine=False)
    c.follow(calibration('spec'), SPEC, None)
    assert c.refiner is None and made == [] and logged == []
    assert c.diagnostics() == {'refine_state': 'off', 'refine_reason': 'refine is false'}


def test_a_spec_calibration_is_refined_and_a_file_calibration_stops_the_refiner():
    c, logged, made = control()
    c.follow(calibration('spec'), SPEC, None)
    assert c.refiner is made[0] and made[0].interval == 2.0
    assert logged[-1] == ('info', 'refine: sampling one frame every 2 s (worker pid 4242, low priority); '
                                  'refining the calibration from spec (generation 0)')
    c.follow(calibration('set_camera_info', 1), SPEC, None)
    assert c.refiner is None and made[0].stopped.startswith('the calibration from set_camera_info is not refined')
    assert logged[-1][1].startswith('refinement stopped (sampling, 0 frame(s) taken; what it found is discarded)')
    assert c.diagnostics()['refine_reason'] == c.off and c.diagnostics()['refine_state'] == 'off'


def test_a_new_spec_restarts_the_refiner_and_the_same_spec_keeps_it():
    c, _, made = control()
    c.follow(calibration('spec'), SPEC, None)
    c.follow(calibration('spec', 1), SPEC, None)
    assert len(made) == 1  # re-solved from the same spec: the evidence still holds
    c.follow(calibration('spec', 2), CameraSpec(640, 360, 120, 69), None)
    assert len(made) == 2 and made[0].stopped == 'the spec changed' and c.refiner is made[1]


def test_a_refined_calibration_keeps_its_refiner_and_a_new_one_starts_from_it():
    c, _, made = control()
    c.follow(calibration('spec'), SPEC, None)
    c.follow(calibration('refined', 1), SPEC, ('camera', 0.5))
    assert len(made) == 1  # its own result
    c.configure(False, 2.0)
    c.follow(calibration('refined', 1), SPEC, ('camera', 0.5))
    c.configure(True, 3.0)
    c.follow(calibration('refined', 1), SPEC, ('camera', 0.5))
    # a restarted refiner starts from the refinement in force and must beat its uncertainty
    assert (made[-1].initial, made[-1].reference, made[-1].interval) == ('camera', 0.5, 3.0)


def test_a_failed_refiner_is_said_once_and_the_calibration_in_force_stays():
    c, logged, made = control()
    c.follow(calibration('spec'), SPEC, None)
    made[0].status.state, made[0].status.frames_processed, made[0].status.reason = 'failed', 3, 'worker died'
    assert c.poll() is None and c.poll() is None
    failures = [text for level, text in logged if level == 'warning']
    assert failures == ['refine: failed after 3 frame(s): worker died; no more refinement (the calibration in '
                        'force stays); set refine to false and true to restart it']
    assert c.diagnostics()['refine_state'] == 'failed'


def test_an_accepted_refinement_is_handed_to_the_node_once():
    c, _, made = control()
    c.follow(calibration('spec'), SPEC, None)
    made[0].result = 'refined'
    assert c.poll() == 'refined' and c.poll() is None


def test_error_lines_are_throttled():
    c, logged, made = control(due=lambda key: False)
    c.follow(calibration('spec'), SPEC, None)
    made[0].status.state, made[0].status.frames_processed = 'error', 1
    c.poll()
    assert [level for level, _ in logged] == ['info']


def test_a_frame_is_offered_as_an_image_and_one_it_cannot_read_is_not():
    c, _, made = control()
    c.follow(calibration('spec'), SPEC, None)
    assert c.offer(np.zeros(640 * 360, np.uint8).tobytes(), 640, 360, 640, 'mono8', 0, False, 1.0)
    assert made[0].offered == [((360, 640), False)]
    assert not c.offer(b'', 640, 360, 640, 'mono8', 0, False, 2.0)


def test_refine_settings_are_checked():
    assert refine_settings({'refine': True, 'refine_interval': 5.0}) == (True, 5.0)
    with pytest.raises(SpecError):
        refine_settings({'refine': 'yes', 'refine_interval': 5.0})
    with pytest.raises(SpecError):
        refine_settings({'refine': True, 'refine_interval': 0.0})


def test_a_new_refine_interval_governs_the_running_refiner_without_restarting_it():
    c, _, made = control()
    c.follow(calibration('spec'), SPEC, None)
    assert len(made) == 1 and made[0].interval == 2.0
    c.configure(True, 5.0)
    c.follow(calibration('spec'), SPEC, None)
    assert len(made) == 1 and made[0].stopped is None
    assert made[0].interval == 5.0
