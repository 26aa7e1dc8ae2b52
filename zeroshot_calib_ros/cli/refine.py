"""``zeroshot-calib refine``: the spec sheet plus straight lines in ordinary images of the camera
(core/estimation/refine.py), with the image circle measured in the images, a contact sheet of the
curves and a report; the zero-shot camera is kept when the refinement is not adopted."""
from __future__ import annotations

import json
import os
import sys

import cv2
import numpy as np

from ..core.lens.fitting import DISTORTION_FITS
from ..core.ros_formats.calibration_file import CameraCalibration, json_safe, solution_summary, summary_text
from ..core.ros_formats.rectify import new_camera_matrix, principal_point_camera_matrix
from ..core.zeroshot.presets import spec_with_preset
from ..core.zeroshot.spec import check_fov
from ..core.zeroshot.solver import solve_zero_shot
from .arguments import (EXIT_NOT_ADOPTED, EXIT_STATUSES, IMAGE_BUDGET, REPORT_HELP, CliError, add_circle_arguments,
                        add_fov_tolerance_argument, add_progress_argument, number)
from .output import (assumption_warnings, check_output_image, error_bar_keys, fit_warnings, kannala_brandt_record, not_adopted,
                     print_warnings, progress_line, read_input_image, save_calibration, uncertainty_line, write_png,
                     write_report)


def add_parser(subparsers):
    refine = subparsers.add_parser('refine', epilog=EXIT_STATUSES,
                                   help='the spec sheet plus straight lines in ordinary images of the camera')
    refine.add_argument('images', nargs='+', help='images of the camera (one size): rooms, streets, corridors; '
                        f'at most {IMAGE_BUDGET} each; an image given twice (same file or same content) counts once')
    refine.add_argument('--hfov', type=number, help='horizontal field of view (deg)')
    refine.add_argument('--vfov', type=number, help='vertical field of view (deg)')
    refine.add_argument('--dfov', type=number, help='diagonal field of view (deg)')
    refine.add_argument('--preset', metavar='NAME', help='the FOVs of a published spec (`zeroshot-calib presets`)')
    add_circle_arguments(refine, refine=True)
    add_fov_tolerance_argument(refine)
    refine.add_argument('--balance', type=number, default=0.0,
                        help='rectified camera: 0 crops to valid pixels, 1 keeps every edge (default 0)')
    refine.add_argument('--fov-scale', type=number, default=1.0,
                        help='rectified camera: divides its focal length (default 1)')
    refine.add_argument('--camera-name', default='camera', help='camera_name in the YAML file')
    refine.add_argument('--json', action='store_true', help='print one JSON object')
    refine.add_argument('--yaml', metavar='FILE', help='write a camera_info_manager calibration file')
    refine.add_argument('--debug-image', metavar='OUT.png',
                        help='write a contact sheet of every image with its curves: used (green), rejected (red), '
                             'left out for staying put (orange), with the verdict, and the first image rectified '
                             'before (zero-shot) and after')
    refine.add_argument('--report', metavar='OUT.png', help=REPORT_HELP.format(extra=' of the first image'))
    add_progress_argument(refine)
    refine.set_defaults(run=run)


REFINE_KEYS = ('accepted', 'reason', 'images_used', 'lines_used', 'line_residual_px_before',
               'line_residual_px_after', 'coverage', 'principal_point_shift_px', 'curves_bowed')


MIN_REFINE_IMAGE_SIDE = 32
"""Smaller images hold no line long enough to measure a lens by (and their camera would be refused
as implausible, without naming the image)."""


