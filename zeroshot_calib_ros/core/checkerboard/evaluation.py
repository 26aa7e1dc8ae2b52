"""The paper's evaluation protocol (secs. 3.2 and 4) and the layouts of its Tables 3 and 4.

RMS reprojection error, eq. 20
    For a camera and N images of M board corners each: every image's extrinsics come from PnP
    on the undistorted corners (``camera.undistort``, identity K; several solvers, see
    ``pose``), refined by Levenberg-Marquardt on the pixel error through the camera model, the
    best pose kept; then eps^2 = 1/(N M) sum_ij ||p_ij - p~_ij||^2.

Single-shot errors, eqs. 21-22
    Calibrate on image k alone (k = 1..N, or on ``shots`` consecutive images starting at k for
    few-shot), evaluate that camera on all N images: eps_gen is the mean over k of the eq.-20
    RMS over all N images, eps_fit the mean over k of the RMS over the image(s) it was
    calibrated on (same protocol). Runs whose calibration failed are counted and listed; the
    means are over the runs that succeeded.

Tables
    Table 3 layout: eps of Pers. (pinhole from the spec's FOVs), ZS, Zhang, FC_eq.d. (and here
    also FC_eq.d. + ZS and OpenCV fisheye) on all N images. Table 4 layout: eps_gen (eps_fit)
    of FC_eq.d.(1), Zhang(1), FC_eq.d.(1) + ZS (and OpenCV fisheye(1)), beside ZS and the full
    Zhang(N) (and fisheye(N)).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from .calibration import METHOD_LABELS, CalibrationResult, calibrate, paper_zero_shot_camera, perspective_camera
from ..lens.models import CameraModel, KannalaBrandtCamera, PlumbBobCamera, RadialCamera
from .corners import CornerSet, check_corner_set
from .pose import BoardPoses, board_poses
from ..zeroshot.solver import solve_zero_shot
from ..zeroshot.spec import CameraSpec, SpecError

FULL_METHODS = ('pers', 'zs', 'zhang', 'fc', 'fc+zs', 'fisheye')
SHOT_METHODS = ('fc', 'zhang', 'fc+zs', 'fisheye')
NEEDS_SPEC = ('pers', 'zs', 'fc+zs')
LABELS = dict(METHOD_LABELS, pers='Pers.', zs='ZS', reference='reference')
PLAIN_NAMES = {
    'pers': "pinhole camera from the spec's FOVs, no distortion",
    'zs': 'zero-shot camera from the spec',
    'zhang': "OpenCV's pinhole calibration (calibrateCamera, plumb_bob)",
    'fc': "checkerboard fit of the paper's fisheye model, default start",
    'fc+zs': "checkerboard fit of the paper's fisheye model, from zero-shot",
    'fisheye': "OpenCV's fisheye calibration (cv2.fisheye.calibrate)",
    'reference': 'the calibration given with --spec-from',
}
"""Each method in plain words, printed beside the paper's name (``LABELS``)."""


def plain_name(key: str, images: Optional[str] = None) -> str:
    """``PLAIN_NAMES[key]`` and, for a calibration, the images it used (``images``: '1 image',
    'all 24 images'; None for a camera that uses no image)."""
    if key in ('pers', 'zs'):
        return f'{PLAIN_NAMES[key]} (no image used)'
    name = PLAIN_NAMES[key]
    if images is None or key == 'reference':
        return name
    if key in ('fc', 'fc+zs'):  # 'checkerboard fit, 1 image, from zero-shot'
        head, start = name.split(', ')
        return f'{head}, {images}, {start}'
    return f'{name}, {images}'


@dataclass
class ReprojectionError:
    """Eq. 20 for one camera over a set of images."""

    rms: float
    per_image: np.ndarray
    """(n,) RMS of each image (eq. 22's inner term); inf where no pose was found."""
    poses: BoardPoses
    views: tuple

    @property
    def unprojectable(self) -> int:
        return self.poses.unprojectable

    @property
    def no_pose(self) -> List[int]:
        return [self.views[i] for i in np.flatnonzero(~self.poses.found)]


