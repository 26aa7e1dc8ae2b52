"""Chessboard corners: detection in images, the corners file, the board's object points.

Board
    ``Board(cols, rows, square)``: ``cols`` x ``rows`` *inner* corners (OpenCV's ``patternSize``
    = (cols, rows); the default 8x6 is the shared ROS data set's board) and the square side in
    metres. Corner ``j = r * cols + c`` (OpenCV's row-major order) is the board point
    ``(c * square, r * square, 0)``.

Detection
    ``detect_corners(paths, board)``: ``cv2.findChessboardCorners`` (adaptive threshold,
    normalised image; ``cv2.findChessboardCornersSB`` as a fallback where it exists), then
    ``cv2.cornerSubPix`` with a window of half the smallest corner spacing (as ROS's
    camera_calibration does). Every image must have the same size; images whose board is not
    found are an error naming them (or, with ``skip_missing=True``, listed in
    ``CornerSet.missing``).

Corners file (JSON, UTF-8)::

    {
      "format": "zeroshot-calib-corners",      (optional on reading)
      "version": 1,                            (optional on reading)
      "image_width": 800,
      "image_height": 503,
      "board": {"cols": 8, "rows": 6, "square": 0.108},
      "images": [
        {"name": "left-0000.png",
         "corners": [[u0, v0], [u1, v1], ...]}  cols * rows points, OpenCV's row-major order,
        ...                                     pixel coordinates (x right, y down; the centre
      ]                                         of the top-left pixel is (0, 0))
    }

Every error (unreadable image, board not found, different image sizes, malformed file) is a
``CornersError`` with a one-line message naming what is wrong.
"""
from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field
from typing import List, Sequence

import cv2
import numpy as np

CORNERS_FORMAT = 'zeroshot-calib-corners'
CORNERS_VERSION = 1
MIN_CORNERS_PER_IMAGE = 6
"""A board with fewer inner corners cannot constrain a pose and the intrinsics together."""

_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)


class CornersError(ValueError):
    """Corners cannot be detected or read; the message says which image / field and why."""


