"""Compare a twin's predictions with a recording, frame by frame: residual maps and error curves.

The prediction side is plain arrays, so the same comparison serves the canonical 3DGS renders of
the static recording (``reconstruction.render_view``) and, later, articulated renders of the
dynamic one. Frames are ordered worst first by the sum of each curve over its median.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artitwin_core._errors import InputError


@dataclass(frozen=True)
class FrameComparison:
    """Per-frame errors and per-pixel residuals of a twin against a recording.

    Attributes:
        rgb_l1: ``[T]`` mean absolute sRGB error in [0, 1] over compared pixels.
        psnr_db: ``[T]`` sRGB PSNR, dB.
        rgb_residual: ``[T, H, W]`` float32 mean absolute sRGB error per pixel (0 outside the mask).
        depth_mae_m: ``[T]`` mean absolute depth error, metres (NaN without depth).
        depth_residual: ``[T, h, w]`` float32 measured minus predicted depth, metres (NaN where not compared).
        mask_iou: ``[T]`` IoU of predicted and observed part masks (NaN where both are empty or none given).
        mask_disagreement: ``[T, H, W]`` bool, pixels where the masks differ (None without masks).
        track_rms_mm: ``[T2]`` RMS 3D track residual per frame, millimetres (None without tracks).
        worst_frames: ``[T]`` frame indices, worst first.
    """

    rgb_l1: np.ndarray
    psnr_db: np.ndarray
    rgb_residual: np.ndarray
    depth_mae_m: np.ndarray
    depth_residual: np.ndarray | None
    mask_iou: np.ndarray
    mask_disagreement: np.ndarray | None
    track_rms_mm: np.ndarray | None
    worst_frames: np.ndarray

    def curves(self) -> dict[str, list[float]]:
        """The per-frame curves by name (JSON-friendly)."""
        out = {"rgb_l1": self.rgb_l1.tolist(), "psnr_db": self.psnr_db.tolist(), "depth_mae_m": self.depth_mae_m.tolist()}
        if np.isfinite(self.mask_iou).any():
            out["mask_iou"] = self.mask_iou.tolist()
        if self.track_rms_mm is not None:
            out["track_rms_mm"] = self.track_rms_mm.tolist()
        return out


def _as_unit(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    return x.astype(np.float32) / 255.0 if x.dtype == np.uint8 else x.astype(np.float32)


def compare_frames(
    rgb_pred: np.ndarray,
    rgb_meas: np.ndarray,
    *,
    rgb_mask: np.ndarray | None = None,
    depth_pred: np.ndarray | None = None,
    depth_meas: np.ndarray | None = None,
    depth_valid: np.ndarray | None = None,
    mask_pred: np.ndarray | None = None,
    mask_meas: np.ndarray | None = None,
    tracks_pred: np.ndarray | None = None,
    tracks_obs: np.ndarray | None = None,
    tracks_valid: np.ndarray | None = None,
) -> FrameComparison:
    """Residual maps and per-frame error curves.

    Args:
        rgb_pred, rgb_meas: ``[T, H, W, 3]`` sRGB, uint8 or float in [0, 1].
        rgb_mask: optional ``[T, H, W]`` bool, pixels to compare (e.g. render alpha > 0.5).
        depth_pred, depth_meas: optional ``[T, h, w]`` metres (0 or NaN = none).
        depth_valid: optional ``[T, h, w]`` bool (e.g. confidence >= 1).
        mask_pred, mask_meas: optional ``[T, H, W]`` part labels (0 = no part) or bool.
        tracks_pred, tracks_obs: optional ``[T2, N, 3]`` metres; tracks_valid ``[T2, N]`` bool.
    """
    p, m = _as_unit(rgb_pred), _as_unit(rgb_meas)
    if p.shape != m.shape or p.ndim != 4:
        raise InputError(f"compare_frames: rgb_pred {p.shape} and rgb_meas {m.shape} must both be [T, H, W, 3].")
    t_count = p.shape[0]
    valid = np.ones(p.shape[:3], bool) if rgb_mask is None else np.asarray(rgb_mask, bool)
    err = np.abs(p - m).mean(-1)
    rgb_res = np.where(valid, err, 0.0).astype(np.float32)
    n = np.maximum(valid.reshape(t_count, -1).sum(1), 1)
    l1 = rgb_res.reshape(t_count, -1).sum(1) / n
    mse = np.where(valid[..., None], (p - m) ** 2, 0.0).reshape(t_count, -1).sum(1) / (3 * n)
    psnr = 10 * np.log10(1.0 / np.maximum(mse, 1e-12))

    depth_mae = np.full(t_count, np.nan)
    depth_res = None
    if depth_pred is not None and depth_meas is not None:
        dp, dm = np.asarray(depth_pred, np.float32), np.asarray(depth_meas, np.float32)
        if dp.shape != dm.shape or dp.shape[0] != t_count:
            raise InputError(f"compare_frames: depth_pred {dp.shape} and depth_meas {dm.shape} must both be [{t_count}, h, w].")
        ok = np.isfinite(dp) & np.isfinite(dm) & (dp > 0) & (dm > 0)
        if depth_valid is not None:
            ok &= np.asarray(depth_valid, bool)
        depth_res = np.where(ok, dm - dp, np.nan).astype(np.float32)
        cnt = ok.reshape(t_count, -1).sum(1)
        depth_mae = np.where(cnt > 0, np.nansum(np.abs(depth_res).reshape(t_count, -1), 1) / np.maximum(cnt, 1), np.nan)

    iou = np.full(t_count, np.nan)
    disagree = None
    if mask_pred is not None and mask_meas is not None:
        a, b = np.asarray(mask_pred) > 0, np.asarray(mask_meas) > 0
        if a.shape != b.shape or a.shape[0] != t_count:
            raise InputError(f"compare_frames: mask_pred {a.shape} and mask_meas {b.shape} must both be [{t_count}, H, W].")
        inter = (a & b).reshape(t_count, -1).sum(1)
        union = (a | b).reshape(t_count, -1).sum(1)
        iou = np.where(union > 0, inter / np.maximum(union, 1), np.nan)
        disagree = a != b

    track_rms = None
    if tracks_pred is not None and tracks_obs is not None:
        tv = np.ones(np.shape(tracks_obs)[:2], bool) if tracks_valid is None else np.asarray(tracks_valid, bool)
        d2 = np.sum((np.asarray(tracks_obs) - np.asarray(tracks_pred)) ** 2, -1)
        cnt = tv.sum(1)
        track_rms = 1000 * np.sqrt(np.where(cnt > 0, np.where(tv, d2, 0).sum(1) / np.maximum(cnt, 1), np.nan))

    score = np.zeros(t_count)
    for curve, worse_high in ((l1, True), (depth_mae, True), (iou, False)):
        if np.isfinite(curve).any():
            c = np.nan_to_num(curve, nan=np.nanmedian(curve))
            med = np.median(c) if worse_high else np.median(1 - c)
            score += (c if worse_high else 1 - c) / max(med, 1e-9)
    worst = np.argsort(-score, kind="stable")
    return FrameComparison(l1, psnr, rgb_res, depth_mae, depth_res, iou, disagree, track_rms, worst)
