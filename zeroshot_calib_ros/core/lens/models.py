"""Camera models with one interface: ``project`` rays to pixels, ``unproject`` pixels to rays.

Rays are 3-vectors in the camera frame (x right, y down, z forward), pixels are (u, v) in
OpenCV's convention. Every model takes arrays of shape (..., 3) / (..., 2) and returns arrays of
the matching shape; points a model cannot represent come back as NaN, never as a wrong number.

- ``ZeroShotCamera``: the paper's exact model (pinhole K + fisheye distortion map G_w).
- ``KannalaBrandtCamera``: OpenCV fisheye / ROS ``equidistant`` (k1..k4);
  ``RadialKannalaBrandtCamera``: one with fx = fy as a RadialCamera, for the ROS fits.
- ``PlumbBobCamera``: OpenCV's radial-tangential / ROS ``plumb_bob`` (k1, k2, p1, p2, k3).
- ``PinholeCamera``: no distortion.
"""
from __future__ import annotations

import math

import numpy as np

from .projections import FisheyeProjection, Equidistant


def _as_rays(rays):
    rays = np.asarray(rays, dtype=float)
    if rays.shape[-1] != 3:
        raise ValueError(f'rays must have shape (..., 3), got {rays.shape}')
    return rays


def _as_pixels(pixels):
    pixels = np.asarray(pixels, dtype=float)
    if pixels.shape[-1] != 2:
        raise ValueError(f'pixels must have shape (..., 2), got {pixels.shape}')
    return pixels


def angle_between(a, b) -> np.ndarray:
    """Angle in radians between rays (robust near 0 and pi, unlike arccos of a dot product)."""
    a = _as_rays(a)
    b = _as_rays(b)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    # the cross product as np.cross computes it, without its overhead (a FOV term's hot path)
    cross = np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)
    return np.arctan2(np.linalg.norm(cross, axis=-1), np.sum(a * b, axis=-1))


FOV_NAMES = ('hfov', 'vfov', 'dfov')


def fov_edge_pixels(width: float, height: float, cx: float, cy: float) -> np.ndarray:
    """(3, 2, 2): the two edge pixels each spec FOV is measured between, in ``FOV_NAMES``' order,
    through the principal point (cx, cy): hfov (0, cy)-(W, cy), vfov (cx, 0)-(cx, H), dfov
    (0, 0)-(W, H)."""
    return np.array([[[0, cy], [width, cy]], [[cx, 0], [cx, height]], [[0, 0], [width, height]]], dtype=float)


