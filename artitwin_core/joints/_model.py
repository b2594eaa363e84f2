"""Forward kinematics of one joint: the rigid motion of the part at state ``q``.

Every joint type is a one-parameter subgroup of SE(3) (``M(q1 + q2) = M(q1) M(q2)``), which the
estimator relies on to move the closed state (``q = 0``) onto any frame after fitting.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.joints._types import JOINT_TYPES, JointType


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[..., 3, 3]`` of vectors ``v [..., 3]``."""
    v = np.asarray(v, dtype=np.float64)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def rotations_about(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rodrigues for one unit ``axis [3]`` and many ``angles [T]`` radians: ``[T, 3, 3]``."""
    k = skew(np.asarray(axis, dtype=np.float64))
    angles = np.asarray(angles, dtype=np.float64)
    s = np.sin(angles)[:, None, None]
    c = np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def joint_motion(
    joint_type: JointType, axis: np.ndarray, pivot: np.ndarray, q: np.ndarray, pitch: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Rotations ``[T, 3, 3]`` and translations ``[T, 3]`` metres of the part at states ``q [T]``.

    A closed-state point ``x`` moves to ``R[t] @ x + t[t]``. ``axis [3]`` is normalised here;
    ``pivot [3]`` metres is any point of the axis line; ``q`` is radians (revolute, screw) or
    metres (prismatic); ``pitch`` is metres per radian (screw only).
    """
    if joint_type not in JOINT_TYPES:
        raise ValueError(f"joint_type {joint_type!r} is not one of {JOINT_TYPES}")
    q = np.atleast_1d(np.asarray(q, dtype=np.float64))
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    pivot = np.asarray(pivot, dtype=np.float64)
    n = q.shape[0]
    if joint_type == "fixed":
        return np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), np.zeros((n, 3))
    if joint_type == "prismatic":
        return np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), q[:, None] * axis
    rot = rotations_about(axis, q)
    trans = pivot - rot @ pivot
    if joint_type == "screw":
        trans = trans + (pitch * q)[:, None] * axis
    return rot, trans


def joint_transforms(
    joint_type: JointType, axis: np.ndarray, pivot: np.ndarray, q: np.ndarray, pitch: float = 0.0
) -> np.ndarray:
    """``[T, 4, 4]`` float64 ``world_from_closed`` part motions at states ``q [T]`` (see ``joint_motion``)."""
    rot, trans = joint_motion(joint_type, axis, pivot, q, pitch)
    out = np.zeros((rot.shape[0], 4, 4))
    out[:, :3, :3] = rot
    out[:, :3, 3] = trans
    out[:, 3, 3] = 1.0
    return out
