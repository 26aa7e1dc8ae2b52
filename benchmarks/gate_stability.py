#!/usr/bin/env python3
"""Stability of the refinement gate: does ``refine_from_images`` 's decision (and the camera it
returns) change smoothly with its input?

Per case, a baseline run and perturbed runs of ``refine_from_images`` (module docstring of
``core/estimation/refine.py`` for the gate):

- ``fov+0.01`` / ``fov-0.01``: every FOV of the spec (hfov, vfov, dfov, and the circle FOV of the
  circular form; not the circle's diameter) moved by +0.01 / -0.01 degree (``--fov-delta``);
- ``jpeg95``: every image re-encoded as JPEG at quality 95 (``--jpeg-quality``; cv2.imencode /
  imdecode);
- ``reversed``: the images in reverse order; ``rotated``: the first image moved to the end (the
  orders that repeat the baseline or another order are left out: none with one image, only
  ``reversed`` with two).

Cases:

- every real camera of ``benchmarks/real_photos.py`` (``benchmarks/data/real_cameras.csv``, photos
  under ``--photos``/<camera>/): its spec (``real_photos.spec_of``), its ``--images`` photos
  evenly through its set (``real_photos.evenly``), read grey, its truth trusted over
  ``real_photos.trusted_pixels``;
- ``--lenses`` rendered lenses: the wide square-pixel profiles of
  ``benchmarks/line_refinement.py --evidence images`` (``$ZEROSHOT_SHARED_DATA/lens_profiles_dev.csv``),
  that many evenly through them (``line_refinement.evenly``), scaled to ``--image-width`` px,
  ``--views`` views of ``--scene`` rendered by ``line_refinement.render_views`` (with
  ``--nuisances``; ``--cache`` keeps the renders: the same file names as line_refinement's
  ``--render-cache``), spec ``line_refinement.profile_spec``, errors over
  ``line_refinement.error_pixels``.

Per run: the decision (accepted or not), the returned camera's error against the truth and its
change against the baseline's returned camera, both with the lens benchmark's metric
(``lens_profiles.best_rotation_rms``: RMS pixel displacement after the best rotation, scaled to
1920 px wide) over the case's error pixels (the change: over those of them the baseline camera
images). Also the fitted camera's change (accepted or not) against the baseline's fitted one:
whether the fit moved or only the gate's verdict did. Totals: the share of perturbed runs whose
decision differs from their baseline's (a flip), the largest change among runs with the
baseline's decision and among flips.

    ZEROSHOT_SHARED_DATA=/work/shared/data nice -n 10 .venv/bin/python benchmarks/gate_stability.py \\
        --cache /tmp/gs/cache --dump /tmp/gs/dump --out benchmarks/results/gate_stability.md
    # resume: the same command (runs already in --dump are read back, not run again);
    # shards: --shard K/N --dump DIR in each, then --rows-from DIR[,DIR] for the report

One run costs about 2 detection rounds x ~3 s per 960 x 540 image on one core; there is no
``--jobs`` (the machine's cores are shared): run shards in separate processes if wanted.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import pickle
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / 'benchmarks'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

import lens_profiles as lp  # noqa: E402
from zeroshot_calib_ros.core.estimation import refine as refine_module  # noqa: E402
from zeroshot_calib_ros.core.estimation.refine import refine_from_images  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec, SpecError  # noqa: E402

BASELINE = 'baseline'
PERTURBATIONS = ('fov+', 'fov-', 'jpeg', 'reversed', 'rotated')
SECONDS_PER_MEGAPIXEL_ROUND = 3.0 / (960 * 540 / 1e6)
"""Estimate of a run's cost: ~3 s per 960 x 540 image per detection round (2 rounds)."""
SECONDS_PER_RUN = 4.0
"""And a run's fixed cost (zero-shot solve, fits, uncertainty)."""


# ---------------------------------------------------------------------------------------------
# Perturbations (pure)


