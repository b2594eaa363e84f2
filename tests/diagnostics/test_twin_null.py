"""The twin's own geometry error against a camera-motion effect.

The prediction comes from a perturbed twin: the ground-truth depth with a world-fixed error (every
surface moved along its normal by 2 cm plus a 3 cm cosine over the floor plan, the same in every
frame that sees it, as an unconverged twin's is). Pose drift's twelve parameters fit a large share
of that error, because the camera faces different surfaces at different times; it must not be
enabled. With a drift injected on top it must still be found.
"""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core.diagnostics import PoseDrift, diagnose
from artitwin_core.diagnostics._surface_null import surface_null_check
from artitwin_core.diagnostics._synthetic import perturb_twin_depth
from tests.diagnostics._scenes import residual_data

TWIN_ERROR = {"amplitude_m": 0.03, "wavelength_m": 2.0, "offset_m": 0.02}


def test_a_world_fixed_twin_error_is_not_pose_drift():
    data = perturb_twin_depth(residual_data("door"), **TWIN_ERROR)
    # Not vacuous: on its own, drift explains well over the enabling threshold (measured 0.61).
    assert PoseDrift().signature(data).explained_fraction > 0.4
    dg = diagnose(data)
    assert "pose_drift" not in [s.name for s in dg.enabled]
    assert "pose_drift" not in dg.significant
    check = next(c for c in dg.null_checks if c.name == "pose_drift")
    assert not check.accepted
    assert check.null_fraction > 0.8  # the static per-surface correction takes it (measured 0.90)
    assert check.gain_over_null < 0.15  # measured 0.04
    assert any("pose_drift was not enabled" in line and "twin's own geometry" in line for line in dg.conclusion)


def test_a_drift_on_top_of_the_twin_error_is_still_found():
    data = perturb_twin_depth(residual_data("door", (("pose_drift", {}),)), **TWIN_ERROR)
    dg = diagnose(data)
    assert dg.enabled[0].name == "pose_drift"
    check = next(c for c in dg.null_checks if c.name == "pose_drift")
    assert check.accepted and check.gain_over_null > 0.5  # measured 0.77
    # The plain fit's rate is pulled by the twin's error (0.034 m/s of 0.02); fitted within surface
    # patches, the world-fixed error drops out (0.0226).
    w1, v1 = np.array(check.rates[:3]), np.array(check.rates[3:])
    drift = -v1 - np.cross(w1, data.world_from_camera[0, :3, 3])
    assert np.linalg.norm(drift) == pytest.approx(0.02, rel=0.25)
    assert dg.enabled[0].params["drift_trans_m_per_s"] > 0.01


def test_the_null_check_on_an_unperturbed_twin():
    clean, drift = residual_data("door"), residual_data("door", (("pose_drift", {}),))
    c0, c1 = surface_null_check(clean), surface_null_check(drift)
    # Noise only: neither the static correction nor the drift's time-varying part explains anything.
    assert not c0.accepted and abs(c0.gain_over_null) < 0.05 and c0.null_fraction < 0.1
    assert c0.energy_null == pytest.approx(c0.floor, rel=0.5)  # whitened noise, measured 0.78 vs 0.62
    # A drift: what varies over time within a surface patch is its signature (measured 0.79).
    assert c1.accepted and c1.gain_over_null > 0.6
    assert np.isfinite(c1.energy_effect) and c1.energy_effect < 2 * c1.floor
