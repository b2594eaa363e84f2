"""Unit quaternions, scalar first ``[w, x, y, z]`` (gsplat's rasterizer and jaxlie's order).

One implementation for numpy arrays and torch tensors: the capture readers and exporters turn
file rows into pose matrices with it, the trainers turn Gaussian rotations into matrices with it.

A quaternion is normalised before use, so any non-zero length is accepted. A zero quaternion
maps to the identity rotation. That is what the rasterizer draws for a Gaussian whose free
rotation parameters reached zero (``q / max(|q|, 1e-12)`` is zero, and a zero quaternion's
matrix formula gives I), and it keeps the torch form free of a host sync to raise. Readers of
pose files check the norm themselves, where they can name the file and frame.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import numpy as np

_ZERO_NORM = 1e-12  # below this a quaternion counts as zero (the rasterizer's clamp)


def _is_torch(x) -> bool:
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


def quat_wxyz_to_matrix(q):
    """Rotation matrices ``[..., 3, 3]`` of quaternions ``[..., 4]`` (w, x, y, z), any norm.

    numpy in, float64 numpy out; a torch tensor in, a tensor of its dtype and device out
    (differentiable). A zero quaternion gives the identity (see the module docstring).
    """
    if _is_torch(q):
        import torch

        q = q / q.norm(dim=-1, keepdim=True).clamp_min(_ZERO_NORM)
        return _matrix_of(torch.stack, *q.unbind(-1))
    q = np.asarray(q, dtype=np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), _ZERO_NORM)
    return _matrix_of(np.stack, *np.moveaxis(q, -1, 0))


def _matrix_of(stack: Callable[..., Any], w: Any, x: Any, y: Any, z: Any) -> Any:
    """The rotation matrix of a unit quaternion's components, built with ``stack`` (numpy's or torch's)."""
    return stack(
        [
            stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat_wxyz(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` to unit quaternions ``[..., 4]`` (w, x, y, z), ``w >= 0``.

    Shepperd's method: each matrix divides by the largest of ``4w^2, 4x^2, 4y^2, 4z^2``, so no
    branch loses precision near a half turn. Of the two quaternions of a rotation, the one with
    ``w >= 0`` is returned. numpy, float64.
    """
    m = np.asarray(rot, dtype=np.float64)
    batch = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    r = {(i, j): m[:, i, j] for i in range(3) for j in range(3)}
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    # Every row of ``cand`` is 4 q q_k for one k (w, x, y, z): the quaternion up to scale and sign.
    cand = np.stack(
        [
            np.stack([1 + tr, r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]], -1),
            np.stack([r[2, 1] - r[1, 2], 1 + 2 * r[0, 0] - tr, r[0, 1] + r[1, 0], r[0, 2] + r[2, 0]], -1),
            np.stack([r[0, 2] - r[2, 0], r[0, 1] + r[1, 0], 1 + 2 * r[1, 1] - tr, r[1, 2] + r[2, 1]], -1),
            np.stack([r[1, 0] - r[0, 1], r[0, 2] + r[2, 0], r[1, 2] + r[2, 1], 1 + 2 * r[2, 2] - tr], -1),
        ],
        1,
    )  # [B, 4 (k), 4]
    pick = np.argmax(np.stack([tr, r[0, 0], r[1, 1], r[2, 2]], -1), -1)
    q = cand[np.arange(len(m)), pick]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[:, :1] < 0, -q, q)
    return q.reshape(*batch, 4)
