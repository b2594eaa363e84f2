"""A camera trajectory sampled at frame times, read at any other time."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline


def interpolate_poses(world_from_camera: np.ndarray, timestamps: np.ndarray, at_s: np.ndarray) -> np.ndarray:
    """The poses ``[N, 4, 4]`` at times ``at_s [N]`` (seconds) of a trajectory recorded as
    ``world_from_camera [T, 4, 4]`` at ``timestamps [T]`` (seconds, increasing).

    Between the recorded poses: a cubic spline through the centres and a rotation spline (cubic in
    the rotation vector, continuous angular rate) through the orientations, so a time shifted by a
    fraction of a frame follows the camera's acceleration; at a recorded time the recorded pose
    comes back exactly. Outside their span: the first or last pose moved on at the constant
    velocity and angular rate of the end interval (a hand does not stop when the recording does).

    Raises:
        ValueError: shapes that do not match, fewer than two poses, or timestamps that do not increase.
    """
    poses = np.asarray(world_from_camera, dtype=np.float64)
    ts = np.asarray(timestamps, dtype=np.float64)
    at = np.atleast_1d(np.asarray(at_s, dtype=np.float64))
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or ts.shape != (poses.shape[0],):
        raise ValueError(f"world_from_camera {poses.shape} and timestamps {ts.shape} must be [T, 4, 4] and [T]")
    if ts.size < 2 or np.any(np.diff(ts) <= 0):
        raise ValueError("interpolate_poses needs at least two poses at increasing timestamps")
    rotations = Rotation.from_matrix(poses[:, :3, :3])
    inside = np.clip(at, ts[0], ts[-1])
    out = np.tile(np.eye(4), (at.size, 1, 1))
    if ts.size == 2:  # a spline needs three knots; two give the constant-rate segment
        out[:] = _constant_rate(poses, ts, 0, 1, inside)
    else:
        out[:, :3, :3] = RotationSpline(ts, rotations)(inside).as_matrix()
        out[:, :3, 3] = CubicSpline(ts, poses[:, :3, 3], axis=0)(inside)
    for outside, a, b in ((at < ts[0], 1, 0), (at > ts[-1], -2, -1)):
        if outside.any():
            out[outside] = _constant_rate(poses, ts, a, b, at[outside])
    return out


def _constant_rate(poses: np.ndarray, ts: np.ndarray, a: int, b: int, at: np.ndarray) -> np.ndarray:
    """Poses at ``at`` on the constant-rate motion through ``poses[a]`` and ``poses[b]`` (centre
    linear in time, orientation turning at a constant rate about a world axis), anchored at ``b``."""
    dt = ts[b] - ts[a]
    velocity = (poses[b, :3, 3] - poses[a, :3, 3]) / dt
    rate = Rotation.from_matrix(poses[b, :3, :3] @ poses[a, :3, :3].T).as_rotvec() / dt
    s = (at - ts[b])[:, None]
    out = np.tile(np.eye(4), (at.size, 1, 1))
    out[:, :3, :3] = (Rotation.from_rotvec(s * rate) * Rotation.from_matrix(poses[b, :3, :3])).as_matrix()
    out[:, :3, 3] = poses[b, :3, 3] + s * velocity
    return out
