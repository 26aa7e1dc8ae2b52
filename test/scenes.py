"""Ordinary scenes (a room, a corridor, a street) rendered through any ``CameraModel``, with the
straight 3-D segments they contain: the test fixture of the line evidence (issue 13).

Every pixel is ray cast: its ray comes from ``camera.unproject`` (so lenses beyond 180 degrees
work; a pixel without a ray, or outside a ``circle_radius``, is black), is rotated into the world
and meets the nearest of a set of axis-aligned rectangles (walls, floor, ceiling, kerbs, boxes).
Each rectangle carries painted items in its own plane coordinates: straight ones (door and window
frames, floor tiles, shelves, storey bands, lane markings) whose edges are the ground truth, and
curved distractors (discs, rings, arches, wheels, foliage-like blobs). Edges are anti-aliased
twice over: painted items are box-filtered analytically over each sample's footprint on its plane
(ray differentials), and ``supersample`` x ``supersample`` samples per pixel are averaged (which
smooths the edges between rectangles). Lighting (ambient + a point light or the sun), a
multiplicative value-noise texture on every surface, an optional blur and Gaussian sensor noise
keep it from being trivially clean.

World frame: X right, Y up, Z forward (metres); the camera frame is OpenCV's (x right, y down,
z forward). ``pose`` = {'position': (x, y, z), 'yaw': deg (about world up, + turns right),
'pitch': deg (+ looks up), 'roll': deg (about the optical axis)}; keys left out keep the scene's
default. ``pose='random'`` draws a pose from ``seed`` inside the scene.

``render(camera, scene, pose, seed) -> (image, segments)``: ``segments`` is an (N, 2, 3) array of
the visible straight 3-D segments (end points in the camera frame; a segment partly hidden is split
into its visible runs). ``render_scene`` returns a ``Rendering`` with more (the noise-free image, the
contrast of each segment, a mask of the curved distractors).

Speed: rays come from ``camera.unproject`` on a grid every ``RAY_GRID`` pixels, are interpolated to
every sample and corrected by one Newton step through the closed-form ``camera.project`` (error
well under 1e-3 px; samples next to a pixel without a ray are unprojected exactly).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

SCENES = ('room', 'corridor', 'street')
RAY_GRID = 8
_F = np.float32


# ----------------------------------------------------------------------------- helpers

def _ramp(x, w):
    """Box-filtered step: the covered fraction of a footprint of width w centred x past the edge."""
    return np.clip(0.5 + x / w, 0.0, 1.0)


def _interval(x, lo, hi, w):
    """Box-filtered indicator of lo <= x <= hi (exact in 1-D, also for intervals thinner than w)."""
    return _ramp(x - lo, w) - _ramp(x - hi, w)


def _square_integral(x, s):
    """Integral from 0 to x of the square wave that is 1 on [s, 2s) of every period 2s."""
    return s * np.floor(x / (2 * s)) + np.clip(np.mod(x, 2 * s) - s, 0.0, s)


def _square_wave(x, s, w):
    """Box filter of width w of the square wave above (exact)."""
    w = np.maximum(w, 1e-6)
    return (_square_integral(x + w / 2, s) - _square_integral(x - w / 2, s)) / w


class ValueNoise:
    """Smooth random texture in [0, 1]: bilinear (smoothstep) interpolation of a random lattice."""

    def __init__(self, rng, size=128):
        self.size = size
        self.grid = rng.random((size, size)).astype(_F)

    def __call__(self, a, b):
        a = np.asarray(a, dtype=_F)
        shape = a.shape
        a = a.ravel()
        b = np.asarray(b, dtype=_F).ravel()
        n = a.size
        if n == 0:
            return np.zeros(shape, dtype=_F)
        cols = 4096
        rows = -(-n // cols)
        # bilinear interpolation of the periodic lattice (cv2.remap wraps around)
        ma = np.zeros(rows * cols, dtype=_F)
        mb = np.zeros(rows * cols, dtype=_F)
        ma[:n] = np.mod(a, self.size)
        mb[:n] = np.mod(b, self.size)
        out = cv2.remap(self.grid, ma.reshape(rows, cols), mb.reshape(rows, cols), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_WRAP)
        return out.ravel()[:n].reshape(shape)


def _tint(rng, saturation=0.25):
    """A random colour of luminance 1 (B, G, R multipliers)."""
    t = 1.0 + saturation * (rng.random(3) * 2 - 1)
    lum = 0.114 * t[0] + 0.587 * t[1] + 0.299 * t[2]
    return tuple(float(x) for x in t / lum)


GREY = (1.0, 1.0, 1.0)


# ----------------------------------------------------------------------------- painted items
# Items live in a surface's plane coordinates (a, b) (metres); see Surface for the axes.
# shade(a, b, wa, wb) -> (coverage, value): coverage in [0, 1] box-filtered over the footprint
# (wa, wb: the footprint's extent along a and b); value a scalar or an array.

class Item:
    value = 0.5
    tint = GREY
    curved = False
    bbox = (-math.inf, -math.inf, math.inf, math.inf)

    def shade(self, a, b, wa, wb):
        raise NotImplementedError

    def covers(self, a, b):
        cov, _ = self.shade(a, b, np.full_like(a, 1e-6), np.full_like(b, 1e-6))
        return cov > 0.5

    def edges(self) -> List[Tuple[Tuple[float, float], Tuple[float, float]]]:
        return []


class RectItem(Item):
    def __init__(self, a0, b0, a1, b1, value, tint=GREY):
        self.a0, self.b0, self.a1, self.b1 = float(a0), float(b0), float(a1), float(b1)
        self.value, self.tint = value, tint
        self.bbox = (self.a0, self.b0, self.a1, self.b1)

    def shade(self, a, b, wa, wb):
        return _interval(a, self.a0, self.a1, wa) * _interval(b, self.b0, self.b1, wb), self.value

    def edges(self):
        a0, b0, a1, b1 = self.bbox
        return [((a0, b0), (a1, b0)), ((a1, b0), (a1, b1)), ((a1, b1), (a0, b1)), ((a0, b1), (a0, b0))]


class DiscItem(Item):
    """A disc (ring when inner > 0): a curved distractor (clock, mirror, lamp, wheel, sign)."""
    curved = True

    def __init__(self, ca, cb, radius, value, inner=0.0, tint=GREY):
        self.ca, self.cb, self.r, self.inner = float(ca), float(cb), float(radius), float(inner)
        self.value, self.tint = value, tint
        self.bbox = (self.ca - self.r, self.cb - self.r, self.ca + self.r, self.cb + self.r)

    def shade(self, a, b, wa, wb):
        d = np.hypot(a - self.ca, b - self.cb)
        w = np.maximum(wa, wb)
        cov = _ramp(self.r - d, w)
        if self.inner > 0:
            cov = cov - _ramp(self.inner - d, w)
        return cov, self.value


class ArchItem(Item):
    """A doorway or window with a round top: straight sides and sill (edges), a curved top."""
    curved = True

    def __init__(self, a0, b0, a1, b_spring, value, tint=GREY):
        self.a0, self.b0, self.a1, self.bs = float(a0), float(b0), float(a1), float(b_spring)
        self.r = (self.a1 - self.a0) / 2
        self.value, self.tint = value, tint
        self.bbox = (self.a0, self.b0, self.a1, self.bs + self.r)

    def shade(self, a, b, wa, wb):
        rect = _interval(a, self.a0, self.a1, wa) * _interval(b, self.b0, self.bs, wb)
        d = np.hypot(a - (self.a0 + self.r), b - self.bs)
        return np.maximum(rect, _ramp(self.r - d, np.maximum(wa, wb))), self.value

    def edges(self):
        return [((self.a0, self.b0), (self.a0, self.bs)), ((self.a1, self.b0), (self.a1, self.bs)),
                ((self.a0, self.b0), (self.a1, self.b0))]


class BlobItem(Item):
    """Foliage: a noise field thresholded inside an ellipse; curved, irregular boundaries."""
    curved = True

    def __init__(self, ca, cb, ra, rb, value, rng, scale=0.25, tint=GREY):
        self.ca, self.cb, self.ra, self.rb = float(ca), float(cb), float(ra), float(rb)
        self.value, self.tint, self.scale = value, tint, scale
        self.noise = ValueNoise(rng, 64)
        self.bbox = (self.ca - self.ra, self.cb - self.rb, self.ca + self.ra, self.cb + self.rb)

    def _field(self, a, b):
        e = np.hypot((a - self.ca) / self.ra, (b - self.cb) / self.rb)
        n = 0.65 * self.noise(a / self.scale, b / self.scale) + 0.35 * self.noise(a / (0.37 * self.scale) + 17,
                                                                                 b / (0.37 * self.scale))
        return n + 0.55 - 0.75 * e

    def shade(self, a, b, wa, wb):
        w = 2.5 * np.maximum(wa, wb) / self.scale + 1e-3
        field_value = self._field(a, b)
        cov = np.clip(0.5 + (field_value - 0.5) / w, 0.0, 1.0)
        value = self.value * (0.7 + 0.6 * self.noise(a / (0.2 * self.scale) + 5, b / (0.2 * self.scale) + 9))
        return cov, value


class CheckerItem(Item):
    """Floor tiles: squares of side ``side`` alternating between two values inside a rectangle."""

    def __init__(self, a0, b0, a1, b1, side, v0, v1, tint=GREY):
        self.a0, self.b0, self.a1, self.b1, self.side = float(a0), float(b0), float(a1), float(b1), float(side)
        self.v0, self.v1, self.value, self.tint = v0, v1, (v0 + v1) / 2, tint
        self.bbox = (self.a0, self.b0, self.a1, self.b1)

    def shade(self, a, b, wa, wb):
        cov = _interval(a, self.a0, self.a1, wa) * _interval(b, self.b0, self.b1, wb)
        sa = _square_wave(a - self.a0, self.side, wa)
        sb = _square_wave(b - self.b0, self.side, wb)
        odd = sa + sb - 2 * sa * sb
        return cov, self.v0 + (self.v1 - self.v0) * odd

    def edges(self):
        out = []
        n_a = int(round((self.a1 - self.a0) / self.side))
        n_b = int(round((self.b1 - self.b0) / self.side))
        for k in range(1, n_a):
            a = self.a0 + k * self.side
            out.append(((a, self.b0), (a, self.b1)))
        for k in range(1, n_b):
            b = self.b0 + k * self.side
            out.append(((self.a0, b), (self.a1, b)))
        return out


class ArrayItem(Item):
    """A template of items repeated on a grid (windows of a facade, books, doors, lamps), each
    cell's values jittered by ``jitter``."""

    def __init__(self, template: Sequence[Item], a0, b0, pitch_a, pitch_b, n_a, n_b, rng, jitter=0.0):
        self.template = list(template)
        self.a0, self.b0, self.pa, self.pb, self.na, self.nb = float(a0), float(b0), pitch_a, pitch_b, n_a, n_b
        self.jitter = rng.uniform(-jitter, jitter, size=(n_b, n_a, len(self.template))).astype(_F)
        lo_a = min(t.bbox[0] for t in self.template)
        lo_b = min(t.bbox[1] for t in self.template)
        hi_a = max(t.bbox[2] for t in self.template)
        hi_b = max(t.bbox[3] for t in self.template)
        self.bbox = (self.a0 + lo_a, self.b0 + lo_b, self.a0 + (n_a - 1) * pitch_a + hi_a,
                     self.b0 + (n_b - 1) * pitch_b + hi_b)
        self.curved = any(t.curved for t in self.template)
        self.value = self.template[0].value
        self.tint = self.template[0].tint

    def _local(self, a, b):
        # nearest cell (templates stay inside their cell, with margins)
        ia = np.clip(np.floor((a - self.a0) / self.pa + 0.5), 0, self.na - 1).astype(np.int32)
        ib = np.clip(np.floor((b - self.b0) / self.pb + 0.5), 0, self.nb - 1).astype(np.int32)
        return a - (self.a0 + ia * self.pa), b - (self.b0 + ib * self.pb), ia, ib

    def layers(self, a, b, wa, wb):
        """(coverage, value, tint) of each template item in turn, for compositing."""
        la, lb, ia, ib = self._local(a, b)
        for k, item in enumerate(self.template):
            cov, value = item.shade(la, lb, wa, wb)
            yield cov, value + self.jitter[ib, ia, k], item.tint

    def shade(self, a, b, wa, wb):
        raise TypeError('ArrayItem is composited layer by layer')

    def covers(self, a, b):
        la, lb, _, _ = self._local(a, b)
        out = np.zeros(np.shape(a), dtype=bool)
        for item in self.template:
            out |= item.covers(la, lb)
        return out

    def edges(self):
        out = []
        for ib in range(self.nb):
            for ia in range(self.na):
                da, db = self.a0 + ia * self.pa, self.b0 + ib * self.pb
                for item in self.template:
                    for (p, q) in item.edges():
                        out.append(((p[0] + da, p[1] + db), (q[0] + da, q[1] + db)))
        return out

    def curved_items(self):
        return [k for k, t in enumerate(self.template) if t.curved]


