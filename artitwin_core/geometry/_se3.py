"""SE(3) and SO(3) helpers on numpy arrays (float64)."""

from __future__ import annotations

import numpy as np

# Flips camera y and z: OpenGL camera axes (x right, y up, z backwards) <-> OpenCV (x right,
# y down, z forwards). Its own inverse: world_from_cv = world_from_gl @ OPENGL_FROM_OPENCV.
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[..., 4]`` (w, x, y, z) to rotation matrices ``[..., 3, 3]``.

    The quaternion is normalised first; a zero quaternion raises ``ValueError``.
    """
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("zero-length quaternion")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat_wxyz(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` to unit quaternions ``[..., 4]`` (w, x, y, z), w >= 0."""
    rot = np.asarray(rot, dtype=np.float64)
    batch = rot.shape[:-2]
    m = rot.reshape(-1, 3, 3)
    out = np.empty((m.shape[0], 4))
    tr = np.trace(m, axis1=1, axis2=2)
    # Shepperd's method: pick the largest of (w, x, y, z) to divide by, for stability.
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], -1)
    pick = np.argmax(cand, -1)
    for i in range(m.shape[0]):
        r = m[i]
        if pick[i] == 0:
            s = np.sqrt(max(tr[i] + 1.0, 0.0)) * 2
            out[i] = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        elif pick[i] == 1:
            s = np.sqrt(max(1.0 + r[0, 0] - r[1, 1] - r[2, 2], 0.0)) * 2
            out[i] = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
        elif pick[i] == 2:
            s = np.sqrt(max(1.0 + r[1, 1] - r[0, 0] - r[2, 2], 0.0)) * 2
            out[i] = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
        else:
            s = np.sqrt(max(1.0 + r[2, 2] - r[0, 0] - r[1, 1], 0.0)) * 2
            out[i] = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    out /= np.linalg.norm(out, axis=-1, keepdims=True)
    out[out[:, 0] < 0] *= -1
    return out.reshape(*batch, 4)


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
