"""The lens-law prior: the shape of real lenses of a given FOV, for a spec sheet with one FOV.

One FOV fixes one point of the lens curve (the angle at one radius) and nothing else: a
rectilinear lens and a fisheye of the same hfov differ by a factor of two in focal length. What
fixes the rest is what real lenses of that FOV look like. The table
``zeroshot_calib_ros/data/lens_prior.csv`` (built by ``benchmarks/build_lens_prior.py`` from
real Kannala-Brandt calibrations, the gyroflow lens_profiles collection, CC0 1.0; its header
says how) gives, for the FOV across the long side, the short side or the diagonal, at a few
aspect ratios and every 2.5 degrees of FOV:

* ``a``: the solver's lens law (the equidistant law continued in angle space,
  r = f rho(psi(theta, a)) / a, ``core/lens/wide_fov.py``; a -> 0 is a pinhole, a = 1 the pure
  fisheye law) of the typical lens of that FOV;
* ``a_low`` / ``a_high``: the 16th / 84th percentiles of the lenses' own a: the spread the
  spec leaves open, which the error bar (``core/estimation/uncertainty.py``) carries, up to at
  least the fisheye law (``LensShape.spread``: robotics lenses are few in the table);
* ``lenses``: how many real lenses weigh in.

Between nodes the table is interpolated (linearly in FOV and log aspect, log a); past its ends
it keeps the end values, so the prior is continuous in the FOV, through 180 degrees too. The
FOV across the long side says the same of a lens whatever the crop, so its rows hold for any
aspect ratio (empty ``aspect``).

A law other than the table's (a forced ``projection``) gets the a whose camera, through the
same FOV, follows the table's camera most closely over the image (``matched_a``).
"""
from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from typing import Dict, List, Optional, Tuple

import numpy as np

from ..lens.projections import PROJECTIONS, FisheyeProjection
from ..lens.wide_fov import psi

PACKAGE = 'zeroshot_calib_ros'
LENS_PRIOR_FILE = ('data', 'lens_prior.csv')
"""Path of the table inside the package."""

TABLE_LAW = 'equidistant'
"""The law the table's a belongs to."""

SIDES = ('long_side', 'short_side', 'diagonal')
COLUMNS = ('side', 'aspect', 'fov_deg', 'lenses', 'a', 'a_low', 'a_high')
_TOTAL = re.compile(r'^#.*?:\s*([\d,]+) lenses\.?\s*$')


class LensPriorError(ValueError):
    """The lens-prior table is malformed (names the line and why)."""


def side_of(fov_name: str, width: int, height: int) -> str:
    """What a spec FOV spans: 'long_side', 'short_side' or 'diagonal' (a portrait image's hfov
    spans its short side; a square image's hfov and vfov both its long side, so that they give
    the same camera)."""
    if fov_name == 'dfov':
        return 'diagonal'
    if width == height:
        return 'long_side'
    across_width = fov_name == 'hfov'
    return 'long_side' if across_width == (width > height) else 'short_side'


@dataclass(frozen=True)
class LensShape:
    """The lens shape assumed for a spec with one FOV (module docstring)."""

    fov_name: str
    """The spec's FOV: 'hfov', 'vfov' or 'dfov'."""
    fov_deg: float
    side: str
    aspect: float
    """Long side over short side of the image."""
    a: float
    a_low: float
    a_high: float
    lenses: float
    """Real lenses that weigh in at this FOV (kernel weights; a few where the data is thin)."""
    total_lenses: int
    """Lenses the table was built from."""
    law: str = TABLE_LAW

    @property
    def spread(self) -> Tuple[float, float]:
        """The lens laws (a) at either end of the spread the error bar carries: the table's
        16th percentile, and its 84th or the fisheye law (``FISHEYE_LAW_A``), whichever is wider."""
        return self.a_low, max(self.a_high, FISHEYE_LAW_A)

    @property
    def assumption(self) -> str:
        """What was assumed, in words (the CLI prints it, the node logs it)."""
        if self.lenses >= FEW_LENSES:
            source = f'the {self.lenses:,.0f} real lenses of about that FOV among {self.total_lenses:,} calibrations'
        else:
            source = f'the nearest real lenses (few of {self.total_lenses:,} calibrations have that FOV)'
        return (f'one FOV ({self.fov_name} {self.fov_deg:g} deg): lens shape from {source}, law a = {self.a:.2f} (0: a pinhole, 1: the pure {self.law} law); '
                'give a second FOV or refine from images to pin it')


