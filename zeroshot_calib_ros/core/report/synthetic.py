"""A synthetic scene of straight lines for a camera that has no image of its own (``solve``):
the inside of a cube around the camera, each face tinted and ruled with a square grid, seen
through the camera model. Rectified with the right model, every grid line is straight."""
from __future__ import annotations

import numpy as np

# face tints (BGR), by the axis the ray meets first and its sign: +x right, -x left, +y floor
# (the camera frame's y points down), -y ceiling, +z ahead, -z behind
FACE_TINTS = {
    (0, 1): (235, 205, 170), (0, -1): (170, 205, 235), (1, 1): (205, 225, 200),
    (1, -1): (240, 235, 225), (2, 1): (245, 245, 245), (2, -1): (160, 160, 200),
}
LINES_PER_FACE = 8
LINE_COLOUR = (40, 40, 40)


def cube_grid(camera, supersample: int = 2) -> np.ndarray:
    """A BGR image of ``camera``'s size of the ruled cube (pixels without a ray black)."""
    w, h = camera.width, camera.height
    s = max(1, int(supersample))
    u, v = np.meshgrid((np.arange(w * s) + 0.5) / s - 0.5, (np.arange(h * s) + 0.5) / s - 0.5)
    rays = camera.unproject(np.stack([u.ravel(), v.ravel()], axis=-1))
    out = np.zeros((h * s * w * s, 3), np.float32)
    ok = np.all(np.isfinite(rays), axis=1)
    d = rays[ok]
    axis = np.argmax(np.abs(d), axis=1)
    major = np.take_along_axis(d, axis[:, None], axis=1)[:, 0]
    sign = np.where(major >= 0, 1, -1)
    colours = np.empty((len(d), 3), np.float32)
    for (a, g), c in FACE_TINTS.items():
        colours[(axis == a) & (sign == g)] = c
    # coordinates on the face, -1..1, and the distance to the nearest grid line in grid units
    others = np.stack([d[np.arange(len(d)), (axis + 1) % 3], d[np.arange(len(d)), (axis + 2) % 3]], axis=1)
    coords = others / np.abs(major)[:, None] * (LINES_PER_FACE / 2.0)
    near = np.min(np.abs(coords - np.round(coords)), axis=1)
    # a line about 1.5 px wide: its half-width in grid units from how fast the coordinates change
    # across a pixel (estimated from the ray's angle per pixel of the image centre)
    centre = camera.unproject(np.array([[camera.cx, camera.cy], [camera.cx + 1.0, camera.cy]], float))
    per_px = float(np.arccos(np.clip(np.dot(centre[0], centre[1]), -1.0, 1.0)))
    per_px = per_px if np.isfinite(per_px) and per_px > 0 else 1.0 / max(w, h)
    slope = (1.0 + np.sum(others ** 2, axis=1) / major ** 2)  # d(tan)/d(angle) grows off the face centre
    half = 0.75 * per_px * slope * (LINES_PER_FACE / 2.0)
    line = np.clip(1.0 - (near - half) / np.maximum(half, 1e-9), 0.0, 1.0)
    colours = colours * (1.0 - line[:, None]) + np.array(LINE_COLOUR, np.float32) * line[:, None]
    out[ok] = colours
    image = out.reshape(h * s, w * s, 3)
    if s > 1:
        image = image.reshape(h, s, w, s, 3).mean(axis=(1, 3))
    return np.clip(image, 0, 255).astype(np.uint8)