class CameraModel:
    """Shared behaviour: intrinsics, image size and the derived conveniences."""

    def __init__(self, fx, fy, cx, cy, width, height):
        self.fx, self.fy, self.cx, self.cy = float(fx), float(fy), float(cx), float(cy)
        self.width, self.height = int(width), int(height)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, rays) -> np.ndarray:
        raise NotImplementedError

    def unproject(self, pixels) -> np.ndarray:
        """Unit rays of the pixels."""
        raise NotImplementedError

    def distort(self, xy) -> np.ndarray:
        """Normalised pinhole coordinates (x/z, y/z) -> distorted pixels."""
        xy = np.asarray(xy, dtype=float)
        return self.project(np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1))

    def undistort(self, pixels) -> np.ndarray:
        """Distorted pixels -> normalised pinhole coordinates (x/z, y/z); NaN beyond 90 deg."""
        rays = self.unproject(pixels)
        with np.errstate(divide='ignore', invalid='ignore'):
            xy = rays[..., :2] / rays[..., 2:3]
        return np.where(rays[..., 2:3] > 0, xy, np.nan)

    def fields_of_view(self) -> dict:
        """Edge-to-edge FOVs in degrees through the principal point: hfov from (0, cy) to (W, cy),
        vfov from (cx, 0) to (cx, H), dfov from (0, 0) to (W, H).

        Each is the sum of the two half-angles, the off-axis angles of the edge rays on either
        side of the principal point (their difference when the principal point lies beyond an
        edge), so a lens seeing more than 180 degrees reports it (206, not the folded 154 of the
        angle between the two rays, which never exceeds 180). Up to 180 degrees the angle between
        the rays is returned: the same for a radially symmetric lens, and the spec-sheet meaning
        when the rays are not coplanar with the axis (tangential distortion, dfov with the
        principal point off the diagonal). NaN where an edge pixel has no ray."""
        w, h, cx, cy = self.width, self.height, self.cx, self.cy
        px = fov_edge_pixels(w, h, cx, cy).reshape(-1, 2)
        r = self.unproject(px)
        plain = angle_between(r[0::2], r[1::2])
        off_axis = np.arctan2(np.linalg.norm(r[:, :2], axis=-1), r[:, 2])
        # where the principal point projects onto each edge-to-edge segment: 0..1 between the ends
        start, end = px[0::2], px[1::2]
        seg = end - start
        t = np.sum((np.array([cx, cy]) - start) * seg, axis=-1) / np.maximum(np.sum(seg * seg, axis=-1), 1e-300)
        halves = np.where(t < 0, off_axis[1::2] - off_axis[0::2],
                          np.where(t > 1, off_axis[0::2] - off_axis[1::2], off_axis[0::2] + off_axis[1::2]))
        with np.errstate(invalid='ignore'):
            ang = np.degrees(np.where(halves > np.pi, halves, plain))
        return {'hfov': float(ang[0]), 'vfov': float(ang[1]), 'dfov': float(ang[2])}

    def max_field_angle(self) -> float:
        """Largest off-axis angle (radians) of any pixel: the farthest image corner's ray."""
        w, h = self.width, self.height
        corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], dtype=float)
        rays = self.unproject(corners)
        return float(np.max(np.arctan2(np.linalg.norm(rays[:, :2], axis=-1), rays[:, 2])))

    def corner_radius(self) -> float:
        """Distance in pixels from the principal point to the farthest image corner."""
        return max(math.hypot(x - self.cx, y - self.cy)
                   for x in (0, self.width) for y in (0, self.height))

    def scaled(self, width: int, height: int) -> 'CameraModel':
        """The same lens at another resolution with the same aspect (binned or resized image)."""
        raise NotImplementedError


class RadialCamera(CameraModel):
    """A model with fx = fy = f whose distortion depends only on the off-axis angle theta:
    pixel radius = f * theta_d(theta). Subclasses give ``theta_d`` and its inverse."""

    def __init__(self, f, cx, cy, width, height):
        super().__init__(f, f, cx, cy, width, height)

    @property
    def f(self) -> float:
        return self.fx

    def theta_d(self, theta):
        raise NotImplementedError

    def theta_from_theta_d(self, theta_d):
        """Inverse of theta_d; NaN where no ray maps to that radius."""
        raise NotImplementedError

    def project(self, rays):
        rays = _as_rays(rays)
        r_xy = np.hypot(rays[..., 0], rays[..., 1])
        theta = np.arctan2(r_xy, rays[..., 2])
        with np.errstate(invalid='ignore', divide='ignore'):
            scale = np.where(r_xy > 0, self.f * self.theta_d(theta) / np.where(r_xy > 0, r_xy, 1.0),
                             # on the axis the limit of theta_d(theta)/theta * f / z
                             self.f / np.where(rays[..., 2] > 0, rays[..., 2], np.nan))
        return np.stack([self.cx + scale * rays[..., 0], self.cy + scale * rays[..., 1]], axis=-1)

    def unproject(self, pixels):
        pixels = _as_pixels(pixels)
        dx = pixels[..., 0] - self.cx
        dy = pixels[..., 1] - self.cy
        r_d = np.hypot(dx, dy)
        theta = self.theta_from_theta_d(r_d / self.f)
        s = np.sin(theta)
        with np.errstate(invalid='ignore', divide='ignore'):
            ux = np.where(r_d > 0, dx / np.where(r_d > 0, r_d, 1.0), 0.0)
            uy = np.where(r_d > 0, dy / np.where(r_d > 0, r_d, 1.0), 0.0)
        return np.stack([ux * s, uy * s, np.cos(theta)], axis=-1)


