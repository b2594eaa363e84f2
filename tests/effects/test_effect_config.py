"""Enabling an effect is one option: which stage config it changes, clear errors for the ones no
stage models, and the Prefect UI summary of a diagnosis with the rerun command."""

from __future__ import annotations

import pytest

from schemas import DiagnosisReport, EffectFinding, PipelineConfig


def test_with_effects_changes_only_the_modelling_stage():
    base = PipelineConfig.preset("quick")
    cfg = base.with_effects(["vignetting", "exposure_white_balance", "screw_joint"])
    assert cfg.reconstruct.sensor_effects == ["exposure_white_balance", "vignetting"]
    assert cfg.fit_joints.model_screw
    # A bare camera effect with no diagnosis to place it is the static recording's (as before scopes).
    assert cfg.enabled_effects() == ["screw_joint", "static:exposure_white_balance", "static:vignetting"]
    for name in ("ingest", "refine_poses", "registration", "part_masks", "track", "articulate", "diagnose"):
        assert getattr(cfg, name) == getattr(base, name), name
    assert cfg.reconstruct.steps == base.reconstruct.steps  # the rest of the stage config is kept
    assert base.enabled_effects() == []


def test_effects_no_stage_models_are_refused_by_name():
    with pytest.raises(ValueError, match="axis_tilt.*can be enabled"):
        PipelineConfig().with_effects(["axis_tilt"])
    with pytest.raises(ValueError):  # the schema itself rejects an unknown sensor effect
        PipelineConfig.model_validate({"reconstruct": {"sensor_effects": ["lens_distortion"]}})


def test_prefect_ui_summary_lists_the_ranking_and_the_rerun_command():
    from flows.scene import diagnosis_markdown

    def finding(name, scope, target, frac, enabled):
        return EffectFinding(name=name, scope=scope, target=target, explained_frac=frac, energy_before=1.0,
                             energy_after=1.0 - frac, significant=enabled, enabled=enabled)

    report = DiagnosisReport(
        findings=[finding("exposure_white_balance", "static recording", "photometric", 0.9, True),
                  finding("axis_tilt", "joint_0", "joint-tracks", 0.6, True),
                  finding("vignetting", "static recording", "photometric", 0.05, False)],
        enabled=["static recording/exposure_white_balance", "joint_0/axis_tilt"],
        conclusion=["exposure explains 90% of the photometric residual"],
    )
    text = "\n".join(diagnosis_markdown(report))
    assert "| 1 | static recording | exposure_white_balance | photometric | 90% | yes | yes |" in text
    assert "--effect static:exposure_white_balance" in text
    assert "--effect axis_tilt" not in text  # no stage models it: not offered as a rerun
    assert "exposure explains 90%" in text


def test_time_offset_takes_the_diagnosed_seconds():
    base = PipelineConfig.preset("quick")
    cfg = base.with_effects(["time_offset=0.033", "screw_joint"])
    assert cfg.joint_states.rgb_time_offset_s == 0.033
    assert cfg.enabled_effects() == ["screw_joint", "time_offset=0.033"]
    assert cfg.with_effects(cfg.enabled_effects()) == cfg  # the inverse round-trips
    for name in ("registration", "part_masks", "track", "reconstruct"):
        assert getattr(cfg, name) == getattr(base, name), name
    with pytest.raises(ValueError, match="needs its seconds.*time_offset=VALUE"):
        base.with_effects(["time_offset"])
    with pytest.raises(ValueError, match="must be a number"):
        base.with_effects(["time_offset=soon"])
    with pytest.raises(ValueError, match="by name alone"):
        base.with_effects(["vignetting=0.3"])
    with pytest.raises(ValueError):  # the stage config bounds the lag (half a second)
        base.with_effects(["time_offset=2"])


def test_the_rerun_command_carries_the_fitted_time_offset():
    from flows._runs import rerun_effects
    from flows.scene import diagnosis_markdown

    lag = EffectFinding(name="time_offset", scope="dynamic recording", target="photometric", explained_frac=0.4,
                        energy_before=1.0, energy_after=0.6, significant=True, enabled=True,
                        params={"seconds": 0.0331, "median_speed_px_per_s": 40.0})
    # the static recording's own fit (not significant) comes first in the report: not the one to model
    static = lag.model_copy(update={"scope": "static recording", "significant": False, "enabled": False,
                                    "params": {"seconds": 0.0006, "median_speed_px_per_s": 30.0}})
    report = DiagnosisReport(findings=[static, lag], enabled=["dynamic recording/time_offset"], conclusion=[])
    assert rerun_effects(report, []) == (["dynamic:time_offset=0.0331"], [])
    assert rerun_effects(report, ["time_offset=0.0331"]) == ([], [])  # already modelled
    assert "--effect dynamic:time_offset=0.0331" in "\n".join(diagnosis_markdown(report))
    PipelineConfig().with_effects(rerun_effects(report, [])[0])  # what it offers is accepted


