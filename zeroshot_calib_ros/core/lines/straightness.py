"""The straightness residual: how far the points of a curve are from imaging one straight 3-D line.

A straight 3-D line and the centre of projection span a plane, so the rays of its image lie on
one great circle of the ray sphere, for every central camera, below or beyond 180 degrees. Under
a candidate camera the residual of a curve (N raw-image pixels believed to image one line) is:

1. unproject the points to unit rays r_i (``camera.unproject``);
2. fit the plane through the origin: its normal n is the smallest singular vector of the rays
   (weighted, see below);
3. the closest ray on the plane to each r_i is q_i = r_i - (r_i . n) n; project q_i back to pixels;
4. residual = observed pixel - projected q_i, slid along the curve's image to the closest pixel
   (first order: the component along the image's tangent at q_i, from the projection of q_i
   turned ``TANGENT_STEP`` along the great circle, is removed): two numbers per point, in pixels,
   across the curve.

Why the slide: the image of the angular foot q_i is not the pixel nearest the observed point
where the lens maps angles anisotropically (radial and tangential scales differ towards the edge
of a fisheye, and of a pinhole), so the plain difference has a component along the curve that
grows with the noise and with that anisotropy. Minimising it favours cameras that are less
anisotropic: on a 116-degree lens with 0.3 px noise it pulled every fit about 1 degree of FOV
narrower (10-14 px of error at 1920 px), the same sign for every noise draw and none without
noise. Across the curve only, the bias is gone (random +-0.2 degree).

Why pixels and not the angle of r_i to the plane: the detector's noise is in pixels, and the
angle-to-plane error times f weights the periphery of a fisheye wrongly (the local scale in px per
radian varies by 2x or more across a wide image). Issue 13 measured the cost: an angle residual
times f is biased along the one direction lines cannot see (a zoom of the undistorted image) and
gave 9.5 px on a lens where the pixel residual gives 0.5. The plane is a nuisance parameter
eliminated in closed form at every evaluation (variable projection): the Jacobian of these
residuals with respect to the camera, by finite differences, is the Jacobian of the reduced
problem, so the covariance after a fit accounts for the planes.

Plane weights. The plain SVD plane minimises the sum of squared angles; the maximum-likelihood
plane minimises the squared pixel distances. With ``reweight`` (default) the plane is refitted
once with each ray weighted by its local scale (pixel residual / angle to the plane of the first
fit), which brings it to the pixel-space optimum to first order.

Vectorised over all curves at once: one ``unproject`` and four ``project`` calls over all points, the
3 x 3 scatter matrices of the curves summed with ``np.add.reduceat`` and their eigenvectors found
by one batched ``eigh``. Points without a ray under the camera (outside its image circle, or
where its polynomial turns back) give NaN residuals; ``residuals`` replaces them by
``invalid_px`` so that a solver sees a large but finite cost there.

The term follows the estimation package's term interface (``residuals(camera)`` unwhitened,
``sigma``, ``loss``, ``group``) without importing it: core/lines sits below core/estimation.
"""
from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import Optional, Sequence

import numpy as np

from ..lens.models import CameraModel

INVALID_PX = 50.0
TANGENT_STEP = 1e-6
"""Radians along the great circle for the finite-difference tangent of a curve's image."""
"""Residual (px per coordinate) given to a point the camera cannot unproject or project."""


def curve_points(curve) -> np.ndarray:
    """The (N, 2) float64 pixels of a curve: a ``Curve`` (anything with ``points``) or an array."""
    points = getattr(curve, 'points', curve)
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f'a curve must be an (N, 2) array of pixels, got shape {points.shape}')
    return points


def curve_image(curve, default=0):
    """The image a curve comes from (``Curve.image``), or ``default`` for a bare array."""
    return getattr(curve, 'image', default)


