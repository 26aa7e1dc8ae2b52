"""Zero-shot fit of the wide-FOV model (``core/lens/wide_fov.py``) to a spec sheet.

Fitting. Every given FOV pins the half-angle at a radius: hfov at W/2, vfov at H/2, dfov at
D/2, and the circular-fisheye form (``CameraSpec.circle_diameter`` px, ``circle_fov`` deg) at
circle_diameter / 2; square pixels tie the focal length f. Two constraints (the first two of
circle, hfov, vfov, dfov with different radii: hfov + vfov for the paper's spec) fix a and f
exactly: a solves rho(psi(t_a; a)) / rho(psi(t_b; a)) = r_a / r_b (the paper's eq. 27 in angle
space; bracketed on a log grid of a and refined by Brent). With the circle alone the pure law
a = 1 is assumed (the usual circular-fisheye reading: f = r / rho(theta)); with one FOV
(``one_fov``) a is that of real lenses of that FOV (``lens_prior.py``). Further constraints
(dfov for an h+v spec) choose the law and, when the pair has several roots, the root: the one
whose predicted FOVs miss the extra constraints least. Without extra constraints the law is
equidistant (the paper's default; if it cannot meet the pair, whichever law can) and
the root is the one closest to the pure law a = 1. (With both angles of the pair below 90 degrees
there is at most one root; with both beyond, as for hfov + dfov of a square 200-degree image,
there can be two.) hfov and vfov of a square image are one constraint.

Why this family: on the 908 wide profiles (hfov >= 100 degrees) of ``benchmarks/lens_profiles.py``
(median RMS px at 1920 wide, measured while choosing the model) it is the paper's camera below 90
degrees (h+v: 4.65) and, with the law chosen by dfov, 4.46; the alternatives tried were worse
or no better: Kannala-Brandt theta (1 + k1 theta^2) from h+v 6.34, unified model (h+v) 4.60
with failures, extended unified model fitted exactly to h+v+d 4.58 (focal error p90 5.9 % vs
3.0 %), this family fitted to all three FOVs by least squares 4.84-5.40 (the diagonal FOV is the
least reliable of the three), pure laws tan(k theta)/k ... sin(k theta)/k 17.0.

"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from ..lens.projections import PROJECTIONS, FisheyeProjection
from .brent import brentq
from .lens_prior import LensShape, a_for_law, lens_shape
from ..lens.wide_fov import WIDE, WIDE_LAWS, WideFovCamera, WideProjection, psi, wide_projection
from .spec import CameraSpec, SpecError

WIDE_CHOICES = (WIDE,) + tuple(f'{WIDE}-{name}' for name in WIDE_LAWS)
"""'wide' (law chosen automatically) and 'wide-<law>' (law fixed)."""

CONSTRAINT_ORDER = ('circle', 'hfov', 'vfov', 'dfov')
"""Priority of the constraints that fix a and f exactly; the others choose law and root."""

_LOG_A_GRID = np.r_[np.linspace(math.log(1e-250), math.log(1e-7), 61)[:-1],
                    np.linspace(math.log(1e-7), math.log(1e7), 1401)]
"""log a where roots are bracketed: coarse towards the pinhole (one root there), fine around a = 1."""



@dataclass
class Constraint:
    name: str
    """'hfov', 'vfov', 'dfov' or 'circle' (the circle_fov of circle_diameter)."""
    radius: float
    """Pixels from the image centre."""
    fov: float
    """Degrees across the centre."""

    @property
    def half_angle(self) -> float:
        return math.radians(self.fov) / 2.0


def spec_constraints(spec: CameraSpec) -> List[Constraint]:
    """The spec's FOVs as (radius, angle) constraints, in ``CONSTRAINT_ORDER``."""
    out = []
    circle_diameter = getattr(spec, 'circle_diameter', None)
    if circle_diameter is not None:
        out.append(Constraint('circle', circle_diameter / 2.0, spec.circle_fov))
    extents = spec.half_extents()
    out += [Constraint(n, extents[n], v) for n, v in spec.given().items()]
    return out


def needs_wide_model(spec: CameraSpec) -> bool:
    """True when the paper's model cannot even be tried: a FOV of 180 degrees or more, or the
    circular-fisheye form. (Specs below 180 degrees whose image corners come out at 90 degrees
    or more are detected by the paper's solver, which then refuses them.)"""
    return getattr(spec, 'circle_diameter', None) is not None or any(v >= 180.0 for v in spec.given().values())


def _field(constraint: Constraint) -> str:
    return 'circle_fov' if constraint.name == 'circle' else constraint.name