# ----------------------------------------------------------------------------- surfaces

_PLANE_AXES = {0: (2, 1), 1: (0, 2), 2: (0, 1)}  # normal axis -> (a axis, b axis)


@dataclass
class Surface:
    """An axis-aligned rectangle: world coordinate ``axis`` = ``position``, a in [a0, a1] and b in
    [b0, b1] along the two other axes (normal X: a = Z, b = Y; normal Y: a = X, b = Z; normal Z:
    a = X, b = Y). ``edges``: whether its border is a ground-truth edge."""
    axis: int
    position: float
    a0: float
    a1: float
    b0: float
    b1: float
    value: float
    tint: Tuple[float, float, float] = GREY
    items: List[Item] = field(default_factory=list)
    texture: float = 0.08
    texture_scale: float = 0.35
    edges: bool = True
    noise: Optional[ValueNoise] = None

    def world(self, a, b):
        p = [0.0, 0.0, 0.0]
        ka, kb = _PLANE_AXES[self.axis]
        p[self.axis], p[ka], p[kb] = self.position, a, b
        return np.array(p)

    def border(self):
        c = [(self.a0, self.b0), (self.a1, self.b0), (self.a1, self.b1), (self.a0, self.b1)]
        return [(self.world(*c[i]), self.world(*c[(i + 1) % 4])) for i in range(4)]


@dataclass
class Scene:
    name: str
    surfaces: List[Surface]
    default_pose: dict
    bounds: Tuple[Tuple[float, float], Tuple[float, float], Tuple[float, float]]  # random positions
    light: Optional[Tuple[float, float, float]] = None  # point light (world); None: the sun
    sun: Tuple[float, float, float] = (0.4, 0.8, 0.3)
    sky: bool = False


def _box(x0, x1, y0, y1, z0, z1, value, rng, faces='all', tint=GREY, texture=0.06):
    """The faces of an axis-aligned box (furniture, a car body, a kerb)."""
    out = []
    shades = {0: 0.9, 1: 1.1, 2: 1.0}
    for axis, (lo, hi) in ((0, (x0, x1)), (1, (y0, y1)), (2, (z0, z1))):
        ka, kb = _PLANE_AXES[axis]
        rng_a = {0: (x0, x1), 1: (y0, y1), 2: (z0, z1)}[ka]
        rng_b = {0: (x0, x1), 1: (y0, y1), 2: (z0, z1)}[kb]
        for side, pos in (('-', lo), ('+', hi)):
            if faces != 'all' and f'{"xyz"[axis]}{side}' not in faces:
                continue
            out.append(Surface(axis, pos, rng_a[0], rng_a[1], rng_b[0], rng_b[1],
                               float(np.clip(value * shades[axis] * rng.uniform(0.92, 1.08), 0.03, 0.97)),
                               tint, texture=texture))
    return out


def _window(width, height, rng, frame=0.9, glass=0.18, bars=True, tint=GREY):
    """A window template centred on its cell origin, bottom at b = 0: frame, panes."""
    t = 0.07
    items: List[Item] = [RectItem(-width / 2, 0, width / 2, height, frame, tint)]
    if bars:
        cols = [(-width / 2 + t, -t / 2), (t / 2, width / 2 - t)]
        rows = [(t, height * 0.6 - t / 2), (height * 0.6 + t / 2, height - t)]
        for a0, a1 in cols:
            for b0, b1 in rows:
                items.append(RectItem(a0, b0, a1, b1, glass + rng.uniform(-0.05, 0.05)))
    else:
        items.append(RectItem(-width / 2 + t, t, width / 2 - t, height - t, glass))
    return items


def _door(width, height, rng, value=0.22, frame=0.85, tint=GREY):
    f = 0.08
    return [RectItem(-width / 2 - f, 0, width / 2 + f, height + f, frame),
            RectItem(-width / 2, 0, width / 2, height, value + rng.uniform(-0.04, 0.04), tint),
            DiscItem(width / 2 - 0.1, 1.0, 0.035, 0.9)]


