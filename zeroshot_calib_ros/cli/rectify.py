"""``zeroshot-calib rectify``: an image file made pinhole, with the camera of a spec sheet, a
--preset or a calibration file (scaled to an image of another size with the same aspect ratio)."""
from __future__ import annotations

import cv2
import numpy as np

from ..core.ros_formats.rectify import INTERPOLATIONS, Rectifier, new_camera_matrix, principal_point_camera_matrix
from ..core.zeroshot.presets import spec_with_preset
from ..core.zeroshot.solver import solve_zero_shot
from .arguments import (IMAGE_BUDGET, SOLVE_SPEC_FIELDS, CliError, add_circle_arguments, add_fov_tolerance_argument,
                        add_output_arguments, add_spec_arguments, integer, options_given)
from .output import assumption_warnings, check_output_image, load_calibration, print_warnings, read_input_image


def add_parser(subparsers):
    rectify = subparsers.add_parser('rectify', help='rectify an image file')
    rectify.add_argument('input', help=f'input image (at most {IMAGE_BUDGET})')
    rectify.add_argument('-o', '--output', required=True, help='output image')
    add_spec_arguments(rectify, size_required=False)
    add_output_arguments(rectify)
    add_circle_arguments(rectify)
    add_fov_tolerance_argument(rectify)
    rectify.add_argument('--preset', metavar='NAME',
                         help='the camera of a published spec (`zeroshot-calib presets`); flags override '
                              'its fields; an image of another size with the same aspect ratio is scaled')
    rectify.add_argument('--calibration', metavar='FILE',
                         help='the camera of a calibration file (camera_calibration_parsers YAML or .ini) '
                              'instead of a spec; its P unless --balance / --fov-scale are given; an image '
                              'of another size with the same aspect ratio is scaled')
    rectify.add_argument('--interpolation', type=integer, default=1, choices=sorted(INTERPOLATIONS),
                         help='0 nearest, 1 linear, 2 cubic, 4 lanczos4 (default 1)')
    rectify.set_defaults(run=run, model=None, balance=None, fov_scale=None)


def run(args):
    check_output_image(args.output)
    image, _ = read_input_image(args.input)
    height, width = image.shape[:2]
    about = {}
    camera, P, R = _rectify_camera(args, width, height, about)
    rectifier = Rectifier(camera, interpolation=args.interpolation, P=P, R=R)
    try:
        written = cv2.imwrite(args.output, rectifier.rectify(image))
    except cv2.error as exc:
        raise CliError(f'cannot write image {args.output}: OpenCV: {exc}') from None
    if not written:
        raise CliError(f'cannot write image {args.output}')
    print(f'wrote {args.output}: {width}x{height} pinhole image ({_focal_and_centre(P)}) from {args.input}; '
          f"camera: {about['model']}, {about['source']}, K {_focal_and_centre(camera.K)}")
    return 0


def _focal_and_centre(matrix):
    """'f F px, principal point (X, Y)' of a 3x3 camera matrix (fx and fy when they differ)."""
    fx, fy, cx, cy = matrix[0][0], matrix[1][1], matrix[0][2], matrix[1][2]
    focal = f'f {fx:.2f} px' if abs(fx - fy) <= 1e-9 * abs(fx) else f'fx {fx:.2f} px, fy {fy:.2f} px'
    return f'{focal}, principal point ({cx:.1f}, {cy:.1f})'


RECTIFY_SPEC_OPTIONS = SOLVE_SPEC_FIELDS + ('preset', 'model')


_ONE_FOV_MEANING = {'hfov': 'the angle across the image width, edge to edge through the centre',
                    'vfov': 'the angle across the image height, edge to edge through the centre',
                    'dfov': 'the angle across the image diagonal, corner to corner'}


def _spec_words(spec, solution):
    """How `rectify` read the spec: the FOVs given and, for one FOV (or the circle) alone, what it
    was taken to mean and what was assumed (the warning gives the details)."""
    given = dict(spec.given())
    circle = spec.circle_diameter is not None and spec.circle_fov is not None
    text = ', '.join(f'{k} {v:g}' for k, v in given.items()) + (' deg' if given else '')
    if circle:
        text += (', ' if given else '') + f'circle {spec.circle_diameter:g} px across {spec.circle_fov:g} deg'
    if len(given) == 1 and not circle and solution.assumption:
        (key, _), = given.items()
        text += f' alone (taken as {_ONE_FOV_MEANING[key]}; lens shape assumed from real lenses of that FOV)'
    elif not given and circle:
        text += ' alone (the pure equidistant law assumed across the circle)'
    return text


def _rectify_camera(args, width, height, about=None):
    """(camera model, P, R) for an image of width x height (R: the calibration file's
    rectification rotation, honoured as image_proc does; the identity for a spec). ``about``, a
    dict, gets 'model' and 'source': where the camera comes from, in words."""
    about = {} if about is None else about
    balance = 0.0 if args.balance is None else args.balance
    fov_scale = 1.0 if args.fov_scale is None else args.fov_scale
    if args.calibration is not None:
        given = options_given(args, RECTIFY_SPEC_OPTIONS)
        if given:
            raise CliError(f'{given[0]} cannot be combined with --calibration: the calibration file '
                           'gives the camera')
        calibration = load_calibration(args.calibration, '--calibration')
        cw, ch = calibration.width, calibration.height
        about.update(model=calibration.distortion_model, source=f'from {args.calibration}' + (
            f' (for {cw}x{ch}, scaled)' if (cw, ch) != (width, height) else ''))
        if (cw, ch) != (width, height):
            if width * ch != height * cw:
                raise CliError(f'the image {args.input} is {width}x{height} but --calibration '
                               f'{args.calibration} is for {cw}x{ch}: allowed: {cw}x{ch} or the same '
                               'aspect ratio (then scaled)')
            calibration = calibration.scaled(width, height)
        camera = calibration.camera()
        if args.balance is not None or args.fov_scale is not None:
            # a calibrated camera's P keeps its principal point, as calibrate, refine and the node
            # write it (core/ros_formats/rectify.principal_point_camera_matrix)
            return camera, principal_point_camera_matrix(camera, balance, fov_scale), calibration.R
        P = np.asarray(calibration.P, dtype=float)[:3, :3]
        if not abs(np.linalg.det(P)) > 0:
            raise CliError(f'--calibration {args.calibration}: projection_matrix {P.tolist()} cannot be '
                           'inverted: allowed: an invertible P (or choose one with --balance / --fov-scale)')
        return camera, P, calibration.R
    fields = {k: getattr(args, k) for k in SOLVE_SPEC_FIELDS}
    if not args.preset:
        fields['width'] = width if args.width is None else args.width
        fields['height'] = height if args.height is None else args.height
    spec = spec_with_preset(args.preset, **fields)
    if spec.width * height != spec.height * width:
        raise CliError(f'the image is {width}x{height} but the spec is {spec.width}x{spec.height}: '
                       'aspect ratios differ')
    solution = solve_zero_shot(spec, args.model or 'auto', fov_tolerance=args.fov_tolerance)
    print_warnings(solution.warnings + assumption_warnings(solution))
    about.update(model=solution.projection.name, source=f'zero-shot from {_spec_words(spec, solution)}' + (
        f' (for {spec.width}x{spec.height}, scaled)' if (spec.width, spec.height) != (width, height) else ''))
    camera = solution.camera if (spec.width, spec.height) == (width, height) \
        else solution.camera.scaled(width, height)
    return camera, new_camera_matrix(camera, balance, fov_scale), None
