"""Seed Gaussians from the capture's sensor depth: back-project, weight, voxel-downsample, colour.

Each valid depth pixel (confidence above the threshold) is lifted into the world with the depth
intrinsics and its frame's pose, then projected into the same frame's RGB image with the RGB
intrinsics to pick up its colour (depth and RGB differ in resolution). Points are merged per
voxel, weighted by confidence; each voxel becomes one isotropic Gaussian whose size is the mean
distance to its three nearest neighbours, as 3DGS does for its SfM points.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.gaussians import LABEL_BACKGROUND, GaussianParams
from artitwin_core.gaussians._sh import SH_C0
from artitwin_core.geometry import pixel_rays, unique_rows
from artitwin_core.reconstruction._config import InitConfig


def backproject_depth(
    capture: Capture,
    world_from_camera: np.ndarray,
    frames: Sequence[int],
    config: InitConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lift the valid depth pixels of ``frames`` into the world and colour them.

    Args:
        capture: the recording (depth ``[T, h, w]`` metres, rgb ``[T, H, W, 3]``).
        world_from_camera: ``[T, 4, 4]`` poses to use (capture or refined), OpenCV axes.
        frames: frame indices to use.
        config: thresholds (``min_confidence``, ``max_depth_m``, ``frame_stride``).

    Returns:
        points ``[M, 3]`` world metres (float64), colours ``[M, 3]`` in [0, 1] (float32),
        weights ``[M]`` (float32, the confidence, 1 where the capture has none).
    """
    pts, cols, wts = [], [], []
    _, h, w = capture.depth.shape
    _, hr, wr, _ = capture.rgb.shape
    v, u = np.mgrid[0:h, 0:w]
    uc, vc = u.ravel() + 0.5, v.ravel() + 0.5  # pixel centres
    for t in list(frames)[:: max(1, config.frame_stride)]:
        z = capture.depth[t].ravel().astype(np.float64)
        ok = np.isfinite(z) & (z > 0.05) & (z < config.max_depth_m)
        weight = np.ones_like(z)
        if capture.confidence is not None:
            conf = capture.confidence[t].ravel().astype(np.float64)
            ok &= conf >= config.min_confidence
            weight = np.maximum(conf, 0.0)
            ok &= weight > 0  # confidence 0 carries no information
        if not ok.any():
            continue
        cam = pixel_rays(capture.depth_intrinsics[t], uc[ok], vc[ok]) * z[ok, None]
        # Colour: project the camera-space point into the RGB image of the same frame.
        rfx, rfy, rcx, rcy = capture.rgb_intrinsics[t]
        ur = rfx * cam[:, 0] / cam[:, 2] + rcx - 0.5
        vr = rfy * cam[:, 1] / cam[:, 2] + rcy - 0.5
        col = _bilinear(capture.rgb[t].astype(np.float32) / 255.0, ur, vr, wr, hr)
        pose = world_from_camera[t]
        pts.append(cam @ pose[:3, :3].T + pose[:3, 3])
        cols.append(col)
        wts.append(weight[ok])
    if not pts:
        raise InputError(
            "reconstruction: no valid depth pixel in the training frames (all NaN, zero confidence or "
            "beyond max_depth_m); check the recording's depth maps or lower InitConfig.min_confidence."
        )
    return np.concatenate(pts), np.concatenate(cols).astype(np.float32), np.concatenate(wts).astype(np.float32)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray, w: int, h: int) -> np.ndarray:
    """Sample ``img`` ``[H, W, C]`` at pixel-index coordinates ``x, y`` (clamped at borders)."""
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2) if w > 1 else np.zeros(len(x), np.int64)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2) if h > 1 else np.zeros(len(y), np.int64)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    top = img[y0, x0] * (1 - ax) + img[y0, x1] * ax
    bot = img[y1, x0] * (1 - ax) + img[y1, x1] * ax
    return top * (1 - ay) + bot * ay


def voxel_downsample(
    points: np.ndarray, colours: np.ndarray, weights: np.ndarray, voxel_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted mean point and colour per occupied voxel.

    Args:
        points: ``[M, 3]`` metres; colours: ``[M, 3]``; weights: ``[M]`` > 0.
        voxel_m: voxel edge, metres.

    Returns:
        points ``[V, 3]``, colours ``[V, 3]``, total weight ``[V]`` of each voxel.
    """
    keys = np.floor(points / voxel_m).astype(np.int64)
    _, inverse, _ = unique_rows(keys)
    n = int(inverse.max()) + 1
    wsum = np.bincount(inverse, weights=weights, minlength=n)
    p = np.stack([np.bincount(inverse, weights=weights * points[:, k], minlength=n) for k in range(3)], 1)
    c = np.stack([np.bincount(inverse, weights=weights * colours[:, k], minlength=n) for k in range(3)], 1)
    return p / wsum[:, None], c / wsum[:, None], wsum


def auto_voxel_size(capture: Capture, frames: Sequence[int]) -> float:
    """About 1.5 RGB pixel footprints at the median valid depth, clamped to [1, 3] cm."""
    z = capture.depth[list(frames)]
    med = float(np.nanmedian(z)) if np.isfinite(z).any() else 2.0
    fx = float(np.median(capture.rgb_intrinsics[list(frames), 0]))
    return float(np.clip(1.5 * med / fx, 0.01, 0.03))


def init_gaussians(
    capture: Capture,
    world_from_camera: np.ndarray,
    frames: Sequence[int],
    config: InitConfig = InitConfig(),
    sh_degree: int = 3,
) -> GaussianParams:
    """Gaussians seeded from the sensor depth of ``frames``.

    Args:
        capture: the recording.
        world_from_camera: ``[T, 4, 4]`` poses (capture or refined), OpenCV axes, metres.
        frames: training frame indices.
        config: seeding thresholds.
        sh_degree: SH degree whose coefficients are allocated (higher bands start at zero).

    Returns:
        ``GaussianParams`` with N <= ``config.max_points`` isotropic Gaussians, identity
        rotations, opacity ``config.opacity``, DC colour from the RGB frames, labels 0.
    """
    points, colours, weights = backproject_depth(capture, world_from_camera, frames, config)
    voxel = config.voxel_size_m or auto_voxel_size(capture, frames)
    means, cols, _ = voxel_downsample(points, colours, weights, voxel)
    while len(means) > config.max_points:
        voxel *= 1.25
        means, cols, _ = voxel_downsample(points, colours, weights, voxel)
    n = len(means)
    if n < 4:
        raise InputError(f"reconstruction: only {n} seed points from depth; the recording needs valid depth.")
    dist, _ = cKDTree(means).query(means, k=4)
    nn = np.clip(dist[:, 1:].mean(axis=1), 0.2 * voxel, 3.0 * voxel)
    k = (sh_degree + 1) ** 2
    sh = np.zeros((n, k, 3), np.float32)
    sh[:, 0] = (np.clip(cols, 0.0, 1.0) - 0.5) / SH_C0
    op = float(np.clip(config.opacity, 1e-4, 1 - 1e-4))
    return GaussianParams(
        means=means.astype(np.float32),
        quats_wxyz=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
        log_scales=np.repeat(np.log(nn)[:, None], 3, axis=1).astype(np.float32),
        opacity_logits=np.full(n, np.log(op / (1 - op)), np.float32),
        sh=sh,
        labels=np.full(n, LABEL_BACKGROUND, np.int32),
    )
