"""Image samples along profiles, and where along them an edge peaks, to a fraction of a sample:
what the line detector (edge points across an LSD segment) and the image-region finder (the
image circle's boundary along rays from its centre) both measure."""
from __future__ import annotations

from typing import Tuple

import cv2
import numpy as np


def sample(img: np.ndarray, x: np.ndarray, y: np.ndarray, interpolation=cv2.INTER_LINEAR) -> np.ndarray:
    """Samples (bilinear, or ``interpolation``) of a float32 image at positions of any shape; NaN
    outside (and at NaN positions)."""
    shape = x.shape
    n = x.size
    cols = 2048  # cv2.remap takes maps of at most 32767 columns: the positions as rows of this many
    rows = max(1, -(-n // cols))
    mx = np.full(rows * cols, -10.0, dtype=np.float32)
    my = np.full(rows * cols, -10.0, dtype=np.float32)
    mx[:n] = np.nan_to_num(x.ravel(), nan=-10.0)
    my[:n] = np.nan_to_num(y.ravel(), nan=-10.0)
    out = cv2.remap(img, mx.reshape(rows, cols), my.reshape(rows, cols), interpolation,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=float('nan'))
    return out.ravel()[:n].reshape(shape)


def peak_offsets(g: np.ndarray, positions: np.ndarray, step: float) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(offset, peak, ok) of the largest value of each row of ``g`` (profiles sampled at
    ``positions``, ``step`` apart; -inf where unusable): its position refined by the parabola
    through it and its two neighbours (at most half a step), the value there, and whether it is
    a true peak (not at a profile's end, finite and positive)."""
    k = np.argmax(g, axis=1)
    n = g.shape[1]
    ok = (k > 0) & (k < n - 1)
    kk = np.clip(k, 1, n - 2)
    rows = np.arange(len(k))
    g0, g1, g2 = g[rows, kk - 1], g[rows, kk], g[rows, kk + 1]
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        denom = g0 - 2 * g1 + g2
        delta = np.where(denom < 0, 0.5 * (g0 - g2) / denom, 0.0)
    delta = np.clip(np.nan_to_num(delta), -0.5, 0.5)
    ok &= np.isfinite(g1) & (g1 > 0)
    return positions[kk] + delta * step, g1, ok
