"""Do a spec's FOVs fit its image? The FOVs given, compared with those of the camera solved from them.

A zero-shot camera reproduces the FOVs it is solved from (the pair of eq. 27: hfov + vfov, or dfov
with one of them; a single FOV) exactly, except in one case: the pair has no barrel root, i.e. the
narrower FOV is too wide for its side of the image (pincushion distortion, which the model cannot
represent). Then w* = 0, f is the mean of the two perspective focals, and the camera misses both
FOVs, by about half the contradiction. A FOV beside the pair (dfov beside hfov + vfov, which only
chooses the projection) is met as closely as the projections allow. FOVs in the wrong order
(hfov > vfov on a portrait image: width and height, or hfov and vfov, swapped) are refused before
solving (``CameraSpec``); here are the ones a camera can be solved from, but that it does not show.

``fov_warnings(solution, tolerance)``: one line per kind of miss,

- a FOV the camera is solved from, missed by more than ``tolerance`` (default
  ``spec.FOV_TOLERANCE_DEG``, 1 degree; the CLI's ``--fov-tolerance``);
- a FOV beside them, missed by more than ``max(tolerance, EXTRA_FOV_WARNING_DEG)``.

Why these thresholds (benchmarks/spec_consistency.py, results in
benchmarks/results/spec_consistency.md):

- Rounding. A spec sheet prints whole degrees (+-0.5). Distortion-free and barrel-distorted
  cameras (equidistant w from 0 to 0.9 of the value that puts the image corner 90 degrees
  off-axis, hfov 20 to 170 degrees, nine image sizes from 672x376 to 4608x2592), hfov and vfov
  each moved by -0.5, 0 or +0.5 degree in all nine combinations (11,657 specs): the solved camera
  misses a given FOV by at most 0.82 degree (a 170-degree pinhole; 0.59 at the 99th percentile).
  So 1 degree never warns about a sheet's rounding.
- Real lenses. The 4,626 usable calibrations of ../shared/data/lens_profiles_dev.csv, their
  implied FOVs rounded to whole degrees as the spec: hfov + vfov are missed by more than 1 degree
  for 81 (1.8 %; 70 with the exact FOVs: lenses with fx != fy or digitally corrected images,
  whose FOVs the square-pixel model does miss); the diagonal beside them by more than 1 degree
  for 26 %, 5 degrees 2.9 %, 15 degrees 1.3 %. A sheet's diagonal is the least reliable of the
  three (often quoted for another mode, or the lens's image circle) and here it only chooses the
  projection, so only a miss beyond 15 degrees is warned about (the published Raspberry Pi Camera
  Module 3 Wide, 102 x 67 x 120 degrees, is missed by 9.1; the Luxonis OAK-D LR, 82 x 56 x 100,
  by 7.8).
"""
from __future__ import annotations

import math
from typing import List

import numpy as np

from .spec import FOV_TOLERANCE_DEG, SpecError
from .wide_solver import Constraint, _primary_pair, spec_constraints

EXTRA_FOV_WARNING_DEG = 15.0
"""A FOV beside those the camera is solved from is warned about when missed by more (degrees)."""


def check_fov_tolerance(tolerance) -> float:
    """``tolerance`` as a float, or SpecError naming the allowed range."""
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or \
            not math.isfinite(tolerance) or tolerance <= 0:
        raise SpecError('fov_tolerance', tolerance, 'degrees, greater than 0 (finite)')
    return float(tolerance)


def fitted_and_extra(spec) -> tuple:
    """(constraints the camera is solved from, constraints beside them), as the solvers choose
    them: the first two of circle, hfov, vfov, dfov with different radii (one if there is no
    second), after FOVs of equal radius and angle (hfov and vfov of a square image) are merged."""
    constraints = spec_constraints(spec)
    constraints = [c for i, c in enumerate(constraints)
                   if not any(d.radius == c.radius and d.fov == c.fov for d in constraints[:i])]
    if not constraints:
        return [], []
    pair = list(_primary_pair(constraints))
    return pair, [c for c in constraints if c not in pair]


def predicted_fov(camera, constraint: Constraint) -> float:
    """The camera's FOV across ``constraint``'s extent (degrees; NaN where an edge pixel has no ray)."""
    if constraint.name in ('hfov', 'vfov', 'dfov'):
        return float(camera.fields_of_view()[constraint.name])
    # the image circle: twice the off-axis angle of a pixel on it
    ray = camera.unproject(np.array([[camera.cx + constraint.radius, camera.cy]], dtype=float))[0]
    return 2.0 * math.degrees(math.atan2(math.hypot(ray[0], ray[1]), ray[2]))


def _constraint_field(c: Constraint) -> str:
    return 'circle_fov' if c.name == 'circle' else c.name


def _misses(camera, constraints, limit) -> list:
    out = []
    for c in constraints:
        got = predicted_fov(camera, c)
        if not (abs(got - c.fov) <= limit):  # NaN (no ray at that edge) is a miss too
            has = f'{got:.1f} deg' if math.isfinite(got) else 'no ray at that edge'
            out.append((c, f'{_constraint_field(c)}: given {c.fov:g} deg, the solved camera has {has}'))
    return out


def _pincushion_text(spec, pair) -> str:
    """Why a pair without a barrel root is missed, with the bound the model can meet."""
    outer, inner = sorted(pair, key=lambda c: -c.radius)
    if max(outer.fov, inner.fov) >= 180.0:
        return ''
    bound = 2.0 * math.degrees(math.atan(math.tan(outer.half_angle) * inner.radius / outer.radius))
    return (f'; beside {_constraint_field(outer)} {outer.fov:g} deg, a lens without pincushion distortion (all the model '
            f'represents) has {_constraint_field(inner)} at most {bound:.1f} deg at {spec.width}x{spec.height}')


def fov_warnings(solution, tolerance: float = FOV_TOLERANCE_DEG) -> List[str]:
    """One-line warnings when ``solution``'s camera misses the FOVs of its spec (module
    docstring); [] when it shows them within the tolerance."""
    tolerance = check_fov_tolerance(tolerance)
    spec, camera = solution.spec, solution.camera
    fitted, extra = fitted_and_extra(spec)
    warnings = []
    missed = _misses(camera, fitted, tolerance)
    if missed:
        why = _pincushion_text(spec, fitted) if len(fitted) == 2 and not solution.root_found else ''
        warnings.append(
            f'the FOVs do not fit a {spec.width}x{spec.height} image: '
            + '; '.join(text for _, text in missed) + f' (tolerance {tolerance:g} deg){why}; check the FOVs, and '
            'that they are for this resolution (another mode or crop of the sensor has other FOVs)')
    extra_limit = max(tolerance, EXTRA_FOV_WARNING_DEG)
    missed = _misses(camera, extra, extra_limit)
    if missed:
        used = ' and '.join(_constraint_field(c) for c in fitted)
        warnings.append(
            '; '.join(text for _, text in missed) + f' (more than {extra_limit:g} deg apart; solved from '
            f'{used}, the rest only chooses the projection): the FOVs do not describe one lens; check '
            'them (a diagonal is sometimes quoted for another mode, or for the image circle)')
    return warnings
