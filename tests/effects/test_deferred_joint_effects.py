"""A joint effect waits while the static recording's own frames show a depth error: the joints'
tracks are lifted from that depth, and a depth error bends them as a screw or a tilt would (a
depth bias in both recordings of a door asked for a screw joint)."""

from __future__ import annotations

from schemas._diagnose import DiagnosisReport, EffectFinding
from tasks._consistency import STATIC_SCOPE, defer_joint_effects


def _finding(name, scope, target, enabled=True, **params):
    return EffectFinding(name=name, scope=scope, target=target, explained_frac=0.4, energy_before=1.0,
                         energy_after=0.6, significant=True, enabled=enabled, params=params)


def _report():
    findings = [_finding("screw_joint", "joint_0", "joint-tracks"), _finding("axis_tilt", "joint_0", "joint-tracks", False),
                _finding("depth_noise", STATIC_SCOPE, "depth-noise")]
    return DiagnosisReport(findings=findings, enabled=["joint_0/screw_joint", f"{STATIC_SCOPE}/depth_noise"],
                           metrics={"enabled_count": 2.0})


def test_joint_effects_wait_for_a_depth_error_the_recording_shows():
    depth = _finding("depth_scale_offset", STATIC_SCOPE, "self-consistency", error_m=0.0685, reference_depth_m=1.89)
    out, lines = defer_joint_effects(_report(), [depth])
    assert out.enabled == [f"{STATIC_SCOPE}/depth_noise"] and out.metrics["enabled_count"] == 1.0
    screw = next(f for f in out.findings if f.name == "screw_joint")
    assert not screw.enabled and screw.significant  # still reported, not asked for
    assert len(lines) == 1 and lines[0].startswith("joint_0: screw_joint is not enabled yet")
    assert "+68 mm off at 1.9 m" in lines[0] and "--effect depth_scale_offset" in lines[0]


def test_without_a_depth_error_the_joint_effects_stand():
    for depth in ([], [_finding("depth_scale_offset", STATIC_SCOPE, "self-consistency", False, error_m=0.001,
                                reference_depth_m=1.9)]):
        out, lines = defer_joint_effects(_report(), depth)
        assert "joint_0/screw_joint" in out.enabled and lines == []
