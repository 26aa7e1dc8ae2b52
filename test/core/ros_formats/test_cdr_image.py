"""Serialized sensor_msgs/Image and CameraInfo without ROS (core/ros_formats/cdr_image.py): read and
built against the bytes ROS 2's own serializer (Fast CDR, through rclpy.serialization) wrote for
the same messages, and against the CDR rules written out here; every malformed buffer refused
with CdrError (the node counts the frame as malformed) or NotPlainCdr (the node deserializes it)."""
import struct

import numpy as np
import pytest

from zeroshot_calib_ros.core.ros_formats.cdr_image import (CdrError, NotPlainCdr, SerializedImage, image_prefix,
                                                        parse_image, patch_stamp, pixel_bytes,
                                                        serialize_camera_info, serialize_image)

# rclpy.serialization.serialize_message (Jazzy, rmw_fastrtps_cpp) of:
# Image(stamp 1700000000.123456789, frame_id 'abc', 2x3 mono8, step 3, data 0..5). Fast CDR
# leaves alignment padding as it was in memory: the byte after is_bigendian (offset 39) is 0x73.
FASTCDR_IMAGE = bytes.fromhex('0001000000f1536515cd5b0704000000616263000200000003000000060000006d6f6e6f38000073'
                              '0300000006000000000102030405')
FASTCDR_IMAGE_PADDING = [39]
# Image(stamp -2 s + 5 ns, frame_id 'cam1', 1x2 16UC1, is_bigendian 1, step 4, data 12 34 ab cd)
FASTCDR_IMAGE_16 = bytes.fromhex('00010000feffffff050000000500000063616d310000000001000000020000000600000031365543'
                                 '3100010004000000040000001234abcd')
# CameraInfo(stamp 42.000000007, frame_id 'cam', 1080x1920 equidistant, d (0.5, -0.25, 0.125, 1),
# k 1..9, r identity, p 0..11, binning 2x1, roi x 10 y 20 h 30 w 40 do_rectify)
FASTCDR_CAMERA_INFO = bytes.fromhex(
    '000100002a000000070000000400000063616d0038040000800700000c0000006571756964697374616e740004000000'
    '00000000000000000000e03f000000000000d0bf000000000000c03f000000000000f03f000000000000f03f00000000'
    '0000004000000000000008400000000000001040000000000000144000000000000018400000000000001c4000000000'
    '000020400000000000002240000000000000f03f00000000000000000000000000000000000000000000000000000000'
    '0000f03f000000000000000000000000000000000000000000000000000000000000f03f000000000000000000000000'
    '0000f03f0000000000000040000000000000084000000000000010400000000000001440000000000000184000000000'
    '00001c40000000000000204000000000000022400000000000002440000000000000264002000000010000000a000000'
    '140000001e0000002800000001')


def test_fast_cdr_images_are_read_field_by_field():
    h = parse_image(FASTCDR_IMAGE)
    assert (h.byte_order, h.sec, h.nanosec, h.frame_id) == ('<', 1700000000, 123456789, 'abc')
    assert (h.height, h.width, h.encoding, h.is_bigendian, h.step) == (2, 3, 'mono8', 0, 3)
    assert (h.data_offset, h.data_size) == (len(FASTCDR_IMAGE) - 6, 6)
    assert bytes(pixel_bytes(FASTCDR_IMAGE, h)) == bytes(range(6))
    h = parse_image(FASTCDR_IMAGE_16)
    assert (h.sec, h.nanosec, h.frame_id, h.height, h.width, h.encoding, h.is_bigendian, h.step) == \
        (-2, 5, 'cam1', 1, 2, '16UC1', 1, 4)
    assert bytes(pixel_bytes(FASTCDR_IMAGE_16, h)) == bytes.fromhex('1234abcd')


def test_pixels_are_a_view_of_the_buffer_not_a_copy():
    buf = bytearray(FASTCDR_IMAGE)
    view = np.frombuffer(pixel_bytes(buf, parse_image(buf)), np.uint8)
    buf[-1] = 200
    assert view[-1] == 200


def test_built_messages_are_the_fast_cdr_bytes_with_zero_padding():
    expected = bytearray(FASTCDR_IMAGE)
    for i in FASTCDR_IMAGE_PADDING:
        expected[i] = 0
    assert serialize_image(1700000000, 123456789, 'abc', 2, 3, 'mono8', 0, 3, bytes(range(6))) == bytes(expected)
    assert serialize_image(-2, 5, 'cam1', 1, 2, '16UC1', 1, 4, bytes.fromhex('1234abcd')) == FASTCDR_IMAGE_16
    info = serialize_camera_info(42, 7, 'cam', 1080, 1920, 'equidistant', [0.5, -0.25, 0.125, 1.0],
                                 [float(i) for i in range(1, 10)], [1.0, 0, 0, 0, 1, 0, 0, 0, 1],
                                 [float(i) for i in range(12)], 2, 1, (10, 20, 30, 40, True))
    assert bytes(info) == FASTCDR_CAMERA_INFO