class ZeroShotCamera(RadialCamera):
    """The paper's model: pinhole focal f, principal point (cx, cy), distortion map G_w.

    A ray theta off-axis lands at the pinhole radius r_u = f tan(theta) and is distorted to
    r_d = G_w(r_u) = rho(arctan(w f tan(theta))) / w. Written with atan2 this stays finite up
    to theta = 90 deg, which a pinhole cannot reach but the lens can.
    """

    def __init__(self, f, cx, cy, width, height, omega=0.0,
                 projection: FisheyeProjection = Equidistant()):
        super().__init__(f, cx, cy, width, height)
        self.omega = float(omega)
        self.projection = projection

    @property
    def a(self) -> float:
        """w * f: 0 is a pinhole, 1 the pure fisheye law with the pinhole's focal length."""
        return self.omega * self.f

    def theta_d(self, theta):
        theta = np.asarray(theta, dtype=float)
        with np.errstate(invalid='ignore'):
            valid = theta <= np.pi / 2
        if self.omega == 0.0:
            with np.errstate(invalid='ignore'):
                return np.where(valid, np.tan(np.minimum(theta, np.pi / 2 - 1e-300)), np.nan)
        a = self.a
        psi = np.arctan2(a * np.sin(theta), np.cos(theta))
        return np.where(valid, self.projection.rho(psi) / a, np.nan)

    def theta_from_theta_d(self, theta_d):
        theta_d = np.asarray(theta_d, dtype=float)
        if self.omega == 0.0:
            return np.arctan(theta_d)
        a = self.a
        rho = a * theta_d
        with np.errstate(invalid='ignore'):
            psi = self.projection.theta(np.minimum(rho, self.projection.rho_max))
            theta = np.arctan2(np.sin(psi), a * np.cos(psi))
            return np.where(rho <= self.projection.rho_max, theta, np.nan)

    def scaled(self, width, height):
        s = width / self.width
        return ZeroShotCamera(self.f * s, self.cx * s, self.cy * height / self.height, width, height,
                              self.omega / s, self.projection)

    def __repr__(self):
        return (f'ZeroShotCamera(f={self.f:.6g}, cx={self.cx:g}, cy={self.cy:g}, '
                f'omega={self.omega:.6g}, projection={self.projection.name}, '
                f'size={self.width}x{self.height})')