def perturb_spec(spec: CameraSpec, delta_deg: float) -> CameraSpec:
    """``spec`` with every FOV it states (hfov, vfov, dfov, circle_fov) moved by ``delta_deg``;
    the image size and the circle's diameter unchanged."""
    changes = {k: v + delta_deg for k, v in spec.given().items()}
    if spec.circle_fov is not None:
        changes['circle_fov'] = spec.circle_fov + delta_deg
    return dataclasses.replace(spec, **changes)


def jpeg(image: np.ndarray, quality: int = 95) -> np.ndarray:
    """``image`` encoded as JPEG at ``quality`` and decoded again (same shape and dtype)."""
    ok, data = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError('JPEG encoding failed')
    out = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if out.ndim == 3 and image.ndim == 2:  # never expected: a grey JPEG decodes grey
        out = cv2.cvtColor(out, cv2.COLOR_BGR2GRAY)
    return out


def orders(n: int) -> Dict[str, List[int]]:
    """The image orders tried for ``n`` images: ``reversed`` and ``rotated`` (the first image
    last), leaving out any that repeats the identity or an earlier order."""
    out: Dict[str, List[int]] = {}
    identity = list(range(n))
    for name, order in (('reversed', identity[::-1]), ('rotated', identity[1:] + identity[:1])):
        if order != identity and order not in out.values():
            out[name] = order
    return out


def perturbation_names(n_images: int, delta_deg: float = 0.01, quality: int = 95) -> Dict[str, str]:
    """{key: label} of the perturbed runs of a case with ``n_images`` images."""
    labels = {'fov+': f'fov+{delta_deg:g}', 'fov-': f'fov-{delta_deg:g}', 'jpeg': f'jpeg{quality}'}
    labels.update({k: k for k in orders(n_images)})
    return labels


def perturbed(spec: CameraSpec, images: Sequence[np.ndarray], key: str, delta_deg: float = 0.01,
              quality: int = 95):
    """(spec, images, image order) of the run ``key`` (BASELINE or one of PERTURBATIONS)."""
    identity = list(range(len(images)))
    if key == BASELINE:
        return spec, list(images), identity
    if key == 'fov+':
        return perturb_spec(spec, +delta_deg), list(images), identity
    if key == 'fov-':
        return perturb_spec(spec, -delta_deg), list(images), identity
    if key == 'jpeg':
        return spec, [jpeg(im, quality) for im in images], identity
    order = orders(len(images))[key]
    return spec, [images[i] for i in order], order


# ---------------------------------------------------------------------------------------------
# Cases


@dataclass
class Case:
    name: str
    kind: str
    """'camera' (real photos) or 'lens' (rendered)."""
    label: str
    load: Callable
    """() -> (spec, images, truth rays (N, 3), pixels (N, 2)) at the images' size."""
    width: int
    height: int
    images: int


def camera_cases(photos: Path, images: int) -> List[Case]:
    import real_photos as rp
    out = []
    for camera in rp.load_cameras(photos=photos):
        def load(camera=camera):
            if not camera.photos:
                raise ValueError(f'photos absent under {photos}: run benchmarks/fetch_real_cameras.py')
            spec = rp.spec_of(camera)
            frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in rp.evenly(camera.photos, images)]
            rays, pixels = rp.trusted_pixels(camera)
            return spec, frames, rays, pixels
        n = len(rp.evenly(camera.photos, images))
        out.append(Case(camera.name, 'camera', camera.name, load, camera.width, camera.height, n))
    return out


def lens_args(args) -> argparse.Namespace:
    """The ``line_refinement`` options its helpers read, for ``--evidence images``."""
    return argparse.Namespace(evidence='images', fov_round=0.0, nuisances=args.nuisances, scene=args.scene,
                              views=args.views, render_cache=args.cache, image_width=args.image_width,
                              seed=args.seed)