def reprojection_error(camera: CameraModel, corners: CornerSet,
                       views: Optional[Sequence[int]] = None, initial=None) -> ReprojectionError:
    """Eq. 20 of ``camera`` on ``views`` (all images by default) of ``corners``."""
    views = tuple(range(len(corners))) if views is None else tuple(views)
    poses = board_poses(camera, corners.object_points(), corners.corners[list(views)], initial)
    sq = poses.errors ** 2
    per_image = np.sqrt(np.mean(sq, axis=1))
    return ReprojectionError(float(np.sqrt(np.mean(sq))), per_image, poses, views)


@dataclass
class FullRow:
    """One column of the Table 3 layout."""

    key: str
    camera: Optional[CameraModel] = None
    error: Optional[ReprojectionError] = None
    result: Optional[CalibrationResult] = None
    failure: str = ''
    notes: List[str] = field(default_factory=list)

    @property
    def label(self):
        return LABELS[self.key]

    @property
    def rms(self) -> float:
        return self.error.rms if self.error is not None else float('nan')


@dataclass
class ShotRun:
    views: tuple
    result: CalibrationResult
    gen: float = float('nan')
    """Eq. 20 over all N images (eq. 21's inner term)."""
    fit: float = float('nan')
    """RMS over the calibration images (eq. 22's inner term)."""


@dataclass
class ShotStudy:
    """One column of the Table 4 layout: every single-/few-shot run of one method."""

    key: str
    shots: int
    runs: List[ShotRun] = field(default_factory=list)
    skipped: str = ''

    @property
    def label(self):
        return f'{LABELS[self.key]}({self.shots})' if self.key != 'fc+zs' else f'FC_eq.d.({self.shots})+ZS'

    @property
    def ok_runs(self):
        return [r for r in self.runs if r.result.ok]

    @property
    def failed_runs(self):
        return [r for r in self.runs if not r.result.ok]

    @property
    def retried_runs(self):
        """Runs whose first OpenCV result was unsound and that a retry from a sound start gave."""
        return [r for r in self.runs if r.result.ok and any(n.startswith('retried from')
                                                            for n in r.result.notes)]

    @property
    def rejected(self):
        """[(run, RejectedCorner)] of the FC runs' outlier corners."""
        return [(r, c) for r in self.runs for c in r.result.rejected]

    @property
    def gen_mean(self) -> float:
        ok = self.ok_runs
        return float(np.mean([r.gen for r in ok])) if ok else float('nan')

    @property
    def fit_mean(self) -> float:
        ok = self.ok_runs
        return float(np.mean([r.fit for r in ok])) if ok else float('nan')

    @property
    def gen_median(self) -> float:
        ok = self.ok_runs
        return float(np.median([r.gen for r in ok])) if ok else float('nan')


@dataclass
class Evaluation:
    name: str
    corners: CornerSet
    spec: Optional[CameraSpec]
    spec_source: str
    shots: int
    full: Dict[str, FullRow]
    studies: Dict[str, ShotStudy]
    reference: Optional[FullRow] = None
    reference_source: str = ''
    seconds: float = 0.0
    input_notes: List[str] = field(default_factory=list)
    """What the corner-set checks found that is not an error (duplicate views)."""
    duplicates: List[tuple] = field(default_factory=list)


def _paper_solution(spec: Optional[CameraSpec]):
    """The spec's solution with the paper's equidistant model, solved once for every row and run
    that starts from it (``calibration.paper_zero_shot_camera``); None without a spec, or when it
    cannot be solved so (each row and run then solves the spec itself and says why, as before)."""
    if spec is None:
        return None
    try:
        return solve_zero_shot(spec, 'equidistant')
    except Exception:  # noqa: BLE001 (whatever it is, the rows meet it again and report it in their place)
        return None


