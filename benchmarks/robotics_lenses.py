#!/usr/bin/env python3
"""Zero-shot from a spec sheet against real robotics cameras' published calibrations.

The cameras of ``benchmarks/data/robotics_lenses.csv`` (camera 0 of twelve rigs: EuRoC's and
two other MT9V034 cameras, RealSense D435i / D455 / T265, TUM VI, UZH-FPV, KITTI and others, read
from the configuration files of two VIO repositories; the csv's header says where). Per camera,
its FOVs (``fields_of_view_through_axis`` of the calibration, rounded to 0.1 degree as a sheet
prints them) given as specs: each FOV alone (hfov, vfov, dfov: the lens shape is then the lens
prior's, built from action, drone and phone cameras) and all three. For each: zero-shot's error
against the calibration (the lens benchmark's metric, ``lens_profiles.best_rotation_rms``: RMS
px over a 33 x 19 grid after the best rotation, at 1920 px wide) and its stated error bar
(``zero_shot_uncertainty``, FOV tolerance 1 degree); "honest" when the error is at most twice
the bar (``lens_profiles``' criterion).

The calibrations are the truth: equidistant rows are Kannala-Brandt cameras as they are; radtan
rows (k1, k2; p1, p2 tangential, which a radial model cannot hold and which are below 2e-3 here)
are their radial part refitted as Kannala-Brandt k1..k4 over the angles their image spans (the
fit's largest radius error is reported).

    .venv/bin/python benchmarks/robotics_lenses.py [--out benchmarks/results/robotics_lenses.md]
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / 'benchmarks'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

import lens_profiles as lp  # noqa: E402
from zeroshot_calib_ros.core.estimation.uncertainty import zero_shot_uncertainty  # noqa: E402
from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.solver import solve_zero_shot  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec  # noqa: E402

TABLE = ROOT / 'benchmarks' / 'data' / 'robotics_lenses.csv'
SPECS = (('hfov',), ('vfov',), ('dfov',), ('hfov', 'vfov', 'dfov'))
HONEST = 2.0
"""An error bar is honest when the error is at most this many times it (as benchmarks/lens_profiles.py)."""


def load(table: Path = TABLE):
    """[(row, truth camera, largest radius error of a radtan refit in px or 0.0)] of the csv."""
    lines = [line for line in table.read_text().splitlines() if not line.startswith('#')]
    out = []
    for row in csv.DictReader(lines):
        w, h = int(row['width']), int(row['height'])
        fx, fy, cx, cy = (float(row[k]) for k in ('fx', 'fy', 'cx', 'cy'))
        d = np.array([float(row[f'd{i}']) for i in range(4)])
        if row['model'] == 'equidistant':
            out.append((row, lp.GroundTruthCamera(fx, fy, cx, cy, w, h, d), 0.0))
            continue
        k, misfit = radtan_as_kannala_brandt(d[0], d[1], max(math.hypot((x - cx) / fx, (y - cy) / fy)
                                                            for x in (0, w) for y in (0, h)))
        out.append((row, lp.GroundTruthCamera(fx, fy, cx, cy, w, h, k), misfit * max(fx, fy)))
    return out


def radtan_as_kannala_brandt(k1: float, k2: float, corner: float, samples: int = 400):
    """(k1..k4, largest error in normalised radius): the radial distortion r_d = r (1 + k1 r^2 +
    k2 r^4), r = tan(theta), as theta_d = theta (1 + k1' theta^2 + ... + k4' theta^8) by least
    squares over the angles up to 2 % past the one whose distorted radius is ``corner`` (the image
    corner's normalised radius)."""
    r = np.linspace(0.0, 3.0, 30001)
    rd = r * (1 + k1 * r ** 2 + k2 * r ** 4)
    stop = np.nonzero(np.diff(rd) <= 0)[0]
    top = stop[0] if stop.size else len(r) - 1
    theta = np.linspace(1e-4, 1.02 * math.atan(float(np.interp(corner, rd[:top], r[:top]))), samples)
    t = np.tan(theta)
    theta_d = t * (1 + k1 * t ** 2 + k2 * t ** 4)
    basis = np.stack([theta ** (2 * j + 1) for j in range(1, 5)], axis=1)
    k = np.linalg.lstsq(basis, theta_d - theta, rcond=None)[0]
    return k, float(np.max(np.abs(theta + basis @ k - theta_d)))


def run_camera(row, truth) -> dict:
    fovs = fields_of_view_through_axis(truth)
    pixels = lp.pixel_grid(truth.width, truth.height)
    rays = truth.unproject(pixels)
    seen = np.all(np.isfinite(rays), axis=1)
    scale = lp.REFERENCE_WIDTH / truth.width
    out = {'fovs': fovs}
    for names in SPECS:
        spec = CameraSpec(truth.width, truth.height, **{k: round(fovs[k], 1) for k in names})
        solution = solve_zero_shot(spec)
        bar = zero_shot_uncertainty(spec, 1.0, solution).rms_px
        error = lp.best_rotation_rms(solution.camera, rays[seen], pixels[seen])[0] * scale
        out['+'.join(names)] = (error, None if bar is None else bar * scale)
    return out


def report(runs, command: str, seconds: float) -> str:
    lines = ['## Zero-shot from the spec sheet against robotics cameras\' published calibrations', '',
             f'`{command}` ({seconds:.0f} s).', '',
             'Error and stated error bar (1 sigma), RMS px at 1920 px wide over the image after the best rotation; '
             f'"x bar": error over bar (honest: at most {HONEST:g}).', '',
             '| camera | size | model | hfov / vfov / dfov | ' +
             ' | '.join(f'{"+".join(n)}: error, bar, x bar' for n in SPECS) + ' |',
             '|---|---|---|---|' + '---:|' * len(SPECS)]
    for row, misfit, out in runs:
        f = out['fovs']
        cells = []
        for names in SPECS:
            error, bar = out['+'.join(names)]
            cells.append(f'{error:.1f}, {bar:.1f}, {error / bar:.1f}' if bar else f'{error:.1f}, -, -')
        model = row['model'] + (f' (KB refit {misfit:.2f} px)' if misfit else '')
        lines.append(f"| {row['name']} ({row['camera']}) | {row['width']}x{row['height']} | {model} | "
                     f"{f['hfov']:.1f} / {f['vfov']:.1f} / {f['dfov']:.1f} | " + ' | '.join(cells) + ' |')
    lines.append('')
    for names in SPECS:
        key = '+'.join(names)
        pairs = [out[key] for _, _, out in runs if out[key][1]]
        honest = sum(e <= HONEST * b for e, b in pairs)
        lines.append(f'- {key}: honest on {honest} of {len(pairs)} cameras; median error '
                     f'{np.median([e for e, _ in pairs]):.1f} px')
    return '\n'.join(lines) + '\n'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--out', help='write the report here too')
    args = parser.parse_args(argv)
    command = 'benchmarks/robotics_lenses.py ' + ' '.join(argv if argv is not None else sys.argv[1:])
    start = time.perf_counter()
    runs = [(row, misfit, run_camera(row, truth)) for row, truth, misfit in load()]
    text = report(runs, command.strip(), time.perf_counter() - start)
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
