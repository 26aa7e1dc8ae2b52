"""ROS-free core of zeroshot_calib_ros: numpy, scipy and OpenCV only, never rclpy.

Typical use::

    from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
    solution = solve_zero_shot(CameraSpec(1920, 1080, hfov=118, vfov=69))
    solution.f, solution.omega, solution.K

The names are imported when first used (module ``__getattr__``), so that importing one module
of the core (the node imports a few) does not import all of it (issue 14: start-up).
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    'CameraSpec': '.zeroshot.spec', 'SpecError': '.zeroshot.spec',
    'PROJECTIONS': '.lens.projections', 'FisheyeProjection': '.lens.projections',
    'get_projection': '.lens.projections',
    'CameraModel': '.lens.models', 'KannalaBrandtCamera': '.lens.models', 'PinholeCamera': '.lens.models',
    'PlumbBobCamera': '.lens.models', 'ZeroShotCamera': '.lens.models', 'camera_from_calibration': '.lens.models',
    'ZeroShotSolution': '.zeroshot.solver', 'solve_zero_shot': '.zeroshot.solver', 'NoConvergence': '.zeroshot.solver',
    'CameraInfoModel': '.ros_formats.camera_info_model',
    'CameraCalibration': '.ros_formats.calibration_file',
    'Rectifier': '.ros_formats.rectify',
}

__all__ = list(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