def _reference_image(order, sec, nanosec, frame_id, height, width, encoding, is_bigendian, step, data):
    """A serialized Image written from the CDR rules directly (alignment from byte 4)."""
    out = bytearray(b'\x00\x01\x00\x00' if order == '<' else b'\x00\x00\x00\x00')

    def pad(n):
        out.extend(bytes(-(len(out) - 4) % n))

    def string(s):
        raw = s.encode() + b'\x00'
        pad(4)
        out.extend(struct.pack(order + 'I', len(raw)) + raw)

    out.extend(struct.pack(order + 'iI', sec, nanosec))
    string(frame_id)
    pad(4)
    out.extend(struct.pack(order + 'II', height, width))
    string(encoding)
    out.append(is_bigendian)
    pad(4)
    out.extend(struct.pack(order + 'II', step, len(data)) + data)
    return bytes(out)


@pytest.mark.parametrize('order', ['<', '>'])
@pytest.mark.parametrize('frame_id, encoding', [('', 'mono8'), ('a', 'bgr8'), ('ab', '16UC3'), ('abc', 'a'),
                                                ('optical_frame', '32FC1'), ('kamera_\u00e9', 'bayer_rggb8')])
def test_any_header_layout_is_read_and_rebuilt(order, frame_id, encoding):
    """Every padding case of the two strings, in both byte orders (a big-endian CDR writer's
    stamp, sizes and step are big-endian numbers; the pixels are bytes either way)."""
    data = np.random.default_rng(len(frame_id)).integers(0, 256, 37, np.uint8).tobytes()
    fields = (-123, 999_999_999, frame_id, 7, 5, encoding, 1, 9)
    wire = _reference_image(order, *fields, data)
    h = parse_image(wire)
    assert (h.byte_order, h.sec, h.nanosec, h.frame_id, h.height, h.width, h.encoding, h.is_bigendian, h.step) == \
        (order, *fields)
    assert bytes(pixel_bytes(wire, h)) == data and h.data_offset + h.data_size == len(wire)
    assert serialize_image(*fields, data, byte_order=order) == wire
    assert parse_image(wire + b'\x00\x00\x00').data_size == len(data)  # a payload's trailing padding: ignored


def test_every_truncation_is_malformed_never_another_exception():
    for wire in (FASTCDR_IMAGE, FASTCDR_IMAGE_16, _reference_image('>', 1, 2, 'xy', 1, 1, 'mono8', 0, 1, b'\x07')):
        for cut in range(len(wire)):
            with pytest.raises(CdrError):
                parse_image(wire[:cut])


@pytest.mark.parametrize('patch, error', [
    ((44, struct.pack('<I', 7)), 'data claims 7 bytes'),             # data length beyond the buffer
    ((44, struct.pack('<I', 2**32 - 1)), 'data claims'),              # a huge data length
    ((12, struct.pack('<I', 10**6)), 'header.frame_id claims 1000000'),  # frame_id beyond the buffer
    ((28, struct.pack('<I', 2**31)), 'encoding claims'),              # encoding beyond the buffer
])
def test_sizes_beyond_the_buffer_are_malformed(patch, error):
    wire = bytearray(_reference_image('<', 1, 2, 'abc', 2, 3, 'mono8', 0, 3, bytes(6)))
    offset, value = patch
    wire[offset:offset + 4] = value
    with pytest.raises(CdrError, match=error):
        parse_image(bytes(wire))


@pytest.mark.parametrize('mutate, why', [
    (lambda w: w.__setitem__(slice(0, 2), b'\x00\x07'), 'encapsulation 0007'),  # XCDR2 little-endian
    (lambda w: w.__setitem__(slice(0, 2), b'\x00\x03'), 'encapsulation 0003'),  # parameter list
    (lambda w: w.__setitem__(slice(12, 16), struct.pack('<I', 0)), 'length 0'),   # frame_id without NUL
    (lambda w: w.__setitem__(17, 0), 'one NUL-terminated'),                       # 'a\0c\0': embedded NUL
    (lambda w: w.__setitem__(19, ord('x')), 'one NUL-terminated'),                # no terminator
    (lambda w: w.__setitem__(slice(16, 18), b'\xff\xfe'), 'not UTF-8'),
])
def test_what_only_the_ros_deserializer_decodes_exactly_is_handed_back(mutate, why):
    """The ROS deserializer truncates a string at an embedded NUL and replaces invalid UTF-8;
    these are handed back (NotPlainCdr) rather than read differently."""
    wire = bytearray(_reference_image('<', 1, 2, 'abc', 2, 3, 'mono8', 0, 3, bytes(6)))
    mutate(wire)
    with pytest.raises(NotPlainCdr, match=why):
        parse_image(bytes(wire))