def _full_row(key, corners, spec, solution=None) -> FullRow:
    row = FullRow(key)
    try:
        if key == 'pers':
            row.camera = perspective_camera(spec, corners.width, corners.height)
        elif key == 'zs':
            row.camera, note = paper_zero_shot_camera(spec, corners.width, corners.height, solution)
            if note:
                row.notes.append(note)
        else:
            row.result = calibrate(corners, key, spec=spec, solution=solution)
            row.notes += row.result.notes
            if not row.result.ok:
                row.failure = row.result.error
                return row
            row.camera = row.result.camera
    except SpecError as exc:
        row.failure = str(exc)
        return row
    initial = None
    if row.result is not None:  # one start pose per image; duplicate views were left out of the fit
        initial = [None] * len(corners)
        for view, pose in zip(row.result.views, row.result.extrinsics() or []):
            initial[view] = pose
    row.error = reprojection_error(row.camera, corners, initial=initial)
    return row


def shot_views(n: int, k: int, shots: int) -> tuple:
    """The ``shots`` consecutive images (cyclically) starting at image ``k``."""
    return tuple((k + j) % n for j in range(shots))


def evaluate(corners: CornerSet, spec: Optional[CameraSpec] = None, shots: int = 1,
             full_methods: Sequence[str] = FULL_METHODS, shot_methods: Sequence[str] = SHOT_METHODS,
             runs: Optional[Sequence[int]] = None, name: str = 'camera', spec_source: str = '',
             reference: Optional[CameraModel] = None, reference_source: str = '',
             progress: Optional[Callable[[str], None]] = None) -> Evaluation:
    """Both tables for ``corners``. ``runs``: the start images k of the single-/few-shot runs
    (all N by default; a subset gives a quicker, partial Table 4)."""
    t0 = time.perf_counter()
    n = len(corners)
    if shots == 0:
        shot_methods = ()
    elif not 1 <= shots <= n:
        raise ValueError(f'shots = {shots!r} is invalid: allowed: 0 (no Table 4) to {n} '
                         '(the number of images)')
    runs = list(range(n)) if runs is None else list(runs)
    report = check_corner_set(corners)  # a wrong board or a degenerate view: CornersError
    say = progress or (lambda message: None)
    solution = _paper_solution(spec)
    full = {}
    for key in full_methods:
        if key in NEEDS_SPEC and spec is None:
            full[key] = FullRow(key, failure='no spec given (needs hfov / vfov / dfov)')
            continue
        say(f'full: {LABELS[key]}')
        full[key] = _full_row(key, corners, spec, solution)
    studies = {}
    for key in shot_methods:
        study = ShotStudy(key, shots)
        studies[key] = study
        if key in NEEDS_SPEC and spec is None:
            study.skipped = 'no spec given (needs hfov / vfov / dfov)'
            continue
        for number, k in enumerate(runs, start=1):
            say(f'{shots}-shot: {study.label}, run {number} of {len(runs)}')
            views = shot_views(n, k, shots)
            try:
                result = calibrate(corners, key, views=views, spec=spec, solution=solution)
            except SpecError as exc:
                study.skipped = str(exc)
                break
            run = ShotRun(views, result)
            if result.ok:
                err = reprojection_error(result.camera, corners)
                run.gen = err.rms
                own = err.per_image[list(views)]
                run.fit = float(np.sqrt(np.mean(own ** 2)))
            study.runs.append(run)
    ref_row = None
    if reference is not None:
        ref_row = FullRow('reference', camera=reference)
        ref_row.error = reprojection_error(reference, corners)
    return Evaluation(name, corners, spec, spec_source, shots, full, studies, ref_row,
                      reference_source, time.perf_counter() - t0, report.notes, report.duplicates)


# ---------------------------------------------------------------------------------------------
# Output


def _fmt(x, width=6, digits=2) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return 'n/a'.rjust(width)
    if math.isinf(x):
        return 'inf'.rjust(width)
    return f'{x:{width}.{digits}f}'


