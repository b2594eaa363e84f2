"""A fit made a :class:`Joint` (step 5 of ``estimate_joint``).

The fit is re-gauged so that ``q = 0`` at the reference frame, its pivot is moved to the point of
the axis line closest to the part's centroid, and the axis is flipped so that the largest ``|q|``
is positive. Per-frame confidence comes from the standard error of ``q_t`` (noise over the lever
arm of the inliers) and the frame's residual; only frames below ``smooth_below_confidence`` are
replaced by a zero-phase local quadratic fit of their neighbours (no lag, and confident frames keep
their unbiased least-squares value: smoothing them would only flatten turning points).
"""

from __future__ import annotations

import numpy as np

from artitwin_core.joints._config import JointFitConfig
from artitwin_core.joints._fit import _Fit, _motions, _predict
from artitwin_core.joints._model import joint_motion
from artitwin_core.joints._types import Joint


def _confidence(fit: _Fit, kind: str, sigma_glob: float, cfg: JointFitConfig, rms: np.ndarray):
    t_count = fit.q.shape[0]
    conf = np.zeros(t_count)
    if kind == "fixed":
        return np.where(np.isfinite(rms), 1.0, 0.0)
    if kind == "prismatic":
        lever2 = np.ones(fit.points.shape[0])
        tol = cfg.q_tolerance_m
    else:
        arm = np.cross(fit.axis, fit.points - fit.pivot) + fit.pitch * fit.axis
        lever2 = np.sum(arm**2, axis=-1)
        tol = cfg.q_tolerance_rad
    info = fit.weights @ np.nan_to_num(lever2)
    for t in range(t_count):
        if not np.isfinite(fit.q[t]) or info[t] <= 0 or not np.isfinite(rms[t]):
            continue
        se = fit.sigma_t[t] / np.sqrt(info[t])
        # RMS of a 3D residual is sqrt(3) sigma under the noise model; allow up to sqrt(6) sigma.
        gof = min(1.0, 6.0 * max(sigma_glob, cfg.noise_floor_m) ** 2 / max(rms[t] ** 2, 1e-300))
        conf[t] = gof / (1.0 + (se / tol) ** 2)
    return conf


def _smooth_low_confidence(q: np.ndarray, conf: np.ndarray, ref: int, cfg: JointFitConfig) -> np.ndarray:
    """Zero-phase local quadratic fit, confidence-weighted, applied only to low-confidence frames.

    A centred window has no lag (unlike a causal filter); confident frames keep their unbiased
    least-squares value; the reference frame is ``q = 0`` by definition and is never changed.
    """
    out = q.copy()
    h = cfg.smoothing_half_window
    t_count = q.shape[0]
    ok = np.isfinite(q) & (conf > 0)
    for t in range(t_count):
        if t == ref or (ok[t] and conf[t] >= cfg.smooth_below_confidence):
            continue
        lo, hi = max(0, t - h), min(t_count, t + h + 1)
        s = np.arange(lo, hi)
        sel = ok[s]
        if sel.sum() < 2:
            continue
        s = s[sel]
        kernel = (1 - (np.abs(s - t) / (h + 1)) ** 3) ** 3
        w = conf[s] * kernel
        deg = 2 if len(s) >= 4 else 1
        if len(np.unique(s)) <= deg:
            deg = len(np.unique(s)) - 1
        coef = np.polyfit(s - t, q[s], deg, w=np.sqrt(w))
        out[t] = coef[-1]
    return out


def _finalize(fit: _Fit, ref: int, y, sigma_glob, cfg: JointFitConfig) -> tuple[Joint, np.ndarray]:
    """Gauge q(ref) = 0, pivot nearest the centroid, positive opening, confidence, smoothing."""
    kind = fit.kind
    t_count = fit.q.shape[0]
    axis = fit.axis / np.linalg.norm(fit.axis)
    pivot = fit.pivot
    q = fit.q.copy()
    points = fit.points.copy()
    if kind != "fixed":
        q_ref = q[ref] if np.isfinite(q[ref]) else 0.0
        rot_ref, trans_ref = joint_motion(kind, axis, pivot, np.array([q_ref]), fit.pitch)
        points = points @ rot_ref[0].T + trans_ref[0]
        q = q - q_ref
        if kind == "revolute":
            # An angle and the same angle +- 2 pi are one pose: a per-frame angle near -pi against a
            # reference near +pi must read as a small turn, not as ~2 pi (a door's range of 356 deg).
            q = np.where(np.isfinite(q), np.mod(q + np.pi, 2.0 * np.pi) - np.pi, q)
    part = fit.track_ok
    centroid = points[part].mean(0) if part.any() else np.nanmean(points, 0)
    pivot = pivot + ((centroid - pivot) @ axis) * axis
    if kind == "fixed":
        axis = np.array([0.0, 0.0, 1.0])
        pivot = centroid
        q = np.where(np.isfinite(q), 0.0, np.nan)
    elif np.any(np.isfinite(q)):
        k = int(np.nanargmax(np.abs(q)))
        if q[k] < 0:
            axis, q = -axis, -q
    fit2 = _Fit(kind, axis, pivot, fit.pitch, q, points, fit.weights, fit.track_ok, fit.sigma_t,
                fit.axis_se, fit.pivot_se)
    rms = _frame_rms(fit2, y)
    conf = _confidence(fit2, kind, sigma_glob, cfg, rms)
    conf[ref] = 1.0  # q(ref) = 0 by definition
    q_s = _smooth_low_confidence(q, conf, ref, cfg) if kind != "fixed" else np.where(np.isfinite(q), 0.0, q)
    if kind == "fixed":
        q_s = np.zeros(t_count)
    elif np.any(~np.isfinite(q_s)):
        good = np.isfinite(q_s)
        q_s = (
            np.interp(np.arange(t_count), np.nonzero(good)[0], q_s[good]) if good.any() else np.zeros(t_count)
        )
    fit2.q = q_s
    rms = _frame_rms(fit2, y)
    finite = q_s[np.isfinite(q_s)]
    q_range = np.array([finite.min(), finite.max()]) if finite.size else np.zeros(2)
    joint = Joint(
        joint_type=kind,
        axis=axis,
        pivot=pivot,
        q=q_s,
        q_range=q_range,
        residual=rms,
        confidence=conf,
        pitch=float(fit.pitch) if kind == "screw" else 0.0,
        axis_se_rad=fit.axis_se,
        pivot_se_m=fit.pivot_se,
    )
    return joint, points


def _frame_rms(fit: _Fit, y) -> np.ndarray:
    rot, trans = _motions(fit.kind, fit.axis, fit.pivot, fit.q, fit.pitch)
    d2 = np.sum((_predict(rot, trans, fit.points) - y) ** 2, axis=-1)
    use = (fit.weights > 0) & np.isfinite(fit.q)[:, None]
    n = use.sum(1)
    s = np.where(use, d2, 0.0).sum(1)
    return np.where(n > 0, np.sqrt(s / np.maximum(n, 1)), np.nan)
