"""User effects outside the package: discovered through ARTITWIN_EFFECTS, used by the diagnosis;
a bad plugin is an InputError that names it and says what to do."""

from __future__ import annotations

import sys
import textwrap

import pytest

from artitwin_core import InputError
from artitwin_core.diagnostics import (
    ENV_VAR,
    _plugin,
    diagnose,
    discover_effects,
    register_effect,
    registered_effects,
)
from tests.diagnostics._scenes import residual_data

PLUGIN = textwrap.dedent('''
    """A user's effect: a constant depth offset (no scale), documented in docs/effects.md."""
    from dataclasses import replace

    import numpy as np

    from artitwin_core.diagnostics import Effect


    class DepthOffset(Effect):
        name = "depth_offset_only"
        target = "depth"
        description = "measured = predicted + offset_m"

        def applies(self, data):
            return data.has_depth

        def fit(self, data):
            return {"offset_m": float(np.nanmedian(data.depth_residual()))}, None

        def apply(self, data, params):
            return replace(data, depth_meas=(data.depth_meas - params["offset_m"]).astype(np.float32))


    class NeedsEveryFrame(DepthOffset):
        name = "needs_every_frame"

        def fit(self, data):
            if not data.depth_valid.any((1, 2)).all():
                raise ValueError("a frame has no depth")
            return super().fit(data)


    class NotAnEffect:
        name = "nope"


    class BadTarget(DepthOffset):
        name = "bad_target"
        target = "smell"


    class Crashes(DepthOffset):
        name = "crashes"

        def fit(self, data):
            raise ZeroDivisionError("oops")
''')


@pytest.fixture
def plugin_module(tmp_path, monkeypatch):
    (tmp_path / "user_effects_mod.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    saved = dict(_plugin._REGISTRY)
    yield "user_effects_mod"
    _plugin._REGISTRY.clear()
    _plugin._REGISTRY.update(saved)
    sys.modules.pop("user_effects_mod", None)


def test_plugin_from_env_var_is_discovered_and_used(plugin_module, monkeypatch):
    monkeypatch.setenv(ENV_VAR, f"{plugin_module}:DepthOffset")
    assert "depth_offset_only" not in registered_effects()
    assert discover_effects() == ["depth_offset_only"]
    effect = registered_effects()["depth_offset_only"]
    dg = diagnose(residual_data("door", (("depth_bias", {"scale": 1.0, "offset_m": 0.02}),)), {effect.name: effect})
    assert [s.name for s in dg.enabled] == ["depth_offset_only"]
    assert dg.enabled[0].params["offset_m"] == pytest.approx(0.02, abs=0.002)
    assert dg.energy_after["depth"] < 0.3 * dg.energy_before["depth"]  # measured 0.2: noise (1e-4) remains


def test_plugin_competes_with_the_builtins(plugin_module, monkeypatch):
    monkeypatch.setenv(ENV_VAR, f"{plugin_module}:DepthOffset")
    discover_effects()
    dg = diagnose(residual_data("door", (("depth_bias", {"scale": 1.0, "offset_m": 0.02}),)))
    names = [s.name for s in dg.ranking]
    assert "depth_offset_only" in names and "depth_scale_offset" in names
    assert dg.enabled[0].name in {"depth_offset_only", "depth_scale_offset"}


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("no_colon_here", "not 'module:attr'"),
        ("module_that_does_not_exist_xyz:Thing", "cannot load"),
        ("{mod}:Missing", "cannot load"),
        ("{mod}:NotAnEffect", "subclass Effect"),
        ("{mod}:BadTarget", "targets 'smell'"),
    ],
)
def test_bad_plugin_is_a_clear_input_error(plugin_module, monkeypatch, spec, message):
    monkeypatch.setenv(ENV_VAR, spec.format(mod=plugin_module))
    with pytest.raises(InputError, match=message) as err:
        discover_effects()
    assert ENV_VAR in str(err.value) or "Effect" in str(err.value)


def test_plugin_that_crashes_is_named(plugin_module, monkeypatch):
    monkeypatch.setenv(ENV_VAR, f"{plugin_module}:Crashes")
    discover_effects()
    effect = registered_effects()["crashes"]
    with pytest.raises(InputError, match=r"effect 'crashes' .*ZeroDivisionError: oops"):
        diagnose(residual_data("door"), {"crashes": effect})


def test_a_name_cannot_be_taken_twice_by_accident(plugin_module):
    mod = __import__(plugin_module)
    register_effect(mod.DepthOffset)
    other = type("Other", (mod.DepthOffset,), {})
    with pytest.raises(InputError, match="already registered"):
        register_effect(other)
    assert register_effect(other, replace=True).name == "depth_offset_only"


def test_a_plugin_that_cannot_be_refitted_on_training_frames_is_reported_not_raised(plugin_module, monkeypatch):
    # The diagnosis (all frames) enables it; the held-out check (training frames only) cannot refit it.
    monkeypatch.setenv(ENV_VAR, f"{plugin_module}:NeedsEveryFrame")
    discover_effects()
    effect = registered_effects()["needs_every_frame"]
    dg = diagnose(residual_data("door", (("depth_bias", {"scale": 1.0, "offset_m": 0.02}),)), {effect.name: effect})
    assert [s.name for s in dg.enabled] == ["needs_every_frame"]
    (check,) = dg.heldout.checks
    assert check.failed == "ValueError: a frame has no depth"
    assert dg.heldout.errors_after == dg.heldout.errors_before  # left out of the held-out chain
    assert any("could not be refitted" in line for line in dg.conclusion)