def _intrinsics(camera: Optional[CameraModel]) -> dict:
    if camera is None:
        return {}
    d = {'model': type(camera).__name__, 'fx': camera.fx, 'fy': camera.fy, 'cx': camera.cx,
         'cy': camera.cy, 'K': camera.K.tolist()}
    if isinstance(camera, RadialCamera) and hasattr(camera, 'omega'):
        d.update(f=camera.f, omega=camera.omega, a=camera.omega * camera.f,
                 projection=camera.projection.name)
    if isinstance(camera, (KannalaBrandtCamera, PlumbBobCamera)):
        d['D'] = [float(x) for x in camera.D[:5 if isinstance(camera, PlumbBobCamera) else 4]]
        d['distortion_model'] = camera.distortion_model
    return d


def _distortion_text(camera) -> str:
    if camera is None:
        return ''
    if hasattr(camera, 'omega'):
        return f'w = {camera.omega:.6g} /px (w f = {camera.omega * camera.f:.4f})'
    if isinstance(camera, KannalaBrandtCamera):
        return 'KB4 [' + ', '.join(f'{x:.5f}' for x in camera.D) + ']'
    if isinstance(camera, PlumbBobCamera):
        if not np.any(camera.D):
            return 'none'
        return 'plumb_bob [' + ', '.join(f'{x:.5f}' for x in camera.D[:5]) + ']'
    return ''


