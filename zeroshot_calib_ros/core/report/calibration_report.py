"""The calibration report: one picture of what a calibration is and how far to trust it.

``render_report(ReportData) -> Report`` draws, under a title with the camera, the model, f, the
principal point and the verdict (accepted or refused, and why):

- the lens curve: the image radius (px from the principal point) against the off-axis angle, of
  the camera written (and of the zero-shot camera of the spec, dashed, when another camera was
  written), with the spec's FOVs marked where they put the image edges (hfov/2 at W/2, vfov/2 at
  H/2, dfov/2 at half the diagonal, the circle FOV at the circle's radius), each with its
  tolerance;
- the error map: the 1-sigma pixel error at each pixel (``estimation.uncertainty.uncertainty_map``,
  the pixel-by-pixel form of ``uncertainty_px``), with a colour bar in px;
- the rectified preview: the given image (``refine``, ``calibrate``), or a synthetic ruled cube
  seen through the camera (``solve``), rectified with the camera's rectified P;
- for ``calibrate``: the board coverage (every view's corners over the image frame) and the
  reprojection RMS of each image under the camera written (a bar chart).

``Report.panels`` gives each panel body's rectangle on the picture, and ``Report.map_rect`` /
``Report.map_vmax`` where the error map is drawn and what its colour bar's top means.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..estimation.uncertainty import Uncertainty, error_bar_text, uncertainty_map
from ..ros_formats.rectify import Rectifier, new_camera_matrix
from .canvas import (BLUE, GREEN, INK, MUTED, ORANGE, PAPER, RED, Rect, as_bgr, axes, colour_bar, fit_size,
                     heat_map, legend, legend_column, nice_ceiling, panel, paste_fitted, polyline, put_label,
                     put_text, put_wrapped, text_width, wrapped_height)
from .synthetic import cube_grid

WIDTH = 1440
"""The report's width (px); its height follows from the rows it has."""
MARGIN = 16
GAP = 14
MAP_GRID = (49, 29)
"""Grid of the error map (nodes edge to edge; ``uncertainty.GRID`` is 33 x 19)."""
PREVIEW_MAX_WIDTH = 720
"""The rectified preview is computed at most this wide (the panel is narrower)."""
CLIP_RATIO = 1.5
"""The error map's colour bar stops at the 98th percentile when the largest error is more than
this many times it (a few corner pixels would leave the rest of the map one colour)."""


@dataclass
class BoardViews:
    """What ``calibrate`` saw: the corners of each view and how well the camera explains them."""

    names: Sequence[str]
    corners: np.ndarray
    """(n, cols * rows, 2) pixels, row by row of the board's inner corners."""
    cols: int
    rows: int
    residual_px: np.ndarray
    """(n,) reprojection RMS of each view under the camera written (its pose solved for it)."""
    used: np.ndarray
    """(n,) bool: the views the calibration used."""


def board_views(corners, camera, used_views: Sequence[int]) -> BoardViews:
    """The ``BoardViews`` of a ``core.checkerboard.corners.CornerSet`` under ``camera``: each
    view's reprojection RMS with its board pose solved for the camera (eq. 20 of the paper, as
    ``evaluate`` reports it), the views in ``used_views`` marked used."""
    from ..checkerboard.evaluation import reprojection_error
    used = np.zeros(len(corners), bool)
    used[list(used_views)] = True
    try:
        residual = np.asarray(reprojection_error(camera, corners).per_image, float)
    except (ValueError, np.linalg.LinAlgError, cv2.error):
        residual = np.full(len(corners), np.nan)
    return BoardViews(list(corners.names), np.asarray(corners.corners, float), corners.board.cols,
                      corners.board.rows, residual, used)


