"""Serialized sensor_msgs/Image and sensor_msgs/CameraInfo (CDR, as DDS carries them), without ROS.

The node takes image_raw as the serialized bytes DDS delivered and publishes bytes (issue 14):
``parse_image`` reads an Image's header fields and where its pixels are, with every bound checked,
so that the pixels can be viewed in place (``numpy.frombuffer``); ``SerializedImage`` is a reused
buffer laid out as a serialized Image (header, then the pixel bytes), into which rectification
writes directly; ``serialize_camera_info`` builds a CameraInfo whose stamp ``patch_stamp`` then
changes frame after frame.

The format is plain CDR (XCDR1, what ROS 2's DDS middlewares write for ROS messages): a 4-byte
encapsulation header (``00 01`` little-endian, ``00 00`` big-endian, 2 option bytes), then the
fields in order, each aligned to its size (at most 8) from the end of that header; a string is a
uint32 length counting its terminating NUL, the bytes, the NUL; a sequence a uint32 count, then the
elements. What is built here writes zeros into the alignment padding (Fast CDR leaves it as it
was in memory; readers ignore it).

Two kinds of refusal: ``CdrError`` for bytes that cannot be the message (truncated, sizes beyond
the buffer: the frame is malformed), ``NotPlainCdr`` for a message this reader does not decode
exactly as the ROS deserializer would (another encapsulation such as XCDR2 or a parameter list,
a string with an embedded NUL, no terminator or not UTF-8): the caller deserializes it the usual
way instead.
"""
from __future__ import annotations

import struct
from typing import NamedTuple, Optional, Sequence, Tuple

import numpy as np

HEADER_SIZE = 4
"""The encapsulation header; field alignment counts from its end."""

_ENCAPSULATIONS = {b'\x00\x00': '>', b'\x00\x01': '<'}
_ENCAPSULATION_OF = {'>': b'\x00\x00\x00\x00', '<': b'\x00\x01\x00\x00'}
_U32 = {order: struct.Struct(order + 'I') for order in '<>'}
_STAMP = {order: struct.Struct(order + 'iI') for order in '<>'}
_SIZE = {order: struct.Struct(order + 'II') for order in '<>'}


class CdrError(ValueError):
    """Bytes that cannot be a serialized message of the type (the frame is malformed)."""


class NotPlainCdr(ValueError):
    """A message this reader does not decode exactly as the ROS deserializer would; deserialize it."""


class ImageHeader(NamedTuple):
    """The fields of a serialized sensor_msgs/Image, and where its pixel bytes are."""

    byte_order: str  # '<' or '>': the CDR's (the pixels' byte order is is_bigendian's)
    sec: int
    nanosec: int
    frame_id: str
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data_offset: int  # of the first pixel byte, in the buffer
    data_size: int    # the data sequence's length (bytes)


def _align(offset: int, size: int) -> int:
    """``offset`` (in the buffer) moved up to a multiple of ``size`` from the CDR origin."""
    return offset + (-(offset - HEADER_SIZE) % size)


def _string(buf, offset: int, order: str, end: int, what: str) -> Tuple[str, int]:
    offset = _align(offset, 4)
    if offset + 4 > end:
        raise CdrError(f'serialized message ends ({end} bytes) inside the length of {what}')
    n, = _U32[order].unpack_from(buf, offset)
    offset += 4
    if n > end - offset:
        raise CdrError(f'{what} claims {n} bytes, {end - offset} remain in the serialized message')
    if n == 0:
        raise NotPlainCdr(f'{what} has length 0 (no terminating NUL)')
    raw = bytes(buf[offset:offset + n])
    if raw[-1] != 0 or 0 in raw[:-1]:
        raise NotPlainCdr(f'{what} is not one NUL-terminated string')
    try:
        return raw[:-1].decode('utf-8'), offset + n
    except UnicodeDecodeError:
        raise NotPlainCdr(f'{what} is not UTF-8') from None


def byte_order_of(buf) -> str:
    """'<' or '>' of a plain CDR buffer; NotPlainCdr for another encapsulation, CdrError if too short."""
    if len(buf) < HEADER_SIZE:
        raise CdrError(f'serialized message of {len(buf)} bytes has no encapsulation header')
    order = _ENCAPSULATIONS.get(bytes(buf[:2]))
    if order is None:
        raise NotPlainCdr(f'encapsulation {bytes(buf[:2]).hex()} is not plain CDR (00 00 / 00 01)')
    return order


def parse_image(buf) -> ImageHeader:
    """The header fields of a serialized sensor_msgs/Image (``bytes``, ``bytearray`` or
    ``memoryview``) and the position of its pixel bytes, which lie within the buffer (bytes after
    them, e.g. a DDS payload's padding, are ignored as the ROS deserializer ignores them).
    Raises CdrError or NotPlainCdr (see the module). The fields themselves are not checked
    against each other here (``image_frames.check_frame`` does that, whichever path a frame took)."""
    order = byte_order_of(buf)
    end = len(buf)
    if end < HEADER_SIZE + 12:
        raise CdrError(f'serialized Image of {end} bytes ends inside its header')
    sec, nanosec = _STAMP[order].unpack_from(buf, HEADER_SIZE)
    frame_id, offset = _string(buf, HEADER_SIZE + 8, order, end, 'header.frame_id')
    offset = _align(offset, 4)
    if offset + 8 > end:
        raise CdrError('serialized Image ends inside height / width')
    height, width = _SIZE[order].unpack_from(buf, offset)
    encoding, offset = _string(buf, offset + 8, order, end, 'encoding')
    if offset + 1 > end:
        raise CdrError('serialized Image ends before is_bigendian')
    is_bigendian = buf[offset]
    offset = _align(offset + 1, 4)
    if offset + 8 > end:
        raise CdrError('serialized Image ends inside step / the data length')
    step, size = _SIZE[order].unpack_from(buf, offset)
    offset += 8
    if size > end - offset:
        raise CdrError(f'data claims {size} bytes, the serialized Image has {end - offset} after its header')
    return ImageHeader(order, sec, nanosec, frame_id, height, width, encoding, is_bigendian, step, offset, size)