FISHEYE_LAW_A = 1.0
"""The error bar's spread of lens shapes reaches at least this law (a = 1: the equidistant
fisheye law; ``LensShape.spread``). The table's lenses are action, drone, phone and cinema
cameras; robotics cameras are few among them, and a small sensor behind an M12 fisheye-law lens
is common there: three of the four robotics cameras with an hfov of 90 to 93 degrees in
benchmarks/data/robotics_lenses.csv (EuRoC's MT9V034 and two others, a close to 1) lie far past
the table's 84th percentile (a = 0.42 at 93 degrees), and zero-shot from one of their FOVs was 58
to 91 px off at 1920, 3.1 to 4.6 times the error bar (benchmarks/robotics_lenses.py). With the
spread reaching a = 1, each of the twelve robotics cameras is within twice it for each one FOV;
on the lens benchmark's held-out lenses (benchmarks/lens_profiles.py), the narrow ones given
one FOV alone are within twice it 98 % of the time (hfov, vfov or dfov) instead of 96, 97 and
93 %, for error bars about twice as wide (the wide lenses' table mostly reaches a = 1 already:
93-95 % either way)."""

FEW_LENSES = 5.0
"""Fewer lenses than this near a FOV (past the widest of the data): the text says so."""


@dataclass(frozen=True)
class _SideTable:
    log_aspects: Tuple[float, ...]
    """Empty: the rows hold for any aspect."""
    fovs: np.ndarray
    values: Dict[str, np.ndarray]
    """Column -> (aspects or 1, fovs); a, a_low, a_high as logarithms."""

    def at(self, fov_deg: float, aspect: float) -> Dict[str, float]:
        per_aspect = {k: np.array([np.interp(fov_deg, self.fovs, row) for row in v]) for k, v in self.values.items()}
        if not self.log_aspects:
            return {k: float(v[0]) for k, v in per_aspect.items()}
        x = math.log(aspect)
        return {k: float(np.interp(x, self.log_aspects, v)) for k, v in per_aspect.items()}


@dataclass(frozen=True)
class LensPrior:
    tables: Dict[str, _SideTable]
    total_lenses: int

    def shape(self, fov_name: str, fov_deg: float, width: int, height: int, side: Optional[str] = None) -> LensShape:
        """The shape for ``fov_name`` of ``fov_deg`` degrees (``side``: what it spans, when not
        the spec FOV's own side: the circle form)."""
        side = side_of(fov_name, width, height) if side is None else side
        aspect = max(width, height) / min(width, height)
        v = self.tables[side].at(float(fov_deg), aspect)
        return LensShape(fov_name, float(fov_deg), side, aspect, math.exp(v['a']), math.exp(v['a_low']),
                         math.exp(v['a_high']), v['lenses'], self.total_lenses)


def parse_lens_prior(text: str, origin: str = LENS_PRIOR_FILE[-1]) -> LensPrior:
    """The table in the format above; LensPriorError naming the line of anything wrong."""
    total = None
    rows: List[Tuple[int, dict]] = []
    header = None
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        if line.startswith('#'):
            match = _TOTAL.match(line)
            if match:
                total = int(match.group(1).replace(',', ''))
            continue
        cells = next(csv.reader(io.StringIO(line)))
        if header is None:
            header = tuple(c.strip() for c in cells)
            if header != COLUMNS:
                raise LensPriorError(f'{origin}:{number}: header must be {",".join(COLUMNS)}')
            continue
        if len(cells) != len(COLUMNS):
            raise LensPriorError(f'{origin}:{number}: {len(cells)} cells, expected {len(COLUMNS)}')
        row = dict(zip(COLUMNS, (c.strip() for c in cells)))
        if row['side'] not in SIDES:
            raise LensPriorError(f'{origin}:{number}: side {row["side"]!r} is not one of {", ".join(SIDES)}')
        try:
            values = {k: float(row[k]) for k in COLUMNS[2:]}
            values['aspect'] = float(row['aspect']) if row['aspect'] else None
        except ValueError as exc:
            raise LensPriorError(f'{origin}:{number}: {exc}') from None
        if not all(math.isfinite(v) for k, v in values.items() if v is not None) or \
                min(values['a'], values['a_low'], values['a_high']) <= 0:
            raise LensPriorError(f'{origin}:{number}: a, a_low and a_high must be finite and positive')
        rows.append((number, dict(values, side=row['side'])))
    if total is None:
        raise LensPriorError(f'{origin}: no "...: N lenses" line in the header')
    tables = {}
    for side in SIDES:
        mine = [r for _, r in rows if r['side'] == side]
        if not mine:
            raise LensPriorError(f'{origin}: no rows for {side}')
        aspects = sorted({r['aspect'] for r in mine}, key=lambda a: -1.0 if a is None else a)
        if None in aspects and len(aspects) > 1:
            raise LensPriorError(f'{origin}: {side} mixes rows for any aspect with rows per aspect')
        fovs = sorted({r['fov_deg'] for r in mine})
        grid = {(r['aspect'], r['fov_deg']): r for r in mine}
        if len(grid) != len(mine) or len(grid) != len(aspects) * len(fovs):
            raise LensPriorError(f'{origin}: {side} rows are not one per aspect and FOV node')
        values = {k: np.array([[math.log(grid[(asp, fov)][k]) if k != 'lenses' else grid[(asp, fov)][k]
                                for fov in fovs] for asp in aspects]) for k in ('a', 'a_low', 'a_high', 'lenses')}
        log_aspects = () if aspects == [None] else tuple(math.log(a) for a in aspects)
        tables[side] = _SideTable(log_aspects, np.array(fovs), values)
    return LensPrior(tables, total)


