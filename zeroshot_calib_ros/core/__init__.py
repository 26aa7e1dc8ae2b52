"""ROS-free core of zeroshot_calib_ros: numpy, scipy and OpenCV only, never rclpy.

Typical use::

    from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
    solution = solve_zero_shot(CameraSpec(1920, 1080, hfov=118, vfov=69))
    solution.f, solution.omega, solution.K
"""
from .zeroshot.spec import CameraSpec, SpecError
from .lens.projections import PROJECTIONS, FisheyeProjection, get_projection
from .lens.models import (CameraModel, KannalaBrandtCamera, PinholeCamera, PlumbBobCamera,
                            ZeroShotCamera, camera_from_calibration)
from .zeroshot.solver import ZeroShotSolution, solve_zero_shot, NoConvergence
from .ros_data.camera_info_model import CameraInfoModel
from .ros_data.calibration_file import CameraCalibration
from .ros_data.rectify import Rectifier

__all__ = [
    'CameraSpec', 'SpecError', 'PROJECTIONS', 'FisheyeProjection', 'get_projection',
    'CameraModel', 'KannalaBrandtCamera', 'PinholeCamera', 'PlumbBobCamera', 'ZeroShotCamera',
    'camera_from_calibration', 'ZeroShotSolution', 'solve_zero_shot', 'NoConvergence', 'CameraInfoModel',
    'CameraCalibration', 'Rectifier',
]
