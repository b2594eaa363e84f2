"""Photometric refinement: pin with the static recording's images what the geometry leaves free.

Where two recordings overlap in part, what they both saw is often a floor, a wall and a cabinet
front: planes whose normals leave the slide along the front nearly free, so point-to-plane ICP
settles wherever small biases push it (centimetres, along the weakest direction). The texture
pins that slide. Matching colours between two fused clouds (coloured ICP) needs both clouds to
sample the texture densely; at phone depth resolution (a point every few centimetres per frame,
one colour sample each) its minimum lay centimetres from the truth (docs/accuracy.md). Here
instead each dynamic point, with the colour its own frame saw, is projected into the static
recording's images and compared with what they show there, at full image resolution: a direct
photometric term.

It is minimised jointly with the point-to-plane term, yaw about gravity and translation only,
by Gauss-Newton, each residual weighted by its inverse variance under a Tukey kernel. A grey-level
residual's variance is the image noise plus the depth noise times the texture's gradient, so a
textured point pins its position along the gradient as well as a point-to-plane match pins it
along the normal, and no better: where the geometry pins a direction the texture does not pull it
away, where it leaves one free the texture decides. Each dynamic point's residuals over the
static views that see it count as one observation. The images are blurred coarse to fine (the
blur an angle, so the reach is the same at any image resolution): the coarse level reaches across
a texture's features, the fine one is precise. Exposure and white balance differ between the
recordings and drift within each, so every pair of (static view, dynamic frame) gets its own
gain on the grey level. Lens distortion is ignored, as in the rest of the registration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from artitwin_core.capture import Capture
from artitwin_core.geometry import axis_angle_to_matrix
from artitwin_core.registration._clouds import backproject
from artitwin_core.registration._evidence import evenly_spaced
from artitwin_core.registration._gravity_icp import PlaneTarget, plane_system

_LUMA = np.array([0.299, 0.587, 0.114])
_TUKEY = 4.685  # Tukey's constant: 95 % efficiency for Gaussian residuals (in robust sigmas)


@dataclass(frozen=True)
class PhotometricResult:
    """``transform [4, 4]`` (canonical_from_session) and, per blur level, a dict with the blur
    (radians), the iterations, the photometric residuals used, and the robust scales of both
    residuals (grey level in [0, 1]; metres)."""

    transform: np.ndarray
    levels: tuple[dict, ...]


def _grey(rgb: np.ndarray, sigma_px: float) -> np.ndarray:
    g = rgb.astype(np.float64) @ _LUMA / 255.0
    return ndimage.gaussian_filter(g, sigma_px) if sigma_px > 0 else g


def _edge_free_depth(depth: np.ndarray, max_depth_m: float, tolerance_m: float) -> np.ndarray:
    """``depth [h, w]`` with NaN where it is invalid or next to a depth jump, where the colour
    mixes two surfaces. A surface's inverse depth is affine in the pixel coordinates (exactly,
    for a plane, and so a floor seen at a grazing angle is no edge); a pixel whose inverse depth
    departs from the mean of its two neighbours, along either axis, by more than ``tolerance_m``
    (converted at its depth), is next to a jump."""
    d = np.where(np.isfinite(depth) & (depth > 0) & (depth < max_depth_m), depth, np.nan).astype(np.float64)
    inv = 1.0 / d
    bend = np.zeros_like(d)
    for axis in (0, 1):
        pad = np.pad(inv, [(1, 1) if a == axis else (0, 0) for a in (0, 1)], constant_values=np.nan)
        lo = pad[:-2] if axis == 0 else pad[:, :-2]
        hi = pad[2:] if axis == 0 else pad[:, 2:]
        bend = np.maximum(bend, np.abs(0.5 * (lo + hi) - inv))  # NaN (an invalid neighbour) propagates
    return np.where(bend * d**2 < tolerance_m, d, np.nan)


def _robust_sigma(r: np.ndarray, floor: float) -> float:
    return max(1.4826 * float(np.median(np.abs(r - np.median(r)))) if len(r) else floor, floor)


def _tukey_weights(r: np.ndarray, c: float) -> np.ndarray:
    return np.where(np.abs(r) < c, (1.0 - (r / c) ** 2) ** 2, 0.0)


@dataclass(frozen=True)
class _Samples:
    """Dynamic points (session frame) with their grey levels, for one blur level."""

    points: np.ndarray  # [N, 3]
    grey: np.ndarray  # [N]
    frame: np.ndarray  # [N] index into the dynamic frames used


def _dynamic_samples(dynamic: Capture, frames, sigma_rad: float, *, stride: int, max_depth_m: float,
                     min_confidence: int, tolerance_m: float, max_points: int) -> _Samples:
    rng = np.random.default_rng(0)
    pts, grey, frame = [], [], []
    for i, t in enumerate(frames):
        depth = dynamic.depth[t].astype(np.float64)
        if dynamic.confidence is not None and min_confidence > 0:
            depth = np.where(dynamic.confidence[t] >= min_confidence, depth, np.nan)
        pc, _ = backproject(_edge_free_depth(depth, max_depth_m, tolerance_m), dynamic.depth_intrinsics[t], stride)
        fx, fy, cx, cy = dynamic.rgb_intrinsics[t]
        img = _grey(dynamic.rgb[t], sigma_rad * fx)
        u, v = pc[:, 0] / pc[:, 2] * fx + cx, pc[:, 1] / pc[:, 2] * fy + cy
        h, w = img.shape
        inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        pose = dynamic.world_from_camera[t]
        pts.append(pc[inside] @ pose[:3, :3].T + pose[:3, 3])
        grey.append(ndimage.map_coordinates(img, [v[inside], u[inside]], order=1))
        frame.append(np.full(int(inside.sum()), i))
    points, grey_, frame_ = np.concatenate(pts), np.concatenate(grey), np.concatenate(frame)
    if len(points) > max_points:
        keep = np.sort(rng.choice(len(points), max_points, replace=False))
        points, grey_, frame_ = points[keep], grey_[keep], frame_[keep]
    return _Samples(points, grey_, frame_)


@dataclass(frozen=True)
class _Views:
    """Static views for one blur level: grey images and their gradients, edge-free depth."""

    grey: np.ndarray  # [K, H, W]
    grad_u: np.ndarray  # [K, H, W] per pixel
    grad_v: np.ndarray  # [K, H, W]
    depth: np.ndarray  # [K, h, w] metres, NaN = unusable
    camera_from_world: np.ndarray  # [K, 4, 4]
    rgb_intrinsics: np.ndarray  # [K, 4]
    depth_intrinsics: np.ndarray  # [K, 4]


def _static_views(static: Capture, frames: np.ndarray, sigma_rad: float, *, max_depth_m: float,
                  min_confidence: int, tolerance_m: float) -> _Views:
    grey, gu, gv, depth = [], [], [], []
    for t in frames:
        img = _grey(static.rgb[t], sigma_rad * static.rgb_intrinsics[t, 0])
        dv, du = np.gradient(img)
        d = static.depth[t].astype(np.float64)
        if static.confidence is not None and min_confidence > 0:
            d = np.where(static.confidence[t] >= min_confidence, d, np.nan)
        grey.append(img)
        gu.append(du)
        gv.append(dv)
        depth.append(_edge_free_depth(d, max_depth_m, tolerance_m))
    return _Views(np.stack(grey), np.stack(gu), np.stack(gv), np.stack(depth),
                  np.linalg.inv(static.world_from_camera[frames]), static.rgb_intrinsics[frames],
                  static.depth_intrinsics[frames])


@dataclass(frozen=True)
class _Terms:
    """Every (dynamic point, static view) pair where the view sees the point: the view's grey
    level there ``[R]``, its gradient with respect to the canonical point ``[R, 3]`` (per metre),
    the view ``[R]`` and the dynamic sample ``[R]``."""

    grey: np.ndarray
    gradient: np.ndarray
    view: np.ndarray
    sample: np.ndarray


def _photometric_terms(x: np.ndarray, views: _Views, tolerance_m: float) -> _Terms:
    """The pairs for dynamic points at ``x [N, 3]`` (canonical): a view sees a point in its
    image whose edge-free depth there is within ``tolerance_m`` of the point's."""
    grey, grad, view, sample = [], [], [], []
    for k in range(len(views.grey)):
        m = views.camera_from_world[k]
        xc = x @ m[:3, :3].T + m[:3, 3]
        z = np.maximum(xc[:, 2], 0.05)
        dfx, dfy, dcx, dcy = views.depth_intrinsics[k]
        h, w = views.depth.shape[1:]
        ud, vd = xc[:, 0] / z * dfx + dcx, xc[:, 1] / z * dfy + dcy
        idx = np.nonzero((xc[:, 2] > 0.05) & (ud >= 0) & (ud <= w - 1) & (vd >= 0) & (vd <= h - 1))[0]
        # Bilinear: NaN next to an unusable pixel, so such points are not seen.
        depth = ndimage.map_coordinates(views.depth[k], [vd[idx], ud[idx]], order=1, mode="nearest")
        idx = idx[np.abs(depth - z[idx]) < tolerance_m]
        fx, fy, cx, cy = views.rgb_intrinsics[k]
        p = xc[idx]
        u, v = p[:, 0] / p[:, 2] * fx + cx, p[:, 1] / p[:, 2] * fy + cy
        H, W = views.grey.shape[1:]
        inside = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
        idx, p, u, v = idx[inside], p[inside], u[inside], v[inside]
        coords = [v, u]
        iu = ndimage.map_coordinates(views.grad_u[k], coords, order=1)
        iv = ndimage.map_coordinates(views.grad_v[k], coords, order=1)
        zz = p[:, 2]
        # d(grey)/d(camera point) through the projection, then to the canonical point.
        dcam = np.stack([iu * fx / zz, iv * fy / zz, -(iu * fx * p[:, 0] + iv * fy * p[:, 1]) / zz**2], -1)
        grey.append(ndimage.map_coordinates(views.grey[k], coords, order=1))
        grad.append(dcam @ m[:3, :3])
        view.append(np.full(len(idx), k))
        sample.append(idx)
    return _Terms(np.concatenate(grey), np.concatenate(grad), np.concatenate(view), np.concatenate(sample))