def fit_planes(rays: np.ndarray, starts: np.ndarray, weights: Optional[np.ndarray] = None) -> np.ndarray:
    """Unit normals (C, 3) of the planes through the origin fitted to consecutive groups of rays.

    ``rays`` (N, 3), ``starts`` (C,) the index of each group's first ray (groups are contiguous
    and in order), ``weights`` (N,) optional per-ray weights (squared inside the scatter)."""
    w = rays if weights is None else rays * weights[:, None]
    # the six distinct products of each ray's outer product (the other three are their mirror
    # images: the same numbers), summed per group in the same order as the whole outer product
    x, y, z = w[:, 0], w[:, 1], w[:, 2]
    products = np.empty((len(w), 6))
    np.multiply(x, x, out=products[:, 0])
    np.multiply(x, y, out=products[:, 1])
    np.multiply(x, z, out=products[:, 2])
    np.multiply(y, y, out=products[:, 3])
    np.multiply(y, z, out=products[:, 4])
    np.multiply(z, z, out=products[:, 5])
    sums = np.add.reduceat(products, starts, axis=0)
    return smallest_eigenvectors(np.ascontiguousarray(sums[:, _SYMMETRIC]).reshape(-1, 3, 3))


_SYMMETRIC = np.array([0, 1, 2, 1, 3, 4, 2, 4, 5])
"""The 3 x 3 symmetric matrix (row by row) from its six distinct entries xx, xy, xz, yy, yz, zz."""


def smallest_eigenvectors(S: np.ndarray, iterations: int = 3) -> np.ndarray:
    """Unit eigenvectors (C, 3) of the smallest eigenvalue of symmetric positive semi-definite
    3 x 3 matrices S (C, 3, 3), from their adjugates: adj(S) = l2 l3 v1 v1^T + l1 l3 v2 v2^T +
    l1 l2 v3 v3^T (eigenvalues l1 >= l2 >= l3), so its largest column is v3 up to terms l3 / l2,
    and each multiplication by adj(S) shrinks them by l3 / l2 again. The scatter of rays that lie
    near a plane has l3 / l2 ~ (noise / span)^2 (1e-6 for a typical curve, 1e-3 for a short noisy
    one), so three multiplications leave v3 exact to double precision (the last one checks it: one
    that still moves v goes to ``eigh``) where a batched ``eigh``
    costs ten times as much (the straightness term evaluates this hundreds of times per fit).
    Matrices whose adjugate vanishes (rank < 2: fewer than two distinct rays) go to ``eigh``."""
    a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 0, 2]
    d, e, f = S[:, 1, 1], S[:, 1, 2], S[:, 2, 2]
    adj = np.empty_like(S)
    adj[:, 0, 0] = d * f - e * e
    adj[:, 1, 1] = a * f - c * c
    adj[:, 2, 2] = a * d - b * b
    adj[:, 0, 1] = adj[:, 1, 0] = c * e - b * f
    adj[:, 0, 2] = adj[:, 2, 0] = b * e - c * d
    adj[:, 1, 2] = adj[:, 2, 1] = b * c - a * e
    norms = np.einsum('cij,cij->cj', adj, adj)
    v = adj[np.arange(len(S)), :, np.argmax(norms, axis=1)]
    previous = v
    for _ in range(iterations):
        previous = v
        v = np.einsum('cij,cj->ci', adj, v)
        length = np.sqrt(np.einsum('ci,ci->c', v, v))
        v = v / np.where(length > 0, length, 1.0)[:, None]
    scale = np.einsum('cii->c', S)
    # not converged (l3 close to l2: a curve shorter than its noise) or degenerate: eigh
    moved = 1.0 - np.abs(np.einsum('ci,ci->c', v, previous))
    bad = ~(np.sqrt(norms.max(axis=1)) > 1e-12 * scale * scale) | ~np.all(np.isfinite(v), axis=1) | ~(moved < 1e-14)
    if np.any(bad):
        v[bad] = np.linalg.eigh(S[bad])[1][:, :, 0]
    return v


def _camera_key(camera) -> Optional[tuple]:
    """What a camera's projections depend on, for the cameras that have it all in their numbers
    (a Kannala-Brandt camera of any class: the class is part of the key, its inverse may differ);
    None for others (never remembered)."""
    D = getattr(camera, 'D', None)
    if D is None or not hasattr(camera, 'fx'):
        return None
    return (type(camera), camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height,
            np.asarray(D, dtype=float).tobytes())


