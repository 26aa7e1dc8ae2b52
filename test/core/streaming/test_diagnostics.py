"""The node's /diagnostics status without DDS (core/streaming/diagnostics.py): its level and
message from the state a user watches for (frames without a CameraInfo, a failed refiner, a spec
whose FOVs do not fit), the values' keys, and the rectify and frame path texts."""
from collections import Counter

import pytest

from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.streaming.diagnostics import (calibration_status, frame_path_text, rectify_text,
                                                           refine_values)
from zeroshot_calib_ros.core.streaming.image_frames import ActiveCalibration


@pytest.fixture(scope='module')
def active():
    solution = solve_zero_shot(CameraSpec(640, 360, 118, 69))
    calibration, _ = CameraCalibration.from_solution(solution)
    return ActiveCalibration(calibration, solution.camera, 'spec', 3, rectify=True, build_maps=False)


def status(active, **changes):
    state = dict(serialized=True, frame_path_reason='', executor='single', rectify='off', rect_subscribers=0,
                 qos_reliability='RELIABLE', pending_generation='', maps_build_ms=float('nan'),
                 process_rss_bytes=100 * 2**20, refine=refine_values(None, 'refine is false'),
                 stats=Counter(), uncalibrated=None)
    state.update(changes)
    return calibration_status('zeroshot_calib', active, **state)


def test_a_calibration_in_force_is_ok_and_says_its_source(active):
    s = status(active)
    assert (s.level, s.name, s.message) == ('OK', 'zeroshot_calib: calibration', 'calibration from spec')
    assert s.hardware_id == active.calibration.camera_name
    assert list(s.values)[:16] == [
        'source', 'generation', 'frame_path', 'executor', 'rectify', 'image_rect_subscribers', 'frames_rectified',
        'frames_not_rectified_no_subscriber', 'fx', 'qos_reliability', 'pending_generation', 'maps_build_ms',
        'map_memory_mb', 'frame_buffer_mb', 'process_rss_mb', 'refine_state']
    assert s.values['generation'] == 3 and s.values['frames_rectified'] == 0
    assert (s.values['maps_build_ms'], s.values['process_rss_mb']) == ('nan', '100.0')
    assert s.values['refine_reason'] == 'refine is false'


def test_the_counters_replace_the_zero_defaults_in_place(active):
    s = status(active, stats=Counter(frames_rectified=5, frames_skipped_aspect=2))
    assert s.values['frames_rectified'] == 5 and s.values['frames_skipped_aspect'] == 2
    assert list(s.values).index('frames_rectified') == 6


def test_frames_without_a_camera_info_are_an_error_naming_their_size(active):
    s = status(active, uncalibrated=((640, 480), 'image 640x480 does not have the aspect ratio'))
    assert s.level == 'ERROR'
    assert s.message == 'no CameraInfo for the 640x480 frames: image 640x480 does not have the aspect ratio'


def test_a_failed_refiner_is_a_warning(active):
    values = dict(state='failed', reason='worker died', frames_processed=3, cameras_offered=0, lines=0,
                  coverage='', residual_px='', uncertainty_px='', zero_shot_uncertainty_px='')
    s = status(active, refine=refine_values(values, 'unused'))
    assert s.level == 'WARN' and s.values['refine_state'] == 'failed' and s.values['refine_frames'] == 3
    assert status(active, refine=refine_values(dict(values, state='sampling'), '')).level == 'OK'


def test_a_spec_whose_fovs_do_not_fit_is_a_warning_with_its_reasons(active):
    warned = ActiveCalibration(active.calibration, active.camera, 'spec', rectify=False, build_maps=False)
    warned.spec_warnings = ('hfov 118 is not shown', 'vfov 69 is not shown')  # as solve_from_settings sets them
    s = status(warned)
    assert s.level == 'WARN' and s.message.endswith(": the spec's FOVs do not fit the image (spec_warning)")
    assert s.values['spec_warning'] == 'hfov 118 is not shown | vfov 69 is not shown'


def test_the_frame_path_value_says_why_the_message_path_is_taken(active):
    assert status(active, serialized=False, frame_path_reason='X=message').values['frame_path'] == 'message (X=message)'
    assert frame_path_text(False, 'X=message') == 'message: sensor_msgs/Image objects (X=message)'
    assert frame_path_text(True, '').startswith('serialized: image_raw taken as CDR bytes')
    assert frame_path_text(True, 'why').endswith(' (why)')


@pytest.mark.parametrize('enabled, count, ever, text', [
    (False, 3, True, 'off'),
    (True, 0, False, 'on, lazy: no subscriber yet'),
    (True, 0, True, 'on, lazy: no subscriber'),
    (True, 1, True, 'on: 1 subscriber'),
    (True, 2, True, 'on: 2 subscribers'),
])
def test_the_rectify_text(enabled, count, ever, text):
    assert rectify_text(enabled, count, ever) == text


@pytest.mark.parametrize('source', ['file', 'set_camera_info', 'refined'])
def test_the_status_names_the_source_of_the_calibration_in_force(active, source):
    """A user reads in /diagnostics where the CameraInfo comes from: a file, a set_camera_info
    call, the refiner, not always the spec the node started from."""
    other = ActiveCalibration(active.calibration, active.camera, source, 4, rectify=False, build_maps=False)
    s = status(other)
    assert s.values['source'] == source and s.message == f'calibration from {source}'
    assert s.values['generation'] == 4
