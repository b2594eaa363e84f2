"""Splat arrays for a browser renderer, part poses at slider states, and a heat-map palette.

The viewer moves a part by giving its scene node the rigid pose ``world_from_part(q)``, so a
slider step sends one 4x4 per part instead of the part's Gaussians. ``pose_splats`` is the plain
reference of what that must look like: every part Gaussian's centre and covariance moved by its
part's pose, for tests and for renderers without per-node transforms.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.gaussians import LABEL_PART, GaussianParams
from artitwin_core.geometry import quat_wxyz_to_matrix
from artitwin_core.joints import Joint, joint_transforms

SH_C0 = 0.28209479177387814  # degree-0 spherical-harmonic basis; colour = 0.5 + SH_C0 * sh_dc


def splat_arrays(params: GaussianParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What a splat renderer takes: view-independent colour (the SH DC term) and covariances.

    Returns:
        centers ``[N, 3]`` float32 metres, covariances ``[N, 3, 3]`` float32 m^2 (``R S^2 R^T``),
        rgbs ``[N, 3]`` float32 in [0, 1], opacities ``[N, 1]`` float32 in [0, 1].
    """
    rot = quat_wxyz_to_matrix(params.quats_wxyz)
    var = np.exp(2.0 * np.asarray(params.log_scales, np.float64))
    cov = np.einsum("nij,nj,nkj->nik", rot, var, rot)
    rgb = np.clip(0.5 + SH_C0 * np.asarray(params.sh, np.float64)[:, 0], 0.0, 1.0)
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(params.opacity_logits, np.float64)))
    return (
        np.asarray(params.means, np.float32),
        cov.astype(np.float32),
        rgb.astype(np.float32),
        opacity[:, None].astype(np.float32),
    )


def slider_range(joint: Joint) -> tuple[float, float]:
    """The slider's ``(lo, hi)``: the estimated ``q_range``, widened to include 0 (the closed twin).

    A degenerate or non-finite range (a joint seen barely moving) gets a usable default span:
    a quarter turn for rotations, 0.3 m for slides.
    """
    lo, hi = (float(v) for v in np.asarray(joint.q_range, np.float64))
    if not (np.isfinite(lo) and np.isfinite(hi)):
        lo = hi = 0.0
    lo, hi = min(lo, 0.0), max(hi, 0.0)
    if hi - lo < 1e-6:
        hi = lo + (0.3 if joint.joint_type == "prismatic" else np.pi / 2)
    return lo, hi


def part_poses(joints: tuple[Joint, ...] | list[Joint], q: np.ndarray) -> np.ndarray:
    """``[K, 4, 4]`` ``world_from_part`` of each part at states ``q [K]`` (radians or metres).

    The part frame is the canonical frame at the closed state, so a closed-state point ``x`` of
    part k is drawn at ``world_from_part[k] @ x``.
    """
    q = np.asarray(q, np.float64).reshape(-1)
    if q.shape[0] != len(joints):
        raise ValueError(f"part_poses: {q.shape[0]} states for {len(joints)} joints")
    out = np.tile(np.eye(4), (len(joints), 1, 1))
    for k, j in enumerate(joints):
        out[k] = joint_transforms(j.joint_type, j.axis, j.pivot, q[k : k + 1], j.pitch)[0]
    return out


def pose_splats(
    centers: np.ndarray, covariances: np.ndarray, labels: np.ndarray, world_from_part: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Reference: move every part Gaussian by its part's pose.

    Args:
        centers: ``[N, 3]`` closed-state centres, metres.
        covariances: ``[N, 3, 3]`` closed-state covariances, m^2.
        labels: ``[N]`` 0 background, 1 interior, 2 + k part k.
        world_from_part: ``[K, 4, 4]`` part poses (``part_poses``).

    Returns:
        centers ``[N, 3]`` and covariances ``[N, 3, 3]`` (``R x + t`` and ``R C R^T`` for part
        Gaussians, unchanged otherwise), float32.
    """
    centers = np.array(centers, np.float32)
    covariances = np.array(covariances, np.float32)
    labels = np.asarray(labels)
    for k, pose in enumerate(np.asarray(world_from_part, np.float64)):
        sel = labels == LABEL_PART + k
        if not sel.any():
            continue
        rot = pose[:3, :3].astype(np.float32)
        centers[sel] = centers[sel] @ rot.T + pose[:3, 3].astype(np.float32)
        covariances[sel] = rot @ covariances[sel] @ rot.T
    return centers, covariances


# Perceptually ordered dark-blue -> teal -> yellow stops (viridis-like), for residual heat maps.
_HEAT_STOPS = np.array(
    [[0.267, 0.005, 0.329], [0.230, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]]
)
_NO_DATA = np.array([0.6, 0.6, 0.6])


def heat_colors(values: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """``[N, 3]`` float32 colours in [0, 1] for ``values [N]``; NaN is grey.

    ``lo``/``hi`` default to the 2nd and 98th percentiles of the finite values, so one outlier
    does not wash the map out.
    """
    v = np.asarray(values, np.float64).reshape(-1)
    finite = np.isfinite(v)
    out = np.tile(_NO_DATA, (v.shape[0], 1))
    if not finite.any():
        return out.astype(np.float32)
    lo = float(np.percentile(v[finite], 2)) if lo is None else float(lo)
    hi = float(np.percentile(v[finite], 98)) if hi is None else float(hi)
    t = np.clip((v[finite] - lo) / max(hi - lo, 1e-12), 0.0, 1.0) * (len(_HEAT_STOPS) - 1)
    i = np.minimum(t.astype(int), len(_HEAT_STOPS) - 2)
    f = (t - i)[:, None]
    out[finite] = _HEAT_STOPS[i] * (1 - f) + _HEAT_STOPS[i + 1] * f
    return out.astype(np.float32)