class _ResidualMemo:
    """Point residuals already computed, per camera (``_camera_key``), for the curves of a term
    and of the terms made from it by ``subset``: a solve that starts where the last one ended
    (the next robust round, the next model order, the held-out fit) finds its first residuals and
    Jacobian columns here instead of computing them again; the numbers are those it would
    compute. The last ``SIZE`` cameras are kept."""

    SIZE = 48

    def __init__(self, sizes):
        self.curves = len(sizes)
        self.points = int(np.sum(sizes))
        self.entries: 'OrderedDict[tuple, tuple]' = OrderedDict()
        self.lock = threading.Lock()

    def get(self, key, curves, points):
        with self.lock:
            entry = self.entries.get(key)
            if entry is None:
                return None
            self.entries.move_to_end(key)
        have, values = entry
        if points is None:  # every curve of the memo's, in its order
            return values.copy() if have.all() else None
        if not have[curves].all():
            return None
        return values[points]

    def put(self, key, curves, points, residual):
        with self.lock:
            entry = self.entries.get(key)
            if entry is None:
                entry = (np.zeros(self.curves, dtype=bool), np.empty((self.points, 2)))
                self.entries[key] = entry
                while len(self.entries) > self.SIZE:
                    self.entries.popitem(last=False)
            else:
                self.entries.move_to_end(key)
            have, values = entry
            if points is None:
                values[...] = residual
                have[...] = True
            else:
                values[points] = residual
                have[curves] = True


