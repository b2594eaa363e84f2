"""The pose_lag and correct_pose_lag stages: a significant lag is stored and applied, none is
left alone, the effect pose_lag forces it (unless it is within its standard error of 0), the
switch turns the correction off (and takes its stage out of the graph), and summary.json and the
diagnosis report it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core.capture import correct_pose_lag as shift_poses
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene
from flows._pipeline import build_summary, scene_pipeline
from flows._runner import StageRun
from flows._runs import rerun_effects
from infra.store import ArtifactStore
from schemas import CaptureArtifact, DiagnosisReport, PipelineConfig, PoseLagResult, PoseLagStageConfig
from tasks import to_artifact
from tasks.diagnose import DYNAMIC_SCOPE, pose_lag_finding
from tasks.pose_lag import correct_pose_lag, fit_pose_lag
from tests._recorder import RecordingExecutor

SMALL = replace(
    BENCHMARK_SCENES["door"], rgb_size=(160, 120), depth_size=(80, 60), static_frames=2, dynamic_frames=20, seed=1
)
FRAME_S = SMALL.dynamic_stride / 30.0


@pytest.fixture(scope="module")
def captures():
    """The dynamic recording with its poses two frames late, and with none."""
    late = generate_scene(replace(SMALL, effects=(("pose_lag", {"seconds": 2 * FRAME_S, "recordings": "dynamic"}),)))
    return to_artifact(CaptureArtifact, late.dynamic), to_artifact(CaptureArtifact, generate_scene(SMALL).dynamic)


def test_a_significant_lag_is_stored_and_applied(captures):
    late, _ = captures
    lag = fit_pose_lag(late, PoseLagStageConfig())
    assert lag.estimated and lag.significant and lag.applied and not lag.forced
    assert lag.lag_frames == pytest.approx(2.0, abs=0.25) and lag.lag_s == pytest.approx(lag.lag_frames * FRAME_S)
    assert lag.z_score > 10 and lag.agreement_z > 2 and lag.residual_lag_m < lag.residual_zero_m
    assert "late" in lag.note and "corrected" in lag.note
    fixed = correct_pose_lag(late, lag, PoseLagStageConfig())
    track = (late.stream_timestamps, late.stream_world_from_camera)  # the 30 fps poses between the frames
    np.testing.assert_array_equal(fixed.world_from_camera,
                                  shift_poses(late.world_from_camera, late.timestamps, lag.lag_s, track))
    np.testing.assert_array_equal(fixed.stream_world_from_camera, shift_poses(track[1], track[0], lag.lag_s))
    assert np.array_equal(fixed.depth, late.depth, equal_nan=True) and np.array_equal(fixed.rgb, late.rgb)
    assert np.abs(fixed.world_from_camera - late.world_from_camera).max() > 0.01


def test_no_lag_is_left_alone_unless_the_effect_forces_it(captures):
    _, clean = captures
    lag = fit_pose_lag(clean, PoseLagStageConfig())
    assert lag.estimated and not lag.significant and not lag.applied
    assert "not corrected" in lag.note
    assert correct_pose_lag(clean, lag, PoseLagStageConfig()) is clean  # passed through, not copied
    forced_config = PipelineConfig().with_effects(["pose_lag"]).pose_lag
    forced = fit_pose_lag(clean, forced_config)
    assert forced.applied and forced.forced and "effect pose_lag" in forced.note
    assert abs(forced.lag_frames) < 0.1  # forcing applies the estimate, which is near zero here
    assert forced.z_score >= 1.0  # measured 1.9: a lag the frames can tell from none, however small


def test_a_forced_lag_within_its_standard_error_is_not_applied():
    """Forced on a recording whose estimate is within one standard error of 0 (the tiny scene's
    static sweep: 0.3), nothing is applied: the capture passes through, and every later stage
    computes what it did without the effect (applied, the 0.2-standard-error lag moved a clean
    scene's joint track residual by 6 %)."""
    clean = to_artifact(CaptureArtifact, generate_scene(BENCHMARK_SCENES["tiny"]).static)
    config = PipelineConfig().with_effects(["pose_lag"]).pose_lag
    lag = fit_pose_lag(clean, config)
    assert lag.estimated and lag.z_score < 1.0 and not lag.applied and not lag.forced
    assert "within one standard error of 0" in lag.note and "effect pose_lag is modelled" in lag.note
    assert correct_pose_lag(clean, lag, config) is clean


def test_the_switch_turns_the_correction_off_but_still_reports(captures):
    late, _ = captures
    lag = fit_pose_lag(late, PoseLagStageConfig(correct=False))
    assert lag.significant and not lag.applied and "pose_lag.correct is off" in lag.note
    with pytest.raises(ValueError, match="needs|correct is off"):
        PoseLagStageConfig(correct=False, model=True)


def test_a_recording_too_short_to_search_is_reported_not_refused(captures):
    late, _ = captures
    short = late.model_copy(update={f: getattr(late, f)[:5] for f in (
        "rgb", "depth", "confidence", "rgb_intrinsics", "depth_intrinsics", "world_from_camera", "timestamps", "frame_ids")})
    lag = fit_pose_lag(short, PoseLagStageConfig())
    assert not lag.estimated and not lag.applied and "5 frames" in lag.note
    assert correct_pose_lag(short, lag, PoseLagStageConfig()) is short


def test_the_lag_is_corrected_before_anything_reads_the_poses(tmp_path):
    scene = write_scene(generate_scene(BENCHMARK_SCENES["tiny"]), tmp_path / "scene")
    ex = RecordingExecutor()
    scene_pipeline(scene, PipelineConfig.preset("quick"), ex)
    for label in ("static", "dynamic"):
        assert ex.calls[f"pose_lag/{label}"] == {"capture": f"ingest/{label}"}
        assert ex.calls[f"correct_pose_lag/{label}"] == {"capture": f"ingest/{label}", "lag": f"pose_lag/{label}"}
    assert ex.calls["refine_poses/static"] == {"capture": "correct_pose_lag/static"}
    assert ex.calls["register/dynamic"] == {"static": "correct_pose_lag/static", "dynamic": "correct_pose_lag/dynamic"}
    assert ex.calls["part_masks/dynamic"]["dynamic"] == "correct_pose_lag/dynamic"
    assert ex.calls["diagnose/scene"]["pose_lag"] == "pose_lag/static"
    assert ex.calls["diagnose_dynamic/dynamic"]["pose_lag"] == "pose_lag/dynamic"
    # Off: the lag is still estimated and diagnosed, but every stage reads the capture as ingested.
    off = RecordingExecutor()
    config = PipelineConfig.preset("quick")
    scene_pipeline(scene, config.model_copy(update={"pose_lag": PoseLagStageConfig(correct=False)}), off)
    assert not any(k.startswith("correct_pose_lag") for k in off.calls)
    assert off.calls["refine_poses/static"] == {"capture": "ingest/static"}
    assert off.calls["register/dynamic"] == {"static": "ingest/static", "dynamic": "ingest/dynamic"}
    assert off.calls["diagnose_dynamic/dynamic"]["pose_lag"] == "pose_lag/dynamic"


def test_summary_and_diagnosis_report_the_lag_and_whether_it_was_corrected(captures, tmp_path):
    late, _ = captures
    applied = fit_pose_lag(late, PoseLagStageConfig())
    held = fit_pose_lag(late, PoseLagStageConfig(correct=False))
    store = ArtifactStore(tmp_path / "store")
    runs = {}
    for i, (label, art) in enumerate((("dynamic", applied), ("static", held))):
        key = f"{i + 1:x}" * 64
        store.put(key, art)
        runs[f"pose_lag/{label}"] = StageRun("pose_lag", label, key, PoseLagResult.kind, "computed", 0.1)
    stages = build_summary(tmp_path, store, runs, 0.0)["stages"]
    m = stages["pose_lag/dynamic"]["metrics"]
    assert m["lag_frames"] == pytest.approx(applied.lag_frames) and m["applied"] == 1.0 and m["significant"] == 1.0
    assert m["residual_after_m"] < m["residual_before_m"] and m["lag_se_s"] > 0
    assert stages["pose_lag/static"]["metrics"]["applied"] == 0.0 and "correct is off" in stages["pose_lag/static"]["notes"][0]

    findings, lines = pose_lag_finding(applied, DYNAMIC_SCOPE)
    assert findings[0].name == "pose_lag" and findings[0].significant and not findings[0].enabled
    assert findings[0].params["frames"] == pytest.approx(applied.lag_frames) and findings[0].params["applied"]
    assert "late" in lines[0] and "were corrected" in lines[0]
    # Significant but left alone: the diagnosis offers the rerun that corrects it.
    findings, lines = pose_lag_finding(held, DYNAMIC_SCOPE)
    assert findings[0].enabled and "--effect pose_lag" in lines[0]
    report = DiagnosisReport(findings=findings, enabled=[f"{DYNAMIC_SCOPE}/pose_lag"], conclusion=lines)
    assert rerun_effects(report, []) == (["dynamic:pose_lag"], [])  # in the scope it was found in
    config = PipelineConfig().with_effects(["pose_lag"])
    assert config.pose_lag.model and config.pose_lag.correct and config.enabled_effects() == ["pose_lag"]
