"""Refinement of the zero-shot camera from straight lines, and the gate that keeps it honest.

``refine_camera(spec, curves, width, height)``: the zero-shot camera (``solve_zero_shot``, 'auto',
fitted to Kannala-Brandt k1..k4) is the start and the reference; the fit (``fit.fit_lines``)
weighs the curves against the spec's FOVs (tolerance ``fov_tolerance_deg``), the principal-point
prior and the shape prior; curves that bow toward the principal point by more than a straight
line could under a plausible camera (a bonnet, a body's edge: ``core.lines.bowing``) are left out
before it, judged against zero-shot. The refined camera replaces the zero-shot one only when

- there are at least ``MIN_LINES`` curves that are straight under one camera, spread over the
  image: at least ``MIN_COVERAGE`` of the cells of an 8 x 6 grid over the image, and reaching
  ``MIN_REACH`` of the way from the centre to the corners, or to the image circle when it is
  nearer (distortion lives at the periphery);
- the images agree: no image with at least 3 curves loses more than half of them as outliers
  while the others keep theirs; and when one of the two checks below fails (the FOVs, the
  held-out curves), each image is fitted alone: if the images' own cameras differ by more than
  their covariances allow (a chi-square test, ``_image_disagreement``), the reason is
  "disagreement between images" (two cameras, two zoom settings), which names the cause better
  than the check that caught it, followed by what that check found;
- the spec agrees: no FOV of the result misses the spec's by more than ``MAX_FOV_SIGMAS``
  tolerances;
- held-out curves (every ``HOLD_OUT_EVERY``-th straight curve, counted in an order that the
  order of the images does not change: ``_hold_out_split``; left out of a second fit) are
  explained better than by the zero-shot camera;
- its uncertainty (``uncertainty.problem_uncertainty``) is lower than zero-shot's
  (``uncertainty.zero_shot_uncertainty``), both over the image circle seen in the images when one
  is (``_seen_circle``: nothing outside it is imaged), else over the whole image;
- and the zero-shot camera is unlikely to be the better one: under the fit's posterior, the
  probability that zero-shot is nearer the truth by more than ``ZERO_SHOT_MARGIN`` (0.3 px at
  1920 px wide, RMS over the image after the best rotation and the best zoom) is at most
  ``MAX_ZERO_SHOT_BETTER`` (``uncertainty.probability_other_is_better``; over the image circle
  seen when there is one), or ``MAX_ZERO_SHOT_BETTER_CONFIRMED`` when the held-out curves are
  explained with an RMS at least ``CONFIRMING_HELD_OUT_GAIN`` lower than under zero-shot (the
  held-out test's own figures: evidence the fit did not see). The posterior mean is
  better on average, but where the lines pin the camera loosely (a nearly rectilinear lens:
  lines then see neither zoom nor principal point) and zero-shot lies inside the posterior's
  spread, zero-shot is as likely to be the nearer one. The zoom (``uncertainty.zoom_field``)
  is left out of the comparison: lines cannot see it, both cameras take it from the same FOVs
  (the refined camera each FOV as far as its shape is known at that FOV's edge: ``zoom.py``),
  and the FOVs' error moves both alike, so the posterior's spread along it (most of the
  refined camera's uncertainty) says nothing about which is nearer. The posterior is the one
  with a systematic-error floor per curve (``SYSTEMATIC_PX``), without which a rectilinear
  lens's hundredths-of-a-pixel curvatures looked like evidence;
- and, for a spec of one constraint (one FOV, or the image circle alone: the lens shape is then
  the lens prior's guess, ``Uncertainty.lens_shape_px``), the held-out curves are explained at
  least ``CONFIRMING_HELD_OUT_GAIN`` better than under zero-shot, whatever the posterior says. The
  zoom follows the lines' shape through the one FOV's edge, so curves that err together (edges
  of padded mats, a detector's bias, a lens the model misfits) bend the shape and move the zoom
  where the posterior cannot see it: EuRoC's 93-degree camera given hfov alone was accepted 59
  px (at 1920) from its calibration with an error bar of 9 px, held-out curves 1.2 % better
  explained (dfov alone: 65 px, bar 10 px, 3.5 %); the real cameras whose one-FOV fits were
  nearer the truth had gains of 11 to 68 % (``benchmarks/results/real_photos.md``). With two
  FOVs or more the spec holds the shape and the posterior test alone decides;
- and every image (with at least ``MIN_IMAGE_LINES`` curves, of two or more) has its lines
  straightened by the refined camera at most ``MAX_IMAGE_WORSE`` times worse than by zero-shot
  (``_image_straightened_worse``): the images of two cameras of one spec meet in a camera between
  theirs, which explains held-out lines better than zero-shot while being farther than it from
  one of them, and that one's images say so.

Every refusal returns the zero-shot camera with the zero-shot camera's error bar
(``uncertainty_px`` = ``zero_shot_uncertainty_px``).

Otherwise the result is the zero-shot camera with ``accepted = False`` and the reason. The gate is
what keeps "never worse than zero-shot" true.

``refine_from_images(spec, images)`` runs ``core.lines.detect.detect_curves`` with the zero-shot
camera, fits, detects again with the refined camera (which finds more and longer curves in the
periphery) and fits again.
"""
from __future__ import annotations

import copy
import math
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from ..lens.models import FOV_NAMES, KannalaBrandtCamera, fov_edge_pixels
from ..lines.bowing import bows_the_wrong_way
from ..lines.straightness import StraightnessTerm, curve_image, curve_points
from ..zeroshot.spec import CameraSpec
from .fit import SOLVE_TOL, LineFit, fit_lines
from .problem import Problem, jacobian_threads, one_blas_thread
from .terms import FOV_TOLERANCE_DEG, SHAPE_SIGMA, FovTerm, ImageCircleTerm, PrincipalPointPrior, ShapePrior
from .uncertainty import (Uncertainty, displacement, image_circle_radius, pixel_grid, probability_other_is_better,
                          problem_uncertainty, rms_over_circle)
from .zero_shot import zero_shot_camera, zero_shot_start  # noqa: F401 (zero_shot_camera: its callers' import)
from .zoom import REZOOM_MISFIT_PX, rezoom, statement_shape_covariance  # noqa: F401 (REZOOM_MISFIT_PX: docs)

