"""The node's calibration life cycle without DDS (core/streaming/calibration_cycle.py): the
calibration at start-up (file before spec), candidates that fail never replace the calibration
in force, a newer generation is never replaced by an older one, set_camera_info is saved only
once in force, refinements are built over the newest calibration."""
import os

import numpy as np
import pytest

from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.streaming.calibration_cycle import CalibrationCycle, summary_warnings
from zeroshot_calib_ros.core.streaming.node_parameters import PARAMETERS, Settings
from zeroshot_calib_ros.core.zeroshot.spec import SpecError

BUDGET = 2**40


def values(**changes):
    v = {name: p.default for name, p in PARAMETERS.items()}
    v.update(width=640, height=360, hfov=118.0, vfov=69.0)
    v.update(changes)
    return v


def started(tmp_path, **changes):
    logged = []
    cycle = CalibrationCycle(str(tmp_path / 'camera.yaml'), BUDGET)
    cycle.start(Settings.from_values(values(**changes)), lambda level, text: logged.append((level, text)))
    cycle.values_in_force = values(**changes)
    return cycle, logged


def a_calibration(width=640, height=360, camera_name='camera'):
    calibration, _ = CameraCalibration.from_solution(solve_zero_shot(CameraSpec(width, height, 118, 69)))
    calibration.camera_name = camera_name
    return calibration


def test_without_a_file_the_spec_is_in_force_and_set_camera_info_will_save_there(tmp_path):
    cycle, logged = started(tmp_path)
    assert cycle.active is cycle.newest and cycle.active.source == 'spec' and cycle.generation == 0
    assert cycle.file_state == f'none at {tmp_path / "camera.yaml"} yet: set_camera_info will save there'
    assert logged[0][0] == 'info' and logged[0][1].startswith('zero-shot calibration from the spec sheet:')


def test_a_file_at_camera_info_url_takes_precedence_over_the_spec(tmp_path):
    path = tmp_path / 'camera.yaml'
    a_calibration(1280, 720, camera_name='other').save(str(path))
    cycle, logged = started(tmp_path)
    assert cycle.active.source == f'file {path}' and cycle.active.size == (1280, 720)
    assert cycle.file_state == f'loaded {path}; set_camera_info saves there'
    warnings = [text for level, text in logged if level == 'warning']
    assert any("camera_name 'other'" in text for text in warnings)
    assert any('is for 1280x720 images, the spec says 640x360' in text for text in warnings)


def test_an_unreadable_file_is_said_and_the_spec_is_used(tmp_path):
    (tmp_path / 'camera.yaml').write_text('image_width: [\n')
    cycle, logged = started(tmp_path)
    assert cycle.active.source == 'spec'
    assert logged[0][0] == 'error' and logged[0][1].startswith(f'ignoring camera_info_url {tmp_path / "camera.yaml"}')
    assert 'unreadable' in cycle.file_state


def test_a_failed_parameter_change_never_replaces_the_calibration_in_force(tmp_path):
    cycle, _ = started(tmp_path)
    active, generation = cycle.active, cycle.generation
    with pytest.raises(SpecError):
        cycle.for_parameters({'hfov'}, values(hfov=-5.0))
    assert (cycle.active, cycle.newest, cycle.generation) == (active, active, generation)


def test_a_parameter_change_is_a_newer_generation_in_force_once_swapped_in(tmp_path):
    cycle, _ = started(tmp_path)
    settings, candidate, summary = cycle.for_parameters({'hfov'}, values(hfov=120.0))
    assert candidate.generation == 1 and summary is not None and settings.spec.hfov == 120.0
    before = cycle.active
    cycle.accept(candidate)
    assert cycle.newest is candidate and cycle.active is before  # its maps being built
    assert cycle.swap_in(candidate, values(hfov=120.0))
    assert cycle.active is candidate and cycle.values_in_force['hfov'] == 120.0
    assert not cycle.swap_in(before, None)  # an older generation never replaces a newer one
    assert cycle.active is candidate


def test_a_rectification_change_keeps_a_file_calibration(tmp_path):
    a_calibration().save(str(tmp_path / 'camera.yaml'))
    cycle, _ = started(tmp_path)
    _, candidate, summary = cycle.for_parameters({'balance'}, values(balance=1.0))
    assert summary is None and candidate.source == cycle.active.source
    assert candidate.calibration.K.tolist() == cycle.active.calibration.K.tolist()
    assert candidate.calibration.P.tolist() != cycle.active.calibration.P.tolist()


def test_maps_that_fail_to_build_leave_the_calibration_in_force_and_restore_its_values(tmp_path):
    cycle, _ = started(tmp_path)
    before = cycle.active
    _, candidate, _ = cycle.for_parameters({'hfov'}, values(hfov=120.0))
    cycle.accept(candidate)
    assert cycle.build_failed(candidate)
    assert cycle.active is before and cycle.newest is before
    assert cycle.values_to_restore(values(hfov=120.0, refine=True)) == {'hfov': 118.0}
    # a failed build that a newer change already replaced: the newer one stays pending
    _, first, _ = cycle.for_parameters({'hfov'}, values(hfov=121.0))
    cycle.accept(first)
    _, second, _ = cycle.for_parameters({'hfov'}, values(hfov=122.0))
    cycle.accept(second)
    assert not cycle.build_failed(first) and cycle.newest is second


