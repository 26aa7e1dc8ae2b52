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
from typing import Callable, List, Optional, Sequence

import cv2
import numpy as np

from ..atomic_file import write_atomically
from ..file_input import InputFileError, read_capped, read_image
from ..zeroshot.spec import MAX_IMAGE_SIDE

CORNERS_FORMAT = 'zeroshot-calib-corners'
CORNERS_VERSION = 1
MIN_CORNERS_PER_IMAGE = 6
"""A board with fewer inner corners cannot constrain a pose and the intrinsics together."""
MAX_BOARD_SIDE = 1000
MAX_CORNERS_FILE_BYTES = 256 << 20
"""Largest corners file read (1000 images of a 30 x 30 board take about 40 MB of JSON)."""

_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)


class CornersError(ValueError):
    """Corners cannot be detected or read; the message says which image / field and why."""


def _finite_number(value) -> bool:
    """A finite int / float that converts to a float (JSON integers may be arbitrarily long)."""
    try:
        return math.isfinite(float(value))
    except (OverflowError, TypeError, ValueError):
        return False


SQUARE_RANGE_M = (1e-5, 10.0)
"""Allowed square side (metres): 10 micrometres (a microscope target) to 10 m. Outside, the value
is a mistake (108 for 108 mm, 1e300), and poses, the board's sag and the fit's steps would be
computed from it."""


@dataclass(frozen=True)
class Board:
    """A chessboard: ``cols`` x ``rows`` inner corners, squares ``square`` metres wide."""

    cols: int = 8
    rows: int = 6
    square: float = 0.108

    def __post_init__(self):
        for name in ('cols', 'rows'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) \
                    or not 2 <= value <= MAX_BOARD_SIDE:
                raise CornersError(f'board {name} = {_clip(value)} is invalid: allowed: an integer '
                                   f'from 2 to {MAX_BOARD_SIDE} (inner corners)')
        if self.cols * self.rows < MIN_CORNERS_PER_IMAGE:
            raise CornersError(f'board = {self.cols}x{self.rows} is invalid: {self.cols * self.rows} '
                               f'inner corners, allowed: at least {MIN_CORNERS_PER_IMAGE}')
        if isinstance(self.square, bool) or not isinstance(self.square, (int, float)) \
                or not square_ok(self.square):
            raise CornersError(f'board square = {_clip(self.square)} is invalid: allowed: {SQUARE_ALLOWED}')

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


SQUARE_ALLOWED = f'a length from {SQUARE_RANGE_M[0]:g} to {SQUARE_RANGE_M[1]:g} (metres)'