def _check_monotonic(constraints: List[Constraint]):
    # either FOV of a pair out of order may be the typo: the error names the outer one and says
    # what the inner one would have to be
    ordered = sorted(constraints, key=lambda c: c.radius)
    for inner, outer in zip(ordered, ordered[1:]):
        if outer.radius > inner.radius and outer.fov <= inner.fov:
            raise SpecError(_field(outer), outer.fov,
                            f'more than {_field(inner)} = {inner.fov:g} degrees, or {_field(inner)} less than '
                            f'{outer.fov:g}',
                            f'{outer.name} spans {outer.radius:g} px from the centre, more than '
                            f'{inner.name} ({inner.radius:g} px), so a radially symmetric lens sees '
                            'a wider angle across it')
        if outer.radius == inner.radius and outer.fov != inner.fov:
            raise SpecError(_field(outer), outer.fov,
                            f'equal to {_field(inner)} = {inner.fov:g} degrees',
                            f'{outer.name} and {inner.name} span the same {inner.radius:g} px')


def _primary_pair(constraints: List[Constraint]) -> Tuple[Constraint, ...]:
    """The first constraint in CONSTRAINT_ORDER and the next one with another radius."""
    first = constraints[0]
    for other in constraints[1:]:
        if abs(other.radius - first.radius) > 1e-9 * first.radius:
            return first, other
    return (first,)


def _log_ratio(law, t_a, t_b, a):
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        return np.log(law.rho(psi(t_a, a))) - np.log(law.rho(psi(t_b, a)))


def pair_roots(law: FisheyeProjection, outer: Constraint, inner: Constraint) -> List[float]:
    """Every a > 0 at which the law puts both constraints' angles at their radii (same f).

    ``outer`` spans the larger radius. With both angles below 90 degrees there is at most one
    root (the paper's bracket argument); with both beyond 90 degrees there can be two."""
    t_a, t_b = outer.half_angle, inner.half_angle
    target = math.log(outer.radius / inner.radius)
    a_grid = np.exp(_LOG_A_GRID)
    j = _log_ratio(law, t_a, t_b, a_grid) - target
    roots = []
    finite = np.isfinite(j)
    for i in np.nonzero(finite[:-1] & finite[1:] & (np.sign(j[:-1]) != np.sign(j[1:])))[0]:
        if j[i] == 0.0:
            roots.append(float(a_grid[i]))
            continue
        u = brentq(lambda u: float(_log_ratio(law, t_a, t_b, math.exp(u))) - target,
                   _LOG_A_GRID[i], _LOG_A_GRID[i + 1], xtol=1e-15, rtol=4 * np.finfo(float).eps, maxiter=200)
        roots.append(math.exp(u))
    return roots


@dataclass
class WideFit:
    """A wide-FOV zero-shot solution (solve_zero_shot wraps it in a ZeroShotSolution)."""

    camera: WideFovCamera
    root_found: bool
    """False: one constraint only (pure law a = 1 assumed), or no barrel root below 90 degrees
    (pinhole limit, as the paper's Hero9(L) row)."""
    focal_estimates: Dict[str, float]
    """f implied by each constraint at the chosen a (equal for the primary pair at a root)."""
    residuals: Dict[str, Dict[str, float]] = field(default_factory=dict)
    """Per law ('wide-<law>'): predicted minus given FOV (degrees) of each constraint outside
    the primary pair."""
    lens_shape: Optional[LensShape] = None
    """One FOV with ``one_fov``: the shape of real lenses of that FOV that a was taken from."""


def _camera(spec, law, a, f):
    circle = getattr(spec, 'circle_diameter', None)
    return WideFovCamera(f, spec.width / 2.0, spec.height / 2.0, spec.width, spec.height,
                         a / f if a else 0.0, WideProjection(law),
                         None if circle is None else circle / 2.0)


def _predicted_fov(camera: WideFovCamera, radius: float) -> float:
    theta = float(camera.theta_from_theta_d(radius / camera.f))
    return 2.0 * math.degrees(theta)


def _pair_candidates(laws, outer: Constraint, inner: Constraint) -> list:
    """(law, a, f, root_found) of every root of every law for the pair."""
    candidates = []
    for lw in laws:
        roots = pair_roots(lw, outer, inner)
        if roots:
            candidates += [(lw, a, outer.radius * a / float(lw.rho(psi(outer.half_angle, a))), True)
                           for a in roots]
        elif max(outer.fov, inner.fov) < 180.0 and \
                math.tan(inner.half_angle) / math.tan(outer.half_angle) >= inner.radius / outer.radius:
            # No barrel root: the paper's w* = 0, f the mean perspective focal (Hero9(L)).
            f = 0.5 * sum(c.radius / math.tan(c.half_angle) for c in (outer, inner))
            candidates.append((lw, 0.0, f, False))
    return candidates