def test_random_corruptions_are_read_consistently_or_refused():
    """Bytes flipped anywhere in a valid message: either refused (CdrError / NotPlainCdr) or read
    as a header whose pixels lie inside the buffer and which rebuilds into the same bytes."""
    rng = np.random.default_rng(7)
    base = _reference_image('<', 5, 6, 'camera', 4, 6, 'bgr8', 0, 18, bytes(range(72)))
    outcomes = set()
    for _ in range(3000):
        wire = bytearray(base)
        for i in rng.integers(0, len(wire), rng.integers(1, 4)):
            wire[i] = int(rng.integers(0, 256))
        try:
            h = parse_image(bytes(wire))
        except (CdrError, NotPlainCdr) as exc:
            outcomes.add(type(exc).__name__)
            continue
        outcomes.add('read')
        assert 0 <= h.data_offset and h.data_offset + h.data_size <= len(wire)
        rebuilt = serialize_image(h.sec, h.nanosec, h.frame_id, h.height, h.width, h.encoding, h.is_bigendian,
                                  h.step, bytes(pixel_bytes(wire, h)), byte_order=h.byte_order)
        assert parse_image(rebuilt) == h._replace(data_offset=parse_image(rebuilt).data_offset)
    assert outcomes == {'read', 'CdrError', 'NotPlainCdr'}


def test_patch_stamp_changes_the_stamp_only():
    info = serialize_camera_info(42, 7, 'cam', 1080, 1920, 'equidistant', [0.5, -0.25, 0.125, 1.0],
                                 [float(i) for i in range(1, 10)], [1.0, 0, 0, 0, 1, 0, 0, 0, 1],
                                 [float(i) for i in range(12)], 2, 1, (10, 20, 30, 40, True))
    patch_stamp(info, -1, 999_999_999)
    expected = bytearray(FASTCDR_CAMERA_INFO)
    expected[4:12] = struct.pack('<iI', -1, 999_999_999)
    assert bytes(info) == bytes(expected)


@pytest.mark.parametrize('shape, dtype, encoding', [((6, 10), np.uint8, 'mono8'), ((6, 10, 3), np.uint8, 'bgr8'),
                                                    ((6, 10), np.uint16, 'mono16'), ((6, 10, 4), np.uint8, 'rgba8'),
                                                    ((6, 10), np.float32, '32FC1')])
def test_serialized_image_buffer_is_the_message_of_what_is_written_into_it(shape, dtype, encoding):
    """A textured frame written into the array prepare() returns: the buffer is that frame's
    serialized Image (packed rows, little-endian pixels), byte for byte the CDR rules' message."""
    rng = np.random.default_rng(11)
    frame = (rng.random(shape) * 60000).astype(dtype)
    out = SerializedImage()
    # the same layout (the buffer reused, its header rewritten), then the pixels move with the header
    for sec, frame_id in enumerate(('left', 'rght', 'a_longer_frame_id', 'r')):
        target = out.prepare(sec, 5678, frame_id, encoding, frame.shape, frame.dtype)
        target[...] = frame
        row = shape[1] * (shape[2] if len(shape) == 3 else 1) * np.dtype(dtype).itemsize
        assert bytes(out.buffer) == _reference_image('<', sec, 5678, frame_id, shape[0], shape[1], encoding, 0,
                                                     row, frame.astype(np.dtype(dtype).newbyteorder('<')).tobytes())
    first = out.buffer
    out.prepare(1, 2, 'r', encoding, frame.shape, frame.dtype)
    assert out.buffer is first  # same layout: the buffer is reused


def test_image_prefix_ends_where_the_pixels_start():
    prefix = image_prefix(1, 2, 'abc', 2, 3, 'mono8', 0, 3, 6)
    assert bytes(prefix) + bytes(range(6)) == serialize_image(1, 2, 'abc', 2, 3, 'mono8', 0, 3, bytes(range(6)))
    assert len(prefix) % 4 == 0  # pixels 4-aligned in the buffer: 16- and 32-bit views are aligned
