"""``refine``'s debug picture: a contact sheet of every image with its curves, and the verdict.

Under a header with the verdict (ACCEPTED in green, REFUSED in red, and the reason) and a legend,
one panel per image in the order given, each labelled with its number, name and its counts of
curves: used by the fit (green), rejected (red: not straight under the fitted camera, or bowing
toward the principal point, ``core.lines.bowing``), left out for staying put across the images
(orange; the vehicle's or robot's own body, lens dirt). Below them the first image rectified
with the zero-shot camera and with the refined camera (the one written when accepted, the one
refused otherwise; none when no fit was made), side by side, with one rectified camera (the
zero-shot one's P) so that the straightness compares directly.

The sheet is at most ``MAX_WIDTH`` px wide and about ``MAX_HEIGHT`` px high: panels are the
images scaled down (never up) to fit; the curves are drawn at the panel's scale.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Dict, List, Sequence, Tuple

import cv2
import numpy as np

from ..lines.detect import draw_curves
from ..ros_formats.rectify import Rectifier, new_camera_matrix
from .calibration_report import verdict_text
from .canvas import (CURVE_REJECTED, CURVE_STATIC, CURVE_USED, INK, MUTED, PAPER, as_bgr, legend, legend_rows,
                     line_height, put_text, put_wrapped, text_width, wrapped_height)

MAX_WIDTH = 1280
MAX_HEIGHT = 2000
MARGIN = 12
GAP = 10
LABEL_H = 22
LABEL_BG = (72, 52, 40)
"""The label bar above each panel: a dark slate, never the colour of a grey image's pixel."""
LABEL_INK = (245, 245, 245)
MAX_COLUMNS = 6
PAIR_WIDTH = 320
"""Each rectified view below the panels is at most this wide (or a panel's width if wider)."""


@dataclass
class DebugSheet:
    image: np.ndarray
    panels: List[Tuple[int, int, int, int]] = field(default_factory=list)
    """(x, y, w, h) of each image's panel (its label bar and the image), in the order given."""
    rectified: List[Tuple[int, int, int, int]] = field(default_factory=list)
    """(x, y, w, h) of the rectified views: zero-shot's, then the refined camera's (if any)."""


def columns_for(n: int, width: int, height: int) -> int:
    """Panels per row: all in one row up to 4 images, else about a square sheet (at most 6)."""
    if n <= 4:
        return max(1, n)
    return min(MAX_COLUMNS, int(math.ceil(math.sqrt(n * height / width * 1.4))))


def _curves_by_image(curves, n_images: int) -> Dict[int, list]:
    out: Dict[int, list] = {i: [] for i in range(n_images)}
    for c in curves or []:
        image = getattr(c, 'image', None)
        out.setdefault(0 if image is None else int(image), []).append(c)
    return out


def _scaled(curves, s: float):
    return [SimpleNamespace(points=np.asarray(c.points, float) * s) for c in curves]


