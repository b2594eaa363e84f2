"""Shared fixtures: the tiny synthetic scene and its ground-truth depth (rendered once per session)."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, render_state


@pytest.fixture(scope="session", autouse=True)
def _torch_threads():
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "2")))  # a share of the cores: tests/conftest.py


@pytest.fixture(scope="session")
def tiny_scene():
    return generate_scene(BENCHMARK_SCENES["tiny"])


@pytest.fixture(scope="session")
def tiny_gt_depth(tiny_scene) -> np.ndarray:
    """``[T, H, W]`` true z-depth at RGB resolution from the true poses (NaN = no surface)."""
    cap = tiny_scene.static
    w, h = cap.rgb_size
    q = [0.0] * len(tiny_scene.truth.joints)
    truth = tiny_scene.truth.static_world_from_camera
    return np.stack([render_state(tiny_scene, truth[t], cap.rgb_intrinsics[t], w, h, q)[1] for t in range(cap.num_frames)])