def lens_cases(args) -> List[Case]:
    import line_refinement as lr
    la = lens_args(args)
    out = []
    if args.lenses <= 0:
        return out
    for p, fovs in lr.evenly(lr.wide_square_profiles(args.csv), args.lenses):
        gt = lr._scaled_profile(p, fovs, la.image_width)

        def load(p=p, fovs=fovs, gt=gt):
            spec = lr.profile_spec(gt, fovs, la)
            images = lr.render_views(p, gt, la, lr.profile_seed(la, p))
            pixels = lr.error_pixels(gt, la)
            return spec, images, gt.unproject(pixels), pixels
        label = f'lens{p.index} ({Path(p.path).stem[:48]})'
        out.append(Case(f'lens{p.index}', 'lens', label, load, gt.width, gt.height, la.views))
    return out


# ---------------------------------------------------------------------------------------------
# Runs


@dataclass
class Run:
    case: str
    key: str
    """BASELINE or a key of PERTURBATIONS."""
    label: str
    order: List[int] = field(default_factory=list)
    accepted: bool = False
    reason: str = ''
    failure: str = ''
    error_px: float = math.nan
    """Returned camera against the truth, px at 1920."""
    fitted_error_px: float = math.nan
    zero_shot_error_px: float = math.nan
    camera: object = None
    """The returned camera."""
    fitted: object = None
    """The fitted camera (accepted or not), None when no fit was made."""
    pixels: Optional[np.ndarray] = None
    scale: float = 1.0
    lines: int = 0
    curves: int = 0
    model_order: Optional[int] = None
    p_zero_shot_better: Optional[float] = None
    zero_shot_distance_px: Optional[float] = None
    held_out_before: Optional[float] = None
    held_out_after: Optional[float] = None
    uncertainty_px: Optional[float] = None
    fitted_uncertainty_px: Optional[float] = None
    zero_shot_uncertainty_px: Optional[float] = None
    fov_residuals_deg: Dict[str, float] = field(default_factory=dict)
    sigma_px: Optional[float] = None
    coverage: float = math.nan
    reach: float = math.nan
    circle_measured_in: int = 0
    seconds: float = math.nan
    rounds: List[dict] = field(default_factory=list)
    """Every detection round's ``refine_camera`` verdict (``_round``), in order."""
    returned_round: Optional[int] = None
    """Which of them (1-based) ``refine_from_images`` returned (an accepted round 1 is returned
    when round 2 refuses)."""


def _round(result, scale: float) -> dict:
    """What one round's refinement decided, and the numbers behind it."""
    return {'accepted': bool(result.accepted), 'reason': result.reason, 'lines': result.lines_used,
            'curves': result.curves_given, 'order': result.order,
            'p_zero_shot_better': result.zero_shot_better_probability,
            'zero_shot_distance_px': None if result.zero_shot_distance_px is None
            else result.zero_shot_distance_px * scale,
            'held_out': (result.held_out_px_before, result.held_out_px_after),
            'uncertainty_px': None if result.refined_uncertainty_px is None else result.refined_uncertainty_px * scale}


def refine_recording_rounds(spec, images, **options):
    """(``refine_from_images`` 's result, [each round's ``refine_camera`` result]): its calls of
    ``refine_camera`` are recorded by wrapping the module's function for the call."""
    attempts = []
    original = refine_module.refine_camera

    def recording(*args, **kwargs):
        attempts.append(original(*args, **kwargs))
        return attempts[-1]

    refine_module.refine_camera = recording
    try:
        return refine_from_images(spec, images, **options), attempts
    finally:
        refine_module.refine_camera = original


