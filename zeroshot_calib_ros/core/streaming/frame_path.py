"""The node's frame path without ROS: a frame in -> its calibration (or why it is skipped), its
serialized CameraInfo, its rectified image as serialized bytes (or as the pixels of a message);
which maps a frame may ask for.

The node (``zeroshot_calib_ros/ros/node.py``) takes the frame, counts and logs a ``FrameSkipped``
(its ``reason`` is the ``frames_skipped_<reason>`` counter of /diagnostics) and publishes the bytes.
"""
from __future__ import annotations

import array
from typing import Callable, Dict, Optional, Tuple

import numpy as np

from ..ros_formats.calibration_file import CameraCalibration
from ..ros_formats.cdr_image import SerializedImage, patch_stamp, pixel_bytes
from .image_frames import (ActiveCalibration, FrameSkipped, MapBudgetExceeded, binned_roi_size,
                           binning_or_roi_reason, check_frame, check_map_budget, image_array, map_bytes)

INFO_TEMPLATES_CACHED = 16


class FramePath:
    """Per-frame state of a stream: the last frame size that got a CameraInfo (``last_size``), the
    frames no calibration describes (``uncalibrated``: (size, why), an ERROR in /diagnostics),
    the sizes whose maps failed to build (``failed_maps``), the serialized CameraInfo templates
    and the reused buffer of the serialized image_rect.

    ``serialize_info(calibration, frame_id)`` makes a serialized CameraInfo template
    (``zeroshot_calib_ros.ros.messages.serialized_camera_info`` in the node)."""

    def __init__(self, serialize_info: Callable[[CameraCalibration, str], bytearray]):
        self._serialize_info = serialize_info
        self.uncalibrated: Optional[Tuple[Tuple[int, int], str]] = None
        self.last_size: Optional[Tuple[int, int]] = None
        # (id(active), width, height) -> (active, why) of maps that failed to build
        self.failed_maps: Dict[tuple, tuple] = {}
        self._info_templates = {}  # (id(calibration), frame_id) -> (calibration, serialized CameraInfo)
        self._rect_serialized = SerializedImage()  # image_rect, reused frame after frame
        self._rect_pixels = None  # the message path's image_rect pixels, reused frame after frame

    def calibration(self, active: ActiveCalibration, width: int, height: int, step: int, encoding: str,
                    nbytes: int) -> CameraCalibration:
        """The calibration of a frame under ``active``, else FrameSkipped (reason 'aspect' for a
        frame size no calibration describes: then ``uncalibrated`` says so until a frame fits)."""
        try:
            # the same checks whatever rectify is: no CameraInfo for an image the message lacks
            check_frame(width, height, step, encoding, nbytes)
            if binning_or_roi_reason(active.calibration):
                # CameraInfo as given (binning and roi tell consumers how the frame maps); no scaling
                calibration = active.calibration
                if (width, height) != binned_roi_size(calibration):
                    raise FrameSkipped('aspect', f'image {width}x{height} is not the {"x".join(map(str, binned_roi_size(calibration)))} '
                                       'that the calibration\'s binning and roi describe')
            else:
                calibration = active.calibration_for(width, height)
            self.uncalibrated = None
            self.last_size = (width, height)
            return calibration
        except FrameSkipped as exc:
            if exc.reason == 'aspect':
                self.uncalibrated = ((width, height), str(exc))
            raise
        except Exception as exc:  # never let a frame take the node down
            raise FrameSkipped('error', f'cannot calibrate frame: {exc}')

    def serialized_info(self, calibration: CameraCalibration, header) -> bytearray:
        """The serialized CameraInfo of ``calibration`` with the frame's header: a template per
        calibration and frame_id, built once; only the stamp is written frame after frame
        (publishing copies the bytes before it returns)."""
        key = (id(calibration), header.frame_id)
        cached = self._info_templates.get(key)
        if cached is None or cached[0] is not calibration:
            if len(self._info_templates) >= INFO_TEMPLATES_CACHED:
                self._info_templates.clear()
            cached = self._info_templates[key] = (calibration, self._serialize_info(calibration, header.frame_id))
        template = cached[1]
        patch_stamp(template, header.sec, header.nanosec)
        return template

    def rectified_serialized(self, raw: bytes, header, rectifier) -> bytearray:
        """The pixels viewed in ``raw`` (no copy) remapped into the buffer of the serialized
        image_rect, returned to be published as it is."""
        image = image_array(pixel_bytes(raw, header), header.width, header.height, header.step, header.encoding,
                            header.is_bigendian)
        out = self._rect_serialized.prepare(header.sec, header.nanosec, header.frame_id, header.encoding,
                                            image.shape, image.dtype)
        rectifier.rectify(image, out=out)
        return self._rect_serialized.buffer

    def rectified_pixels(self, data, width: int, height: int, step: int, encoding: str, is_bigendian: bool,
                         rectifier) -> tuple:
        """The message path's image_rect: a frame's pixels remapped into one buffer reused frame
        after frame (an ``array('B')``, which rclpy takes as an Image's data as is and serialises
        during publish(), so reuse is safe); returns (buffer, height, width, step)."""
        image = image_array(data, width, height, step, encoding, is_bigendian)
        nbytes = image.nbytes
        if self._rect_pixels is None or len(self._rect_pixels) != nbytes:
            self._rect_pixels = array.array('B', bytes(nbytes))
        out = np.frombuffer(self._rect_pixels, dtype=image.dtype).reshape(image.shape)
        rectifier.rectify(image, out=out)
        out_step = image.shape[1] * (image.shape[2] if image.ndim == 3 else 1) * image.dtype.itemsize
        return self._rect_pixels, image.shape[0], image.shape[1], out_step

    def ahead_sizes(self, active: ActiveCalibration, budget_bytes: int) -> list:
        """The sizes whose maps are built when image_rect gets a subscriber: the configured one and
        the last frame's (if its calibration and the map budget allow). Maps that failed are tried
        again."""
        self.failed_maps.clear()  # tried again for the new subscriber
        sizes = [active.size]
        if self.last_size is not None and self.last_size != active.size:
            width, height = self.last_size
            try:
                active.calibration_for(width, height)
                check_map_budget(width, height, budget_bytes - map_bytes(*active.size))
                sizes.append(self.last_size)
            except (FrameSkipped, MapBudgetExceeded):
                pass  # its frames say why when they come
        return sizes

    def maps_failed(self, active: ActiveCalibration, size: Tuple[int, int], why: str):
        """The maps of ``size`` under ``active`` could not be built: its frames are skipped as maps_failed."""
        self.failed_maps[(id(active), *size)] = (active, why)

    def check_maps_request(self, active: ActiveCalibration, calibration: CameraCalibration, width: int, height: int,
                           budget_bytes: int):
        """FrameSkipped if the maps of a frame whose maps are not built may not be requested
        (binning or roi, a build that failed, the map budget); else returns and the frame is
        skipped as ``maps_pending`` while they are built."""
        reason = binning_or_roi_reason(calibration)
        if reason:
            raise FrameSkipped('binning_roi', reason)
        failed = self.failed_maps.get((id(active), width, height))
        if failed is not None and failed[0] is active:
            raise FrameSkipped('maps_failed', f'rectification maps of {width}x{height} could not be built '
                               f'({failed[1]}); frames of that size are not rectified')
        if (width, height) != active.size:
            try:
                check_map_budget(width, height, budget_bytes - map_bytes(*active.size),
                                 what='rectification maps of this frame size (beside the configured size)')
            except MapBudgetExceeded as exc:
                raise FrameSkipped('maps_budget', str(exc)) from None

    @staticmethod
    def maps_pending(width: int, height: int) -> FrameSkipped:
        """A frame skipped (not rectified) while its maps are being built."""
        return FrameSkipped('maps_pending', f'rectification maps of {width}x{height} are being built; '
                            'frames of that size are not rectified until they are ready')
