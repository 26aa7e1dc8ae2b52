"""One road from a spec to its zero-shot camera: a run solves the spec once and passes the result on.

``core.estimation.zero_shot.zero_shot_start`` makes the spec's zero-shot result (the solution, its
Kannala-Brandt camera at the images' size, its error bar) once per run; ``refine_from_images`` gives
it to every round's fit, ``fit_board`` uses it, and a caller that solved the spec already (the CLI,
for its warnings) passes its solution on, so that nothing solves the spec again."""
from unittest import mock

import numpy as np
import pytest

import scenes
from zeroshot_calib_ros.core.estimation import zero_shot as zero_shot_module
from zeroshot_calib_ros.core.estimation.refine import refine_camera, refine_from_images
from zeroshot_calib_ros.core.estimation.zero_shot import (ZeroShotStart, rounded_fovs, zero_shot_camera,
                                                          zero_shot_start)
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis
from zeroshot_calib_ros.core.zeroshot import solver as solver_module
from zeroshot_calib_ros.core.zeroshot.solver import solve_zero_shot
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec, SpecError

CAMERA = KannalaBrandtCamera(430.0, 430.0, 654.0, 391.0, 1280, 800, [0.035, -0.012, 0.003, -0.0004]).scaled(640, 400)
SPEC = CameraSpec(640, 400, **{k: round(v + 0.7, 1) for k, v in fields_of_view_through_axis(CAMERA).items()})
"""A spec 0.7 degrees wide of the lens: the lines refine it in both rounds."""


@pytest.fixture(scope='module')
def room():
    return scenes.render(CAMERA, 'room', seed=1)[0]


def counting():
    """Patches that count every solve of a spec (whatever the projection or the caller) and every
    zero-shot error bar of a start."""
    return (mock.patch.object(solver_module, '_solve_zero_shot', wraps=solver_module._solve_zero_shot),
            mock.patch.object(zero_shot_module, 'zero_shot_uncertainty', wraps=zero_shot_module.zero_shot_uncertainty))


def test_one_refine_run_solves_the_spec_once(room):
    """Two rounds of detection and fit over a rendered room: the spec is solved once and its error
    bar computed once; given the solution (as the CLI does), the spec is not solved at all."""
    fits = []
    solves_patch, bars_patch = counting()
    with solves_patch as solves, bars_patch as bars:
        result = refine_from_images(SPEC, [room], rounds=2, progress=lambda p: p.stage == 'fit' and fits.append(p))
    assert len(fits) == 2 and result.accepted, result.reason
    assert solved_specs(solves) == [SPEC, rounded_fovs(SPEC)]  # the second: the camera the detector looks with
    assert bars.call_count == 1
    assert np.array_equal(result.zero_shot_camera.K, zero_shot_camera(SPEC, 640, 400).K)
    solution = solve_zero_shot(SPEC, 'auto')
    solves_patch, bars_patch = counting()
    with solves_patch as solves, bars_patch as bars:
        refine_from_images(SPEC, [np.full_like(room, 128)], solution=solution)
    assert solved_specs(solves) == [rounded_fovs(SPEC)] and bars.call_count == 1


def solved_specs(solves):
    return [call.args[0] if call.args else call.kwargs['spec'] for call in solves.call_args_list]


def test_the_detector_looks_with_a_camera_that_ignores_the_last_digits_of_the_fovs():
    """The views the detector makes follow the spec's FOVs rounded to whole degrees: specs 0.01
    degree apart look with one camera (so find the same lines), which is within a few pixels of
    each one's own zero-shot camera; a spec of whole degrees looks with its own camera."""
    spec = CameraSpec(752, 480, hfov=121.4, vfov=76.3, dfov=146.8)
    looks = []
    for delta in (-0.01, 0.0, 0.01):
        shifted = CameraSpec(752, 480, **{k: v + delta for k, v in spec.given().items()})
        start = zero_shot_start(shifted, 752, 480)
        look = start.detection_camera
        assert look is start.detection_camera  # made once per start
        looks.append(look)
        pixels = np.stack(np.meshgrid(np.linspace(0, 752, 17), np.linspace(0, 480, 11)), -1).reshape(-1, 2)
        moved = np.linalg.norm(look.project(start.camera.unproject(pixels)) - pixels, axis=1)
        assert 0.05 < np.max(moved) < 4.0
    for look in looks[1:]:
        assert (look.fx, look.fy, look.cx, look.cy) == (looks[0].fx, looks[0].fy, looks[0].cx, looks[0].cy)
        np.testing.assert_array_equal(look.D, looks[0].D)
    whole = zero_shot_start(CameraSpec(752, 480, hfov=121, vfov=76), 752, 480)
    assert whole.detection_camera is whole.camera
    half = zero_shot_start(spec, 376, 240)  # images binned 2x2: the detector looks at their size
    assert (half.detection_camera.width, half.detection_camera.height) == (376, 240)
    assert half.detection_camera.fx == pytest.approx(looks[1].fx / 2, rel=1e-9)


def test_rounded_fovs_rounds_every_fov_and_keeps_the_rest():
    spec = CameraSpec(1032, 778, circle_diameter=770.0, circle_fov=187.6)
    assert rounded_fovs(spec) == CameraSpec(1032, 778, circle_diameter=770.0, circle_fov=188.0)
    assert rounded_fovs(CameraSpec(640, 480, hfov=93.49, vfov=59.51, dfov=106.4)) == \
        CameraSpec(640, 480, hfov=93.0, vfov=60.0, dfov=106.0)


@pytest.mark.parametrize('width, height', [(640, 480), (320, 240)])
def test_a_spec_whose_rounded_fovs_are_no_spec_refines_looking_with_its_own_camera(width, height):
    """A spec valid as given whose FOVs rounded to whole degrees are not (a fisheye cropped at the
    sides: its dfov 0.2 degree over its hfov, both round to 190, and the diagonal must be the
    widest) is refined, not refused: the detector looks with the spec's own zero-shot camera, at
    the images' size (full or binned 2x2)."""
    spec = CameraSpec(640, 480, hfov=190.2, vfov=150.0, dfov=190.4)
    with pytest.raises(SpecError):
        rounded_fovs(spec)
    start = zero_shot_start(spec, width, height)
    assert start.detection_camera is start.camera
    assert (start.detection_camera.width, start.detection_camera.height) == (width, height)
    result = refine_from_images(spec, [np.full((height, width), 128, np.uint8)])
    assert not result.accepted and result.zero_shot_camera.width == width


def test_a_start_is_used_as_it_is_and_checked():
    """A ``ZeroShotStart`` given as the solution is used without computing anything of the spec
    again; one of another size or tolerance is refused, not silently used."""
    start = zero_shot_start(SPEC, 320, 200, 1.0)
    assert isinstance(start, ZeroShotStart)
    assert start.solution.spec == SPEC and (start.camera.width, start.camera.height) == (320, 200)
    solves_patch, bars_patch = counting()
    with solves_patch as solves, bars_patch as bars:
        result = refine_camera(SPEC, [], 320, 200, 1.0, solution=start)
        assert zero_shot_start(SPEC, 320, 200, 1.0, start) is start
    assert solves.call_count == 0 and bars.call_count == 0
    assert result.camera is start.camera and result.zero_shot_uncertainty is start.uncertainty
    assert result.uncertainty_px == start.uncertainty.rms_px * 0.5
    with pytest.raises(ValueError, match='FOV tolerance'):
        refine_camera(SPEC, [], 320, 200, 2.0, solution=start)
    with pytest.raises(ValueError, match='640x400'):
        refine_camera(SPEC, [], 640, 400, 1.0, solution=start)