def run(args):
    from ..core.estimation.refine import circle_diameter_agrees, refine_from_images  # scipy: only when asked
    from ..core.lines.image_region import combine_circles, find_image_region
    if args.debug_image:
        check_output_image(args.debug_image, '--debug-image')
    check_fov('circle_fov', args.circle_fov)  # named before the images are read for its diameter
    images, names, seen = [], [], {}
    for path in args.images:
        key = os.path.realpath(path)
        if key in seen:
            print_warnings([f'{path} is given more than once: counted once'])
            continue
        image, digest = read_input_image(path, finite=True)
        if digest in seen.values():
            first = next(p for p, d in seen.items() if d == digest)
            print_warnings([f'{path} has the same content as {first}: counted once'])
            seen[key] = digest
            continue
        seen[key] = digest
        if min(image.shape[:2]) < MIN_REFINE_IMAGE_SIDE:
            raise CliError(f'{path} is {image.shape[1]}x{image.shape[0]}: allowed: images at least '
                           f'{MIN_REFINE_IMAGE_SIDE} px wide and high (lines to straighten need room)')
        images.append(image)
        names.append(path)
    sizes = sorted({(im.shape[1], im.shape[0]) for im in images})
    if len(sizes) != 1:
        listed = ', '.join(f'{w}x{h}' for w, h in sizes)
        raise CliError(f'the images have different sizes ({listed}): allowed: images of one camera, one size')
    images = [im if im.dtype == np.uint8 else cv2.convertScaleAbs(im, alpha=255.0 / max(1.0, float(im.max())))
              for im in images]
    (width, height), = sizes
    # the part of each image that shows the scene, and the image circle if one is seen
    regions = [find_image_region(im) for im in images]
    circle = combine_circles([r.circle for r in regions])
    measured_in = sum(r.circle is not None for r in regions)
    circle_warnings = []
    given_diameter = args.circle_diameter
    measure_diameter = args.circle_fov is not None and given_diameter is None and _preset_circle_diameter(args) is None
    if measure_diameter:
        if circle is None:
            raise CliError(f'--circle-fov {args.circle_fov:g} needs the image circle\'s diameter, and none was found in '
                           f'the image{"s" if len(images) > 1 else ""} (looked for a dark surround with a circular '
                           'boundary seen on opposite sides): give --circle-diameter PX')
        args.circle_diameter = round(circle.diameter, 2)
        if circle.edge_sigma_px > 0:
            # where the light ends and where it falls steepest part by a few px on a soft rim, and near
            # 180 degrees a few px of radius are a large share of f
            circle_warnings.append(
                f'the image circle\'s rim fades softly (+- {circle.edge_sigma_px:.1f} px of radius from the fade '
                f'alone): the diameter measured, {circle.diameter:.1f} px, is where its light falls steepest, and '
                f'--circle-fov {args.circle_fov:g} puts the scale there; a spec sheet\'s circle may be where the light '
                'ends, a few px wider (on two real circular fisheyes 3-4 % of the radius, which moved f by 11-12 %): '
                'give --circle-diameter when the sheet states it')
    spec = _refine_spec(args, width, height)
    if circle is not None and spec.circle_diameter is not None and given_diameter is not None \
            and not circle_diameter_agrees(spec.circle_diameter, circle):
        circle_warnings.append(
            f'--circle-diameter {spec.circle_diameter:g} px differs from the image circle measured in the images: '
            f'{circle.diameter:.1f} +- {2 * circle.radius_uncertainty_px:.1f} px ({measured_in} of {len(images)} images); '
            'the given diameter is used, the measured centre only as the principal point: check --circle-diameter, '
            'or leave it out to use the measured diameter')
    solution = solve_zero_shot(spec, 'auto', fov_tolerance=args.fov_tolerance)
    progress = progress_line(args, 'refine')
    # the images are detected in worker processes, one per core (the same curves, in the same order)
    try:
        result = refine_from_images(spec, images, args.fov_tolerance, workers=os.cpu_count() or 1, regions=regions,
                                    solution=solution, image_names=names,
                                    progress=None if progress is None else
                                    (lambda report: progress(_refine_progress_text(report))))
    finally:
        if progress is not None:
            progress.close()
    summary, calibration = _refined_summary(result, spec, solution, args)
    summary['image_circle'] = None if circle is None else {
        'cx': circle.cx, 'cy': circle.cy, 'diameter': circle.diameter,
        'centre_sigma_px': circle.centre_sigma_px, 'diameter_sigma_px': 2 * circle.radius_uncertainty_px,
        'measured_from': measured_in, 'images': len(images),
        'diameter_used': 'measured' if measure_diameter else ('given' if spec.circle_diameter is not None else None)}
    # the spec's FOVs against the zero-shot camera, and against the image circle seen
    warnings = list(solution.warnings) + circle_warnings + list(result.spec_warnings)
    if not result.accepted:  # zero-shot returned: solve's warnings on its fit and on the lens shape it assumed
        warnings += fit_warnings(solution, calibration, DISTORTION_FITS['equidistant'](solution.camera))
        warnings += assumption_warnings(solution)
    summary['uncertainty_px'] = result.uncertainty_px if result.accepted else result.zero_shot_uncertainty_px
    # every key of `solve --json` whatever the verdict (a client reads them without asking which):
    # the error bar's how, its lens-shape part and what it is over, of the camera returned; no
    # assumption when the lines fitted the lens's shape
    summary.update(error_bar_keys(result.uncertainty, result.uncertainty.circle_radius is not None))
    if result.accepted:
        summary['assumption'] = None
    summary['refinement'] = json_safe({k: getattr(result, k) for k in REFINE_KEYS})
    summary['refinement']['curves_static'] = len(result.static_curves)
    if getattr(result, 'zero_shot_uncertainty', None) is not None and result.zero_shot_uncertainty.warning \
            and not result.accepted:
        warnings.append(result.zero_shot_uncertainty.warning)
    summary['warning'] = warnings
    canvas = _debug_image(images, names, result, solution, args) if args.debug_image else None
    report = None
    if args.report:
        from ..core.report.calibration_report import ReportData
        report = ReportData('refine', result.camera, summary['model'], result.accepted, result.reason, spec,
                            args.fov_tolerance, result.uncertainty, summary['uncertainty_px'],
                            getattr(result.uncertainty, 'reason', ''), result.zero_shot_camera, images[0],
                            os.path.basename(names[0]), args.balance, args.fov_scale, warnings=warnings,
                            camera_name=args.camera_name,
                            rectified=principal_point_camera_matrix if result.accepted else new_camera_matrix)
    refused = None if result.accepted else not_adopted('not refined', result.reason, args.yaml)
    if args.yaml:  # written only now: every step has succeeded
        save_calibration(calibration, args.yaml, [refused[0]] if refused else ())
    written = [f'--yaml {args.yaml}'] if args.yaml else []
    if canvas is not None:
        write_png(args.debug_image, canvas, '--debug-image', written)
        written.append(f'--debug-image {args.debug_image}')
    write_report(args, report, written)
    if args.json:
        print(json.dumps(summary))
    else:
        print(summary_text(summary) + '\n' + uncertainty_line(summary, args.fov_tolerance))
        print(_image_circle_line(summary['image_circle']))
        if result.static_curves:
            # a still camera with much moving in front of it (a board, people) looks the same: say how
            # to keep its lines
            print(f'left out  {len(result.static_curves)} curves at the same pixels in the images while the rest '
                  "moved: taken for the vehicle's or robot's own body or lens dirt (a camera that stood still "
                  'while things moved in front of it: give one image, whose lines are all kept)')
        if result.curves_bowed:
            print(f'left out  {result.curves_bowed} curves bowing toward the image centre (a bonnet, a body\'s edge): '
                  'this lens bows straight lines the other way')
        print(f"refined   {'yes' if result.accepted else 'no'}: {result.reason}")
        if args.yaml:
            print(f'wrote {args.yaml}')
        if canvas is not None:
            print(f'wrote {args.debug_image}')
        if args.report:
            print(f'wrote {args.report}')
    print_warnings(warnings)
    if refused:
        print(refused[1], file=sys.stderr, flush=True)
        return EXIT_NOT_ADOPTED
    return 0