def square_ok(value) -> bool:
    """A finite square side within SQUARE_RANGE_M (metres)."""
    return _finite_number(value) and SQUARE_RANGE_M[0] <= float(value) <= SQUARE_RANGE_M[1]


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
        """Write the corners file all or nothing (atomic_file); SaveError names the target."""
        write_atomically(path, (json.dumps(self.to_dict()) + '\n').encode('utf-8'))

    @classmethod
    def from_dict(cls, d, source: str = 'corners file') -> 'CornerSet':
        def bad(where, what):
            return CornersError(f'{source}: {where} {what}')

        if not isinstance(d, dict):
            raise bad('top level', 'is not a JSON object: allowed: an object with image_width, '
                      'image_height, board, images')
        if 'format' in d and d['format'] != CORNERS_FORMAT:
            raise bad('format', f'= {_clip(d["format"])} is invalid: allowed: {CORNERS_FORMAT!r}')
        if 'version' in d and (isinstance(d['version'], bool) or d['version'] != CORNERS_VERSION):
            raise bad('version', f'= {_clip(d["version"])} is not supported: allowed: {CORNERS_VERSION}')
        size = []
        for key in ('image_width', 'image_height'):
            if key not in d:
                raise bad(key, 'is missing')
            v = d[key]
            if isinstance(v, bool) or not isinstance(v, int) or not 0 < v <= MAX_IMAGE_SIDE:
                raise bad(key, f'= {_clip(v)} is invalid: allowed: a positive integer (pixels) up to '
                          f'{MAX_IMAGE_SIDE}')
            size.append(v)
        b = d.get('board')
        if not isinstance(b, dict):
            raise bad('board', 'is missing or invalid: allowed: an object with cols, rows, square')
        for key in ('cols', 'rows', 'square'):
            if key not in b:
                raise bad(f'board.{key}', 'is missing')
        try:
            board = Board(b['cols'], b['rows'], b['square'])
        except CornersError as exc:
            raise CornersError(f'{source}: {exc}') from None
        images = d.get('images')
        if not isinstance(images, list):
            raise bad('images', 'is missing or invalid: allowed: a list of {name, corners} objects')
        if not images:
            raise bad('images', 'is empty: allowed: at least one image')
        names, corners = [], []
        for k, item in enumerate(images):
            if not isinstance(item, dict):
                raise bad(f'images[{k}]', 'is invalid: allowed: an object with name and corners')
            name = item.get('name', f'image_{k}')
            if not isinstance(name, str):
                raise bad(f'images[{k}].name', f'= {_clip(name)} is invalid: allowed: a string')
            pts = item.get('corners')
            if not isinstance(pts, list):
                raise bad(f'images[{k}].corners', f'is missing or not a list: allowed: {board.count} '
                          '[u, v] pixel pairs')
            if len(pts) != board.count:
                raise bad(f'images[{k}].corners', f'has {len(pts)} points, allowed: {board.count} '
                          f'(a {board.size} board)')
            for j, p in enumerate(pts):
                if not (isinstance(p, list) and len(p) == 2
                        and all(not isinstance(x, bool) and isinstance(x, (int, float))
                                and _finite_number(x) for x in p)):
                    raise bad(f'images[{k}].corners[{j}]', f'= {_clip(p)} is invalid: allowed: a '
                              '[u, v] pair of finite numbers (pixels)')
            arr = np.array(pts, dtype=float)
            outside = (arr[:, 0] < -0.5) | (arr[:, 0] > size[0] - 0.5) | (arr[:, 1] < -0.5) \
                | (arr[:, 1] > size[1] - 0.5)
            if np.any(outside):
                j = int(np.flatnonzero(outside)[0])
                raise bad(f'images[{k}].corners[{j}]', f'= {arr[j].tolist()} is outside the '
                          f'{size[0]}x{size[1]} image: allowed: u in [-0.5, {size[0] - 0.5}], '
                          f'v in [-0.5, {size[1] - 0.5}]')
            names.append(name)
            corners.append(arr)
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise bad('images', f'has duplicate names: {_short_list(dup)}; allowed: one entry per '
                      'image name')
        return cls(size[0], size[1], board, names, np.array(corners))

    @classmethod
    def load(cls, path: str) -> 'CornerSet':
        try:
            d = json.loads(read_capped(path, MAX_CORNERS_FILE_BYTES, 'a corners file (JSON)').decode('utf-8'))
        except InputFileError as exc:
            raise CornersError(str(exc).replace('cannot read ', 'cannot read corners file ', 1)) from None
        except RecursionError:
            raise CornersError(f'corners file {path} is not valid JSON: nested too deeply') from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise CornersError(f'corners file {path} is not valid JSON: {exc}') from None
        return cls.from_dict(d, f'corners file {path}')


def _clip(value, limit: int = 40) -> str:
    """repr of a (possibly huge) JSON value, shortened to one short line."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 5] + ' ...' + text[-1]


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


def detect_corners(paths: Sequence[str], board: Board = Board(), skip_missing: bool = False,
                   progress: Optional[Callable[[str], None]] = None) -> CornerSet:
    """Detect ``board`` in every image of ``paths`` (see the module docstring); ``progress`` is
    told of each image before it is read."""
    paths = list(paths)
    if not paths:
        raise CornersError('no images given')
    names, corners, missing = [], [], []
    size, first = None, None
    for number, path in enumerate(paths, start=1):
        if progress is not None:
            progress(f'finding the board in image {number}/{len(paths)} ({os.path.basename(str(path))}), '
                     f'found in {len(names)} so far')
        try:
            gray, _ = read_image(str(path), cv2.IMREAD_GRAYSCALE)
        except InputFileError as exc:
            raise CornersError(str(exc)) from None
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
        hint = _board_hint(missing[0], board) if not names else ''
        raise CornersError(f'board {board.size} (inner corners) not found in {len(missing)} of '
                           f'{len(paths)} images: {_short_list(missing)}{hint}')
    return CornerSet(size[0], size[1], board, names, np.array(corners), missing)


def _board_hint(path: str, board: Board) -> str:
    """When no image shows ``board``: the near board size (one more / fewer corner per side, e.g.
    squares counted instead of inner corners) that the first image does show, as a message tail
    ('' if none). Only OpenCV's classic detector with its fast check: a few quick calls."""
    try:
        gray, _ = read_image(str(path), cv2.IMREAD_GRAYSCALE)
    except InputFileError:
        return ''
    c, r = board.cols, board.rows
    for cols, rows in ((c - 1, r - 1), (c + 1, r + 1), (c - 1, r), (c, r - 1), (c + 1, r), (c, r + 1)):
        if cols < 2 or rows < 2 or cols * rows < MIN_CORNERS_PER_IMAGE:
            continue
        found, _ = cv2.findChessboardCorners(gray, (cols, rows),
                                             flags=_FIND_FLAGS | cv2.CALIB_CB_FAST_CHECK)
        if found:
            return (f'; {os.path.basename(str(path))} shows a board of {cols}x{rows} inner corners: '
                    f'give --board {cols}x{rows} (COLSxROWS counts inner corners, squares - 1)')
    return ''


