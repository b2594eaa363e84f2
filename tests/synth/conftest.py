"""Small synthetic scenes shared by the synth tests (each renders in well under a second)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from artitwin_core.synth import BENCHMARK_SCENES, generate_scene

TINY = BENCHMARK_SCENES["tiny"]


_CACHE: dict[str, object] = {}


def make(**changes):
    """The tiny scene with ``changes`` applied, generated once per session (keyed by the spec's
    repr: specs hold dicts, so they are not hashable)."""
    spec = dataclasses.replace(TINY, **changes)
    key = repr(spec)
    if key not in _CACHE:
        _CACHE[key] = generate_scene(spec)
    return _CACHE[key]


@pytest.fixture(scope="session")
def tiny():
    return make()


@pytest.fixture(scope="session")
def clean():
    """Noise-free tiny scene: depth is exact wherever it is valid."""
    return make(noise_level=0.0)


def valid_backprojection(depth: np.ndarray, intrinsics: np.ndarray, world_from_camera: np.ndarray) -> np.ndarray:
    """Valid pixels of ``depth [h, w]`` (z metres) -> world points ``[N, 3]``."""
    fx, fy, cx, cy = intrinsics
    v, u = np.nonzero(np.isfinite(depth))
    z = depth[v, u].astype(np.float64)
    cam = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], -1)
    return cam @ world_from_camera[:3, :3].T + world_from_camera[:3, 3]


@pytest.fixture(scope="session")
def make_scene():
    """``make_scene(**changes)``: the tiny scene with SceneSpec fields changed (cached)."""
    return make


@pytest.fixture(scope="session")
def backproject():
    return valid_backprojection
