"""Partition of the canonical Gaussians into background, interior and parts, from masks and joints.

Every Gaussian centre is tested in every dynamic view under the hypotheses "static" and "moves
with joint k". A hypothesis is supported where the moved centre lands on the observed surface
(sensor depth within a tolerance) inside a mask of the label it predicts, and contradicted where
it lands on the surface under another label or floats in front of the observed surface (free
space). Centres hidden behind closed part k in the closed frames, and almost never seen there,
are interior: what the part covers and the dynamic recording reveals when it opens.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.articulation._config import PartitionConfig
from artitwin_core.articulation._kinematics import world_from_part
from artitwin_core.gaussians import LABEL_BACKGROUND, LABEL_INTERIOR, LABEL_PART
from artitwin_core.joints import Joint
from artitwin_core.masks import MaskSequence


@dataclass(frozen=True)
class PartitionVotes:
    """The evidence behind the labels.

    Attributes:
        labels: ``[N]`` int32 ``LABEL_BACKGROUND``, ``LABEL_INTERIOR`` or ``LABEL_PART + k``.
        support: ``[K + 1, N]`` float observations supporting each hypothesis (row 0 static,
            row 1 + k part k).
        against: ``[K + 1, N]`` float observations contradicting it.
        hidden_closed: ``[K, N]`` closed frames in which the centre lay behind part k's surface.
    """

    labels: np.ndarray
    support: np.ndarray
    against: np.ndarray
    hidden_closed: np.ndarray


def closed_frames(joint: Joint, closed_frac: float) -> np.ndarray:
    """``[T]`` bool, frames whose state is within ``closed_frac`` of the largest |q| of the closed state."""
    q = np.abs(np.asarray(joint.q, np.float64))
    scale = max(float(q.max()) if len(q) else 0.0, 1e-9)
    return q <= closed_frac * scale


def surface_hits(
    means: np.ndarray,
    cam_from_world: np.ndarray,
    intrinsics: np.ndarray,
    depth: np.ndarray,
    depth_weight: np.ndarray,
    depth_tol_m: float,
) -> np.ndarray:
    """``[N]`` number of views in which each centre lies on the observed surface (sensor depth
    within ``depth_tol_m``); arguments as in :func:`partition_gaussians`."""
    means = np.asarray(means, np.float64)
    homo = np.concatenate([means, np.ones((len(means), 1))], 1)
    hits = np.zeros(len(means))
    _, h, w = depth.shape
    for v in range(len(cam_from_world)):
        cam = homo @ np.asarray(cam_from_world[v], np.float64).T
        z = cam[:, 2]
        fx, fy, cx, cy = intrinsics[v]
        zs = np.where(z > 1e-3, z, 1.0)
        col = np.floor(fx * cam[:, 0] / zs + cx).astype(np.int64)
        row = np.floor(fy * cam[:, 1] / zs + cy).astype(np.int64)
        ii = np.nonzero((z > 1e-3) & (col >= 0) & (col < w) & (row >= 0) & (row < h))[0]
        r, c = row[ii], col[ii]
        ok = (depth_weight[v][r, c] > 0) & (np.abs(z[ii] - depth[v][r, c]) <= depth_tol_m)
        hits[ii[ok]] += 1
    return hits


def partition_gaussians(
    means: np.ndarray,
    joints: Sequence[Joint],
    masks: MaskSequence,
    frames: Sequence[int],
    cam_from_world: np.ndarray,
    intrinsics: np.ndarray,
    depth: np.ndarray,
    depth_weight: np.ndarray,
    config: PartitionConfig = PartitionConfig(),
    seen_closed: np.ndarray | None = None,
) -> PartitionVotes:
    """Label every canonical Gaussian centre.

    Args:
        means: ``[N, 3]`` canonical centres, metres (parts closed).
        joints: one joint per part; ``joints[k].q`` is indexed by dynamic frame.
        masks: the dynamic recording's masks (part label k + 1 = joint k), ``[T, H, W]``.
        frames: ``[V]`` dynamic frame indices of the views below.
        cam_from_world: ``[V, 4, 4]`` canonical-to-camera transforms of those frames (OpenCV).
        intrinsics: ``[V, 4]`` ``(fx, fy, cx, cy)`` pixels at mask resolution.
        depth: ``[V, H, W]`` sensor depth on the mask pixel grid, metres (any value where the
            weight is 0).
        depth_weight: ``[V, H, W]`` > 0 where the depth is valid.
        config: tolerances.
        seen_closed: optional ``[N]`` observations of each centre on the surface of the static
            recording (parts closed, see :func:`surface_hits`); a centre seen there is not interior.
    """
    means = np.asarray(means, np.float64)
    n, k_parts = len(means), len(joints)
    _, h, w = masks.part.shape
    if depth.shape[1:] != (h, w):
        raise InputError(
            f"partition: masks are {w}x{h} pixels but the depth views are {depth.shape[2]}x{depth.shape[1]}; "
            "give masks at the dynamic recording's RGB resolution."
        )
    for k, j in enumerate(joints):
        if len(j.q) != masks.part.shape[0]:
            raise InputError(
                f"partition: joint {k} has {len(j.q)} states but the masks have {masks.part.shape[0]} frames; "
                "joints and masks must come from the same dynamic recording."
            )
    support = np.zeros((k_parts + 1, n))
    against = np.zeros((k_parts + 1, n))
    hidden = np.zeros((k_parts, n))
    visible_closed = np.zeros((k_parts, n))
    closed = [closed_frames(j, config.closed_frac) for j in joints]
    tol = config.depth_tol_m
    homo = np.concatenate([means, np.ones((n, 1))], 1)
    for v, t in enumerate(frames):
        label = masks.part[t].astype(np.int64)
        hand = masks.hand[t]
        for hyp in range(k_parts + 1):
            motion = np.eye(4) if hyp == 0 else world_from_part(joints[hyp - 1], float(joints[hyp - 1].q[t]))
            cam = homo @ (cam_from_world[v] @ motion).T
            z = cam[:, 2]
            fx, fy, cx, cy = intrinsics[v]
            zs = np.where(z > 1e-3, z, 1.0)
            col = np.floor(fx * cam[:, 0] / zs + cx).astype(np.int64)
            row = np.floor(fy * cam[:, 1] / zs + cy).astype(np.int64)
            inside = (z > 1e-3) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
            ii = np.nonzero(inside)[0]
            r, c = row[ii], col[ii]
            ok = (depth_weight[v][r, c] > 0) & ~hand[r, c]
            ii, r, c = ii[ok], r[ok], c[ok]
            d, lab, zi = depth[v][r, c], label[r, c], z[ii]
            on_surface = np.abs(zi - d) <= tol
            in_front = zi < d - tol
            expected = 0 if hyp == 0 else hyp
            agree = on_surface & (lab == expected)
            np.add.at(support[hyp], ii[agree], 1.0)
            np.add.at(against[hyp], ii[on_surface & ~agree], 1.0)
            np.add.at(against[hyp], ii[in_front], config.free_space_weight)
            if hyp == 0:
                for k in range(k_parts):
                    if closed[k][t]:
                        behind = (zi > d + tol) & (lab == k + 1)
                        np.add.at(hidden[k], ii[behind], 1.0)
                        np.add.at(visible_closed[k], ii[on_surface & (lab == 0)], 1.0)
    labels = np.full(n, LABEL_BACKGROUND, np.int32)
    if k_parts:
        net = support - against
        best = 1 + np.argmax(net[1:], axis=0)
        best_net = np.take_along_axis(net, best[None], 0)[0]
        best_support = np.take_along_axis(support, best[None], 0)[0]
        is_part = (best_support >= config.min_agree) & (best_net > net[0])
        labels[is_part] = LABEL_PART + best[is_part] - 1
        hk = np.argmax(hidden, axis=0)
        h_best = np.take_along_axis(hidden, hk[None], 0)[0]
        seen = np.take_along_axis(visible_closed, hk[None], 0)[0]
        interior = ~is_part & (h_best >= 1) & (seen <= config.interior_visible_frac * h_best)
        if seen_closed is not None:
            interior &= np.asarray(seen_closed) <= 0
        labels[interior] = LABEL_INTERIOR
    return PartitionVotes(labels=labels, support=support, against=against, hidden_closed=hidden)
