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
from artitwin_core.capture._config import DepthCalibrationConfig
from artitwin_core.capture._drift import (
    DriftSignificance,
    FeatureCache,
    PoseDrift,
    block_jackknife_cov,
    depth_at_pixels,
    drift_significance,
    pixel_rays,
    ray_normals,
    sift_matches,
)
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import depth_normals
from artitwin_core.geometry import pixel_rays as camera_rays


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
        drift: the poses' fitted drift (``config.pose_drift``), None when not modelled.
        drift_significance: how far its rate moves a point at ``reference_depth_m`` ahead of the
            first camera by the last frame, with standard errors.
        initial_residual_m: ``residual_m`` before any correction (the depth as measured, the
            poses as recorded).
    """

    scale: float
    offset_m: float
    residual_m: float
    points: int
    scale_se: float = float("nan")
    offset_m_se: float = float("nan")
    reference_depth_m: float = float("nan")
    error_se_m: float = float("nan")
    drift: PoseDrift | None = None
    drift_significance: DriftSignificance | None = None
    initial_residual_m: float = float("nan")


# ``DepthCalibrationConfig.step_tolerance_m`` measures a step at this distance from the camera.
_TOLERANCE_REACH_M = 2.0


def _target_maps(capture: Capture, j: int, a: float, b: float, cfg: DepthCalibrationConfig) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``j`` as the target of :func:`_pair_terms`: its measured depth ``[H, W]`` (NaN where
    its confidence is too low) and the unit normals ``[H, W, 3]`` (camera frame) of its depth at
    the calibration ``true = a * measured + b``, smoothed over 5 x 5 pixels (the noise tilts them
    otherwise). The same for every pair frame ``j`` ends, so :func:`_estimate` computes it once
    per frame and iteration."""
    conf = capture.confidence if capture.confidence is not None and cfg.min_confidence > 0 else None
    kj = np.asarray(capture.depth_intrinsics[j], np.float64)
    dj_map = np.asarray(capture.depth[j], np.float64)
    if conf is not None:
        dj_map = np.where(np.asarray(conf[j]) >= cfg.min_confidence, dj_map, np.nan)  # NaN drops the sample
    zs = cv2.blur(np.nan_to_num(a * dj_map + b).astype(np.float32), (5, 5)).astype(np.float64)
    return dj_map, depth_normals(np.where(np.isfinite(dj_map), zs, np.nan), kj)


