"""Bounded pose refinement: which frame pairs a long recording matches, and how many features."""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.geometry import make_se3
from artitwin_core.reconstruction import PoseRefineConfig
from artitwin_core.reconstruction._poses import match_pairs


def _out_and_back(t: int) -> Capture:
    """A camera walking 2 m sideways past a wall 2 m away and back along the same line."""
    x = np.concatenate([np.linspace(0, 2, t // 2), np.linspace(2, 0, t - t // 2)])
    intr = np.tile([30.0, 30.0, 15.5, 11.5], (t, 1))
    return Capture(
        rgb=np.zeros((t, 24, 32, 3), np.uint8), depth=np.full((t, 24, 32), 2.0, np.float32), confidence=None,
        rgb_intrinsics=intr, depth_intrinsics=intr, world_from_camera=np.stack([make_se3(np.eye(3), [xi, 0, 0]) for xi in x]),
        timestamps=np.arange(t) / 30.0, frame_ids=np.arange(t),
    )


def test_sequential_pairs_plus_loop_closures():
    cap = _out_and_back(60)
    plain = match_pairs(cap, overlap=5, loop_pairs=0)
    assert plain == sorted({(i, j) for i in range(60) for j in range(i + 1, min(60, i + 6))})
    pairs = match_pairs(cap, overlap=5, loop_pairs=3)
    loops = [(i, j) for i, j in pairs if j - i > 5]
    assert loops and len(pairs) <= len(plain) + 3 * 60
    # Each loop pair joins the walk out with the walk back near the same place (the capture poses).
    for i, j in loops:
        assert np.linalg.norm(cap.world_from_camera[i, :3, 3] - cap.world_from_camera[j, :3, 3]) < 2.0
    assert any(i < 30 <= j for i, j in loops)


def test_features_scale_with_the_working_resolution():
    cfg = PoseRefineConfig(max_features=None)
    assert cfg.features_for(512, 384) == 1774 and cfg.features_for(640, 480) == 2217
    assert cfg.features_for(1920, 1440) == 6651 and cfg.features_for(64, 48) == 1024
    assert PoseRefineConfig().features_for(640, 480) == 4096  # a given number is kept
