"""`artitwin compare` leads with the residual the new effect targets, in its scope, on held-out
frames, and flags a rise beyond noise in any other scope as a regression of the modelling."""

from __future__ import annotations

import numpy as np

from artitwin_core.diagnostics._runs import RunRecord, compare_runs, curve_shift
from flows._runs import comparison_targets

DYN, STAT = "diagnose/dynamic recording/rgb_rms", "diagnose/static recording/rgb_rms"


def _record(name, effects, dyn, stat):
    held = list(range(0, 20, 5))
    return RunRecord(name=name, effects=effects, per_frame={DYN: list(dyn), STAT: list(stat)},
                     heldout={DYN: held, STAT: held})


def test_compare_leads_with_the_targeted_residual_and_flags_other_scopes():
    rng = np.random.default_rng(0)
    dyn_a = 0.08 + 0.005 * rng.standard_normal(20)
    stat = 0.03 + 0.001 * rng.standard_normal(20)
    a = _record("a", [], dyn_a, stat)
    # The effect cuts the dynamic residual; the static one is untouched up to noise.
    b = _record("b", ["dynamic:exposure_white_balance"], 0.4 * dyn_a, stat + 0.0005 * rng.standard_normal(20))
    targets, others = comparison_targets(a, b)
    assert targets == [("dynamic recording, photometric (rgb_rms)", DYN, "dynamic:exposure_white_balance")]
    cmp = compare_runs(a, b, targets, others)
    assert cmp.lead[0].startswith("dynamic recording, photometric (rgb_rms), held-out: 0.0") and "-60%" in cmp.lead[0]
    assert "the loop worked" in cmp.lead[0] and cmp.regressions == []
    # Modelled in the wrong scope: the static twin worse by 25 %, the dynamic one unchanged.
    c = _record("c", ["static:exposure_white_balance"], dyn_a + 0.0005 * rng.standard_normal(20), 1.25 * stat)
    cmp = compare_runs(a, c, *comparison_targets(a, c))
    assert "static recording, photometric" in cmp.lead[0] and "made it worse" in cmp.lead[0], cmp.lead
    # (the static curve is the target here, so no separate regression line for it; the dynamic one did not move)
    assert cmp.regressions == []
    d = _record("d", ["dynamic:exposure_white_balance"], dyn_a, 1.25 * stat)
    cmp = compare_runs(a, d, *comparison_targets(a, d))
    assert "no change beyond noise" in cmp.lead[0]
    assert len(cmp.regressions) == 1 and "static recording, rgb_rms" in cmp.regressions[0] and "+25%" in cmp.regressions[0]


def test_noise_is_judged_on_the_heldout_frames():
    a = _record("a", [], np.full(20, 0.05), np.full(20, 0.03))
    b = _record("b", [], np.full(20, 0.051), np.full(20, 0.03))  # +2 %: within the 5 % floor
    ma, mb, n, beyond = curve_shift(a, b, DYN)
    assert n == 4 and not beyond and mb > ma


def _own_record(name, effects, curve, level, metric, value, se):
    """A run with a flat per-frame ``curve`` at ``level`` and the scalar ``metric`` (a recording's
    disagreement with itself) at ``value`` with standard error ``se``."""
    return RunRecord(name=name, effects=effects, per_frame={curve: [level] * 20}, heldout={curve: list(range(0, 20, 5))},
                     metrics={metric: value, metric + "_se": se})


def test_a_depth_error_the_twin_absorbed_is_judged_by_the_recording_against_itself():
    """A twin trained on biased depth absorbs it: its depth curve does not move when the bias is
    modelled. The static recording's disagreement with itself does, and compare leads with it."""
    depth = "diagnose/static recording/depth_rms_m"
    own = "diagnose/static recording/self_consistency_depth_error_m"

    def rec(name, effects, error_m, se_m):
        return _own_record(name, effects, depth, 0.02, own, error_m, se_m)

    a = rec("a", [], 0.0685, 0.0004)
    b = rec("b", ["depth_scale_offset"], 0.0011, 0.0004)
    targets, _ = comparison_targets(a, b)
    assert targets == [("static recording, agreement with itself (self_consistency_depth_error_m)", own, "depth_scale_offset")]
    lead = compare_runs(a, b, *comparison_targets(a, b)).lead[0]
    assert "0.0685 -> 0.0011, -98%" in lead and "the loop worked" in lead, lead
    # Within two combined standard errors: no change beyond noise.
    c = rec("c", ["depth_scale_offset"], 0.0675, 0.0004)
    assert "no change beyond noise" in compare_runs(a, c, *comparison_targets(a, c)).lead[0]
    # A run without the metric (an older diagnosis) falls back to the depth curve.
    d = RunRecord(name="d", effects=["depth_scale_offset"], per_frame={depth: [0.02] * 20}, heldout={depth: [0, 5, 10, 15]})
    assert comparison_targets(a, d)[0] == [("static recording, depth (depth_rms_m)", depth, "depth_scale_offset")]


def test_the_dynamic_recordings_vignetting_is_judged_by_its_own_frames():
    """The dynamic recording's vignetting, modelled in stage IV: compare leads with the fall-off its
    own frames still show past the model (diagnose_dynamic's metric, not the static diagnosis's)."""
    rgb = "diagnose/dynamic recording/rgb_rms"
    own = "diagnose_dynamic/dynamic recording/self_consistency_vignetting_falloff"

    def rec(name, effects, falloff, se):
        return _own_record(name, effects, rgb, 0.05, own, falloff, se)

    a, b = rec("a", [], 0.347, 0.001), rec("b", ["dynamic:vignetting"], 0.02, 0.001)
    targets, _ = comparison_targets(a, b)
    assert targets == [("dynamic recording, agreement with itself (self_consistency_vignetting_falloff)", own,
                        "dynamic:vignetting")]
    lead = compare_runs(a, b, targets, []).lead[0]
    assert "-94%" in lead and "the loop worked" in lead, lead
    # Modelled in the static recording: the dynamic recording's own frames are not its target.
    c = rec("c", ["static:vignetting"], 0.347, 0.001)
    assert comparison_targets(a, c)[0][0][1] == "diagnose/static recording/rgb_rms"