def execute(case: Case, key: str, spec, images, rays, pixels, args, label: str) -> Run:
    spec_k, images_k, order = perturbed(spec, images, key, args.fov_delta, args.jpeg_quality)
    run = Run(case.name, key, label, order)
    scale = lp.REFERENCE_WIDTH / case.width
    run.pixels, run.scale = pixels, scale
    start = time.perf_counter()
    try:
        result, attempts = refine_recording_rounds(spec_k, images_k, fov_tolerance_deg=args.fov_tolerance)
    except (SpecError, ValueError) as exc:
        run.failure = f'{type(exc).__name__}: {exc}'
        return run
    run.seconds = time.perf_counter() - start

    def err(c):
        return lp.best_rotation_rms(c, rays, pixels)[0] * scale if c is not None else math.nan

    run.accepted, run.reason = bool(result.accepted), result.reason
    run.camera, run.fitted = result.camera, result.refined_camera
    run.error_px, run.fitted_error_px, run.zero_shot_error_px = (err(result.camera), err(result.refined_camera),
                                                                 err(result.zero_shot_camera))
    run.lines, run.curves, run.model_order = result.lines_used, result.curves_given, result.order
    run.p_zero_shot_better = result.zero_shot_better_probability
    run.zero_shot_distance_px = None if result.zero_shot_distance_px is None else result.zero_shot_distance_px * scale
    run.held_out_before = result.held_out_px_before
    run.held_out_after = result.held_out_px_after
    px = (lambda v: None if v is None else v * scale)  # noqa: E731
    run.uncertainty_px = px(result.uncertainty_px)
    run.fitted_uncertainty_px = px(result.refined_uncertainty_px)
    run.zero_shot_uncertainty_px = px(result.zero_shot_uncertainty_px)
    run.fov_residuals_deg = dict(result.fov_residuals_deg)
    run.sigma_px = result.sigma_px
    run.coverage, run.reach = result.coverage, result.reach
    run.circle_measured_in = result.circle_measured_in
    run.rounds = [_round(a, scale) for a in attempts]
    run.returned_round = next((i + 1 for i, a in enumerate(attempts) if a is result), None)
    return run


def change_px(camera, reference, pixels: np.ndarray, scale: float) -> float:
    """RMS displacement (px, times ``scale``) of ``camera`` against ``reference`` after the best
    rotation, over the ``pixels`` that ``reference`` images."""
    if camera is None or reference is None:
        return math.nan
    rays = reference.unproject(pixels)
    ok = np.all(np.isfinite(rays), axis=1)
    if ok.sum() < 3:
        return math.nan
    return lp.best_rotation_rms(camera, rays[ok], pixels[ok])[0] * scale


def _file(dump: str, case: str, key: str) -> str:
    return os.path.join(dump, f'{case}__{key}.run.pkl')


class _Unpickler(pickle.Unpickler):
    """Reads the runs a ``__main__`` (this script run as one) pickled, from any module."""

    def find_class(self, module, name):
        if module == '__main__' and name == 'Run':
            return Run
        return super().find_class(module, name)


def load_run(path: str) -> Run:
    with open(path, 'rb') as f:
        return _Unpickler(f).load()


def load_runs(directories: Sequence[str]) -> List[Run]:
    return [load_run(os.path.join(directory, name)) for directory in directories
            for name in sorted(os.listdir(directory)) if name.endswith('.run.pkl')]


# ---------------------------------------------------------------------------------------------
# Flips and changes (pure, over Runs)


@dataclass
class Compared:
    run: Run
    flip: bool
    change_px: float
    fitted_change_px: float


def compare(runs: Sequence[Run]) -> Dict[str, List[Compared]]:
    """{case: [Compared for each perturbed run of the case]}: a flip is a decision other than the
    baseline's; cases without a (successful) baseline are left out, failed runs too."""
    by_case: Dict[str, Dict[str, Run]] = {}
    for r in runs:
        by_case.setdefault(r.case, {})[r.key] = r
    out: Dict[str, List[Compared]] = {}
    for case, keyed in by_case.items():
        base = keyed.get(BASELINE)
        if base is None or base.failure:
            continue
        out[case] = [Compared(r, r.accepted != base.accepted, change_px(r.camera, base.camera, base.pixels, base.scale),
                              change_px(r.fitted, base.fitted, base.pixels, base.scale))
                     for k, r in keyed.items() if k != BASELINE and not r.failure]
    return out