# ----------------------------------------------------------------------------- the three scenes

def _room(rng) -> Scene:
    X, Y, Z = (-3.0, 3.0), (0.0, 2.8), (-3.5, 4.5)
    s = []
    floor = Surface(1, 0.0, X[0], X[1], Z[0], Z[1], 0.45, _tint(rng, 0.15), texture=0.06)
    floor.items = [CheckerItem(X[0], Z[0], X[1], Z[1], 0.5, 0.32, 0.62),
                   DiscItem(0.8, 1.6, 0.9, 0.42, tint=_tint(rng, 0.4)),  # round rug
                   DiscItem(0.8, 1.6, 0.75, 0.55, inner=0.62)]
    ceiling = Surface(1, Y[1], X[0], X[1], Z[0], Z[1], 0.82, texture=0.03)
    ceiling.items = [ArrayItem([RectItem(-0.3, -0.6, 0.3, 0.6, 0.98), RectItem(-0.25, -0.55, 0.25, 0.55, 1.0)],
                               -1.5, -1.5, 3.0, 3.0, 2, 2, rng, jitter=0.01),
                     DiscItem(0.0, 3.2, 0.3, 0.97), DiscItem(0.0, 3.2, 0.36, 0.5, inner=0.3)]
    back = Surface(2, Z[1], X[0], X[1], Y[0], Y[1], 0.72, _tint(rng), texture=0.07)
    back.items = [ArrayItem(_door(0.9, 2.05, rng), -1.8, 0.0, 1, 1, 1, 1, rng),
                  ArrayItem(_window(1.4, 1.2, rng), 0.9, 0.9, 1, 1, 1, 1, rng),
                  DiscItem(-0.3, 2.2, 0.2, 0.15), DiscItem(-0.3, 2.2, 0.17, 0.92),  # clock
                  RectItem(X[0], 0.0, X[1], 0.1, 0.35)]  # skirting board
    left = Surface(0, X[0], Z[0], Z[1], Y[0], Y[1], 0.66, _tint(rng), texture=0.07)
    books = [RectItem(-0.035, 0.0, 0.035, 0.3, 0.5)]
    left.items = [RectItem(0.2, 0.0, 1.6, 1.9, 0.28),  # bookcase
                  ArrayItem([RectItem(-0.68, -0.02, 0.68, 0.02, 0.75)], 0.9, 0.45, 1, 0.45, 1, 4, rng),
                  ArrayItem(books, 0.3, 0.47, 0.095, 0.45, 13, 3, rng, jitter=0.25),
                  ArchItem(2.3, 0.0, 3.3, 1.8, 0.12),
                  DiscItem(-1.6, 1.5, 0.35, 0.85), DiscItem(-1.6, 1.5, 0.4, 0.2, inner=0.35),  # mirror
                  RectItem(Z[0], 0.0, Z[1], 0.1, 0.35),
                  BlobItem(-2.6, 0.7, 0.5, 0.7, 0.25, rng, tint=(0.8, 1.2, 0.8))]  # plant
    right = Surface(0, X[1], Z[0], Z[1], Y[0], Y[1], 0.6, _tint(rng), texture=0.07)
    right.items = [ArrayItem(_window(1.1, 1.3, rng), -1.5, 0.9, 2.4, 1, 3, 1, rng, jitter=0.03),
                   RectItem(Z[0], 0.0, Z[1], 0.1, 0.35),
                   BlobItem(-2.7, 0.6, 0.45, 0.6, 0.22, rng, tint=(0.8, 1.2, 0.8))]
    front = Surface(2, Z[0], X[0], X[1], Y[0], Y[1], 0.7, _tint(rng), texture=0.07)
    front.items = [ArrayItem(_door(0.9, 2.05, rng, value=0.3), 1.2, 0.0, 1, 1, 1, 1, rng),
                   RectItem(-2.2, 1.0, -0.6, 2.0, 0.25), RectItem(-2.1, 1.1, -0.7, 1.9, 0.55),  # picture
                   DiscItem(0.1, 1.9, 0.18, 0.95), DiscItem(0.1, 1.9, 0.22, 0.3, inner=0.18),
                   RectItem(X[0], 0.0, X[1], 0.1, 0.35)]
    s += [floor, ceiling, back, left, right, front]
    s += _box(1.6, 2.9, 0.0, 0.75, 2.8, 4.4, 0.4, rng, faces=('x-', 'y+', 'z-'))  # desk / cabinet
    return Scene('room', s, {'position': (0.3, 1.4, -0.6), 'yaw': 0.0, 'pitch': 0.0, 'roll': 0.0},
                 ((-1.5, 1.5), (1.1, 1.8), (-2.0, 1.5)), light=(0.2, 2.6, 0.8))


def _corridor(rng) -> Scene:
    X, Y, Z = (-1.1, 1.1), (0.0, 2.6), (-30.0, 30.0)
    floor = Surface(1, 0.0, X[0], X[1], Z[0], Z[1], 0.45, _tint(rng, 0.15), texture=0.05)
    floor.items = [CheckerItem(X[0], Z[0], X[1], Z[1], 0.55, 0.35, 0.6)]
    ceiling = Surface(1, Y[1], X[0], X[1], Z[0], Z[1], 0.85, texture=0.03)
    ceiling.items = [ArrayItem([RectItem(-0.3, -0.6, 0.3, 0.6, 0.99)], 0.0, Z[0] + 1.5, 1, 3.0, 1, 20, rng),
                     ArrayItem([DiscItem(0.0, 0.0, 0.2, 0.97), DiscItem(0.0, 0.0, 0.25, 0.4, inner=0.2)],
                               0.0, Z[0] + 3.0, 1, 6.0, 1, 10, rng)]
    walls = []
    for x, offset in ((X[0], 0.0), (X[1], 2.0)):
        wall = Surface(0, x, Z[0], Z[1], Y[0], Y[1], 0.7 + rng.uniform(-0.05, 0.05), _tint(rng), texture=0.07)
        door = _door(0.9, 2.05, rng) + [DiscItem(0.0, 1.55, 0.14, 0.85), DiscItem(0.0, 1.55, 0.18, 0.45, inner=0.14)]
        wall.items = [RectItem(Z[0], 0.0, Z[1], 0.12, 0.3),  # skirting
                      RectItem(Z[0], 0.95, Z[1], 1.0, 0.4),  # handrail stripe
                      ArrayItem(door, Z[0] + 2.0 + offset, 0.0, 4.0, 1, 14, 1, rng, jitter=0.05),
                      ArrayItem([RectItem(-0.35, 1.25, 0.35, 1.85, 0.3), RectItem(-0.3, 1.3, 0.3, 1.8, 0.75)],
                                Z[0] + 4.0 + offset, 0.0, 8.0, 1, 7, 1, rng, jitter=0.1),  # posters
                      ArrayItem([ArchItem(-0.4, 1.2, 0.4, 1.9, 0.2)], Z[0] + 8.0 + offset, 0.0, 16.0, 1, 3, 1, rng)]
        walls.append(wall)
    end_far = Surface(2, Z[1], X[0], X[1], Y[0], Y[1], 0.65, texture=0.05)
    end_far.items = [ArrayItem(_window(1.2, 1.2, rng), 0.0, 0.9, 1, 1, 1, 1, rng)]
    end_near = Surface(2, Z[0], X[0], X[1], Y[0], Y[1], 0.6, texture=0.05)
    end_near.items = [ArrayItem(_door(0.9, 2.05, rng), 0.0, 0.0, 1, 1, 1, 1, rng)]
    s = [floor, ceiling] + walls + [end_far, end_near]
    return Scene('corridor', s, {'position': (0.25, 1.5, 0.0), 'yaw': 0.0, 'pitch': 0.0, 'roll': 0.0},
                 ((-0.5, 0.5), (1.2, 1.8), (-10.0, 10.0)), light=(0.0, 2.4, 1.0))