def pixel_bytes(buf, header: ImageHeader) -> memoryview:
    """The data field of a parsed Image, a view of ``buf`` (no copy)."""
    return memoryview(buf)[header.data_offset:header.data_offset + header.data_size]


# --- building ---------------------------------------------------------------------------------
class _Writer:
    def __init__(self, order: str):
        self.order = order
        self.out = bytearray(_ENCAPSULATION_OF[order])

    def align(self, size: int):
        self.out += bytes(-(len(self.out) - HEADER_SIZE) % size)

    def pack(self, fmt: str, *values, size: int):
        self.align(size)
        self.out += struct.pack(self.order + fmt, *values)

    def string(self, text: str):
        raw = text.encode('utf-8')
        if 0 in raw:
            raise ValueError(f'{text!r} contains a NUL character')
        self.pack('I', len(raw) + 1, size=4)
        self.out += raw + b'\x00'

    def header(self, sec: int, nanosec: int, frame_id: str):
        self.pack('iI', sec, nanosec, size=4)
        self.string(frame_id)


def image_prefix(sec: int, nanosec: int, frame_id: str, height: int, width: int, encoding: str,
                 is_bigendian: int, step: int, data_size: int, byte_order: str = '<') -> bytearray:
    """A serialized sensor_msgs/Image up to its first pixel byte (the data's length included):
    the message is this followed by ``data_size`` pixel bytes."""
    w = _Writer(byte_order)
    w.header(sec, nanosec, frame_id)
    w.pack('II', height, width, size=4)
    w.string(encoding)
    w.out.append(int(is_bigendian) & 0xFF)
    w.pack('II', step, data_size, size=4)
    return w.out


def serialize_image(sec: int, nanosec: int, frame_id: str, height: int, width: int, encoding: str,
                    is_bigendian: int, step: int, data, byte_order: str = '<') -> bytes:
    """A whole serialized sensor_msgs/Image."""
    data = memoryview(data).cast('B')
    return bytes(image_prefix(sec, nanosec, frame_id, height, width, encoding, is_bigendian, step,
                              len(data), byte_order) + data)


def serialize_camera_info(sec: int, nanosec: int, frame_id: str, height: int, width: int,
                          distortion_model: str, d: Sequence[float], k: Sequence[float],
                          r: Sequence[float], p: Sequence[float], binning_x: int, binning_y: int,
                          roi: Tuple[int, int, int, int, bool], byte_order: str = '<') -> bytearray:
    """A serialized sensor_msgs/CameraInfo; ``roi`` is (x_offset, y_offset, height, width,
    do_rectify) in the message's field order."""
    if (len(k), len(r), len(p)) != (9, 9, 12):
        raise ValueError(f'k, r, p need 9, 9 and 12 numbers, got {len(k)}, {len(r)}, {len(p)}')
    w = _Writer(byte_order)
    w.header(sec, nanosec, frame_id)
    w.pack('II', height, width, size=4)
    w.string(distortion_model)
    w.pack('I', len(d), size=4)
    for values in (d, k, r, p):
        if len(values):
            w.pack(f'{len(values)}d', *map(float, values), size=8)
    w.pack('II', binning_x, binning_y, size=4)
    w.pack('IIII', *roi[:4], size=4)
    w.out.append(1 if roi[4] else 0)
    return w.out


def patch_stamp(buf: bytearray, sec: int, nanosec: int):
    """Set header.stamp of a serialized message (any type with a std_msgs/Header first)."""
    _STAMP[byte_order_of(buf)].pack_into(buf, HEADER_SIZE, sec, nanosec)


class SerializedImage:
    """A reused buffer laid out as a serialized sensor_msgs/Image: ``prepare`` writes the header
    of the next message and returns a writable array over its pixel bytes, where the frame is
    rectified; ``buffer`` is then the whole message. The buffer is reallocated only when the
    message's size or the pixels' offset change (a new frame size, encoding or frame_id length).

    The pixels are packed rows (step = width x channels x element size) in the host's byte
    order, as the message path publishes them (is_bigendian 0)."""

    def __init__(self, byte_order: str = '<'):
        self.byte_order = byte_order
        self.buffer: Optional[bytearray] = None
        self._offset = -1

    def prepare(self, sec: int, nanosec: int, frame_id: str, encoding: str, shape: Tuple[int, ...],
                dtype: np.dtype) -> np.ndarray:
        dtype = np.dtype(dtype)
        height, width = shape[:2]
        channels = shape[2] if len(shape) == 3 else 1
        step = width * channels * dtype.itemsize
        size = step * height
        prefix = image_prefix(sec, nanosec, frame_id, height, width, encoding, 0, step, size, self.byte_order)
        if self.buffer is None or len(prefix) != self._offset or len(self.buffer) != len(prefix) + size:
            self.buffer = bytearray(len(prefix) + size)
            self._offset = len(prefix)
        self.buffer[:len(prefix)] = prefix
        return np.frombuffer(self.buffer, dtype=dtype, count=size // dtype.itemsize,
                             offset=self._offset).reshape(shape)
