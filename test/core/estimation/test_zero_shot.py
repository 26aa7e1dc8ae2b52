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
from zeroshot_calib_ros.core.estimation.zero_shot import ZeroShotStart, zero_shot_camera, zero_shot_start
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis
from zeroshot_calib_ros.core.zeroshot import solver as solver_module
from zeroshot_calib_ros.core.zeroshot.solver import solve_zero_shot
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec

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
    assert solves.call_count == 1
    assert bars.call_count == 1
    assert np.array_equal(result.zero_shot_camera.K, zero_shot_camera(SPEC, 640, 400).K)
    solution = solve_zero_shot(SPEC, 'auto')
    solves_patch, bars_patch = counting()
    with solves_patch as solves, bars_patch as bars:
        refine_from_images(SPEC, [np.full_like(room, 128)], solution=solution)
    assert solves.call_count == 0 and bars.call_count == 1


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