class StraightnessTerm:
    """Pixel-space residuals of curves that must image straight 3-D lines (module docstring).

    ``curves``: Curve objects (with ``points`` (N, 2) and ``image``) or (N, 2) arrays, at least 3
    points each. ``sigma``: the detector's noise per coordinate in pixels. ``loss`` /
    ``loss_scale``: the robust loss a solver applies per point (both coordinates together: a
    point is the unit of an outlier), in units of sigma."""

    name = 'straightness'
    group = 2
    """Residuals come in groups of 2 (one point's x and y): the robust loss acts per group."""

    def __init__(self, curves: Sequence, sigma: float = 0.5, loss: Optional[str] = 'soft_l1',
                 loss_scale: float = 3.0, reweight: bool = True, invalid_px: float = INVALID_PX,
                 perpendicular: bool = True):
        self.curves = list(curves)
        points = [curve_points(c) for c in self.curves]
        for i, p in enumerate(points):
            if len(p) < 3:
                raise ValueError(f'curve {i} has {len(p)} points: a straightness residual needs at least 3')
        if not points:
            raise ValueError('no curves: a straightness term needs at least one')
        self.sizes = np.array([len(p) for p in points])
        self.starts = np.r_[0, np.cumsum(self.sizes)[:-1]]
        self.points = np.concatenate(points)
        self.curve_of_point = np.repeat(np.arange(len(points)), self.sizes)
        self.images = [curve_image(c, i) for i, c in enumerate(self.curves)]
        self.sigma = float(sigma)
        self.loss = loss
        self.loss_scale = float(loss_scale)
        self.reweight = reweight
        self.perpendicular = perpendicular
        self.invalid_px = float(invalid_px)
        # this term's curves among those of the term it was made from by ``subset`` (itself when
        # made directly), and the residuals already computed for those curves (``_ResidualMemo``)
        self._memo = _ResidualMemo(self.sizes)
        self._curve_index = np.arange(len(self.curves))
        self._point_index = np.arange(len(self.points))

    def __len__(self):
        return len(self.curves)

    def __getstate__(self):
        state = dict(self.__dict__)
        state['_memo'] = None
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        if getattr(self, '_memo', None) is None:
            self._memo = _ResidualMemo(self.sizes)
            self._curve_index = np.arange(len(self.curves))
            self._point_index = np.arange(len(self.points))

    def subset(self, keep) -> 'StraightnessTerm':
        """The same term over the curves selected by ``keep`` (boolean mask or indices)."""
        keep = np.asarray(keep)
        index = np.nonzero(keep)[0] if keep.dtype == bool else keep
        term = StraightnessTerm([self.curves[i] for i in index], self.sigma, self.loss, self.loss_scale,
                                self.reweight, self.invalid_px, self.perpendicular)
        # the curves' residuals depend on the camera and on each curve's own points only (every
        # plane fit, weight and projection is per curve or per point), so the terms made from
        # one another share what they computed
        index = np.asarray(index, dtype=int).reshape(-1)
        term._memo = self._memo
        term._curve_index = self._curve_index[index]
        if len(index):
            term._point_index = np.concatenate([self._point_index[a:a + n] for a, n in
                                                zip(self.starts[index], self.sizes[index])])
        return term

    def with_sigma(self, sigma: float) -> 'StraightnessTerm':
        term = self.subset(np.arange(len(self.curves)))
        term.sigma = float(sigma)
        return term

    def squared_distances(self, camera: CameraModel) -> np.ndarray:
        """Squared distance (px^2) of every point with a ray under ``camera`` from its line's image."""
        r = self.point_residuals(camera)
        d2 = np.sum(r * r, axis=1)
        return d2[np.isfinite(d2)]

    def noise_dof(self, points: int) -> int:
        """Degrees of freedom of ``points`` such distances beside the camera: one a point, less two a
        curve (its plane)."""
        return points - 2 * len(self)

    def point_residuals(self, camera: CameraModel) -> np.ndarray:
        """(N, 2) observed minus re-projected pixels, NaN where the camera has no ray."""
        key = _camera_key(camera)
        # None: this term's points are all of the memo's, in its order (a copy's, with_sigma's)
        points = None if self._whole() else self._point_index
        if key is not None:
            known = self._memo.get(key, self._curve_index, points)
            if known is not None:
                return known
        residual = self._point_residuals(camera)
        if key is not None:
            self._memo.put(key, self._curve_index, points, residual)
        return residual

    def _whole(self) -> bool:
        index = self._point_index
        return len(index) == self._memo.points and bool(np.all(index[1:] > index[:-1]))

    def _point_residuals(self, camera: CameraModel) -> np.ndarray:
        rays = camera.unproject(self.points)
        ok = np.all(np.isfinite(rays), axis=1)
        safe = np.where(ok[:, None], rays, 0.0)
        normals = fit_planes(safe, self.starts)
        per_point = normals[self.curve_of_point]
        residual = self._residual(camera, safe, per_point)
        if self.reweight:
            angle = np.abs(np.einsum('ij,ij->i', safe, per_point))
            with np.errstate(invalid='ignore', divide='ignore'):
                scale = np.sqrt(np.einsum('ij,ij->i', residual, residual)) / angle
            good = np.isfinite(scale) & (angle > 1e-12) & ok
            # the curve's mean scale where the ratio is ill-defined (points on the plane)
            count = np.add.reduceat(good.astype(float), self.starts)
            total = np.add.reduceat(np.where(good, scale, 0.0), self.starts)
            mean = np.where(count > 0, total / np.maximum(count, 1.0), 1.0)
            scale = np.where(good, scale, mean[self.curve_of_point])
            normals = fit_planes(safe, self.starts, np.where(ok, scale, 0.0))
            residual = self._residual(camera, safe, normals[self.curve_of_point])
        residual[~ok] = np.nan
        return residual

    def _residual(self, camera, rays, n):
        """Residuals (N, 2) of ``rays`` from the planes of their curves' normals ``n`` (N, 3)."""
        on_plane = rays - np.einsum('ij,ij->i', rays, n)[:, None] * n
        with np.errstate(invalid='ignore', divide='ignore'):
            on_plane /= np.sqrt(np.einsum('ij,ij->i', on_plane, on_plane))[:, None]
        if not self.perpendicular:
            return self.points - camera.project(on_plane)
        # slide along the curve's image to the closest pixel (first order): keep the component
        # of the residual across the curve's tangent g = d project / d angle along the circle
        # both points to project in one array: the feet, then the feet turned TANGENT_STEP along
        # the great circle (n x foot, written out: np.cross costs several times as much)
        count = len(on_plane)
        both_rays = np.empty((2 * count, 3))
        both_rays[:count] = on_plane
        along = both_rays[count:]
        np.subtract(n[:, 1] * on_plane[:, 2], n[:, 2] * on_plane[:, 1], out=along[:, 0])
        np.subtract(n[:, 2] * on_plane[:, 0], n[:, 0] * on_plane[:, 2], out=along[:, 1])
        np.subtract(n[:, 0] * on_plane[:, 1], n[:, 1] * on_plane[:, 0], out=along[:, 2])
        along *= TANGENT_STEP
        along += on_plane
        both = camera.project(both_rays)
        foot = both[:len(on_plane)]
        residual = self.points - foot
        g = (both[len(on_plane):] - foot) / TANGENT_STEP
        with np.errstate(invalid='ignore', divide='ignore'):
            g /= np.sqrt(np.einsum('ij,ij->i', g, g))[:, None]
        return residual - np.einsum('ij,ij->i', residual, g)[:, None] * g

    def systematic_modes(self) -> np.ndarray:
        """(2N, 2): per residual, the two lowest shapes of a systematic error of its curve that
        its plane cannot absorb: a bow and an S (Legendre P2 and P3 of the position t in [-1, 1]
        along the curve, each scaled to unit RMS over the curve), along the curve's normal.
        A detector errs in these shapes along a whole curve (blur and anti-aliasing of a bent
        edge, a gently curved edge taken for a line); they carry the curvature that tells the
        distortion and the principal point, so a floor on them is a floor on what lines can say."""
        p = self.points
        out = np.zeros((len(p), 2, 2))
        for c, (start, size) in enumerate(zip(self.starts, self.sizes)):
            q = p[start:start + size]
            step = np.hypot(*np.diff(q, axis=0).T)
            arc = np.r_[0.0, np.cumsum(step)]
            t = 2.0 * arc / max(arc[-1], 1e-9) - 1.0
            tangent = np.gradient(q, axis=0)
            tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
            normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
            for k, mode in enumerate((1.5 * t * t - 0.5, 2.5 * t ** 3 - 1.5 * t)):
                mode = mode - mode.mean()
                rms = math.sqrt(float(np.mean(mode * mode)))
                out[start:start + size, :, k] = normal * (mode / rms if rms > 0 else 0.0)[:, None]
        return out.reshape(2 * len(p), 2)

    systematic_modes_text = 'every curve allowed a systematic bow and S'
    """What ``uncertainty.systematic_covariance`` says it allowed for this term's clusters."""

    def residual_clusters(self) -> np.ndarray:
        """The curve of each residual (2N,): errors shared along a curve are one cluster for a
        cluster-robust covariance."""
        return np.repeat(self.curve_of_point, 2)

    def residuals(self, camera: CameraModel) -> np.ndarray:
        """Unwhitened residuals (2N,) in pixels; points without a ray get ``invalid_px``."""
        r = self.point_residuals(camera)
        return np.where(np.isfinite(r), r, self.invalid_px).ravel()

    def curve_rms(self, camera: CameraModel) -> np.ndarray:
        """RMS point distance (px) of each curve from the image of its fitted line (inf: a point
        without a ray)."""
        r = self.point_residuals(camera)
        d2 = np.sum(r * r, axis=1)
        sums = np.add.reduceat(np.where(np.isfinite(d2), d2, np.inf), self.starts)
        return np.sqrt(sums / self.sizes)

    def rms(self, camera: CameraModel) -> float:
        """RMS point distance over all curves (px); inf when a point has no ray."""
        r = self.point_residuals(camera)
        d2 = np.sum(r * r, axis=1)
        return float(np.sqrt(np.mean(d2))) if np.all(np.isfinite(d2)) else float('inf')