@dataclass
class ReportData:
    """Everything a report shows; the CLI fills it from a command's result."""

    command: str
    """'solve', 'refine' or 'calibrate'."""
    camera: object
    """The camera written (a ``core.lens.models.CameraModel``)."""
    model: str
    """How the camera came about, as the CLI's ``model`` field says it."""
    accepted: Optional[bool]
    """True / False: the quality gate's decision; None: nothing was accepted or refused (``solve``,
    a calibration without a spec)."""
    reason: str = ''
    spec: Optional[object] = None
    """The spec sheet (``core.zeroshot.spec.CameraSpec``), if one was given."""
    fov_tolerance_deg: float = 1.0
    uncertainty: Optional[Uncertainty] = None
    """The camera's error bar with its covariance: the error map."""
    uncertainty_px: Optional[float] = None
    uncertainty_reason: str = ''
    zero_shot_camera: Optional[object] = None
    """The spec's zero-shot camera, drawn dashed on the lens curve when another camera is written."""
    image: Optional[np.ndarray] = None
    """The image to rectify for the preview (None: the synthetic cube)."""
    image_name: str = ''
    balance: float = 0.0
    fov_scale: float = 1.0
    board: Optional[BoardViews] = None
    warnings: Sequence[str] = ()
    camera_name: str = 'camera'
    rectified: Callable = new_camera_matrix
    """The rule that makes the P written from the camera, ``balance`` and ``fov_scale``
    (``core.ros_formats.rectify``): the preview shows what that P shows."""


@dataclass
class Report:
    image: np.ndarray
    panels: Dict[str, Tuple[int, int, int, int]] = field(default_factory=dict)
    """Panel name ('title', 'lens', 'uncertainty', 'rectified', and for ``calibrate`` 'coverage',
    'residuals') -> (x, y, w, h) of its body on ``image``."""
    map_rect: Optional[Tuple[int, int, int, int]] = None
    """Where the error map is drawn (the image frame, edge to edge), if there is one."""
    map_vmax: Optional[float] = None
    """The error (px) of the top of the colour bar: a map pixel of colour lut[k] is k / 255 of it."""


def render_report(data: ReportData) -> Report:
    """The report of ``data`` (module docstring), a BGR picture ``WIDTH`` px wide."""
    camera = data.camera
    w, h = camera.width, camera.height
    panel_w = (WIDTH - 2 * MARGIN - 2 * GAP) // 3
    body_h = int(np.clip(round(panel_w * h / w), 300, panel_w))
    row_h = body_h + 27
    title_lines = _title_lines(data, WIDTH - 2 * MARGIN)
    title_h = sum(wrapped_height(text, WIDTH - 2 * MARGIN, scale, thick, cap)
                  for text, scale, _, thick, cap in title_lines) + 14
    rows = 2 if data.board is not None else 1
    height = MARGIN + title_h + GAP + rows * row_h + (rows - 1) * GAP + MARGIN
    canvas = np.full((height, WIDTH, 3), PAPER, np.uint8)
    report = Report(canvas)

    y = MARGIN
    report.panels['title'] = (MARGIN, y, WIDTH - 2 * MARGIN, title_h)
    ty = y + 4
    for text, scale, colour, thick, cap in title_lines:
        ty = put_wrapped(canvas, text, MARGIN, ty, WIDTH - 2 * MARGIN, scale, colour, thick, cap)
    y += title_h + GAP

    xs = [MARGIN + i * (panel_w + GAP) for i in range(3)]
    body = panel(canvas, Rect(xs[0], y, panel_w, row_h), 'lens: image radius against the off-axis angle')
    report.panels['lens'] = body.as_tuple()
    _lens_curve(canvas, body, data)

    u_px = data.uncertainty_px
    title = ('1-sigma error over the image' + (f' (RMS {u_px:.3g} px)' if u_px is not None else ''))
    body = panel(canvas, Rect(xs[1], y, panel_w, row_h), title)
    report.panels['uncertainty'] = body.as_tuple()
    report.map_rect, report.map_vmax = _error_map(canvas, body, data)

    source = (f'{data.image_name} rectified' if data.image is not None and data.image_name else
              'the image rectified' if data.image is not None else 'a ruled cube seen by the camera, rectified')
    body = panel(canvas, Rect(xs[2], y, panel_w, row_h), f'preview: {source}')
    report.panels['rectified'] = body.as_tuple()
    _rectified(canvas, body, data)

    if data.board is not None:
        y += row_h + GAP
        used, n = int(np.sum(data.board.used)), len(data.board.names)
        body = panel(canvas, Rect(xs[0], y, panel_w, row_h),
                     f'board coverage: {n} view{"s" if n != 1 else ""}' + (f', {used} used' if used != n else ''))
        report.panels['coverage'] = body.as_tuple()
        _coverage(canvas, body, data)
        body = panel(canvas, Rect(xs[1], y, 2 * panel_w + GAP, row_h),
                     'reprojection RMS of each image under the camera written (px)')
        report.panels['residuals'] = body.as_tuple()
        _residual_bars(canvas, body, data)
    return report


