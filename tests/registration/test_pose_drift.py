"""The effect pose_drift: each recording's linear odometry drift is fitted and undone, and only
when it is real (large, certain, and the same in both halves of the recording)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.capture import (
    DepthCalibrationConfig,
    PoseDrift,
    drift_significance,
    estimate_depth_calibration,
)
from artitwin_core.change import build_canonical_tsdf
from artitwin_core.geometry import axis_angle_to_matrix, make_se3
from artitwin_core.registration import estimate_session_drift
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene
from flows._pipeline import scene_pipeline
from schemas import CaptureArtifact, PipelineConfig, PoseDriftConfig
from tasks import to_artifact
from tasks.drift import correct_pose_drift, fit_static_drift
from tests._recorder import RecordingExecutor

GRAVITY = (0.0, -1.0, 0.0)
DRIFT = {"trans_m_per_s": 0.02, "yaw_rad_per_s": 0.01}  # the synthetic effect's defaults
BIAS = {"scale": 1.03, "offset_m": 0.01}
GATE = PoseDriftConfig()


def _door(*effects):
    return generate_scene(replace(BENCHMARK_SCENES["door"], effects=tuple(effects)))


def _error_at_pivot_mm(poses: np.ndarray, true: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """``[T]`` how far each pose's error moves ``pivot``, with frame 0's error taken out (the
    static recording defines its own world frame only up to its first pose)."""
    out = []
    for p, q in zip(poses, true, strict=True):
        err = p @ np.linalg.inv(q)
        out.append(err[:3, :3] @ pivot + err[:3, 3] - pivot)
    out = np.asarray(out)
    return 1e3 * np.linalg.norm(out - out[0], axis=1)


@pytest.fixture(scope="module")
def drifting():
    return _door(("pose_drift", DRIFT))


@pytest.fixture(scope="module")
def clean():
    return _door()


def _rigid(rng) -> np.ndarray:
    return make_se3(axis_angle_to_matrix(rng.normal(size=3), rng.uniform(0, np.pi)), rng.normal(size=3))


def test_a_drift_moves_poses_as_its_rates_say_and_changes_frame_consistently():
    rng = np.random.default_rng(0)
    drift = PoseDrift(pivot=rng.normal(size=3), t0_s=1.0, rot0_rad=0.01 * rng.normal(size=3), trans0_m=0.01 * rng.normal(size=3),
                      rot_rate_rad_per_s=np.array([0.0, 0.02, 0.0]), trans_rate_m_per_s=np.array([0.01, 0.0, -0.02]))
    poses, ts = np.stack([_rigid(rng) for _ in range(5)]), np.array([1.0, 1.5, 2.0, 3.0, 4.0])
    # At t0 only the constant part acts; the pivot is moved by the offset's translation only.
    g = drift.correction(ts)
    assert np.allclose(g[0][:3, :3] @ drift.pivot + g[0][:3, 3], drift.pivot + drift.trans0_m)
    # The same correction seen from another frame.
    m = _rigid(rng)
    moved = drift.in_frame(m).apply(np.einsum("ij,tjk->tik", m, poses), ts)
    assert np.allclose(moved, np.einsum("ij,tjk->tik", m, drift.apply(poses, ts)), atol=1e-12)
    # rate_at is the rate part's velocity of a point (finite difference, 1 ms).
    x = rng.normal(size=3)
    numeric = (drift.rate_displacement_m(x, 1.001) - drift.rate_displacement_m(x, 1.0)) / 0.001
    assert np.allclose(drift.rate_at(x), numeric, atol=1e-6)
    # The gate: size, then significance, then both halves (unknown halves: not applied).
    sig = drift_significance(drift, x, 4.0, 1e-8 * np.eye(4), yaw_axis=np.array([0.0, 1.0, 0.0]))
    assert sig.size_m > 0.03 and sig.z_score > 100  # 3 s at 1.2 cm/s
    assert "too short" in sig.why_not(0.01, 3.0, 1.0)
    rate = sig.rate_m_per_s
    assert sig.why_not(10.0, 3.0, 1.0).endswith("under the 10000 mm that would matter")
    assert "standard errors" in sig.why_not(0.01, 1e6, 1.0)
    agree = replace(sig, half_rates_m_per_s=np.stack([rate * 1.2, rate * 0.8]))
    assert agree.half_disagreement == pytest.approx(0.4) and agree.why_not(0.01, 3.0, 1.0) == ""
    assert "halves of the recording disagree" in replace(sig, half_rates_m_per_s=np.stack([rate * 2, -rate])).why_not(0.01, 3.0, 1.0)


def test_static_drift_is_recovered_from_the_recordings_own_frames(drifting, clean):
    cfg = DepthCalibrationConfig(pose_drift=True)  # as the static_drift stage fits it
    fit = estimate_depth_calibration(drifting.static, config=cfg)
    # The recorded poses turn at +0.01 rad/s about up (-gravity); the correction turns them back.
    yaw = float(np.dot(fit.drift.rot_rate_rad_per_s, -np.asarray(GRAVITY)))
    assert yaw == pytest.approx(-DRIFT["yaw_rad_per_s"], abs=0.0015), fit.drift  # measured -0.0101
    pivot = drifting.truth.joints[0].pivot
    before = _error_at_pivot_mm(drifting.static.world_from_camera, drifting.truth.static_world_from_camera, pivot)
    after = _error_at_pivot_mm(fit.drift.apply(drifting.static.world_from_camera, drifting.static.timestamps),
                               drifting.truth.static_world_from_camera, pivot)
    assert before.max() > 60 and after.max() < 8, (before.round(1), after.round(1))  # measured 86 -> 3.5 mm
    sig = fit.drift_significance
    assert sig.half_rates_m_per_s is not None and sig.half_disagreement < 0.3
    assert sig.why_not(GATE.min_displacement_m, GATE.min_z_score, GATE.max_half_disagreement) == ""
    # No drift: a millimetre-sized fit, and the gate says so.
    none = estimate_depth_calibration(clean.static, config=cfg).drift_significance
    assert none.size_m < 0.005
    assert "under the 10 mm" in none.why_not(GATE.min_displacement_m, GATE.min_z_score, GATE.max_half_disagreement)


def test_the_depth_error_is_found_once_the_static_drift_is_undone():
    """A drift bends the frames' agreement as a depth error does: with drifting poses the depth
    error's estimate is uncertain (and wrong); the drift fitted with the depth error as a nuisance
    undoes it, and the plain estimate on the corrected poses is the injected error."""
    scene = _door(("pose_drift", DRIFT), ("depth_bias", BIAS))
    drifting_poses = estimate_depth_calibration(scene.static)
    assert drifting_poses.error_se_m > 0.01  # measured 30 mm: the stage would not apply it
    joint = estimate_depth_calibration(scene.static, config=DepthCalibrationConfig(pose_drift=True))
    s = scene.static
    fixed = replace(s, world_from_camera=joint.drift.apply(s.world_from_camera, s.timestamps))
    cal = estimate_depth_calibration(fixed)
    assert cal.scale == pytest.approx(1.03, abs=0.004) and cal.offset_m == pytest.approx(0.01, abs=0.004), cal
    assert cal.error_se_m < 0.003


@pytest.fixture(scope="module")
def dynamic_fit(drifting):
    s, d = drifting.static, drifting.dynamic
    static_fit = estimate_depth_calibration(s, config=DepthCalibrationConfig(pose_drift=True))
    s = replace(s, world_from_camera=static_fit.drift.apply(s.world_from_camera, s.timestamps))
    mesh = build_canonical_tsdf(s)
    # The true registration and part and hand masks: the registration and the part finder are
    # tested on their own (tests/registration, tests/change), and took half of this fixture's time.
    truth = drifting.truth
    c = truth.canonical_from_dynamic_session
    fit = estimate_session_drift(d, c, mesh, truth.part_masks, truth.hand_masks, s)
    return c, truth, mesh, s, fit


@pytest.mark.slow
def test_dynamic_drift_is_fitted_against_the_canonical_model(drifting, dynamic_fit):
    c, _, _, _, fit = dynamic_fit
    d, truth = drifting.dynamic, drifting.truth
    pivot = truth.joints[0].pivot

    def at_pivot(poses):
        out = []
        for t in range(d.num_frames):
            err = c @ poses[t] @ np.linalg.inv(truth.dynamic_world_from_camera[t])
            out.append(1e3 * np.linalg.norm(err[:3, :3] @ pivot + err[:3, 3] - pivot))
        return np.asarray(out)

    before = at_pivot(d.world_from_camera)
    after = at_pivot(fit.drift.apply(d.world_from_camera, d.timestamps))
    assert before.max() > 10 and after.max() < 4, (before.round(1), after.round(1))  # measured 17.6 -> 1.7 mm
    assert fit.significance.why_not(GATE.min_displacement_m, GATE.min_z_score, GATE.max_half_disagreement) == ""


def test_session_drift_input_errors_are_named(drifting, dynamic_fit):
    c, truth, mesh, s, _ = dynamic_fit
    with pytest.raises(InputError, match="masks have shapes"):
        estimate_session_drift(drifting.dynamic, c, mesh, truth.part_masks[:-1], truth.hand_masks, s)
    # Everything masked: nothing left to fit.
    with pytest.raises(InputError, match="fewer than 100 unmasked depth points"):
        estimate_session_drift(drifting.dynamic, c, mesh, np.ones_like(truth.part_masks), truth.hand_masks, s)


@pytest.mark.slow
def test_a_trend_the_halves_disagree_on_is_not_applied():
    """high-noise has no drift, but its jittering poses and noisy canonical model fake a 1 cm trend
    with a small jackknife error (z 10); the two halves of the recording fit trends 5 times
    apart, so the gate leaves it alone. With the true registration and masks: the recording's
    own poses and depth make the trend (the pipeline's registration and part finder, 80 % of this
    test's time, gave 10.3 mm at z 8.4, halves 5.4 times apart)."""
    scene = generate_scene(BENCHMARK_SCENES["high-noise"])
    s, d, truth = scene.static, scene.dynamic, scene.truth
    mesh = build_canonical_tsdf(s)
    sig = estimate_session_drift(d, truth.canonical_from_dynamic_session, mesh, truth.part_masks, truth.hand_masks, s).significance
    assert sig.size_m > GATE.min_displacement_m and sig.z_score > GATE.min_z_score  # size and z alone would apply it
    why = sig.why_not(GATE.min_displacement_m, GATE.min_z_score, GATE.max_half_disagreement)
    assert "halves of the recording disagree" in why and sig.half_disagreement > 2  # measured 11.1 mm, z 10.3, 4.9


def test_stages_fit_decide_and_correct(drifting, clean):
    static = to_artifact(CaptureArtifact, drifting.static)
    drift = fit_static_drift(static, GATE)
    assert drift.applied and not drift.note and drift.recording == "static"
    fixed = correct_pose_drift(static, drift, GATE)
    pivot = drifting.truth.joints[0].pivot
    err = _error_at_pivot_mm(fixed.world_from_camera, drifting.truth.static_world_from_camera, pivot)
    assert err.max() < 8
    np.testing.assert_array_equal(fixed.depth, static.depth)
    # No drift in the recording: fitted, stored, not applied, and the capture is left as it is.
    plain = to_artifact(CaptureArtifact, clean.static)
    held = fit_static_drift(plain, GATE)
    assert not held.applied and "not applied" in held.note and "static" in held.note
    assert correct_pose_drift(plain, held, GATE).equals(plain)


def test_pipeline_routes_later_stages_through_the_drift_corrections(tmp_path):
    scene = write_scene(generate_scene(BENCHMARK_SCENES["tiny"]), tmp_path / "scene")
    plain = RecordingExecutor()
    scene_pipeline(scene, PipelineConfig.preset("quick"), plain)
    assert not any("drift" in k for k in plain.calls)
    ex = RecordingExecutor()
    config = PipelineConfig.preset("quick").with_effects(["pose_drift", "depth_scale_offset"])
    assert config.enabled_effects() == ["depth_scale_offset", "pose_drift"]
    scene_pipeline(scene, config, ex)
    # The static drift first: the depth calibration would be biased by drifting poses.
    assert ex.calls["static_drift/static"] == {"capture": "correct_pose_lag/static"}
    assert ex.calls["correct_pose_drift/static"] == {"capture": "correct_pose_lag/static", "drift": "static_drift/static"}
    assert ex.calls["depth_calibration/static"] == {"capture": "correct_pose_drift/static"}
    assert ex.calls["calibrate_depth/static"] == {"capture": "correct_pose_drift/static", "calibration": "depth_calibration/static"}
    assert ex.calls["register/dynamic"] == {"static": "calibrate_depth/static", "dynamic": "calibrate_depth/dynamic"}
    # The dynamic drift after the masks, against the corrected static recording.
    assert ex.calls["session_drift/dynamic"] == {
        "static": "calibrate_depth/static", "dynamic": "calibrate_depth/dynamic",
        "registration": "register/dynamic", "masks": "part_masks/dynamic",
    }
    assert ex.calls["correct_pose_drift/dynamic"] == {"capture": "calibrate_depth/dynamic", "drift": "session_drift/dynamic"}
    # The per-frame pose corrections on top of the drift's, then every later stage reads the result.
    assert ex.calls["frame_poses/dynamic"] == {"dynamic": "correct_pose_drift/dynamic", "masks": "part_masks/dynamic"}
    assert ex.calls["correct_frame_poses/dynamic"] == {
        "capture": "correct_pose_drift/dynamic", "corrections": "frame_poses/dynamic",
    }
    for name in ("track/dynamic", "settle_parts/dynamic", "joint_states/dynamic", "predict_dynamic/dynamic", "articulate/scene",
                 "export/scene"):
        assert ex.calls[name]["dynamic"] == "correct_frame_poses/dynamic", name
    assert ex.calls["reconstruct/static"]["capture"] == "calibrate_depth/static"
    assert ex.calls["articulate/scene"]["static"] == "calibrate_depth/static"


def test_the_diagnosis_finds_a_drift_and_a_depth_error_from_the_recording_itself(drifting, clean):
    """The twin-based tests cannot tell a drift or a depth error from a short-trained twin's own
    geometry; the static recording's self-consistency can, and names the effect to model."""
    from schemas._diagnose import DiagnoseConfig
    from tasks.diagnose import self_consistency, self_consistency_metrics

    def enabled(scene):
        findings, lines = self_consistency(to_artifact(CaptureArtifact, scene.static), DiagnoseConfig())
        on = sorted(f.name for f in findings if f.enabled)
        assert len(lines) == len(on) and all(f"--effect {name}" in " ".join(lines) for name in on)
        return on, {f.name: f for f in findings}

    on, found = enabled(drifting)
    assert on == ["pose_drift"] and found["pose_drift"].params["z_score"] > 10
    on, found = enabled(_door(("depth_bias", BIAS)))
    assert on == ["depth_scale_offset"]
    assert found["depth_scale_offset"].params["scale"] == pytest.approx(1.03, abs=0.004)
    # The metrics compare leads with when depth_scale_offset is modelled (the twin absorbs the bias).
    err = "static recording/self_consistency_depth_error_m"
    biased = self_consistency_metrics(list(found.values()))
    assert biased[err] > 10 * biased[err + "_se"]
    on, found = enabled(clean)
    assert on == [] and not any(f.significant for f in found.values())
    assert self_consistency_metrics(list(found.values()))[err] < 0.2 * biased[err]


def test_the_self_consistency_test_is_not_run_on_coarse_depth():
    """On 64x48 depth maps the test's standard errors are too small to gate on (it flagged 4 of 20
    clean tiny recordings): it says it did not run rather than advise a depth correction."""
    from schemas._diagnose import DiagnoseConfig
    from tasks.diagnose import self_consistency

    coarse = to_artifact(CaptureArtifact, generate_scene(BENCHMARK_SCENES["tiny"]).static)
    assert coarse.depth.shape[1] * coarse.depth.shape[2] < DiagnoseConfig().self_consistency_min_depth_pixels
    findings, lines = self_consistency(coarse, DiagnoseConfig())
    assert findings == [] and len(lines) == 1 and "was not tested" in lines[0] and "64x48" in lines[0]
    findings, _ = self_consistency(coarse, DiagnoseConfig(self_consistency_min_depth_pixels=0))
    assert {f.name for f in findings} == {"pose_drift", "depth_scale_offset"}