class KannalaBrandtCamera(CameraModel):
    """OpenCV fisheye (ROS ``equidistant``): theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)."""

    distortion_model = 'equidistant'

    def __init__(self, fx, fy, cx, cy, width, height, D):
        super().__init__(fx, fy, cx, cy, width, height)
        D = np.asarray(D, dtype=float).ravel()
        if D.size != 4:
            raise ValueError(f'equidistant distortion needs 4 coefficients, got {D.size}')
        self.D = D

    def theta_d(self, theta):
        t2 = np.asarray(theta, dtype=float) ** 2
        k1, k2, k3, k4 = self.D
        return theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def _dtheta_d(self, theta):
        t2 = theta * theta
        k1, k2, k3, k4 = self.D
        return 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))

    @property
    def theta_max(self) -> float:
        """Largest angle up to which theta_d(theta) rises (the polynomial may turn back after
        it; no ray beyond is recoverable), at most pi."""
        k1, k2, k3, k4 = self.D
        # d theta_d / d theta = 1 + 3 k1 u + 5 k2 u^2 + 7 k3 u^3 + 9 k4 u^4 with u = theta^2
        roots = np.roots([9 * k4, 7 * k3, 5 * k2, 3 * k1, 1.0])
        u = [r.real for r in roots if abs(r.imag) <= 1e-12 * max(1.0, abs(r)) and r.real > 0]
        return float(min(np.sqrt(min(u)), np.pi)) if u else float(np.pi)

    def theta_from_theta_d(self, theta_d, iterations: int = 60):
        """Inverse of theta_d on [0, theta_max]: Newton steps kept inside a shrinking bracket
        (bisection where Newton would leave it), so it converges for every lens; NaN beyond
        theta_d(theta_max), where no unique ray exists."""
        theta_d = np.asarray(theta_d, dtype=float)
        hi_theta = self.theta_max
        lo = np.zeros_like(theta_d)
        hi = np.full_like(theta_d, hi_theta)
        theta = np.clip(theta_d, 0.0, hi_theta)
        # each element's iteration depends on its own (theta, lo, hi) only, and one that an
        # iteration leaves unchanged is at a fixed point: it leaves the active set, so the loop
        # costs what the slow elements need (Newton converges in under ten iterations; the cap is
        # for bisection towards theta_max, where theta_d lies beyond the lens's reach)
        flat_target, flat_theta = theta_d.reshape(-1), theta.reshape(-1)
        flat_lo, flat_hi = lo.reshape(-1), hi.reshape(-1)
        active = np.arange(flat_theta.size)
        for _ in range(iterations):
            if not active.size:
                break
            t, lo_a, hi_a = flat_theta[active], flat_lo[active], flat_hi[active]
            with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
                err = self.theta_d(t) - flat_target[active]
                new_lo = np.where(err < 0, t, lo_a)
                new_hi = np.where(err > 0, t, hi_a)
                step = t - err / self._dtheta_d(t)
                new = np.where((step > new_lo) & (step < new_hi), step, 0.5 * (new_lo + new_hi))
            moving = ~(((new == t) | (np.isnan(new) & np.isnan(t))) & (new_lo == lo_a) & (new_hi == hi_a))
            flat_theta[active], flat_lo[active], flat_hi[active] = new, new_lo, new_hi
            active = active[moving]
        theta = flat_theta.reshape(theta_d.shape)
        with np.errstate(invalid='ignore', over='ignore'):
            ok = (theta_d >= 0) & (np.abs(self.theta_d(theta) - theta_d) <= 1e-12 * np.maximum(1.0, theta_d))
        return np.where(ok, theta, np.nan)

    def project(self, rays):
        rays = _as_rays(rays)
        x, y = rays[..., 0], rays[..., 1]
        r_xy = np.hypot(x, y)
        theta = np.arctan2(r_xy, rays[..., 2])
        off_axis = r_xy > 0
        with np.errstate(invalid='ignore', divide='ignore'):
            if off_axis.all():  # the usual case: no ray on the axis, nothing to guard
                scale = self.theta_d(theta) / r_xy
            else:
                scale = np.where(off_axis, self.theta_d(theta) / np.where(off_axis, r_xy, 1.0),
                                 1.0 / np.where(rays[..., 2] > 0, rays[..., 2], np.nan))
        # cx + (fx scale) x, computed into the output's columns (the same numbers as np.stack's)
        out = np.empty(r_xy.shape + (2,))
        u, v = out[..., 0], out[..., 1]
        np.multiply(self.fx * scale, x, out=u)
        u += self.cx
        np.multiply(self.fy * scale, y, out=v)
        v += self.cy
        return out

    def unproject(self, pixels):
        pixels = _as_pixels(pixels)
        mx = (pixels[..., 0] - self.cx) / self.fx
        my = (pixels[..., 1] - self.cy) / self.fy
        theta_d = np.hypot(mx, my)
        theta = self.theta_from_theta_d(theta_d)
        s = np.sin(theta)
        off_centre = theta_d > 0
        out = np.empty(theta_d.shape + (3,))
        with np.errstate(invalid='ignore', divide='ignore'):
            if off_centre.all():  # the usual case: no pixel on the principal point
                ux, uy = mx / theta_d, my / theta_d
            else:
                ux = np.where(off_centre, mx / np.where(off_centre, theta_d, 1.0), 0.0)
                uy = np.where(off_centre, my / np.where(off_centre, theta_d, 1.0), 0.0)
        np.multiply(ux, s, out=out[..., 0])
        np.multiply(uy, s, out=out[..., 1])
        np.cos(theta, out=out[..., 2])
        return out

    def scaled(self, width, height):
        sx, sy = width / self.width, height / self.height
        return KannalaBrandtCamera(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy,
                                   width, height, self.D)