# -- the title --------------------------------------------------------------------------------------

def _fov_text(spec) -> str:
    if spec is None:
        return 'no spec'
    given = ', '.join(f'{k} {v:g}' for k, v in spec.given().items())
    circle = getattr(spec, 'circle_diameter', None)
    if circle is not None and getattr(spec, 'circle_fov', None) is not None:
        given = (given + ', ' if given else '') + f'circle {circle:g} px / {spec.circle_fov:g}'
    return f'spec {given} deg' if given else 'spec without FOVs'


def verdict_text(accepted: Optional[bool], reason: str, command: str = '') -> Tuple[str, tuple]:
    """(the verdict line, its colour): ACCEPTED (green), REFUSED (red) with the reason, or what the
    camera is when nothing was judged."""
    reason = ' '.join(str(reason).split())
    for prefix in ('accepted: ', 'accepted ', 'zero-shot kept: '):
        if reason.lower().startswith(prefix) and not (prefix == 'accepted ' and reason.startswith('accepted (')):
            reason = reason[len(prefix):]
            break
    if accepted is True:
        return f'ACCEPTED: {reason}' if reason else 'ACCEPTED', GREEN
    if accepted is False:
        kept = 'zero-shot camera written' if command in ('refine', 'calibrate') else 'not adopted'
        return f'REFUSED ({kept}): {reason}' if reason else f'REFUSED ({kept})', RED
    return reason or 'nothing to accept or refuse: the camera of the spec sheet', INK


def _error_bar(data: ReportData) -> str:
    """The title's error bar, as the CLI states it (``uncertainty.error_bar_text``): over the image
    circle when it is, with the lens-shape spread's part for one FOV (at the size it is stated at)."""
    u = data.uncertainty
    over = 'image circle' if u is not None and u.circle_radius is not None else 'image'
    shapes = None
    if u is not None and u.lens_shape_px is not None and u.rms_px:
        shapes = u.lens_shape_px * data.uncertainty_px / u.rms_px
    return error_bar_text(data.uncertainty_px, data.fov_tolerance_deg, over, shapes, '.3g')


def _title_lines(data: ReportData, width: int):
    camera = data.camera
    f = float(camera.K[0, 0])
    fy = float(camera.K[1, 1])
    focal = f'f {f:.2f} px' if abs(fy - f) < 1e-6 * max(abs(f), 1.0) else f'fx {f:.2f} / fy {fy:.2f} px'
    head = (f'zeroshot-calib {data.command}: {data.camera_name} {camera.width}x{camera.height}, {data.model}, '
            f'{focal}, principal point ({camera.cx:.1f}, {camera.cy:.1f})')
    verdict, colour = verdict_text(data.accepted, data.reason, data.command)
    error = (_error_bar(data) if data.uncertainty_px is not None else
             f'error bar: none ({data.uncertainty_reason or "not estimated"})')
    lines = [(head, 0.62, INK, 2, None), (f'{_fov_text(data.spec)}; {error}', 0.5, MUTED, 1, 2),
             (verdict, 0.55, colour, 1, 3)]
    for warning in list(data.warnings)[:2]:
        lines.append((f'warning: {warning}', 0.45, ORANGE, 1, 2))
    if len(data.warnings) > 2:
        lines.append((f'... and {len(data.warnings) - 2} more warnings (on stderr)', 0.45, ORANGE, 1, 1))
    return lines


# -- the lens curve ---------------------------------------------------------------------------------