# ---------------------------------------------------------------------------------------------
# Corner-set checks before fitting

GRID_MIN_SINE = 0.05
"""A board cell (four neighbouring corners) is sound when its quadrilateral turns the same way
at all four corners, each turn's sine above this (interior angles between ~3 and ~177 degrees):
true of any board seen by a central camera in front of it, under any radial distortion."""
GRID_MAX_BAD_FRACTION = 0.25
"""An image whose declared grid has more bad cells than this fraction is not that grid (one
outlier corner spoils at most 4 cells: 11 % of an 8x6 board's 35)."""
COLLAPSED_SPACING_PX = 1.0
"""Median distance of grid-neighbouring corners below which a view is collapsed."""
COLLINEAR_RATIO = 0.01
"""A view whose corners spread less than this fraction across their principal line than along
it (RMS spreads, the corners' covariance) is collinear: no homography, no pose."""
DUPLICATE_RMS_PX = 0.5
"""Two views whose corners differ by less than this RMS (px, in either corner order) are the
same view."""


@dataclass
class CornerReport:
    """What ``check_corner_set`` found that is not an error."""

    duplicates: List[tuple] = field(default_factory=list)
    """(name, earlier name, RMS difference px) of views with (nearly) the same corners."""
    positions: List[int] = field(default_factory=list)
    """Positions (in the views checked) of the duplicates: the views a fit leaves out."""

    @property
    def notes(self) -> List[str]:
        return [f'duplicate view: {os.path.basename(a)} has the corners of {os.path.basename(b)} '
                f'(RMS difference {d:.3f} px): it counts once (left out)' for a, b, d in self.duplicates]

    def distinct(self, views: Sequence[int]) -> tuple:
        """``views`` (those checked) without the duplicates: a copy of a view adds no evidence, so
        counting it again would shrink the error bar for nothing."""
        return tuple(v for i, v in enumerate(views) if i not in set(self.positions))

    def to_list(self) -> List[dict]:
        return [{'image': a, 'same_as': b, 'rms_difference_px': d} for a, b, d in self.duplicates]


def _bad_cells(points: np.ndarray, cols: int, rows: int) -> int:
    """Cells of the cols x rows grid ``points`` (M, 2) that are folded or flat (GRID_MIN_SINE)."""
    g = points.reshape(rows, cols, 2)
    quad = [g[:-1, :-1], g[:-1, 1:], g[1:, 1:], g[1:, :-1]]
    sines = []
    for i in range(4):
        e1 = quad[(i + 1) % 4] - quad[i]
        e2 = quad[(i + 2) % 4] - quad[(i + 1) % 4]
        cross = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
        norm = np.linalg.norm(e1, axis=-1) * np.linalg.norm(e2, axis=-1)
        sines.append(np.where(norm > 0, cross / np.where(norm > 0, norm, 1.0), 0.0))
    sines = np.stack(sines, axis=-1)
    handed = np.sign(np.sum(np.sign(sines)))  # the grid's majority handedness
    good = np.all(handed * sines > GRID_MIN_SINE, axis=-1) if handed else np.zeros(sines.shape[:2], bool)
    return int(np.count_nonzero(~good))


def _not_grid(points: np.ndarray, cols: int, rows: int) -> bool:
    return _bad_cells(points, cols, rows) > GRID_MAX_BAD_FRACTION * (cols - 1) * (rows - 1)


