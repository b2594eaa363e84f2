"""Keyframes of a long recording, chosen from its poses and depth before any image is decoded.

A phone records 30-60 frames a second and neighbouring frames see nearly the same thing. A
recording longer than ``max_frames`` keeps a frame when enough has changed since the last one
kept: the view (camera travel over the scene's depth plus rotation: keyframes then overlap
alike, and cover the sweep evenly) or the scene itself (the share of depth pixels that moved:
where a part moves, frames are kept densely), and at least one every ``max_gap_s``. Frames that
see surface no keyframe sees are added back (coverage). The change thresholds are scaled
together until at most ``max_frames`` frames are kept; a recording of ``max_frames`` or fewer
is kept whole.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artitwin_core.capture._config import KeyframeConfig
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import backproject


@dataclass(frozen=True)
class KeyframeSelection:
    """The frames kept and why.

    Attributes:
        frames: ``[K]`` ascending positions of the kept frames in the capture.
        added_for_coverage: ``[C]`` the positions among ``frames`` added back for coverage.
        scale: how much the change thresholds were widened to meet ``max_frames`` (1 = not).
        scene_change: ``[T]`` share of each frame's depth pixels that moved since the keyframe
            before it (0 where not measured; large where a part or a hand moves).
    """

    frames: np.ndarray
    added_for_coverage: np.ndarray
    scale: float
    scene_change: np.ndarray


def _points(capture: Capture, t: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """World points ``[M, 3]`` of frame ``t``'s valid depth on a ``step``-pixel grid and the depth-pixel
    coordinates ``[M, 2]`` they came from."""
    d = capture.depth[t, ::step, ::step]
    vv, uu = np.mgrid[0 : capture.depth.shape[1] : step, 0 : capture.depth.shape[2] : step]
    ok = np.isfinite(d) & (d > 0)
    if capture.confidence is not None:
        ok &= capture.confidence[t, ::step, ::step] >= 1
    cam = backproject(d[ok], capture.depth_intrinsics[t], uu[ok], vv[ok])
    pose = capture.world_from_camera[t]
    return cam @ pose[:3, :3].T + pose[:3, 3], np.stack([uu[ok], vv[ok]], 1)


def _moved_share(capture: Capture, world: np.ndarray, k: int, tol_m: float) -> float:
    """Share of the points ``world`` (from some frame) that keyframe ``k`` sees at another depth."""
    if not len(world):
        return 0.0
    pose = capture.world_from_camera[k]
    cam = (world - pose[:3, 3]) @ pose[:3, :3]
    z = cam[:, 2]
    fx, fy, cx, cy = capture.depth_intrinsics[k]
    h, w = capture.depth.shape[1:]
    front = z > 1e-3
    u = np.round(np.where(front, cam[:, 0] / np.where(front, z, 1) * fx + cx, -1)).astype(np.int64)
    v = np.round(np.where(front, cam[:, 1] / np.where(front, z, 1) * fy + cy, -1)).astype(np.int64)
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    if not inside.any():
        return 0.0
    dk = capture.depth[k][v[inside], u[inside]].astype(np.float64)
    ok = np.isfinite(dk) & (dk > 0)
    if not ok.any():
        return 0.0
    zi = z[inside][ok]
    moved = np.abs(zi - dk[ok]) > tol_m + 0.02 * zi
    return float(moved.mean()) * float(ok.sum()) / len(world)


def _rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    c = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def _greedy(capture: Capture, config: KeyframeConfig, scale: float, points, median_depth, change) -> list[int]:
    keys = [0]
    t = capture.timestamps
    centres = capture.world_from_camera[:, :3, 3]
    for i in range(1, capture.num_frames):
        k = keys[-1]
        view = np.linalg.norm(centres[i] - centres[k]) / median_depth[k] + _rotation_angle(
            capture.world_from_camera[k], capture.world_from_camera[i]
        )
        if view >= scale * config.view_step or t[i] - t[k] >= scale * config.max_gap_s:
            keys.append(i)
            continue
        if (i, k) not in change:
            change[(i, k)] = _moved_share(capture, points[i], k, config.depth_tol_m)
        if change[(i, k)] >= scale * config.change_step:
            keys.append(i)
    if keys[-1] != capture.num_frames - 1:
        keys.append(capture.num_frames - 1)
    return keys


def _voxels(points: np.ndarray, voxel: float) -> set:
    return set(map(tuple, np.unique(np.floor(points / voxel).astype(np.int64), axis=0))) if len(points) else set()


def select_keyframes(capture: Capture, config: KeyframeConfig = KeyframeConfig()) -> KeyframeSelection:
    """Choose the keyframes of ``capture`` from its poses, timestamps and depth (its RGB is not
    read: a ``ReadOptions(skip_rgb=True)`` capture will do). See the module docstring."""
    n = capture.num_frames
    if n <= config.max_frames:
        return KeyframeSelection(np.arange(n), np.zeros(0, np.int64), 1.0, np.zeros(n))
    step = max(1, int(config.grid_px))
    points = [_points(capture, t, step)[0] for t in range(n)]
    median_depth = np.array([float(np.median(np.linalg.norm(p - capture.world_from_camera[t, :3, 3], axis=1)))
                             if len(p) else 1.0 for t, p in enumerate(points)])
    median_depth = np.maximum(median_depth, 0.3)
    change: dict[tuple[int, int], float] = {}
    budget = config.max_frames - max(1, config.max_frames // 10)  # room for coverage frames
    lo, hi = 1.0, 1.0
    keys = _greedy(capture, config, hi, points, median_depth, change)
    while len(keys) > budget:  # widen until within budget, then bisect back
        lo, hi = hi, hi * 2.0
        keys = _greedy(capture, config, hi, points, median_depth, change)
    if hi > 1.0:
        for _ in range(12):
            mid = 0.5 * (lo + hi)
            k_mid = _greedy(capture, config, mid, points, median_depth, change)
            if len(k_mid) > budget:
                lo = mid
            else:
                hi, keys = mid, k_mid
    # Coverage: frames seeing what no keyframe sees.
    seen: set = set()
    for k in keys:
        seen |= _voxels(points[k], config.coverage_voxel_m)
    added: list[int] = []
    rest = sorted(set(range(n)) - set(keys))
    voxels = {i: _voxels(points[i], config.coverage_voxel_m) for i in rest}
    while rest and len(keys) + len(added) < config.max_frames:
        new = {i: len(voxels[i] - seen) / max(len(voxels[i]), 1) for i in rest}
        best = max(new, key=new.get)
        if new[best] < config.min_new_coverage:
            break
        added.append(best)
        seen |= voxels[best]
        rest.remove(best)
    frames = np.array(sorted(set(keys) | set(added)), np.int64)
    scene_change = np.zeros(n)
    for (i, _k), v in change.items():
        scene_change[i] = max(scene_change[i], v)
    return KeyframeSelection(frames, np.array(sorted(added), np.int64), float(hi), scene_change)