def test_set_camera_info_is_saved_once_in_force(tmp_path):
    cycle, _ = started(tmp_path)
    calibration = a_calibration()
    candidate = cycle.for_camera_info(calibration, Settings.from_values(values()))
    assert candidate.source == 'set_camera_info' and candidate.generation == 1
    cycle.accept(candidate)
    cycle.save_when_in_force = (calibration, candidate.generation)
    assert not os.path.exists(tmp_path / 'camera.yaml')
    cycle.swap_in(candidate, None)
    assert cycle.save_in_force(candidate) == (
        'info', f'calibration from set_camera_info in force and saved to {tmp_path / "camera.yaml"}')
    assert os.path.exists(tmp_path / 'camera.yaml') and cycle.save_when_in_force is None


def test_set_camera_info_replaced_before_it_is_in_force_is_not_saved(tmp_path):
    cycle, _ = started(tmp_path)
    calibration = a_calibration()
    candidate = cycle.for_camera_info(calibration, Settings.from_values(values()))
    cycle.accept(candidate)
    cycle.save_when_in_force = (calibration, candidate.generation)
    _, spec, _ = cycle.for_parameters({'hfov'}, values(hfov=120.0))
    cycle.accept(spec)
    cycle.swap_in(spec, None)
    assert cycle.save_in_force(spec) == (
        'warning', 'calibration from set_camera_info (generation 1) not adopted and not saved: spec is in force instead')
    assert not os.path.exists(tmp_path / 'camera.yaml')
    assert cycle.drop_pending_save(5, 'again') is None  # said once


def test_a_save_to_a_path_that_cannot_be_a_file_says_so(tmp_path):
    (tmp_path / 'camera.yaml').mkdir()  # a directory where the file would go
    cycle = CalibrationCycle(str(tmp_path / 'camera.yaml'), BUDGET)
    saved, text = cycle.save_camera_info(a_calibration())
    assert not saved and text.startswith(f' but NOT saved to {tmp_path / "camera.yaml"}: ')
    assert cycle.save(a_calibration())[1].startswith('NOT saved to ')


def test_a_refinement_is_built_over_the_newest_calibration_in_the_configured_model(tmp_path):
    cycle, _ = started(tmp_path, distortion_model='plumb_bob')
    refined_camera = a_calibration(1280, 720).camera()  # equidistant: a Kannala-Brandt camera
    active, fit_error_px = cycle.for_refinement(refined_camera, Settings.from_values(values(distortion_model='plumb_bob')))
    assert active.source == 'refined' and active.generation == cycle.generation + 1
    assert active.size == (640, 360) and active.calibration.distortion_model == 'plumb_bob'
    assert fit_error_px > 0
    assert cycle.active.source == 'spec'  # built, not adopted


def test_a_spec_that_the_solved_camera_misses_is_warned():
    summary = {'warning': ['hfov 118 is not shown'], 'fit_error_px': 0.0, 'distortion_model': 'equidistant'}
    assert summary_warnings(summary) == ['spec: hfov 118 is not shown']
    summary = {'fit_error_px': 50.0, 'distortion_model': 'plumb_bob'}
    assert summary_warnings(summary)[0].endswith('(use distortion_model: equidistant for a lens this wide)')
    assert summary_warnings(None) == []


def test_a_new_balance_keeps_a_refined_cameras_principal_point_in_p(tmp_path):
    """balance changed after a refined 175-degree lens, 1 px off-centre, was adopted: the new P's
    principal point is still the camera's own (OpenCV's rule would move it 250 px to one side)."""
    from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
    cycle, _ = started(tmp_path)
    lens = KannalaBrandtCamera(209.18, 209.18, 321.0, 176.3, 640, 360, [0.0, 0.0, 0.0, 0.0])
    refined, _ = cycle.for_refinement(lens, Settings.from_values(values()))
    cycle.accept(refined)
    _, active, _ = cycle.for_parameters({'balance'}, values(balance=0.5))
    assert active.source == 'refined'
    np.testing.assert_allclose(active.calibration.P[:2, 2], [321.0, 176.3])
    assert active.calibration.P[0, 0] != pytest.approx(refined.calibration.P[0, 0])


def test_a_refined_calibrations_P_is_chosen_by_balance_and_fov_scale_as_the_zero_shot_ones(tmp_path):
    """A user who sets balance or fov_scale gets the same choice of rectified camera after a
    refinement is adopted: balance 1 keeps every edge (a shorter focal length than balance 0),
    fov_scale 2 halves the focal length."""
    cycle, _ = started(tmp_path)
    refined_camera = a_calibration().camera()

    def P(**changes):
        active, _ = cycle.for_refinement(refined_camera, Settings.from_values(values(**changes)))
        return active.calibration.P

    tight, wide, scaled = P(balance=0.0), P(balance=1.0), P(balance=0.0, fov_scale=2.0)
    assert wide[0, 0] < 0.95 * tight[0, 0]
    assert scaled[0, 0] == pytest.approx(tight[0, 0] / 2, rel=1e-9)
    assert scaled[1, 1] == pytest.approx(tight[1, 1] / 2, rel=1e-9)
