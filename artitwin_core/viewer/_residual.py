"""The residual heat map in 3D: where the twin's predicted depth disagrees with the measured depth."""

from __future__ import annotations

import numpy as np

from artitwin_core._errors import InputError


def depth_residual_points(
    depth: np.ndarray,
    predicted: np.ndarray,
    intrinsics: np.ndarray,
    world_from_camera: np.ndarray,
    *,
    stride: int = 4,
    max_points: int = 200_000,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Measured depth pixels as world points carrying ``|measured - predicted|``.

    Args:
        depth: ``[T, h, w]`` measured z-depth, metres; 0 or non-finite where none.
        predicted: ``[T, h, w]`` the twin's depth at the same pixels, metres; 0 or NaN where none.
        intrinsics: ``[T, 4]`` ``(fx, fy, cx, cy)`` of the depth images, pixels (pixel centres at +0.5).
        world_from_camera: ``[T, 4, 4]`` camera poses (OpenCV axes), metres.
        stride: every ``stride``-th pixel in both directions.
        max_points: random subsample to at most this many points (fixed ``seed``).

    Returns:
        points ``[M, 3]`` float32 metres (the measured surface) and values ``[M]`` float32 metres.
    """
    depth, predicted = np.asarray(depth), np.asarray(predicted)
    if depth.shape != predicted.shape or depth.ndim != 3:
        raise InputError(f"residual: measured depth {depth.shape} and predicted depth {predicted.shape} must both be "
                         "[T, h, w]; predict the views at the capture's depth size.")
    t = depth.shape[0]
    if np.shape(intrinsics) != (t, 4) or np.shape(world_from_camera) != (t, 4, 4):
        raise InputError(f"residual: intrinsics {np.shape(intrinsics)} and poses {np.shape(world_from_camera)} must be "
                         f"[{t}, 4] and [{t}, 4, 4], one per depth frame.")
    v, u = np.mgrid[0 : depth.shape[1] : stride, 0 : depth.shape[2] : stride]
    points, values = [], []
    for i in range(t):
        z = depth[i, v, u].astype(np.float64)
        zp = predicted[i, v, u].astype(np.float64)
        ok = np.isfinite(z) & (z > 0) & np.isfinite(zp) & (zp > 0)
        fx, fy, cx, cy = np.asarray(intrinsics[i], np.float64)
        cam = np.stack([(u[ok] + 0.5 - cx) / fx * z[ok], (v[ok] + 0.5 - cy) / fy * z[ok], z[ok]], 1)
        pose = np.asarray(world_from_camera[i], np.float64)
        points.append(cam @ pose[:3, :3].T + pose[:3, 3])
        values.append(np.abs(z[ok] - zp[ok]))
    pts, vals = np.concatenate(points), np.concatenate(values)
    if pts.shape[0] > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(pts.shape[0], max_points, replace=False))
        pts, vals = pts[keep], vals[keep]
    return pts.astype(np.float32), vals.astype(np.float32)
