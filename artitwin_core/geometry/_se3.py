"""SE(3) and SO(3) helpers on numpy arrays (float64)."""

from __future__ import annotations

import numpy as np

# Flips camera y and z: OpenGL camera axes (x right, y up, z backwards) <-> OpenCV (x right,
# y down, z forwards). Its own inverse: world_from_cv = world_from_gl @ OPENGL_FROM_OPENCV.
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def axis_angle_to_matrix(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Rodrigues: unit ``axis [3]`` and ``angle`` (radians, scalar or ``[N]``) to ``[..., 3, 3]``."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    angle = np.asarray(angle, dtype=np.float64)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s = np.sin(angle)[..., None, None]
    c = np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def make_se3(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Stack ``rot [..., 3, 3]`` and ``trans [..., 3]`` into ``[..., 4, 4]``."""
    rot = np.asarray(rot, dtype=np.float64)
    trans = np.asarray(trans, dtype=np.float64)
    out = np.zeros(rot.shape[:-2] + (4, 4))
    out[..., :3, :3] = rot
    out[..., :3, 3] = trans
    out[..., 3, 3] = 1.0
    return out


def invert_se3(t: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``[..., 4, 4]`` (uses R^T, not a general inverse)."""
    t = np.asarray(t, dtype=np.float64)
    rot_t = np.swapaxes(t[..., :3, :3], -1, -2)
    return make_se3(rot_t, -(rot_t @ t[..., :3, 3, None])[..., 0])


def transform_points(t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``t [4, 4]`` to ``points [..., 3]``."""
    points = np.asarray(points, dtype=np.float64)
    return points @ t[:3, :3].T + t[:3, 3]


def check_rigid(t: np.ndarray, tol: float = 1e-3) -> str | None:
    """Return why ``t [4, 4]`` is not a finite rigid transform, or ``None`` if it is one.

    ``tol`` bounds ``|R^T R - I|`` and ``|det R - 1|``; poses from AR sessions are float32
    round-tripped, so 1e-3 accepts them while rejecting scaled or sheared matrices.
    """
    t = np.asarray(t, dtype=np.float64)
    if t.shape != (4, 4):
        return f"shape {t.shape}, expected (4, 4)"
    if not np.all(np.isfinite(t)):
        return "contains NaN or infinity"
    if np.max(np.abs(t[3] - [0, 0, 0, 1])) > tol:
        return f"last row is {t[3].tolist()}, expected [0, 0, 0, 1]"
    rot = t[:3, :3]
    orth = np.max(np.abs(rot.T @ rot - np.eye(3)))
    if orth > tol:
        return f"rotation part is not orthonormal (|R^T R - I| = {orth:.3g})"
    det = np.linalg.det(rot)
    if abs(det - 1) > tol:
        return f"rotation determinant is {det:.4f}, expected 1 (reflection or scale)"
    return None
