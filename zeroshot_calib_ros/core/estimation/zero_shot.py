"""The spec's zero-shot result at one image size, made once per run and passed on.

Every fit of this layer starts from the zero-shot camera and measures itself against it: the line
refinement (``refine.refine_camera``, over every round of ``refine.refine_from_images``) and the
board fit (``board_fit.fit_board``). ``zero_shot_start`` makes what they need of the spec in one
place: the solution (``solve_zero_shot``, 'auto'), its camera fitted to Kannala-Brandt k1..k4 at
the images' size (``zero_shot_camera``) and its error bar (``uncertainty.zero_shot_uncertainty``
at the FOV tolerance of the run); a caller that has solved the spec already (the CLI, for its
warnings) passes its solution, and nothing solves the spec again. The fits take either as their
``solution`` argument: a ``ZeroShotStart`` is used as it is, a ``ZeroShotSolution`` (or nothing)
is made into one.

The detector looks with the zero-shot camera of the spec with its FOVs rounded to whole degrees
(``ZeroShotStart.detection_camera``), and the lines it finds are judged and fitted under the
exact one. The segment detector is not continuous in the views it is given: views resampled a
hundredth of a pixel differently gain or lose segments, so when the views followed the spec's
last digits, FOVs moved by 0.01 degree changed which lines were found (a real 121-degree office
photo: 116 to 123 lines instead of 127) and with them the gate's decision. The camera the views
are made with only decides where to look: each edge point is mapped back to the raw image through
the same camera the view was made with and measured there, and a camera off by a degree of FOV
is well inside what the detector is built for (a few percent in f).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property
from typing import Optional

from ..lens.fitting import fit_kannala_brandt
from ..lens.models import KannalaBrandtCamera
from ..zeroshot.solver import NoConvergence, ZeroShotSolution, solve_zero_shot
from ..zeroshot.spec import CameraSpec, SpecError
from .terms import FOV_TOLERANCE_DEG
from .uncertainty import Uncertainty, zero_shot_uncertainty


DETECTION_FOV_STEP_DEG = 1.0
"""The FOVs of the camera the detector looks with are the spec's rounded to this (module docstring)."""


def rounded_fovs(spec: CameraSpec, step_deg: float = DETECTION_FOV_STEP_DEG) -> CameraSpec:
    """``spec`` with every FOV it states (hfov, vfov, dfov, circle_fov) rounded to ``step_deg``;
    the image size and the circle's diameter as they are. SpecError if that is no valid spec."""
    changes = {k: step_deg * round(v / step_deg) for k, v in spec.given().items()}
    if spec.circle_fov is not None:
        changes['circle_fov'] = step_deg * round(spec.circle_fov / step_deg)
    return dataclasses.replace(spec, **changes)


def zero_shot_camera(spec: CameraSpec, width: int, height: int, solution=None) -> KannalaBrandtCamera:
    """The zero-shot camera ('auto') fitted to Kannala-Brandt k1..k4, at width x height."""
    solution = solve_zero_shot(spec, 'auto') if solution is None else solution
    camera = fit_kannala_brandt(solution.camera).camera
    if (width, height) != (spec.width, spec.height):
        camera = camera.scaled(width, height)
    return camera


@dataclass(frozen=True)
class ZeroShotStart:
    """The zero-shot result of ``spec`` for images of ``width`` x ``height`` (``zero_shot_start``)."""

    spec: CameraSpec
    solution: ZeroShotSolution
    """``solve_zero_shot(spec, 'auto')`` (its ``warnings`` at whatever tolerance its caller asked)."""
    camera: KannalaBrandtCamera
    """The solution's camera fitted to Kannala-Brandt k1..k4, at ``width`` x ``height``: the start
    and the reference of every fit."""
    uncertainty: Uncertainty
    """The zero-shot camera's error bar at ``fov_tolerance_deg``, in the spec's pixels."""
    fov_tolerance_deg: float
    width: int
    height: int

    def check(self, spec: CameraSpec, width: int, height: int, fov_tolerance_deg: float) -> 'ZeroShotStart':
        """Itself, when it is the start of ``spec`` at that size and tolerance; else ValueError."""
        if (self.spec is not spec and self.spec != spec) or (self.width, self.height) != (width, height) \
                or self.fov_tolerance_deg != fov_tolerance_deg:
            raise ValueError(f'the zero-shot start given is of a {self.spec.width}x{self.spec.height} spec at '
                             f'{self.width}x{self.height} and a FOV tolerance of {self.fov_tolerance_deg:g} degrees; '
                             f'this fit is of images of {width}x{height} at {fov_tolerance_deg:g} degrees')
        return self

    @cached_property
    def detection_camera(self) -> KannalaBrandtCamera:
        """The camera the line detector looks with (module docstring): the zero-shot camera of the
        spec with its FOVs rounded to ``DETECTION_FOV_STEP_DEG``, at this size; ``camera`` itself
        when the spec's FOVs are whole already or the rounded ones are no spec that solves."""
        try:
            rounded = rounded_fovs(self.spec)
            if rounded == self.spec:
                return self.camera
            return zero_shot_camera(rounded, self.width, self.height)
        except (SpecError, NoConvergence, ValueError):
            return self.camera


def zero_shot_start(spec: CameraSpec, width: Optional[int] = None, height: Optional[int] = None,
                    fov_tolerance_deg: float = FOV_TOLERANCE_DEG, solution=None) -> ZeroShotStart:
    """The spec's ``ZeroShotStart`` for images of ``width`` x ``height`` (default the spec's size) at
    ``fov_tolerance_deg``. ``solution``: a ``ZeroShotStart`` already made (returned as it is, after
    ``ZeroShotStart.check``), or the spec solved with 'auto' (``ZeroShotSolution``), or None (the
    spec is solved here)."""
    width = spec.width if width is None else int(width)
    height = spec.height if height is None else int(height)
    if isinstance(solution, ZeroShotStart):
        return solution.check(spec, width, height, fov_tolerance_deg)
    solution = solve_zero_shot(spec, 'auto') if solution is None else solution
    camera = zero_shot_camera(spec, width, height, solution)
    uncertainty = zero_shot_uncertainty(spec, fov_tolerance_deg, solution)
    return ZeroShotStart(spec, solution, camera, uncertainty, fov_tolerance_deg, width, height)
