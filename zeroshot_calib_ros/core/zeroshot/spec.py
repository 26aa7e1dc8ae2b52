"""What a camera's spec sheet says: resolution and fields of view, validated."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

MAX_IMAGE_SIDE = 100_000
"""Largest accepted image side in pixels (well above any sensor; catches typos like 19200)."""

VALUE_TEXT_CHARS = 80
"""Longest text of a rejected value in an error message (a longer one is cut, its length said)."""


def value_text(value, limit: int = VALUE_TEXT_CHARS) -> str:
    """``repr(value)``, cut to ``limit`` characters with '... (N characters)' when longer: a
    rejected value goes into log lines and service replies, and a 1 MB string must not."""
    text = repr(value)
    if len(text) <= limit:
        return text
    size = len(value) if isinstance(value, str) else len(text)
    return f'{text[:limit]}... ({size} characters)'


MAX_FOV_DEG = 360.0
"""A spec FOV is an angle across the image; models narrow this further (see projections)."""
MIN_FOV_DEG = 0.01
"""The narrowest spec FOV: a telescope's is a tenth of a degree. Below it the focal length leaves
every range a calibration file allows (1e-320 degrees overflowed it to infinity)."""

FOV_TOLERANCE_DEG = 1.0
"""Default standard deviation of a spec FOV (degrees): a spec sheet's rounding and its
unit-to-unit spread. The uncertainty, the refinement and the consistency warnings
(``consistency.py``) use it."""


class SpecError(ValueError):
    """A camera specification value is invalid.

    ``field`` names the offending input (``hfov``, ``width``, ...), ``value`` is what was given
    and ``allowed`` describes the accepted range, so callers (CLI, ROS node) can report it in one
    line.
    """

    def __init__(self, field: str, value, allowed: str, reason: str = '', missing: bool = False):
        self.field = field
        self.value = value
        self.allowed = allowed
        self.reason = reason
        detail = f'{reason}; ' if reason else ''
        if missing:  # a value the input lacks: "= None" would read as one given
            super().__init__(f'{field} is not given: {detail}allowed: {allowed}')
        else:
            super().__init__(f'{field} = {value_text(value)} is invalid: {detail}allowed: {allowed}')


def _check_side(field: str, value) -> int:
    allowed = f'an integer from 1 to {MAX_IMAGE_SIDE} (pixels)'
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpecError(field, value, allowed, 'not a number')
    if isinstance(value, float):
        if not math.isfinite(value) or value != int(value):
            raise SpecError(field, value, allowed, 'not a whole number')
        value = int(value)
    if not 1 <= value <= MAX_IMAGE_SIDE:
        raise SpecError(field, value, allowed)
    return int(value)


def check_fov(field: str, value) -> Optional[float]:
    """``value`` as degrees (None: not given), or SpecError naming ``field`` and the allowed range."""
    if value is None:
        return None
    allowed = f'degrees, at least {MIN_FOV_DEG:g} and less than {MAX_FOV_DEG:g}, or not given'
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpecError(field, value, allowed, 'not a number')
    value = float(value)
    if not math.isfinite(value) or not MIN_FOV_DEG <= value < MAX_FOV_DEG:
        raise SpecError(field, value, allowed)
    return value


def _check_circle_diameter(value) -> Optional[float]:
    if value is None:
        return None
    allowed = f'pixels, greater than 0 and at most {2 * MAX_IMAGE_SIDE}, or not given'
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpecError('circle_diameter', value, allowed, 'not a number')
    value = float(value)
    if not math.isfinite(value) or not 0.0 < value <= 2 * MAX_IMAGE_SIDE:
        raise SpecError('circle_diameter', value, allowed)
    return value


def _check_not_swapped(spec: 'CameraSpec'):
    """SpecError when the wider of hfov and vfov spans the shorter side of the image: no radially
    symmetric lens does that (its angle grows with the distance from the centre), and a spec
    sheet's rounding cannot turn the order round (equal is possible, so equal passes). Width and
    height swapped, or hfov and vfov, is what gives it; which of the two is guessed from the
    orientation (spec sheets quote landscape FOVs, hfov > vfov), and the message names both."""
    w, h, hfov, vfov = spec.width, spec.height, spec.hfov, spec.vfov
    if hfov is None or vfov is None or w == h or (hfov > vfov) == (w > h) or hfov == vfov:
        return
    if w < h:  # a portrait size with landscape FOVs: the size is the likelier slip
        raise SpecError('width, height', f'{w}x{h}', f'{h}x{w}, or vfov greater than hfov for a {w}x{h} image',
                        f'width and height look swapped: hfov {hfov:g} > vfov {vfov:g} degrees needs the wider '
                        f'side horizontal (a lens sees the wider angle across the longer side), and {w}x{h} is '
                        'taller than wide (for a camera turned 90 degrees, swap hfov and vfov instead)')
    raise SpecError('vfov', vfov, f'less than hfov = {hfov:g} degrees on a {w}x{h} image',
                    f'hfov and vfov look swapped: vfov {vfov:g} > hfov {hfov:g} degrees needs the taller side '
                    f'vertical (a lens sees the wider angle across the longer side), and {w}x{h} is wider '
                    'than tall (for a portrait image, swap width and height instead)')


@dataclass(frozen=True)
class CameraSpec:
    """Image size in pixels and the spec-sheet fields of view in degrees.

    Accepted combinations: any non-empty subset of ``hfov``, ``vfov``, ``dfov`` (the paper uses
    hfov + vfov; hfov alone is the perspective-only case of its C905 row). The FOVs are angles
    between the rays of opposite image edges (hfov), top and bottom (vfov) or opposite corners
    (dfov), through the image centre.

    Circular-fisheye form (optional, both or neither): ``circle_diameter`` (pixels) of the image
    circle, centred on the image, and ``circle_fov`` (degrees) seen across it. It may stand
    alone or beside the FOVs; only the wide model (``projection='wide'``, chosen by 'auto')
    uses it. ``given()`` lists hfov, vfov and dfov only.
    """

    width: int
    height: int
    hfov: Optional[float] = None
    vfov: Optional[float] = None
    dfov: Optional[float] = None
    circle_diameter: Optional[float] = None
    circle_fov: Optional[float] = None

    def __post_init__(self):
        object.__setattr__(self, 'width', _check_side('width', self.width))
        object.__setattr__(self, 'height', _check_side('height', self.height))
        for name in ('hfov', 'vfov', 'dfov'):
            object.__setattr__(self, name, check_fov(name, getattr(self, name)))
        object.__setattr__(self, 'circle_diameter', _check_circle_diameter(self.circle_diameter))
        object.__setattr__(self, 'circle_fov', check_fov('circle_fov', self.circle_fov))
        if (self.circle_diameter is None) != (self.circle_fov is None):
            missing, given = (('circle_fov', 'circle_diameter') if self.circle_fov is None
                              else ('circle_diameter', 'circle_fov'))
            raise SpecError(missing, None, f'a value beside {given}',
                            'the circular-fisheye form needs both the circle diameter and its FOV', missing=True)
        if self.hfov is None and self.vfov is None and self.dfov is None and self.circle_fov is None:
            raise SpecError('hfov', None, 'at least one of hfov, vfov, dfov (or circle_diameter with '
                            'circle_fov)', 'no field of view given')
        # The diagonal is the longest extent: its FOV must exceed the other two for any
        # radially symmetric lens whose FOV grows with the distance from the centre.
        for name in ('hfov', 'vfov'):
            other = getattr(self, name)
            if self.dfov is not None and other is not None and self.dfov <= other:
                raise SpecError('dfov', self.dfov, f'greater than {name} = {other:g} degrees',
                                'the diagonal field of view must be the widest')
        if self.width == self.height and self.hfov is not None and self.vfov is not None \
                and self.hfov != self.vfov:
            raise SpecError('vfov', self.vfov, f'equal to hfov = {self.hfov:g} degrees on a square image',
                            'a square image with square pixels has equal horizontal and vertical FOV')
        _check_not_swapped(self)

    @property
    def diagonal(self) -> float:
        """Image diagonal in pixels."""
        return math.hypot(self.width, self.height)

    def given(self) -> dict:
        """The FOVs that were given, as {name: degrees}."""
        return {n: getattr(self, n) for n in ('hfov', 'vfov', 'dfov') if getattr(self, n) is not None}

    def half_extents(self) -> dict:
        """Distance in pixels from the image centre to the edge each FOV spans."""
        return {'hfov': self.width / 2.0, 'vfov': self.height / 2.0, 'dfov': self.diagonal / 2.0}