class RadialKannalaBrandtCamera(RadialCamera):
    """A Kannala-Brandt camera with fx = fy seen as a RadialCamera: the same theta_d, with one focal
    length f = fx and unprojection by pixel radius. The ROS fits of core/lens/fitting.py take it as
    they take the zero-shot camera (fitting the KannalaBrandtCamera itself, whose unprojection goes
    through the normalised radius, agrees only to the last bits)."""

    def __init__(self, camera: KannalaBrandtCamera):
        super().__init__(camera.fx, camera.cx, camera.cy, camera.width, camera.height)
        self.kannala_brandt = camera

    def theta_d(self, theta):
        return self.kannala_brandt.theta_d(theta)

    def theta_from_theta_d(self, theta_d):
        return self.kannala_brandt.theta_from_theta_d(theta_d)


class PlumbBobCamera(CameraModel):
    """OpenCV's radial-tangential model (ROS ``plumb_bob``), D = (k1, k2, p1, p2, k3)."""

    distortion_model = 'plumb_bob'

    def __init__(self, fx, fy, cx, cy, width, height, D):
        super().__init__(fx, fy, cx, cy, width, height)
        D = np.zeros(5) if D is None or len(D) == 0 else np.asarray(D, dtype=float).ravel()
        if D.size not in (4, 5, 8):
            raise ValueError(f'plumb_bob distortion needs 5 coefficients, got {D.size}')
        self.D = np.pad(D, (0, 8 - D.size)) if D.size < 8 else D

    def _distort_normalised(self, x, y):
        k1, k2, p1, p2, k3, k4, k5, k6 = self.D
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def project(self, rays):
        rays = _as_rays(rays)
        with np.errstate(invalid='ignore', divide='ignore'):
            z = np.where(rays[..., 2] > 0, rays[..., 2], np.nan)
            xd, yd = self._distort_normalised(rays[..., 0] / z, rays[..., 1] / z)
        return np.stack([self.cx + self.fx * xd, self.cy + self.fy * yd], axis=-1)

    def unproject(self, pixels, iterations: int = 50):
        """Fixed-point inversion as cv2.undistortPoints, iterated to convergence."""
        pixels = _as_pixels(pixels)
        xd = (pixels[..., 0] - self.cx) / self.fx
        yd = (pixels[..., 1] - self.cy) / self.fy
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            with np.errstate(invalid='ignore', over='ignore'):
                xe, ye = self._distort_normalised(x, y)
                x, y = x - (xe - xd), y - (ye - yd)
        with np.errstate(invalid='ignore', over='ignore'):
            xe, ye = self._distort_normalised(x, y)
            ok = np.hypot(xe - xd, ye - yd) < 1e-9
        n = np.sqrt(x * x + y * y + 1)
        rays = np.stack([x / n, y / n, 1 / n], axis=-1)
        return np.where(ok[..., None], rays, np.nan)

    def scaled(self, width, height):
        sx, sy = width / self.width, height / self.height
        return PlumbBobCamera(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy,
                              width, height, self.D[:5])


class PinholeCamera(PlumbBobCamera):
    """No distortion."""

    def __init__(self, fx, fy, cx, cy, width, height):
        super().__init__(fx, fy, cx, cy, width, height, np.zeros(5))

    def unproject(self, pixels):
        pixels = _as_pixels(pixels)
        x = (pixels[..., 0] - self.cx) / self.fx
        y = (pixels[..., 1] - self.cy) / self.fy
        n = np.sqrt(x * x + y * y + 1)
        return np.stack([x / n, y / n, 1 / n], axis=-1)


def camera_from_calibration(distortion_model: str, K, D, width: int, height: int) -> CameraModel:
    """The model a ROS CameraInfo / calibration file describes."""
    K = np.asarray(K, dtype=float).reshape(3, 3)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if distortion_model in ('equidistant', 'fisheye'):
        return KannalaBrandtCamera(fx, fy, cx, cy, width, height, D)
    if distortion_model in ('plumb_bob', 'rational_polynomial'):
        return PlumbBobCamera(fx, fy, cx, cy, width, height, D)
    raise ValueError(f"distortion_model = {distortion_model!r} is invalid: allowed: "
                     "equidistant, plumb_bob, rational_polynomial")