def test_an_effect_is_modelled_in_the_scope_it_is_named_with():
    base = PipelineConfig.preset("quick")
    cfg = base.with_effects(["dynamic:exposure_white_balance", "static:vignetting", "joint_0:screw_joint"])
    assert cfg.articulate.sensor_effects == ["exposure_white_balance"]  # stage IV, the dynamic recording
    assert cfg.reconstruct.sensor_effects == ["vignetting"]  # reconstruct, the static recording
    # The named joint only; a bare name models every rotating joint.
    assert cfg.fit_joints.screw_joints == ["joint_0"] and not cfg.fit_joints.model_screw
    assert cfg.enabled_effects() == ["dynamic:exposure_white_balance", "joint_0:screw_joint", "static:vignetting"]
    assert cfg.with_effects(cfg.enabled_effects()) == cfg  # the inverse round-trips
    both = base.with_effects(["joint_2:screw_joint", "joint_10:screw_joint", "screw_joint"]).fit_joints
    assert both.screw_joints == ["joint_2", "joint_10"] and both.model_screw
    only_dynamic = base.with_effects(["dynamic recording:vignetting"])  # the diagnosis's own scope names work too
    assert only_dynamic.reconstruct == base.reconstruct and only_dynamic.articulate.sensor_effects == ["vignetting"]
    for bad, says in (("dynmaic:vignetting", "unknown scope 'dynmaic'.*static, dynamic or a joint"),
                      ("dynamic:depth_scale_offset", "can be modelled in static, not in dynamic"),
                      ("joint_0:exposure_white_balance", "static, dynamic, not in joint_0"),
                      ("static:screw_joint", "a joint")):
        with pytest.raises(ValueError, match=says):
            base.with_effects([bad])
    with pytest.raises(ValueError, match="sensor_effects"):  # the stage config names its valid choices
        PipelineConfig.model_validate({"articulate": {"sensor_effects": ["depth_scale_offset"]}})


def test_the_rerun_command_names_the_scope_the_diagnosis_found():
    from flows._runs import rank_findings, rerun_effects, scope_bare_effects

    def finding(name, scope, target, frac, enabled):
        return EffectFinding(name=name, scope=scope, target=target, explained_frac=frac, energy_before=1.0,
                             energy_after=1.0 - frac, significant=enabled, enabled=enabled)

    report = DiagnosisReport(
        findings=[finding("vignetting", "static recording", "photometric", 0.05, False),
                  finding("screw_joint", "joint_0", "joint-tracks", 0.5, True),
                  finding("exposure_white_balance", "dynamic recording", "photometric", 0.77, True),
                  finding("depth_scale_offset", "dynamic recording", "depth", 0.4, True)],
        enabled=["joint_0/screw_joint", "dynamic recording/exposure_white_balance", "dynamic recording/depth_scale_offset"],
    )
    flags, cannot = rerun_effects(report, [])
    assert flags == ["dynamic:exposure_white_balance", "joint_0:screw_joint"]
    assert cannot == ["depth_scale_offset (dynamic recording: modelled only in the static scope)"]
    # Modelled in the static recording is not modelled in the dynamic one: still offered.
    assert rerun_effects(report, ["exposure_white_balance", "screw_joint"])[0] == ["dynamic:exposure_white_balance"]
    assert rerun_effects(report, ["dynamic:exposure_white_balance", "screw_joint"])[0] == []
    # A bare name goes where the diagnosis found it; without one, to the static recording.
    assert scope_bare_effects(["exposure_white_balance", "static:vignetting"], report) == [
        "dynamic:exposure_white_balance", "static:vignetting"]
    assert scope_bare_effects(["exposure_white_balance"], None) == ["exposure_white_balance"]
    # One ranking over every scope: the enabled dynamic finding first, the disabled static one last.
    assert [f.name for f in rank_findings(report.findings)] == [
        "exposure_white_balance", "screw_joint", "depth_scale_offset", "vignetting"]


def test_a_joint_the_diagnosis_names_is_the_part_fit_joints_fits(tmp_path):
    """The diagnosis names the settled joints (joint_k: the k-th part kept); fit_joints names its
    candidates (joint_<label - 1>). With candidate 0 dropped, the diagnosis's joint_0 is fit_joints'
    joint_1, and `artitwin run --effect joint_0:screw_joint` must model that one."""
    import numpy as np

    from flows._runs import fit_joint_names, joint_effects_as_fitted, scope_bare_effects
    from infra.store import ArtifactStore
    from schemas import JointParams, JointSet

    def joint(name):
        return JointParams(name=name, joint_type="revolute", axis=np.array([0.0, 0, 1]), pivot=np.zeros(3),
                           q=np.zeros(4), q_range=np.zeros(2), residual=np.zeros(4), confidence=np.ones(4))

    store = ArtifactStore(str(tmp_path / "store"))
    store.put("a" * 64, JointSet(joints=[joint("joint_0"), joint("joint_1")], mask_labels=[2, 3]))
    summary = {"stages": {"settle_parts": {"status": "computed", "key": "a" * 64}}, "store": str(tmp_path / "store")}
    names = fit_joint_names(summary)
    assert names == {"joint_0": "joint_1", "joint_1": "joint_2"}
    scoped, notes = joint_effects_as_fitted(["joint_0:screw_joint", "dynamic:vignetting"], names)
    assert scoped == ["joint_1:screw_joint", "dynamic:vignetting"] and len(notes) == 1
    # A bare name goes to the joints the diagnosis enabled it on.
    report = DiagnosisReport(findings=[], enabled=["joint_1/screw_joint"])
    assert scope_bare_effects(["screw_joint"], report) == ["joint_1:screw_joint"]
    assert scope_bare_effects(["screw_joint"], None) == ["screw_joint"]
