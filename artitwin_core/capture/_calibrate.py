"""Undo a sensor's affine depth error: ``true = (measured - offset) / scale``.

LiDAR and time-of-flight depth on phones carries a systematic scale and offset error of a few
percent and millimetres (the effect ``depth_scale_offset``). Both recordings of a scene come from
the same sensor, so once the canonical reconstruction has learned the error (its Gaussians are
fitted to the images' multi-view geometry, the sensor's depth to them through ``scale`` and
``offset``), every later stage reads the corrected depth: the registration, the change masks, the
lifted tracks, the joint states and the articulated training. :func:`estimate_depth_calibration`
finds the error from the recording itself: its frames' depth maps only agree, at their poses,
under the right correction.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.capture._types import Capture


def calibrate_depth(capture: Capture, scale: float, offset_m: float) -> Capture:
    """``capture`` with each depth map ``d`` replaced by ``(d - offset_m) / scale``.

    Args:
        capture: the recording as measured.
        scale, offset_m: the sensor's error, ``measured = scale * true + offset_m`` (metres).

    Returns:
        A new capture (the input is not changed). Missing depth (NaN) stays missing, and a
        corrected depth that is not positive becomes missing.

    Raises:
        InputError: a scale that is not a positive finite number or an offset that is not finite.
    """
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise InputError(f"depth calibration: scale must be a positive finite number, got {scale!r}.")
    if not (isinstance(offset_m, (int, float)) and math.isfinite(offset_m)):
        raise InputError(f"depth calibration: offset_m must be a finite number of metres, got {offset_m!r}.")
    depth = (np.asarray(capture.depth, np.float32) - np.float32(offset_m)) / np.float32(scale)
    depth = np.where(depth > 0, depth, np.nan).astype(np.float32)
    return dataclasses.replace(capture, depth=depth)


@dataclass(frozen=True)
class DepthCalibrationConfig:
    """Hyperparameters of :func:`estimate_depth_calibration`.

    Attributes:
        frame_gaps: each frame is compared with the frames this many frames later.
        pixel_stride: every n-th depth pixel each way is used.
        max_depth_m: depth beyond this is not used.
        min_confidence: depth whose ARKit confidence (0 low, 1 medium, 2 high) is below this is
            not used, in either frame of a pair (0 uses all; captures without confidence use all).
        min_facing_cos: surfaces seen more obliquely than this (cosine of the angle between the
            surface normal and the viewing ray) are not used: their depth is the least certain.
        edge_m: a projected point whose four neighbouring depths span more than this lies on a
            depth edge and is not used.
        iterations: re-associations (each a weighted least-squares solve).
        jackknife_blocks: the standard errors come from leaving out this many blocks of
            consecutive frames in turn (a frame's points share its pose and depth-map errors, so
            points are not independent).
    """

    frame_gaps: tuple[int, ...] = (2, 4, 8)
    pixel_stride: int = 2
    max_depth_m: float = 4.5
    min_confidence: int = 1
    min_facing_cos: float = 0.5
    edge_m: float = 0.02
    iterations: int = 8
    jackknife_blocks: int = 8


@dataclass(frozen=True)
class DepthCalibration:
    """A sensor's affine depth error, ``measured = scale * true + offset_m``.

    Attributes:
        scale, offset_m: the error (1 and 0 for an ideal sensor).
        residual_m: robust spread (1.4826 MAD) of the frames' disagreement after calibration.
        points: point pairs in the final solve.
        scale_se, offset_m_se: standard errors of ``scale`` and ``offset_m`` (frame-block
            jackknife); NaN with fewer than 3 blocks.
        reference_depth_m: median depth of the points used.
        error_se_m: standard error of the depth error ``(scale - 1) z + offset_m`` at that depth
            (the two estimates are strongly anti-correlated, so it is far below what their
            separate standard errors suggest where the data are).
    """

    scale: float
    offset_m: float
    residual_m: float
    points: int
    scale_se: float = float("nan")
    offset_m_se: float = float("nan")
    reference_depth_m: float = float("nan")
    error_se_m: float = float("nan")


def _normals(z: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``[H, W, 3]`` unit normals (camera frame) of a z-depth map, NaN where undefined."""
    fx, fy, cx, cy = k
    h, w = z.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    p = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], -1)
    du, dv = np.full_like(p, np.nan), np.full_like(p, np.nan)
    du[:, 1:-1] = p[:, 2:] - p[:, :-2]
    dv[1:-1] = p[2:] - p[:-2]
    n = np.cross(du, dv)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _pair_terms(capture: Capture, poses: np.ndarray, i: int, j: int, a: float, b: float, cfg: DepthCalibrationConfig):
    """Point-to-plane terms of frame ``i``'s depth against frame ``j``'s at the current
    calibration ``true = a * measured + b``: ``(c0, ca, cb, depth)`` with residual ``c0 + a ca + b
    cb``, and the measured depths of the points of frame ``i``."""
    ki, kj = np.asarray(capture.depth_intrinsics[i], np.float64), np.asarray(capture.depth_intrinsics[j], np.float64)
    h, w = capture.depth.shape[1:]
    st = cfg.pixel_stride
    v, u = np.mgrid[0:h:st, 0:w:st]
    di = np.asarray(capture.depth[i], np.float64)[::st, ::st]
    ok = np.isfinite(di) & (di > 0) & (di < cfg.max_depth_m)
    conf = capture.confidence if capture.confidence is not None and cfg.min_confidence > 0 else None
    if conf is not None:
        ok &= np.asarray(conf[i])[::st, ::st] >= cfg.min_confidence
    u, v, di = u[ok].astype(np.float64), v[ok].astype(np.float64), di[ok]
    ri, ci = poses[i][:3, :3], poses[i][:3, 3]
    rj, cj = poses[j][:3, :3], poses[j][:3, 3]
    ray_i = np.stack([(u - ki[2]) / ki[0], (v - ki[3]) / ki[1], np.ones_like(u)], -1) @ ri.T
    y = (ci + (a * di + b)[:, None] * ray_i - cj) @ rj
    z = y[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uj, vj = kj[0] * y[:, 0] / z + kj[2], kj[1] * y[:, 1] / z + kj[3]
    inb = (z > 0.1) & (uj >= 2) & (uj < w - 3) & (vj >= 2) & (vj < h - 3)
    uu, vv = uj[inb], vj[inb]
    dj_map = np.asarray(capture.depth[j], np.float64)
    if conf is not None:
        dj_map = np.where(np.asarray(conf[j]) >= cfg.min_confidence, dj_map, np.nan)  # NaN drops the sample
    u0, v0 = np.floor(uu).astype(int), np.floor(vv).astype(int)
    fu, fv = uu - u0, vv - v0
    q = np.stack([dj_map[v0, u0], dj_map[v0, u0 + 1], dj_map[v0 + 1, u0], dj_map[v0 + 1, u0 + 1]], 1)
    dj = q[:, 0] * (1 - fu) * (1 - fv) + q[:, 1] * fu * (1 - fv) + q[:, 2] * (1 - fu) * fv + q[:, 3] * fu * fv
    with np.errstate(invalid="ignore"):
        edge = ~((np.max(q, 1) - np.min(q, 1)) <= cfg.edge_m)
    # Normals of frame j's calibrated depth, smoothed over 5 x 5 pixels (the noise tilts them otherwise).
    zs = cv2.blur(np.nan_to_num(a * dj_map + b).astype(np.float32), (5, 5)).astype(np.float64)
    n_cam = _normals(np.where(np.isfinite(dj_map), zs, np.nan), kj)[np.round(vv).astype(int), np.round(uu).astype(int)]
    ray_c = np.stack([(uu - kj[2]) / kj[0], (vv - kj[3]) / kj[1], np.ones_like(uu)], -1)
    facing = np.abs(np.sum(n_cam * ray_c, 1)) / np.linalg.norm(ray_c, axis=1)
    good = np.isfinite(dj) & ~edge & np.all(np.isfinite(n_cam), 1) & (np.nan_to_num(facing) > cfg.min_facing_cos)
    idx = np.nonzero(inb)[0][good]
    n = n_cam[good] @ rj.T
    ray_j = ray_c[good] @ rj.T
    c0 = n @ (ci - cj)
    ca = np.sum(n * (di[idx, None] * ray_i[idx] - dj[good, None] * ray_j), 1)
    cb = np.sum(n * (ray_i[idx] - ray_j), 1)
    return c0, ca, cb, di[idx]


def estimate_depth_calibration(
    capture: Capture, world_from_camera: np.ndarray | None = None, config: DepthCalibrationConfig = DepthCalibrationConfig()
) -> DepthCalibration:
    """The sensor's depth error, from how its frames' depth disagree at their poses.

    Each frame's depth, placed in the world by its pose, should lie on the surfaces the other
    frames' depth shows. A depth error ``measured = s * true + o`` moves every surface along each
    camera's rays by an amount that depends on that camera's distance to it, so frames taken from
    different places disagree, and ``(s, o)`` are what makes them agree. For frame pairs ``(i,
    i + gap)``, each point of frame ``i`` is projected into frame ``j``, where frame ``j``'s depth
    there (bilinear) and its surface normal give a point-to-plane residual. With ``true = a *
    measured + b`` the residual is ``c0 + a ca + b cb``, linear in ``(a, b)``; dividing by ``a``
    leaves the noisy depths in one term only, ``s c0 + (b / a) cb + ca``, which least squares in
    ``(s, b / a)`` then fits without the shrinkage that noise in a regressor causes (with 9 mm of
    depth noise at 2 m, solving for ``(a, b)`` directly made an exact sensor look 2 % long).
    Tukey weights drop occlusions and moved objects; the association is redone at each estimate.

    The poses must be metric and locally consistent (a recording's own ARKit poses); their errors
    bias the result (3 mm / 3 mrad of jitter per frame: about 1 % of scale).

    Raises:
        InputError: too few frames or overlapping points to estimate anything, or poses of the
            wrong shape.
    """
    poses = np.asarray(capture.world_from_camera if world_from_camera is None else world_from_camera, np.float64)
    t_count = capture.num_frames
    if poses.shape != (t_count, 4, 4):
        raise InputError(f"estimate_depth_calibration: poses have shape {poses.shape}; expected ({t_count}, 4, 4).")
    pairs = [(i, i + g) for g in config.frame_gaps for i in range(t_count) if i + g < t_count]
    if not pairs:
        raise InputError(
            f"estimate_depth_calibration: a recording of {t_count} frames has no frame pairs {config.frame_gaps} apart; "
            "record a longer sweep, or lower the frame gaps."
        )
    a, b, spread, count = 1.0, 0.0, float("nan"), 0
    blocks = config.jackknife_blocks
    for _ in range(config.iterations):
        terms = [_pair_terms(capture, poses, i, j, a, b, config) for i, j in pairs]
        block = np.concatenate([np.full(len(t[0]), (i * blocks) // t_count) for t, (i, _) in zip(terms, pairs, strict=True)])
        c0 = np.concatenate([t[0] for t in terms])
        ca = np.concatenate([t[1] for t in terms])
        cb = np.concatenate([t[2] for t in terms])
        depths = np.concatenate([t[3] for t in terms])
        if len(c0) < 100:
            raise InputError(
                f"estimate_depth_calibration: only {len(c0)} points of the recording's frames overlap; the depth "
                "calibration needs frames that see the same surfaces from different places."
            )
        x = np.stack([c0, cb], 1)
        s_cur, ba_cur = 1.0 / a, b / a
        r = x @ np.array([s_cur, ba_cur]) + ca
        spread = float(1.4826 * np.median(np.abs(r))) + 1e-9
        wts = np.clip(1.0 - (r / (4.685 * spread)) ** 2, 0.0, 1.0) ** 2
        hess = (x * wts[:, None]).T @ x
        if np.linalg.cond(hess) > 1e12:
            raise InputError(
                "estimate_depth_calibration: the frames' viewpoints do not separate a depth scale from an offset "
                "(all surfaces seen from one distance); record the scene from nearer and farther."
            )
        s_new, ba_new = np.linalg.solve(hess, -(x * wts[:, None]).T @ ca)
        a, b = 1.0 / s_new, ba_new / s_new
        count = int(np.count_nonzero(wts > 0))
    # Jackknife over blocks of frames, at the last association and weights.
    drops = []
    for k in np.unique(block):
        keep = block != k
        xk, wk = x[keep], wts[keep]
        hk = (xk * wk[:, None]).T @ xk
        if np.linalg.cond(hk) < 1e12:
            sk, bak = np.linalg.solve(hk, -(xk * wk[:, None]).T @ ca[keep])
            drops.append((sk, -bak))  # the unknowns are (s, b / a) and the offset is -b / a
    scale_se = offset_se = error_se = float("nan")
    z_ref = float(np.median(depths[wts > 0])) if np.any(wts > 0) else float("nan")
    if len(drops) >= 3:
        d = np.asarray(drops)
        n = len(d)
        cov = (n - 1) / n * (d - d.mean(0)).T @ (d - d.mean(0))
        scale_se, offset_se = float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))
        grad = np.array([z_ref, 1.0])
        error_se = float(np.sqrt(max(grad @ cov @ grad, 0.0)))
    return DepthCalibration(
        scale=float(1.0 / a), offset_m=float(-b / a), residual_m=spread, points=count,
        scale_se=scale_se, offset_m_se=offset_se, reference_depth_m=z_ref, error_se_m=error_se,
    )
