"""Each frame's rigid motion against the reference frame (step 1 of ``estimate_joint``).

Per frame, the part's rigid motion by 3-point RANSAC over the tracks valid in both frames
(:func:`ransac_rigid`). Its consensus gives a model-agnostic set ``S`` of inlier observations
(tracks that stay rigid with the majority in most frames) and a robust noise level ``sigma``
(median residual, chi-3 corrected), on which every joint hypothesis is then fitted and scored.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artitwin_core.joints._config import JointFitConfig
from artitwin_core.joints._rigid import CHI3_MEDIAN, ransac_rigid


@dataclass(frozen=True)
class FrameMotions:
    """The per-frame rigid motions and what they say about the tracks.

    Attributes:
        rots, trans: ``[T, 3, 3]`` and ``[T, 3]`` metres, each frame's motion of a part point's
            reference-frame position (NaN where fewer than 3 tracks were shared with it).
        has: ``[T]`` bool, frames with a motion.
        ransac_in: ``[T, N]`` bool, RANSAC inliers of each frame.
        sigma: robust per-coordinate noise level of one observation, metres.
        track_ok: ``[N]`` bool, tracks that stay rigid with the majority.
        s_mask: ``[T, N]`` bool, the common inlier set ``S`` the hypotheses are scored on.
        rigid: ``[T, 4, 4]`` the motions as transforms (identity at the reference frame).
        centroid: ``[3]`` metres, the rigid tracks' centroid at the reference frame.
    """

    rots: np.ndarray
    trans: np.ndarray
    has: np.ndarray
    ransac_in: np.ndarray
    sigma: float
    track_ok: np.ndarray
    s_mask: np.ndarray
    rigid: np.ndarray
    centroid: np.ndarray


def frame_motions(pts: np.ndarray, valid: np.ndarray, ref: int, cfg: JointFitConfig) -> FrameMotions:
    """RANSAC motions of every frame against ``ref`` from tracks ``pts [T, N, 3]`` (``valid [T, N]``)."""
    t_count, n = pts.shape[:2]
    rng = np.random.default_rng(cfg.seed)
    rots = np.full((t_count, 3, 3), np.nan)
    trans = np.full((t_count, 3), np.nan)
    rots[ref], trans[ref] = np.eye(3), np.zeros(3)
    ransac_in = np.zeros((t_count, n), bool)
    checked = np.zeros((t_count, n), bool)
    diff_res = []
    for t in range(t_count):
        if t == ref:
            continue
        common = np.nonzero(valid[ref] & valid[t])[0]
        res = ransac_rigid(
            pts[ref, common],
            pts[t, common],
            rng,
            iterations=cfg.ransac_iterations,
            threshold_m=cfg.ransac_threshold_m,
            min_threshold_m=cfg.min_inlier_threshold_m,
            inlier_sigmas=cfg.inlier_sigmas * np.sqrt(2.0),
        )
        if res is None or res.inliers.sum() < 3:
            continue
        rots[t], trans[t] = res.rotation, res.translation
        ransac_in[t, common] = res.inliers
        checked[t, common] = True
        diff_res.append(res.residuals[res.inliers])
    has = np.isfinite(rots[:, 0, 0])
    # A difference of two observations has twice the per-coordinate variance of one.
    if diff_res:
        sigma = float(np.median(np.concatenate(diff_res)) / CHI3_MEDIAN / np.sqrt(2.0))
    else:
        sigma = cfg.noise_floor_m
    sigma = max(sigma, cfg.noise_floor_m)
    track_ok, s_mask = _common_set(valid, ref, ransac_in, checked, cfg)
    rigid = np.full((t_count, 4, 4), np.nan)
    rigid[has, :3, :3] = rots[has]
    rigid[has, :3, 3] = trans[has]
    rigid[has, 3] = [0, 0, 0, 1]
    centroid = pts[ref, track_ok].mean(0)
    return FrameMotions(rots, trans, has, ransac_in, sigma, track_ok, s_mask, rigid, centroid)


def _common_set(
    valid: np.ndarray, ref: int, ransac_in: np.ndarray, checked: np.ndarray, cfg: JointFitConfig
) -> tuple[np.ndarray, np.ndarray]:
    """``[N]`` tracks inlier in at least ``min_track_inlier_fraction`` of their frames (all valid
    reference tracks when fewer than 3 are), and ``[T, N]`` their inlier observations."""
    n_checked = checked.sum(0)
    frac = ransac_in.sum(0) / np.maximum(n_checked, 1)
    track_ok = valid[ref] & (n_checked >= 1) & (frac >= cfg.min_track_inlier_fraction)
    if track_ok.sum() < 3:
        track_ok = valid[ref].copy()
    s_mask = (ransac_in & track_ok[None, :]) & valid
    s_mask[ref] = track_ok & valid[ref]
    return track_ok, s_mask
