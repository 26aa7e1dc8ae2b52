"""Zero-shot calibration of lenses that see 180 degrees and more (beyond the paper).

The paper's model (``ZeroShotCamera``) sends a ray theta off-axis through a pinhole of focal f
and then through the fisheye map G_w: r_d = G_w(f tan theta) = f rho(arctan(a tan theta)) / a,
a = w f. At theta = 90 degrees the pinhole radius is infinite, so that model stops there, and so
does every spec whose FOV reaches 180 degrees or whose image corners reach 90 degrees off-axis.

The same lens law written in angle space,

    r_d = f * theta_d(theta),   theta_d(theta) = rho(psi) / a,   psi = atan2(a sin theta, cos theta),

is *identical* to the paper's for theta < 90 degrees (tan psi = a tan theta) and continues
smoothly and monotonically up to theta = 180 degrees (psi runs from 0 to pi for any a > 0, and
rho is increasing on [0, pi] for the equidistant, equisolid and stereographic laws; orthographic
stops at 90 degrees and is not offered). a = 1 is the pure fisheye law (r = f theta for
equidistant), a -> 0 the pinhole. ``WideFovCamera`` is that camera: a ``ZeroShotCamera``
subclass (``RadialCamera`` interface: theta_d and its exact inverse), so fitting Kannala-Brandt
k1..k4 for ROS, rectification and calibration files work with it unchanged; its ``omega`` is the
paper's w = a / f (finite; equal to the paper's w* whenever the paper's model can represent the
spec, 0 in the pinhole limit).

Fitting. Every given FOV pins the half-angle at a radius: hfov at W/2, vfov at H/2, dfov at
D/2, and the circular-fisheye form (``CameraSpec.circle_diameter`` px, ``circle_fov`` deg) at
circle_diameter / 2; square pixels tie the focal length f. Two constraints (the first two of
circle, hfov, vfov, dfov with different radii: hfov + vfov for the paper's spec) fix a and f
exactly: a solves rho(psi(t_a; a)) / rho(psi(t_b; a)) = r_a / r_b (the paper's eq. 27 in angle
space; bracketed on a log grid of a and refined by Brent). With one constraint the pure law
a = 1 is assumed (the usual circular-fisheye reading: f = r / rho(theta)). Further constraints
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

A ray beyond the pair's angles is extrapolated by the law; a pixel beyond the law's largest
radius (theta = 180 degrees: r = f pi / a for equidistant, 2 f / a for equisolid) has no ray
(NaN), as outside a circular fisheye's image circle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np
from scipy.optimize import brentq

from .camera_models import CameraModel, ZeroShotCamera, angle_between
from .projections import PROJECTIONS, FisheyeProjection
from .spec import CameraSpec, SpecError

WIDE = 'wide'
"""Projection choice of solve_zero_shot: the angle-space model, law chosen as described above."""

WIDE_LAWS = ('equidistant', 'equisolid', 'stereographic')
"""Fisheye laws rho that stay increasing up to 180 degrees (orthographic does not)."""

WIDE_CHOICES = (WIDE,) + tuple(f'{WIDE}-{name}' for name in WIDE_LAWS)
"""'wide' (law chosen automatically) and 'wide-<law>' (law fixed)."""

CONSTRAINT_ORDER = ('circle', 'hfov', 'vfov', 'dfov')
"""Priority of the constraints that fix a and f exactly; the others choose law and root."""

_LOG_A_GRID = np.r_[np.linspace(math.log(1e-250), math.log(1e-7), 61)[:-1],
                    np.linspace(math.log(1e-7), math.log(1e7), 1401)]
"""log a where roots are bracketed: coarse towards the pinhole (one root there), fine around a = 1."""


class WideProjection(FisheyeProjection):
    """A fisheye law continued in angle space; named 'wide-<law>' (rho, theta as the law's)."""

    def __init__(self, law: FisheyeProjection):
        if law.name not in WIDE_LAWS:
            raise ValueError(f"law = {law.name!r} is invalid: allowed: {', '.join(WIDE_LAWS)}")
        self.law = law
        self.name = f'{WIDE}-{law.name}'

    def rho(self, theta):
        return self.law.rho(theta)

    def theta(self, rho):
        return self.law.theta(rho)

    def dtheta_drho(self, rho):
        return self.law.dtheta_drho(rho)

    @property
    def rho_limit(self) -> float:
        """rho at 180 degrees: the largest normalised radius a ray reaches (inf: stereographic)."""
        with np.errstate(over='ignore'):
            value = float(self.law.rho(np.pi))
        return math.inf if not math.isfinite(value) or value > 1e15 else value

    def __repr__(self):
        return f'WideProjection({self.law!r})'


def wide_projection(name: str) -> WideProjection:
    """'equidistant' / 'wide-equidistant' -> WideProjection; ValueError naming the choices."""
    law = name[len(WIDE) + 1:] if name.startswith(WIDE + '-') else name
    if law not in WIDE_LAWS:
        raise ValueError(f"law = {name!r} is invalid: allowed: {', '.join(WIDE_LAWS)}")
    return WideProjection(PROJECTIONS[law])


def _psi(theta, a):
    return np.arctan2(a * np.sin(theta), np.cos(theta))


def fields_of_view_through_axis(camera: CameraModel) -> dict:
    """Edge-to-edge FOVs in degrees through the principal point, as
    ``CameraModel.fields_of_view`` (hfov between the rays of (0, cy) and (W, cy), vfov between
    (cx, 0) and (cx, H), dfov between (0, 0) and (W, H)), except that when the two rays' off-axis
    angles add up to more than 180 degrees the angle is measured through the optical axis
    (360 degrees minus the plain angle between the rays): a 200-degree lens has hfov 200, not 160.
    Identical to ``fields_of_view`` below 180 degrees; NaN where a pixel has no ray."""
    w, h, cx, cy = camera.width, camera.height, camera.cx, camera.cy
    px = np.array([[0, cy], [w, cy], [cx, 0], [cx, h], [0, 0], [w, h]], dtype=float)
    rays = camera.unproject(px)
    off_axis = np.arctan2(np.linalg.norm(rays[:, :2], axis=-1), rays[:, 2])
    angle = angle_between(rays[0::2], rays[1::2])
    angle = np.where(off_axis[0::2] + off_axis[1::2] > np.pi, 2.0 * np.pi - angle, angle)
    angle = np.degrees(angle)
    return {'hfov': float(angle[0]), 'vfov': float(angle[1]), 'dfov': float(angle[2])}


class WideFovCamera(ZeroShotCamera):
    """The paper's camera continued in angle space up to 180 degrees off-axis (module docstring).

    ``projection`` is a ``WideProjection`` (a law name is accepted too). ``circle_radius``
    (px, optional): the image circle of a circular fisheye; pixels outside it are dark, so
    ``max_field_angle`` (the range a Kannala-Brandt fit covers) stops at the circle.
    """

    def __init__(self, f, cx, cy, width, height, omega=1.0, projection='equidistant',
                 circle_radius: Optional[float] = None):
        if not isinstance(projection, WideProjection):
            projection = wide_projection(projection if isinstance(projection, str) else projection.name)
        super().__init__(f, cx, cy, width, height, omega, projection)
        self.circle_radius = None if circle_radius is None else float(circle_radius)

    @property
    def law(self) -> FisheyeProjection:
        return self.projection.law

    def theta_d(self, theta):
        if self.omega == 0.0:
            return super().theta_d(theta)  # the pinhole limit: tan(theta), NaN from 90 degrees
        theta = np.asarray(theta, dtype=float)
        a = self.a
        with np.errstate(invalid='ignore'):
            valid = (theta >= 0.0) & (theta <= np.pi)
            return np.where(valid, self.law.rho(_psi(theta, a)) / a, np.nan)

    def theta_from_theta_d(self, theta_d):
        if self.omega == 0.0:
            return super().theta_from_theta_d(theta_d)
        theta_d = np.asarray(theta_d, dtype=float)
        a = self.a
        rho = a * theta_d
        limit = self.projection.rho_limit
        with np.errstate(invalid='ignore', over='ignore'):
            valid = (rho >= 0.0) & (rho <= limit)
            psi = np.minimum(self.law.theta(np.where(valid, rho, 0.0)), np.pi)
            return np.where(valid, np.arctan2(np.sin(psi), a * np.cos(psi)), np.nan)

    def fields_of_view(self) -> dict:
        """Edge-to-edge FOVs, measured through the optical axis beyond 180 degrees
        (``fields_of_view_through_axis``)."""
        return fields_of_view_through_axis(self)

    def max_field_angle(self) -> float:
        """Largest off-axis angle (radians) of a pixel with a ray: the farthest image corner's,
        or the image circle's when the circle is smaller; at most just under 180 degrees."""
        radius = self.corner_radius()
        if self.circle_radius is not None:
            radius = min(radius, self.circle_radius)
        theta = float(self.theta_from_theta_d(radius / self.f))
        cap = np.nextafter(np.pi, 0.0) * (1 - 1e-9)
        return cap if not math.isfinite(theta) else min(theta, cap)

    def scaled(self, width, height):
        s = width / self.width
        return WideFovCamera(self.f * s, self.cx * s, self.cy * height / self.height, width, height,
                             self.omega / s, self.projection,
                             None if self.circle_radius is None else self.circle_radius * s)

    def __repr__(self):
        circle = '' if self.circle_radius is None else f', circle_radius={self.circle_radius:g}'
        return (f'WideFovCamera(f={self.f:.6g}, cx={self.cx:g}, cy={self.cy:g}, '
                f'omega={self.omega:.6g} (a={self.a:.6g}), law={self.law.name}, '
                f'size={self.width}x{self.height}{circle})')


# ---------------------------------------------------------------------------------------------
# Zero-shot fit


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


def _check_monotonic(constraints: List[Constraint]):
    ordered = sorted(constraints, key=lambda c: c.radius)
    for inner, outer in zip(ordered, ordered[1:]):
        if outer.radius > inner.radius and outer.fov <= inner.fov:
            raise SpecError(outer.name if outer.name != 'circle' else 'circle_fov', outer.fov,
                            f'more than {inner.name} = {inner.fov:g} degrees',
                            f'{outer.name} spans {outer.radius:g} px from the centre, more than '
                            f'{inner.name} ({inner.radius:g} px), so a radially symmetric lens sees '
                            'a wider angle across it')
        if outer.radius == inner.radius and outer.fov != inner.fov:
            raise SpecError(outer.name if outer.name != 'circle' else 'circle_fov', outer.fov,
                            f'equal to {inner.name} = {inner.fov:g} degrees',
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
        return np.log(law.rho(_psi(t_a, a))) - np.log(law.rho(_psi(t_b, a)))


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
            candidates += [(lw, a, outer.radius * a / float(lw.rho(_psi(outer.half_angle, a))), True)
                           for a in roots]
        elif max(outer.fov, inner.fov) < 180.0 and \
                math.tan(inner.half_angle) / math.tan(outer.half_angle) >= inner.radius / outer.radius:
            # No barrel root: the paper's w* = 0, f the mean perspective focal (Hero9(L)).
            f = 0.5 * sum(c.radius / math.tan(c.half_angle) for c in (outer, inner))
            candidates.append((lw, 0.0, f, False))
    return candidates


def solve_wide(spec: CameraSpec, law: Optional[str] = None) -> WideFit:
    """Zero-shot fit of the angle-space model to ``spec`` (module docstring).

    ``law``: None chooses (equidistant, or by the extra constraints when there are any); a law
    name or 'wide-<law>' fixes it. Raises SpecError when no camera of the family meets the
    spec's primary constraints (or they contradict a radially symmetric lens)."""
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
    if len(pair) == 1:
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
            raise SpecError(pair[1].name if pair[1].name != 'circle' else 'circle_fov', pair[1].fov,
                            f'a value that a lens of the wide model can pair with {pair[0].name} = '
                            f'{pair[0].fov:g} degrees',
                            f'no equidistant/equisolid/stereographic lens continued in angle space '
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
            focal[c.name] = c.radius * camera.a / float(camera.law.rho(_psi(c.half_angle, camera.a)))
    return WideFit(camera, root, focal, {k: v[0] for k, v in residuals.items()})
