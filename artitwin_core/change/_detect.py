"""Per-frame change maps: where an observed RGB-D frame differs from the canonical model rendered
at the same pose, robust to exposure (a fitted per-frame colour transform and a census transform)
and to depth noise (a tolerance growing with depth squared, as LiDAR/ToF noise does).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.change._config import ChangeConfig


@dataclass(frozen=True)
class ChangeMaps:
    """Change maps of one frame, at RGB resolution ``[H, W]``.

    Attributes:
        depth_difference: float32 metres, rendered minus observed depth (> 0: the observed surface
            is in front of the canonical one); NaN where either is unknown.
        closer: bool, something new in front of the canonical surface (a moved part, a hand).
        farther: bool, the canonical surface is gone (the part moved away from here).
        appearance: float32 in [0, 1], appearance change after the colour transform.
        changed: bool, ``closer | farther``, plus appearance changes where depth is unknown.
        colour_gain, colour_offset: ``[3]`` the fitted transform ``observed ~ gain * rendered +
            offset`` per channel (0-255 units) on unchanged pixels.
    """

    depth_difference: np.ndarray
    closer: np.ndarray
    farther: np.ndarray
    appearance: np.ndarray
    changed: np.ndarray
    colour_gain: np.ndarray
    colour_offset: np.ndarray


def depth_tolerance(depth: np.ndarray, config: ChangeConfig) -> np.ndarray:
    """``[...]`` metres of depth difference still explained by noise at ``depth`` metres."""
    return config.depth_tol_m + config.depth_tol_per_m2 * np.nan_to_num(depth, nan=0.0) ** 2


def _resize_depth(depth: np.ndarray, size_hw: tuple[int, int]) -> np.ndarray:
    if depth.shape == size_hw:
        return depth.astype(np.float32)
    return cv2.resize(depth.astype(np.float32), (size_hw[1], size_hw[0]), interpolation=cv2.INTER_NEAREST)


def census(gray: np.ndarray, radius: int) -> np.ndarray:
    """``[H, W, K]`` bool census signature: is each neighbour brighter than the centre pixel."""
    pad = np.pad(gray, radius, mode="edge")
    h, w = gray.shape
    bits = []
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            if dy or dx:
                bits.append(pad[radius + dy:radius + dy + h, radius + dx:radius + dx + w] > gray + 2.0)
    return np.stack(bits, -1)


def _fit_colour(obs: np.ndarray, ren: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel robust least squares ``obs ~ gain * ren + offset`` on pixels ``ok``."""
    gain, offset = np.ones(3), np.zeros(3)
    if ok.sum() < 50:
        return gain, offset
    for c in range(3):
        # Saturated or black pixels do not follow the affine model.
        use = ok & (obs[..., c] < 250) & (obs[..., c] > 5) & (ren[..., c] < 250)
        if use.sum() < 50:
            continue
        x, y = ren[..., c][use], obs[..., c][use]
        keep = np.ones(len(x), bool)
        for _ in range(3):
            a = np.stack([x[keep], np.ones(keep.sum())], -1)
            (g, o), *_ = np.linalg.lstsq(a, y[keep], rcond=None)
            r = np.abs(y - (g * x + o))
            keep = r < max(3.0 * 1.4826 * np.median(r[keep]), 4.0)
        gain[c], offset[c] = g, o
    return gain, offset


def detect_changes(
    observed_rgb: np.ndarray,
    observed_depth: np.ndarray,
    rendered_rgb: np.ndarray,
    rendered_depth: np.ndarray,
    config: ChangeConfig | None = None,
) -> ChangeMaps:
    """Compare one observed RGB-D frame with the canonical model rendered at the same pose.

    Args:
        observed_rgb: ``[H, W, 3]`` uint8 observed frame.
        observed_depth: ``[h, w]`` float32 observed z-depth, metres, NaN = invalid (any resolution
            with the RGB aspect ratio; resampled to ``[H, W]``).
        rendered_rgb: ``[H, W, 3]`` uint8 canonical model rendered at this frame's pose.
        rendered_depth: ``[h', w']`` float32 rendered z-depth, metres, NaN = no surface.
        config: thresholds.

    Returns:
        :class:`ChangeMaps` at ``[H, W]``.
    """
    cfg = config or ChangeConfig()
    if observed_rgb.ndim != 3 or observed_rgb.shape != rendered_rgb.shape:
        raise InputError(
            f"detect_changes: observed_rgb {observed_rgb.shape} and rendered_rgb {rendered_rgb.shape} must both "
            "be [H, W, 3] of the same size; render the canonical model at the observed RGB resolution."
        )
    h, w = observed_rgb.shape[:2]
    obs_d = _resize_depth(observed_depth, (h, w))
    ren_d = _resize_depth(rendered_depth, (h, w))
    obs_d = np.where(obs_d > 0, obs_d, np.nan)
    ren_d = np.where(ren_d > 0, ren_d, np.nan)
    diff = ren_d - obs_d
    tol = depth_tolerance(np.fmin(obs_d, ren_d), cfg)
    both = np.isfinite(diff)
    closer = both & (diff > tol)
    farther = both & (diff < -tol)
    # An observed surface where the canonical model has none is new too (it is in front of "nothing").
    closer |= np.isfinite(obs_d) & ~np.isfinite(ren_d)

    obs = observed_rgb.astype(np.float64)
    ren = rendered_rgb.astype(np.float64)
    unchanged = both & ~closer & ~farther
    gain, offset = _fit_colour(obs, ren, unchanged)
    mapped = np.clip(ren * gain + offset, 0, 255)
    colour_res = np.abs(obs - mapped).mean(-1) / 255.0
    g_obs = cv2.GaussianBlur(obs.mean(-1), (3, 3), 0)
    g_ren = cv2.GaussianBlur(mapped.mean(-1), (3, 3), 0)
    hamming = (census(g_obs, cfg.census_radius) != census(g_ren, cfg.census_radius)).mean(-1)
    appearance = 0.5 * np.clip(colour_res / 0.2, 0, 1) + 0.5 * hamming
    appearance = cv2.blur(appearance.astype(np.float32), (5, 5))

    changed = closer | farther | (~both & (appearance > cfg.appearance_threshold) & np.isfinite(ren_d))
    closer, farther, changed = (remove_small(m, cfg.min_region_px) for m in (closer, farther, changed))
    return ChangeMaps(
        depth_difference=diff.astype(np.float32),
        closer=closer,
        farther=farther,
        appearance=appearance.astype(np.float32),
        changed=changed,
        colour_gain=gain,
        colour_offset=offset,
    )


def remove_small(mask: np.ndarray, min_px: int) -> np.ndarray:
    """``mask`` without its 8-connected regions smaller than ``min_px`` pixels."""
    if min_px <= 1 or not mask.any():
        return mask
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_px
    keep[0] = False
    return keep[lab]