def radius_curve(camera, theta: np.ndarray) -> np.ndarray:
    """Image radius (px from the principal point, along +x) of rays ``theta`` (rad) off-axis."""
    rays = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=-1)
    with np.errstate(all='ignore'):
        px = camera.project(rays)
    r = np.hypot(px[:, 0] - camera.cx, px[:, 1] - camera.cy)
    r[~np.all(np.isfinite(px), axis=1)] = np.nan
    # a model past its domain folds back: the curve stops where the radius stops growing
    grows = np.concatenate([[True], np.diff(r) > 0])
    stop = np.argmin(grows) if not np.all(grows) else len(r)
    r[stop:] = np.nan
    return r


def spec_marks(spec, width: int, height: int, tolerance: float) -> List[Tuple[str, float, float, float]]:
    """(label, half-angle deg, image radius px, half-angle tolerance deg) of each FOV the spec gives:
    where it says the image edge (or the image circle) is seen, for a principal point at the centre."""
    if spec is None:
        return []
    marks = []
    for key, radius in (('hfov', width / 2.0), ('vfov', height / 2.0), ('dfov', math.hypot(width, height) / 2.0)):
        value = getattr(spec, key, None)
        if value is not None:
            marks.append((f'{key} {value:g}', value / 2.0, radius, tolerance / 2.0))
    circle, circle_fov = getattr(spec, 'circle_diameter', None), getattr(spec, 'circle_fov', None)
    if circle is not None and circle_fov is not None:
        marks.append((f'circle {circle_fov:g}', circle_fov / 2.0, circle / 2.0, tolerance / 2.0))
    return marks


def _lens_curve(canvas, body: Rect, data: ReportData):
    camera = data.camera
    w, h = camera.width, camera.height
    marks = spec_marks(data.spec, w, h, data.fov_tolerance_deg)
    corner = math.hypot(w, h) / 2.0
    # the angles shown: up to where the curve reaches the image corner's radius (or, for a lens
    # model that turns back before it, where it stops), and every FOV mark
    probe = np.radians(np.linspace(0.0, 180.0, 721))
    radii = radius_curve(camera, probe)
    reached = np.nonzero(np.isfinite(radii) & (radii >= corner))[0]
    seen = np.nonzero(np.isfinite(radii))[0]
    top_angle = (math.degrees(probe[reached[0]]) if len(reached) else
                 math.degrees(probe[seen[-1]]) if len(seen) else float('nan'))
    angles = [a + t for _, a, _, t in marks] + ([top_angle] if math.isfinite(top_angle) else [])
    x_max = nice_ceiling(max(angles + [30.0]) * 1.06)
    x_max = min(x_max, 180.0) if max(angles + [0.0]) <= 180.0 else x_max
    y_max = nice_ceiling(max([corner] + [r for _, _, r, _ in marks]) * 1.06)
    ax = axes(canvas, body, (0.0, x_max), (0.0, y_max), 'off-axis angle (deg)', 'image radius (px)')
    theta = np.radians(np.linspace(0.0, x_max, 400))

    def clipped(r):
        return np.where(r <= y_max, r, np.nan)
    # the image's own radii: the edges (W/2, H/2) and the corner, faint, labelled at the right
    for label, radius in (('W/2', w / 2.0), ('H/2', h / 2.0), ('corner', corner)):
        (x0, yv), (x1, _) = ax.to_px([0.0, x_max], [radius, radius])
        polyline(canvas, np.array([[x0, yv], [x1, yv]]), (185, 185, 185), 1, dashed=True)
        put_text(canvas, label, int(x0) + 4, int(yv) - 14, 0.38, MUTED, 1)
    entries = []
    if data.zero_shot_camera is not None and data.zero_shot_camera is not camera:
        polyline(canvas, ax.to_px(np.degrees(theta), clipped(radius_curve(data.zero_shot_camera, theta))), MUTED,
                 2, dashed=True)
        entries.append(('zero-shot', MUTED))
    polyline(canvas, ax.to_px(np.degrees(theta), clipped(radius_curve(camera, theta))), BLUE, 2)
    entries.insert(0, ('camera written', BLUE))
    for label, angle, radius, tol in marks:
        (u, v), = ax.to_px([angle], [radius])
        (ul, _), = ax.to_px([angle - tol], [radius])
        (ur, _), = ax.to_px([angle + tol], [radius])
        cv2.line(canvas, (int(ul), int(v)), (int(ur), int(v)), ORANGE, 2, cv2.LINE_AA)
        cv2.drawMarker(canvas, (int(round(u)), int(round(v))), ORANGE, cv2.MARKER_TILTED_CROSS, 11, 2, cv2.LINE_AA)
        # the label below and right of its mark, else above and left (a rising curve leaves both empty)
        right = u + 10 + text_width(label, 0.42) < ax.area.x + ax.area.w - 4
        put_label(canvas, label, int(u) + (10 if right else -10), int(v) + (7 if right else -22), 0.42, ORANGE,
                  'left' if right else 'right')
    if marks:
        entries.append((f'spec FOV edge, +- {data.fov_tolerance_deg / 2:g} deg off-axis', ORANGE))
    # the legend in the lower right corner, which a rising curve leaves empty
    legend_column(canvas, ax.area.x + ax.area.w - 6, ax.area.y + ax.area.h - 4, entries, 0.4)