def _source_samples(capture: Capture, i: int, cfg: DepthCalibrationConfig) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``i`` as the source of :func:`_pair_terms`: the measured depths ``[N]`` of its
    usable pixels (every ``pixel_stride``-th, in range, confident enough) and their rays ``[N, 3]``
    in its camera frame. They depend on nothing that changes between iterations."""
    ki = np.asarray(capture.depth_intrinsics[i], np.float64)
    h, w = capture.depth.shape[1:]
    st = cfg.pixel_stride
    v, u = np.mgrid[0:h:st, 0:w:st]
    di = np.asarray(capture.depth[i], np.float64)[::st, ::st]
    ok = np.isfinite(di) & (di > 0) & (di < cfg.max_depth_m)
    conf = capture.confidence if capture.confidence is not None and cfg.min_confidence > 0 else None
    if conf is not None:
        ok &= np.asarray(conf[i])[::st, ::st] >= cfg.min_confidence
    u, v, di = u[ok].astype(np.float64), v[ok].astype(np.float64), di[ok]
    return di, camera_rays(ki, u, v)


def _pair_terms(capture: Capture, poses: np.ndarray, i: int, j: int, a: float, b: float, cfg: DepthCalibrationConfig,
                target: tuple[np.ndarray, np.ndarray] | None = None, source: tuple[np.ndarray, np.ndarray] | None = None):
    """Point-to-plane terms of frame ``i``'s depth against frame ``j``'s at the current
    calibration ``true = a * measured + b``: ``(c0, ca, cb, depth, points, normals)`` with residual
    ``c0 + a ca + b cb``, the measured depths of the points of frame ``i``, the points ``[N, 3]`` in
    the world and frame ``j``'s surface normals ``[N, 3]`` there. ``target``: frame ``j``'s
    :func:`_target_maps` at ``(a, b)``, ``source``: frame ``i``'s :func:`_source_samples`, when
    already computed."""
    kj = np.asarray(capture.depth_intrinsics[j], np.float64)
    h, w = capture.depth.shape[1:]
    di, rays = _source_samples(capture, i, cfg) if source is None else source
    ri, ci = poses[i][:3, :3], poses[i][:3, 3]
    rj, cj = poses[j][:3, :3], poses[j][:3, 3]
    ray_i = rays @ ri.T
    y = (ci + (a * di + b)[:, None] * ray_i - cj) @ rj
    z = y[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uj, vj = kj[0] * y[:, 0] / z + kj[2], kj[1] * y[:, 1] / z + kj[3]
    inb = (z > 0.1) & (uj >= 2) & (uj < w - 3) & (vj >= 2) & (vj < h - 3)
    uu, vv = uj[inb], vj[inb]
    dj_map, n_map = _target_maps(capture, j, a, b, cfg) if target is None else target
    u0, v0 = np.floor(uu).astype(int), np.floor(vv).astype(int)
    fu, fv = uu - u0, vv - v0
    q = np.stack([dj_map[v0, u0], dj_map[v0, u0 + 1], dj_map[v0 + 1, u0], dj_map[v0 + 1, u0 + 1]], 1)
    dj = q[:, 0] * (1 - fu) * (1 - fv) + q[:, 1] * fu * (1 - fv) + q[:, 2] * (1 - fu) * fv + q[:, 3] * fu * fv
    with np.errstate(invalid="ignore"):
        edge = ~((np.max(q, 1) - np.min(q, 1)) <= cfg.edge_m)
    n_cam = n_map[np.round(vv).astype(int), np.round(uu).astype(int)]
    ray_c = np.stack([(uu - kj[2]) / kj[0], (vv - kj[3]) / kj[1], np.ones_like(uu)], -1)
    facing = np.abs(np.sum(n_cam * ray_c, 1)) / np.linalg.norm(ray_c, axis=1)
    good = np.isfinite(dj) & ~edge & np.all(np.isfinite(n_cam), 1) & (np.nan_to_num(facing) > cfg.min_facing_cos)
    idx = np.nonzero(inb)[0][good]
    n = n_cam[good] @ rj.T
    ray_j = ray_c[good] @ rj.T
    c0 = n @ (ci - cj)
    ca = np.sum(n * (di[idx, None] * ray_i[idx] - dj[good, None] * ray_j), 1)
    cb = np.sum(n * (ray_i[idx] - ray_j), 1)
    points = ci + (a * di[idx] + b)[:, None] * ray_i[idx]
    return c0, ca, cb, di[idx], points, n


def _feature_terms(
    capture: Capture, poses: np.ndarray, i: int, j: int, pi: np.ndarray, pj: np.ndarray, a: float, b: float,
    cfg: DepthCalibrationConfig,
):
    """Reprojection terms of matched pixels ``pi`` (frame ``i``, lifted by its depth) against the
    rays of ``pj`` (frame ``j``): the point's distance from the ray in two directions across it,
    ``c0 + a ca + b cb`` as in :func:`_pair_terms`; with the points and the directions."""
    d = depth_at_pixels(capture, i, pi, cfg.edge_m, cfg.min_confidence)
    ok = np.isfinite(d) & (d > 0) & (d < cfg.max_depth_m)
    if not np.any(ok):
        return None
    pi, pj, d = pi[ok], pj[ok], d[ok]
    ci, cj = poses[i][:3, 3], poses[j][:3, 3]
    ray_i = pixel_rays(capture.rgb_intrinsics[i], pi, poses[i])
    ray_j = pixel_rays(capture.rgb_intrinsics[j], pj, poses[j])
    points = ci + (a * d + b)[:, None] * ray_i
    out = []
    for m in ray_normals(ray_j):
        out.append((m @ (ci - cj), d * np.sum(m * ray_i, 1), np.sum(m * ray_i, 1), d, points, m))
    return tuple(np.concatenate([o[k] for o in out]) for k in range(6))


def estimate_depth_calibration(
    capture: Capture, world_from_camera: np.ndarray | None = None, config: DepthCalibrationConfig = DepthCalibrationConfig(),
    halves_gate: tuple[float, float] | None = None,
) -> DepthCalibration:
    """The sensor's depth error, from how its frames' depth disagree at their poses; with
    ``config.pose_drift``, the poses' linear drift with it.

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

    A drift (``config.pose_drift``) adds four unknowns, the yaw rate about gravity and the
    translation rate, linearised about the current poses (each frame's correction moves a point
    ``X`` by ``dt (w x (X - pivot) + v)`` relative to the other frame's). Depth alone cannot see
    a drift along a wall, so SIFT matches between frames add reprojection terms of the same form
    (a lifted keypoint's distance from its match's ray).

    The poses must be metric and locally consistent (a recording's own ARKit poses); their errors
    bias the result (3 mm / 3 mrad of jitter per frame: about 1 % of scale).

    ``halves_gate``: ``(min_displacement_m, min_z)`` of ``DriftSignificance.why_not``: the halves
    are fitted only for a drift that passes these first two tests (one that fails them is refused
    whatever its halves say, and the halves cost half the fit again); their rates stay None.

    Raises:
        InputError: too few frames or overlapping points to estimate anything, or poses of the
            wrong shape.
    """
    cal = _estimate(capture, world_from_camera, config)
    if cal.drift is None or capture.num_frames < 2 * max(config.frame_gaps) + 2:
        return cal
    if halves_gate is not None and cal.drift_significance is not None:
        sig = cal.drift_significance
        if sig.size_m < halves_gate[0] or not sig.z_score >= halves_gate[1]:
            return cal
    # The drift seen by each half of the recording alone: a linear drift is the same in both.
    poses = np.asarray(capture.world_from_camera if world_from_camera is None else world_from_camera, np.float64)
    half = capture.num_frames // 2
    rates = []
    for part in (slice(0, half), slice(half, None)):
        try:
            fit = _estimate(capture.select_frames(part), poses[part], config)
        except InputError:
            return cal  # too little overlap within a half: the check is skipped
        rates.append(fit.drift.rate_at(cal.drift_significance.point))
    return dataclasses.replace(
        cal, drift_significance=dataclasses.replace(cal.drift_significance, half_rates_m_per_s=np.stack(rates))
    )


def _estimate(capture: Capture, world_from_camera: np.ndarray | None, config: DepthCalibrationConfig) -> DepthCalibration:
    recorded = np.asarray(capture.world_from_camera if world_from_camera is None else world_from_camera, np.float64)
    t_count = capture.num_frames
    if recorded.shape != (t_count, 4, 4):
        raise InputError(f"estimate_depth_calibration: poses have shape {recorded.shape}; expected ({t_count}, 4, 4).")
    if not (config.estimate_depth or config.pose_drift):
        raise InputError("estimate_depth_calibration: nothing to estimate (estimate_depth and pose_drift both off).")
    pairs = [(i, i + g) for g in config.frame_gaps for i in range(t_count) if i + g < t_count]
    if not pairs:
        raise InputError(
            f"estimate_depth_calibration: a recording of {t_count} frames has no frame pairs {config.frame_gaps} apart; "
            "record a longer sweep, or lower the frame gaps."
        )
    ts = np.asarray(capture.timestamps, np.float64)
    gravity = np.asarray(config.gravity, np.float64)
    gravity = gravity / np.linalg.norm(gravity)
    drift = PoseDrift(pivot=recorded[0, :3, 3].copy(), t0_s=float(ts[0])) if config.pose_drift else None
    matches = {}
    if config.pose_drift:
        if ts[-1] - ts[0] <= 0:
            raise InputError("estimate_depth_calibration: the pose drift needs increasing timestamps; they span 0 s.")
        features = FeatureCache(capture.rgb)
        for g in config.feature_gaps:
            for i in range(t_count - g):
                pi, pj = sift_matches(features(i), features(i + g))
                if len(pi):
                    matches[(i, i + g)] = (pi, pj)
    n_depth = 2 if config.estimate_depth else 0
    a, b, spread, count, initial = 1.0, 0.0, float("nan"), 0, float("nan")
    blocks = config.jackknife_blocks
    samples = {i: _source_samples(capture, i, config) for i in sorted({i for i, _ in pairs})}
    for _ in range(config.iterations):
        poses = drift.apply(recorded, ts) if drift is not None else recorded
        targets = {j: _target_maps(capture, j, a, b, config) for j in sorted({j for _, j in pairs})}
        sources = [([_pair_terms(capture, poses, i, j, a, b, config, targets[j], samples[i]) for i, j in pairs], pairs)]
        del targets
        if matches:
            found = [(_feature_terms(capture, poses, i, j, pi, pj, a, b, config), (i, j)) for (i, j), (pi, pj) in matches.items()]
            found = [(t, p) for t, p in found if t is not None]
            sources.append(([t for t, _ in found], [p for _, p in found]))
        hess, grad, rows = 0.0, 0.0, []
        if len(sources) == 2 and sum(len(t[0]) for t in sources[1][0]) < 100:
            sources.pop()  # too few keypoint terms to weigh robustly: depth alone
        for terms, which in sources:
            c0, ca, cb, depths, points, normals = (np.concatenate([t[k] for t in terms]) for k in range(6))
            if len(c0) < 100 and not rows:
                raise InputError(
                    f"estimate_depth_calibration: only {len(c0)} points of the recording's frames overlap; the depth "
                    "calibration needs frames that see the same surfaces from different places."
                )
            dt = np.concatenate([np.full(len(t[0]), ts[i] - ts[j]) for t, (i, j) in zip(terms, which, strict=True)])
            block = np.concatenate([np.full(len(t[0]), (i * blocks) // t_count) for t, (i, _) in zip(terms, which, strict=True)])
            cols = []
            if config.estimate_depth:
                cols += [c0, cb]
                rhs = ca
                cur = [1.0 / a, b / a]
            else:
                rhs = c0 / a + ca + (b / a) * cb
                cur = []
            if drift is not None:
                rel = points - drift.pivot
                cols += [dt * (np.cross(rel, normals) @ gravity)] + [dt * normals[:, k] for k in range(3)]
                cur += [0.0] * 4
            x = np.stack(cols, 1)
            r = x @ np.asarray(cur) + rhs
            src_spread = float(1.4826 * np.median(np.abs(r))) + 1e-9
            if not rows:
                spread = src_spread  # the depth terms' spread: the residual reported
                if np.isnan(initial):
                    initial = spread  # ... and before any correction
            wts = np.clip(1.0 - (r / (4.685 * src_spread)) ** 2, 0.0, 1.0) ** 2 / src_spread**2
            hess = hess + (x * wts[:, None]).T @ x
            grad = grad + (x * wts[:, None]).T @ rhs
            rows.append((x, wts, rhs, block, depths))
        if config.estimate_depth and np.linalg.cond(hess[:2, :2]) > 1e12:
            raise InputError(
                "estimate_depth_calibration: the frames' viewpoints do not separate a depth scale from an offset "
                "(all surfaces seen from one distance); record the scene from nearer and farther."
            )
        sol = np.linalg.solve(hess, -grad)
        moved = 0.0  # how far this step moves the answer, metres (step_tolerance_m)
        if config.estimate_depth:
            a_new, b_new = 1.0 / sol[0], sol[1] / sol[0]
            moved = abs((a_new - a) * _TOLERANCE_REACH_M + (b_new - b))
            a, b = a_new, b_new
        if drift is not None:
            step = a * sol[n_depth:]
            drift = PoseDrift(
                pivot=drift.pivot, t0_s=drift.t0_s,
                rot_rate_rad_per_s=drift.rot_rate_rad_per_s + step[0] * gravity,
                trans_rate_m_per_s=drift.trans_rate_m_per_s + step[1:4],
            )
            moved = max(moved, float(ts[-1] - ts[0]) * (abs(step[0]) * _TOLERANCE_REACH_M + float(np.linalg.norm(step[1:4]))))
        count = int(sum(np.count_nonzero(w > 0) for _, w, _, _, _ in rows))
        if moved < config.step_tolerance_m:
            break
    # Jackknife over blocks of frames, at the last association and weights (the solution there is
    # the last step; each drop's is compared with it).
    cov = block_jackknife_cov(*(np.concatenate([r[k] for r in rows]) for k in range(4)))
    depths = rows[0][4][rows[0][1] > 0]
    z_ref = float(np.median(depths)) if len(depths) else float("nan")
    scale_se = offset_se = error_se = float("nan")
    rate_cov = None
    if cov is not None:
        if config.estimate_depth:
            # the unknowns are (s, b / a) and the offset is -b / a
            scale_se, offset_se = float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))
            grad_e = np.array([z_ref, -1.0])
            error_se = float(np.sqrt(max(grad_e @ cov[:2, :2] @ grad_e, 0.0)))
        if drift is not None:
            rate_cov = a**2 * cov[n_depth:, n_depth:]
    significance = None
    if drift is not None:
        ahead = recorded[0, :3, 3] + (z_ref if np.isfinite(z_ref) else 2.0) * recorded[0, :3, 2]
        significance = drift_significance(drift, ahead, float(ts[-1]), rate_cov, yaw_axis=gravity)
    return DepthCalibration(
        scale=float(1.0 / a), offset_m=float(-b / a), residual_m=spread, points=count,
        scale_se=scale_se, offset_m_se=offset_se, reference_depth_m=z_ref, error_se_m=error_se,
        drift=drift, drift_significance=significance, initial_residual_m=initial,
    )

