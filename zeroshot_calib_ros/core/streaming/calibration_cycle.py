"""The node's calibration life cycle without ROS: which calibration is in force, which was
accepted last, and the candidates that may replace them (from the spec, a file, a parameter
change, set_camera_info, a refinement), with the saves that go with them.

A candidate is built here whole or not at all (an exception names why): a failed candidate never
touches the calibration in force. ``accept`` makes one the newest (later changes build on it)
while its maps are built; ``swap_in`` puts it in force, never over a newer generation. The node
(``zeroshot_calib_ros/ros/node.py``) builds the maps, logs what this returns and publishes."""
from __future__ import annotations

import os
from typing import Callable, Optional, Tuple

import numpy as np

from ..lens.fitting import FIT_WARNING_PX
from ..ros_formats.calibration_file import CalibrationFileError, CameraCalibration, summary_text
from .image_frames import ActiveCalibration
from .node_parameters import CALIBRATION_PARAMETERS, RECTIFICATION_PARAMETERS, Settings, solve_from_settings

REFINABLE_SOURCES = ('spec', 'refined')
"""Sources of a calibration that ``refine`` refines (never a file's or set_camera_info's)."""


def summary_warnings(summary: Optional[dict]) -> list:
    """The warnings of a solved calibration: the spec's FOVs that the solved camera misses
    (core/zeroshot/consistency.py; the calibration is still adopted, and published, as the spec
    gives it), and a published model that departs from the zero-shot lens."""
    texts = [f'spec: {warning}' for warning in (summary or {}).get('warning', ())]
    if summary and summary['fit_error_px'] > FIT_WARNING_PX:
        texts.append(
            f"the published {summary['distortion_model']} model departs from the zero-shot lens by up to "
            f"{summary['fit_error_px']:.3g} px (more than {FIT_WARNING_PX:g} px): consumers of CameraInfo "
            'see that error' + (' (use distortion_model: equidistant for a lens this wide)'
                                if summary['distortion_model'] != 'equidistant' else ''))
    return texts


