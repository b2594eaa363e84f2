"""The tiny synthetic door scene, its true stage-IV inputs and a briefly trained canonical model.

The articulation tests get the true joints, masks and registration so that they measure this
stage alone; the canonical model is trained for a few steps at the true static poses.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from artitwin_core.gaussians import GaussianParams
from artitwin_core.geometry import invert_se3
from artitwin_core.masks import MaskSequence
from artitwin_core.reconstruction import (
    InitConfig,
    TrainConfig,
    TrainState,
    init_gaussians,
    make_views,
    scene_extent,
    train,
)
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, render_state

CANONICAL_STEPS = 60


@pytest.fixture(scope="session", autouse=True)
def _torch_threads():
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "2")))  # a share of the cores: tests/conftest.py


@pytest.fixture(scope="session")
def tiny_scene():
    return generate_scene(BENCHMARK_SCENES["tiny"])


@pytest.fixture(scope="session")
def true_masks(tiny_scene) -> MaskSequence:
    t = tiny_scene.truth
    return MaskSequence(part=t.part_masks, hand=t.hand_masks, score=np.ones(len(t.part_masks), np.float32))


@pytest.fixture(scope="session")
def canonical(tiny_scene) -> GaussianParams:
    cap = tiny_scene.static
    poses = tiny_scene.truth.static_world_from_camera
    frames = list(range(cap.num_frames))
    g0 = init_gaussians(cap, poses, frames, InitConfig(max_points=4000))
    state = TrainState.from_params(g0, scene_extent(poses))
    train(
        state, make_views(cap, poses, frames), TrainConfig.with_schedule(CANONICAL_STEPS, max_gaussians=8000)
    )
    return state.to_params()


@pytest.fixture(scope="session")
def gt_part_gaussians(tiny_scene, canonical) -> np.ndarray:
    """``[N]`` bool: canonical centres that project into the true part mask in the closed
    dynamic frames: on the true surface (within 2 cm of the true depth) there, and inside the
    part mask in at least 80 % of the closed frames where they lie on any surface."""
    cap = tiny_scene.dynamic
    truth = tiny_scene.truth
    w, h = cap.rgb_size
    q = truth.joints[0].q
    closed = [t for t in range(cap.num_frames) if abs(q[t]) <= 0.03 * np.abs(q).max()]
    on_surface = np.zeros(canonical.num_gaussians)
    on_part = np.zeros(canonical.num_gaussians)
    for t in closed:
        pose = truth.dynamic_world_from_camera[t]
        _, depth, part = render_state(tiny_scene, pose, cap.rgb_intrinsics[t], w, h, [q[t]])
        cam = invert_se3(pose)
        x = canonical.means.astype(np.float64) @ cam[:3, :3].T + cam[:3, 3]
        fx, fy, cx, cy = cap.rgb_intrinsics[t]
        z = np.where(x[:, 2] > 1e-3, x[:, 2], 1.0)
        u = np.floor(fx * x[:, 0] / z + cx).astype(np.int64)
        v = np.floor(fy * x[:, 1] / z + cy).astype(np.int64)
        i = np.nonzero((x[:, 2] > 1e-3) & (u >= 0) & (u < w) & (v >= 0) & (v < h))[0]
        surf = np.abs(x[i, 2] - depth[v[i], u[i]]) < 0.02
        on_surface[i[surf]] += 1
        on_part[i[surf & (part[v[i], u[i]] == 1)]] += 1
    return (on_surface >= 1) & (on_part >= 0.8 * on_surface)