def _street(rng) -> Scene:
    Z = (-80.0, 80.0)
    road = Surface(1, 0.0, -4.0, 4.0, Z[0], Z[1], 0.22, texture=0.12, texture_scale=0.2)
    road.items = [ArrayItem([RectItem(-0.07, -1.5, 0.07, 1.5, 0.85)], 0.0, Z[0] + 2.0, 1, 6.0, 1, 27, rng),
                  RectItem(-3.6, Z[0], -3.45, Z[1], 0.8), RectItem(3.45, Z[0], 3.6, Z[1], 0.8),
                  ArrayItem([RectItem(-0.25, -2.0, 0.25, 2.0, 0.85)], -2.75, 6.0, 0.9, 1, 7, 1, rng)]  # crossing
    s = [road]
    for side in (-1, 1):
        x_kerb, x_wall = 4.0 * side, 7.0 * side
        walk = Surface(1, 0.15, min(x_kerb, x_wall), max(x_kerb, x_wall), Z[0], Z[1], 0.5, texture=0.08)
        walk.items = [ArrayItem([RectItem(-0.73, -0.48, 0.73, 0.48, 0.55)], min(x_kerb, x_wall) + 0.75, Z[0] + 0.5,
                                1.5, 1.0, 2, 160, rng, jitter=0.05)]
        kerb = Surface(0, x_kerb, Z[0], Z[1], 0.0, 0.15, 0.75, texture=0.05)
        s += [walk, kerb]
        z = Z[0]
        k = 0
        while z < Z[1]:
            length = float(rng.uniform(12.0, 22.0))
            height = float(rng.uniform(9.0, 18.0))
            b = Surface(0, x_wall, z, min(z + length, Z[1]), 0.15, height,
                        float(rng.uniform(0.45, 0.8)), _tint(rng, 0.3), texture=0.07)
            n_win = max(1, int((length - 2.0) // 2.6))
            floors = int((height - 3.5) // 3.0)
            items: List[Item] = [RectItem(z, 0.15, z + length, 0.6, b.value * 0.6)]  # plinth
            items.append(ArrayItem([RectItem(-length / 2, -0.1, length / 2, 0.1, b.value * 0.75)],
                                   z + length / 2, 3.3, 1, 3.0, 1, max(floors, 1), rng))  # storey bands
            if floors > 0:
                items.append(ArrayItem(_window(1.2, 1.5, rng, frame=0.88), z + (length - (n_win - 1) * 2.6) / 2,
                                       4.0, 2.6, 3.0, n_win, floors, rng, jitter=0.04))
            items.append(ArrayItem(_door(1.2, 2.3, rng), z + 2.2, 0.15, 1, 1, 1, 1, rng))
            if k % 2 == 0:
                items.append(ArchItem(z + length - 3.0, 0.15, z + length - 1.4, 2.2, 0.15))
            else:
                items.append(DiscItem(z + length - 2.2, 2.2, 0.5, 0.2))
                items.append(DiscItem(z + length - 2.2, 2.2, 0.6, 0.85, inner=0.5))
            b.items = items
            s.append(b)
            z += length
            k += 1
        # trees: a trunk and a crown of foliage on a vertical plane across the walkway
        for zt in np.arange(Z[0] + 7.0, Z[1], 17.0) + rng.uniform(-2, 2):
            xt = 5.3 * side
            tree = Surface(2, float(zt), xt - 2.0, xt + 2.0, 0.15, 7.0, 0.0, texture=0.0, edges=False)
            tree.items = [RectItem(xt - 0.12, 0.15, xt + 0.12, 3.2, 0.25),
                          BlobItem(xt, 4.6, 1.9, 2.3, 0.28, rng, scale=0.35, tint=(0.7, 1.25, 0.8))]
            tree.transparent = True
            s.append(tree)
        # parked cars: boxes with wheels
        for zc in np.arange(Z[0] + 11.0, Z[1], 23.0) + rng.uniform(-3, 3):
            xc = 3.0 * side
            car = _box(xc - 0.85, xc + 0.85, 0.35, 1.45, zc - 2.1, zc + 2.1, float(rng.uniform(0.2, 0.7)), rng,
                       tint=_tint(rng, 0.5))
            for face in car:
                if face.axis == 0:
                    face.items = [DiscItem(zc - 1.35, 0.35, 0.33, 0.08), DiscItem(zc + 1.35, 0.35, 0.33, 0.08),
                                  DiscItem(zc - 1.35, 0.35, 0.18, 0.6), DiscItem(zc + 1.35, 0.35, 0.18, 0.6),
                                  RectItem(zc - 1.2, 0.95, zc + 0.9, 1.35, 0.15)]
                    face.b0 = 0.02
            s += car
        # a round traffic sign on a pole
        zs = float(rng.uniform(5, 15))
        sign = Surface(2, zs, 3.7 * side - 0.5, 3.7 * side + 0.5, 0.0, 3.0, 0.0, texture=0.0, edges=False)
        sign.items = [RectItem(3.7 * side - 0.04, 0.0, 3.7 * side + 0.04, 2.3, 0.45),
                      DiscItem(3.7 * side, 2.4, 0.35, 0.9), DiscItem(3.7 * side, 2.4, 0.35, 0.3, inner=0.28)]
        sign.transparent = True
        s.append(sign)
    return Scene('street', s, {'position': (1.0, 1.5, 0.0), 'yaw': 0.0, 'pitch': 0.0, 'roll': 0.0},
                 ((-2.5, 2.5), (1.2, 2.0), (-20.0, 20.0)), light=None, sky=True)


def curves_only_scene(seed: int = 0, distance: float = 3.0, count: int = 90) -> Scene:
    """A wall (too large for its border to be seen by a lens of less than ~178 degrees) covered
    with curved things only: discs, rings, wheels and foliage blobs, no straight edge; the camera
    at the origin faces it. For tests that curved distractors are not returned as lines."""
    rng = np.random.default_rng(seed)
    wall = Surface(2, distance, -200.0, 200.0, -200.0, 200.0, 0.55, texture=0.08, edges=False)
    items: List[Item] = []
    for _ in range(count):
        # positions spread in angle (so the whole image gets some), sizes grow with distance
        ang = rng.uniform(0, 2 * math.pi)
        off = math.radians(rng.uniform(0, 70))
        rad = distance * math.tan(off)
        ca, cb = rad * math.cos(ang), rad * math.sin(ang)
        size = (0.1 + 0.35 * rng.random()) * math.hypot(distance, rad) / distance
        kind = rng.integers(0, 4)
        if kind == 0:
            items.append(DiscItem(ca, cb, size, float(rng.uniform(0.05, 0.95))))
        elif kind == 1:
            items.append(DiscItem(ca, cb, size, float(rng.uniform(0.05, 0.35)), inner=0.7 * size))
        elif kind == 2:  # a wheel: tyre, rim
            items.append(DiscItem(ca, cb, size, 0.08))
            items.append(DiscItem(ca, cb, 0.55 * size, 0.7))
        else:
            items.append(BlobItem(ca, cb, 1.5 * size, 1.5 * size, float(rng.uniform(0.15, 0.3)), rng,
                                  scale=0.4 * size))
    wall.items = items
    wall.noise = ValueNoise(rng, 128)
    return Scene('curves', [wall], {'position': (0.0, 0.0, 0.0), 'yaw': 0.0, 'pitch': 0.0, 'roll': 0.0},
                 ((0, 0), (0, 0), (0, 0)), light=(0.0, 1.0, 0.5))


_BUILDERS = {'room': _room, 'corridor': _corridor, 'street': _street}


def make_scene(name: str, seed: int = 0) -> Scene:
    if name not in _BUILDERS:
        raise ValueError(f"scene = {name!r} is invalid: allowed: {', '.join(SCENES)}")
    rng = np.random.default_rng(seed)
    scene = _BUILDERS[name](rng)
    for surf in scene.surfaces:
        surf.noise = ValueNoise(rng, 128)
    return scene


# ----------------------------------------------------------------------------- poses

def _rot(axis, deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    if axis == 0:
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == 1:
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def pose_matrix(pose: dict):
    """(R, C): R maps camera-frame vectors to world vectors, C is the camera centre (world)."""
    flip = np.diag([1.0, -1.0, 1.0])  # camera (x right, y down, z fwd) -> world (X right, Y up, Z fwd)
    R = _rot(1, pose.get('yaw', 0.0)) @ flip @ _rot(0, pose.get('pitch', 0.0)) @ _rot(2, pose.get('roll', 0.0))
    return R, np.asarray(pose['position'], dtype=float)


def random_pose(scene: Scene, seed: int) -> dict:
    rng = np.random.default_rng(10_000 + seed)
    (x0, x1), (y0, y1), (z0, z1) = scene.bounds
    return {'position': (float(rng.uniform(x0, x1)), float(rng.uniform(y0, y1)), float(rng.uniform(z0, z1))),
            'yaw': float(rng.uniform(-180, 180) if scene.name == 'room' else rng.uniform(-40, 40)),
            'pitch': float(rng.uniform(-15, 25)), 'roll': float(rng.uniform(-8, 8))}


# ----------------------------------------------------------------------------- rays

def _has_circle(camera):
    r = getattr(camera, 'circle_radius', None)
    return r is not None and math.isfinite(r)


class _RayField:
    """Rays of any pixel position of one camera: ``camera.unproject`` on a grid, interpolated,
    one Newton step through ``camera.project``; exact unprojection where the grid has holes."""

    def __init__(self, camera, step=RAY_GRID):
        self.camera = camera
        self.step = step
        w, h = camera.width, camera.height
        gx = np.arange(-step, w + 2 * step, step, dtype=float)
        gy = np.arange(-step, h + 2 * step, step, dtype=float)
        self.x0, self.y0 = gx[0], gy[0]
        u, v = np.meshgrid(gx, gy)
        e = 0.25
        pix = np.stack([u, v], axis=-1)
        rays = camera.unproject(pix)
        du = (camera.unproject(pix + [e, 0]) - camera.unproject(pix - [e, 0])) / (2 * e)
        dv = (camera.unproject(pix + [0, e]) - camera.unproject(pix - [0, e])) / (2 * e)
        grid = np.concatenate([rays, du, dv], axis=-1).astype(np.float32)  # (gh, gw, 9)
        self.channels = [np.ascontiguousarray(grid[..., k]) for k in range(9)]

    def rays(self, px, py):
        """px, py: float arrays (n,) -> unit rays (n, 3) float64, dray/du and dray/dv (n, 3)."""
        px = np.asarray(px, dtype=float).ravel()
        py = np.asarray(py, dtype=float).ravel()
        n = px.size
        cols = 4096
        rows = max(1, -(-n // cols))
        mx = np.zeros(rows * cols, dtype=np.float32)
        my = np.zeros(rows * cols, dtype=np.float32)
        mx[:n] = (px - self.x0) / self.step
        my[:n] = (py - self.y0) / self.step
        mx, my = mx.reshape(rows, cols), my.reshape(rows, cols)
        vals = [cv2.remap(c, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=float('nan')).ravel()[:n] for c in self.channels]
        r0 = np.stack(vals[0:3], axis=-1).astype(float)
        du = np.stack(vals[3:6], axis=-1).astype(float)
        dv = np.stack(vals[6:9], axis=-1).astype(float)
        with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
            p0 = self.camera.project(r0)
            eu, ev = px - p0[:, 0], py - p0[:, 1]
            r1 = r0 + du * eu[:, None] + dv * ev[:, None]
            r1 /= np.linalg.norm(r1, axis=-1, keepdims=True)
        bad = ~np.isfinite(r1).all(axis=-1)
        if bad.any():
            r1[bad] = self.camera.unproject(np.stack([px[bad], py[bad]], axis=-1))
            du[bad] = 0.0
            dv[bad] = 0.0
        if _has_circle(self.camera):
            outside = np.hypot(px - self.camera.cx, py - self.camera.cy) > self.camera.circle_radius
            r1[outside] = np.nan
        return r1, du, dv


# ----------------------------------------------------------------------------- casting and shading

TILE = 64


def _cull_table(scene: Scene, C):
    """Bounding cones of the surfaces seen from C: (unit directions (S, 3), half-angles (S,),
    always (S,): True where C is inside or near the bounding sphere)."""
    dirs, alpha, always = [], [], []
    for s in scene.surfaces:
        centre = s.world((s.a0 + s.a1) / 2, (s.b0 + s.b1) / 2)
        radius = 0.5 * math.hypot(s.a1 - s.a0, s.b1 - s.b0) * 1.001 + 1e-3
        v = centre - C
        dist = float(np.linalg.norm(v))
        inside = dist <= radius * 1.05
        dirs.append(v / dist if dist > 0 else np.array([0.0, 0.0, 1.0]))
        alpha.append(math.pi if inside else math.asin(radius / dist))
        always.append(inside)
    return np.array(dirs), np.array(alpha), np.array(always)


def _intersect(scene: Scene, C, d, max_t=None, cull=None, tiles=None):
    """Nearest surface of each ray: (index (-1 none), t, a, b). C: (3,), d: (n, 3) world rays;
    ``tiles``: a group id per ray (rays of one group point close together: only the surfaces
    whose bounding cone meets the group's cone are tested)."""
    if isinstance(d, (tuple, list)):
        dcols = [np.asarray(c, dtype=_F) for c in d]
    else:
        d = np.asarray(d, dtype=_F)
        dcols = [np.ascontiguousarray(d[:, k]) for k in range(3)]
    n = dcols[0].shape[0]
    dirs, alpha, always = _cull_table(scene, C) if cull is None else cull
    best_t = np.full(n, np.inf, dtype=_F) if max_t is None else np.asarray(max_t, dtype=_F).copy()
    best = np.full(n, -1, dtype=np.int32)
    best_a = np.zeros(n, dtype=_F)
    best_b = np.zeros(n, dtype=_F)
    if n == 0:
        return best, best_t, best_a, best_b
    if tiles is None:
        groups = [np.arange(n)]
    else:
        order = np.argsort(tiles, kind='stable')
        cuts = np.nonzero(np.diff(tiles[order]))[0] + 1
        groups = np.split(order, cuts)
    Cf = C.astype(_F)
    for g in groups:
        cols = [c[g] for c in dcols] if len(groups) > 1 else dcols
        m = np.array([float(np.sum(c, dtype=float)) for c in cols])
        norm = np.linalg.norm(m)
        if norm > 1e-9 * len(g):
            m /= norm
            mf = m.astype(_F)
            cos_min = float(np.min(cols[0] * mf[0] + cols[1] * mf[1] + cols[2] * mf[2]))
            beta = math.acos(min(1.0, max(-1.0, cos_min)))
            ang = np.arccos(np.clip(dirs @ m, -1.0, 1.0))
            candidates = np.nonzero(always | (ang <= alpha + beta + 1e-3))[0]
        else:
            candidates = range(len(scene.surfaces))
        bt = best_t[g]
        bi = best[g]
        ba = best_a[g]
        bb = best_b[g]
        for k in candidates:
            s = scene.surfaces[k]
            ka, kb = _PLANE_AXES[s.axis]
            with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
                t = (_F(s.position) - Cf[s.axis]) / cols[s.axis]
                a = Cf[ka] + t * cols[ka]
                b = Cf[kb] + t * cols[kb]
                hit = (t > 1e-6) & (t < bt) & (a >= s.a0) & (a <= s.a1) & (b >= s.b0) & (b <= s.b1)
            if getattr(s, 'transparent', False):
                # see-through planes (trees, signs): only where an item covers the point
                h = np.nonzero(hit)[0]
                if h.size:
                    cov = np.zeros(h.size, dtype=bool)
                    for item in s.items:
                        cov |= item.covers(a[h], b[h])
                    hit[h[~cov]] = False
            bi[hit] = k
            bt[hit] = t[hit]
            ba[hit] = a[hit]
            bb[hit] = b[hit]
        best[g], best_t[g], best_a[g], best_b[g] = bi, bt, ba, bb
    return best, best_t, best_a, best_b


def _composite(items, a, b, wa, wb, base_value, base_tint, colour):
    value = np.full(a.shape, base_value, dtype=_F)
    tint = np.tile(np.asarray(base_tint, dtype=_F), (a.shape[0], 1)) if colour else None
    curved = np.zeros(a.shape, dtype=_F)
    for item in items:
        x0, y0, x1, y1 = item.bbox
        m = (a >= x0 - wa) & (a <= x1 + wa) & (b >= y0 - wb) & (b <= y1 + wb)
        idx = np.nonzero(m)[0]
        if idx.size == 0:
            continue
        ai, bi, wai, wbi = a[idx], b[idx], wa[idx], wb[idx]
        layers = item.layers(ai, bi, wai, wbi) if isinstance(item, ArrayItem) else \
            [(*item.shade(ai, bi, wai, wbi), item.tint)]
        curved_layers = set(item.curved_items()) if isinstance(item, ArrayItem) else ({0} if item.curved else set())
        vi = value[idx]
        ci = curved[idx]
        ti = tint[idx] if colour else None
        for li, (cov, val, tnt) in enumerate(layers):
            cov = np.asarray(cov, dtype=_F)
            vi = vi + (np.asarray(val, dtype=_F) - vi) * cov
            if colour:
                ti = ti + (np.asarray(tnt, dtype=_F)[None, :] - ti) * cov[:, None]
            ci = np.maximum(ci, cov) if li in curved_layers else ci * (1 - cov)
        value[idx] = vi
        curved[idx] = ci
        if colour:
            tint[idx] = ti
    return value, tint, curved


def _shade(scene: Scene, R, C, rays_c, du_c, dv_c, colour, cull, tiles=None):
    """Shade samples: camera-frame rays (n, 3) and their differentials per sample step ->
    (grey (n,), bgr (n, 3) or None, curved coverage (n,), surface index (n,): -1 sky, -2 no ray)."""
    n = rays_c.shape[0]
    valid = np.isfinite(rays_c).all(axis=1)

    def world(v, fill):
        c = [np.where(valid, v[:, k], fill).astype(_F) if fill is not None else v[:, k].astype(_F) for k in range(3)]
        return [_F(R[j, 0]) * c[0] + _F(R[j, 1]) * c[1] + _F(R[j, 2]) * c[2] for j in range(3)]
    d = world(rays_c, 0.0)
    ddu = world(np.nan_to_num(du_c), None)
    ddv = world(np.nan_to_num(dv_c), None)
    idx, t, a, b = _intersect(scene, C, d, cull=cull, tiles=tiles)
    idx[~valid] = -2
    grey = np.zeros(n, dtype=_F)
    bgr = np.zeros((n, 3), dtype=_F) if colour else None
    curved = np.zeros(n, dtype=_F)
    key = idx.astype(np.int16) if len(scene.surfaces) < 30000 else idx
    order = np.argsort(key, kind='stable')
    bounds = np.searchsorted(key[order], np.arange(-2, len(scene.surfaces) + 1))
    Cf = C.astype(_F)
    for k, s in enumerate(scene.surfaces):
        sel = order[bounds[k + 2]:bounds[k + 3]]
        if sel.size == 0:
            continue
        ka, kb, kn = _PLANE_AXES[s.axis] + (s.axis,)
        ts = t[sel]
        dk = d[kn][sel]
        # ray differentials: dX/du = t (dd/du - d (dd_k/du) / d_k)
        ra, rb = d[ka][sel] / dk, d[kb][sel] / dk
        un, vn = ddu[kn][sel], ddv[kn][sel]
        wa = ts * (np.abs(ddu[ka][sel] - ra * un) + np.abs(ddv[ka][sel] - ra * vn)) + _F(1e-6)
        wb = ts * (np.abs(ddu[kb][sel] - rb * un) + np.abs(ddv[kb][sel] - rb * vn)) + _F(1e-6)
        aa, bb = a[sel], b[sel]
        if getattr(s, 'transparent', False):
            # a see-through plane is hit only where an item covers it: no blending with the
            # plane itself at item edges (the supersampling anti-aliases them against the scene)
            wa = np.full_like(wa, 1e-6)
            wb = np.full_like(wb, 1e-6)
        value, tint, curv = _composite(s.items, aa, bb, wa, wb, s.value, s.tint, colour)
        if s.texture > 0:
            sc = s.texture_scale
            tex = 0.7 * s.noise(aa / sc, bb / sc) + 0.3 * s.noise(aa / (0.23 * sc) + 31.0, bb / (0.23 * sc) + 7.0)
            value = value * (1 + _F(s.texture * 2) * (tex - _F(0.5)))
        # lighting: ambient + diffuse, the normal facing the camera
        sign = -np.sign(dk)
        if scene.light is not None:
            L = [_F(scene.light[i]) - (Cf[i] + ts * d[i][sel]) for i in range(3)]
            dist = np.sqrt(L[0] * L[0] + L[1] * L[1] + L[2] * L[2])
            lam = np.clip(sign * L[kn] / dist, 0, 1) / (1 + (dist * _F(0.2)) ** 2)
            light = 0.45 + 0.9 * lam
        else:
            sun = np.asarray(scene.sun, dtype=_F) / _F(np.linalg.norm(scene.sun))
            light = 0.55 + 0.5 * np.clip(sign * sun[kn], 0, 1)
        shade = value * light
        grey[sel] = shade
        curved[sel] = curv
        if colour:
            bgr[sel] = shade[:, None] * tint
    if scene.sky:
        sky = order[bounds[1]:bounds[2]]
        if sky.size:
            g = (0.78 + 0.15 * np.clip(d[1][sky], -1, 1)).astype(_F)
            grey[sky] = g
            if colour:
                bgr[sky] = g[:, None] * np.array([1.15, 1.0, 0.8], dtype=_F)[None, :]
    return grey, bgr, curved, idx


# ----------------------------------------------------------------------------- ground truth

def _visible_segments(scene: Scene, camera, rays: '_RayField', R, C, min_px=8.0):
    """Visible runs of every straight edge: list of (start, end, kind) with camera-frame points."""
    cand_p, cand_q, cand_k, cand_j = [], [], [], []
    seen = set()
    for k, s in enumerate(scene.surfaces):
        if s.edges:
            for P, Q in s.border():
                key = tuple(np.round(np.concatenate([P, Q]), 6))
                key2 = tuple(np.round(np.concatenate([Q, P]), 6))
                if key in seen or key2 in seen:
                    continue
                seen.add(key)
                cand_p.append(P), cand_q.append(Q), cand_k.append(k), cand_j.append(-1)
        for j, item in enumerate(s.items):
            for (pa, pb), (qa, qb) in item.edges():
                cand_p.append(s.world(pa, pb)), cand_q.append(s.world(qa, qb)), cand_k.append(k), cand_j.append(j)
    if not cand_p:
        return []
    P, Q = np.array(cand_p), np.array(cand_q)
    K, J = np.array(cand_k), np.array(cand_j)
    Rt = R.T
    # a coarse look: how long is each edge in the image (skip the tiny and the unseen)
    ts = np.linspace(0, 1, 9)
    Xc = ((P[:, None, :] + ts[None, :, None] * (Q - P)[:, None, :]) - C) @ Rt.T
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        px = camera.project(Xc)
        steps = np.linalg.norm(np.diff(px, axis=1), axis=2)
        sane = np.isfinite(steps) & (steps < 4 * (camera.width + camera.height))
        length = np.nansum(np.where(sane, steps, 0), axis=1)
    keep = np.nonzero(np.isfinite(px).any(axis=(1, 2)) & (length >= min_px))[0]
    if keep.size == 0:
        return []
    counts = np.clip(length[keep] / 1.5, 16, 3000).astype(int)
    edge = np.repeat(keep, counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(edge.size) - np.repeat(first, counts)) / np.repeat(counts - 1, counts)
    Xw = P[edge] + t[:, None] * (Q[edge] - P[edge])
    Xc = (Xw - C) @ Rt.T
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        px = camera.project(Xc)
        vis = np.isfinite(px).all(axis=1) & (px[:, 0] >= 0) & (px[:, 0] <= camera.width - 1) & \
            (px[:, 1] >= 0) & (px[:, 1] <= camera.height - 1)
    idx = np.nonzero(vis)[0]
    if idx.size:
        # the lens sees these rays where it is one-to-one (a polynomial may fold back)
        back, _, _ = rays.rays(px[idx, 0], px[idx, 1])
        dirs = Xc[idx] / np.linalg.norm(Xc[idx], axis=1, keepdims=True)
        with np.errstate(invalid='ignore'):
            vis[idx] = np.sum(back * dirs, axis=1) > 1 - 1e-7
    idx = np.nonzero(vis)[0]
    if idx.size:
        # not occluded: nothing nearer along the ray (the edge's own surface is hit at ~dist)
        rel = Xw[idx] - C
        dist = np.linalg.norm(rel, axis=1)
        tiles = (px[idx, 1] // TILE).astype(np.int64) * 100_000 + (px[idx, 0] // TILE).astype(np.int64)
        hit, _, _, _ = _intersect(scene, C, rel / dist[:, None], max_t=dist * (1 - 2e-5) - 1e-5, tiles=tiles)
        vis[idx] = hit < 0
    # painted edges: no later item of the surface covers either side
    painted = np.nonzero(vis & (J[edge] >= 0))[0]
    if painted.size:
        pairs = K[edge[painted]] * 100_000 + J[edge[painted]]
        for key in np.unique(pairs):
            sel = painted[pairs == key]
            k, j = divmod(int(key), 100_000)
            s = scene.surfaces[k]
            later = s.items[j + 1:]
            if not later:
                continue
            ka, kb = _PLANE_AXES[s.axis]
            e = Q[edge[sel]] - P[edge[sel]]
            e /= np.linalg.norm(e, axis=1, keepdims=True)
            ok = np.ones(sel.size, dtype=bool)
            for side in (1, -1):
                a = (Xw[sel, ka] - side * 2e-3 * e[:, kb]).astype(_F)
                b = (Xw[sel, kb] + side * 2e-3 * e[:, ka]).astype(_F)
                for item in later:
                    ok &= ~item.covers(a, b)
            vis[sel] = ok
    # runs of visible samples within each edge
    first_of_edge = np.zeros(edge.size, bool)
    first_of_edge[np.concatenate([[0], np.cumsum(counts)[:-1]])] = True
    last_of_edge = np.roll(first_of_edge, -1)
    start = vis & (first_of_edge | ~np.roll(vis, 1))
    stop = vis & (last_of_edge | ~np.roll(vis, -1))
    s0, s1 = np.nonzero(start)[0], np.nonzero(stop)[0]
    step = np.zeros(edge.size)
    step[1:] = np.hypot(*(px[1:] - px[:-1]).T)
    step[first_of_edge] = 0.0
    cum = np.cumsum(np.nan_to_num(step))
    length = cum[s1] - cum[s0]
    good = (s1 - s0 >= 1) & (length >= min_px)
    out = [(Xc[a], Xc[b], 'surface' if J[edge[a]] < 0 else 'painted') for a, b in zip(s0[good], s1[good])]
    return out


# ----------------------------------------------------------------------------- entry points

@dataclass
class Rendering:
    image: np.ndarray          # uint8 (H, W) grey or (H, W, 3) BGR
    segments: np.ndarray       # (N, 2, 3) camera-frame end points of the visible straight edges
    kinds: List[str]           # 'surface' (edge between surfaces) or 'painted' per segment
    contrast: np.ndarray       # (N,) median grey-level step across each segment, noise-free image
    clean: np.ndarray          # float32 (H, W) grey, 0..255, before blur and sensor noise
    curved_mask: np.ndarray    # bool (H, W): pixels on a curved distractor (disc, arch, blob)
    valid: np.ndarray          # bool (H, W): pixels with a ray
    pose: dict
    R: np.ndarray              # camera -> world rotation
    C: np.ndarray              # camera centre (world)


_RAY_FIELDS: dict = {}


def _ray_field(camera):
    key = (type(camera).__name__, repr(sorted((k, repr(v)) for k, v in vars(camera).items())))
    field_ = _RAY_FIELDS.get(key)
    if field_ is None:
        if len(_RAY_FIELDS) > 8:
            _RAY_FIELDS.clear()
        field_ = _RAY_FIELDS[key] = _RayField(camera)
    return field_


def render_scene(camera, scene='room', pose=None, seed=0, colour=False, supersample=4,
                 noise=1.5, blur=0.5, exposure=255.0, min_segment_px=8.0,
                 nuisances: Optional['Nuisances'] = None) -> Rendering:
    """Render ``scene`` (a name or a ``Scene``) through ``camera`` (module docstring).
    ``nuisances``: what real fisheye photos add (``Nuisances``; default none: the image is
    exactly what it was without the option).

    One ray per pixel centre, painted edges box-filtered over the pixel footprint; then every
    pixel next to an edge between surfaces (or a see-through item, or the end of the lens' rays)
    again with ``supersample`` x ``supersample`` rays, averaged."""
    sc = make_scene(scene, seed) if isinstance(scene, str) else scene
    if pose is None:
        pose_d = dict(sc.default_pose)
    elif isinstance(pose, str):
        if pose != 'random':
            raise ValueError(f"pose = {pose!r} is invalid: a dict or 'random'")
        pose_d = random_pose(sc, seed)
    else:
        pose_d = dict(sc.default_pose)
        pose_d.update(pose)
    R, C = pose_matrix(pose_d)
    w, h = camera.width, camera.height
    rays = _ray_field(camera)
    cull = _cull_table(sc, C)
    n = w * h
    grey = np.zeros(n, dtype=_F)
    bgr = np.zeros((n, 3), dtype=_F) if colour else None
    curved = np.zeros(n, dtype=_F)
    index = np.zeros(n, dtype=np.int32)
    valid = np.zeros(n, dtype=_F)
    chunk = TILE * w * max(1, 400_000 // (TILE * w))
    ys_all, xs_all = np.divmod(np.arange(n), w)
    tile_all = (ys_all // TILE) * 100_000 + xs_all // TILE
    for i0 in range(0, n, chunk):
        i1 = min(n, i0 + chunk)
        r, du, dv = rays.rays(xs_all[i0:i1], ys_all[i0:i1])
        g, col, cv, ix = _shade(sc, R, C, r, du, dv, colour, cull, tile_all[i0:i1])
        grey[i0:i1], curved[i0:i1], index[i0:i1] = g, cv, ix
        valid[i0:i1] = ix > -2
        if colour:
            bgr[i0:i1] = col
    # pixels whose footprint may straddle an edge between surfaces: supersample them
    im = index.reshape(h, w)
    edge = np.zeros((h, w), dtype=bool)
    edge[:, 1:] |= im[:, 1:] != im[:, :-1]
    edge[:, :-1] |= im[:, 1:] != im[:, :-1]
    edge[1:, :] |= im[1:, :] != im[:-1, :]
    edge[:-1, :] |= im[1:, :] != im[:-1, :]
    ss = int(supersample)
    if ss > 1:
        e_idx = np.nonzero(edge.ravel())[0]
        off = (np.arange(ss) + 0.5) / ss - 0.5
        ou, ov = [o.ravel() for o in np.meshgrid(off, off)]
        per = ss * ss
        step = max(1, chunk // per)
        for j0 in range(0, e_idx.size, step):
            sel = e_idx[j0:j0 + step]
            xs = (xs_all[sel][:, None] + ou[None, :]).ravel()
            ys = (ys_all[sel][:, None] + ov[None, :]).ravel()
            r, du, dv = rays.rays(xs, ys)
            g, col, cv, ix = _shade(sc, R, C, r, du / ss, dv / ss, colour, cull, np.repeat(tile_all[sel], per))
            grey[sel] = g.reshape(-1, per).mean(axis=1)
            curved[sel] = cv.reshape(-1, per).mean(axis=1)
            valid[sel] = (ix > -2).reshape(-1, per).mean(axis=1)
            if colour:
                bgr[sel] = col.reshape(-1, per, 3).mean(axis=1)
    grey = grey.reshape(h, w)
    curved = curved.reshape(h, w)
    valid = valid.reshape(h, w)
    clean = np.clip(grey * exposure, 0, 255)
    rng = np.random.default_rng(seed + 7919)
    out = bgr.reshape(h, w, 3) * exposure if colour else grey * exposure
    if blur > 0:
        out = cv2.GaussianBlur(out, (0, 0), blur)
    if noise > 0:
        out = out + rng.normal(0.0, noise, out.shape).astype(_F)
    vmask = valid > 0.5
    if nuisances is None:
        out = np.where(vmask[..., None] if colour else vmask, out, 0.0)
        image = np.clip(np.round(out), 0, 255).astype(np.uint8)
    else:
        image = apply_nuisances(out, camera, nuisances, seed)
    segs = _visible_segments(sc, camera, rays, R, C, min_segment_px)
    segments = np.array([[p, q] for p, q, _ in segs], dtype=float).reshape(-1, 2, 3)
    kinds = [k for _, _, k in segs]
    contrast = segment_contrast(clean, camera, segments)
    return Rendering(image, segments, kinds, contrast, clean.astype(_F), curved > 0.05, vmask,
                     pose_d, R, C)


@dataclass
class Nuisances:
    """What real fisheye photos add to a rendering (``render_scene(..., nuisances=...)``).

    ``circle``: an image circle of ``circle_radius`` px (default the camera's ``circle_radius``)
    about the principal point: inside, a vignetting fall-off to ``vignetting`` of the brightness
    at the rim (``(rho / R)^3``); the boundary blurred by ``edge_px``; outside, not black: a
    ``surround`` grey level, a ``glow`` that fades over ``glow_px`` from the rim, and noise of
    ``surround_noise``. ``vehicle``: a body part in view at the bottom edge (a dark curved shape
    with a bright rim, like a car's bonnet). Then an extra ``blur`` and sensor ``noise`` (sigma),
    and JPEG re-encoding at ``jpeg_quality`` (None: none)."""
    circle: bool = True
    circle_radius: Optional[float] = None
    vignetting: float = 0.45
    edge_px: float = 1.2
    surround: float = 14.0
    surround_noise: float = 3.0
    glow: float = 16.0
    glow_px: float = 10.0
    vehicle: bool = False
    blur: float = 0.0
    noise: float = 0.0
    jpeg_quality: Optional[int] = None


ALL_NUISANCES = Nuisances(circle=True, vehicle=True, blur=0.6, noise=2.0, jpeg_quality=80)


def apply_nuisances(out, camera, nuisances: Nuisances, seed=0) -> np.ndarray:
    """The float rendering ``out`` (grey (H, W) or BGR (H, W, 3), 0..255) with ``nuisances``
    (``Nuisances``), as uint8."""
    rng = np.random.default_rng(seed + 104729)
    img = np.asarray(out, dtype=_F).copy()
    h, w = img.shape[:2]
    colour = img.ndim == 3
    yy, xx = np.mgrid[0:h, 0:w].astype(_F)
    if nuisances.vehicle:
        ex, ey, a, b = 0.5 * w, 1.22 * h, 0.42 * w, 0.36 * h
        f = ((xx - ex) / a) ** 2 + ((yy - ey) / b) ** 2
        grad = np.sqrt((2 * (xx - ex) / a ** 2) ** 2 + (2 * (yy - ey) / b ** 2) ** 2) + 1e-6
        sd = (f - 1.0) / grad                       # signed distance (px), negative inside
        cover = np.clip(0.5 - sd, 0.0, 1.0)
        body = 30.0 + 150.0 * np.exp(-np.square((sd + 3.0) / 2.5)) + 10.0 * (yy / h)
        if colour:
            cover, body = cover[..., None], body[..., None]
        img = img * (1 - cover) + body * cover
    if nuisances.circle:
        R = nuisances.circle_radius if nuisances.circle_radius is not None else getattr(camera, 'circle_radius', None)
        if R is None:
            raise ValueError('the circle nuisance needs circle_radius (or a camera with one)')
        rho = np.hypot(xx - camera.cx, yy - camera.cy)
        cover = np.clip(0.5 - (rho - R), 0.0, 1.0).astype(_F)
        vig = 1.0 - (1.0 - nuisances.vignetting) * np.clip(rho / R, 0, 1) ** 3
        outside = (nuisances.surround + nuisances.glow * np.exp(-np.maximum(rho - R, 0) / nuisances.glow_px)
                   + rng.normal(0.0, nuisances.surround_noise, (h, w))).astype(_F)
        band = np.clip(1.0 - np.abs(rho - R) / (3.0 * nuisances.edge_px + 1.0), 0.0, 1.0)
        if colour:
            cover, vig, outside, band = cover[..., None], vig[..., None], outside[..., None], band[..., None]
        # the camera's own circle already darkens the scene outside R (anti-aliased): no second edge
        own = getattr(camera, 'circle_radius', None) is not None and abs(camera.circle_radius - R) < 0.5
        img = img * vig * (1.0 if own else cover) + outside * (1 - cover)
        if nuisances.edge_px > 0:  # the lens's soft boundary: blurred across it
            img = img * (1 - band) + cv2.GaussianBlur(img, (0, 0), nuisances.edge_px) * band
    if nuisances.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), nuisances.blur)
    if nuisances.noise > 0:
        img = img + rng.normal(0.0, nuisances.noise, img.shape).astype(_F)
    image = np.clip(np.round(img), 0, 255).astype(np.uint8)
    if nuisances.jpeg_quality is not None:
        ok, buf = cv2.imencode('.jpg', image, [int(cv2.IMWRITE_JPEG_QUALITY), int(nuisances.jpeg_quality)])
        image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED if colour else cv2.IMREAD_GRAYSCALE)
    return image


def render(camera, scene='room', pose=None, seed=0, **kwargs):
    """(image uint8 (H, W) grey, or (H, W, 3) BGR with colour=True; segments (N, 2, 3)): the visible
    straight 3-D segments, end points in the camera frame."""
    r = render_scene(camera, scene, pose, seed, **kwargs)
    return r.image, r.segments


def segment_pixels(camera, segment, step_px=1.0):
    """Pixels of a 3-D segment (2, 3) through ``camera``, about ``step_px`` apart (a curve)."""
    px, _ = sample_segments(camera, np.asarray(segment, dtype=float)[None], step_px)
    return px


def sample_segments(camera, segments, step_px=1.0, max_points=20000):
    """Pixels of many 3-D segments (N, 2, 3), about ``step_px`` apart along each image curve:
    (pixels (M, 2), segment index (M,))."""
    segments = np.asarray(segments, dtype=float).reshape(-1, 2, 3)
    if len(segments) == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=int)
    P, Q = segments[:, 0], segments[:, 1]
    ts = np.linspace(0, 1, 17)
    with np.errstate(invalid='ignore'):
        coarse = camera.project(P[:, None, :] + ts[None, :, None] * (Q - P)[:, None, :])
        length = np.nansum(np.linalg.norm(np.diff(coarse, axis=1), axis=2), axis=1)
    counts = np.clip(length / step_px, 1, max_points).astype(int) + 1
    seg = np.repeat(np.arange(len(segments)), counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(seg.size) - np.repeat(first, counts)) / np.repeat(counts - 1, counts)
    return camera.project(P[seg] + t[:, None] * (Q[seg] - P[seg])), seg


def _sample(img, x, y):
    """Bilinear samples of ``img`` at float positions (any count); NaN outside."""
    n = x.size
    cols = 4096
    rows = max(1, -(-n // cols))
    mx = np.full(rows * cols, -10.0, dtype=np.float32)
    my = np.full(rows * cols, -10.0, dtype=np.float32)
    mx[:n], my[:n] = x, y
    out = cv2.remap(img, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=float('nan'))
    return out.ravel()[:n]


def segment_contrast(image, camera, segments, offset_px=1.5):
    """Median |difference| of ``image`` sampled ``offset_px`` on either side of each segment."""
    segments = np.asarray(segments, dtype=float).reshape(-1, 2, 3)
    out = np.zeros(len(segments))
    if len(segments) == 0:
        return out
    px, seg = sample_segments(camera, segments, 2.0)
    tangent = np.gradient(px, axis=0)
    # ends of each run: one-sided differences within the segment
    first = np.r_[True, seg[1:] != seg[:-1]]
    last = np.r_[seg[1:] != seg[:-1], True]
    nxt = np.minimum(np.arange(len(px)) + 1, len(px) - 1)
    prv = np.maximum(np.arange(len(px)) - 1, 0)
    tangent[first] = (px[nxt] - px)[first]
    tangent[last] = (px - px[prv])[last]
    nrm = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    img = np.asarray(image, dtype=np.float32)
    vals = []
    for sgn in (1, -1):
        q = (px + sgn * offset_px * nrm).astype(np.float32)
        q = np.nan_to_num(q, nan=-10.0)
        vals.append(_sample(img, q[:, 0], q[:, 1]))
    diff = np.abs(vals[0] - vals[1])
    ok = np.isfinite(diff)
    for i in range(len(segments)):
        d = diff[(seg == i) & ok]
        out[i] = float(np.median(d)) if d.size else 0.0
    return out


def dense_rms(camera, truth, grid=(33, 19)) -> float:
    """RMS pixel distance, over a grid of the image, between the truth's pixels and where
    ``camera`` puts the truth's rays (no rotation: the principal point's error counts too)."""
    u, v = np.meshgrid(np.linspace(0, truth.width - 1, grid[0]), np.linspace(0, truth.height - 1, grid[1]))
    pixels = np.stack([u.ravel(), v.ravel()], 1)
    rays = truth.unproject(pixels)
    ok = np.isfinite(rays).all(1)
    return float(np.sqrt(np.mean(np.sum((camera.project(rays[ok]) - pixels[ok]) ** 2, 1))))


def soft_rim(fade_px, width=640, height=480, cx=322.0, cy=238.0, radius=220.0, seed=0):
    """A disc of texture whose light fades linearly to a dark, noisy surround over the last
    ``fade_px`` px inside ``radius`` (0: a sharp rim), as the rims of some real circular fisheyes
    do (OCamCalib's: over 10-20 px)."""
    rng = np.random.default_rng(seed)
    scene = cv2.GaussianBlur(rng.uniform(60, 230, (height // 8, width // 8)).astype(np.float32), (0, 0), 1.0)
    scene = cv2.resize(scene, (width, height), interpolation=cv2.INTER_LINEAR)
    yy, xx = np.mgrid[:height, :width]
    rho = np.hypot(xx - cx, yy - cy)
    fade = np.clip((radius - rho) / fade_px, 0, 1) if fade_px > 0 else (rho <= radius).astype(np.float32)
    image = 10 + (scene - 10) * fade + rng.normal(0, 2, (height, width))
    return np.clip(cv2.GaussianBlur(image.astype(np.float32), (0, 0), 0.8), 0, 255).astype(np.uint8)