# -- the error map ----------------------------------------------------------------------------------

def _error_map(canvas, body: Rect, data: ReportData):
    camera = data.camera
    bar_w = 64
    box = Rect(body.x + 10, body.y + 10, body.w - 20 - bar_w, body.h - 36)
    u = data.uncertainty
    emap = uncertainty_map(u, MAP_GRID) if u is not None else None
    if emap is None or not np.any(np.isfinite(emap.sigma_px)):
        reason = data.uncertainty_reason or (u.reason if u is not None else '') or 'not estimated'
        put_text(canvas, 'no error map:', body.x + 14, body.y + 20, 0.5, INK, 1)
        put_wrapped(canvas, reason, body.x + 14, body.y + 46, body.w - 28, 0.45, MUTED, 1, 8)
        return None, None
    sigma = emap.sigma_px
    if data.uncertainty_px is not None and math.isfinite(emap.rms_px) and emap.rms_px > 0 \
            and (emap.width, emap.height) != (camera.width, camera.height):
        sigma = sigma * (camera.width / emap.width)  # an error bar stated at the spec's size
    # the colour bar's top: the largest error, or where a few pixels (an image corner near the
    # edge of the lens model) would darken the rest of the map, the 98th percentile (above: its colour)
    largest = float(np.nanmax(sigma))
    high = float(np.nanpercentile(sigma, 98))
    clipped = largest > CLIP_RATIO * high
    vmax = nice_ceiling(high if clipped else largest)
    fw, fh = fit_size(camera.width, camera.height, box.w, box.h)
    x, y = box.x + (box.w - fw) // 2, box.y + (box.h - fh) // 2
    no_data = None
    circle = getattr(u, 'circle_radius', None)
    if circle is not None:  # the error bar is stated over the image circle: its edge, drawn exactly
        s = fw / emap.width
        gx, gy = np.meshgrid((np.arange(fw) + 0.5) / s, (np.arange(fh) + 0.5) / s)
        no_data = np.hypot(gx - emap.width / 2.0, gy - emap.height / 2.0) > circle
    canvas[y:y + fh, x:x + fw] = heat_map(sigma, vmax, (fw, fh), no_data)
    cv2.rectangle(canvas, (x - 1, y - 1), (x + fw, y + fh), INK, 1)
    # the principal point of the camera written
    pp = (int(round(x + camera.cx / camera.width * fw)), int(round(y + camera.cy / camera.height * fh)))
    cv2.drawMarker(canvas, pp, (255, 255, 255), cv2.MARKER_CROSS, 12, 1, cv2.LINE_AA)
    colour_bar(canvas, Rect(x + fw + 14, y, 14, fh), vmax, 'px', clipped)
    notes = ['cross: principal point']
    if clipped:
        notes.append(f'largest {largest:.3g} px')
    if circle is not None:
        notes.append('grey: outside the image circle')
    elif np.any(~np.isfinite(sigma)):
        notes.append('grey: no ray (beyond the lens model)')
    put_text(canvas, '; '.join(notes), body.x + 10, body.y + body.h - 22, 0.4, MUTED, 1)
    return (x, y, fw, fh), vmax


