"""The node's frame path without DDS (core/streaming/frame_path.py): which frames get a
CameraInfo and which are skipped with which reason, the serialized CameraInfo with each frame's
stamp, the rectified image as serialized bytes (or as a message's pixels), and which maps a frame
may ask for."""
import numpy as np
import pytest

from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration
from zeroshot_calib_ros.core.ros_formats.cdr_image import image_prefix, parse_image, serialize_camera_info
from zeroshot_calib_ros.core.streaming.frame_path import FramePath
from zeroshot_calib_ros.core.streaming.image_frames import ActiveCalibration, FrameSkipped, map_bytes


def serialize_info(calibration, frame_id, sec=0, nanosec=0):
    """What the node passes (ros/messages.py's serialized_camera_info), without sensor_msgs."""
    roi = calibration.roi
    return serialize_camera_info(sec, nanosec, frame_id, calibration.height, calibration.width,
                                 calibration.distortion_model, calibration.D.tolist(),
                                 calibration.K.ravel().tolist(), calibration.R.ravel().tolist(),
                                 calibration.P.ravel().tolist(), int(calibration.binning_x),
                                 int(calibration.binning_y),
                                 (int(roi.x_offset), int(roi.y_offset), int(roi.height), int(roi.width),
                                  bool(roi.do_rectify)))


@pytest.fixture(scope='module')
def active():
    solution = solve_zero_shot(CameraSpec(640, 360, 118, 69))
    calibration, _ = CameraCalibration.from_solution(solution)
    return ActiveCalibration(calibration, solution.camera, 'spec', rectify=True, build_maps=False)


def mono_frame(width, height, stamp=(7, 8), frame_id='cam'):
    pixels = (np.arange(width * height) % 251).astype(np.uint8).tobytes()
    return bytes(image_prefix(stamp[0], stamp[1], frame_id, height, width, 'mono8', 0, width, len(pixels))) + pixels


def test_a_frame_of_the_calibrated_size_gets_the_calibration_in_force(active):
    frames = FramePath(serialize_info)
    assert frames.calibration(active, 640, 360, 640, 'mono8', 640 * 360) is active.calibration
    assert frames.last_size == (640, 360) and frames.uncalibrated is None


def test_a_frame_of_the_same_aspect_gets_scaled_intrinsics(active):
    calibration = FramePath(serialize_info).calibration(active, 320, 180, 320, 'mono8', 320 * 180)
    assert (calibration.width, calibration.height) == (320, 180)
    assert calibration.K[0, 0] == pytest.approx(active.calibration.K[0, 0] / 2)


def test_a_frame_of_another_aspect_is_skipped_with_its_reason_until_one_fits(active):
    frames = FramePath(serialize_info)
    frames.calibration(active, 640, 360, 640, 'mono8', 640 * 360)
    with pytest.raises(FrameSkipped) as caught:
        frames.calibration(active, 640, 480, 640, 'mono8', 640 * 480)
    assert caught.value.reason == 'aspect' and 'aspect ratio' in str(caught.value)
    # /diagnostics says so (an ERROR) while such frames come; the last size that got a CameraInfo stays
    assert frames.uncalibrated == ((640, 480), str(caught.value))
    assert frames.last_size == (640, 360)
    frames.calibration(active, 640, 360, 640, 'mono8', 640 * 360)
    assert frames.uncalibrated is None


def test_a_frame_whose_data_does_not_match_its_fields_is_skipped_as_malformed(active):
    frames = FramePath(serialize_info)
    with pytest.raises(FrameSkipped) as caught:
        frames.calibration(active, 640, 360, 640, 'mono8', 640 * 359)
    assert caught.value.reason == 'malformed'
    assert frames.uncalibrated is None and frames.last_size is None


def test_an_unexpected_error_skips_the_frame_as_error(active):
    class Broken:
        calibration = active.calibration

        def calibration_for(self, width, height):
            raise RuntimeError('boom')
    with pytest.raises(FrameSkipped) as caught:
        FramePath(serialize_info).calibration(Broken(), 640, 360, 640, 'mono8', 640 * 360)
    assert caught.value.reason == 'error' and str(caught.value) == 'cannot calibrate frame: boom'