class CalibrationCycle:
    """``active``: the calibration in force; ``newest``: the last one accepted (in force, or its
    maps being built); ``generation``: the highest generation given out; ``values_in_force``: the
    parameter values of ``active``; ``save_when_in_force``: (calibration, generation) of a
    set_camera_info calibration saved to ``url_path`` once in force; ``refined``: (camera,
    uncertainty px) of the last refinement adopted (a restarted refiner starts from it and must
    beat it)."""

    def __init__(self, url_path: str, map_budget_bytes: int):
        self.url_path = url_path
        self.map_budget_bytes = map_budget_bytes
        self.active: Optional[ActiveCalibration] = None
        self.newest: Optional[ActiveCalibration] = None
        self.generation = 0
        self.values_in_force: Optional[dict] = None
        self.save_when_in_force: Optional[Tuple[CameraCalibration, int]] = None
        self.refined = None
        self.file_state = ''

    # --- start-up: the file at camera_info_url, else the spec ---------------------------------
    def start(self, settings: Settings, log: Callable[[str, str], None]) -> ActiveCalibration:
        """The calibration in force at start-up, said through ``log(level, text)``."""
        self.active = self.newest = self._initial_calibration(settings, log)
        self.generation = self.active.generation
        return self.active

    def _initial_calibration(self, settings: Settings, log) -> ActiveCalibration:
        path = self.url_path
        self.file_state = f'none at {path} yet: set_camera_info will save there'
        if os.path.isfile(path):
            try:
                calibration = CameraCalibration.load(path)
                active = ActiveCalibration(calibration, calibration.camera(), f'file {path}', 0,
                                           settings.rectify, settings.interpolation, build_maps=False,
                                           map_budget_bytes=self.map_budget_bytes)
            except (CalibrationFileError, ValueError) as exc:
                log('error', f'ignoring camera_info_url {path}: {exc}; solving from the spec '
                    'instead (set_camera_info will overwrite the file)')
                self.file_state = f'{path} unreadable ({exc}): set_camera_info will overwrite it'
            else:
                for warning in getattr(calibration, 'load_warnings', ()):
                    log('warning', f'{path}: {warning}')
                for warning in file_differs_warnings(calibration, settings, path):
                    log('warning', warning)
                log('info', f'calibration loaded from {path} (takes precedence over the spec):\n'
                    f'  {calibration.width} x {calibration.height} px, camera_name {calibration.camera_name}\n'
                    f'  K {calibration.K.tolist()}\n  {calibration.distortion_model} D {calibration.D.tolist()}')
                self.file_state = f'loaded {path}; set_camera_info saves there'
                return active
        active, summary = solve_from_settings(settings, 0, build_maps=False, map_budget_bytes=self.map_budget_bytes)
        log('info', 'zero-shot calibration from the spec sheet:\n' + summary_text(summary))
        for warning in summary_warnings(summary):
            log('warning', warning)
        return active

    # --- candidates: built whole, or an exception and nothing changes ---------------------------
    def for_parameters(self, names: set, values: dict) -> Tuple[Settings, ActiveCalibration, Optional[dict]]:
        """(settings, calibration, solver summary or None) of changed calibration or rectification
        parameters: re-solved from the spec, or (a file's or set_camera_info's calibration stays)
        the newest calibration with new P or maps. Raises SpecError, CalibrationFileError,
        NoConvergence, ValueError (or anything else) for values that give no calibration."""
        basis = self.newest
        generation = self.generation + 1
        settings = Settings.from_values(values)
        if names & set(CALIBRATION_PARAMETERS) or basis.source == 'spec':
            active, summary = solve_from_settings(settings, generation, build_maps=False,
                                                  map_budget_bytes=self.map_budget_bytes)
            return settings, active, summary
        new_p = bool(names & {'balance', 'fov_scale'})
        # with_rectification numbers its result one after the calibration it starts from
        active = ActiveCalibration(basis.calibration, basis.camera, basis.source,
                                   generation - 1 if new_p else generation,
                                   settings.rectify, settings.interpolation, build_maps=False,
                                   map_budget_bytes=self.map_budget_bytes)
        if new_p:
            active = active.with_rectification(settings.balance, settings.fov_scale, build_maps=False)
        return settings, active, None

    def for_camera_info(self, calibration: CameraCalibration, settings: Settings) -> ActiveCalibration:
        """A set_camera_info calibration (raises CalibrationFileError or ValueError if implausible,
        MapBudgetExceeded if its maps would not fit)."""
        return ActiveCalibration(calibration, calibration.camera(), 'set_camera_info', self.generation + 1,
                                 settings.rectify, settings.interpolation, build_maps=False,
                                 map_budget_bytes=self.map_budget_bytes)

    def for_refinement(self, refined_camera, settings: Settings) -> Tuple[ActiveCalibration, float]:
        """(calibration, fit error px) of a refined camera in the configured distortion model
        (plumb_bob fitted to the refined lens, with its error), at the newest calibration's size.
        Raises CalibrationFileError, MapBudgetExceeded or ValueError."""
        from .online_refinement import refined_calibration_and_fit

        basis = self.newest
        calibration, fit_error_px = refined_calibration_and_fit(
            refined_camera, basis.calibration.width, basis.calibration.height, settings.balance,
            settings.fov_scale, settings.camera_name, settings.distortion_model)
        camera = calibration.camera()
        active = ActiveCalibration(calibration, camera, 'refined', self.generation + 1, settings.rectify,
                                   settings.interpolation, build_maps=False, map_budget_bytes=self.map_budget_bytes)
        return active, fit_error_px

    # --- accepted, in force, failed -----------------------------------------------------------
    def accept(self, active: ActiveCalibration):
        """``active`` is the newest (later changes build on it) even before it is in force."""
        self.generation = max(self.generation, active.generation)
        self.newest = active

    def swap_in(self, active: ActiveCalibration, values: Optional[dict]) -> bool:
        """Put ``active`` in force (with its parameter values) unless a newer one already is."""
        if active.generation <= self.active.generation:
            return False  # superseded while it was built
        self.active = active
        if values is not None:
            self.values_in_force = values
        return True

    def build_failed(self, active: ActiveCalibration) -> bool:
        """The maps of an accepted ``active`` could not be built: the calibration in force stays.
        True if it was the newest (then the parameters go back to ``values_in_force``)."""
        if active is not self.newest:
            return False
        self.newest = self.active
        return True

    def values_to_restore(self, values: dict) -> dict:
        """The calibration and rectification parameters whose ``values`` differ from those in force."""
        return {name: value for name, value in self.values_in_force.items()
                if name in CALIBRATION_PARAMETERS + RECTIFICATION_PARAMETERS and values[name] != value}

    # --- saves --------------------------------------------------------------------------------
    def save_in_force(self, active: ActiveCalibration) -> Optional[Tuple[str, str]]:
        """(level, log text) when ``active``, now in force, settles a pending set_camera_info save:
        saved if it is that calibration (or a change of its P or maps), dropped otherwise."""
        pending = self.save_when_in_force
        if pending is None or active.generation < pending[1]:
            return None
        if active.source == 'set_camera_info':  # it, or a change of its P / maps
            self.save_when_in_force = None
            return 'info', f'calibration from set_camera_info in force{self.save_camera_info(pending[0])[1]}'
        return 'warning', self.drop_pending_save(active.generation, f'{active.source} is in force instead')

    def drop_pending_save(self, generation: int, why: str) -> Optional[str]:
        """The warning when a pending set_camera_info save of ``generation`` or older is dropped."""
        pending = self.save_when_in_force
        if pending is not None and generation >= pending[1]:
            self.save_when_in_force = None
            return (f'calibration from set_camera_info (generation {pending[1]}) not adopted '
                    f'and not saved: {why}')
        return None

    def save(self, calibration: CameraCalibration) -> Tuple[bool, str]:
        """(saved, 'saved to ...' / 'NOT saved to ...: why') of saving a calibration to camera_info_url."""
        try:
            calibration.save(self.url_path)
            return True, f'saved to {self.url_path}'
        except (OSError, CalibrationFileError) as exc:
            return False, f'NOT saved to {self.url_path}: {getattr(exc, "strerror", None) or exc}'

    def save_camera_info(self, calibration: CameraCalibration) -> Tuple[bool, str]:
        """(saved, text for the reply / log) of saving a set_camera_info calibration in force."""
        saved, text = self.save(calibration)
        return saved, f' and {text}' if saved else f' but {text}'