@lru_cache(maxsize=1)
def packaged_lens_prior() -> LensPrior:
    resource = resources.files(PACKAGE).joinpath(*LENS_PRIOR_FILE)
    return parse_lens_prior(resource.read_text(encoding='utf-8'), '/'.join(LENS_PRIOR_FILE))


def lens_shape(fov_name: str, fov_deg: float, width: int, height: int) -> LensShape:
    """The lens shape the packaged table gives for one FOV of a ``width`` x ``height`` image."""
    return packaged_lens_prior().shape(fov_name, fov_deg, width, height)


def nearest_side(radius: float, width: int, height: int) -> str:
    """The side whose half extent is closest (in ratio) to ``radius`` px: what an image circle of
    that radius is most like."""
    extents = {'long_side': max(width, height) / 2.0, 'short_side': min(width, height) / 2.0,
               'diagonal': math.hypot(width, height) / 2.0}
    return min(SIDES, key=lambda side: abs(math.log(radius / extents[side])))


def law_theta_d(law: FisheyeProjection, theta, a):
    """theta_d(theta) = rho(psi(theta, a)) / a of ``law`` in angle space (wide_fov.py)."""
    with np.errstate(invalid='ignore', over='ignore'):
        return law.rho(psi(np.asarray(theta, dtype=float), a)) / a


def focal_through(law: FisheyeProjection, a: float, radius: float, half_angle: float) -> float:
    """f of the camera of ``law`` and ``a`` that puts ``half_angle`` (rad) at ``radius`` (px)."""
    return float(radius / law_theta_d(law, half_angle, a))


_MATCH_GRID = np.exp(np.linspace(math.log(1e-3), math.log(10.0), 601))


def corner_angle(a: float, radius: float, half_angle: float, corner_radius: float) -> float:
    """Off-axis angle (rad) at ``corner_radius`` px of the table law's camera of ``a`` through the
    FOV (``half_angle`` at ``radius``); pi where that camera has no ray."""
    theta_d = corner_radius / focal_through(PROJECTIONS[TABLE_LAW], a, radius, half_angle)
    p = a * theta_d  # the equidistant law: rho = psi
    return math.pi if p >= math.pi else math.atan2(math.sin(p), a * math.cos(p))


def a_for_law(shape: LensShape, law: FisheyeProjection, radius: float, half_angle: float,
              corner_radius: float, theta_cap: float = math.pi) -> float:
    """The a of ``law`` for ``shape``: the table's own a for the table's law, else the a whose
    camera through the FOV (``half_angle`` at ``radius``) follows the table's camera most closely
    out to the image corner (``matched_a``; angles capped at ``theta_cap``)."""
    if law.name == shape.law:
        return shape.a
    theta_max = min(corner_angle(shape.a, radius, half_angle, corner_radius), theta_cap)
    return matched_a(law, shape.a, radius, half_angle, theta_max)


def matched_a(law: FisheyeProjection, a_table: float, radius: float, half_angle: float, theta_max: float) -> float:
    """The a of ``law`` whose camera through the FOV (``half_angle`` at ``radius``) is closest
    to the table law's camera of ``a_table`` over [0, theta_max] (RMS of the radius; a grid of
    1.5 % steps, refined by a parabola)."""
    table_law = PROJECTIONS[TABLE_LAW]
    if law.name == TABLE_LAW:
        return float(a_table)
    theta = np.linspace(theta_max / 32, theta_max, 32)
    reference = focal_through(table_law, a_table, radius, half_angle) * law_theta_d(table_law, theta, a_table)
    a = _MATCH_GRID[:, None]
    with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
        radii = radius / law_theta_d(law, half_angle, a) * law_theta_d(law, theta[None, :], a)
        cost = np.sqrt(np.mean((radii - reference) ** 2, axis=1))
    cost = np.where(np.isfinite(cost), cost, np.inf)
    i = int(np.argmin(cost))
    if not math.isfinite(cost[i]):
        return float(a_table)
    if 0 < i < len(cost) - 1 and np.all(np.isfinite(cost[i - 1:i + 2])):
        c0, c1, c2 = cost[i - 1:i + 2]
        curvature = c0 - 2 * c1 + c2
        step = 0.5 * (c0 - c2) / curvature if curvature > 0 else 0.0
        log_step = math.log(_MATCH_GRID[1] / _MATCH_GRID[0])
        return float(math.exp(math.log(_MATCH_GRID[i]) + max(-1.0, min(1.0, step)) * log_step))
    return float(_MATCH_GRID[i])