def _pair_gains(terms: _Terms, samples: _Samples) -> np.ndarray:
    """``[R]`` the gain of each pair's (static view, dynamic frame): the ratio of the median grey
    levels of the points both see (exposure and white balance differ between them)."""
    pair = terms.view * (int(samples.frame.max()) + 1) + samples.frame[terms.sample]
    _, inverse = np.unique(pair, return_inverse=True)
    ref = samples.grey[terms.sample]
    gain = np.array([np.median(terms.grey[inverse == j]) / max(float(np.median(ref[inverse == j])), 1e-3)
                     for j in range(int(inverse.max()) + 1)])
    return gain[inverse]


def photometric_refine(
    static: Capture,
    dynamic: Capture,
    dynamic_frames,
    target: PlaneTarget,
    geometric_points: np.ndarray,
    init: np.ndarray,
    up: np.ndarray,
    *,
    blur_rad: tuple[float, ...],
    num_views: int,
    max_points: int,
    visibility_m: float,
    max_distance_m: float,
    kernel_m: float,
    grey_noise: float,
    stride: int,
    max_depth_m: float,
    min_confidence: int,
    iterations: int = 30,
    tolerance: float = 1e-4,
) -> PhotometricResult:
    """Refine ``init`` (yaw about ``up`` and translation; its tilt is kept) by photometric and
    point-to-plane residuals together.

    Args:
        static: the static recording: its images, depth (visibility) and poses (canonical).
        dynamic: the dynamic recording; ``dynamic_frames`` the frames whose points are used.
        target: the static surface for the point-to-plane term (canonical frame).
        geometric_points: ``[M, 3]`` dynamic points (session frame) for the point-to-plane term.
        init: ``[4, 4]`` starting canonical_from_session.
        up: ``[3]`` unit vector against gravity.
        blur_rad: Gaussian blur of the images per level, coarse to fine (radians: times the
            focal length in pixels).
        num_views: static views used (evenly spaced).
        max_points: at most this many dynamic points (a fixed random subset).
        visibility_m: a static view sees a point when its depth there is within this (metres),
            and pixels within one pixel of a depth jump larger than this are not used.
        max_distance_m, kernel_m: the point-to-plane term's match distance and Tukey width (m).
        grey_noise: the least standard deviation (grey levels in [0, 1]) of a grey-level
            residual where the texture is flat: what two recordings of one surface disagree by
            beyond their measured noise (a gain does not capture all of exposure and white
            balance; vignetting; the hand's shadow). Its robust estimate from the residuals is
            used where larger; the Tukey kernel is 4.685 of it.
        stride, max_depth_m, min_confidence: which depth pixels give dynamic points.
        iterations, tolerance: per level, at most this many Gauss-Newton steps; stop when a
            step turns less than ``tolerance`` radians and moves less than it (metres).
    """
    up = np.asarray(up, dtype=np.float64)
    transform = np.asarray(init, dtype=np.float64).copy()
    view_frames = evenly_spaced(static.num_frames, num_views)
    geo = np.asarray(geometric_points, dtype=np.float64)
    levels = []
    for sigma in blur_rad:
        samples = _dynamic_samples(dynamic, dynamic_frames, sigma, stride=stride, max_depth_m=max_depth_m,
                                   min_confidence=min_confidence, tolerance_m=visibility_m, max_points=max_points)
        views = _static_views(static, view_frames, sigma, max_depth_m=max_depth_m, min_confidence=min_confidence,
                              tolerance_m=visibility_m)
        info = {"blur_rad": float(sigma), "iterations": 0, "residuals": 0, "points": 0, "sigma_grey": float("nan"),
                "sigma_m": float("nan")}
        levels.append(info)
        if len(samples.points) < 50:
            continue
        for _ in range(iterations):
            info["iterations"] += 1
            geo_sys = plane_system(geo @ transform[:3, :3].T + transform[:3, 3], target, up,
                                   max_distance_m=max_distance_m, kernel_m=kernel_m)
            if geo_sys is None:
                break
            centre = geo_sys.centre
            x = samples.points @ transform[:3, :3].T + transform[:3, 3]
            terms = _photometric_terms(x, views, visibility_m)
            if len(terms.sample) < 50:
                break
            r = terms.grey - _pair_gains(terms, samples) * samples.grey[terms.sample]
            sigma_grey = _robust_sigma(r, grey_noise)
            sigma_m = _robust_sigma(geo_sys.residuals, 1e-4)
            # The variance of a grey-level residual: the image noise, plus the point's position
            # noise (the depth noise, as the point-to-plane residuals measure it) times the
            # texture's gradient. A textured point then pins its position along the gradient as
            # well as a point-to-plane match pins it along the normal, and no better.
            variance = sigma_grey**2 + np.sum(terms.gradient**2, axis=1) * sigma_m**2
            # Each dynamic point's residuals over the views that see it count as one observation.
            views_per_point = np.bincount(terms.sample, minlength=len(samples.points))[terms.sample]
            wp = _tukey_weights(r, _TUKEY * sigma_grey) / variance / views_per_point
            jac = np.hstack([(np.cross(x[terms.sample] - centre, terms.gradient) @ up)[:, None], terms.gradient])
            h = geo_sys.hessian / sigma_m**2 + jac.T @ (wp[:, None] * jac)
            g = geo_sys.gradient / sigma_m**2 + jac.T @ (wp * r)
            h += np.eye(4) * (1e-9 * np.trace(h) + 1e-12)
            step = -np.linalg.solve(h, g)
            transform = _yaw_step(step, centre, up) @ transform
            info.update(residuals=int(len(r)), points=int(len(np.unique(terms.sample))), sigma_grey=sigma_grey,
                        sigma_m=sigma_m)
            if abs(step[0]) < tolerance and np.linalg.norm(step[1:]) < tolerance:
                break
    return PhotometricResult(transform, tuple(levels))


def _yaw_step(x: np.ndarray, centre: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``[4, 4]`` the motion ``(yaw, tx, ty, tz)``: a turn by ``yaw`` about ``up`` through ``centre``, then a shift."""
    rot = axis_angle_to_matrix(up, float(x[0]))
    step = np.eye(4)
    step[:3, :3] = rot
    step[:3, 3] = centre - rot @ centre + x[1:]
    return step
