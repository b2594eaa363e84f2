"""Shared fixtures: the tiny synthetic door scene and a twin made from its ground truth."""

from __future__ import annotations

import socket

import pytest

from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
from artitwin_core.viewer import synthetic_twin


@pytest.fixture(scope="package")
def door_scene():
    return generate_scene(BENCHMARK_SCENES["tiny"])  # one revolute door, ~3 s on one core


@pytest.fixture(scope="package")
def door_twin(door_scene):
    return synthetic_twin(door_scene, max_gaussians=12_000)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
