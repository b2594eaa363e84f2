"""Tiny synthetic scenes with injected effects, generated once per test session."""

from __future__ import annotations

from dataclasses import replace

import pytest

from artitwin_core.diagnostics._synthetic import synthetic_residual_data
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene

# No hand: the static recording never shows one, and the tracks come from the true part motion.
BASE = replace(BENCHMARK_SCENES["tiny"], hand_occlusion=0.0)
_SCENES: dict[str, object] = {}
_DATA: dict[str, object] = {}


def scene(furniture: str = "door", effects: tuple = (), seed: int = 7, **overrides):
    """A tiny scene, cached (specs hold dicts and are unhashable: the cache keys on their repr).

    ``overrides`` replace more ``SceneSpec`` fields, e.g. ``static_stride=1`` (consecutive 30 fps
    frames: the timing effects need poses dense enough to follow the camera through hand shake).
    """
    spec = replace(BASE, furniture=furniture, effects=effects, seed=seed, **overrides)
    if repr(spec) not in _SCENES:
        _SCENES[repr(spec)] = generate_scene(spec)
    return _SCENES[repr(spec)]


def residual_data(furniture: str = "door", effects: tuple = (), seed: int = 7, **overrides):
    """The scene's static RGB-D against clean renders, and part 0's tracks against the nominal joint."""
    key = repr((furniture, effects, seed, sorted(overrides.items())))
    if key not in _DATA:
        _DATA[key] = synthetic_residual_data(scene(furniture, effects, seed, **overrides))
    return _DATA[key]


@pytest.fixture
def clean_registry():
    """Restore the effect registry after a test that registers plugins."""
    from artitwin_core.diagnostics import _plugin

    saved = dict(_plugin._REGISTRY)
    yield
    _plugin._REGISTRY.clear()
    _plugin._REGISTRY.update(saved)
