"""Files read from users, bounded: a regular file (never a device, a FIFO or a directory, which
would block or never end), at most a stated number of bytes, and for images at most a stated
number of pixels, known from the file's header before anything is decoded.

Every refusal is an ``InputFileError`` (a ValueError) with one line naming the file, what is
wrong and what is allowed.
"""
from __future__ import annotations

import hashlib
import os
import stat
import struct
import tempfile
from typing import Iterator, Optional, Tuple

import numpy as np

# cv2 is imported where an image is decoded: the node reads its calibration file through this
# module at start-up and loads OpenCV only once it rectifies (its first CameraInfo comes sooner).

MAX_IMAGE_PIXELS = 50_000_000
"""Largest image read (width x height): 50 megapixels (8K video is 33, a 45 Mpx camera's photo 45)."""
MAX_IMAGE_FILE_BYTES = 512 << 20
"""Largest image file read."""
_BUDGET_TEXT = f'{MAX_IMAGE_PIXELS // 1_000_000} megapixels'


class InputFileError(ValueError):
    """A file given to read cannot be used; one line naming the file."""

    def __init__(self, message):
        super().__init__(' '.join(str(message).splitlines()))


def read_capped(path, max_bytes: int, allowed: str = '') -> bytes:
    """The bytes of the regular file ``path``, if it has at most ``max_bytes``. A FIFO, a device
    or a directory is refused without reading (opened non-blocking, so a FIFO never waits for a
    writer); a bigger file is refused after reading ``max_bytes + 1`` bytes at most."""
    path = os.fspath(path)
    tail = f': allowed: {allowed}' if allowed else ''
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, 'O_NONBLOCK', 0) | getattr(os, 'O_CLOEXEC', 0))
    except OSError as exc:
        raise InputFileError(f'cannot read {path}: {exc.strerror or exc}') from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = ('a directory' if stat.S_ISDIR(mode) else 'a FIFO' if stat.S_ISFIFO(mode) else
                'a device' if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else 'a socket' if stat.S_ISSOCK(mode)
                else 'not a regular file')
        raise InputFileError(f'cannot read {path}: it is {kind}, not a regular file{tail}')
    with os.fdopen(fd, 'rb') as f:
        try:
            data = f.read(max_bytes + 1)
        except OSError as exc:
            raise InputFileError(f'cannot read {path}: {exc.strerror or exc}') from None
    if len(data) > max_bytes:
        raise InputFileError(f'cannot read {path}: it is larger than {max_bytes} bytes{tail}')
    return data


def image_header_size(data: bytes) -> Optional[Tuple[int, int]]:
    """(width, height) that an image file's header declares (PNG, JPEG, GIF, BMP, WebP, PNM,
    TIFF), None for other formats or a header that cannot be read."""
    try:
        if data[:8] == b'\x89PNG\r\n\x1a\n' and data[12:16] == b'IHDR':
            return struct.unpack('>II', data[16:24])
        if data[:2] == b'\xff\xd8':
            return _jpeg_size(data)
        if data[:6] in (b'GIF87a', b'GIF89a'):
            return struct.unpack('<HH', data[6:10])
        if data[:2] == b'BM':
            width, height = struct.unpack('<ii', data[18:26])
            return abs(width), abs(height)
        if data[:4] == b'RIFF' and data[8:12] == b'WEBP':
            kind = data[12:16]
            if kind == b'VP8X':
                return 1 + int.from_bytes(data[24:27], 'little'), 1 + int.from_bytes(data[27:30], 'little')
            if kind == b'VP8 ':
                width, height = struct.unpack('<HH', data[26:30])
                return width & 0x3fff, height & 0x3fff
            if kind == b'VP8L':
                bits = int.from_bytes(data[21:25], 'little')
                return 1 + (bits & 0x3fff), 1 + ((bits >> 14) & 0x3fff)
        if data[:1] == b'P' and data[1:2] in b'123456' and len(data) > 2:
            return _pnm_size(data)
        if data[:4] in (b'II*\0', b'MM\0*'):
            return _tiff_size(data)
    except (struct.error, ValueError, IndexError):
        return None
    return None


def _jpeg_segments(data: bytes) -> Iterator[Tuple[int, int]]:
    """(marker, offset of its 0xff) of each segment of a JPEG from its start up to and including
    the start of scan; ValueError where the data is not a segment."""
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xff:
            raise ValueError('not a JPEG segment')
        marker = data[i + 1]
        if marker == 0xff:  # fill byte
            i += 1
            continue
        yield marker, i
        if marker == 0xda:
            return
        if marker in (0xd8, 0x01) or 0xd0 <= marker <= 0xd7:  # markers without a length
            i += 2
            continue
        i += 2 + struct.unpack('>H', data[i + 2:i + 4])[0]


def _jpeg_size(data: bytes) -> Optional[Tuple[int, int]]:
    for marker, i in _jpeg_segments(data):
        if 0xc0 <= marker <= 0xcf and marker not in (0xc4, 0xc8, 0xcc):  # a start of frame
            height, width = struct.unpack('>HH', data[i + 5:i + 9])
            return width, height
    return None


