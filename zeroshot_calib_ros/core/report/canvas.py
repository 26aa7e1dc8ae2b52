"""Drawing with OpenCV alone: text that wraps, panels with a header, plot axes, a colour bar.

Every picture of ``core/report`` is drawn here on a BGR uint8 canvas; OpenCV's Hershey fonts
have ASCII only, so text goes through ``ascii_text`` first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
WHITE = (255, 255, 255)
PAPER = (250, 250, 250)
INK = (30, 30, 30)
MUTED = (120, 120, 120)
GRID = (225, 225, 225)
PANEL_EDGE = (200, 200, 200)
HEADER = (60, 60, 60)
GREEN = (0, 150, 0)
RED = (0, 0, 210)
ORANGE = (0, 120, 230)
BLUE = (180, 100, 20)
CURVE_USED = (0, 220, 0)
CURVE_REJECTED = (0, 0, 255)
CURVE_STATIC = (0, 140, 255)
"""The colours ``core.lines.detect.draw_curves`` draws curves in (used, rejected, left out)."""
COLORMAP = cv2.COLORMAP_VIRIDIS
NO_DATA = (205, 205, 205)

_REPLACE = {'\u00b1': '+-', '\u00b0': ' deg', '\u2013': '-', '\u2014': '-', '\u2212': '-', '\u00d7': 'x',
            '\u2018': "'", '\u2019': "'", '\u201c': '"', '\u201d': '"', '\u2026': '...', '\u03c3': 'sigma',
            '\u03b8': 'theta'}


def ascii_text(text: str) -> str:
    """``text`` as the Hershey fonts can draw it: a few symbols spelled out, other non-ASCII '?'."""
    text = ''.join(_REPLACE.get(ch, ch) for ch in str(text))
    return text.encode('ascii', 'replace').decode('ascii')


def text_width(text: str, scale: float = 0.5, thickness: int = 1) -> int:
    return cv2.getTextSize(ascii_text(text), FONT, scale, thickness)[0][0]


def line_height(scale: float = 0.5) -> int:
    """Pixels from one line's top to the next line's top."""
    return int(round(cv2.getTextSize('Ag', FONT, scale, 1)[0][1] * 1.9)) + 2


def put_text(image, text: str, x: int, y: int, scale: float = 0.5, colour=INK, thickness: int = 1,
             align: str = 'left') -> int:
    """Draw one line with its top-left (``align`` 'left'), top-centre ('centre') or top-right
    ('right') at (x, y); returns its width."""
    text = ascii_text(text)
    (w, h), _ = cv2.getTextSize(text, FONT, scale, thickness)
    if align == 'centre':
        x -= w // 2
    elif align == 'right':
        x -= w
    cv2.putText(image, text, (int(x), int(y + h)), FONT, scale, colour, thickness, cv2.LINE_AA)
    return w


def wrap(text: str, width: int, scale: float = 0.5, thickness: int = 1) -> List[str]:
    """``text`` broken at spaces into lines no wider than ``width`` px (a longer word is cut)."""
    lines: List[str] = []
    for paragraph in ascii_text(text).split('\n'):
        current = ''
        for word in paragraph.split(' '):
            trial = f'{current} {word}' if current else word
            if text_width(trial, scale, thickness) <= width:
                current = trial
                continue
            if current:
                lines.append(current)
            while text_width(word, scale, thickness) > width and len(word) > 1:
                cut = len(word)
                while cut > 1 and text_width(word[:cut], scale, thickness) > width:
                    cut -= 1
                lines.append(word[:cut])
                word = word[cut:]
            current = word
        lines.append(current)
    return lines


def put_wrapped(image, text: str, x: int, y: int, width: int, scale: float = 0.5, colour=INK,
                thickness: int = 1, max_lines: Optional[int] = None) -> int:
    """Draw ``text`` wrapped to ``width``; returns the y below it. With ``max_lines``, the last
    line shown ends in '...' when more would follow."""
    lines = wrap(text, width, scale, thickness)
    if max_lines is not None and len(lines) > max_lines:
        lines = lines[:max_lines]
        last = lines[-1]
        while last and text_width(last + ' ...', scale, thickness) > width:
            last = last[:-1]
        lines[-1] = last.rstrip() + ' ...'
    step = line_height(scale)
    for line in lines:
        put_text(image, line, x, y, scale, colour, thickness)
        y += step
    return y


def wrapped_height(text: str, width: int, scale: float = 0.5, thickness: int = 1,
                   max_lines: Optional[int] = None) -> int:
    n = len(wrap(text, width, scale, thickness))
    return line_height(scale) * (n if max_lines is None else min(n, max_lines))


def as_bgr(image) -> np.ndarray:
    """A BGR uint8 copy of a grey, BGR or BGRA image of any depth (scaled to 0-255)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = img.astype(np.float64)
        finite = img[np.isfinite(img)]
        top = float(finite.max()) if finite.size else 1.0
        img = np.clip(np.nan_to_num(img) * (255.0 / max(top, 1e-12)), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 1:
        return cv2.cvtColor(img[..., 0], cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(img[..., :3])


@dataclass
class Rect:
    x: int
    y: int
    w: int
    h: int

    def as_tuple(self) -> Tuple[int, int, int, int]:
        return (self.x, self.y, self.w, self.h)

    def view(self, image):
        return image[self.y:self.y + self.h, self.x:self.x + self.w]


def fit_size(width: int, height: int, box_w: int, box_h: int) -> Tuple[int, int]:
    """The largest size of aspect width:height inside box_w x box_h."""
    s = min(box_w / width, box_h / height)
    return max(1, int(round(width * s))), max(1, int(round(height * s)))


def paste_fitted(canvas, image, box: Rect, interpolation=cv2.INTER_AREA) -> Rect:
    """``image`` resized to fit ``box`` (aspect kept), centred in it; returns where it went."""
    h, w = image.shape[:2]
    fw, fh = fit_size(w, h, box.w, box.h)
    small = cv2.resize(as_bgr(image), (fw, fh), interpolation=interpolation if fw < w else cv2.INTER_LINEAR)
    x, y = box.x + (box.w - fw) // 2, box.y + (box.h - fh) // 2
    canvas[y:y + fh, x:x + fw] = small
    return Rect(x, y, fw, fh)


PANEL_HEADER = 26


def panel(canvas, rect: Rect, title: str) -> Rect:
    """A panel: white, a thin frame, ``title`` in its header; returns the body below the header."""
    cv2.rectangle(canvas, (rect.x, rect.y), (rect.x + rect.w - 1, rect.y + rect.h - 1), WHITE, -1)
    cv2.rectangle(canvas, (rect.x, rect.y), (rect.x + rect.w - 1, rect.y + rect.h - 1), PANEL_EDGE, 1)
    lines = wrap(title, rect.w - 16, 0.5, 1)
    title = lines[0] if len(lines) == 1 else lines[0] + ' ...'
    while text_width(title) > rect.w - 16 and len(title) > 4:
        title = title[:-5] + ' ...'
    put_text(canvas, title, rect.x + 8, rect.y + 7, 0.5, HEADER, 1)
    return Rect(rect.x + 1, rect.y + PANEL_HEADER, rect.w - 2, rect.h - PANEL_HEADER - 1)


def nice_step(span: float, target: int = 5) -> float:
    """A 1, 2 or 5 times a power of ten giving about ``target`` ticks over ``span``."""
    if not (span > 0 and math.isfinite(span)):
        return 1.0
    raw = span / max(target, 1)
    power = 10 ** math.floor(math.log10(raw))
    for m in (1, 2, 5, 10):
        if m * power >= raw:
            return m * power
    return 10 * power


def nice_ceiling(value: float) -> float:
    """The smallest round number (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6 or 8 times a power of ten) at or
    above ``value`` (> 0)."""
    if not (value > 0 and math.isfinite(value)):
        return 1.0
    power = 10 ** math.floor(math.log10(value))
    for m in (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8, 10):
        if m * power >= value * (1 - 1e-9):
            return m * power
    return 10 * power


def tick_label(value: float, step: float) -> str:
    decimals = max(0, -int(math.floor(math.log10(step)))) if step < 1 else 0
    return f'{value:.{decimals}f}'


@dataclass
class Axes:
    """A plot area inside a body rect, with data limits: ``to_px`` maps data to canvas pixels."""

    area: Rect
    x_range: Tuple[float, float]
    y_range: Tuple[float, float]

    def to_px(self, x, y) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        (x0, x1), (y0, y1) = self.x_range, self.y_range
        u = self.area.x + (x - x0) / (x1 - x0) * (self.area.w - 1)
        v = self.area.y + self.area.h - 1 - (y - y0) / (y1 - y0) * (self.area.h - 1)
        return np.stack([u, v], axis=-1)


def axes(canvas, body: Rect, x_range, y_range, x_label: str, y_label: str, x_ticks: int = 6,
         y_ticks: int = 5, x_tick_labels: Optional[Sequence[Tuple[float, str]]] = None) -> Axes:
    """Plot axes in ``body``: grid, ticks with labels, axis labels; returns the ``Axes``."""
    left, bottom, top, right = 52, 40, 24, 14
    area = Rect(body.x + left, body.y + top, body.w - left - right, body.h - top - bottom)
    ax = Axes(area, tuple(map(float, x_range)), tuple(map(float, y_range)))
    cv2.rectangle(canvas, (area.x, area.y), (area.x + area.w - 1, area.y + area.h - 1), INK, 1)
    y_step = nice_step(y_range[1] - y_range[0], y_ticks)
    value = math.ceil(y_range[0] / y_step) * y_step
    while value <= y_range[1] + 1e-9 * y_step:
        _, v = ax.to_px(x_range[0], value)
        v = int(round(v))
        cv2.line(canvas, (area.x + 1, v), (area.x + area.w - 2, v), GRID, 1)
        cv2.line(canvas, (area.x - 4, v), (area.x, v), INK, 1)
        put_text(canvas, tick_label(value, y_step), area.x - 7, v - 5, 0.4, INK, 1, 'right')
        value += y_step
    if x_tick_labels is None:
        x_step = nice_step(x_range[1] - x_range[0], x_ticks)
        ticks = []
        value = math.ceil(x_range[0] / x_step) * x_step
        while value <= x_range[1] + 1e-9 * x_step:
            ticks.append((value, tick_label(value, x_step)))
            value += x_step
    else:
        ticks = list(x_tick_labels)
    for value, label in ticks:
        u, _ = ax.to_px(value, y_range[0])
        u = int(round(u))
        if x_tick_labels is None:
            cv2.line(canvas, (u, area.y + 1), (u, area.y + area.h - 2), GRID, 1)
        cv2.line(canvas, (u, area.y + area.h - 1), (u, area.y + area.h + 3), INK, 1)
        if label:
            put_text(canvas, label, u, area.y + area.h + 6, 0.4, INK, 1, 'centre')
    cv2.rectangle(canvas, (area.x, area.y), (area.x + area.w - 1, area.y + area.h - 1), INK, 1)
    put_text(canvas, x_label, area.x + area.w // 2, body.y + body.h - 17, 0.45, INK, 1, 'centre')
    # the y label, above the axis (Hershey text does not rotate)
    put_text(canvas, y_label, body.x + 6, body.y + 4, 0.4, MUTED, 1)
    return ax


def polyline(canvas, points: np.ndarray, colour, thickness: int = 2, dashed: bool = False):
    """A polyline through (N, 2) canvas points; NaN points break it; ``dashed``: 8 px on, 6 off."""
    p = np.asarray(points, dtype=float)
    good = np.all(np.isfinite(p), axis=1)
    runs, start = [], None
    for i, ok in enumerate(good):
        if ok and start is None:
            start = i
        if (not ok or i == len(good) - 1) and start is not None:
            end = i + 1 if ok else i
            if end - start >= 2:
                runs.append(p[start:end])
            start = None
    shift = 4
    for run in runs:
        if dashed:
            # resampled about every pixel, so that long straight segments are dashed too
            seg = np.hypot(*np.diff(run, axis=0).T)
            t = np.concatenate([[0.0], np.cumsum(seg)])
            if t[-1] > 0:
                fine = np.linspace(0.0, t[-1], max(2, int(t[-1]) + 1))
                run = np.stack([np.interp(fine, t, run[:, 0]), np.interp(fine, t, run[:, 1])], axis=1)
            seg = np.hypot(*np.diff(run, axis=0).T)
            s = np.concatenate([[0.0], np.cumsum(seg)])
            on = (s % 14.0) < 8.0
            pieces, begin = [], None
            for i, flag in enumerate(on):
                if flag and begin is None:
                    begin = i
                if (not flag or i == len(on) - 1) and begin is not None:
                    if i - begin >= 1:
                        pieces.append(run[begin:i + 1])
                    begin = None
        else:
            pieces = [run]
        pts = [np.round(q * (1 << shift)).astype(np.int32).reshape(-1, 1, 2) for q in pieces if len(q) >= 2]
        if pts:
            cv2.polylines(canvas, pts, False, colour, thickness, cv2.LINE_AA, shift)


def colour_lut() -> np.ndarray:
    """(256, 3) BGR of ``COLORMAP``: value v / 255 of the bar's range has colour lut[v]."""
    return cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(-1, 1), COLORMAP).reshape(256, 3)


def fill_from_neighbours(values: np.ndarray, passes: int = 3) -> np.ndarray:
    """NaN nodes of a grid next to finite ones take their neighbours' mean (``passes`` rings)."""
    out = np.array(values, dtype=float)
    for _ in range(passes):
        valid = np.isfinite(out)
        if valid.all() or not valid.any():
            break
        padded = np.pad(np.where(valid, out, 0.0), 1)
        count = np.pad(valid.astype(float), 1)
        total = sum(padded[1 + di:padded.shape[0] - 1 + di, 1 + dj:padded.shape[1] - 1 + dj]
                    for di in (-1, 0, 1) for dj in (-1, 0, 1))
        n = sum(count[1 + di:count.shape[0] - 1 + di, 1 + dj:count.shape[1] - 1 + dj]
                for di in (-1, 0, 1) for dj in (-1, 0, 1))
        grow = ~valid & (n > 0)
        out[grow] = total[grow] / n[grow]
    return out


def heat_map(values: np.ndarray, vmax: float, size: Tuple[int, int],
             no_data: Optional[np.ndarray] = None) -> np.ndarray:
    """A (rows, cols) grid of values spanning an image edge to edge, drawn at ``size`` (w, h) in
    ``COLORMAP`` over 0..vmax, bilinear between the grid nodes; NaN nodes are ``NO_DATA``.
    ``no_data``: an (h, w) mask drawn as ``NO_DATA`` instead (the values then extended past it
    so that its edge is the mask's, not the grid's)."""
    rows, cols = values.shape
    w, h = size
    if no_data is not None:
        values = fill_from_neighbours(values)
    valid = np.isfinite(values)
    filled = np.where(valid, values, 0.0).astype(np.float32)
    weight = valid.astype(np.float32)
    # grid node (i, j) is at pixel (j (w - 1) / (cols - 1), i (h - 1) / (rows - 1)): remap samples there
    u = np.linspace(0.0, cols - 1.0, w, dtype=np.float32)
    v = np.linspace(0.0, rows - 1.0, h, dtype=np.float32)
    mx, my = np.meshgrid(u, v)
    num = cv2.remap(filled * weight, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    den = cv2.remap(weight, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    with np.errstate(invalid='ignore', divide='ignore'):
        field = np.where(den > 0.5, num / np.maximum(den, 1e-6), np.nan)
    level = np.clip(np.nan_to_num(field / max(vmax, 1e-12)) * 255.0, 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(level, COLORMAP)
    out[~np.isfinite(field) if no_data is None else no_data] = NO_DATA
    return out


def put_label(image, text: str, x: int, y: int, scale: float = 0.42, colour=INK, align: str = 'left',
              background=WHITE) -> int:
    """``put_text`` on a filled box of ``background`` (readable over a plot's lines and bars)."""
    w = text_width(text, scale)
    h = cv2.getTextSize(ascii_text(text), FONT, scale, 1)[0][1]
    left = x - (w // 2 if align == 'centre' else w if align == 'right' else 0)
    cv2.rectangle(image, (left - 3, y - 3), (left + w + 3, y + h + 5), background, -1)
    return put_text(image, text, x, y, scale, colour, 1, align)


def colour_bar(canvas, rect: Rect, vmax: float, label: str = 'px', clipped: bool = False):
    """A vertical colour bar of 0..vmax in ``rect`` (top: vmax), ticks and ``label`` beside it;
    ``clipped``: values above vmax are drawn in its colour (the top tick says '+')."""
    bar_w = 14
    lut = colour_lut()
    column = lut[np.linspace(255, 0, rect.h).astype(int)]
    canvas[rect.y:rect.y + rect.h, rect.x:rect.x + bar_w] = column[:, None, :]
    cv2.rectangle(canvas, (rect.x, rect.y), (rect.x + bar_w - 1, rect.y + rect.h - 1), INK, 1)
    step = nice_step(vmax, 4)
    value = 0.0
    while value <= vmax * (1 + 1e-9):
        v = int(round(rect.y + rect.h - 1 - value / vmax * (rect.h - 1)))
        cv2.line(canvas, (rect.x + bar_w, v), (rect.x + bar_w + 4, v), INK, 1)
        top = value + step > vmax * (1 + 1e-9)
        put_text(canvas, tick_label(value, step) + ('+' if clipped and top else ''), rect.x + bar_w + 7, v - 5,
                 0.4, INK, 1)
        value += step
    put_text(canvas, label, rect.x, rect.y + rect.h + 6, 0.4, INK, 1)


def legend_width(entries: Sequence[Tuple[str, tuple]], scale: float = 0.45) -> int:
    return sum(28 + text_width(text, scale) + 18 for text, _ in entries) - 18


def legend_rows(entries: Sequence[Tuple[str, tuple]], max_width: int, scale: float = 0.45) -> List[list]:
    """``entries`` (text, colour) in rows of at most ``max_width`` px each (``legend``'s layout),
    in order; an entry wider than that alone on its row."""
    rows: List[list] = []
    for entry in entries:
        if rows and legend_width(rows[-1] + [entry], scale) <= max_width:
            rows[-1].append(entry)
        else:
            rows.append([entry])
    return rows


def legend(canvas, x: int, y: int, entries: Sequence[Tuple[str, tuple]], scale: float = 0.45,
           line: bool = True) -> int:
    """Entries (text, colour) left to right from (x, y), each a short stroke (or a square) and its
    text; returns the x after the last."""
    for text, colour in entries:
        if line:
            cv2.line(canvas, (x, y + 6), (x + 22, y + 6), colour, 3, cv2.LINE_AA)
        else:
            cv2.rectangle(canvas, (x + 4, y), (x + 16, y + 12), colour, -1)
        x += 28
        x += put_text(canvas, text, x, y, scale, INK, 1) + 18
    return x


def legend_column(canvas, right: int, bottom: int, entries: Sequence[Tuple[str, tuple]], scale: float = 0.4):
    """Entries (text, colour) one under the other, a stroke and the text each, the block's lower
    right corner at (right, bottom)."""
    step = line_height(scale)
    width = max(text_width(text, scale) for text, _ in entries) + 30
    y = bottom - step * len(entries)
    cv2.rectangle(canvas, (right - width - 6, y - 4), (right + 2, bottom), WHITE, -1)
    for text, colour in entries:
        cv2.line(canvas, (right - width, y + 6), (right - width + 22, y + 6), colour, 3, cv2.LINE_AA)
        put_text(canvas, text, right - width + 28, y, scale, INK, 1)
        y += step