@dataclass(frozen=True)
class Board:
    """A chessboard: ``cols`` x ``rows`` inner corners, squares ``square`` metres wide."""

    cols: int = 8
    rows: int = 6
    square: float = 0.108

    def __post_init__(self):
        for name in ('cols', 'rows'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 2:
                raise CornersError(f'board {name} = {value!r} is invalid: allowed: an integer >= 2 '
                                   '(inner corners)')
        if self.cols * self.rows < MIN_CORNERS_PER_IMAGE:
            raise CornersError(f'board = {self.cols}x{self.rows} is invalid: {self.cols * self.rows} '
                               f'inner corners, allowed: at least {MIN_CORNERS_PER_IMAGE}')
        if isinstance(self.square, bool) or not isinstance(self.square, (int, float)) \
                or not math.isfinite(self.square) or self.square <= 0:
            raise CornersError(f'board square = {self.square!r} is invalid: allowed: a length > 0 '
                               '(metres)')

    @property
    def size(self) -> str:
        return f'{self.cols}x{self.rows}'

    @property
    def count(self) -> int:
        return self.cols * self.rows

    def object_points(self) -> np.ndarray:
        """(cols * rows, 3) board points in OpenCV's row-major corner order."""
        c, r = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        pts = np.zeros((self.count, 3))
        pts[:, 0] = c.ravel() * self.square
        pts[:, 1] = r.ravel() * self.square
        return pts


def parse_board(text: str, square: float = 0.108) -> Board:
    """``'8x6'`` (inner corners, cols x rows) -> Board."""
    m = re.fullmatch(r'\s*(\d+)\s*[xX*]\s*(\d+)\s*', str(text))
    if not m:
        raise CornersError(f'board = {text!r} is invalid: allowed: COLSxROWS inner corners, e.g. 8x6')
    return Board(int(m.group(1)), int(m.group(2)), square)


@dataclass
class CornerSet:
    """Detected corners of ``n`` images of one board: ``corners`` is (n, cols * rows, 2)."""

    width: int
    height: int
    board: Board
    names: List[str]
    corners: np.ndarray
    missing: List[str] = field(default_factory=list)
    """Images whose board was not found (only with ``skip_missing``)."""

    def __post_init__(self):
        self.corners = np.asarray(self.corners, dtype=float).reshape(len(self.names), -1, 2)
        if self.corners.shape[1] != self.board.count:
            raise CornersError(f'{self.corners.shape[1]} corners per image for a {self.board.size} '
                               f'board, allowed: {self.board.count}')

    def __len__(self):
        return len(self.names)

    def object_points(self) -> np.ndarray:
        return self.board.object_points()

    def subset(self, indices: Sequence[int]) -> 'CornerSet':
        indices = list(indices)
        return CornerSet(self.width, self.height, self.board, [self.names[i] for i in indices],
                         self.corners[indices], list(self.missing))

    def index(self, name: str) -> int:
        """Index of the image called ``name`` (full name, or its file name)."""
        for i, n in enumerate(self.names):
            if n == name:
                return i
        base = os.path.basename(name)
        matches = [i for i, n in enumerate(self.names) if os.path.basename(n) == base]
        if len(matches) == 1:
            return matches[0]
        raise CornersError(f'image {name!r} is not in the corner set ({len(self.names)} images: '
                           f'{_short_list(self.names)})')

    def to_dict(self) -> dict:
        return {
            'format': CORNERS_FORMAT, 'version': CORNERS_VERSION,
            'image_width': int(self.width), 'image_height': int(self.height),
            'board': {'cols': self.board.cols, 'rows': self.board.rows, 'square': self.board.square},
            'images': [{'name': n, 'corners': [[float(u), float(v)] for u, v in c]}
                       for n, c in zip(self.names, self.corners)],
        }

    def save(self, path: str):
        directory = os.path.dirname(os.path.abspath(path))
        os.makedirs(directory, exist_ok=True)
        tmp = f'{path}.tmp{os.getpid()}'
        with open(tmp, 'w') as f:
            json.dump(self.to_dict(), f)
            f.write('\n')
        os.replace(tmp, path)

    @classmethod
    def from_dict(cls, d, source: str = 'corners file') -> 'CornerSet':
        def bad(where, what):
            return CornersError(f'{source}: {where} {what}')

        if not isinstance(d, dict):
            raise bad('top level', 'is not a JSON object')
        if 'format' in d and d['format'] != CORNERS_FORMAT:
            raise bad('format', f'= {d["format"]!r} is invalid: allowed: {CORNERS_FORMAT!r}')
        if 'version' in d and d['version'] != CORNERS_VERSION:
            raise bad('version', f'= {d["version"]!r} is not supported: allowed: {CORNERS_VERSION}')
        size = []
        for key in ('image_width', 'image_height'):
            if key not in d:
                raise bad(key, 'is missing')
            v = d[key]
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise bad(key, f'= {v!r} is invalid: allowed: a positive integer (pixels)')
            size.append(v)
        b = d.get('board')
        if not isinstance(b, dict):
            raise bad('board', 'is missing or not an object with cols, rows, square')
        for key in ('cols', 'rows', 'square'):
            if key not in b:
                raise bad(f'board.{key}', 'is missing')
        try:
            board = Board(b['cols'], b['rows'], b['square'])
        except CornersError as exc:
            raise CornersError(f'{source}: {exc}') from None
        images = d.get('images')
        if not isinstance(images, list):
            raise bad('images', 'is missing or not a list')
        if not images:
            raise bad('images', 'is empty: allowed: at least one image')
        names, corners = [], []
        for k, item in enumerate(images):
            if not isinstance(item, dict):
                raise bad(f'images[{k}]', 'is not an object with name and corners')
            name = item.get('name', f'image_{k}')
            if not isinstance(name, str):
                raise bad(f'images[{k}].name', f'= {name!r} is not a string')
            pts = item.get('corners')
            if not isinstance(pts, list):
                raise bad(f'images[{k}].corners', 'is missing or not a list')
            if len(pts) != board.count:
                raise bad(f'images[{k}].corners', f'has {len(pts)} points, allowed: {board.count} '
                          f'(a {board.size} board)')
            try:
                arr = np.array(pts, dtype=float)
            except (TypeError, ValueError):
                raise bad(f'images[{k}].corners', 'is not a list of [u, v] number pairs') from None
            if arr.shape != (board.count, 2) or not np.all(np.isfinite(arr)):
                raise bad(f'images[{k}].corners', 'is not a list of finite [u, v] number pairs')
            outside = (arr[:, 0] < -0.5) | (arr[:, 0] > size[0] - 0.5) | (arr[:, 1] < -0.5) \
                | (arr[:, 1] > size[1] - 0.5)
            if np.any(outside):
                j = int(np.flatnonzero(outside)[0])
                raise bad(f'images[{k}].corners[{j}]', f'= {arr[j].tolist()} is outside the '
                          f'{size[0]}x{size[1]} image')
            names.append(name)
            corners.append(arr)
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise bad('images', f'has duplicate names: {_short_list(dup)}')
        return cls(size[0], size[1], board, names, np.array(corners))

    @classmethod
    def load(cls, path: str) -> 'CornerSet':
        try:
            with open(path) as f:
                d = json.load(f)
        except OSError as exc:
            raise CornersError(f'cannot read corners file {path}: {exc.strerror}') from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise CornersError(f'corners file {path} is not valid JSON: {exc}') from None
        return cls.from_dict(d, f'corners file {path}')


def _short_list(names, limit: int = 6) -> str:
    names = [os.path.basename(str(n)) or str(n) for n in names]
    if len(names) <= limit:
        return ', '.join(names)
    return ', '.join(names[:limit]) + f', ... ({len(names) - limit} more)'


def _subpix_window(corners: np.ndarray, board: Board) -> int:
    """Half the smallest spacing of neighbouring corners (px), from 2 to 15."""
    grid = corners.reshape(board.rows, board.cols, 2)
    d = min(np.min(np.linalg.norm(np.diff(grid, axis=1), axis=-1)),
            np.min(np.linalg.norm(np.diff(grid, axis=0), axis=-1)))
    return int(np.clip(math.ceil(0.5 * d), 2, 15))


def find_board(gray: np.ndarray, board: Board):
    """Sub-pixel corners (cols * rows, 2) of ``board`` in a grey image, or None."""
    pattern = (board.cols, board.rows)
    found, corners = cv2.findChessboardCorners(gray, pattern, flags=_FIND_FLAGS)
    if found:
        win = _subpix_window(corners.reshape(-1, 2), board)
        corners = cv2.cornerSubPix(gray, corners, (win, win), (-1, -1), _SUBPIX_CRITERIA)
        return corners.reshape(-1, 2).astype(float)
    if hasattr(cv2, 'findChessboardCornersSB'):
        try:
            found, corners = cv2.findChessboardCornersSB(gray, pattern, flags=0)
        except cv2.error:
            found = False
        if found:
            return corners.reshape(-1, 2).astype(float)  # SB is sub-pixel accurate already
    return None


def detect_corners(paths: Sequence[str], board: Board = Board(), skip_missing: bool = False) -> CornerSet:
    """Detect ``board`` in every image of ``paths`` (see the module docstring)."""
    paths = list(paths)
    if not paths:
        raise CornersError('no images given')
    names, corners, missing = [], [], []
    size, first = None, None
    for path in paths:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise CornersError(f'cannot read image {path}')
        this = (gray.shape[1], gray.shape[0])
        if size is None:
            size, first = this, str(path)
        elif this != size:
            raise CornersError(f'images differ in size: {path} is {this[0]}x{this[1]} but {first} is '
                               f'{size[0]}x{size[1]}; allowed: one camera resolution')
        found = find_board(gray, board)
        if found is None:
            missing.append(str(path))
        else:
            names.append(str(path))
            corners.append(found)
    if missing and (not skip_missing or not names):
        raise CornersError(f'board {board.size} (inner corners) not found in {len(missing)} of '
                           f'{len(paths)} images: {_short_list(missing)}')
    return CornerSet(size[0], size[1], board, names, np.array(corners), missing)