def solve_wide(spec: CameraSpec, law: Optional[str] = None, one_fov: bool = False) -> WideFit:
    """Zero-shot fit of the angle-space model to ``spec`` (module docstring).

    ``law``: None chooses (equidistant, or by the extra constraints when there are any); a law
    name or 'wide-<law>' fixes it. ``one_fov``: a spec of one FOV (hfov, vfov or dfov, no circle)
    takes a from real lenses of that FOV (``lens_prior.py``) instead of the pure law a = 1.
    Raises SpecError when no camera of the family meets the spec's primary constraints (or they
    contradict a radially symmetric lens)."""
    constraints = spec_constraints(spec)
    if not constraints:
        raise SpecError('hfov', None, 'at least one FOV or the circle form', 'no field of view given')
    _check_monotonic(constraints)
    # Equal radius and angle (hfov and vfov of a square image): one constraint, not two.
    constraints = [c for i, c in enumerate(constraints)
                   if not any(d.radius == c.radius and d.fov == c.fov for d in constraints[:i])]
    if law is not None:
        laws = [wide_projection(law).law]
    elif len(constraints) >= 3:
        laws = [PROJECTIONS[n] for n in WIDE_LAWS]
    else:
        laws = [PROJECTIONS['equidistant']]
    pair = _primary_pair(constraints)
    shape = None
    if len(pair) == 1 and one_fov and pair[0].name != 'circle':
        # One FOV: the shape of real lenses of that FOV, f through the FOV (lens_prior.py).
        c = pair[0]
        shape = lens_shape(c.name, c.fov, spec.width, spec.height)
        candidates = []
        for lw in laws:
            a = a_for_law(shape, lw, c.radius, c.half_angle, spec.diagonal / 2.0)
            candidates.append((lw, a, c.radius * a / float(lw.rho(psi(c.half_angle, a))), False))
    elif len(pair) == 1:
        # One radius: f from the pure law a = 1 (what "a 190-degree circular fisheye of 1080 px"
        # means for an equidistant lens; choose another law with 'wide-<law>').
        c = pair[0]
        candidates = [(lw, 1.0, c.radius / float(lw.rho(c.half_angle)), False) for lw in laws]
    else:
        outer, inner = sorted(pair, key=lambda c: -c.radius)
        candidates = _pair_candidates(laws, outer, inner)
        if not candidates and law is None and len(laws) < len(WIDE_LAWS):
            # The default law cannot meet the pair: any law that can is better than none.
            candidates = _pair_candidates([PROJECTIONS[n] for n in WIDE_LAWS], outer, inner)
        if not candidates:
            # Name the laws tried; a law asked for is never replaced by another, but the error says which can.
            tried = [lw.name for lw in laws] if law is not None else list(WIDE_LAWS)
            others = [f'{WIDE}-{n}' for n in WIDE_LAWS if n not in tried and
                      _pair_candidates([PROJECTIONS[n]], outer, inner)]
            raise SpecError(pair[1].name if pair[1].name != 'circle' else 'circle_fov', pair[1].fov,
                            f'a value that a lens of the wide model can pair with {pair[0].name} = '
                            f'{pair[0].fov:g} degrees' + (f" (or projection {' / '.join(others)} or '{WIDE}')"
                                                          if others else ''),
                            f"no {'/'.join(tried)} lens continued in angle space "
                            f'puts {pair[0].fov:g} degrees across {2 * pair[0].radius:g} px and '
                            f'{pair[1].fov:g} degrees across {2 * pair[1].radius:g} px')
    extra = [c for c in constraints if c not in pair]
    scored = []
    residuals: Dict[str, Dict[str, float]] = {}
    for lw, a, f, root in candidates:
        camera = _camera(spec, lw, a, f)
        res = {c.name: _predicted_fov(camera, c.radius) - c.fov for c in extra}
        if extra:
            score = sum(v * v if math.isfinite(v) else math.inf for v in res.values())
        else:
            score = abs(math.log(a)) if a > 0 else 0.0
        key = camera.projection.name
        if key not in residuals or score < residuals[key][1]:
            residuals[key] = (res, score)
        scored.append((score, camera, root))
    score, camera, root = min(scored, key=lambda s: s[0])
    if not math.isfinite(score):
        raise SpecError(extra[0].name, extra[0].fov, 'a FOV the wide model can reach',
                        'the fitted lens has no ray at that radius')
    focal = {}
    for c in constraints:
        if camera.omega == 0.0:
            focal[c.name] = c.radius / math.tan(c.half_angle) if c.fov < 180 else math.nan
        else:
            focal[c.name] = c.radius * camera.a / float(camera.law.rho(psi(c.half_angle, camera.a)))
    return WideFit(camera, root, focal, {k: v[0] for k, v in residuals.items()}, shape)