def _jpeg_complete(data: bytes) -> bool:
    """Whether a JPEG has its end-of-image marker after the start of its scan data (segments
    walked from the start, so an EXIF thumbnail's end marker does not count)."""
    try:
        for marker, i in _jpeg_segments(data):
            if marker == 0xda:
                return b'\xff\xd9' in data[i + 2:]
    except (ValueError, struct.error):
        return False
    return False


def _pnm_size(data: bytes) -> Optional[Tuple[int, int]]:
    tokens, i = [], 2
    while len(tokens) < 2 and i < min(len(data), 4096):
        ch = data[i:i + 1]
        if ch == b'#':
            while i < len(data) and data[i:i + 1] not in (b'\n', b'\r'):
                i += 1
        elif ch.isspace():
            i += 1
        else:
            start = i
            while i < len(data) and not data[i:i + 1].isspace():
                i += 1
            tokens.append(int(data[start:i]))
    return (tokens[0], tokens[1]) if len(tokens) == 2 else None


def _tiff_size(data: bytes) -> Optional[Tuple[int, int]]:
    order = '<' if data[:2] == b'II' else '>'
    offset = struct.unpack(order + 'I', data[4:8])[0]
    count = struct.unpack(order + 'H', data[offset:offset + 2])[0]
    size = {}
    for k in range(count):
        entry = data[offset + 2 + 12 * k:offset + 14 + 12 * k]
        tag, kind = struct.unpack(order + 'HH', entry[:4])
        if tag in (256, 257):
            size[tag] = struct.unpack(order + ('H' if kind == 3 else 'I'), entry[8:10] if kind == 3 else entry[8:12])[0]
    return (size[256], size[257]) if len(size) == 2 else None


def _decode_checked(path: str, data: bytes, flags: int):
    """cv2.imdecode, with what libjpeg writes to stderr about corrupt data caught (OpenCV
    decodes such a JPEG anyway, with grey or shifted blocks)."""
    import cv2
    buffer = np.frombuffer(data, np.uint8)
    if data[:2] != b'\xff\xd8':
        return cv2.imdecode(buffer, flags), ''
    saved = os.dup(2)
    with tempfile.TemporaryFile() as messages:
        try:
            os.dup2(messages.fileno(), 2)
            image = cv2.imdecode(buffer, flags)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        messages.seek(0)
        text = messages.read(2000).decode('utf-8', 'replace')
    return image, ' '.join(text.split())


def read_image(path, flags: int = -1, finite: bool = False):
    """(image, sha1 of the file) of the image file ``path``: a regular file of at most
    MAX_IMAGE_FILE_BYTES, declaring at most MAX_IMAGE_PIXELS in its header (checked before
    decoding), decoded completely (a JPEG without its end marker or with corrupt data is refused);
    with ``finite``, a float image holding NaN or infinity is refused. InputFileError otherwise.
    ``flags``: cv2.imdecode's (default -1, cv2.IMREAD_UNCHANGED)."""
    import cv2
    path = os.fspath(path)
    allowed = f'an image file of at most {_BUDGET_TEXT}'
    try:
        data = read_capped(path, MAX_IMAGE_FILE_BYTES, allowed)
    except InputFileError as exc:
        raise InputFileError(str(exc).replace('cannot read ', 'cannot read image ', 1)) from None
    size = image_header_size(data)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise InputFileError(f'cannot read image {path}: it is {size[0]}x{size[1]} pixels: allowed: at most '
                             f'{_BUDGET_TEXT} ({MAX_IMAGE_PIXELS} pixels)')
    if not data:  # (OpenCV's own message for it is an assertion about its buffer)
        raise InputFileError(f'cannot read image {path}: the file is empty: allowed: an image file')
    if data[:2] == b'\xff\xd8' and not _jpeg_complete(data):
        raise InputFileError(f'cannot read image {path}: the JPEG file is truncated (no end-of-image marker): '
                             'allowed: a complete image file')
    try:
        image, messages = _decode_checked(path, data, flags)
    except cv2.error as exc:
        raise InputFileError(f'cannot read image {path}: OpenCV: {" ".join(str(exc).split())}') from None
    if image is None or image.size == 0:
        raise InputFileError(f'cannot read image {path}: not an image file OpenCV can decode: allowed: an image file '
                             '(PNG, JPEG, TIFF, BMP, PGM/PPM, WebP, ...)')
    if messages:
        raise InputFileError(f'cannot read image {path}: the file is corrupt ({messages[:120]}): allowed: an '
                             'undamaged image file')
    if image.shape[0] * image.shape[1] > MAX_IMAGE_PIXELS:
        raise InputFileError(f'cannot read image {path}: it is {image.shape[1]}x{image.shape[0]} pixels: '
                             f'allowed: at most {_BUDGET_TEXT} ({MAX_IMAGE_PIXELS} pixels)')
    if finite and image.dtype.kind == 'f' and not np.all(np.isfinite(image)):
        raise InputFileError(f'cannot read image {path}: it holds NaN or infinite pixel values: allowed: '
                             'finite values')
    return image, hashlib.sha1(data).hexdigest()
