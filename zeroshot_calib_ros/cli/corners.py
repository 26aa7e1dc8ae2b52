"""The chessboard input that ``calibrate`` and ``evaluate`` share: images (files or glob patterns)
or a corners file, the board, and the spec-sheet FOVs given with them."""
from __future__ import annotations

import glob
import os
import sys

from ..core.checkerboard.corners import SQUARE_ALLOWED, CornerSet, detect_corners, parse_board, square_ok
from ..core.zeroshot.spec import CameraSpec
from .arguments import IMAGE_BUDGET, CliError, number
from .output import end_progress


def add_corner_arguments(parser):
    parser.add_argument('images', nargs='*', help=f'chessboard images: files or glob patterns (at most {IMAGE_BUDGET} '
                        'each)')
    parser.add_argument('--corners', metavar='FILE',
                        help='a corners file (JSON, see docs/calibration.md) instead of images')
    parser.add_argument('--board', default='8x6',
                        help='inner corners COLSxROWS, as OpenCV patternSize (default 8x6)')
    parser.add_argument('--square', type=number, default=0.108, help='square side in metres (default 0.108)')
    parser.add_argument('--skip-missing', action='store_true',
                        help='leave out (and list on stderr) images whose board is not found, '
                             'instead of failing')
    parser.add_argument('--save-corners', metavar='FILE', help='write the detected corners to FILE')
    parser.add_argument('--hfov', type=number, help='spec-sheet horizontal field of view (deg)')
    parser.add_argument('--vfov', type=number, help='spec-sheet vertical field of view (deg)')
    parser.add_argument('--dfov', type=number, help='spec-sheet diagonal field of view (deg)')


def image_paths(patterns):
    """The files of ``patterns``: a name as it is, a glob pattern as its matches, sorted (none: an error)."""
    paths = []
    for pattern in patterns:
        if any(ch in pattern for ch in '*?['):
            found = sorted(glob.glob(pattern))
            if not found:
                raise CliError(f'no image matches {pattern}')
            paths += found
        else:
            paths.append(pattern)
    return paths


def corner_set(args, single=None, progress=None):
    """The CornerSet of the images / --corners file; writes --save-corners. ``progress``: a
    ProgressLine told of each image searched."""
    if args.corners and args.images:
        raise CliError('give chessboard images or --corners FILE, not both')
    if not square_ok(args.square):
        raise CliError(f'--square {args.square:g} is invalid: allowed: {SQUARE_ALLOWED}, the side of one '
                       'board square')
    if args.corners:
        corners = CornerSet.load(args.corners)
    else:
        paths = image_paths(args.images) or ([single] if single else [])
        if not paths:
            raise CliError('no input: give chessboard images or --corners FILE')
        corners = detect_corners(paths, parse_board(args.board, args.square), args.skip_missing, progress)
        if corners.missing:
            end_progress()
            print(f'zeroshot-calib: warning: board {corners.board.size} not found in '
                  f'{len(corners.missing)} of {len(paths)} images, left out: '
                  f'{", ".join(os.path.basename(p) for p in corners.missing)}', file=sys.stderr)
    if args.save_corners:
        corners.save(args.save_corners)
    return corners


def fov_spec(args, corners):
    """The spec of the FOV flags at the corners' image size; None when none is given."""
    if args.hfov is None and args.vfov is None and args.dfov is None:
        return None
    return CameraSpec(corners.width, corners.height, args.hfov, args.vfov, args.dfov)