def file_differs_warnings(calibration: CameraCalibration, settings: Settings, path: str) -> list:
    """Warnings for a file at camera_info_url of another camera or image size than the spec's."""
    spec = settings.spec
    texts = []
    if calibration.camera_name != settings.camera_name:
        texts.append(f'{path} is the calibration of camera_name {calibration.camera_name!r}, '
                     f'this node is camera_name {settings.camera_name!r}; using the file')
    if (calibration.width, calibration.height) != (spec.width, spec.height):
        texts.append(f'{path} is for {calibration.width}x{calibration.height} images, the spec '
                     f'says {spec.width}x{spec.height}; using the file (frames of the spec '
                     'size get scaled intrinsics if the aspect ratio agrees)')
    return texts


def refinement_texts(result, basis: ActiveCalibration, active: ActiveCalibration, fit_error_px: float) -> list:
    """(level, text) log lines of a refinement being adopted as ``active`` over ``basis``."""
    from .online_refinement import px_text as px

    s = result.status
    calibration = active.calibration

    def text(c):
        return f'K {np.round(c.K, 3).tolist()}\n    {c.distortion_model} D {np.round(c.D.ravel(), 6).tolist()}'
    lines = [('info',
              f'refinement accepted: {s.lines} lines from {s.frames_used} frame(s), coverage {100 * s.coverage:.0f} %, '
              f'line residual {px(s.residual_px_before)} -> {px(s.residual_px)} px, uncertainty '
              f'{px(s.zero_shot_uncertainty_px)} -> {px(s.uncertainty_px)} px, principal point moved '
              f'{px(s.principal_point_shift_px)} px; adopting it as generation {active.generation}\n'
              f'  before (generation {basis.generation}, {basis.source}): {text(basis.calibration)}\n'
              f'  after  (refined): {text(calibration)}'
              + (f'\n  {calibration.distortion_model} fitted to the refined lens: error up to {fit_error_px:.3g} px'
                 if calibration.distortion_model != 'equidistant' else ''))]
    if fit_error_px > FIT_WARNING_PX:
        lines.append(('warning',
                      f'the published {calibration.distortion_model} model departs from the refined lens by up to '
                      f'{fit_error_px:.3g} px (more than {FIT_WARNING_PX:g} px): consumers of CameraInfo see that '
                      'error (use distortion_model: equidistant for a lens this wide)'))
    return lines
