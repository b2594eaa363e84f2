"""Per-frame corrections of a recording's poses, measured on its own static background.

Recorded poses (ARKit's visual-inertial odometry) jitter from frame to frame by millimetres and
milliradians. A part's tracks are lifted with those poses, so the jitter lands on the joint: at
3 mm / 3 mrad per frame a door's pivot line comes out several times farther off than with the
true poses (docs/accuracy.md).

Everything outside the parts and the hand is static, so any motion of it between two frames'
lifted depth is pose error. Keyframes every ``keyframe_step`` frames are models (their static
pixels lifted with depth, with grey levels); every frame within ``reach`` of a keyframe is aligned
to it by the model tracker's Gauss-Newton (point-to-plane depth plus grey levels under an affine
exposure model, ``_model_track``), which measures ``log(E_t E_k^-1) ~ e_t - e_k`` for the frames'
pose errors ``E = exp(e)`` (``recorded = E @ true``). The errors are the robust least-squares
solution of all those measurements with their mean held at zero (the registration owns where the
recording sits as a whole). Each frame is measured against two to four keyframes, so errors do not
pile up along the recording as chained odometry's do (fusing such frame-to-frame odometry bent the
hinge: its errors are correlated along the arc the door turns through).

What to apply is decided by three tests, since the grey levels also move with things that are
not pose error:
- The measurements' scatter about the solution gives the corrections' standard errors. Their
  frame-to-frame part (the corrections less a straight line in time over ``slow_frames``) must
  stand out from them (``min_chi2_per_dof``): real jitter stands out by two orders of
  magnitude more than exact poses do, with or without sensor defects.
- A slow error is left alone: an undeclared lens, a depth bias, vignetting or a rolling shutter
  "correct" exact poses by 2-3 mm, smoothly along the camera path, and drift has its own effect
  (``pose_drift``). Only corrections that change from frame to frame as much as white noise
  does (``min_whiteness``) are applied whole; otherwise only their frame-to-frame part (with a
  depth bias and an undeclared lens as well, applying everything made the error larger).
- Depth must agree (``min_depth_agreement``). Depth and pose are sampled together, so a real
  pose error misaligns depth as it does the grey levels; an RGB image exposed 33 ms before its
  depth and pose shows the camera's shake as frame-to-frame "jitter" that depth disagrees with
  (z = -13 against +10 for real jitter).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.tracking._config import FramePoseConfig
from artitwin_core.tracking._flow import to_gray
from artitwin_core.tracking._model_track import (
    RigidParams,
    _align_levels,
    _bilinear,
    _evaluate,
    _Frame,
    _normals,
    _patches,
    _seen_points,
)


@dataclass(frozen=True)
class FramePoseFit:
    """Per-frame pose corrections of a recording: ``corrected[t] = corrections[t] @ recorded[t]``.

    Attributes:
        corrections: ``[T, 4, 4]`` the rigid motions to apply, in the recording's own world frame
            (the part of the fitted ones that ``applied`` says; identity when none).
        fitted: ``[T, 4, 4]`` the corrections as fitted, whether applied or not.
        pivot: ``[3]`` the point the corrections' rotations are taken about (the first keyframe's
            static centroid), metres.
        rotation_rad, translation_m: ``[T, 3]`` each frame's fitted correction: rotation vector
            and the translation of ``pivot``.
        rotation_se_rad, translation_se_m: ``[T]`` their standard errors (root mean square over
            the three components); inf where no alignment reached the frame.
        pairs: alignments tried; ``pairs_used``: those that passed the checks and were not
            down-weighted as outliers.
        measured: ``[T]`` bool, frames reached by at least one used alignment.
        scatter: ``[6]`` the used alignments' spread about the solution (rotation radians,
            translation metres).
        chi2_per_dof: the fitted corrections against their standard errors, per degree of freedom.
        fast_chi2_per_dof: the same for their frame-to-frame part (the corrections less a
            straight line in time over ``slow_frames`` frames around each frame).
        whiteness: how much the corrections change from one frame to the next against how much
            they vary overall (1 for white noise such as jitter, ~0 for a slow error).
        depth_agreement: how much better the frames' depth agrees at the corrected poses than
            at the recorded ones, as a z-score (``_depth_agreement``; 0 when nothing passed the
            other tests, so it was not measured).
        applied: ``"all"`` (the frame-to-frame part is significant and the corrections look
            white), ``"frame-to-frame"`` (it is significant, but a slow part that looks like a
            model defect is left alone) or ``"none"``.
    """

    corrections: np.ndarray
    fitted: np.ndarray
    pivot: np.ndarray
    rotation_rad: np.ndarray
    translation_m: np.ndarray
    rotation_se_rad: np.ndarray
    translation_se_m: np.ndarray
    pairs: int
    pairs_used: int
    measured: np.ndarray
    scatter: np.ndarray
    chi2_per_dof: float
    fast_chi2_per_dof: float
    whiteness: float
    depth_agreement: float
    applied: str

    @property
    def significant(self) -> bool:
        """Whether any part of the corrections is applied."""
        return self.applied != "none"

    def apply(self, world_from_camera: np.ndarray) -> np.ndarray:
        """``[T, 4, 4]`` poses corrected (unchanged where the corrections are not significant)."""
        return np.einsum("tij,tjk->tik", self.corrections, np.asarray(world_from_camera, dtype=np.float64))


def _log(motion: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """``[6]`` rotation vector and the translation ``motion`` gives ``pivot``."""
    rot = motion[:3, :3]
    return np.r_[Rotation.from_matrix(rot).as_rotvec(), rot @ pivot + motion[:3, 3] - pivot]


def _exp(v: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """Inverse of ``_log``: the rigid motion turning by ``v[:3]`` about ``pivot`` and moving it by ``v[3:]``."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(v[:3]).as_matrix()
    out[:3, 3] = v[3:] + pivot - out[:3, :3] @ pivot
    return out


