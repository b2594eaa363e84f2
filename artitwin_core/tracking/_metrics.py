"""Track errors against a known part motion (synthetic ground truth)."""

from __future__ import annotations

import numpy as np

from artitwin_core.tracking._types import Trajectories


def true_track_positions(
    traj: Trajectories, world_from_closed: np.ndarray, true_query_points: np.ndarray
) -> np.ndarray:
    """Where each tracked surface point really is in every frame.

    Args:
        traj: the tracks (only ``query_frame`` is used).
        world_from_closed: ``[T, 4, 4]`` the part's true rigid motion per frame (closed state to
            frame t, canonical frame), e.g. ``SceneGroundTruth.part_world_from_closed[k]``.
        true_query_points: ``[N, 3]`` metres, the true canonical position of each track's surface
            point in the query frame (e.g. from a noise-free depth render).

    Returns:
        ``[T, N, 3]`` metres: ``world_from_closed[t] @ inv(world_from_closed[q]) @ x``.
    """
    m = np.asarray(world_from_closed, dtype=np.float64)
    rel = m @ np.linalg.inv(m[traj.query_frame])
    x = np.asarray(true_query_points, dtype=np.float64)
    return np.einsum("tij,nj->tni", rel[:, :3, :3], x) + rel[:, None, :3, 3]


def track_errors_m(traj: Trajectories, true_positions: np.ndarray) -> np.ndarray:
    """3D error ``[T, N]`` metres of every valid sample against ``true_positions [T, N, 3]``
    (NaN where the track is not valid)."""
    err = np.linalg.norm(np.asarray(traj.points_in_world) - np.asarray(true_positions), axis=-1)
    return np.where(traj.valid, err, np.nan)
