"""The effect depth_scale_offset through stages II-V: the sensor's affine depth error is found
from the static recording's own frames and undone in both recordings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.capture import DepthCalibrationConfig, calibrate_depth, estimate_depth_calibration
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene
from flows._pipeline import scene_pipeline
from schemas import CaptureArtifact, DepthCalibrationResult, PipelineConfig
from schemas import DepthCalibrationConfig as StageConfig
from tasks import to_artifact
from tasks.calibrate import calibrate_capture_depth, estimate_capture_depth_calibration
from tests._recorder import RecordingExecutor

BIAS = {"scale": 1.03, "offset_m": 0.01}  # the synthetic effect depth_bias: recorded = 1.03 z + 1 cm


def _door(bias: bool):
    spec = BENCHMARK_SCENES["door"]
    return generate_scene(replace(spec, effects=(("depth_bias", BIAS),) if bias else ()))


@pytest.fixture(scope="module")
def doors():
    return _door(False), _door(True)


def test_calibrate_depth_undoes_the_bias_exactly(doors):
    clean, biased = doors
    out = calibrate_depth(biased.static, BIAS["scale"], BIAS["offset_m"])
    assert out is not biased.static and out.depth is not biased.static.depth  # a new capture
    ok = np.isfinite(clean.static.depth)
    assert np.array_equal(ok, np.isfinite(out.depth))
    np.testing.assert_allclose(out.depth[ok], clean.static.depth[ok], atol=2e-6)
    np.testing.assert_array_equal(out.rgb, biased.static.rgb)
    # The biased depth itself is 1-8 cm off, so the comparison can fail.
    assert np.nanmax(np.abs(biased.static.depth - clean.static.depth)) > 0.05


def test_estimate_finds_the_injected_bias_and_no_bias_where_there_is_none(doors):
    clean, biased = doors
    found = estimate_depth_calibration(biased.static)
    assert found.scale == pytest.approx(1.03, abs=0.004), found
    assert found.offset_m == pytest.approx(0.01, abs=0.004), found
    none = estimate_depth_calibration(clean.static)
    assert none.scale == pytest.approx(1.0, abs=0.004), none
    assert none.offset_m == pytest.approx(0.0, abs=0.004), none
    # At the cabinet's 2 m: 0.07 m injected, found within 5 mm either way.
    assert abs(found.scale * 2.0 + found.offset_m - 2.07) < 0.005
    assert abs(none.scale * 2.0 + none.offset_m - 2.0) < 0.005


def test_bad_calibration_input_is_named(doors):
    _, biased = doors
    with pytest.raises(InputError, match="scale must be a positive"):
        calibrate_depth(biased.static, 0.0, 0.0)
    with pytest.raises(InputError, match="offset_m must be a finite"):
        calibrate_depth(biased.static, 1.0, float("nan"))
    two = replace(biased.static, **{f: getattr(biased.static, f)[:2] for f in
                                    ("rgb", "depth", "confidence", "rgb_intrinsics", "depth_intrinsics",
                                     "world_from_camera", "timestamps", "frame_ids")})
    with pytest.raises(InputError, match="no frame pairs"):
        estimate_depth_calibration(two, config=DepthCalibrationConfig(frame_gaps=(4,)))
    # Low-confidence depth is not used: with every pixel marked low, nothing overlaps.
    low = replace(biased.static, confidence=np.zeros_like(biased.static.confidence))
    with pytest.raises(InputError, match="points of the recording's frames overlap"):
        estimate_depth_calibration(low)
    assert estimate_depth_calibration(low, config=DepthCalibrationConfig(min_confidence=0)).points > 1000


def test_stages_estimate_on_the_static_recording_and_correct_either(doors):
    clean, biased = doors
    static = to_artifact(CaptureArtifact, biased.static, source_path="static.r3d")
    cal = estimate_capture_depth_calibration(static, StageConfig())
    assert isinstance(cal, DepthCalibrationResult) and cal.method == "multi-view-depth-consistency"
    assert cal.scale == pytest.approx(1.03, abs=0.004) and cal.points_count > 1000
    dynamic = to_artifact(CaptureArtifact, biased.dynamic)
    fixed = calibrate_capture_depth(dynamic, cal, StageConfig())
    ok = np.isfinite(clean.dynamic.depth) & np.isfinite(fixed.depth)
    err = np.abs(fixed.depth[ok] - clean.dynamic.depth[ok])
    assert np.median(err) < 0.004 and np.median(np.abs(dynamic.depth[ok] - clean.dynamic.depth[ok])) > 0.05
    np.testing.assert_array_equal(fixed.world_from_camera, dynamic.world_from_camera)
    assert cal.applied and not cal.note and cal.error_se_m < 0.002
    # An implausible or uncertain estimate is kept but not applied, and says why.
    for cfg, words in ((StageConfig(max_scale_error=0.01), "max_scale_error"),
                       (StageConfig(max_error_se_m=1e-5), "max_error_se_m")):
        held = estimate_capture_depth_calibration(static, cfg)
        assert not held.applied and words in held.note and "static.r3d" in held.note
        assert calibrate_capture_depth(dynamic, held, cfg).equals(dynamic)


def test_jittering_poses_make_the_estimate_uncertain_and_it_is_not_applied():
    """high-noise's static poses jitter by 3 mm / 3 mrad: the fit's 1.7 cm at 1.7 m is wrong (the
    sensor has no bias), and its standard error says so."""
    scene = generate_scene(BENCHMARK_SCENES["high-noise"])
    cal = estimate_capture_depth_calibration(to_artifact(CaptureArtifact, scene.static), StageConfig())
    err = (cal.scale - 1.0) * cal.reference_depth_m + cal.offset_m
    assert abs(err) < 3 * cal.error_se_m  # the error is within what the standard error admits
    assert cal.error_se_m > 0.01 and not cal.applied and "uncertain" in cal.note


def test_pipeline_routes_later_stages_through_the_calibration_when_modelled(tmp_path):
    scene = write_scene(generate_scene(BENCHMARK_SCENES["tiny"]), tmp_path / "scene")
    plain, ex = RecordingExecutor(), RecordingExecutor()
    scene_pipeline(scene, PipelineConfig.preset("quick"), plain)
    assert not any(k.startswith(("depth_calibration", "calibrate_depth")) for k in plain.calls)
    assert plain.calls["register/dynamic"] == {"static": "correct_pose_lag/static", "dynamic": "correct_pose_lag/dynamic"}
    scene_pipeline(scene, PipelineConfig.preset("quick").with_effects(["depth_scale_offset"]), ex)
    assert ex.calls["depth_calibration/static"] == {"capture": "correct_pose_lag/static"}
    cal = "depth_calibration/static"
    assert ex.calls["calibrate_depth/dynamic"] == {"capture": "correct_pose_lag/dynamic", "calibration": cal}
    assert ex.calls["register/dynamic"] == {"static": "calibrate_depth/static", "dynamic": "calibrate_depth/dynamic"}
    # The per-frame pose corrections are measured on the corrected depth, and later stages read both.
    assert ex.calls["frame_poses/dynamic"] == {"dynamic": "calibrate_depth/dynamic", "masks": "part_masks/dynamic"}
    assert ex.calls["correct_frame_poses/dynamic"]["capture"] == "calibrate_depth/dynamic"
    for name in ("track/dynamic", "joint_states/dynamic", "predict_dynamic/dynamic"):
        assert ex.calls[name]["dynamic"] == "correct_frame_poses/dynamic", name
    assert ex.calls["articulate/scene"]["static"] == "calibrate_depth/static"
    # Stage I too: the Gaussians start on metric depth, as the joints do.
    for name in ("refine_poses/static", "reconstruct/static", "predict_views/static", "diagnose/scene"):
        assert ex.calls[name]["capture"] == "calibrate_depth/static", name
    # ... and it is not asked to learn the corrected error again.
    assert "depth_scale_offset" not in ex.configs["reconstruct/static"].sensor_effects
