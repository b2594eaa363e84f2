"""The residual heat map in 3D: where the twin's predicted depth disagrees with the measured depth."""

from __future__ import annotations

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.geometry import backproject


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
        intrinsics: ``[T, 4]`` ``(fx, fy, cx, cy)`` of the depth images, pixels (pixel centres at integers).
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
        cam = backproject(z[ok], intrinsics[i], u[ok], v[ok])
        pose = np.asarray(world_from_camera[i], np.float64)
        points.append(cam @ pose[:3, :3].T + pose[:3, 3])
        values.append(np.abs(z[ok] - zp[ok]))
    pts, vals = np.concatenate(points), np.concatenate(values)
    if pts.shape[0] > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(pts.shape[0], max_points, replace=False))
        pts, vals = pts[keep], vals[keep]
    return pts.astype(np.float32), vals.astype(np.float32)


def residual_on_gaussians(
    means: np.ndarray, points: np.ndarray, values: np.ndarray, *, max_distance_m: float = 0.03
) -> np.ndarray:
    """Accumulate residual points onto the model: each point goes to its nearest Gaussian centre
    (within ``max_distance_m``), and each Gaussian gets the mean of its points.

    Args:
        means: ``[N, 3]`` Gaussian centres, metres.
        points, values: ``[M, 3]`` residual points and ``[M]`` their values (``depth_residual_points``).

    Returns:
        ``[N]`` float32 mean residual per Gaussian; NaN where no point landed (not observed).
    """
    from scipy.spatial import cKDTree

    means, points, values = np.asarray(means, np.float64), np.asarray(points, np.float64), np.asarray(values, np.float64)
    if means.ndim != 2 or means.shape[1] != 3 or points.ndim != 2 or points.shape[1] != 3 or values.shape != points.shape[:1]:
        raise InputError(f"residual: means {means.shape} and points {points.shape} must be [*, 3], values {values.shape} [M].")
    out = np.full(means.shape[0], np.nan, np.float32)
    if not len(means) or not len(points):
        return out
    dist, idx = cKDTree(means).query(points, distance_upper_bound=max_distance_m)
    hit = np.isfinite(dist)
    sums = np.bincount(idx[hit], weights=values[hit], minlength=len(means))
    counts = np.bincount(idx[hit], minlength=len(means))
    seen = counts > 0
    out[seen] = (sums[seen] / counts[seen]).astype(np.float32)
    return out


def residual_by_label(per_gaussian: np.ndarray, labels: np.ndarray, names: dict[int, str]) -> dict[str, float]:
    """Mean of the per-Gaussian residual over each label's observed Gaussians (``{name: value}``;
    NaN for a label none of whose Gaussians was observed)."""
    per_gaussian, labels = np.asarray(per_gaussian, np.float64), np.asarray(labels)
    out = {}
    for label, name in names.items():
        v = per_gaussian[(labels == label) & np.isfinite(per_gaussian)]
        out[name] = float(v.mean()) if v.size else float("nan")
    return out