def _refine_spec(args, width, height):
    """The spec of `refine`: the images' size, the FOVs of the flags / --preset (whose size, if it
    has one, must be the images' or of their aspect ratio: a crop is another camera)."""
    if args.preset:
        preset_spec = spec_with_preset(args.preset)
        if preset_spec.width * height != preset_spec.height * width:
            raise CliError(f'the images are {width}x{height} but --preset {args.preset} is for '
                           f'{preset_spec.width}x{preset_spec.height}: allowed: the same aspect ratio')
    fields = {k: getattr(args, k) for k in ('hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov')}
    if not args.preset and all(v is None for v in fields.values()):
        raise CliError('refine needs the spec sheet: --hfov / --vfov / --dfov, --circle-diameter with '
                       '--circle-fov, or --preset NAME')
    return spec_with_preset(args.preset, width=width, height=height, **fields)


def _refined_summary(result, spec, solution, args):
    """`solve --json`'s record of the camera ``refine`` gives (the refined one, or zero-shot's)."""
    if not result.accepted:
        calibration, fit = CameraCalibration.from_solution(solution, 'equidistant', args.balance, args.fov_scale,
                                                           args.camera_name)
        summary = solution_summary(solution, calibration, fit)
        return summary, calibration
    # P as calibrate writes it: the refined camera is not centred in its image (output.py)
    summary, calibration = kannala_brandt_record(result.camera, spec, 'refined (Kannala-Brandt)', args,
                                                  root_found=solution.root_found,
                                                  rectified=principal_point_camera_matrix)
    return json_safe(summary), calibration


def _debug_image(images, names, result, solution, args):
    """The contact sheet of --debug-image (core/report/debug_sheet.py), written by the caller once
    everything has succeeded."""
    from ..core.report.debug_sheet import render_debug_sheet
    return render_debug_sheet(images, names, result, solution.camera, args.balance, args.fov_scale).image


def _preset_circle_diameter(args):
    """The circle diameter of --preset, if it has one."""
    return spec_with_preset(args.preset).circle_diameter if args.preset else None


def _image_circle_line(circle) -> str:
    """The text output's line on the image circle measured in the images."""
    if circle is None:
        return 'circle    none seen in the images'
    used = {'measured': ' (used as the spec\'s circle diameter)', 'given': ''}.get(circle['diameter_used'], '')
    return (f"circle    diameter {circle['diameter']:.1f} px +- {circle['diameter_sigma_px']:.2g}{used}, centre "
            f"({circle['cx']:.1f}, {circle['cy']:.1f}) +- {circle['centre_sigma_px']:.2g} px, measured in "
            f"{circle['measured_from']} of {circle['images']} image{'s' if circle['images'] > 1 else ''}")


def _refine_progress_text(p) -> str:
    """``refine``'s progress report (core/estimation/refine.py) as the text of its progress line."""
    camera = p.camera
    estimate = f'f {camera.fx:.1f} px, principal point ({camera.cx:.1f}, {camera.cy:.1f})'
    if p.stage == 'detection':
        return (f'round {p.round}/{p.rounds}: {p.frames_done}/{p.frames} images, {p.lines} lines found; '
                f'looking with {estimate}')
    # not "accepted": a later round may return another fit, and the verdict comes with the result
    return (f'round {p.round}/{p.rounds}: fitted {p.lines} lines: {estimate} '
            f'({"passes" if p.accepted else "fails"} the gate)')
