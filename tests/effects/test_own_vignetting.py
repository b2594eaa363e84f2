"""Vignetting is diagnosed in the recording whose camera has it: each recording's own frames are
tested (``vignetting_consistency``), and a radial pattern in one recording's residual against the
twin that its own frames do not show (the twin carries the other recording's vignetting) is not
enabled there."""

from __future__ import annotations

from dataclasses import replace

import pytest

from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
from schemas import CaptureArtifact
from schemas._diagnose import DiagnoseConfig, DiagnosisReport, EffectFinding
from tasks import to_artifact
from tasks._consistency import (
    DYNAMIC_SCOPE,
    STATIC_SCOPE,
    overrule_twin_vignetting,
    self_consistency_metrics,
    vignetting_consistency,
)


@pytest.fixture(scope="module")
def static_only():
    """The tiny scene with vignetting (corners 35 % darker) in the static recording only."""
    spec = replace(BENCHMARK_SCENES["tiny"], static_frames=16,
                   effects=(("vignetting", {"strength": 0.35, "recordings": "static"}),))
    scene = generate_scene(spec)
    return to_artifact(CaptureArtifact, scene.static), to_artifact(CaptureArtifact, scene.dynamic)


def test_each_recording_is_tested_on_its_own_frames(static_only):
    static, dynamic = static_only
    found, lines = vignetting_consistency(static, STATIC_SCOPE, DiagnoseConfig())
    (f,) = found
    assert f.enabled and f.significant and f.target == "self-consistency"
    assert f.params["corner_falloff"] == pytest.approx(0.35, abs=0.01)
    assert len(lines) == 1 and "--effect static:vignetting" in lines[0] and "35 % darker" in lines[0]
    metrics = self_consistency_metrics(found)
    assert metrics[f"{STATIC_SCOPE}/self_consistency_vignetting_falloff"] == pytest.approx(0.35, abs=0.01)
    # The dynamic recording's camera has none: nothing enabled, nothing to model.
    (g,), lines = vignetting_consistency(dynamic, DYNAMIC_SCOPE, DiagnoseConfig())
    assert not g.enabled and abs(g.params["corner_falloff"]) < 0.01 and lines == []
    # The twin's camera model holding it: what it left is measured, and here it left nothing.
    (h,), lines = vignetting_consistency(static, STATIC_SCOPE, DiagnoseConfig(), modelled=[-0.35, 0.0])
    assert not h.enabled and abs(h.params["corner_falloff"]) < 0.01 and lines == []
    # A model that holds half of it: the other half is still found, and said to be past the model.
    (k,), lines = vignetting_consistency(static, STATIC_SCOPE, DiagnoseConfig(), modelled=[-0.175, 0.0])
    assert k.enabled and 0.14 < k.params["corner_falloff"] < 0.23
    assert "beyond what the twin's model of this camera holds" in lines[0]


def _twin_finding(scope: str) -> EffectFinding:
    return EffectFinding(name="vignetting", scope=scope, target="photometric", explained_frac=0.22,
                         energy_before=1.0, energy_after=0.78, significant=True, enabled=True)


def test_a_radial_residual_the_recordings_own_frames_do_not_show_is_not_enabled(static_only):
    _, dynamic = static_only
    report = DiagnosisReport(findings=[_twin_finding(DYNAMIC_SCOPE)],
                             enabled=[f"{DYNAMIC_SCOPE}/vignetting"], metrics={"enabled_count": 1.0})
    own, _ = vignetting_consistency(dynamic, DYNAMIC_SCOPE, DiagnoseConfig())
    out, lines = overrule_twin_vignetting(report, DYNAMIC_SCOPE, own)
    assert out.enabled == [] and out.metrics["enabled_count"] == 0.0
    assert not out.findings[0].enabled and out.findings[0].significant  # still reported, no longer asked for
    assert len(lines) == 1 and "its own frames show no vignetting" in lines[0]
    # When its own frames do show it, the twin-based finding stands.
    static, _ = static_only
    report = report.model_copy(update={"findings": [_twin_finding(STATIC_SCOPE)], "enabled": [f"{STATIC_SCOPE}/vignetting"]})
    own, _ = vignetting_consistency(static, STATIC_SCOPE, DiagnoseConfig())
    out, lines = overrule_twin_vignetting(report, STATIC_SCOPE, own)
    assert out.enabled == [f"{STATIC_SCOPE}/vignetting"] and out.findings[0].enabled and lines == []
