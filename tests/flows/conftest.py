"""A tiny synthetic scene shared by the flow tests (rendered once per test session)."""

from __future__ import annotations

import pytest

import tests.flows._toy  # noqa: F401  (registers the toy stages)


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene

    out = tmp_path_factory.mktemp("tiny") / "scene"
    write_scene(generate_scene(BENCHMARK_SCENES["tiny"]), out)
    return out
