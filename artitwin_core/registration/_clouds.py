"""Fuse a recording's depth maps into one coloured point cloud with normals (session frame)."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.geometry import backproject as backproject_points
from artitwin_core.geometry import nearest_pixel, project


def backproject(depth: np.ndarray, intrinsics: np.ndarray, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points of one depth map.

    Args:
        depth: ``[h, w]`` z-depth in metres, NaN or <= 0 = invalid.
        intrinsics: ``(fx, fy, cx, cy)`` pixels at depth resolution (pixel centres at integers).
        stride: keep every ``stride``-th pixel each way.

    Returns:
        points ``[N, 3]`` metres (OpenCV camera axes) and their pixel coordinates ``[N, 2]``
        ``(u, v)`` of the valid pixels.
    """
    d = depth[::stride, ::stride]
    v, u = np.nonzero(np.isfinite(d) & (d > 0))
    z = d[v, u].astype(np.float64)
    u = u * stride
    v = v * stride
    return backproject_points(z, intrinsics, u, v), np.stack([u, v], -1)


def frame_points(
    capture: Capture,
    t: int,
    *,
    stride: int = 1,
    max_depth_m: float = np.inf,
    min_confidence: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """World (session-frame) points ``[N, 3]`` and RGB colours ``[N, 3]`` in [0, 1] of frame ``t``."""
    depth = capture.depth[t].astype(np.float32, copy=True)
    depth[~(depth < max_depth_m)] = np.nan
    if capture.confidence is not None and min_confidence > 0:
        depth[capture.confidence[t] < min_confidence] = np.nan
    pts_cam, uv = backproject(depth, capture.depth_intrinsics[t], stride)
    # Colour: project the camera point into the RGB image (intrinsics may differ in scale).
    h, w = capture.rgb.shape[1:3]
    uv, _ = project(pts_cam, capture.rgb_intrinsics[t], min_z=1e-6)
    ur, vr = nearest_pixel(uv)
    ur, vr = np.clip(ur, 0, w - 1), np.clip(vr, 0, h - 1)
    colours = capture.rgb[t][vr, ur].astype(np.float64) / 255.0
    pose = capture.world_from_camera[t]
    return pts_cam @ pose[:3, :3].T + pose[:3, 3], colours


def fused_cloud(
    capture: Capture,
    frames,
    *,
    voxel_m: float,
    stride: int = 2,
    max_depth_m: float = 4.5,
    min_confidence: int = 1,
    keep_fraction=None,
    seed: int = 0,
) -> o3d.geometry.PointCloud:
    """Fuse ``frames`` of ``capture`` into one voxel-downsampled cloud with colours and normals.

    Args:
        frames: frame indices to fuse.
        voxel_m: voxel size of the downsampling (metres); normals use a radius of ``3 * voxel_m``.
        keep_fraction: optional ``[len(frames)]`` fraction of each frame's points to keep (a
            random subset with ``seed``): how much each frame weighs in the fused cloud.
    """
    rng = np.random.default_rng(seed)
    pts, cols = [], []
    for i, t in enumerate(frames):
        p, c = frame_points(capture, int(t), stride=stride, max_depth_m=max_depth_m, min_confidence=min_confidence)
        if keep_fraction is not None and keep_fraction[i] < 1.0:
            keep = rng.random(len(p)) < keep_fraction[i]
            p, c = p[keep], c[keep]
        pts.append(p)
        cols.append(c)
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(points) < 100:
        raise InputError(
            f"The {capture.source_format} recording has only {len(points)} valid depth points in the "
            f"frames used for registration (depth < {max_depth_m} m, confidence >= {min_confidence}); "
            "check that its depth maps are present and in metres."
        )
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.colors = o3d.utility.Vector3dVector(np.concatenate(cols))
    cloud = cloud.voxel_down_sample(voxel_m)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * voxel_m, max_nn=30))
    return cloud