MIN_LINES = 8
MIN_POINTS = 6
MAX_POINTS_PER_CURVE = 40
"""Curves are resampled to at most this many points (evenly along the curve): neighbouring
sub-pixel edge points carry little new information and the fit's cost is linear in points."""
MAX_POINTS = 6000
"""And all curves together to at most this many (each curve to MAX_POINTS // curves, at least
``MIN_CURVE_POINTS``): four 1080p frames give ~500 curves, whose 20,000 points cost 3x the
time of 6,000 (the fit's cost is linear in points); the noise of neighbouring edge points is
correlated (the same blur and the same LSD segment), so counting every one as independent
would only make the covariance overconfident."""
MIN_CURVE_POINTS = 10
MIN_COVERAGE = 0.25
MIN_REACH = 0.55
COVERAGE_GRID = (8, 6)
HOLD_OUT_EVERY = 5
"""Every this-many-th straight curve is held out of a second fit; the fitted camera is refused
unless it explains them better than zero-shot does, strictly. A tie there sits at the gate's
edge (the last digits of a JPEG re-encoding tip it), and letting a tie through to the posterior
test was tried: a tie within 1 % of the RMS, or within one standard error of the curves'
paired differences, flipped 1 decision in 160 perturbed rendered runs with nuisances (against
2), but accepted a rendered lens from one frame 1.4 to 2.0 px worse than zero-shot (held-out
0.1707 against 0.1703 px), where the posterior, too narrow for a lens the model misfits, gave
zero-shot 0.1 %. A flip between two good answers costs less than a wrong one adopted
(benchmarks/results/gate_stability.md)."""
MAX_FOV_SIGMAS = 3.0
MIN_IMAGE_LINES = 5
MAX_IMAGE_WORSE = 1.1
"""The refined camera is refused when it straightens one image's lines (RMS) more than this many
times worse than zero-shot does (``_image_straightened_worse``)."""
DISAGREEMENT_P = 1e-3
"""Significance level of the consistency test between images (``_image_disagreement``): the
images disagree when cameras of one camera's images would scatter as widely as theirs with a
probability below this."""
MAX_ZERO_SHOT_BETTER = 0.01
MAX_ZERO_SHOT_BETTER_CONFIRMED = 0.05
CONFIRMING_HELD_OUT_GAIN = 0.05
"""The probability that zero-shot is better may reach MAX_ZERO_SHOT_BETTER_CONFIRMED (instead of
MAX_ZERO_SHOT_BETTER) when the held-out curves, which the fit did not see, are explained with an
RMS at least this share lower than under zero-shot. The posterior is the model's word: too wide
where curves err together (rendered 14 mm phone lenses refused at 2-3 % although their fits were
4 px nearer the truth, their held-out curves 25-48 % better explained), too narrow where the
model misfits the lens (a real 93-degree radial-tangential camera, EuRoC's: 1.7 %, its fit 3.4
px farther from the truth than zero-shot, its held-out curves 0.8 % better). A misfit cannot
explain curves it did not see much better, so the held-out gain tells the two apart. Chosen on the
line benchmark's tuning set (``--tuning-set``): there every camera with a probability between 1
and 5 % and a held-out gain of 5 % was nearer the truth than zero-shot (now accepted: 8.97 ->
1.01 px and 1.11 -> 0.18 px, gains 13.7 and 7.0 %; with the nuisances 2.15 -> 0.61 px, 5.8 %),
and the first camera farther than zero-shot came at 8 % (benchmarks/results/line_refinement.md)."""
ZERO_SHOT_MARGIN = 0.3 / 1920
"""The gate keeps zero-shot when, under the fit's posterior, the probability that zero-shot is
nearer the truth by more than this fraction of the width (0.3 px at 1920 wide) exceeds
MAX_ZERO_SHOT_BETTER."""
INITIAL_SIGMA_PX = 0.5
REFINE_SHAPE_SIGMA = 4 * SHAPE_SIGMA
"""The refinement's shape prior: four times the population's (weak beside the lines; it only
holds the shape where no line reaches)."""
ONE_CONSTRAINT_SHAPE_SPREAD = 0.1
"""For a spec of one constraint (one FOV, or the image circle alone) the error bar counts the
shape prior at this width (10 % of the radius, RMS) instead of ``REFINE_SHAPE_SIGMA``. There
zero-shot's shape is a guess from real lenses of that FOV (rectilinear wide-angles and fisheyes
share one FOV and differ by 30-40 % in radius near the centre), and where no line reaches (the
corners a dfov is measured to) the prior alone holds the shape the one FOV's zoom rests on: at 2 %
the bar stated it known, and rendered lenses given dfov alone were accepted 19.8 and 50.8 px from
the truth at 2.7 and 6.1 times their bars. The fit keeps the 2 % prior: at 10 % in the fit the
shape beyond the lines wandered on real photos (a 187-degree fisheye given hfov alone 6.6 -> 48 px,
a 120-degree camera given dfov 10.7 -> 197 px; benchmarks/results/line_refinement.md, "One FOV
alone")."""


REZOOM = True
"""The refined camera takes its zoom from the FOVs alone (``zoom.rezoom``), each FOV weighed by
how well the refined camera's shape is known at its edge (``zoom.statement_shape_covariance``)."""
SYSTEMATIC_PX = 0.05
"""Every curve may err systematically by this much (px RMS) in a bow and in an S along it
(``uncertainty.systematic_covariance``): the floor under what lines say through curvature, the
same 0.05 px as ``fit.MIN_SIGMA_PX`` (what sub-pixel edge detectors do not beat). Chosen on
the line benchmark's tuning set (``--tuning-set``, disjoint from the reported profiles): at
0.02 a rendered Laowa 7.5 mm (nearly rectilinear) whose refined principal point was 20 px (at
1920) off was still accepted (3.1 px worse than zero-shot); at 0.05 it is refused and the
fisheye lenses tried (6) stay accepted with the same cameras."""
SYSTEMATIC_SHARE = 0.5
"""And at least this share of the estimated noise of the line points (``fit.sigma_px``): what blurs
and shifts an edge's points (motion blur, a soft lens, JPEG, low resolution) shifts a whole
curve too, by an amount that grows with them. Renders have sigma 0.07-0.13 px, so the floor stays
``SYSTEMATIC_PX`` there; real photos at 752x480 have 0.1-0.4 px, and with the fixed floor a
real 93-degree camera (EuRoC's) whose lines sat at 0.38 px was accepted 5-7 px worse than
zero-shot at a stated 0.04-0.2 % chance of zero-shot being better, whenever a perturbation of
0.01 degree or a JPEG re-encoding tipped its held-out check."""


def systematic_floor_px(sigma_px: Optional[float]) -> float:
    """The systematic-error floor per curve (px) for lines of noise ``sigma_px``."""
    if sigma_px is None or not math.isfinite(sigma_px):
        return SYSTEMATIC_PX
    return max(SYSTEMATIC_PX, SYSTEMATIC_SHARE * float(sigma_px))


CLUSTERED_COVARIANCE = False
"""When True (and SYSTEMATIC_PX is 0), the refined camera's covariance is the cluster-robust one
(``uncertainty.clustered_covariance``). Off: on the rendered Laowa 7.5 mm that motivated it, it
widened the spread by 1 %, where the systematic floor is what the evidence lacked."""
SHAPE_PRIOR_ON_RADIUS = True
"""The refinement's shape prior holds the image radius f theta_d(theta) near zero-shot's, not
theta_d alone: lines and FOVs fix the radius function, and a camera whose f differs from
zero-shot's by 5 % with the same radii (the shared real set: f 290 px against zero-shot's 305,
radius at 90 degrees the same to 0.3 %) must not pay a 5 % shape deviation for it."""


@dataclass
class Refinement:
    """What ``refine_camera`` decided, and the numbers behind it."""

    camera: KannalaBrandtCamera
    """The camera to use: the refined one when accepted, else zero-shot's (KB4 fit)."""
    accepted: bool
    reason: str
    uncertainty_px: Optional[float]
    """RMS over the image of the 1-sigma pixel displacement of ``camera`` (image pixels, after
    the best rotation); None when it cannot be estimated."""
    zero_shot_uncertainty_px: Optional[float]
    images_used: int
    lines_used: int
    line_residual_px_before: Optional[float]
    """RMS distance (px) of the used curves' points from their lines' images under zero-shot."""
    line_residual_px_after: Optional[float]
    """The same under the refined camera (None when no fit was made)."""
    coverage: float
    """Fraction of the cells of an 8 x 6 grid over the image that the used curves touch."""
    principal_point_shift_px: float
    zero_shot_camera: KannalaBrandtCamera = None
    refined_camera: Optional[KannalaBrandtCamera] = None
    """The fitted camera even when the gate refused it (None when no fit was made)."""
    refined_uncertainty_px: Optional[float] = None
    held_out_px_before: Optional[float] = None
    held_out_px_after: Optional[float] = None
    zero_shot_better_probability: Optional[float] = None
    """Under the fit's posterior, the probability that the zero-shot camera is nearer the truth."""
    zero_shot_distance_px: Optional[float] = None
    """RMS over the image of refined - zero-shot pixels after the best rotation."""
    curves_given: int = 0
    curves_rejected: int = 0
    """Curves not used: not straight under the fitted camera, or bowing the wrong way."""
    curves_bowed: int = 0
    """Of those, the curves left out before the fit because they bow toward the principal point by
    more than a line could under a plausible camera (``core.lines.bowing``): a bonnet, a body's edge."""
    order: Optional[int] = None
    """Number of Kannala-Brandt coefficients the lines moved (0..4)."""
    sigma_px: Optional[float] = None
    """Estimated noise of the line points (px)."""
    reach: float = 0.0
    """Largest distance of a used point from the centre over the centre-to-corner distance."""
    fov_residuals_deg: Dict[str, float] = field(default_factory=dict)
    image_circle: Optional[object] = None
    """The image circle measured in the images (``core.lines.image_region.ImageCircle``), combined
    over them, when one was seen; None otherwise."""
    circle_measured_in: int = 0
    """How many of the images showed it."""
    static_curves: List = field(default_factory=list, repr=False)
    """Curves left out because they stay put across the images (the vehicle's or robot's body in
    view, lens dirt: ``core.lines.static_curves``); not in ``curves``."""
    used: Optional[np.ndarray] = field(default=None, repr=False)
    """Boolean mask over the given curves: those the fit used."""
    curves: List = field(default_factory=list, repr=False)
    """The curves given, in order (``used`` is over them): what a debug image draws."""
    warnings: List[str] = field(default_factory=list)
    spec_warnings: List[str] = field(default_factory=list)
    """What the images show against the spec given (``dark_fov_warning``), accepted or not."""
    zero_shot_uncertainty: Optional[Uncertainty] = field(default=None, repr=False)
    refined_uncertainty: Optional[Uncertainty] = field(default=None, repr=False)
    """The fitted camera's error bar with its covariance (None when no fit was made): the map of
    ``uncertainty.uncertainty_map``; ``uncertainty_px`` is its ``rms_px`` when accepted."""

    @property
    def uncertainty(self) -> Optional[Uncertainty]:
        """The error bar of ``camera``: the refined camera's when accepted, else zero-shot's."""
        return self.refined_uncertainty if self.accepted else self.zero_shot_uncertainty