# -- the rectified preview --------------------------------------------------------------------------

def _rectified(canvas, body: Rect, data: ReportData):
    camera = data.camera
    scale = min(1.0, PREVIEW_MAX_WIDTH / camera.width)
    small = camera
    if scale < 1.0:
        sw, sh = max(1, int(round(camera.width * scale))), max(1, int(round(camera.height * scale)))
        try:
            small = camera.scaled(sw, sh)
        except NotImplementedError:
            small = camera
    if data.image is not None:
        image = as_bgr(data.image)
        if (small.width, small.height) != (image.shape[1], image.shape[0]):
            image = cv2.resize(image, (small.width, small.height), interpolation=cv2.INTER_AREA)
    else:
        image = cube_grid(small)
    try:
        P = data.rectified(small, data.balance, data.fov_scale)
        rectified = Rectifier(small, P=P).rectify(image)
    except (ValueError, cv2.error) as exc:
        put_wrapped(canvas, f'no preview: {exc}', body.x + 14, body.y + 20, body.w - 28, 0.45, MUTED, 1, 8)
        return
    box = Rect(body.x + 10, body.y + 10, body.w - 20, body.h - 36)
    where = paste_fitted(canvas, rectified, box)
    cv2.rectangle(canvas, (where.x - 1, where.y - 1), (where.x + where.w, where.y + where.h), INK, 1)
    # the rectified camera's principal point far off the image: balance 0 kept one side of a lens
    # whose edges are seen at very different angles (say so: the preview is not the whole scene)
    u0, v0 = P[0, 2] / small.width, P[1, 2] / small.height
    if not (0.0 <= u0 <= 1.0 and 0.0 <= v0 <= 1.0):
        note = (f'rectified principal point ({P[0, 2] / scale:.0f}, {P[1, 2] / scale:.0f}) off the image: '
                'one side shown (--balance)')
        put_text(canvas, note, body.x + 10, body.y + body.h - 22, 0.4, RED, 1)
        return
    put_text(canvas, f'balance {data.balance:g}, fov-scale {data.fov_scale:g}: straight lines should be straight',
             body.x + 10, body.y + body.h - 22, 0.4, MUTED, 1)


# -- calibrate: coverage and residuals --------------------------------------------------------------

def view_colour(i: int, n: int) -> tuple:
    """A distinct colour per view (hues around the circle, BGR)."""
    hue = np.uint8(int(180 * (i * 0.618034 % 1.0)))
    return tuple(int(c) for c in cv2.cvtColor(np.array([[[hue, 200, 220]]], np.uint8), cv2.COLOR_HSV2BGR)[0, 0])


def _board_outline(corners: np.ndarray, cols: int, rows: int) -> np.ndarray:
    grid = corners.reshape(rows, cols, 2)
    return np.concatenate([grid[0, :], grid[:, -1], grid[-1, ::-1], grid[::-1, 0]])


