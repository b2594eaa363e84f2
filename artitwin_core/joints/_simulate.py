"""Synthetic point trajectories from a ground-truth joint, for tests and benchmarks.

Outliers mimic what a 2D tracker lifted to 3D produces on a real recording: tracks on the static
background (they never move), tracks that slide off the part onto the background mid-sequence,
tracks on the hand (a smooth random path), and part tracks that jump in a few frames.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.joints._model import joint_motion
from artitwin_core.joints._types import Joint, JointType
from artitwin_core.tracking import Trajectories


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 2] = -q[:, 2]
    return q


def opening_profile(n_frames: int, q_max: float, rng: np.random.Generator) -> np.ndarray:
    """``[T]`` smooth state: rest at 0, ease-in-out opening to ``q_max``, maybe a partial close."""
    t = np.linspace(0.0, 1.0, n_frames)
    start = rng.uniform(0.05, 0.15)
    peak = rng.uniform(0.6, 0.9)
    u = np.clip((t - start) / (peak - start), 0.0, 1.0)
    q = q_max * (0.5 - 0.5 * np.cos(np.pi * u))
    back = rng.uniform(0.0, 0.3)
    tail = np.clip((t - peak) / max(1.0 - peak, 1e-6), 0.0, 1.0)
    return q * (1.0 - back * tail)


def random_part_joint(
    joint_type: JointType, n_tracks: int, n_frames: int, rng: np.random.Generator
) -> tuple[Joint, np.ndarray]:
    """A random door-, drawer- or knob-like part and its joint.

    The part is a 0.4 x 0.6 x 0.03 m slab at a random orientation 1-3 m from the origin (the
    camera). Revolute: the hinge runs along one long edge, up to 90 degrees. Prismatic: along the
    slab's normal, up to 0.35 m. Screw: axis through the slab, pitch 0.02-0.1 m/rad, up to 90
    degrees. Fixed: ``q = 0``.

    Returns:
        The ground-truth ``Joint`` (``residual`` zeros, ``confidence`` ones) and the closed-state
        points ``[N, 3]`` metres.
    """
    rot = _random_rotation(rng)
    centre = _unit(rng.normal(size=3)) * rng.uniform(1.0, 3.0)
    local = rng.uniform([-0.2, -0.3, -0.015], [0.2, 0.3, 0.015], size=(n_tracks, 3))
    points = local @ rot.T + centre
    pitch = 0.0
    if joint_type == "revolute":
        axis = rot[:, 1]
        pivot = centre + 0.2 * rot[:, 0] * rng.choice([-1.0, 1.0])
        q_max = np.deg2rad(rng.uniform(30.0, 90.0))
    elif joint_type == "prismatic":
        axis = rot[:, 2]
        pivot = centre
        q_max = rng.uniform(0.1, 0.35)
    elif joint_type == "screw":
        axis = _unit(rot[:, 2] + 0.3 * rng.normal(size=3))
        pivot = centre + 0.05 * rng.normal(size=3)
        pitch = rng.uniform(0.02, 0.1) * rng.choice([-1.0, 1.0])
        q_max = np.deg2rad(rng.uniform(30.0, 90.0))
    elif joint_type == "fixed":
        axis = np.array([0.0, 0.0, 1.0])
        pivot = centre
        q_max = 0.0
    else:
        raise ValueError(f"unknown joint_type {joint_type!r}")
    q = opening_profile(n_frames, q_max, rng)
    if joint_type != "fixed" and rng.random() < 0.5:
        # Random sign of the axis: the estimator must flip it so the opening is positive.
        axis, q = -axis, -q
    finite_q = q if joint_type != "fixed" else np.zeros(n_frames)
    joint = Joint(
        joint_type=joint_type,
        axis=axis,
        pivot=pivot,
        q=finite_q,
        q_range=np.array([finite_q.min(), finite_q.max()]),
        residual=np.zeros(n_frames),
        confidence=np.ones(n_frames),
        pitch=pitch,
    )
    return joint, points


def simulate_trajectories(
    joint: Joint,
    points_closed: np.ndarray,
    rng: np.random.Generator,
    *,
    noise_m: float = 0.0,
    noise_grows_with_depth: bool = False,
    outlier_fraction: float = 0.0,
    invalid_fraction: float = 0.0,
) -> tuple[Trajectories, np.ndarray]:
    """Trajectories of ``points_closed [N, 3]`` metres moved by ``joint`` (``q [T]``), corrupted.

    Args:
        joint: the ground truth; frame t shows the part at ``joint.q[t]``.
        points_closed: ``[N, 3]`` metres, the part's points at ``q = 0``.
        rng: random generator (fixed seed for reproducible tests).
        noise_m: per-coordinate Gaussian noise, metres (at 1 m depth if ``noise_grows_with_depth``).
        noise_grows_with_depth: scale the noise by ``depth^2`` (depth = distance to the origin),
            as for stereo and structured-light sensors.
        outlier_fraction: fraction of tracks replaced by outliers, split between background,
            sliding, hand and jumping tracks.
        invalid_fraction: fraction of (frame, track) entries marked invalid (NaN).

    Returns:
        ``Trajectories`` (``pixels`` all NaN: no camera is simulated) and ``is_part [N]`` bool,
        True for the tracks that follow the joint in every frame (jumping tracks are False).
    """
    q = np.asarray(joint.q, dtype=np.float64)
    t_count, n = q.shape[0], points_closed.shape[0]
    rot, trans = joint_motion(joint.joint_type, joint.axis, joint.pivot, q, joint.pitch)
    pts = np.einsum("tij,nj->tni", rot, points_closed) + trans[:, None, :]
    is_part = np.ones(n, bool)
    n_out = int(round(outlier_fraction * n))
    out_idx = rng.choice(n, n_out, replace=False)
    kinds = rng.integers(0, 4, n_out)
    for i, kind in zip(out_idx, kinds, strict=True):
        is_part[i] = False
        if kind == 0:  # background just beside the part: never moves
            pts[:, i] = points_closed[i] + rng.normal(scale=0.05, size=3)
        elif kind == 1:  # slides off the part onto the background at a random frame
            k = rng.integers(1, max(t_count - 1, 2))
            pts[k:, i] = pts[k - 1, i]
        elif kind == 2:  # on the hand: a smooth random path near the part
            start = pts[0, i] + rng.normal(scale=0.1, size=3)
            steps = np.cumsum(rng.normal(scale=0.02, size=(t_count, 3)), axis=0)
            pts[:, i] = start + steps
        else:  # jumps by 5-30 cm in 30% of the frames
            jump = rng.random(t_count) < 0.3
            offs = _unit_rows(rng.normal(size=(t_count, 3))) * rng.uniform(0.05, 0.3, size=(t_count, 1))
            pts[jump, i] += offs[jump]
    if noise_m > 0:
        scale = noise_m
        if noise_grows_with_depth:
            scale = noise_m * np.sum(pts**2, axis=-1, keepdims=True)
        pts = pts + rng.normal(size=pts.shape) * scale
    valid = rng.random((t_count, n)) >= invalid_fraction
    pts = np.where(valid[..., None], pts, np.nan)
    traj = Trajectories(
        points_in_world=pts,
        pixels=np.full((t_count, n, 2), np.nan, dtype=np.float32),
        valid=valid,
        query_frame=0,
    )
    return traj, is_part


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)