def format_tables(ev: Evaluation) -> str:
    """The evaluation as text: Table 3 and Table 4 layouts, intrinsics, failures and notes."""
    c = ev.corners
    n = len(c)
    out = [f'data     {ev.name}: N = {n} images {c.width}x{c.height}, board {c.board.size} inner '
           f'corners, square {c.board.square:g} m, M = {c.board.count} corners per image']
    if ev.spec is not None:
        spec = ', '.join(f'{k} {v:.2f} deg' for k, v in ev.spec.given().items())
        out.append(f'spec     {spec}' + (f'  ({ev.spec_source})' if ev.spec_source else ''))
    else:
        out.append('spec     none given: Pers., ZS and FC_eq.d.+ZS are n/a')
    name_w = max(10, len(ev.name))

    out += ['', 'Table 3 layout: RMS reprojection error eps (px, eq. 20) on all N images']
    cols = [k for k in FULL_METHODS if k in ev.full]
    head = f'{"camera":<{name_w}}  {"N":>3}  ' + '  '.join(
        f'{LABELS[k]:>{max(6, len(LABELS[k]))}}' for k in cols)
    out += [head, f'{ev.name:<{name_w}}  {n:>3}  ' + '  '.join(
        _fmt(ev.full[k].rms, max(6, len(LABELS[k]))) for k in cols)]

    if ev.studies:
        s = ev.shots
        out += ['', f'Table 4 layout: {"single" if s == 1 else f"{s}-image few"}-shot calibration, '
                    f'mean over the runs of eps_gen (eps_fit) (px, eqs. 21-22)']
        order = [('fc', 'study'), ('zhang', 'study'), ('zs', 'full'), ('fc+zs', 'study'),
                 ('zhang', 'full'), ('fisheye', 'study'), ('fisheye', 'full')]
        cells, heads = [], []
        for key, kind in order:
            if kind == 'study' and key in ev.studies:
                st = ev.studies[key]
                heads.append(st.label)
                if st.skipped or not st.ok_runs:
                    cells.append('n/a')
                else:
                    cells.append(f'{st.gen_mean:.2f} ({st.fit_mean:.2f})'
                                 + (f' [{len(st.ok_runs)}/{len(st.runs)} ok]' if st.failed_runs else '')
                                 + (f' [{len(st.retried_runs)} retried]' if st.retried_runs else ''))
            elif kind == 'full' and key in ev.full:
                heads.append(f'{LABELS[key]}(N)' if key != 'zs' else 'ZS')
                cells.append(_fmt(ev.full[key].rms, 0).strip())
        widths = [max(len(h), len(v)) for h, v in zip(heads, cells)]
        out.append(f'{"camera":<{name_w}}  {"N":>3}  ' + '  '.join(h.rjust(w) for h, w in zip(heads, widths)))
        out.append(f'{ev.name:<{name_w}}  {n:>3}  ' + '  '.join(v.rjust(w) for v, w in zip(cells, widths)))
        runs = next((len(st.runs) for st in ev.studies.values() if st.runs), 0)
        if runs and runs != n:
            out.append(f'(partial: {runs} of the {n} runs)')
        out.append('runs     ' + '; '.join(
            f'{st.label}: median eps_gen {_fmt(st.gen_median, 0).strip()}, worst '
            f'{_fmt(max((r.gen for r in st.ok_runs), default=float("nan")), 0).strip()}'
            for st in ev.studies.values() if st.ok_runs))
        for st in ev.studies.values():
            if st.skipped:
                out.append(f'skipped  {st.label}: {st.skipped}')
            if st.failed_runs:
                names = ', '.join(f'{c.names[r.views[0]].split("/")[-1]}' for r in st.failed_runs)
                out.append(f'failed   {st.label}: {len(st.failed_runs)} of {len(st.runs)} runs '
                           f'({names}); first error: {st.failed_runs[0].result.error}')
            if st.retried_runs:
                names = ', '.join(f'{c.names[r.views[0]].split("/")[-1]}' for r in st.retried_runs)
                first = next(n for n in st.retried_runs[0].result.notes if n.startswith('retried from'))
                out.append(f'retried  {st.label}: {len(st.retried_runs)} of {len(st.runs)} runs ({names}) '
                           f'gave an unsound camera first, shown is the retry; first: {first}')
            if st.rejected:
                out.append(f'rejected {st.label}: {len(st.rejected)} outlier corner(s) in '
                           f'{len({id(r) for r, _ in st.rejected})} runs: '
                           + ', '.join(str(cr) for _, cr in st.rejected[:6])
                           + (' ...' if len(st.rejected) > 6 else ''))

    out += [''] + _key_lines(ev, [k for k in FULL_METHODS if k in ev.full])
    out += ['', 'Full calibrations and cameras (intrinsics in px)']
    rows = [(LABELS[k], ev.full[k]) for k in FULL_METHODS if k in ev.full]
    if ev.reference is not None:
        rows.append(('reference', ev.reference))
    for label, row in rows:
        if row.camera is None:
            out.append(f'  {label:<15} failed: {row.failure}')
            continue
        cam = row.camera
        own = ''
        if row.result is not None:
            own = f', own RMS {row.result.rms_px:.3f}'
            if row.result.opencv_rms is not None:
                own += f' (OpenCV {row.result.opencv_rms:.3f})'
        out.append(f'  {label:<15} fx {cam.fx:8.3f} fy {cam.fy:8.3f} cx {cam.cx:7.2f} cy {cam.cy:7.2f}  '
                   f'{_distortion_text(cam)}; eps {row.rms:.3f}{own}')
        if row.error is not None and (row.error.unprojectable or row.error.no_pose):
            out.append(f'  {"":<15} {row.error.unprojectable} corners not projectable, '
                       f'{len(row.error.no_pose)} images without a pose')
    if ev.reference is not None and ev.reference_source:
        out.append(f'  (reference: {ev.reference_source})')
    notes = {}
    for row in ev.full.values():
        for note in row.notes:
            if note not in ev.input_notes:
                notes.setdefault(note, []).append(row.label)
    if notes or ev.input_notes:
        out += [''] + [f'warning  {note}' for note in ev.input_notes]
        out += [f'note     {", ".join(labels)}: {note}' for note, labels in notes.items()]
    out.append(f'time     {ev.seconds:.1f} s')
    return '\n'.join(out)