def totals(compared: Dict[str, List[Compared]]) -> dict:
    """Share of perturbed runs that flip, and the largest change among same-decision runs and
    among flips (NaN when there are none)."""
    every = [c for cs in compared.values() for c in cs]
    same = [c.change_px for c in every if not c.flip and math.isfinite(c.change_px)]
    flips = [c.change_px for c in every if c.flip and math.isfinite(c.change_px)]
    return {'runs': len(every), 'flips': sum(c.flip for c in every),
            'flip_share': sum(c.flip for c in every) / len(every) if every else math.nan,
            'max_change_same_px': max(same) if same else math.nan,
            'max_change_flip_px': max(flips) if flips else math.nan,
            'cases_with_flip': sum(any(c.flip for c in cs) for cs in compared.values())}


# ---------------------------------------------------------------------------------------------
# Report


def _f(x, d=2):
    return '-' if x is None or (isinstance(x, float) and not math.isfinite(x)) else f'{x:.{d}f}'


def _yes(b):
    return 'yes' if b else 'no'


def _cell(c: Optional[Compared]) -> str:
    if c is None:
        return 'n/a'
    if c.flip:
        return f'**{_yes(c.run.accepted)}, FLIP**, {_f(c.change_px)}'
    return f'{_yes(c.run.accepted)}, no flip, {_f(c.change_px)}'


def _p(v):
    return '-' if v is None else f'{v:.3g}'


def _rounds(r: Run) -> str:
    """Each round's verdict (y / n), the returned one starred: 'y* n' is round 1 accepted, round 2
    refused, round 1 returned."""
    return ' '.join(('y' if a['accepted'] else 'n') + ('*' if i + 1 == r.returned_round else '')
                    for i, a in enumerate(r.rounds)) or '-'


def _diagnostics(r: Run) -> str:
    fov = ', '.join(f'{k} {v:+.2f}' for k, v in r.fov_residuals_deg.items())
    return (f'lines {r.lines}/{r.curves}, order {r.model_order}, sigma {_p(r.sigma_px)} px, held-out '
            f'{_p(r.held_out_after)} vs zero-shot {_p(r.held_out_before)} px, u {_p(r.fitted_uncertainty_px)} '
            f'vs zero-shot {_p(r.zero_shot_uncertainty_px)} px, P(zero-shot better) {_p(r.p_zero_shot_better)}, '
            f'distance to zero-shot {_p(r.zero_shot_distance_px)} px, FOV residuals (deg) {fov or "-"}, '
            f'coverage {_f(r.coverage)} reach {_f(r.reach)}, circle seen in {r.circle_measured_in}; '
            f'round {r.returned_round} of {len(r.rounds)} returned' + ''.join(
                f'; round {i + 1}: {_yes(a["accepted"])}, {a["lines"]} lines, order {a["order"]}, P(zero-shot better) '
                f'{_p(a["p_zero_shot_better"])}, distance {_p(a["zero_shot_distance_px"])} px'
                + ('' if a['accepted'] else f' ({a["reason"][:120]})') for i, a in enumerate(r.rounds)))