def render_debug_sheet(images: Sequence[np.ndarray], names: Sequence[str], result, zero_shot_camera,
                       balance: float = 0.0, fov_scale: float = 1.0) -> DebugSheet:
    """The contact sheet (module docstring) of ``refine``'s ``result`` (a ``Refinement``: its
    ``curves`` and ``used`` mask, ``static_curves``, ``accepted``, ``reason`` and ``camera``) over
    ``images`` (the images the curves' ``image`` indices refer to) named ``names``."""
    n = len(images)
    h, w = images[0].shape[:2]
    cols = columns_for(n, w, h)
    rows = int(math.ceil(n / cols))
    s = min(1.0, (MAX_WIDTH - 2 * MARGIN - (cols - 1) * GAP) / (cols * w))
    verdict, colour = verdict_text(result.accepted, result.reason, 'refine')
    curves = list(getattr(result, 'curves', None) or [])
    used_mask = getattr(result, 'used', None)
    used_mask = np.zeros(len(curves), bool) if used_mask is None else np.asarray(used_mask, bool)
    static = list(getattr(result, 'static_curves', None) or [])
    totals = (int(used_mask.sum()), int(len(curves) - used_mask.sum()), len(static))
    entries = [(f'used by the fit ({totals[0]})', CURVE_USED),
               (f'rejected: not straight, or bowing toward the centre ({totals[1]})', CURVE_REJECTED),
               (f'left out: stayed put across the images ({totals[2]})', CURVE_STATIC)]
    legend_step = line_height(0.45) + 6
    # keep the sheet about MAX_HEIGHT high: the panels scaled down further if needed (the header
    # counted at its largest, the rectified pair at half the sheet's width each)
    fixed = 2 * MARGIN + 4 * 24 + 38 + 2 * legend_step + 2 * GAP + LABEL_H + (MAX_WIDTH // 2) * h / w + rows * LABEL_H + (rows - 1) * GAP
    if rows * h * s > MAX_HEIGHT - fixed > 0:
        s = (MAX_HEIGHT - fixed) / (rows * h)
    pw = max(1, int(w * s))  # rounded down: the row never wider than MAX_WIDTH
    ph = max(1, int(round(h * pw / w)))
    width = max(2 * MARGIN + cols * pw + (cols - 1) * GAP, 640)
    # the legend in as many rows as the sheet's width needs (a narrow sheet cut its last entry)
    legend_lines = legend_rows(entries, width - 2 * MARGIN)
    header_h = wrapped_height(verdict, width - 2 * MARGIN, 0.55, 1, 4) + 38 + (len(legend_lines) - 1) * legend_step
    # the first image rectified twice, side by side below the panels (MAX_HEIGHT assumed them at
    # most half the sheet's width each)
    pair_w = max(1, min(w, (width - 2 * MARGIN - GAP) // 2, max(pw, PAIR_WIDTH)))
    pair_h = max(1, int(round(h * pair_w / w)))
    grid_h = rows * (LABEL_H + ph) + (rows - 1) * GAP
    height = MARGIN + header_h + GAP + grid_h + GAP + LABEL_H + pair_h + MARGIN
    canvas = np.full((height, width, 3), PAPER, np.uint8)
    sheet = DebugSheet(canvas)

    # header: the verdict and the legend
    y = MARGIN
    y = put_wrapped(canvas, verdict, MARGIN, y, width - 2 * MARGIN, 0.55, colour, 1, 4)
    for k, row in enumerate(legend_lines):
        legend(canvas, MARGIN, y + 6 + k * legend_step, row, 0.45)
    y = MARGIN + header_h + GAP

    by_image = _curves_by_image(curves, n)
    used_by_image = _curves_by_image([c for c, ok in zip(curves, used_mask) if ok], n)
    static_by_image = _curves_by_image(static, n)
    for i, image in enumerate(images):
        r, c = divmod(i, cols)
        x0 = MARGIN + c * (pw + GAP)
        y0 = y + r * (LABEL_H + ph + GAP)
        used = used_by_image.get(i, [])
        rejected = [k for k in by_image.get(i, []) if not any(k is u for u in used)]
        left_out = static_by_image.get(i, [])
        small = cv2.resize(as_bgr(image), (pw, ph), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        drawn = draw_curves(small, _scaled(used, pw / w), _scaled(rejected, pw / w), thickness=2 if s > 0.45 else 1,
                            static=_scaled(left_out, pw / w))
        canvas[y0 + LABEL_H:y0 + LABEL_H + ph, x0:x0 + pw] = drawn
        cv2.rectangle(canvas, (x0, y0), (x0 + pw - 1, y0 + LABEL_H - 1), LABEL_BG, -1)
        name = str(names[i]).replace('\\', '/').rsplit('/', 1)[-1] if i < len(names) else ''
        counts = f'{len(used)} / {len(rejected)} / {len(left_out)}'
        label = f'{i + 1}: {name}'
        room = pw - 12 - text_width(counts, 0.42)
        while label and text_width(label, 0.42) > room - 8:
            label = label[:-2] if len(label) > 4 else ''
        put_text(canvas, label, x0 + 5, y0 + 5, 0.42, LABEL_INK, 1)
        x_counts = x0 + pw - 5
        for text, col in ((str(len(left_out)), CURVE_STATIC), (' / ', LABEL_INK), (str(len(rejected)), CURVE_REJECTED),
                          (' / ', LABEL_INK), (str(len(used)), CURVE_USED)):
            x_counts -= put_text(canvas, text, x_counts, y0 + 5, 0.42, col, 1, 'right')
        sheet.panels.append((x0, y0, pw, LABEL_H + ph))
    y += grid_h + GAP

    # the first image rectified with zero-shot and with the refined camera (written, or refused and
    # not written; none when no fit was made), one P (zero-shot's)
    P = new_camera_matrix(zero_shot_camera, balance, fov_scale)
    fitted = result.camera if result.accepted else getattr(result, 'refined_camera', None)
    # the refined view's title says the P: its principal point moved, so a margin of the view can
    # be outside the image (black), which the written file's own P does not show
    titles = ('image 1 rectified with the zero-shot camera',
              ('with the refined camera (written)' if result.accepted else 'the refined camera (refused)')
              + ", zero-shot's P")
    for k, camera in enumerate((zero_shot_camera, fitted)):
        if camera is None:
            put_text(canvas, 'no refined camera: no fit was made', MARGIN + pair_w + GAP, y + 4, 0.45, MUTED, 1)
            continue
        x0 = MARGIN + k * (pair_w + GAP)
        rect = Rectifier(camera, P=P).rectify(images[0])
        rect = cv2.resize(as_bgr(rect), (pair_w, pair_h),
                          interpolation=cv2.INTER_AREA if pair_w < w else cv2.INTER_LINEAR)
        canvas[y + LABEL_H:y + LABEL_H + pair_h, x0:x0 + pair_w] = rect
        put_text(canvas, titles[k], x0, y + 4, 0.45, INK if k else MUTED, 1)
        sheet.rectified.append((x0, y + LABEL_H, pair_w, pair_h))
    return sheet