def _coverage(canvas, body: Rect, data: ReportData):
    board = data.board
    camera = data.camera
    box = Rect(body.x + 10, body.y + 10, body.w - 20, body.h - 36)
    fw, fh = fit_size(camera.width, camera.height, box.w, box.h)
    x, y = box.x + (box.w - fw) // 2, box.y + (box.h - fh) // 2
    if data.image is not None:
        frame = cv2.resize(as_bgr(data.image), (fw, fh), interpolation=cv2.INTER_AREA)
        frame = (0.25 * frame + 0.75 * 255).astype(np.uint8)  # faint: the boards are what counts here
    else:
        frame = np.full((fh, fw, 3), 245, np.uint8)
    s = fw / camera.width
    layer = frame.copy()
    n = len(board.names)
    order = [i for i in range(n) if not board.used[i]] + [i for i in range(n) if board.used[i]]
    for i in order:
        pts = np.asarray(board.corners[i], float)
        if not np.all(np.isfinite(pts)):
            continue
        outline = np.round(_board_outline(pts, board.cols, board.rows) * s * 16).astype(np.int32)
        colour = view_colour(i, n) if board.used[i] else (170, 170, 170)
        cv2.fillPoly(layer, [outline.reshape(-1, 1, 2)], colour, cv2.LINE_AA, 4)
    frame = cv2.addWeighted(layer, 0.35, frame, 0.65, 0)
    for i in order:
        pts = np.asarray(board.corners[i], float)
        if not np.all(np.isfinite(pts)):
            continue
        colour = view_colour(i, n) if board.used[i] else (150, 150, 150)
        outline = np.round(_board_outline(pts, board.cols, board.rows) * s * 16).astype(np.int32)
        cv2.polylines(frame, [outline.reshape(-1, 1, 2)], True, colour, 1, cv2.LINE_AA, 4)
        for p in pts * s:
            cv2.circle(frame, (int(round(p[0] * 16)), int(round(p[1] * 16))), 2 * 16, colour, -1, cv2.LINE_AA, 4)
    canvas[y:y + fh, x:x + fw] = frame
    cv2.rectangle(canvas, (x - 1, y - 1), (x + fw, y + fh), INK, 1)
    note = 'each view a colour' + ('; grey: views not used' if not np.all(board.used) else '')
    put_text(canvas, note, body.x + 10, body.y + body.h - 22, 0.4, MUTED, 1)


def _residual_bars(canvas, body: Rect, data: ReportData):
    board = data.board
    values = np.asarray(board.residual_px, float)
    n = len(values)
    finite = values[np.isfinite(values)]
    top = nice_ceiling(float(finite.max()) * 1.1) if finite.size and finite.max() > 0 else 1.0
    every = max(1, int(math.ceil(n / 30)))
    labels = [(i + 1.0, str(i + 1) if i % every == 0 else '') for i in range(n)]
    ax = axes(canvas, body, (0.5, n + 0.5), (0.0, top), 'image (in the order given)', 'px', y_ticks=5,
              x_tick_labels=labels)
    slot = ax.area.w / max(n, 1)
    half = max(1.0, slot * 0.35)
    for i, value in enumerate(values):
        (u, v), = ax.to_px([i + 1.0], [value if np.isfinite(value) else 0.0])
        (_, v0), = ax.to_px([i + 1.0], [0.0])
        colour = view_colour(i, n) if board.used[i] else (170, 170, 170)
        if not np.isfinite(value):
            put_text(canvas, 'x', int(u), int(v0) - 14, 0.4, RED, 1, 'centre')
            continue
        cv2.rectangle(canvas, (int(round(u - half)), int(round(v))), (int(round(u + half)), int(round(v0)) - 1),
                      colour, -1)
        cv2.rectangle(canvas, (int(round(u - half)), int(round(v))), (int(round(u + half)), int(round(v0)) - 1),
                      INK, 1)
    if finite.size:
        rms = float(np.sqrt(np.mean(finite ** 2)))
        (_, v), = ax.to_px([0.5], [rms])
        polyline(canvas, np.array([[ax.area.x, v], [ax.area.x + ax.area.w - 1, v]]), INK, 1, dashed=True)
        text = f'RMS {rms:.3g} px over the {finite.size} image{"s" if finite.size != 1 else ""}'
        put_label(canvas, text, ax.area.x + ax.area.w - 8, int(v) - 18, 0.42, INK, 'right')
    worst = int(np.nanargmax(values)) if finite.size else None
    if worst is not None:
        name = str(board.names[worst]).replace('\\', '/').rsplit('/', 1)[-1]
        put_label(canvas, f'largest: image {worst + 1} ({name}), {values[worst]:.3g} px', ax.area.x + 8,
                  ax.area.y + 8, 0.42, INK)
    if not np.all(board.used):
        first = int(np.argmax(board.used)) if np.any(board.used) else 0
        legend(canvas, ax.area.x + 8, ax.area.y + 30, [('used in the calibration', view_colour(first, n)),
                                                      ('not used', (170, 170, 170))], 0.4, line=False)