def report(cases: List[Case], runs: List[Run], command: str, seconds: float, args) -> str:
    compared = compare(runs)
    by_case: Dict[str, Dict[str, Run]] = {}
    for r in runs:
        by_case.setdefault(r.case, {})[r.key] = r
    t = totals(compared)
    labels = perturbation_names(4, args.fov_delta, args.jpeg_quality)
    lines = ['## Stability of the refinement gate under small input perturbations', '',
             f'`{command}` ({seconds:.0f} s of runs).', '',
             f'Perturbations: every FOV of the spec {labels["fov+"][3:]} / -{args.fov_delta:g} degree '
             f'(circle FOV included, circle diameter not); every image re-encoded as JPEG at quality '
             f'{args.jpeg_quality}; the images reversed; the first image moved last (`rotated`; orders that '
             'repeat another are n/a). Cases: the real cameras of benchmarks/real_photos.py '
             f'({args.images} photos each, its spec and truth), and rendered lenses of '
             f'benchmarks/line_refinement.py --evidence images (scene `{args.scene}`, {args.views} views at '
             f'{args.image_width} px wide, nuisances `{args.nuisances}`, exact h + v + d spec).', '',
             'Error: the returned camera (refined when accepted, else zero-shot) against the truth; change: the '
             'returned camera against the baseline\'s returned camera. Both RMS px after the best rotation at 1920 '
             'px wide (lens_profiles.best_rotation_rms) over the case\'s error pixels (real: where the truth is '
             'trusted; lenses: the 33 x 19 grid, or inside the image circle with nuisances). A cell: decision '
             '(accepted?), flip against the baseline, change px.', '',
             '### Totals', '',
             f'- perturbed runs: {t["runs"]} in {len(compared)} cases; decision flips: {t["flips"]} '
             f'({100 * t["flip_share"]:.1f} %), in {t["cases_with_flip"]} case(s)' if t['runs'] else '- no runs',
             f'- largest change of the returned camera, same decision as the baseline: '
             f'{_f(t["max_change_same_px"])} px at 1920',
             f'- largest change of the returned camera, flipped decision: {_f(t["max_change_flip_px"])} px at 1920']
    per_kind = {}
    for key in PERTURBATIONS:
        cs = [c for v in compared.values() for c in v if c.run.key == key]
        if cs:
            per_kind[key] = (sum(c.flip for c in cs), len(cs))
    if per_kind:
        lines.append('- flips per perturbation: ' + ', '.join(
            f'{labels.get(k, k)} {f} / {n}' for k, (f, n) in per_kind.items()))
    fitted = [c.fitted_change_px for v in compared.values() for c in v if math.isfinite(c.fitted_change_px)]
    if fitted:
        lines.append(f'- the fitted camera (accepted or not) against the baseline\'s fitted camera: median '
                     f'{_f(float(np.median(fitted)))} px, largest {_f(max(fitted))} px at 1920')
    failed = [r for r in runs if r.failure]
    if failed:
        lines.append(f'- failed runs ({len(failed)}): ' + '; '.join(f'{r.case} {r.label}: {r.failure[:100]}'
                                                                 for r in failed[:10]))
    lines += ['', '### Per case', '',
              '| case | images | baseline: accepted, error px | ' + ' | '.join(labels[k] for k in PERTURBATIONS)
              + ' |', '|---|---:|---|' + '---|' * len(PERTURBATIONS)]
    for case in cases:
        keyed = by_case.get(case.name)
        if not keyed or BASELINE not in keyed:
            continue
        base = keyed[BASELINE]
        if base.failure:
            lines.append(f'| {case.label} | {case.images} | failed: {base.failure[:80]} |' + ' |' * len(PERTURBATIONS))
            continue
        cs = {c.run.key: c for c in compared.get(case.name, [])}
        lines.append(f'| {case.label} | {case.images} | {_yes(base.accepted)}, {_f(base.error_px)} | '
                     + ' | '.join(_cell(cs.get(k)) for k in PERTURBATIONS) + ' |')
    flips = [(case, c) for case in cases for c in compared.get(case.name, []) if c.flip]
    if flips:
        lines += ['', '### The flips', '']
        for case, c in flips:
            base = by_case[case.name][BASELINE]
            lines += [f'- **{case.label}, {c.run.label}**: {_yes(base.accepted)} -> {_yes(c.run.accepted)}; '
                      f'error {_f(base.error_px)} -> {_f(c.run.error_px)} px, change {_f(c.change_px)} px, fitted '
                      f'camera moved {_f(c.fitted_change_px)} px (fitted error {_f(base.fitted_error_px)} -> '
                      f'{_f(c.run.fitted_error_px)} px)',
                      f'  - baseline: {base.reason}',
                      f'    ({_diagnostics(base)})',
                      f'  - {c.run.label}: {c.run.reason}',
                      f'    ({_diagnostics(c.run)})']
    lines += ['', '### Every run', '',
              '| case | run | accepted | error px | change px | fitted error px | fitted change px | lines | order '
              '| P(zs better) | held-out px (refined / zs) | rounds | s | reason |',
              '|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|---|---:|---|']
    for case in cases:
        keyed = by_case.get(case.name, {})
        cs = {c.run.key: c for c in compared.get(case.name, [])}
        for key in (BASELINE,) + PERTURBATIONS:
            r = keyed.get(key)
            if r is None:
                continue
            c = cs.get(key)
            lines.append(f'| {case.name} | {r.label} | {_yes(r.accepted)} | {_f(r.error_px)} | '
                         f'{_f(c.change_px) if c else "-"} | {_f(r.fitted_error_px)} | '
                         f'{_f(c.fitted_change_px) if c else "-"} | {r.lines} | {r.model_order} | '
                         f'{_p(r.p_zero_shot_better)} | {_p(r.held_out_after)} / {_p(r.held_out_before)} | '
                         f'{_rounds(r)} | {_f(r.seconds, 0)} | {(r.failure or r.reason)[:160]} |')
    return '\n'.join(lines) + '\n'


