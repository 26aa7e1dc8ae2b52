"""sensor_msgs/CameraInfo <-> CameraCalibration (the node's only message conversions), as a
message or as its serialized bytes (the per-frame path, core/ros_formats/cdr_image.py)."""
from __future__ import annotations

import numpy as np
from sensor_msgs.msg import CameraInfo

from ..core.ros_formats.calibration_file import CameraCalibration, RegionOfInterest
from ..core.ros_formats.cdr_image import serialize_camera_info


def camera_info_fields(calibration: CameraCalibration) -> dict:
    """The CameraInfo fields of ``calibration`` (all but the header), the one conversion both the
    message and the serialized CameraInfo are filled from."""
    roi = calibration.roi
    return dict(
        width=calibration.width, height=calibration.height, distortion_model=calibration.distortion_model,
        d=calibration.D.tolist(), k=calibration.K.ravel().tolist(), r=calibration.R.ravel().tolist(),
        p=calibration.P.ravel().tolist(),
        # as given (a file, set_camera_info); 0 and an all-zero roi mean the full image, unbinned
        binning_x=int(calibration.binning_x), binning_y=int(calibration.binning_y),
        roi=(int(roi.x_offset), int(roi.y_offset), int(roi.height), int(roi.width), bool(roi.do_rectify)))


def fill_camera_info(msg: CameraInfo, calibration: CameraCalibration):
    fields = camera_info_fields(calibration)
    msg.width, msg.height = fields['width'], fields['height']
    msg.distortion_model = fields['distortion_model']
    msg.d, msg.k, msg.r, msg.p = fields['d'], fields['k'], fields['r'], fields['p']
    msg.binning_x, msg.binning_y = fields['binning_x'], fields['binning_y']
    msg.roi.x_offset, msg.roi.y_offset, msg.roi.height, msg.roi.width, msg.roi.do_rectify = fields['roi']


def serialized_camera_info(calibration: CameraCalibration, frame_id: str, sec: int = 0,
                           nanosec: int = 0) -> bytearray:
    """The CameraInfo of ``calibration`` serialized (little-endian CDR), with that header: the
    bytes ``fill_camera_info`` + ``serialize_message`` give (padding aside); a template whose
    stamp ``cdr_image.patch_stamp`` changes frame after frame."""
    fields = camera_info_fields(calibration)
    return serialize_camera_info(sec, nanosec, frame_id, fields['height'], fields['width'],
                                 fields['distortion_model'], fields['d'], fields['k'], fields['r'],
                                 fields['p'], fields['binning_x'], fields['binning_y'], fields['roi'])


def calibration_from_camera_info(msg: CameraInfo, camera_name: str) -> CameraCalibration:
    roi = RegionOfInterest(int(msg.roi.x_offset), int(msg.roi.y_offset), int(msg.roi.height),
                           int(msg.roi.width), bool(msg.roi.do_rectify))
    return CameraCalibration(int(msg.width), int(msg.height), np.array(msg.k), msg.distortion_model,
                             np.array(msg.d), np.array(msg.r), np.array(msg.p), camera_name,
                             int(msg.binning_x), int(msg.binning_y), roi)
