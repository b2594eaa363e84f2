"""The part's surface as depth sees it, shared by the state and axis refinements.

Frames' part pixels are lifted to canonical points with normals (``lift_frame``), moved back to
the closed state by a joint (``to_closed``) and merged into a closed-state point model with
normals turned towards the cameras (``build_model``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from artitwin_core.capture import Capture
from artitwin_core.geometry import unique_rows
from artitwin_core.joints._config import StateRefineConfig
from artitwin_core.joints._model import joint_motion
from artitwin_core.joints._types import Joint
from artitwin_core.masks import MaskSequence
from artitwin_core.tracking._lift import lift_pixels


@dataclass
class SurfaceModel:
    points: np.ndarray  # [M, 3] closed-state points
    normals: np.ndarray  # [M, 3]
    tree: cKDTree


def lift_frame(
    capture: Capture, masks: MaskSequence, t: int, label: int, c_from_s, cfg
) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """Canonical points ``[N, 3]`` of frame ``t``'s part pixels (eroded, hand excluded), their
    unsigned surface normals ``[N, 3]`` (None when the normal gate is off), and whether the
    mask was eroded (False: the sliver fallback below).

    The erosion keeps mixed depth at the part's outline out. A part seen nearly edge-on (a door
    opened past the camera's line of sight) is a sliver a few pixels wide that the erosion
    removes whole: when the eroded mask leaves fewer than ``min_points`` points, the mask is
    lifted uneroded (the depth-edge and confidence tests still drop its mixed pixels), and the
    last frames of a door opened past the line of sight can be fitted (see
    ``StateRefineConfig.tail_max_se_rad``; docs/accuracy.md). Such
    a sliver is too thin to show a face's plane: ``refine_joint_states`` keeps it out of the
    hinge line's plane fit.

    Normals come from a denser lift (``normal_oversample`` times the points kept): from the
    kept subsample alone, a door mostly out of view or cut by a hand gives too few neighbours."""
    part = (masks.part[t] == label).astype(np.uint8)
    hand: np.ndarray = np.asarray(masks.hand[t]).astype(np.uint8)
    grow = int(np.ceil(cfg.hand_dilate_depth_px * hand.shape[1] / np.asarray(capture.depth[t]).shape[1]))
    if grow > 0 and hand.any():
        k = 2 * grow + 1
        hand = cv2.dilate(hand, np.ones((k, k), np.uint8))
    if cfg.mask_erode_px > 0:
        k = 2 * cfg.mask_erode_px + 1
        pts = _lift_mask(capture, t, cv2.erode(part, np.ones((k, k), np.uint8)), hand, c_from_s, cfg)
        if pts.shape[0] >= cfg.min_points:
            return (*_with_normals(pts, cfg), True)
    return (*_with_normals(_lift_mask(capture, t, part, hand, c_from_s, cfg), cfg), cfg.mask_erode_px <= 0)


def _lift_mask(capture: Capture, t: int, mask: np.ndarray, hand: np.ndarray, c_from_s, cfg) -> np.ndarray:
    """Canonical points ``[N, 3]`` of ``mask``'s pixels outside ``hand`` with trusted depth (at
    most ``max_points * normal_oversample`` pixels, evenly subsampled)."""
    v, u = np.nonzero(mask.astype(bool) & ~hand.astype(bool))
    dense = cfg.max_points * (cfg.normal_oversample if cfg.normal_gate_deg < 90.0 else 1)
    if u.size > dense:
        idx = np.linspace(0, u.size - 1, dense).astype(np.int64)
        u, v = u[idx], v[idx]
    if u.size == 0:
        return np.zeros((0, 3))
    pose = c_from_s @ np.asarray(capture.world_from_camera[t], dtype=np.float64)
    pts, ok = lift_pixels(
        np.stack([u, v], -1).astype(np.float64),
        np.asarray(capture.depth[t]),
        None if capture.confidence is None else np.asarray(capture.confidence[t]),
        np.asarray(capture.rgb_intrinsics[t]),
        np.asarray(capture.depth_intrinsics[t]),
        pose,
        capture.distortion,
        edge_rel=cfg.edge_rel,
        min_confidence=cfg.min_depth_confidence,
    )
    return pts[ok]


def _with_normals(pts: np.ndarray, cfg) -> tuple[np.ndarray, np.ndarray | None]:
    """``pts`` with their normals (see ``lift_frame``), subsampled to ``max_points``."""
    if pts.shape[0] == 0:
        return pts, None
    normals = None
    if cfg.normal_gate_deg < 90.0 and pts.shape[0] >= 3:
        normals = cloud_normals(pts, cfg)
    if pts.shape[0] > cfg.max_points:
        keep = np.linspace(0, pts.shape[0] - 1, cfg.max_points).astype(np.int64)
        pts = pts[keep]
        normals = None if normals is None else normals[keep]
    return pts, normals


def to_closed(joint: Joint, pts: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Closed-state positions ``[Q, N, 3]`` of frame points ``[N, 3]`` under states ``q [Q]``."""
    rot, trans = joint_motion(joint.joint_type, joint.axis, joint.pivot, q, joint.pitch)
    # x = R c + t  =>  c = R^T (x - t)
    return np.einsum("qji,qnj->qni", rot, pts[None] - trans[:, None, :])


def cloud_normals(points: np.ndarray, cfg: StateRefineConfig) -> np.ndarray:
    """Unsigned PCA normals ``[N, 3]`` of one frame's points ``[N, 3]``."""
    k = min(cfg.frame_normal_neighbours, points.shape[0])
    _, nn = cKDTree(points).query(points, k=k, workers=-1)
    near = points[nn]
    nb = near - near.mean(1, keepdims=True)
    return np.linalg.eigh(np.einsum("mki,mkj->mij", nb, nb))[1][:, :, 0]


def build_model(points: np.ndarray, views: np.ndarray, cfg: StateRefineConfig) -> SurfaceModel | None:
    """Voxel-merged closed-state model with normals turned towards the cameras that saw it.

    ``points [N, 3]`` closed-state metres; ``views [N, 3]`` unit directions from each point
    towards its camera, in the same frame. PCA normals have no sign; without a consistent one
    the point-to-plane residuals of one surface split into two modes of opposite sign.
    """
    if points.shape[0] < cfg.normal_neighbours:
        return None
    keys = np.floor(points / cfg.voxel_m).astype(np.int64)
    _, inv, counts = unique_rows(keys)
    merged = np.zeros((counts.size, 3))
    np.add.at(merged, inv, points)
    merged /= counts[:, None]
    view = np.zeros((counts.size, 3))
    np.add.at(view, inv, views)
    if merged.shape[0] < cfg.normal_neighbours:
        return None
    tree = cKDTree(merged)
    _, nn = tree.query(merged, k=cfg.normal_neighbours, workers=-1)
    near = merged[nn]
    centroid = near.mean(1)
    nb = near - centroid[:, None, :]
    cov = np.einsum("mki,mkj->mij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]
    normals *= np.where(np.sum(normals * view, axis=1) < 0, -1.0, 1.0)[:, None]
    if cfg.smooth_model:
        # Each point onto its neighbours' plane: depth noise in the model would otherwise bias
        # which model point is nearest to a frame point, unevenly across the surface.
        merged = merged - np.sum((merged - centroid) * normals, axis=1, keepdims=True) * normals
        tree = cKDTree(merged)
    return SurfaceModel(merged, normals, tree)