# ---------------------------------------------------------------------------------------------
# Main


def estimate_seconds(case: Case, runs: int) -> float:
    return runs * (SECONDS_PER_RUN + 2 * case.images * case.width * case.height / 1e6 * SECONDS_PER_MEGAPIXEL_ROUND)


def main(argv=None) -> int:
    import real_photos as rp
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--photos', default=str(rp.PHOTOS), help='real photos: the directory holding '
                        '<camera>/ folders (default %(default)s)')
    parser.add_argument('--images', type=int, default=4, help='real photos per camera, evenly through its set')
    parser.add_argument('--lenses', type=int, default=20, help='rendered lenses, evenly through the profiles '
                        '(0: none)')
    parser.add_argument('--views', type=int, default=4, help='rendered views per lens')
    parser.add_argument('--image-width', type=int, default=960)
    parser.add_argument('--scene', default='room')
    parser.add_argument('--nuisances', choices=('none', 'circle', 'all'), default='none')
    parser.add_argument('--cache', help='directory where rendered views are kept and read back')
    parser.add_argument('--csv', default=str(lp.DEFAULT_CSV), help='lens profiles')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--fov-tolerance', type=float, default=1.0)
    parser.add_argument('--fov-delta', type=float, default=0.01, help='degrees added to / taken from every FOV')
    parser.add_argument('--jpeg-quality', type=int, default=95)
    parser.add_argument('--only', default='', help='comma-separated case names (camera names, lens<index>)')
    parser.add_argument('--no-cameras', action='store_true', help='leave out the real cameras')
    parser.add_argument('--dump', help='keep every run here (pickle); runs already there are read back, not run')
    parser.add_argument('--shard', help='K/N: only every N-th case from the K-th')
    parser.add_argument('--rows-from', help='comma-separated --dump directories: report their runs, run nothing')
    parser.add_argument('--out', help='write the markdown report here too')
    args = parser.parse_args(argv)
    command = 'benchmarks/gate_stability.py ' + ' '.join(argv if argv is not None else sys.argv[1:])
    only = {n for n in args.only.split(',') if n}

    cases: List[Case] = []
    if not args.no_cameras:
        cases += camera_cases(Path(args.photos), args.images)
    if args.lenses > 0:
        if not os.path.exists(args.csv):
            print(f'gate_stability: error: {args.csv} not found (set ZEROSHOT_SHARED_DATA)', file=sys.stderr)
            return 2
        cases += lens_cases(args)
    if only:
        unknown = only - {c.name for c in cases}
        if unknown:
            print(f'gate_stability: warning: no such case(s): {", ".join(sorted(unknown))}', file=sys.stderr)
        cases = [c for c in cases if c.name in only]
    shard, shards = (int(v) for v in args.shard.split('/')) if args.shard else (0, 1)
    mine = [c for k, c in enumerate(cases) if k % shards == shard]

    if args.rows_from:
        runs = load_runs(args.rows_from.split(','))
        names = {c.name for c in cases}
        runs = [r for r in runs if r.case in names]
        text = report(cases, runs, command.strip(), sum(r.seconds for r in runs if math.isfinite(r.seconds)), args)
    else:
        if args.dump:
            os.makedirs(args.dump, exist_ok=True)
        plan = [(c, [BASELINE] + list(perturbation_names(c.images, args.fov_delta, args.jpeg_quality))) for c in mine]
        todo = [(c, [k for k in keys if not (args.dump and os.path.exists(_file(args.dump, c.name, k)))])
                for c, keys in plan]
        estimate = sum(estimate_seconds(c, len(keys)) for c, keys in todo)
        print(f'gate_stability: {len(mine)} case(s), {sum(len(k) for _, k in todo)} run(s) to do '
              f'({sum(len(k) for _, k in plan)} in all); estimated {estimate / 60:.0f} min on one idle core '
              f'(~{SECONDS_PER_MEGAPIXEL_ROUND * 0.5184:.0f} s per 960 x 540 image per detection round, 2 rounds)',
              file=sys.stderr, flush=True)
        runs: List[Run] = []
        start = time.perf_counter()
        done_estimate = 0.0
        for n, ((case, keys), (_, every)) in enumerate(zip(todo, plan)):
            t0 = time.perf_counter()
            case_runs: List[Run] = []
            previous = [k for k in every if k not in keys]
            for k in previous:
                case_runs.append(load_run(_file(args.dump, case.name, k)))
            if keys:
                labels = {BASELINE: BASELINE, **perturbation_names(case.images, args.fov_delta, args.jpeg_quality)}
                try:
                    spec, images, rays, pixels = case.load()
                except (SpecError, ValueError) as exc:
                    failed = Run(case.name, BASELINE, BASELINE, failure=f'{type(exc).__name__}: {exc}')
                    case_runs.append(failed)
                    keys = []
                    print(f'[{n + 1}/{len(todo)}] {case.name}: {failed.failure}', file=sys.stderr, flush=True)
                for key in keys:
                    run = execute(case, key, spec, images, rays, pixels, args, labels[key])
                    case_runs.append(run)
                    if args.dump:
                        with open(_file(args.dump, case.name, key), 'wb') as f:
                            pickle.dump(run, f)
                    print(f'  {case.name} {run.label}: {"accepted" if run.accepted else "refused"} '
                          f'{_f(run.error_px)} px, {run.lines} lines, {_f(run.seconds, 0)} s; '
                          f'{(run.failure or run.reason)[:100]}', file=sys.stderr, flush=True)
            runs += case_runs
            cs = compare(case_runs).get(case.name, [])
            done_estimate += estimate_seconds(case, len(keys))
            elapsed = time.perf_counter() - start
            left = (estimate - done_estimate) * (elapsed / done_estimate if done_estimate > 0 else 1.0)
            print(f'[{n + 1}/{len(todo)}] {case.name}: {len(keys)} run(s) in {time.perf_counter() - t0:.0f} s; '
                  f'flips {sum(c.flip for c in cs)} / {len(cs)}, largest change '
                  f'{_f(max([c.change_px for c in cs if math.isfinite(c.change_px)], default=math.nan))} px; '
                  f'about {left / 60:.0f} min left', file=sys.stderr, flush=True)
        text = report(cases, runs, command.strip(), sum(r.seconds for r in runs if math.isfinite(r.seconds)), args)
    print(text, end='')
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        Path(args.out).write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