def _prepare(curves: Sequence, width: int, height: int):
    """(kept curve arrays, their indices into ``curves``, their image ids)."""
    kept, index, images = [], [], []
    for i, c in enumerate(curves):
        try:
            p = curve_points(c)
        except ValueError:
            continue
        p = p[np.all(np.isfinite(p), axis=1)]
        p = p[(p[:, 0] >= 0) & (p[:, 0] <= width) & (p[:, 1] >= 0) & (p[:, 1] <= height)]
        if len(p) < MIN_POINTS:
            continue
        kept.append(p)
        index.append(i)
        images.append(curve_image(c, 0))
    cap = max(MIN_CURVE_POINTS, min(MAX_POINTS_PER_CURVE, MAX_POINTS // max(len(kept), 1)))
    kept = [p if len(p) <= cap else p[np.round(np.linspace(0, len(p) - 1, cap)).astype(int)] for p in kept]
    return kept, np.array(index, dtype=int), images


def coverage_of(points: np.ndarray, width: int, height: int, grid=COVERAGE_GRID, circle_radius=None):
    """(fraction of grid cells touched, reach: largest distance from the centre / corner distance,
    or / the image circle's radius when ``circle_radius`` (px) is given and smaller: nothing
    beyond the circle is imaged)."""
    if len(points) == 0:
        return 0.0, 0.0
    gx = np.clip((points[:, 0] / width * grid[0]).astype(int), 0, grid[0] - 1)
    gy = np.clip((points[:, 1] / height * grid[1]).astype(int), 0, grid[1] - 1)
    cells = len(set(zip(gx.tolist(), gy.tolist())))
    radius = np.hypot(points[:, 0] - width / 2, points[:, 1] - height / 2)
    limit = math.hypot(width / 2, height / 2)
    if circle_radius is not None and 0 < circle_radius < limit:
        limit = circle_radius
    reach = float(np.max(radius) / limit)
    return cells / (grid[0] * grid[1]), reach


def _curve_lengths(term: StraightnessTerm) -> np.ndarray:
    """Each curve's length along its points (px)."""
    steps = np.hypot(*np.diff(term.points, axis=0).T)
    steps[term.starts[1:] - 1] = 0.0  # no step from one curve's last point to the next curve's first
    return np.add.reduceat(np.r_[steps, 0.0], term.starts)


def _hold_out_split(images: Sequence, lengths: np.ndarray, every: int = HOLD_OUT_EVERY) -> np.ndarray:
    """Every ``every``-th curve held out, counted in an order the order of the images does not
    change (else the gate's decision would flip with it): each image's curves by their place in
    that image's list (the detector's, longest first), the images' first curves first, then their
    second ones, ..., curves of the same place longest first. One image: its own order."""
    lengths = np.asarray(lengths, dtype=float)
    place = np.zeros(len(lengths), dtype=int)
    seen = {}
    for k, image in enumerate(images):
        place[k] = seen.get(image, 0)
        seen[image] = place[k] + 1
    order = np.lexsort((-lengths, place))
    held = np.zeros(len(lengths), dtype=bool)
    held[order[every // 2::every]] = True
    return held


CIRCLE_AGREEMENT_SIGMAS = 3.0
"""A spec's circle diameter agrees with the measured one when they differ by at most this many
sigmas of the measured diameter (and at least 1 px); only then does the measurement state the
circle FOV (else the spec's diameter does, and the measurement only the principal point)."""


def circle_diameter_agrees(given: float, circle) -> bool:
    """Whether a given circle diameter (px) agrees with a measured ``ImageCircle``."""
    return abs(given - circle.diameter) <= max(1.0, CIRCLE_AGREEMENT_SIGMAS * 2.0 * circle.radius_uncertainty_px)


def circle_term(spec: CameraSpec, circle, width: int, fov_tolerance_deg: float, reference) -> ImageCircleTerm:
    """The ``ImageCircleTerm`` of a measured circle: the principal point always; the circle FOV
    when the spec has one and its diameter (scaled to ``width``) agrees with the measurement."""
    circle_fov = getattr(spec, 'circle_fov', None)
    if circle_fov is not None:
        given = spec.circle_diameter * width / spec.width
        if not circle_diameter_agrees(given, circle):
            circle_fov = None
    return ImageCircleTerm(circle.cx, circle.cy, circle.radius, circle.centre_sigma_px, circle.radius_uncertainty_px,
                           width, circle_fov, fov_tolerance_deg, reference)


DARK_EDGE_SIGMAS = 3.0
"""A FOV's edge pixel lies past the image circle seen when it is farther from the circle's centre
than its radius by more than this many sigmas of the radius (and at least 1 px)."""
FOV_EDGES = {'hfov': ('the left edge', 'the right edge', 'the left and right edges'),
             'vfov': ('the top edge', 'the bottom edge', 'the top and bottom edges'),
             'dfov': ('the top-left corner', 'the bottom-right corner', 'the corners')}
"""Where each spec FOV is measured to (``lens.models.fov_edge_pixels``), in words: its first edge,
its second, both."""


def _edges_past_image_circle(spec: CameraSpec, circle, width: int, height: int) -> Dict[str, str]:
    """{FOV name: its edges outside the image circle ``circle``, in words} (``fovs_past_image_circle``)."""
    margin = max(1.0, DARK_EDGE_SIGMAS * circle.radius_uncertainty_px)
    edges = dict(zip(FOV_NAMES, fov_edge_pixels(width, height, circle.cx, circle.cy)))
    past = {}
    for name in spec.given():
        out = np.hypot(*(edges[name] - (circle.cx, circle.cy)).T) > circle.radius + margin
        if out.any():
            first, second, both = FOV_EDGES[name]
            past[name] = both if out.all() else (first if out[0] else second)
    return past


def fovs_past_image_circle(spec: CameraSpec, circle, width: int, height: int) -> List[str]:
    """The spec's FOVs (hfov, vfov, dfov) with an edge pixel outside the image circle ``circle``
    measured in images of ``width`` x ``height`` (``core.lines.image_region.ImageCircle``; its
    centre is the principal point): pixels that no light reaches, where nothing is imaged."""
    return list(_edges_past_image_circle(spec, circle, width, height))


def dark_fov_warning(spec: CameraSpec, circle, width: int, height: int) -> Optional[str]:
    """One line when a FOV of the spec is stated across pixels outside the image circle seen in the
    images (``fovs_past_image_circle``), else None. Nothing is imaged there, so the scale such a FOV
    gives rests on how the lens continues past the last thing imaged, which no line checks. The
    usual case is a circular fisheye's one figure, its FOV across the image circle, given as hfov or
    dfov: a rendered 190-degree circular fisheye (640 x 480, a corridor view with every nuisance)
    given ``hfov 190`` or ``dfov 190`` was refined 46 and 58 px from the truth inside its circle, at
    14 and 11 times its error bar; given ``circle_fov 190``, to 0.8 px (test_cli_refine's). A FOV
    the lens truly has past its circle is safe where the lens continues as the model does
    (renders), not always on a real lens: OCamCalib's 748 x 480
    circular fisheye given its calibration's dfov, 218 degrees across the dark corners, was refined
    with the shape right and the zoom 19 % off, at 5.7 times its error bar, and given its circle's
    FOV with the measured diameter and the calibration's hfov across the dark left and right edges,
    at 4.2 times (benchmarks/real_photos.py --spec dfov; the CLI)."""
    if circle is None:
        return None
    past = _edges_past_image_circle(spec, circle, width, height)
    if not past:
        return None
    given = spec.given()
    stated = ', '.join(f'{name} {given[name]:g} (to {edges})' for name, edges in past.items())
    advice = ('the FOV across the image circle (circle_fov) states the scale where light is'
              if getattr(spec, 'circle_fov', None) is not None else
              "a circular fisheye's spec sheet usually states its FOV across the image circle: give that as circle_fov "
              "(--circle-fov)")
    return (f'{stated}: the image circle seen in the images ({circle.diameter:.0f} px across) ends before '
            f'{"it reaches" if len(past) == 1 else "they reach"} them, so nothing is imaged there and the scale '
            f'{"it gives" if len(past) == 1 else "they give"} rests on how the lens continues into the dark, which '
            f'no line checks and the error bar may not cover; {advice}')


@one_blas_thread()  # its solves are small: OpenBLAS's threads only wait for busy cores (problem.py)
def refine_camera(spec: CameraSpec, curves: Sequence, width: Optional[int] = None, height: Optional[int] = None,
                  fov_tolerance_deg: float = FOV_TOLERANCE_DEG, initial: Optional[KannalaBrandtCamera] = None,
                  solution=None, image_circle=None, image_names=None) -> Refinement:
    """Refine the zero-shot camera of ``spec`` with ``curves`` (module docstring).

    ``curves``: ``core.lines.detect.Curve`` objects (or (N, 2) arrays of raw pixels, counted as
    one image), from images of ``width`` x ``height`` (default the spec's;
    another size of the same aspect is a binned or resized mode). ``initial``: a camera to start
    from (e.g. an earlier refinement); the zero-shot camera stays the reference of the gate.
    ``solution``: the zero-shot solution if already computed, or the spec's whole zero-shot result
    at this size and tolerance (a ``zero_shot.ZeroShotStart``: then nothing of the spec is computed
    again). ``image_circle``: the image circle
    measured in the images (``core.lines.image_region.ImageCircle``), evidence of the principal
    point and, with the spec's circle FOV, of the scale (``circle_term``). ``image_names``: what a
    reason calls each image (a sequence indexed by the curves' image ids, e.g. the files' paths);
    default their ids."""
    width = spec.width if width is None else int(width)
    height = spec.height if height is None else int(height)
    if abs(width * spec.height - height * spec.width) > 0.01 * spec.width * spec.height:
        raise ValueError(f'images are {width}x{height} but the spec is {spec.width}x{spec.height}: '
                         'not the same aspect ratio')
    start = zero_shot_start(spec, width, height, fov_tolerance_deg, solution)
    zs, zs_u = start.camera, start.uncertainty
    # one FOV or the circle alone: zero-shot's lens shape is a guess from real lenses of that FOV
    shape_guessed = zs_u.lens_shape_px is not None
    scale = width / spec.width
    zs_u_px = None if zs_u.rms_px is None else zs_u.rms_px * scale
    warnings = [zs_u.warning] if zs_u.warning else []
    kept, index, images = _prepare(curves, width, height)
    # a curve bowing toward the principal point is no line of this lens (a bonnet, a body's edge):
    # judged against zero-shot, the plausible camera, before any fit can bend toward it
    bowed = bows_the_wrong_way(kept, zs, width)
    if bowed.any():
        kept = [p for p, b in zip(kept, bowed) if not b]
        index = index[~bowed]
        images = [g for g, b in zip(images, bowed) if not b]
    result = Refinement(zs, False, '', zs_u_px, zs_u_px, 0, 0, None, None, 0.0, 0.0, zero_shot_camera=zs,
                        curves_given=len(curves), warnings=warnings, zero_shot_uncertainty=zs_u)
    result.curves_bowed = int(bowed.sum())
    result.curves_rejected = result.curves_bowed
    result.used = np.zeros(len(curves), dtype=bool)
    result.curves = list(curves)
    result.image_circle = image_circle
    dark = dark_fov_warning(spec, image_circle, width, height)
    result.spec_warnings = [dark] if dark else []

    def refuse(reason):
        result.accepted = False
        result.reason = reason
        result.camera = zs
        result.uncertainty_px = zs_u_px
        return result

    circle_limit = None  # nothing is imaged beyond the image circle: the reach is measured to it
    if image_circle is not None:
        circle_limit = image_circle.radius
    elif getattr(spec, 'circle_diameter', None) is not None:
        circle_limit = spec.circle_diameter * width / spec.width / 2.0
    if len(kept) < MIN_LINES:
        return refuse(f'too few lines: {len(kept)} usable curves of {len(curves)}, at least {MIN_LINES} needed')
    all_points = np.concatenate(kept)
    result.coverage, result.reach = coverage_of(all_points, width, height, circle_radius=circle_limit)
    if result.reach < MIN_REACH or result.coverage < MIN_COVERAGE:
        return refuse(f'lines only near the centre (coverage): they touch {100 * result.coverage:.0f} % of the '
                      f'image and reach {100 * result.reach:.0f} % of the way to the corners; at least '
                      f'{100 * MIN_COVERAGE:.0f} % and {100 * MIN_REACH:.0f} % are needed')

    term = StraightnessTerm(kept, sigma=INITIAL_SIGMA_PX)
    circle = None if image_circle is None else circle_term(spec, image_circle, width, fov_tolerance_deg, zs)
    states_fov = circle is not None and circle.circle_fov is not None
    fov = FovTerm.from_spec(spec, fov_tolerance_deg, width, height, leave_out=('circle',) if states_fov else ())
    zoom_terms = [t for t in (fov, circle if states_fov else None) if t is not None]
    theta_max = zs.max_field_angle()
    priors = [t for t in (fov, circle) if t is not None] + [
        PrincipalPointPrior(width, height), ShapePrior(zs, theta_max, REFINE_SHAPE_SIGMA, radius=SHAPE_PRIOR_ON_RADIUS)]
    fit = fit_lines(term, priors, zs, initial)
    refined = fit.camera
    result.refined_camera = refined
    result.order = fit.order
    result.sigma_px = fit.sigma_px
    inliers = fit.inliers
    result.used[index[inliers]] = True
    result.lines_used = int(inliers.sum())
    result.curves_rejected = int(len(kept) - inliers.sum()) + result.curves_bowed
    used_images = [images[i] for i in np.nonzero(inliers)[0]]
    result.images_used = len(set(used_images))
    used_term = term.subset(inliers)
    result.line_residual_px_before = used_term.rms(zs)
    result.line_residual_px_after = used_term.rms(refined)
    result.principal_point_shift_px = float(math.hypot(refined.cx - zs.cx, refined.cy - zs.cy))
    given_fovs, fov_sigmas = _fov_statements(fov, circle if states_fov else None)
    result.fov_residuals_deg = _fov_residuals(fov, circle if states_fov else None, refined)
    seen = _seen_circle(image_circle)
    ref_u, u_layout, u_x, u_jacobian = _fit_uncertainty(
        fit, seen, ONE_CONSTRAINT_SHAPE_SPREAD if shape_guessed else None)
    result.refined_uncertainty_px = ref_u.rms_px
    result.refined_uncertainty = ref_u
    if REZOOM:
        # the zoom from the FOVs alone (the lines' say on it is the model's artefact): after the
        # checks above, which judge the fit as it is
        top = fit.top_problem if fit.top_problem is not None else fit.problem
        shape = statement_shape_covariance(top, u_x, u_jacobian, systematic_floor_px(fit.sigma_px), zoom_terms,
                                           refined, *(seen if seen is not None else (None, None)))
        refined = rezoom(refined, zoom_terms, shape_covariance=shape)
        result.refined_camera = refined
        result.line_residual_px_after = used_term.rms(refined)

    if result.lines_used < MIN_LINES:
        return refuse(f'too few straight lines: {result.lines_used} of {len(kept)} curves are straight under '
                      f'one camera, at least {MIN_LINES} needed')
    result.coverage, result.reach = coverage_of(used_term.points, width, height, circle_radius=circle_limit)
    if result.reach < MIN_REACH or result.coverage < MIN_COVERAGE:
        return refuse(f'lines only near the centre (coverage): the straight ones touch {100 * result.coverage:.0f} % '
                      f'of the image and reach {100 * result.reach:.0f} % of the way to the corners')
    no_rays = _pixels_without_rays(refined, zs, width, height, seen)
    if no_rays:
        return refuse(no_rays)
    disagreeing = _disagreeing_images(images, inliers)
    if disagreeing:
        named = ', '.join(_image_label(image_names, i) for i in disagreeing)
        return refuse(f'disagreement between images: most curves of image(s) {named} are not straight under the '
                      'camera that straightens the others (another camera, or another lens setting?)')
    worst = max(result.fov_residuals_deg.items(), key=lambda kv: abs(kv[1]) / fov_sigmas[kv[0]])
    if abs(worst[1]) > MAX_FOV_SIGMAS * fov_sigmas[worst[0]]:
        across = ' across the image circle measured in the images' if worst[0] == 'circle' and states_fov else ''
        detail = (f'the camera that straightens the lines has {worst[0]} '
                  f'{given_fovs[worst[0]] + worst[1]:.1f} degrees{across} against the '
                  f"spec's {given_fovs[worst[0]]:g} (tolerance {fov_sigmas[worst[0]]:.3g} deg)")
        split = _image_disagreement(fit, used_term, used_images, priors, image_names)
        if split:
            return refuse(f'{split}; all images together: {detail}')
        # the lines fix the lens's shape but hardly its scale (the zoom): the FOV they ask for
        # follows the spec given, and a user who gives it back gets a confident wrong camera
        return refuse(f'disagreement between the lines and the spec: {detail}; check the spec sheet '
                      f'(lines fix a lens\'s shape but hardly its scale: this FOV given back as the spec '
                      f'would not be a measurement)')

    held = _hold_out_split(used_images, _curve_lengths(used_term))
    before, after = _held_out(fit, used_term, held, priors)
    result.held_out_px_before, result.held_out_px_after = before, after
    if ref_u.rms_px is None:
        return refuse(f'the refined camera has no uncertainty: {ref_u.reason}')
    if not after < before:
        detail = f'held-out lines are not explained better: {after:.3g} px RMS against zero-shot {before:.3g} px'
        split = _image_disagreement(fit, used_term, used_images, priors, image_names)
        if split:
            return refuse(f'{split}; all images together: {detail}')
        return refuse(detail)
    # the two error bars compared over the same pixels: those of the image circle seen in the images
    # when there is one (nothing outside it is imaged, ``_seen_circle``), else the whole image; the
    # circle form alone without a seen circle states zero-shot's over the spec's circle, the refined
    # camera's over the whole image: no comparison there; the other checks still apply
    ref_compared, zs_compared = ref_u.rms_px, zs_u_px
    if seen is not None and zs_u_px is not None:
        radius, (cx, cy) = seen
        ref_compared = rms_over_circle(ref_u, radius, (cx, cy))
        zs_seen = rms_over_circle(zs_u, radius / scale, (cx / scale, cy / scale))
        zs_compared = None if zs_seen is None or ref_compared is None else zs_seen * scale
    elif image_circle_radius(spec) is not None:
        zs_compared = None
    over = ' over the image circle seen' if seen is not None else ''
    if zs_compared is not None and not ref_compared < zs_compared:
        return refuse(f'not more certain than zero-shot{over}: {ref_compared:.3g} px against {zs_compared:.3g} px')
    margin = ZERO_SHOT_MARGIN * width
    p_better, distance, spread = probability_other_is_better(
        u_layout, u_x, ref_u.covariance, zs, margin, after_zoom=True,
        circle_radius=None if seen is None else seen[0], circle_centre=None if seen is None else seen[1])
    result.zero_shot_better_probability, result.zero_shot_distance_px = p_better, distance
    confirmed = after <= (1.0 - CONFIRMING_HELD_OUT_GAIN) * before  # the held-out lines see the gain too
    allowed = MAX_ZERO_SHOT_BETTER_CONFIRMED if confirmed else MAX_ZERO_SHOT_BETTER
    if p_better > allowed:
        return refuse(f'the lines do not rule out zero-shot: beside the zoom (which only the FOVs fix, for both) the '
                      f'refined camera is {distance:.3g} px RMS from it with an uncertainty of {spread:.3g} px, '
                      f'so zero-shot may be as good (probability {100 * p_better:.2g} % that it is better by '
                      f'{margin:.2g} px, at most {100 * allowed:g} % allowed); zero-shot kept')
    if shape_guessed and not confirmed:
        return refuse(f'held-out lines are explained only {100 * (1.0 - after / before):.1f} % better than by '
                      f'zero-shot ({after:.3f} px RMS against {before:.3f} px), and with one FOV (or the image circle '
                      f'alone) the focal length rests on the lens shape the lines show, so the fit needs them at least '
                      f'{100 * CONFIRMING_HELD_OUT_GAIN:.0f} % better; zero-shot kept: give a second FOV (vfov or '
                      f'dfov) from the spec sheet, or images whose straight edges reach further across the image')
    # every image's lines are straightened by the refined camera: the checks above judge the images
    # together, where the images of two cameras (a stereo pair's, two units of one model) meet in a
    # camera between theirs that explains held-out lines better than zero-shot
    worse = _image_straightened_worse(used_term, used_images, refined, zs, image_names)
    if worse:
        return refuse(worse)
    result.accepted = True
    result.camera = refined
    result.uncertainty_px = ref_u.rms_px
    result.reason = (f'accepted: {result.lines_used} lines from {result.images_used} image(s); held-out lines '
                     f'{after:.3g} px RMS (zero-shot {before:.3g} px); uncertainty {ref_u.rms_px:.3g} px '
                     f'(zero-shot {zs_u_px:.3g} px)' if zs_u_px is not None else
                     f'accepted: held-out lines {after:.3g} px RMS (zero-shot {before:.3g} px)')
    if zs_compared is not None and seen is not None:
        result.reason += f'; {over.strip()}: {ref_compared:.3g} px against {zs_compared:.3g} px'
    return result


def _fov_statements(fov: Optional[FovTerm], circle: Optional[ImageCircleTerm]):
    """({FOV name: given degrees}, {FOV name: sigma degrees}) of the spec's FOVs, the circle's
    stated by ``circle`` (the measured image circle) when it is given."""
    given, sigma = {}, {}
    if fov is not None:
        given.update(zip(fov.keys, fov.given.tolist()))
        sigma.update({k: fov.sigma for k in fov.keys})
    if circle is not None:
        given['circle'], sigma['circle'] = circle.circle_fov, float(circle.sigma[2])
    return given, sigma


def _fov_residuals(fov: Optional[FovTerm], circle: Optional[ImageCircleTerm], camera) -> Dict[str, float]:
    out = {} if fov is None else dict(zip(fov.keys, fov.residuals(camera).tolist()))
    if circle is not None:
        out['circle'] = float(circle.residuals(camera)[2])
    return out


def _disagreeing_images(images: List, inliers: np.ndarray) -> List:
    """Images (with at least 3 curves) that lost more than half their curves while the rest lost
    at most a quarter."""
    by_image: Dict = {}
    for img, ok in zip(images, inliers):
        by_image.setdefault(img, []).append(bool(ok))
    if len(by_image) < 2:
        return []
    out = []
    for img, flags in by_image.items():
        if len(flags) < 3 or np.mean(flags) >= 0.5:
            continue
        others = [f for other, fl in by_image.items() if other != img for f in fl]
        if others and np.mean(others) >= 0.75:
            out.append(img)
    return out


def _images_with_lines(images: List) -> List:
    """The images (keys of ``images``, in order of first appearance) with at least
    ``MIN_IMAGE_LINES`` curves: those that can be judged alone."""
    counts: Dict = {}
    for image in images:
        counts[image] = counts.get(image, 0) + 1
    return [k for k, n in counts.items() if n >= MIN_IMAGE_LINES]


def image_line_rms(term: StraightnessTerm, images: List, camera, other) -> Dict:
    """{image: (RMS px of its curves under ``camera``, under ``other``)} for every image with at
    least ``MIN_IMAGE_LINES`` curves (``images``: each curve's image), over the curves both cameras
    unproject (a point one of them has no ray for, a root its inverse misses, would make an RMS
    infinite: one point of 24,893 did so under a rendered phone lens's refined camera); an image
    with no such curve is left out."""
    a, b = term.curve_rms(camera), term.curve_rms(other)
    both = np.isfinite(a) & np.isfinite(b)
    of_image = np.array(images, dtype=object)
    out = {}
    for key in _images_with_lines(images):
        mask = both & (of_image == key)
        if mask.any():
            n = term.sizes[mask]
            out[key] = (float(np.sqrt(np.sum(a[mask] ** 2 * n) / n.sum())),
                        float(np.sqrt(np.sum(b[mask] ** 2 * n) / n.sum())))
    return out


def _image_straightened_worse(term: StraightnessTerm, images: List, refined, zs, names=None) -> Optional[str]:
    """Why the refined camera is refused when it straightens one image's lines worse than zero-shot
    does (their RMS more than ``MAX_IMAGE_WORSE`` times zero-shot's), among at least two images with
    ``MIN_IMAGE_LINES`` curves; None otherwise.

    Images of one camera are each straightened better by the camera fitted to all of them when it
    is nearer the truth than zero-shot: on the line benchmark's renders (one camera, four views)
    the accepted cameras straighten every view at least as well as zero-shot, to within 3 %; on
    the real photos of one camera each the largest ratio is 0.99. Images of two cameras (the same
    spec, principal points 54 px apart) are fitted by a camera between theirs, and where it is
    farther from one of them than zero-shot is, that camera's images say so: 1.2 to 2.7 times
    zero-shot's RMS in 8 of the 9 of 20 such sets that were accepted without this check, the
    ninth's camera as near each camera as zero-shot (test_refine's two-camera cases). What it
    does not see: two cameras as alike as a stereo pair's (MyntEye's left and right photos with
    the right camera's spec, principal points 11 px apart: the left image at 1.02, accepted 1.6 px
    at 1920 farther from the right camera than zero-shot; lines of 0.1 px noise do not tell them
    apart), nor the real mixes whose camera is nearer both than zero-shot is
    (benchmarks/results/mixed_cameras.md)."""
    ratios = image_line_rms(term, images, refined, zs)
    if len(ratios) < 2:
        return None
    key = max(ratios, key=lambda k: ratios[k][0] / ratios[k][1])
    after, before = ratios[key]
    if not after > MAX_IMAGE_WORSE * before:
        return None
    return (f'disagreement between images: the camera fitted to all the images straightens the lines of image '
            f'{_image_label(names, key)} worse than zero-shot does ({after:.3g} px RMS against {before:.3g} px) '
            '(images of different cameras or lens settings?)')


def _pixels_without_rays(camera, reference, width: int, height: int, seen=None) -> Optional[str]:
    """Why ``camera`` cannot be the image's camera, or None: it has no ray for a pixel of the
    image (of the image circle ``seen`` when one is, ``_seen_circle``) that ``reference``
    (zero-shot) has one for, i.e. its lens curve turns back inside the image, where no line held
    it. Such a camera cannot be rectified or undistorted where the scene is imaged: a real 752 x
    480 camera (EuRoC's) given hfov 93 and one photo whose lines stop short of the corners was
    fitted a Kannala-Brandt curve that turns over at 57 degrees, short of its corners, and was
    accepted before this check."""
    radius, centre = (None, None) if seen is None else seen
    pixels = pixel_grid(width, height, circle_radius=radius, circle_centre=centre)
    with np.errstate(invalid='ignore', over='ignore'):
        has = np.all(np.isfinite(reference.unproject(pixels)), axis=1)
        lost = has & ~np.all(np.isfinite(camera.unproject(pixels)), axis=1)
    if not lost.any():
        return None
    top = camera.theta_max if math.isfinite(getattr(camera, 'theta_max', math.nan)) else None
    if top is None:
        where = ''
    elif top < math.pi - 1e-6:
        where = f' (its lens curve turns back at {math.degrees(top):.0f} degrees off-axis)'
    else:  # rises to the model's end: a focal too short for the image, nothing turns back
        where = ' (its lens curve ends at 180 degrees off-axis, short of them)'
    over = ' of the image circle seen' if seen is not None else ''
    return (f'the camera that straightens the lines has no ray for {int(lost.sum())} of {int(has.sum())} grid pixels'
            f'{over} that zero-shot images{where}: no line reaches there to hold its lens curve; images with lines '
            'nearer the corners would')


def _seen_circle(image_circle):
    """(radius, (cx, cy)) of the image circle measured in the images, or None (none seen): the
    pixels where the refined camera and zero-shot are compared (their error bars, the chance that
    zero-shot is the nearer) and where a lower order's bias is measured. Nothing outside it is
    imaged: there a circular fisheye's dark corners lie past the last ray any line shows, where
    the Kannala-Brandt polynomials of two orders part by tens of pixels and a covariance grows
    without bound (a real 187 x 134-degree camera: its order-3 camera 12.6 px from the order-4
    one over the whole image, 1.2 px inside its circle; 14.8 px of covariance over the whole
    image, 2.5 px inside). The error bar a user is given stays over the whole image."""
    if image_circle is None:
        return None
    return float(image_circle.radius), (float(image_circle.cx), float(image_circle.cy))


def _widened(term, shape_sigma: float):
    """``term``, or a copy of it at ``shape_sigma`` when it is a ``ShapePrior``."""
    if not isinstance(term, ShapePrior):
        return term
    wide = copy.copy(term)
    wide.sigma_relative = float(shape_sigma)
    wide.sigma = wide.sigma_relative * math.sqrt(len(term.theta))
    return wide


def _fit_uncertainty(fit: LineFit, seen=None, shape_sigma: Optional[float] = None):
    """(Uncertainty, layout, x, jacobian) of the chosen camera under the highest-order model (RMS over the
    whole image; a lower order's bias measured inside the image circle ``seen`` when given,
    ``_seen_circle``).

    A lower order's own covariance is overconfident wherever its restriction stands in for
    evidence: with k1 alone free, lines "determine" the zoom that only the FOVs can (a lens of
    the benchmark: 0.9 px reported, 8.9 px true). So the covariance is the highest order's, at the
    chosen camera, inflated by the chosen camera's distance from the highest order's solution
    (the bias of the restriction), added in quadrature. ``shape_sigma``: the shape prior counted at
    this width (``ONE_CONSTRAINT_SHAPE_SPREAD``); the Jacobian returned is the fit's own."""
    top = fit.top_problem if fit.top_problem is not None else fit.problem
    layout = top.layout
    x = layout.x_from(fit.camera)
    radius, centre = (None, None) if seen is None else seen
    J = top.jacobian(x)
    stated, J_stated = top, J
    if shape_sigma is not None:
        stated = Problem(layout, [_widened(t, shape_sigma) for t in top.terms])
        J_stated = stated.jacobian(x)
    u = problem_uncertainty(stated, x, J_stated, clustered=CLUSTERED_COVARIANCE,
                            systematic_px=systematic_floor_px(fit.sigma_px))
    if u.rms_px is None or fit.top_solution is None or fit.order == layout.order:
        return u, layout, x, J
    rays = fit.camera.unproject(pixel_grid(fit.camera.width, fit.camera.height, circle_radius=radius,
                                           circle_centre=centre))
    rays = rays[np.all(np.isfinite(rays), axis=1)]
    bias = displacement(fit.camera, layout.camera(fit.top_solution.x), rays)
    bias_rms = float(np.sqrt(np.nanmean(np.sum(bias * bias, axis=1))))
    total = math.hypot(u.rms_px, bias_rms)
    scale = (total / u.rms_px) ** 2 if u.rms_px > 0 else 1.0
    u = Uncertainty(total, f'{u.reason}, order {fit.order} of {layout.order}: {bias_rms:.3g} px from the '
                    f'highest order added{" (inside the image circle seen)" if seen is not None else ""}',
                    covariance=u.covariance * scale, names=u.names, layout=layout, x=x)
    return u, layout, x, J


def _image_label(names: Optional[Sequence], image) -> str:
    """What a reason calls ``image`` (an id): its name when ``names`` has one, else the id."""
    if names is not None and isinstance(image, (int, np.integer)) and 0 <= image < len(names):
        return str(names[image])
    return str(image)


def _image_disagreement(fit: LineFit, term: StraightnessTerm, images: List, priors,
                        names: Optional[Sequence] = None) -> Optional[str]:
    """Why the fit fails when the images disagree (two cameras, two zoom settings); None when they
    agree, or when fewer than two images have ``MIN_IMAGE_LINES`` curves.

    Each such image g is fitted alone (its curves, the priors but the FOVs, the joint fit's noise
    sigma), which gives its camera x_g and covariance C_g (the gate's own: with the systematic
    floor ``SYSTEMATIC_PX``). Images of one camera give cameras that scatter about their
    precision-weighted mean as their covariances allow: Q = sum_g (x_g - mean)^T C_g^-1 (x_g - mean)
    is chi^2 with (K - 1) p degrees of freedom for K images and p parameters (the multivariate
    heterogeneity test of a meta-analysis, Cochran's Q). The images disagree when
    P(chi^2 > Q) < ``DISAGREEMENT_P``. The remaining priors (principal point, shape) are in every
    C_g and pull every x_g towards the same camera, so one camera's images scatter less than the
    C_g say: the test errs towards "they agree" (Q of 0.25 to 0.65 times its degrees of freedom on
    six lenses of the line benchmark and on three renders of one camera), while two cameras'
    images give 34 times (test_refine_cli's, principal points 30 px apart). The FOVs are left
    out because they are the other suspect (and so is the measured image circle, which would pull
    every image's principal point to the same place): a spec a few degrees off pulls each image's camera
    towards it by an amount that depends on how much that image's lines say, which made one
    camera's three images look apart (Q from 8 with the right spec to 31 for 14 degrees of
    freedom with hfov and dfov 8 degrees off); without them Q stays at 8 to 10, whatever the spec.

    A ratio of residuals does not see it: the RMS of a curve is mostly its noise, so each image
    alone is straightened to 0.75-0.95 of its residual under those two cameras' joint fit, where
    Q weighs every point's evidence."""
    from scipy.special import chdtrc  # chi^2's survival function (scipy.stats takes 1.5 s to import)
    keys = _images_with_lines(images)
    if len(keys) < 2:
        return None
    layout = fit.problem.layout
    keys_used, xs, covs = [], [], []
    for key in keys:
        mask = np.array([i == key for i in images])
        sub = term.subset(mask).with_sigma(fit.sigma_px)
        problem = Problem(layout, [sub] + [p for p in priors if not isinstance(p, (FovTerm, ImageCircleTerm))])
        solution = problem.solve(fit.x, max_nfev=30, ftol=SOLVE_TOL, xtol=SOLVE_TOL)
        u = problem_uncertainty(problem, solution.x, systematic_px=systematic_floor_px(fit.sigma_px))
        if u.covariance is None or not np.all(np.isfinite(solution.x)):
            continue  # this image alone does not determine a camera: it cannot disagree
        keys_used.append(key)
        xs.append(np.asarray(solution.x, dtype=float))
        covs.append(u.covariance)
    if len(xs) < 2:
        return None
    weights = [np.linalg.inv(c) for c in covs]
    total = sum(weights)
    mean = np.linalg.solve(total, sum(w @ x for w, x in zip(weights, xs)))
    q = float(sum((x - mean) @ w @ (x - mean) for w, x in zip(weights, xs)))
    dof = (len(xs) - 1) * len(mean)
    p = float(chdtrc(dof, q))
    if not p < DISAGREEMENT_P:
        return None

    def against_others(g):
        """(chi^2 of image g's camera against the others' weighted mean, that mean, the covariance
        of their difference)."""
        rest = total - weights[g]
        others = np.linalg.solve(rest, sum(w @ x for h, (w, x) in enumerate(zip(weights, xs)) if h != g))
        d = xs[g] - others
        spread = covs[g] + np.linalg.inv(rest)
        return float(d @ np.linalg.solve(spread, d)), others, spread

    scores = [against_others(g) for g in range(len(xs))]
    worst = max(range(len(xs)), key=lambda g: scores[g][0])
    _, others, spread = scores[worst]
    sd = np.sqrt(np.diag(covs[worst]))
    # the part of the camera that differs most (its chi^2 alone, as a p-value): a principal point
    # within its error bar is no reason to quote it, and the parts may differ only together
    d = xs[worst] - others
    parts = {'principal point': [layout.names.index('cx'), layout.names.index('cy')],
             'focal length': [layout.names.index('f')],
             'lens shape': [i for i, n in enumerate(layout.names) if n not in ('f', 'cx', 'cy')]}
    chances = {part: float(chdtrc(len(i), d[i] @ np.linalg.solve(spread[np.ix_(i, i)], d[i])))
               for part, i in parts.items() if i}
    part = min(chances, key=chances.get)
    if chances[part] >= DISAGREEMENT_P:
        detail = ('its camera as a whole (no one of its principal point, focal length and lens shape differs from '
                  'the others\' alone)')
    elif part == 'principal point':
        detail = (f'its principal point ({xs[worst][1]:.1f}, {xs[worst][2]:.1f}) +- ({sd[1]:.2g}, {sd[2]:.2g}) px '
                  f'against ({others[1]:.1f}, {others[2]:.1f}) from the others')
    elif part == 'focal length':
        detail = f'its focal length {xs[worst][0]:.1f} +- {sd[0]:.2g} px against {others[0]:.1f} from the others'
    else:
        detail = "the lens shape (distortion) its lines ask for"
    return (f'disagreement between images: the cameras their lines ask for one by one differ by more than their '
            f'uncertainties allow (chi^2 {q:.3g} for {dof} degrees of freedom, p = {p:.2g}); image '
            f'{_image_label(names, keys_used[worst])} differs most, in {detail} '
            '(images of different cameras or lens settings, or curves in some images that are not straight in the '
            'scene?)')


def _held_out(fit: LineFit, term: StraightnessTerm, held: np.ndarray, priors) -> tuple:
    """(held-out RMS under zero-shot, under the camera fitted without them) in px."""
    layout = fit.problem.layout
    train = term.subset(~held).with_sigma(fit.sigma_px)
    problem = Problem(layout, [train] + list(priors))
    solution = problem.solve(fit.x, ftol=SOLVE_TOL, xtol=SOLVE_TOL)
    test = term.subset(held)
    return test.rms(layout.base), test.rms(layout.camera(solution.x))


@dataclass
class RefineProgress:
    """What ``refine_from_images`` tells its ``progress`` callback after each image's detection
    and after each fit."""

    stage: str
    """'detection' (an image's curves were found) or 'fit' (a round's fit is done)."""
    round: int
    """The detection round, from 1."""
    rounds: int
    frames_done: int
    """Images detected in this round so far."""
    frames: int
    lines: int
    """Curves found so far in this round ('detection'), or the lines the fit used ('fit')."""
    camera: KannalaBrandtCamera
    """The current estimate: the camera the curves are detected with ('detection'), or the camera
    the fit returned, refined or zero-shot ('fit')."""
    accepted: Optional[bool] = None
    """Whether the fit's gate accepted it ('fit' only)."""


def refine_from_frames(spec: CameraSpec, curves: Sequence, images, width: int, height: int,
                       fov_tolerance_deg: float = FOV_TOLERANCE_DEG, initial: Optional[KannalaBrandtCamera] = None,
                       solution=None, image_circle=None, gradients: Optional[dict] = None,
                       image_names=None) -> Refinement:
    """``refine_camera`` over the curves of several frames of one moving camera, what stays put
    across them (``core.lines.static_curves``: the vehicle's or robot's own body in view, lens
    dirt) left out of the fit and listed in ``Refinement.static_curves``. ``images``: the frames,
    indexed by the curves' ``image``. What ``refine_from_images`` and the node's refine worker
    both fit. ``solution``: as ``refine_camera``'s. ``gradients``: a dict kept across calls on
    the same ``images`` (``static_curves``': their gradients computed once); ``image_names``: as
    ``refine_camera``'s, whose BLAS calls run in one thread (``problem.one_blas_thread``: the same
    numbers, without OpenBLAS's threads waiting for busy cores)."""
    from ..lines.static_curves import static_curves
    static = static_curves(curves, images, gradients)
    result = refine_camera(spec, [c for c, s in zip(curves, static) if not s], width, height,
                           fov_tolerance_deg, initial=initial, solution=solution, image_circle=image_circle,
                           image_names=image_names)
    result.static_curves = [c for c, s in zip(curves, static) if s]
    return result


def refine_from_images(spec: CameraSpec, images: Sequence, fov_tolerance_deg: float = FOV_TOLERANCE_DEG,
                       rounds: int = 2, workers: int = 1, regions: Optional[Sequence] = None,
                       use_image_circle: bool = True, progress: Optional[Callable[[RefineProgress], None]] = None,
                       solution=None, image_names=None, **detect_options) -> Refinement:
    """Detect curves in ``images`` (grey or BGR arrays, all one size) with the zero-shot camera,
    fit, make curves again of the same edge points under the refined camera (``find_edges`` once,
    ``curves_from_edges`` per round) and fit again (``rounds`` fits in all).

    Needs ``core.lines.detect`` (imported here, not at module load, so that the estimator works
    without the detector). ``workers`` > 1: several images are detected in that many worker
    processes at once (``core.lines.detection_processes``: fresh interpreters, started and ended
    by this call; the caller's ``__main__`` is not run again), the views of one image in that many
    threads, and the fits' Jacobians computed in that many threads (``problem.jacobian_threads``);
    the first round's curves are the same, in the same order, and the Jacobians the same as in
    one thread (up to the last digits of a BLAS whose sums depend on where the arrays lie in
    memory, as numpy 1.26's OpenBLAS does on some CPUs, run to run).

    Each image's usable region (``core.lines.image_region.find_image_region``, or ``regions`` if
    already found) keeps the detector off an image circle's boundary and off black borders; the
    image circles seen are combined (``combine_circles``: one camera) and, with
    ``use_image_circle``, are evidence of the principal point and, with the spec's circle FOV, of
    the scale (``refine_camera``'s ``image_circle``). Curves that stay put across the images
    (``core.lines.static_curves``: the vehicle's or robot's body in view) are left out of every
    fit (``Refinement.static_curves``).

    ``progress``: called with a ``RefineProgress`` after each image's detection and after each
    fit (in the calling thread, whatever ``workers``); what it does changes nothing here.
    ``image_names``: what a reason calls each image (e.g. its file), in the order of ``images``.

    The spec's zero-shot result (``zero_shot.zero_shot_start``: the solution, its Kannala-Brandt
    camera at the images' size, its error bar) is made once, from ``solution`` when given (a
    ``ZeroShotSolution``, or a ``ZeroShotStart`` of the images' size and ``fov_tolerance_deg``), and
    passed to every round's fit."""
    from ..lines.detect import curves_from_edges, make_views
    from ..lines.detection_processes import DetectionProcesses, detect_image
    from ..lines.image_region import combine_circles
    images = list(images)
    if not images:
        raise ValueError('no images given')
    sizes = {tuple(np.asarray(im).shape[:2]) for im in images}
    if len(sizes) != 1:
        raise ValueError('images have different sizes: ' + ', '.join(f'{w}x{h}' for h, w in sorted(sizes)))
    (height, width), = sizes
    if regions is not None and len(regions) != len(images):
        raise ValueError(f'{len(regions)} regions for {len(images)} images')
    regions = list(regions) if regions is not None else [None] * len(images)  # None: found with the edges
    start = zero_shot_start(spec, width, height, fov_tolerance_deg, solution)
    camera = start.camera
    result = None
    total_rounds = max(1, rounds)
    edges = [None] * len(images)
    gradients = {}  # static_curves' image gradients, the same in every round
    # several images on several cores: in worker processes (detection_processes: threads would
    # share one core, the merging of pieces holds the GIL); the same function either way
    several = workers > 1 and len(images) > 1
    with DetectionProcesses(min(workers, len(images))) if several else nullcontext() as processes:
        for round_index in range(total_rounds):
            curves = []

            def detected(done, camera=camera, round_index=round_index):
                if progress is not None:
                    progress(RefineProgress('detection', round_index + 1, total_rounds, done, len(images),
                                            len(curves), camera))

            # the edge points are looked for once, with zero-shot's camera (its FOVs rounded:
            # zero_shot.ZeroShotStart.detection_camera); later rounds make curves
            # of them under the refined camera (pieces straight under it, merged), which is where a
            # better camera changes the evidence: longer lines pass the straightness test and merge
            look = start.detection_camera
            first = round_index == 0
            if first:
                # static_curves' gradients of each image, made beside its detection
                jobs = [((image, look, camera, regions[i], i, len(images) > 1), detect_options)
                        for i, image in enumerate(images)]
            else:
                jobs = [((edges[i], camera, i), {}) for i in range(len(images))]
            if processes is not None:
                found = processes.map('detect_image' if first else 'curves_from_edges', jobs)
            elif first:
                views = make_views(look, workers=workers)
                found = (detect_image(*args, views=views, **kwargs) for args, kwargs in jobs)
            else:
                found = (curves_from_edges(*args) for args, _ in jobs)
            for index, answer in enumerate(found):
                if first:
                    regions[index], edges[index], answer, image_gradient = answer
                    if image_gradient is not None:
                        gradients[index] = image_gradient
                curves += answer
                detected(index + 1)
            circle = combine_circles([r.circle for r in regions])
            measured_in = sum(r.circle is not None for r in regions)
            with jacobian_threads(workers):
                attempt = refine_from_frames(spec, curves, images, width, height, fov_tolerance_deg,
                                             initial=camera if result is not None else None, solution=start,
                                             image_circle=circle if use_image_circle else None, gradients=gradients,
                                             image_names=image_names)
            attempt.image_circle, attempt.circle_measured_in = circle, measured_in
            if progress is not None:
                progress(RefineProgress('fit', round_index + 1, total_rounds, len(images), len(images),
                                        attempt.lines_used, attempt.camera, attempt.accepted))
            if result is not None and not attempt.accepted:
                break
            result = attempt
            if not attempt.accepted:
                break
            camera = attempt.camera
    return result
