"""Camera effects: the lens (radial-tangential distortion), the clock (RGB late against depth and
pose, a rolling shutter) and the odometry (poses that drift away from the world).

The three image effects are displacement fields: the measured image is the predicted one sampled
elsewhere, ``meas(u) = pred(u + d(u; theta))``, with ``d`` in pixels. Their fit is Gauss-Newton on
``theta`` over every valid pixel of every frame (Lucas-Kanade with a handful of global unknowns):
``meas - warp(pred) ~ grad(warp(pred)) . (dd/dtheta) dtheta``, coarse to fine (the images are
blurred first, so a several-pixel displacement is still in the linear range). ``apply`` resamples
the prediction (bilinear); a pixel whose sample falls off the render takes the border's value and
is left out of the fit. Where the data holds a denser render of the prediction (``rgb_pred_hi``),
fit and apply resample that one and reduce it to pixels as the capture samples them: bilinear
resampling of a 1x render is wrong at every edge by about as much as the lens moves it (on the
bench's point-sampled lens scenes the true coefficients explained 0.40 of the residual from the 1x
render, 0.70 from a 3x one).

The timing effects move each pixel by its image velocity (pixels per second) times a time: the
velocity of the predicted surface point seen at that pixel, projected into the recorded poses of
the neighbouring frames (central difference). A time offset moves every pixel by the same time, a
rolling shutter each row by its own.

Pose drift is a slow rigid motion of the recorded world against the true one, linear in time; its
signature is in depth: the measured point cloud, placed with the recorded pose, is off the
predicted surface by that motion. It is fitted by a point-to-plane alignment of all frames at once
(projective association, as KinectFusion) and applied by resampling the measured depth.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.optimize import minimize_scalar

from artitwin_core.diagnostics._patch import drift_columns
from artitwin_core.diagnostics._plugin import Effect, Evidence, register_effect
from artitwin_core.diagnostics._residuals import NOT_READ_BY_IMAGE_EFFECTS, ResidualData, target_energy
from artitwin_core.geometry import axis_angle_to_matrix, backproject, pixel_grid, relative_motion


def _binned_mean(x: np.ndarray, y: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    edges = np.quantile(x, np.linspace(0, 1, n + 1))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, n - 1)
    counts = np.bincount(idx, minlength=n)
    sums = np.bincount(idx, weights=y, minlength=n)
    return 0.5 * (edges[1:] + edges[:-1]), np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def _scaled_least_squares(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``argmin |a x - b|`` for a tall ``a [n, k]`` (k a few parameters, n up to millions of
    pixels), through the normal equations of ``a`` with its columns scaled to unit norm (the
    parameters' units differ by orders of magnitude): ``k x k`` work after one pass over ``a``,
    where an SVD of ``a`` itself costs a copy and several passes. A column of zeros gets 0."""
    scale = np.maximum(np.linalg.norm(a, axis=0), 1e-12)
    an = a / scale
    gram, rhs = an.T @ an, an.T @ b
    return np.linalg.lstsq(gram, rhs, rcond=None)[0] / scale


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``img [T, H, W, C]`` at pixel coordinates ``x, y [T, H, W]``.

    Returns ``[T, H, W, C]`` values and ``[T, H, W]`` inside (all neighbours with weight in the image).
    """
    t_count, h, w = img.shape[:3]
    ok = np.isfinite(x) & np.isfinite(y) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    xc, yc = np.clip(np.nan_to_num(x), 0, w - 1), np.clip(np.nan_to_num(y), 0, h - 1)
    x0, y0 = np.minimum(np.floor(xc).astype(np.int64), w - 2), np.minimum(np.floor(yc).astype(np.int64), h - 2)
    fx, fy = (xc - x0)[..., None], (yc - y0)[..., None]
    flat = img.reshape(t_count, h * w, -1)
    base = (np.arange(t_count)[:, None, None] * (h * w) + y0 * w + x0).ravel()
    src = flat.reshape(t_count * h * w, -1)

    def at(off):
        return src[base + off].reshape(t_count, h, w, -1)

    out = (at(0) * (1 - fx) * (1 - fy) + at(1) * fx * (1 - fy) + at(w) * (1 - fx) * fy + at(w + 1) * fx * fy)
    return out, ok


def _upsample(field: np.ndarray, s: int) -> np.ndarray:
    """``[T, H, W, C]`` -> ``[T, sH, sW, C]``, linear, read at the centres of the s x s sub-pixels
    (sub-pixel i of an axis lies at pixel ``(i + 0.5) / s - 0.5``; clamped at the border)."""
    out = field
    for axis in (1, 2):
        n = field.shape[axis]
        c = np.clip((np.arange(s * n) + 0.5) / s - 0.5, 0, n - 1)
        i0 = np.minimum(np.floor(c).astype(np.int64), max(n - 2, 0))
        i1 = np.minimum(i0 + 1, n - 1)
        f = (c - i0).reshape([-1 if a == axis else 1 for a in range(4)])
        out = np.take(out, i0, axis=axis) * (1 - f) + np.take(out, i1, axis=axis) * f
    return out


def _reduce_hi(data: ResidualData, img: np.ndarray) -> np.ndarray:
    """``[T, sH, sW, 3]`` sub-pixels -> ``[T, H, W, 3]`` pixels, as the capture records a pixel
    (``rgb_pred_sampling``: the mean of its sub-pixels, or the centre one)."""
    s = data.rgb_pred_scale
    if data.rgb_pred_sampling == "point":
        return img[:, s // 2::s, s // 2::s]
    t_count, hh, ww, c = img.shape
    return img.reshape(t_count, hh // s, s, ww // s, s, c).mean((2, 4))


def _warp_hi(data: ResidualData, d: np.ndarray) -> np.ndarray:
    """The prediction displaced by ``d [T, H, W, 2]`` (pixels), resampled from the dense render
    ``rgb_pred_hi``: each sub-pixel takes the displacement at its place (``d`` interpolated), the
    dense render is sampled there (bilinear, on its s times finer grid) and reduced to pixels.
    What other effects already did to ``rgb_pred`` (an exposure gain, vignetting) is its difference
    from the reduced dense render; it is added back, so no displacement gives ``rgb_pred`` exactly."""
    s, hi = data.rgb_pred_scale, data.rgb_pred_hi
    d_hi = s * _upsample(np.nan_to_num(d), s)
    t_count, hh, ww = hi.shape[:3]
    u, v = np.meshgrid(np.arange(ww, dtype=np.float64), np.arange(hh, dtype=np.float64))
    img, _ = _bilinear(hi, u[None] + d_hi[..., 0], v[None] + d_hi[..., 1])
    return _reduce_hi(data, img) + (data.rgb_pred - _reduce_hi(data, hi))


def _take_frames(data: ResidualData, idx: np.ndarray) -> ResidualData:
    """The image frames ``idx`` of ``data`` (RGB, depth, intrinsics, poses, times; tracks untouched)."""
    names = ("rgb_pred", "rgb_meas", "rgb_valid", "rgb_intrinsics", "depth_pred", "depth_meas", "depth_valid",
             "depth_intrinsics", "world_from_camera", "timestamps", "rgb_pred_hi")
    return replace(data, **{n: getattr(data, n)[idx] for n in names if getattr(data, n) is not None})


class _Displacement(Effect):
    """An image effect that displaces the prediction: ``meas(u) = pred(u + d(u; theta))``.

    Subclasses name the parameters (``param_names``, with a step ``steps`` for the numerical
    Jacobian in the parameters' units) and give the displacement field ``displacement``.
    """

    target = "photometric"
    # The displaced prediction and the timing effects' image velocity read RGB, the predicted
    # depth, the poses and times; never the assumed sigma(z) or the tracks.
    unaffected_by = NOT_READ_BY_IMAGE_EFFECTS
    param_names: tuple[str, ...] = ()
    steps: tuple[float, ...] = ()
    # Coarse to fine: Gaussian blur (pixels) of both images at each Gauss-Newton step.
    blurs: tuple[float, ...] = (2.0, 1.5, 1.0, 0.7, 0.7)
    max_step_px = 2.0

    def displacement(self, data: ResidualData, theta: np.ndarray) -> np.ndarray:
        """``[T, H, W, 2]`` displacement (dx, dy) in pixels for parameters ``theta``; NaN where unknown."""
        raise NotImplementedError

    def _warp(self, data: ResidualData, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_count, h, w = data.rgb_valid.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        x, y = u[None] + d[..., 0], v[None] + d[..., 1]
        img, inside = _bilinear(data.rgb_pred, x, y)
        vmask, _ = _bilinear(data.rgb_valid[..., None].astype(np.float32), x, y)
        usable = data.rgb_valid & inside & (vmask[..., 0] > 0.999)
        if data.rgb_pred_hi is not None:
            img = _warp_hi(data, d)
        return img.astype(np.float32), usable

    def _theta(self, params: dict) -> np.ndarray:
        return np.array([params[n] for n in self.param_names], np.float64)

    # The parameters are global: a few frames spread in time fix them (the fit costs per frame).
    max_fit_frames = 8

    def _fit_view(self, data: ResidualData) -> ResidualData:
        """``data`` cut to at most ``max_fit_frames`` frames with valid pixels, spread in time."""
        usable = np.flatnonzero(data.rgb_valid.any((1, 2)))
        if usable.size <= self.max_fit_frames:
            return data
        idx = usable[np.unique(np.round(np.linspace(0, usable.size - 1, self.max_fit_frames)).astype(int))]
        return _take_frames(data, idx)

    def _solve(self, data: ResidualData) -> np.ndarray:
        return self._solve_view(self._fit_view(data))

    def _solve_view(self, data: ResidualData) -> np.ndarray:
        """The linearised fit on ``data``, already cut to the fit frames (``_fit_view``)."""
        theta = np.zeros(len(self.param_names))
        steps = np.asarray(self.steps, np.float64)
        for sigma in self.blurs:
            d0 = self.displacement(data, theta)
            pred, valid = self._warp(data, d0)
            blur = (0, sigma, sigma, 0)
            pb = gaussian_filter(np.where(valid[..., None], pred, 0), blur)
            mb = gaussian_filter(np.where(valid[..., None], data.rgb_meas, 0), blur)
            wb = gaussian_filter(valid.astype(np.float32), blur[:3])
            ok = valid & (wb > 0.98)  # the blur did not mix in pixels from outside the valid set
            pb, mb = pb / np.maximum(wb, 1e-6)[..., None], mb / np.maximum(wb, 1e-6)[..., None]
            gy, gx = np.gradient(pb, axis=(1, 2))
            cols = []
            for k in range(theta.size):
                dk = (self.displacement(data, theta + steps[k] * np.eye(theta.size)[k]) - d0) / steps[k]
                cols.append((gx * dk[..., :1] + gy * dk[..., 1:])[ok].ravel())
            a = np.nan_to_num(np.stack(cols, 1))
            r = (mb - pb)[ok].ravel()
            step = _scaled_least_squares(a, r)
            theta = theta + self._limit(data, theta, step, d0)
        return theta

    def _limit(self, data: ResidualData, theta: np.ndarray, step: np.ndarray, d0: np.ndarray) -> np.ndarray:
        """``step`` shortened so that no pixel moves by more than ``max_step_px`` (a residual the
        effect does not explain can ask for absurd parameters; the linearisation holds for a few px)."""
        for _ in range(8):
            with np.errstate(all="ignore"):
                change = np.nanmax(np.abs(self.displacement(data, theta + step) - d0))
            if np.isfinite(change) and change <= self.max_step_px:
                return step
            step = step * (0.5 if not np.isfinite(change) else 0.9 * self.max_step_px / change)
        return np.zeros_like(step)

    def apply(self, data: ResidualData, params: dict) -> ResidualData:
        # The validity masks stay as they are (the held-out check relies on it): a pixel whose
        # sample falls off the render takes the nearest border value, the best the render can say.
        pred, _ = self._warp(data, self.displacement(data, self._theta(params)))
        return replace(data, rgb_pred=pred)


def _undistort(xd: np.ndarray, yd: np.ndarray, k1, k2, p1, p2, iterations: int = 20):
    """Normalised undistorted coordinates of distorted ones (OpenCV's fixed-point iteration)."""
    x, y = xd.copy(), yd.copy()
    with np.errstate(over="ignore", invalid="ignore"):  # diverges (to NaN) only far beyond a real lens
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1 + k1 * r2 + k2 * r2 * r2
            dx = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            x, y = x + (xd - dx), y + (yd - dy)
    return x, y


class LensDistortion(_Displacement):
    """Radial-tangential lens distortion (OpenCV k1 k2 p1 p2) the twin's pinhole camera misses."""

    name = "lens_distortion"
    description = ("OpenCV radial-tangential distortion k1, k2 (radial), p1, p2 (tangential) of the RGB camera, "
                   "on normalised coordinates: the measured pixel sees the pinhole pixel of undistort(x).")
    param_names = ("k1", "k2", "p1", "p2")
    steps = (1e-3, 1e-3, 1e-4, 1e-4)

    def applies(self, data: ResidualData) -> bool:
        return data.has_rgb

    def displacement(self, data, theta):
        t_count, h, w = data.rgb_valid.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        # One field per distinct camera (usually one for the whole recording).
        cams, which = np.unique(data.rgb_intrinsics, axis=0, return_inverse=True)
        k = cams[:, :, None, None]
        xd, yd = (u[None] - k[:, 2]) / k[:, 0], (v[None] - k[:, 3]) / k[:, 1]
        x, y = _undistort(xd, yd, *theta)
        return np.stack([(x - xd) * k[:, 0], (y - yd) * k[:, 1]], -1)[which.ravel()]

    def fit(self, data: ResidualData):
        theta = self._solve(data)
        params = dict(zip(self.param_names, (float(t) for t in theta), strict=True))
        d = self.displacement(data, theta)
        # Evidence: per radius bin, the radial shift that best explains the residual (one unknown
        # per bin, linearised), beside the fitted model's radial displacement.
        t_count, h, w = data.rgb_valid.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        k = data.rgb_intrinsics[:, :, None, None]
        ru, rv = u[None] - k[:, 2], v[None] - k[:, 3]
        rad = np.hypot(ru, rv)
        er = np.stack([ru, rv], -1) / np.maximum(rad, 1e-9)[..., None]
        pb = gaussian_filter(data.rgb_pred, (0, 1.0, 1.0, 0))
        mb = gaussian_filter(data.rgb_meas, (0, 1.0, 1.0, 0))
        gy, gx = np.gradient(pb, axis=(1, 2))
        g = gx * er[..., :1] + gy * er[..., 1:]  # [T, H, W, 3] derivative along the radius
        ok = data.rgb_valid
        num, den = (g * (mb - pb)).sum(-1)[ok], (g * g).sum(-1)[ok]
        x, top = _binned_mean(rad[ok], num, 10)
        _, bottom = _binned_mean(rad[ok], den, 10)
        _, model = _binned_mean(rad[ok], np.sum(d * er, -1)[ok], 10)
        ev = Evidence("radial displacement of the measured image vs radius", "radius from principal point (px)",
                      "radial shift (px)", x.tolist(), (top / np.maximum(bottom, 1e-12)).tolist(), model.tolist())
        corner = float(np.nanmax(np.abs(d[..., 0] + 1j * d[..., 1])))
        return {**params, "max_shift_px": corner}, ev


def _rotate(rot: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``rot [T, 3, 3]`` applied to ``points [T, h, w, 3]`` (a batched matmul; einsum is slow here)."""
    t_count = points.shape[0]
    flat = points.reshape(t_count, -1, 3)
    return np.matmul(flat, np.swapaxes(rot, 1, 2)).reshape(points.shape)


def _backproject(depth: np.ndarray, k: np.ndarray, world_from_camera: np.ndarray) -> np.ndarray:
    """``[T, h, w, 3]`` world points (metres) of z-depth maps ``[T, h, w]`` (NaN stays NaN)."""
    u, v = pixel_grid(depth.shape[2], depth.shape[1])
    cam = backproject(depth, k, u[None], v[None])
    return _rotate(world_from_camera[:, :3, :3], cam) + world_from_camera[:, None, None, :3, 3]


def _project(points: np.ndarray, k: np.ndarray, world_from_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel x, y and z-depth (``[T, h, w]`` each) of world points ``[T, h, w, 3]`` in each frame's camera."""
    rot, trans = world_from_camera[:, :3, :3], world_from_camera[:, :3, 3]
    cam = _rotate(np.swapaxes(rot, 1, 2), points - trans[:, None, None, :])
    k = k[:, :, None, None]
    z = cam[..., 2]
    return k[:, 0] * cam[..., 0] / z + k[:, 2], k[:, 1] * cam[..., 1] / z + k[:, 3], z


def _normals(points: np.ndarray) -> np.ndarray:
    """``[T, h, w, 3]`` unit normals of a back-projected depth map (NaN at holes and image borders)."""
    dy, dx = np.gradient(points, axis=(1, 2))
    n = np.cross(dx, dy)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _rigid(rotvec: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """``[T, 4, 4]`` rigid transforms from rotation vectors ``[T, 3]`` (radians) and translations ``[T, 3]``."""
    angle = np.linalg.norm(rotvec, axis=-1)
    axis = np.where(angle[:, None] > 0, rotvec / np.maximum(angle, 1e-300)[:, None], [1.0, 0, 0])
    out = np.tile(np.eye(4), (rotvec.shape[0], 1, 1))
    for t in range(rotvec.shape[0]):
        out[t, :3, :3] = axis_angle_to_matrix(axis[t], angle[t])
    out[:, :3, 3] = trans
    return out


class PoseDrift(Effect):
    """Odometry drift: the recorded world slides and turns away from the true one, linearly in time.

    The correction ``C_t`` maps the measured point cloud (placed with the recorded pose) onto the
    twin: rotation vector ``w0 + w1 s`` about the world origin and translation ``v0 + v1 s``,
    ``s = t - t0`` seconds since the first frame. The drift is its inverse; it is reported as a
    rotation rate (rad/s) and the translation rate of the world point under the first camera (m/s).
    """

    name = "pose_drift"
    target = "depth"
    description = ("Recorded poses drift linearly in time: the measured point cloud needs the rigid correction "
                   "rotation w0 + w1 s (rad), translation v0 + v1 s (m), s seconds since the first frame.")
    iterations = 3

    def null_columns(self, geometry):
        return drift_columns(geometry)

    def applies(self, data: ResidualData) -> bool:
        return (data.has_depth and data.has_poses and data.depth_intrinsics is not None
                and data.depth_pred.shape[0] >= 3)

    @staticmethod
    def _per_frame(params: dict, data: ResidualData) -> tuple[np.ndarray, np.ndarray]:
        s = (data.timestamps - params["t0_s"])[:, None]
        w = np.asarray(params["rot0_rad"]) + s * np.asarray(params["rot_rad_per_s"])
        v = np.asarray(params["trans0_m"]) + s * np.asarray(params["trans_m_per_s"])
        return w, v

    @staticmethod
    def _surface(data: ResidualData) -> tuple[np.ndarray, np.ndarray]:
        """The predicted surface's world points and unit normals (``[T, h, w, 3]`` each): what
        ``_system`` compares the measurement with. ``apply_to_target`` changes only the
        measurement, so one fit computes them once."""
        p = _backproject(data.depth_pred, data.depth_intrinsics, data.world_from_camera)
        return p, _normals(p)

    def _system(self, data: ResidualData, t0: float, surface: tuple[np.ndarray, np.ndarray] | None = None):
        """Point-to-plane rows ``[n, 12]``, right-hand side ``[n]``, and the frame of each row;
        ``surface``: ``_surface(data)`` when already computed."""
        p, n = self._surface(data) if surface is None else surface
        q = _backproject(data.depth_meas, data.depth_intrinsics, data.world_from_camera)
        ok = np.isfinite(data.depth_residual()) & np.all(np.isfinite(n), -1)
        a, b = data.depth_sigma
        sigma = a + b * data.depth_pred.astype(np.float64) ** 2
        frame = np.broadcast_to(np.arange(ok.shape[0])[:, None, None], ok.shape)[ok]
        s = (data.timestamps[frame] - t0)[:, None]
        qn = np.cross(q[ok], n[ok])
        wgt = 1.0 / sigma[ok][:, None]
        rows = np.concatenate([qn, s * qn, n[ok], s * n[ok]], 1) * wgt
        rhs = -np.sum(n[ok] * (q[ok] - p[ok]), -1) * wgt[:, 0]
        return rows, rhs, frame

    def fit(self, data: ResidualData):
        t0 = float(data.timestamps[0])
        params = {"t0_s": t0, "rot0_rad": [0.0] * 3, "rot_rad_per_s": [0.0] * 3, "trans0_m": [0.0] * 3,
                  "trans_m_per_s": [0.0] * 3}
        surface = self._surface(data)  # the prediction's: the same at every step
        for _ in range(self.iterations):
            rows, rhs, _ = self._system(self.apply_to_target(data, params), t0, surface)
            if rows.shape[0] < 100:
                break
            x = _scaled_least_squares(rows, rhs)
            for i, key in enumerate(("rot0_rad", "rot_rad_per_s", "trans0_m", "trans_m_per_s")):
                params[key] = (np.asarray(params[key]) + x[3 * i: 3 * i + 3]).tolist()
        # The drift is the correction's inverse: about the first camera, D_t x ~ x + s (-w1 x (x - c0) - v1 - w1 x c0).
        c0 = data.world_from_camera[0, :3, 3]
        w1, v1 = np.asarray(params["rot_rad_per_s"]), np.asarray(params["trans_m_per_s"])
        drift_v = -v1 - np.cross(w1, c0)
        params.update(drift_rot_rad_per_s=float(np.linalg.norm(w1)), drift_trans_m_per_s=float(np.linalg.norm(drift_v)),
                      drift_trans_m_per_s_xyz=drift_v.tolist(), drift_rot_rad_per_s_xyz=(-w1).tolist())
        return params, self._evidence(data, params, c0, surface)

    def _evidence(self, data: ResidualData, params: dict, c0: np.ndarray,
                  surface: tuple[np.ndarray, np.ndarray] | None = None) -> Evidence | None:
        """Per frame, a free rigid correction (one linear point-to-plane step) against the fitted line."""
        rows, rhs, frame = self._system(data, float(params["t0_s"]), surface)
        t_count = data.depth_pred.shape[0]
        y = np.full((3, t_count), np.nan)
        for t in range(t_count):
            sel = frame == t
            if sel.sum() < 100:
                continue
            a = rows[sel][:, [0, 1, 2, 6, 7, 8]]
            x = _scaled_least_squares(a, rhs[sel])
            y[:, t] = -(x[3:] + np.cross(x[:3], c0))  # drift of the point under the first camera
        w, v = self._per_frame(params, data)
        model = -(v + np.cross(w, c0)).T
        return Evidence("drift of the recorded world (at the first camera) per frame", "time (s)",
                        "drift (m)", data.timestamps.tolist(), y.tolist(), model.tolist(), ("x", "y", "z"))

    def apply(self, data: ResidualData, params: dict) -> ResidualData:
        out = self.apply_to_target(data, params)
        if data.has_rgb:
            w, v = self._per_frame(params, data)
            out = replace(out, rgb_pred=self._rgb(data, _rigid(w, v)))
        return out

    def apply_to_target(self, data: ResidualData, params: dict) -> ResidualData:
        """The depth measurement corrected (what the fit and the depth residual see); ``apply``
        also moves the RGB prediction, which the depth never reads."""
        # The measurement is corrected: each pixel's predicted point is moved by C_t^-1 to where the
        # sensor saw it, the measured depth there is sampled (bilinear), and its point moved back by C_t.
        w, v = self._per_frame(params, data)
        corr = _rigid(w, v)
        k, poses = data.depth_intrinsics, data.world_from_camera
        p = _backproject(data.depth_pred, k, poses)
        inv = np.linalg.inv(corr)
        p_sensor = _rotate(inv[:, :3, :3], p) + inv[:, None, None, :3, 3]
        x, y, _ = _project(p_sensor, k, poses)
        # The measured depth there: the prediction interpolated (bilinear) plus the residual of the
        # nearest pixel, so that the sensor noise is not averaged away (the noise model must see it).
        pz = data.depth_pred.astype(np.float64)
        finite = np.isfinite(pz)
        zp, inside = _bilinear(np.where(finite, pz, 0.0)[..., None], x, y)
        share, _ = _bilinear(finite[..., None].astype(np.float64), x, y)
        h, w = pz.shape[1:]
        xi, yi = np.clip(np.rint(np.nan_to_num(x)), 0, w - 1).astype(np.int64), np.clip(np.rint(np.nan_to_num(y)), 0, h - 1).astype(np.int64)
        frames = np.broadcast_to(np.arange(pz.shape[0])[:, None, None], xi.shape)
        r_near = (data.depth_meas.astype(np.float64) - pz)[frames, yi, xi]
        ok = inside & (share[..., 0] > 0.999)
        z = np.where(ok, zp[..., 0] / np.maximum(share[..., 0], 1e-9) + r_near, np.nan)
        # Back-project the sampled depth at the sampled pixel, move it by C_t, read its depth.
        kk = k[:, :, None, None]
        cam = np.stack([(x - kk[:, 2]) / kk[:, 0] * z, (y - kk[:, 3]) / kk[:, 1] * z, z], -1)
        q = _rotate(poses[:, :3, :3], cam) + poses[:, None, None, :3, 3]
        q = _rotate(corr[:, :3, :3], q) + corr[:, None, None, :3, 3]
        _, _, depth = _project(q, k, poses)
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
        # A pixel with no corrected measurement is NaN, which every residual leaves out; the
        # validity mask itself stays as it is (the held-out check relies on it).
        return replace(data, depth_meas=depth)

    @staticmethod
    def _rgb(data: ResidualData, corr: np.ndarray) -> np.ndarray:
        """The predicted RGB seen from the corrected (true) camera ``corr @ world_from_camera``:
        each pixel's predicted point lands at ``x'`` there, so the prediction moves by ``u - x'``
        (read at ``u``, as the image effects do; no depth, no move)."""
        t_count, h, w = data.rgb_valid.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        p = rgb_world_points(data)
        inv = np.linalg.inv(corr)
        p_true = _rotate(inv[:, :3, :3], p) + inv[:, None, None, :3, 3]
        x, y, _ = _project(p_true, data.rgb_intrinsics, data.world_from_camera)
        dx, dy = np.nan_to_num(u[None] - x), np.nan_to_num(v[None] - y)
        img, _ = _bilinear(data.rgb_pred, u[None] + dx, v[None] + dy)
        return img.astype(np.float32)


_VELOCITY_CACHE: list = []
VELOCITY_POINTS = 5


def _derivative_weights(timestamps: np.ndarray, n_pts: int) -> np.ndarray:
    """``[T, n_pts]`` weights of frames ``first(i) .. first(i) + n_pts - 1`` (``first`` centres frame i
    where it can) whose sum with the values there is the derivative at ``timestamps[i]`` of their
    interpolating polynomial (any spacing, one-sided at the ends)."""
    t_count = timestamps.shape[0]
    out = np.zeros((t_count, n_pts))
    for i in range(t_count):
        first = min(max(i - n_pts // 2, 0), t_count - n_pts)
        tau = timestamps[first:first + n_pts] - timestamps[i]
        tau = tau / np.max(np.abs(tau))  # conditioning; undone below
        vander = tau[:, None] ** np.arange(n_pts)[None]
        e1 = np.zeros(n_pts)
        e1[1] = 1.0
        out[i] = np.linalg.solve(vander.T, e1) / np.max(np.abs(timestamps[first:first + n_pts] - timestamps[i]))
    return out


def image_velocity(data: ResidualData) -> np.ndarray:
    """``[T, H, W, 2]`` image velocity (pixels per second) of the predicted surface at each RGB pixel.

    Each pixel's predicted point (predicted depth, nearest depth pixel) is projected into the
    camera a moment before and after the frame's time. With a pose stream
    (``data.track_timestamps``) those cameras are the frame's pose moved by the stream's motion
    over one stream interval either side (a central difference, one-sided at its ends). Without,
    they are the recorded poses of the five frames around it, and the velocity is the derivative
    at the frame's time of the polynomial through those projections (centred, one-sided at the
    ends); frames far apart alias hand shake.
    The camera moves, the scene does not: this is the motion field of the recorded camera path.
    NaN where the prediction has no depth.
    """
    key_arrays = (data.depth_pred, data.world_from_camera, data.rgb_intrinsics, data.track_world_from_camera)
    for key, value in _VELOCITY_CACHE:  # fits call this many times on the same recording
        if all(a is b for a, b in zip(key, key_arrays, strict=True)):
            return value
    t_count, h, w = data.rgb_valid.shape
    poses = data.world_from_camera
    world = rgb_world_points(data)
    if data.track_timestamps is not None and data.track_world_from_camera is not None:
        out = _track_velocity(data, world)
    else:
        # The derivative at t_i of the polynomial through the projections into the frames around i
        # (five where there are: hand shake is fast, a three-point difference underestimates it).
        n_pts = min(VELOCITY_POINTS, t_count)
        out = np.zeros((t_count, h, w, 2))
        for j in range(n_pts):
            others = np.array([min(max(i - n_pts // 2, 0), t_count - n_pts) + j for i in range(t_count)])
            x, y, _ = _project(world, data.rgb_intrinsics[others], poses[others])
            out += _derivative_weights(data.timestamps, n_pts)[:, j, None, None, None] * np.stack([x, y], -1)
    _remember_velocity(data, out)
    return out


def _track_velocity(data: ResidualData, world: np.ndarray) -> np.ndarray:
    """``[T, H, W, 2]`` the image velocity of ``world [T, H, W, 3]`` from the pose stream's motion
    about each frame's time (see :func:`image_velocity`)."""
    ts, track = data.track_timestamps, data.track_world_from_camera
    dt = float(np.median(np.diff(ts)))
    t = np.clip(data.timestamps, ts[0], ts[-1])
    before, after = np.clip(t - dt, ts[0], ts[-1]), np.clip(t + dt, ts[0], ts[-1])
    moved = relative_motion(track, ts, np.concatenate([t, t]), np.concatenate([before, after]))
    t_count = t.size
    xa, ya, _ = _project(world, data.rgb_intrinsics, data.world_from_camera @ moved[:t_count])
    xb, yb, _ = _project(world, data.rgb_intrinsics, data.world_from_camera @ moved[t_count:])
    span = np.maximum(after - before, 1e-9)[:, None, None, None]
    return np.stack([xb - xa, yb - ya], -1) / span


def _remember_velocity(data: ResidualData, velocity: np.ndarray) -> None:
    """Cache ``velocity`` for ``data`` (by the identity of its arrays); the last few are kept."""
    _VELOCITY_CACHE.insert(0, ((data.depth_pred, data.world_from_camera, data.rgb_intrinsics,
                                data.track_world_from_camera), velocity))
    del _VELOCITY_CACHE[3:]


def rgb_world_points(data: ResidualData) -> np.ndarray:
    """``[T, H, W, 3]`` world points (metres) of the predicted surface at each RGB pixel: the
    predicted depth of the nearest depth pixel, on the RGB pixel's ray from the recorded pose."""
    t_count, h, w = data.rgb_valid.shape
    dh, dw = data.depth_pred.shape[1:]
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    k, kd = data.rgb_intrinsics[:, :, None, None], data.depth_intrinsics[:, :, None, None]
    xn, yn = (u[None] - k[:, 2]) / k[:, 0], (v[None] - k[:, 3]) / k[:, 1]
    ud = np.rint(xn * kd[:, 0] + kd[:, 2]).astype(np.int64)
    vd = np.rint(yn * kd[:, 1] + kd[:, 3]).astype(np.int64)
    inside = (ud >= 0) & (ud < dw) & (vd >= 0) & (vd < dh)
    frames = np.broadcast_to(np.arange(t_count)[:, None, None], ud.shape)
    z = np.where(inside, data.depth_pred[frames, np.clip(vd, 0, dh - 1), np.clip(ud, 0, dw - 1)], np.nan)
    poses = data.world_from_camera
    cam = np.stack([xn * z, yn * z, z], -1)
    return _rotate(poses[:, :3, :3], cam) + poses[:, None, None, :3, 3]


class _Timing(_Displacement):
    """A timing error: each pixel is displaced by its image velocity times a time (seconds)."""

    steps = (1e-3,)
    # Hand shake reaches ~6 Hz: poses further apart than this cannot tell the camera's velocity.
    max_frame_interval_s = 0.1

    def applies(self, data: ResidualData) -> bool:
        if not (data.has_rgb and data.has_depth and data.has_poses and data.depth_intrinsics is not None
                and data.rgb_pred.shape[0] >= 3):
            return False
        gaps = np.diff(data.timestamps)
        # A pose stream gives the camera's motion between frames kept far apart.
        poses_gaps = gaps if data.track_timestamps is None else np.diff(data.track_timestamps)
        return bool(np.all(gaps > 0) and np.median(poses_gaps) <= self.max_frame_interval_s)

    def seconds(self, data: ResidualData, theta: np.ndarray) -> np.ndarray:
        """``[T or 1, H or 1, W or 1]`` the time (seconds) by which each measured pixel is late."""
        raise NotImplementedError

    def displacement(self, data, theta):
        # No depth, no velocity: such pixels are left where they are.
        return np.nan_to_num(self.seconds(data, theta)[..., None] * image_velocity(data))

    def _fit_view(self, data: ResidualData) -> ResidualData:
        # The velocity needs the neighbouring frames: computed on the whole recording, then cut.
        view = super()._fit_view(data)
        if view is not data:
            idx = np.searchsorted(data.timestamps, view.timestamps)
            _remember_velocity(view, image_velocity(data)[idx])
        return view

    # The linearised steps stop short of the energy's minimum: each undershoots the displacement
    # it is after (a 50 ms offset on the tiny door, against the quick twin: the steps reached 26
    # ms, where the applied effect's energy is lowest near 40 ms; without the step limit, 31 ms
    # and still rising). The energy itself is then searched along the fitted time, from half to
    # three times it (one warp of the fit frames per evaluation, ~0.1 s on 8 frames of 256x192).
    line_search = (0.5, 3.0)

    def _solve_view(self, view: ResidualData) -> np.ndarray:
        theta = super()._solve_view(view)
        if theta.size != 1 or not np.isfinite(theta[0]) or theta[0] == 0.0:
            return theta

        def energy(value: float) -> float:
            return target_energy(self.apply(view, {self.param_names[0]: value}), self.target)

        lo, hi = sorted(theta[0] * k for k in self.line_search)
        best = minimize_scalar(energy, bounds=(lo, hi), method="bounded", options={"xatol": 0.01 * abs(theta[0])})
        return np.array([float(best.x)]) if best.success and best.fun < energy(float(theta[0])) else theta

    def _speed_evidence(self, data: ResidualData, theta: np.ndarray, x_of_pixel: np.ndarray, x_label: str,
                        title: str) -> Evidence:
        """Per bin of ``x_of_pixel [T, H, W]``: the time shift that best explains the residual
        along the image velocity (linearised, one unknown per bin) against the fitted one."""
        vel = np.nan_to_num(image_velocity(data))
        pb = gaussian_filter(data.rgb_pred, (0, 1.0, 1.0, 0))
        mb = gaussian_filter(data.rgb_meas, (0, 1.0, 1.0, 0))
        gy, gx = np.gradient(pb, axis=(1, 2))
        g = gx * vel[..., :1] + gy * vel[..., 1:]  # [T, H, W, 3]: d(pred)/d(time)
        ok = data.rgb_valid
        num, den = (g * (mb - pb)).sum(-1)[ok], (g * g).sum(-1)[ok]
        x, top = _binned_mean(x_of_pixel[ok], num, 8)
        _, bottom = _binned_mean(x_of_pixel[ok], den, 8)
        _, model = _binned_mean(x_of_pixel[ok], np.broadcast_to(self.seconds(data, theta), ok.shape)[ok], 8)
        return Evidence(title, x_label, "time shift (s)", x.tolist(), (top / np.maximum(bottom, 1e-12)).tolist(),
                        model.tolist())


class TimeOffset(_Timing):
    """The RGB stream lags the depth and pose streams by a constant time."""

    name = "time_offset"
    description = ("RGB exposed `seconds` before its depth map and recorded pose (negative: after); the "
                   "prediction at the recorded pose is seen moved by seconds x image velocity.")
    param_names = ("seconds",)

    def seconds(self, data, theta):
        return np.full((1, 1, 1), theta[0])

    def fit(self, data: ResidualData):
        theta = self._solve(data)
        speed = np.linalg.norm(np.nan_to_num(image_velocity(data)), axis=-1)
        t_count = data.rgb_valid.shape[0]
        frame = np.broadcast_to(np.arange(t_count, dtype=np.float64)[:, None, None], data.rgb_valid.shape)
        ev = self._speed_evidence(data, theta, frame, "frame", "RGB time shift against depth and pose, per frame")
        return {"seconds": float(theta[0]),
                "median_speed_px_per_s": float(np.median(speed[data.rgb_valid])) if data.rgb_valid.any() else 0.0}, ev


class RollingShutter(_Timing):
    """A rolling shutter: row v of the RGB image is exposed at t + (v / (H - 1) - 0.5) readout_s."""

    name = "rolling_shutter"
    description = ("RGB rows exposed one after another over readout_s seconds (top first when positive); "
                   "the recorded pose is the mid-row one.")
    param_names = ("readout_s",)

    def seconds(self, data, theta):
        h = data.rgb_valid.shape[1]
        # Row v is late by s_v = (v / (H - 1) - 0.5) readout: it sees the prediction moved back by s_v.
        return -(np.arange(h, dtype=np.float64) / (h - 1) - 0.5)[None, :, None] * theta[0]

    def fit(self, data: ResidualData):
        theta = self._solve(data)
        t_count, h, w = data.rgb_valid.shape
        row = np.broadcast_to(np.arange(h, dtype=np.float64)[None, :, None], data.rgb_valid.shape)
        ev = self._speed_evidence(data, theta, row, "image row", "RGB time shift (lead) per image row")
        return {"readout_s": float(theta[0])}, ev


BUILTIN_CAMERA_EFFECTS = (LensDistortion, PoseDrift, TimeOffset, RollingShutter)
for _cls in BUILTIN_CAMERA_EFFECTS:
    register_effect(_cls)