def test_the_serialized_camera_info_is_built_once_and_carries_each_frames_stamp(active):
    built = []

    def counting(calibration, frame_id):
        built.append(frame_id)
        return serialize_info(calibration, frame_id)
    frames = FramePath(counting)
    first = parse_image(mono_frame(640, 360, stamp=(1, 2)))
    info = bytes(frames.serialized_info(active.calibration, first))
    second = parse_image(mono_frame(640, 360, stamp=(3, 4)))
    info2 = bytes(frames.serialized_info(active.calibration, second))
    assert built == ['cam']
    assert info == bytes(serialize_info(active.calibration, 'cam', 1, 2))
    assert info2 == bytes(serialize_info(active.calibration, 'cam', 3, 4))
    frames.serialized_info(active.calibration, parse_image(mono_frame(640, 360, frame_id='other')))
    assert built == ['cam', 'other']


def test_the_rectified_frame_is_a_serialized_image_with_the_frames_header(active):
    rectified = ActiveCalibration(active.calibration, active.camera, 'spec', rectify=True, build_maps=True)
    rectifier = rectified.rectifier_for(640, 360)
    raw = mono_frame(640, 360, stamp=(5, 6))
    out = FramePath(serialize_info).rectified_serialized(raw, parse_image(raw), rectifier)
    header = parse_image(bytes(out))
    assert (header.sec, header.nanosec, header.frame_id, header.encoding) == (5, 6, 'cam', 'mono8')
    assert (header.width, header.height, header.step) == (640, 360, 640)
    pixels = np.frombuffer(bytes(out), np.uint8, count=640 * 360, offset=len(out) - 640 * 360).reshape(360, 640)
    expected = rectifier.rectify(np.frombuffer(raw, np.uint8, count=640 * 360,
                                               offset=len(raw) - 640 * 360).reshape(360, 640))
    assert np.array_equal(pixels, expected)


def test_the_message_paths_rectified_pixels_are_one_buffer_reused_frame_after_frame(active):
    rectified = ActiveCalibration(active.calibration, active.camera, 'spec', rectify=True, build_maps=True)
    rectifier = rectified.rectifier_for(640, 360)
    frames = FramePath(serialize_info)
    bgr = (np.arange(640 * 360 * 3) % 253).astype(np.uint8)
    data, height, width, step = frames.rectified_pixels(bgr.tobytes(), 640, 360, 640 * 3, 'bgr8', False, rectifier)
    assert (height, width, step) == (360, 640, 640 * 3) and len(data) == 640 * 360 * 3
    assert np.array_equal(np.frombuffer(data, np.uint8).reshape(360, 640, 3), rectifier.rectify(bgr.reshape(360, 640, 3)))
    again = frames.rectified_pixels(bgr.tobytes(), 640, 360, 640 * 3, 'bgr8', False, rectifier)[0]
    assert again is data  # rclpy serialises it during publish(): reused, not allocated per frame
    mono16 = frames.rectified_pixels(bytes(640 * 360 * 2), 640, 360, 640 * 2, 'mono16', False, rectifier)
    assert mono16[0] is not data and mono16[1:] == (360, 640, 640 * 2)


def test_maps_of_another_size_beyond_the_budget_are_not_requested(active):
    frames = FramePath(serialize_info)
    with pytest.raises(FrameSkipped) as caught:
        frames.check_maps_request(active, active.calibration_for(1280, 720), 1280, 720,
                                  map_bytes(640, 360) + map_bytes(1280, 720) - 1)
    assert caught.value.reason == 'maps_budget'
    frames.check_maps_request(active, active.calibration_for(1280, 720), 1280, 720,
                              map_bytes(640, 360) + map_bytes(1280, 720))
    assert frames.maps_pending(1280, 720).reason == 'maps_pending'


def test_maps_that_failed_are_not_requested_again_until_a_subscriber_comes(active):
    frames = FramePath(serialize_info)
    frames.maps_failed(active, (320, 180), 'out of memory')
    with pytest.raises(FrameSkipped) as caught:
        frames.check_maps_request(active, active.calibration_for(320, 180), 320, 180, 2**40)
    assert caught.value.reason == 'maps_failed' and 'out of memory' in str(caught.value)
    frames.calibration(active, 320, 180, 320, 'mono8', 320 * 180)
    # a new subscriber: the configured size and the last frame's, and the failed ones tried again
    assert frames.ahead_sizes(active, 2**40) == [(640, 360), (320, 180)]
    frames.check_maps_request(active, active.calibration_for(320, 180), 320, 180, 2**40)


def test_the_last_frame_size_is_built_ahead_only_within_the_budget(active):
    frames = FramePath(serialize_info)
    frames.calibration(active, 1280, 720, 1280, 'mono8', 1280 * 720)
    assert frames.ahead_sizes(active, map_bytes(640, 360) + map_bytes(1280, 720) - 1) == [(640, 360)]
