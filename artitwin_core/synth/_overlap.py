"""How much of what the dynamic recording sees the static one saw too: the true overlap fraction.

Measured on the clean (noise-free) depth maps at the true poses: every dynamic depth pixel on the
scene (the hand left out) is back-projected, a moving part's points are carried back to where the
part sat closed, and a point counts as seen when some static frame's depth map has a surface
within a few centimetres of it along that frame's ray.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.geometry import backproject, invert_se3, nearest_pixel, project


def overlap_fraction(
    static_depth: np.ndarray,
    static_world_from_camera: np.ndarray,
    dynamic_depth: np.ndarray,
    dynamic_labels: np.ndarray,
    dynamic_world_from_camera: np.ndarray,
    closed_from_world: np.ndarray,
    intrinsics,
    stride: int = 2,
    hand_label: int = -2,
) -> float:
    """Fraction of the dynamic recording's surface pixels whose point a static frame also saw.

    Args:
        static_depth: ``[Ts, h, w]`` clean z-depth (metres, inf where nothing was hit).
        static_world_from_camera: ``[Ts, 4, 4]`` the poses those depth maps were taken at.
        dynamic_depth: ``[Td, h, w]`` clean z-depth of the dynamic recording.
        dynamic_labels: ``[Td, h, w]`` int: -1 static, k part k, ``hand_label`` the hand.
        dynamic_world_from_camera: ``[Td, 4, 4]``.
        closed_from_world: ``[K, Td, 4, 4]`` maps part k at frame t back to its closed pose.
        intrinsics: ``(fx, fy, cx, cy)`` of the depth maps (pixels).
        stride: every ``stride``-th pixel each way is tested.

    Returns:
        The fraction in [0, 1] (pixels of all dynamic frames pooled); NaN if none is valid.
    """
    h, w = dynamic_depth.shape[1:]
    v, u = np.mgrid[0:h:stride, 0:w:stride]
    points = []
    for i in range(dynamic_depth.shape[0]):
        z = dynamic_depth[i][v, u]
        lab = dynamic_labels[i][v, u]
        ok = np.isfinite(z) & (lab != hand_label)
        z, lab = z[ok], lab[ok]
        cam = backproject(z, intrinsics, u[ok], v[ok])
        pose = dynamic_world_from_camera[i]
        world = cam @ pose[:3, :3].T + pose[:3, 3]
        for k in np.unique(lab[lab >= 0]):
            sel = lab == k
            m = closed_from_world[k, i]
            world[sel] = world[sel] @ m[:3, :3].T + m[:3, 3]
        points.append(world)
    pts = np.concatenate(points) if points else np.zeros((0, 3))
    if pts.shape[0] == 0:
        return float("nan")
    seen = np.zeros(pts.shape[0], dtype=bool)
    sh, sw = static_depth.shape[1:]
    for j in range(static_depth.shape[0]):
        cam_from_world = invert_se3(static_world_from_camera[j])
        pc = pts @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
        uv, z = project(pc, intrinsics, min_z=0.05)
        front = z > 0.05
        ui, vi = nearest_pixel(uv)
        inside = front & (ui >= 0) & (ui < sw) & (vi >= 0) & (vi < sh)
        idx = np.nonzero(inside & ~seen)[0]
        surface = static_depth[j][vi[idx], ui[idx]]
        # A pixel's footprint on a slanted surface spans a few cm of depth at these resolutions.
        seen[idx] |= np.abs(z[idx] - surface) < 0.02 + 0.02 * z[idx]
    return float(seen.mean())
