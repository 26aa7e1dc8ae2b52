"""sensor_msgs/CameraInfo <-> CameraCalibration (the node's only message conversions)."""
from __future__ import annotations

import numpy as np
from sensor_msgs.msg import CameraInfo

from ..core.ros_data.calibration_file import CameraCalibration, RegionOfInterest

def fill_camera_info(msg: CameraInfo, calibration: CameraCalibration):
    msg.width, msg.height = calibration.width, calibration.height
    msg.distortion_model = calibration.distortion_model
    msg.d = calibration.D.tolist()
    msg.k = calibration.K.ravel().tolist()
    msg.r = calibration.R.ravel().tolist()
    msg.p = calibration.P.ravel().tolist()
    # as given (a file, set_camera_info); 0 and an all-zero roi mean the full image, unbinned
    msg.binning_x, msg.binning_y = int(calibration.binning_x), int(calibration.binning_y)
    roi = calibration.roi
    msg.roi.x_offset, msg.roi.y_offset = int(roi.x_offset), int(roi.y_offset)
    msg.roi.width, msg.roi.height = int(roi.width), int(roi.height)
    msg.roi.do_rectify = bool(roi.do_rectify)


def calibration_from_camera_info(msg: CameraInfo, camera_name: str) -> CameraCalibration:
    roi = RegionOfInterest(int(msg.roi.x_offset), int(msg.roi.y_offset), int(msg.roi.height),
                           int(msg.roi.width), bool(msg.roi.do_rectify))
    return CameraCalibration(int(msg.width), int(msg.height), np.array(msg.k), msg.distortion_model,
                             np.array(msg.d), np.array(msg.r), np.array(msg.p), camera_name,
                             int(msg.binning_x), int(msg.binning_y), roi)