def _shot_images(shots: int) -> str:
    return '1 image' if shots == 1 else f'{shots} consecutive images'


def _key_lines(ev: Evaluation, table3: Sequence[str]) -> List[str]:
    """The key to the tables: each column's paper name with a plain name beside it, and what the
    numbers are."""
    n = len(ev.corners)
    rows = [(LABELS[k], plain_name(k, f'all {n} images')) for k in table3]
    if ev.studies:
        rows += [(st.label, plain_name(st.key, _shot_images(st.shots))) for st in ev.studies.values()]
        rows += [(f'{LABELS[k]}(N)', plain_name(k, f'all {n} images')) for k in ('zhang', 'fisheye') if k in ev.full]
    width = max(len(label) for label, _ in rows)
    lines = ['Key to the columns (the paper\'s name: in plain words)']
    lines += [f'  {label:<{width}}  {plain}' for label, plain in rows]
    lines.append(f'  {"eps":<{width}}  RMS reprojection error (px) of the camera on all {n} images')
    if ev.studies:
        lines.append(f'  {"eps_gen (eps_fit)":<{width}}  Table 4: the same on all {n} images (on the image(s) it '
                     'was calibrated on), mean over the runs')
    return lines


def _finite(x):
    return None if x is None or not math.isfinite(x) else float(x)


def evaluation_to_dict(ev: Evaluation) -> dict:
    """The evaluation as JSON-ready data (the CLI's ``--json``)."""
    c = ev.corners

    def row_dict(row: FullRow):
        d = {'label': row.label, 'plain_name': plain_name(row.key, f'all {len(c)} images'),
             'eps': _finite(row.rms), 'failure': row.failure or None,
             'camera': _intrinsics(row.camera), 'notes': row.notes}
        if row.error is not None:
            d['per_image_eps'] = [_finite(x) for x in row.error.per_image]
            d['unprojectable_corners'] = row.error.unprojectable
        if row.result is not None:
            d.update(own_rms=_finite(row.result.rms_px), opencv_rms=row.result.opencv_rms,
                     init=row.result.init, fixed_principal_point=row.result.fixed_principal_point,
                     rejected_corners=[r.to_dict() for r in row.result.rejected])
        return d

    def study_dict(st: ShotStudy):
        return {
            'label': st.label, 'plain_name': plain_name(st.key, _shot_images(st.shots)),
            'shots': st.shots, 'skipped': st.skipped or None,
            'eps_gen': _finite(st.gen_mean), 'eps_fit': _finite(st.fit_mean),
            'eps_gen_median': _finite(st.gen_median),
            'runs_total': len(st.runs), 'runs_ok': len(st.ok_runs), 'runs_failed': len(st.failed_runs),
            'runs_retried': len(st.retried_runs),
            'runs': [{'images': [c.names[v] for v in r.views], 'ok': r.result.ok,
                      'error': r.result.error or None, 'eps_gen': _finite(r.gen), 'eps_fit': _finite(r.fit),
                      'camera': _intrinsics(r.result.camera), 'init': r.result.init,
                      'notes': list(r.result.notes),
                      'rejected_corners': [x.to_dict() for x in r.result.rejected]} for r in st.runs],
        }

    d = {
        'name': ev.name, 'images': len(c), 'width': c.width, 'height': c.height,
        'board': {'cols': c.board.cols, 'rows': c.board.rows, 'square': c.board.square},
        'spec': ev.spec.given() if ev.spec is not None else None, 'spec_source': ev.spec_source or None,
        'shots': ev.shots,
        'table3': {k: row_dict(r) for k, r in ev.full.items()},
        'table4': {k: study_dict(s) for k, s in ev.studies.items()},
        'seconds': ev.seconds,
        'duplicate_views': [{'image': a, 'same_as': b, 'rms_difference_px': x} for a, b, x in ev.duplicates],
    }
    if ev.reference is not None:
        d['reference'] = dict(row_dict(ev.reference), source=ev.reference_source or None)
    return d
