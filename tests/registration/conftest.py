"""Synthetic scenes shared by the registration tests (generated once per session)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core.synth import SceneSpec, generate_scene

# 192x144 RGB / 96x72 depth: at the "tiny" benchmark scene's 64x48 depth (4 cm between pixels
# at 2 m) the cabinet's sides are too few points to pin the translation along the cabinet's
# width (measured 1.0-1.4 cm there), so these tests use a slightly larger scene.
SMALL = SceneSpec(
    furniture="door", static_frames=14, dynamic_frames=12, static_stride=8, dynamic_stride=5,
    rgb_size=(192, 144), depth_size=(96, 72), seed=21,
)


@pytest.fixture(scope="session")
def clean_small_scene():
    return generate_scene(replace(SMALL, noise_level=0.0))


@pytest.fixture(scope="session")
def small_scene():
    return generate_scene(SMALL)


def pose_errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Rotation error (degrees) and translation error (metres) between two [4, 4] transforms."""
    d = np.linalg.inv(truth) @ estimate
    angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return float(angle), float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