def _degenerate(name: str, points: np.ndarray, board: Board) -> str:
    """Why the view is degenerate ('' if it is not)."""
    g = points.reshape(board.rows, board.cols, 2)
    spacing = np.concatenate([np.linalg.norm(np.diff(g, axis=1), axis=-1).ravel(),
                              np.linalg.norm(np.diff(g, axis=0), axis=-1).ravel()])
    median = float(np.median(spacing))
    if median < COLLAPSED_SPACING_PX:
        centre = points.mean(axis=0)
        far = float(np.max(np.linalg.norm(points - centre, axis=1)))
        return (f'image {name} is degenerate: its {board.count} corners are collapsed (all within '
                f'{far:.2f} px of ({centre[0]:.1f}, {centre[1]:.1f}), median neighbour spacing '
                f'{median:.2f} px; allowed: at least {COLLAPSED_SPACING_PX:g} px)')
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False) / math.sqrt(len(points))
    if spread[1] < COLLINEAR_RATIO * spread[0]:
        return (f'image {name} is degenerate: its corners are collinear (RMS spread {spread[0]:.1f} px '
                f'along a line, {spread[1]:.3f} px across; allowed: at least {100 * COLLINEAR_RATIO:g} % '
                'across)')
    return ''


def _duplicates(names, corners: np.ndarray) -> tuple:
    """([(name, earlier name, RMS difference px)], [position of each duplicate])."""
    out, positions = [], []
    n = len(names)
    for i in range(1, n):
        same = np.sqrt(np.mean(np.sum((corners[:i] - corners[i]) ** 2, axis=-1), axis=-1))
        rev = np.sqrt(np.mean(np.sum((corners[:i] - corners[i][::-1]) ** 2, axis=-1), axis=-1))
        d = np.minimum(same, rev)
        j = int(np.argmin(d))
        if d[j] < DUPLICATE_RMS_PX:
            out.append((names[i], names[j], float(d[j])))
            positions.append(i)
    return out, positions


def check_corner_set(corners: CornerSet, views: Optional[Sequence[int]] = None) -> CornerReport:
    """Checks of ``views`` (all images by default) before any fit; raises CornersError (one line)
    on the first of:

    * a board declared transposed or with the wrong shape: in more than GRID_MAX_BAD_FRACTION of
      the cells of the declared cols x rows grid the four corners are folded or flat
      (``_bad_cells``) in some image, and another factorisation a x b of the corner count
      (e.g. 15x9 for a declared 9x15) makes every image a sound grid: the error names it;
    * a degenerate view, named: collapsed corners (median neighbour spacing below
      COLLAPSED_SPACING_PX) or collinear ones (RMS spread across the principal line below
      COLLINEAR_RATIO of that along it);
    * a view whose corners do not form the declared grid and no other shape explains (corners
      out of order, or many outliers), named.

    Duplicate views (corners within DUPLICATE_RMS_PX RMS of an earlier view's, in the same or the
    reversed order) are not an error: the report lists them with both names, and the fits leave
    them out (``CornerReport.distinct``)."""
    views = list(range(len(corners))) if views is None else [int(v) for v in views]
    board = corners.board
    pts = corners.corners[views]
    names = [corners.names[v] for v in views]
    short = [os.path.basename(n) or n for n in names]
    for name, p in zip(short, pts):
        why = _degenerate(name, p, board)
        if why:
            raise CornersError(why)
    failing = [i for i, p in enumerate(pts) if _not_grid(p, board.cols, board.rows)]
    if failing:
        alternatives = []
        for a in range(2, board.count // 2 + 1):
            b = board.count // a
            if a * b != board.count or b < 2 or a == board.cols:
                continue
            bad = sum(_not_grid(p, a, b) for p in pts)
            alternatives.append((bad, a, b))
        best = min(alternatives, default=None)
        if best is not None and best[0] == 0:
            _, a, b = best
            raise CornersError(
                f'the corners of {len(failing)} of {len(pts)} images (e.g. {short[failing[0]]}) form a '
                f'{a}x{b} grid, not the declared {board.size} board (COLSxROWS inner corners, '
                f'row-major): allowed: the board they were detected with: give --board {a}x{b} or '
                "fix the corners file's board")
        i = failing[0]
        bad = _bad_cells(pts[i], board.cols, board.rows)
        cells = (board.cols - 1) * (board.rows - 1)
        raise CornersError(
            f'image {short[i]}: its corners do not form a {board.size} grid ({bad} of {cells} '
            f'cells folded or flat; allowed: at most {100 * GRID_MAX_BAD_FRACTION:g} %): wrong board '
            'size or corners out of row-major order')
    return CornerReport(*_duplicates(names, pts))