def _validate(capture: Capture, part: np.ndarray, hand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    shape = capture.rgb.shape[:3]
    part = np.asarray(part)
    hand = np.asarray(hand, dtype=bool)
    if part.shape != shape or hand.shape != shape:
        raise InputError(
            f"frame pose correction: part masks {part.shape} and hand masks {hand.shape} must both match the "
            f"recording's RGB frames {shape} (one mask per frame at RGB resolution)."
        )
    return part, hand


def _measure(
    capture: Capture, depth: np.ndarray, moving: np.ndarray, excluded: np.ndarray, cfg: FramePoseConfig
):
    """Every keyframe-to-frame alignment: ``(pivot, [(t, k, v [6], usable)], {k: (points [M, 3],
    normals [M, 3])})``, the last the keyframes' models."""
    t_count = capture.num_frames
    poses = np.asarray(capture.world_from_camera, dtype=np.float64)
    params = RigidParams(max_model_points=cfg.model_points)
    keys = sorted(set(range(0, t_count, cfg.keyframe_step)) | {t_count - 1})
    rng = np.random.default_rng(0)
    pivot = None
    out = []
    models = {}
    for k in keys:
        allowed_k = ~excluded[k]
        xq = _seen_points(
            depth[k], allowed_k, poses[k], capture.rgb_intrinsics[k], capture.depth_intrinsics[k], 10**7
        )
        if xq.shape[0] < params.min_points:
            continue
        if xq.shape[0] > cfg.model_points:
            xq = xq[rng.choice(xq.shape[0], cfg.model_points, replace=False)]
        if pivot is None:
            pivot = xq.mean(0)
        nq = _normals(xq)
        flip = np.sum(nq * (poses[k][:3, 3] - xq), axis=1) < 0
        nq[flip] *= -1
        models[k] = (xq, nq)
        gray = to_gray(capture.rgb, k)  # each frame's grey levels scaled to the keyframe's exposure
        key_frame = _Frame(gray[k], depth[k], allowed_k, poses[k], capture.rgb_intrinsics[k],
                           capture.depth_intrinsics[k], params.blur_sigmas, moving[k])  # fmt: skip
        pc = xq @ key_frame.cam_from_world[:3, :3].T + key_frame.cam_from_world[:3, 3]
        fx, fy, cx, cy = capture.rgb_intrinsics[k]
        uq, vq = fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy
        grey_levels = [np.nan_to_num(_bilinear(img, uq, vq)) for img, _, _ in key_frame.levels]
        patches = _patches(uq, vq, params.patch_px)
        for t in range(max(0, k - cfg.reach), min(t_count, k + cfg.reach + 1)):
            if t == k:
                continue
            frame = _Frame(gray[t], depth[t], ~excluded[t], poses[t], capture.rgb_intrinsics[t],
                           capture.depth_intrinsics[t], params.blur_sigmas, moving[t])  # fmt: skip
            motion, cost, frac, _, ncc = _align_levels(frame, np.eye(4), xq, nq, grey_levels, params, patches)
            v = _log(motion, pivot)
            usable = bool(
                np.isfinite(cost)
                and np.isfinite(ncc)  # NaN: a background without texture; depth alone cannot pin it
                and ncc >= cfg.min_ncc
                and frac >= cfg.min_inlier_fraction
                and np.linalg.norm(v[:3]) <= cfg.max_rotation_rad
                and np.linalg.norm(v[3:]) <= cfg.max_translation_m
            )
            out.append((t, k, v, usable))
    return pivot, out, models


def _depth_agreement(capture, depth, excluded, models, pairs, corrections: np.ndarray) -> float:
    """How much better the frames' depth agrees with the keyframes' at the corrected poses than at
    the recorded ones: the mean over ``pairs [(t, k)]`` of the drop in robust mean squared
    point-to-plane distance, over its standard error (a z-score; positive: better).

    Depth and pose are sampled together, so a real pose error shows in depth as it does in the
    grey levels. An RGB image exposed at another time than its depth and pose (a lag, a rolling
    shutter) or an undeclared lens moves only the grey levels: the alignments then report
    corrections that depth disagrees with.
    """
    poses = np.asarray(capture.world_from_camera, dtype=np.float64)
    blank = np.zeros(capture.rgb.shape[1:3], np.uint8)
    gain = np.array([1.0, 0.0])
    drops = []
    for t, k in pairs:
        xq, nq = models[k]
        frame = _Frame(blank, depth[t], ~excluded[t], poses[t], capture.rgb_intrinsics[t],
                       capture.depth_intrinsics[t], (0.0,))  # fmt: skip
        tq = np.zeros(xq.shape[0])
        r0, _, _, _, ok0, _, _ = _evaluate(frame, 0, np.eye(4), xq, nq, tq, gain, False)
        motion = np.linalg.inv(corrections[t]) @ corrections[k]
        r1, _, _, _, ok1, _, _ = _evaluate(frame, 0, motion, xq, nq, tq, gain, False)
        ok = ok0 & ok1
        if ok.sum() < 50:
            continue
        cap = (3.0 * 1.4826 * np.median(np.abs(r0[ok]))) ** 2
        drops.append(np.mean(np.minimum(r0[ok] ** 2, cap)) - np.mean(np.minimum(r1[ok] ** 2, cap)))
    if len(drops) < 3:
        return 0.0
    drops = np.asarray(drops)
    se = np.std(drops, ddof=1) / np.sqrt(drops.size)
    return float(drops.mean() / se) if se > 0 else 0.0


def _solve(t_count: int, pairs, cfg: FramePoseConfig):
    """Robust least squares of ``e_t - e_k = v`` over the usable pairs, mean of ``e`` zero.

    Returns ``(e [T, 6], se [T, 6], weights [P], scatter [6])``.
    """
    rows = np.zeros((len(pairs), t_count))
    for i, (t, k, _) in enumerate(pairs):
        rows[i, t], rows[i, k] = 1.0, -1.0
    v = np.array([p[2] for p in pairs])
    prior = 1.0 / np.r_[np.full(3, cfg.prior_rotation_rad), np.full(3, cfg.prior_translation_m)] ** 2
    ones = np.ones((t_count, t_count))
    # Per component the problem is the same linear one with its own prior; the pairs' weights are
    # shared (an alignment that failed, failed in every component).
    floor = np.full(6, 1e-4)

    def solve(weights: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(e [T, 6], se [T, 6])`` for the pairs' ``weights [P]`` and per-component ``scale [6]``."""
        h = (rows * weights[:, None]).T @ rows
        b = (rows * weights[:, None]).T @ v
        e, se = np.empty((t_count, 6)), np.empty((t_count, 6))
        for c in range(6):
            a = h / scale[c] ** 2 + prior[c] * np.eye(t_count)
            # The zero mean as a stiff penalty on the sum; the prior keeps every block of frames
            # that no alignment links to the others determined.
            a += 1e3 * np.trace(a) / t_count * ones / t_count
            cov = np.linalg.inv(a)
            e[:, c] = cov @ b[:, c] / scale[c] ** 2
            se[:, c] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        return e, se

    w = np.ones(len(pairs))
    scale = np.full(6, 1e-3)
    for _ in range(10):
        e, se = solve(w, scale)
        r = rows @ e - v
        scale = np.maximum(1.4826 * np.median(np.abs(r), axis=0), floor)
        norm = np.sqrt(np.mean((r / scale) ** 2, axis=1))
        w = 1.0 / (1.0 + (norm / 2.0) ** 2)  # Cauchy: a failed alignment pulls little
    # The spread of the kept alignments about the solution sets the standard errors.
    n_frames = int(np.count_nonzero(np.abs(rows).sum(0)))
    dof = max(float(w.sum()) - (n_frames - 1), 1.0)
    scatter = np.maximum(np.sqrt(np.sum(w[:, None] * r**2, axis=0) / dof), floor)
    e, se = solve(w, scatter)
    return e, se, w, scatter


def _local_linear(times: np.ndarray, frames: int) -> np.ndarray:
    """``[T, T]`` smoother: row ``t`` holds the weights of a straight line fitted in time to the
    ``frames`` frames around ``t`` (fewer at the ends), evaluated at ``t``."""
    t_count = times.size
    half = frames // 2
    out = np.zeros((t_count, t_count))
    for t in range(t_count):
        lo, hi = max(0, min(t - half, t_count - frames)), min(t_count, max(t + half + 1, frames))
        design = np.stack([np.ones(hi - lo), times[lo:hi] - times[t]], 1)
        out[t, lo:hi] = np.linalg.pinv(design)[0]
    return out


def _decide(c: np.ndarray, se: np.ndarray, measured: np.ndarray, times: np.ndarray, cfg: FramePoseConfig):
    """Which part of the corrections ``c [T, 6]`` (standard errors ``se [T, 6]``) to apply.

    Returns ``(applied [T, 6], part, chi2_per_dof, fast_chi2_per_dof, whiteness)``.
    """
    smoother = _local_linear(times, min(cfg.slow_frames, times.size))
    slow = smoother @ c
    fast = c - slow
    # The variance white noise keeps after the slow part is taken out, per frame.
    keep = (1.0 - np.diag(smoother)) ** 2 + np.sum(smoother**2, axis=1) - np.diag(smoother) ** 2
    m = measured
    dof = max(6 * (int(m.sum()) - 1), 1)
    chi2 = float(np.sum((c[m] / se[m]) ** 2) / dof)
    fast_chi2 = float(np.sum(fast[m] ** 2 / (se[m] ** 2 * keep[m, None])) / dof)
    # White noise changes as much from one frame to the next as between any two frames (ratio
    # 1); a slow error (drift, or a defect that moves with the viewpoint) barely does (ratio ~0).
    z = c[m] / se[m]
    spread = float(np.sum((z - z.mean(0)) ** 2)) / max(z.shape[0] - 1, 1)
    whiteness = (
        float(np.mean(np.sum(np.diff(z, axis=0) ** 2, axis=1)) / (2 * spread))
        if z.shape[0] > 2 and spread > 0
        else 0.0
    )
    if fast_chi2 < cfg.min_chi2_per_dof:
        return np.zeros_like(c), "none", chi2, fast_chi2, whiteness
    if whiteness >= cfg.min_whiteness:
        return c, "all", chi2, fast_chi2, whiteness
    return fast, "frame-to-frame", chi2, fast_chi2, whiteness


def estimate_frame_poses(
    capture: Capture, part: np.ndarray, hand: np.ndarray, config: FramePoseConfig | None = None
) -> FramePoseFit:
    """Fit each frame's pose correction against the recording's static background (module docstring).

    Args:
        capture: the recording (RGB, depth, intrinsics, poses in its own world frame).
        part: ``[T, H, W]`` part labels at RGB resolution (0 = static).
        hand: ``[T, H, W]`` bool hand and arm pixels.
        config: hyperparameters; ``FramePoseConfig()`` when None.

    Returns:
        The corrections, their standard errors and whether they are significant. A recording
        with fewer than two frames, or whose background no alignment could use, gets identity
        corrections that are not significant.

    Raises:
        InputError: masks that do not match the recording's frames.
    """
    cfg = config if config is not None else FramePoseConfig()
    part, hand = _validate(capture, part, hand)
    t_count = capture.num_frames
    moving = (part > 0) | hand
    kernel = np.ones((2 * cfg.mask_dilation_px + 1,) * 2, np.uint8)
    excluded = np.stack([cv2.dilate(m.astype(np.uint8), kernel) > 0 for m in moving])
    depth = np.array(capture.depth, dtype=np.float32)
    depth[~(depth <= cfg.max_depth_m)] = np.nan
    if capture.confidence is not None:
        depth[np.asarray(capture.confidence) < cfg.min_confidence] = np.nan

    pivot, measured_pairs, models = (
        _measure(capture, depth, moving, excluded, cfg) if t_count >= 2 else (None, [], {})
    )
    used = [(t, k, v) for t, k, v, ok in measured_pairs if ok]
    identity = np.tile(np.eye(4), (t_count, 1, 1))
    if pivot is None or not used:
        zeros = np.zeros((t_count, 3))
        return FramePoseFit(
            corrections=identity,
            fitted=identity.copy(),
            pivot=np.zeros(3) if pivot is None else pivot,
            rotation_rad=zeros,
            translation_m=zeros.copy(),
            rotation_se_rad=np.full(t_count, np.inf),
            translation_se_m=np.full(t_count, np.inf),
            pairs=len(measured_pairs),
            pairs_used=0,
            measured=np.zeros(t_count, bool),
            scatter=np.full(6, np.nan),
            chi2_per_dof=0.0,
            fast_chi2_per_dof=0.0,
            whiteness=0.0,
            depth_agreement=0.0,
            applied="none",
        )
    e, se, w, scatter = _solve(t_count, used, cfg)
    measured = np.zeros(t_count, bool)
    for (t, k, _), wi in zip(used, w, strict=True):
        if wi >= 0.3:
            measured[t] = measured[k] = True
    # The correction undoes the error: corrected = exp(-e) @ recorded.
    c = -e
    times = np.asarray(capture.timestamps, dtype=np.float64)
    applied, part_applied, chi2, fast_chi2, whiteness = _decide(c, se, measured, times, cfg)
    fitted = np.stack([_exp(c[t], pivot) for t in range(t_count)])
    corrections = np.stack([_exp(applied[t], pivot) for t in range(t_count)])
    agreement = 0.0
    if part_applied != "none":
        agreement = _depth_agreement(
            capture, depth, excluded, models, [(t, k) for t, k, _ in used], corrections
        )
        if agreement < cfg.min_depth_agreement:
            part_applied, corrections = "none", np.tile(np.eye(4), (t_count, 1, 1))
    rms = lambda x: np.sqrt(np.mean(x**2, axis=1))  # noqa: E731
    return FramePoseFit(
        corrections=corrections,
        fitted=fitted,
        pivot=pivot,
        rotation_rad=c[:, :3],
        translation_m=c[:, 3:],
        rotation_se_rad=np.where(measured, rms(se[:, :3]), np.inf),
        translation_se_m=np.where(measured, rms(se[:, 3:]), np.inf),
        pairs=len(measured_pairs),
        pairs_used=int(np.sum(w >= 0.3)),
        measured=measured,
        scatter=scatter,
        chi2_per_dof=chi2,
        fast_chi2_per_dof=fast_chi2,
        whiteness=whiteness,
        depth_agreement=agreement,
        applied=part_applied,
    )
