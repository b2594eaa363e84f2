"""The diagnose stage on artifacts: a synthetic capture with exposure wander and a rising hinge,
predicted by the ground truth without either; the report names both, with errors before and after,
survives the store, and its HTML shows plots and residual maps."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
import zarr
from zarr.storage import MemoryStore

from artitwin_core import InputError
from artitwin_core.diagnostics._synthetic import synthetic_tracks
from artitwin_core.synth import render_state
from artitwin_core.synth._generate import scene_model
from artitwin_core.synth._motion import camera_path
from schemas import Artifact, CaptureArtifact, JointParams, JointSet, TrajectoriesArtifact
from schemas._diagnose import DiagnoseConfig, DiagnosisReport, ViewPrediction
from tasks._convert import to_artifact
from tasks.diagnose import STATIC_SCOPE, diagnose_twin
from tests.diagnostics._scenes import scene

EFFECTS = (("exposure", {}), ("screw_joint", {}))


def _artifacts(effects):
    sc = scene("door", effects)
    cap, truth = sc.static, sc.truth
    h, w = cap.rgb.shape[1:3]
    dh, dw = cap.depth.shape[1:3]
    rgb, depth = [], []
    for t in range(cap.num_frames):
        pose = truth.static_world_from_camera[t]
        rgb.append(render_state(sc, pose, cap.rgb_intrinsics[t], w, h, q=[0.0])[0])
        depth.append(render_state(sc, pose, cap.depth_intrinsics[t], dw, dh, q=[0.0])[1])
    prediction = ViewPrediction(rgb=np.stack(rgb), depth=np.stack(depth), frame_ids=cap.frame_ids.astype(np.int64))
    obs, valid = synthetic_tracks(sc, 0, n_points=120)
    traj = TrajectoriesArtifact(points_in_world=obs, pixels=np.full(obs.shape[:2] + (2,), np.nan, np.float32),
                                valid=valid, part_ids=np.zeros(obs.shape[1], np.int32))
    hinge = replace(truth.joints[0], joint_type="revolute", pitch=0.0)  # the twin's joint: a pure hinge
    joints = JointSet(joints=[to_artifact(JointParams, hinge, name="joint_0")])
    return to_artifact(CaptureArtifact, cap), prediction, joints, traj


def test_stage_names_both_effects_and_the_error_falls():
    capture, prediction, joints, traj = _artifacts(EFFECTS)
    report = diagnose_twin(capture, prediction, joints, traj, DiagnoseConfig())
    assert report.enabled == [f"{STATIC_SCOPE}/exposure_white_balance", "joint_0/screw_joint"]
    assert not report.no_effect_needed
    m = report.metrics
    assert m[f"{STATIC_SCOPE}/photometric_energy_after"] < 0.05 * m[f"{STATIC_SCOPE}/photometric_energy_before"]
    assert m["joint_0/joint-tracks_energy_after"] < 0.5 * m["joint_0/joint-tracks_energy_before"]
    # Per-frame curves: every frame improves on RGB; the track error falls overall.
    before, after = (np.array(report.per_frame[f"{STATIC_SCOPE}/rgb_rms_{w}"]) for w in ("before", "after"))
    assert len(before) == capture.rgb.shape[0] and np.all(after < before)
    tb, ta = (np.nanmean(report.per_frame[f"joint_0/track_rms_m_{w}"]) for w in ("before", "after"))
    assert ta < tb
    # Held-out frames: each effect refitted without them still lowers the error there.
    for scope, effect, err in ((STATIC_SCOPE, "exposure_white_balance", "rgb_mae_linear"),
                               ("joint_0", "screw_joint", "track_rms_m")):
        assert m[f"{scope}/{effect}/heldout_{err}_after"] < m[f"{scope}/{effect}/heldout_{err}_before"]
        assert m[f"{scope}/heldout_{err}_after"] < m[f"{scope}/heldout_{err}_before"]
    assert m[f"{STATIC_SCOPE}/heldout_image_frames_count"] == 3
    assert "Held-out frames" in report.html and "re-estimated on each held-out frame" in report.html
    screw = next(f for f in report.findings if f.scope == "joint_0" and f.name == "screw_joint")
    assert screw.enabled and screw.significant
    assert screw.params["pitch_m_per_rad"] == pytest.approx(scene("door", EFFECTS).truth.joints[0].pitch, abs=0.0015)
    # The HTML report: ranked effects, error curves as SVG, residual maps as PNG.
    assert "exposure_white_balance" in report.html and "<svg" in report.html
    assert "data:image/png;base64," in report.html and "rgb_rms per frame" in report.html
    assert report.images and report.images[0].pixels.ndim == 3
    # The report is an artifact like any other: it round-trips exactly.
    group = zarr.open_group(MemoryStore(), mode="w")
    report.to_zarr(group)
    assert Artifact.from_zarr(group).equals(report)
    assert isinstance(Artifact.from_zarr(group), DiagnosisReport)


def test_stage_on_a_clean_scene_says_no_effect_is_needed():
    report = diagnose_twin(*_artifacts(()), DiagnoseConfig())
    assert report.enabled == [] and report.no_effect_needed
    assert report.metrics["significant_count"] == 0
    assert len(report.findings) >= 5  # tested, found nothing
    m = report.metrics
    for err in ("rgb_mae_linear", "depth_mae_m", "depth_nll_nats"):
        assert m[f"{STATIC_SCOPE}/heldout_{err}_after"] == m[f"{STATIC_SCOPE}/heldout_{err}_before"]


def test_stage_restricted_to_named_effects():
    capture, prediction, joints, traj = _artifacts(EFFECTS)
    report = diagnose_twin(capture, prediction, JointSet(joints=[]), traj, DiagnoseConfig(effects=["depth_scale_offset"]))
    assert {f.name for f in report.findings} == {"depth_scale_offset"}
    assert report.enabled == []
    assert any("Unexplained structure" in line and "photometric" in line for line in report.conclusion)
    with pytest.raises(InputError, match="unknown effects \\['glue_creep'\\]"):
        diagnose_twin(capture, prediction, joints, traj, DiagnoseConfig(effects=["glue_creep"]))


def test_stage_refuses_a_prediction_of_another_size():
    capture, prediction, joints, traj = _artifacts(())
    small = prediction.model_copy(update={"depth": prediction.depth[:, :-1]})
    with pytest.raises(InputError, match="depth intrinsics and size"):
        diagnose_twin(capture, small, joints, traj, DiagnoseConfig())


def test_predict_views_renders_every_frame_at_the_capture_sizes():
    from schemas import CameraPoses, GaussianCheckpoint
    from schemas._diagnose import PredictViewsConfig
    from tasks.diagnose import predict_views

    capture = to_artifact(CaptureArtifact, scene("door").static)
    capture = capture.model_copy(update={k: getattr(capture, k)[:3] for k in (
        "rgb", "depth", "confidence", "rgb_intrinsics", "depth_intrinsics", "world_from_camera", "timestamps", "frame_ids")})
    rng = np.random.default_rng(0)
    n = 200
    centre = capture.world_from_camera[0, :3, 3] + 1.5 * capture.world_from_camera[0, :3, 2]  # 1.5 m ahead
    ckpt = GaussianCheckpoint(
        means=(centre + 0.3 * rng.standard_normal((n, 3))).astype(np.float32),
        quats_wxyz=np.tile(np.float32([1, 0, 0, 0]), (n, 1)), log_scales=np.full((n, 3), np.log(0.05), np.float32),
        opacity_logits=np.full(n, 3.0, np.float32), sh=(0.3 * rng.standard_normal((n, 1, 3))).astype(np.float32),
        labels=np.zeros(n, np.int32))
    poses = CameraPoses(world_from_camera=capture.world_from_camera, frame_ids=capture.frame_ids, frame="canonical")
    pred = predict_views(capture, poses, ckpt, PredictViewsConfig(backend="cpu"))
    np.testing.assert_array_equal(pred.world_from_camera, capture.world_from_camera)
    assert pred.rgb.shape == capture.rgb.shape and pred.depth.shape == capture.depth.shape
    assert 0.05 < pred.coverage[0].mean() < 0.99
    assert 0.8 < np.nanmedian(pred.depth[0]) < 2.2  # the blob sits 1.5 m ahead of frame 0
    report = diagnose_twin(capture, pred, JointSet(joints=[]), _artifacts(())[3], DiagnoseConfig())
    assert report.findings and report.html


def test_predictions_of_some_frames_at_a_lower_resolution_are_diagnosed():
    """PredictViewsConfig.max_frames and max_side (the CPU preset's): runs of consecutive frames at a
    lower RGB resolution; the diagnosis compares them with those frames of the capture, downscaled."""
    from schemas import CameraPoses, GaussianCheckpoint
    from schemas._diagnose import PredictViewsConfig
    from tasks.diagnose import predict_views, prediction_frames

    assert prediction_frames(10, PredictViewsConfig()) == list(range(10))
    assert prediction_frames(40, PredictViewsConfig(max_frames=12, run_frames=4)) == [
        0, 1, 2, 3, 18, 19, 20, 21, 36, 37, 38, 39]
    capture, prediction, joints, traj = _artifacts(EFFECTS)
    n = 200
    rng = np.random.default_rng(0)
    centre = capture.world_from_camera[0, :3, 3] + 1.5 * capture.world_from_camera[0, :3, 2]
    ckpt = GaussianCheckpoint(
        means=(centre + 0.3 * rng.standard_normal((n, 3))).astype(np.float32),
        quats_wxyz=np.tile(np.float32([1, 0, 0, 0]), (n, 1)), log_scales=np.full((n, 3), np.log(0.05), np.float32),
        opacity_logits=np.full(n, 3.0, np.float32), sh=(0.3 * rng.standard_normal((n, 1, 3))).astype(np.float32),
        labels=np.zeros(n, np.int32))
    poses = CameraPoses(world_from_camera=capture.world_from_camera, frame_ids=capture.frame_ids, frame="canonical")
    h, w = capture.rgb.shape[1:3]
    pred = predict_views(capture, poses, ckpt, PredictViewsConfig(backend="cpu", max_side=w // 2, max_frames=6, run_frames=3))
    assert pred.rgb.shape[0] == 6 and pred.rgb.shape[1:3] == (h // 2, w // 2)
    assert pred.depth.shape[1:] == capture.depth.shape[1:]
    np.testing.assert_array_equal(pred.frame_ids, capture.frame_ids[prediction_frames(len(capture.frame_ids),
                                  PredictViewsConfig(max_frames=6, run_frames=3))])
    # The ground truth, predicted for those frames at half resolution, still shows the exposure wander.
    keep = np.searchsorted(prediction.frame_ids, pred.frame_ids)
    small = np.stack([cv2.resize(f, (w // 2, h // 2), interpolation=cv2.INTER_AREA) for f in prediction.rgb[keep]])
    truth = ViewPrediction(rgb=small, depth=prediction.depth[keep], frame_ids=pred.frame_ids)
    report = diagnose_twin(capture, truth, joints, traj, DiagnoseConfig())
    assert f"{STATIC_SCOPE}/exposure_white_balance" in report.enabled
    # The report says which recording frames its curves are (a comparison finds the held-out ones by them).
    assert report.frames[STATIC_SCOPE] == prediction_frames(len(capture.frame_ids), PredictViewsConfig(max_frames=6, run_frames=3))
    assert report.recording_frames[STATIC_SCOPE] == len(capture.frame_ids)


def test_states_on_the_rgb_clock_are_compared_on_the_tracks_clock():
    """With the effect time_offset modelled, joint_states writes the states on the RGB clock; the
    tracks were lifted with the later depth, so the joint-tracks residual moves them back."""
    from artitwin_core.joints import Joint, to_rgb_clock
    from tasks._convert import to_core

    capture, prediction, joints, traj = _artifacts(())
    ts = scene("door", ()).dynamic.timestamps
    lag = 0.05
    on_rgb = to_artifact(JointParams, to_rgb_clock(to_core(Joint, joints.joints[0]), ts, lag), name="joint_0")
    cfg = DiagnoseConfig(effects=["screw_joint"])

    def energy(js: JointSet) -> float:
        return diagnose_twin(capture, prediction, js, traj, cfg).metrics["joint_0/joint-tracks_energy_before"]

    base = energy(joints)
    naive = energy(JointSet(joints=[on_rgb]))
    aware = energy(JointSet(joints=[on_rgb], rgb_time_offset_s=lag, timestamps=ts))
    # Measured: the 50 ms lag shows as 27x the residual of the tracks' own clock; moved back, 6x
    # (this scene has 6 frames a second, and the states were interpolated there and back).
    assert naive > 10.0 * base, (naive, base)
    assert aware < 0.3 * naive, (aware, naive)
    # joint_states keeps the states as measured (depth_clock_q): the residual is the tracks' own
    kept = energy(JointSet(joints=[on_rgb], rgb_time_offset_s=lag, timestamps=ts,
                           depth_clock_q=np.asarray(joints.joints[0].q, np.float64)[None]))
    assert kept == pytest.approx(base, rel=0.01), (kept, base)


def test_predict_dynamic_renders_rgb_and_depth_each_on_its_clock(monkeypatch):
    """States on the RGB clock (time_offset modelled): each frame's RGB is rendered at its exposure
    (pose interpolated back, the states as stored), its depth at the recorded pose with the
    states moved back to the depth map's time."""
    import tasks.diagnose as td
    from artitwin_core.joints import Joint, poses_on_rgb_clock, to_rgb_clock
    from schemas import GaussianCheckpoint, MaskSequenceArtifact, Registration
    from schemas._diagnose import PredictViewsConfig
    from tasks._convert import to_core

    sc = scene("door", ())
    dyn = to_artifact(CaptureArtifact, sc.dynamic)
    t_frames = dyn.rgb.shape[0]
    hinge = replace(sc.truth.joints[0], joint_type="revolute", pitch=0.0)
    lag = 0.05
    stored = JointSet(joints=[to_artifact(JointParams, hinge, name="joint_0")], rgb_time_offset_s=lag,
                      timestamps=dyn.timestamps)
    ckpt = GaussianCheckpoint(
        means=np.zeros((1, 3), np.float32), quats_wxyz=np.float32([[1, 0, 0, 0]]), log_scales=np.zeros((1, 3), np.float32),
        opacity_logits=np.zeros(1, np.float32), sh=np.zeros((1, 1, 3), np.float32), labels=np.zeros(1, np.int32))
    calls = []

    class FakeTwin:
        def __init__(self, params, joints, **_):
            pass

        def render(self, q, pose, intrinsics, w, h):
            calls.append((w, np.asarray(q, float), np.asarray(pose)))
            return np.zeros((h, w, 3)), np.ones((h, w)), np.ones((h, w))

    monkeypatch.setattr(td, "TwinRenderer", FakeTwin)
    masks = MaskSequenceArtifact(part=np.zeros(dyn.rgb.shape[:3], np.uint8), hand=np.zeros(dyn.rgb.shape[:3], bool),
                                 score=np.ones(t_frames, np.float32))
    reg = Registration(canonical_from_session=np.eye(4), residual_m=0.0, inlier_fraction=1.0, method="test")
    td.predict_dynamic(ckpt, dyn, reg, masks, stored, PredictViewsConfig(backend="cpu"))
    width = dyn.rgb.shape[2]
    rgb_calls = [c for c in calls if c[0] == width]
    depth_calls = [c for c in calls if c[0] != width]
    stream = (dyn.stream_timestamps, dyn.stream_world_from_camera)
    rgb_poses = poses_on_rgb_clock(dyn.world_from_camera, dyn.timestamps, lag, stream)
    # read off the 30 fps pose stream, the RGB pose is the camera's 50 ms earlier (the scene's poses
    # are exact): within 0.1 mm (measured 0.03), where the frames' own poses, 0.17 s apart, put it
    # up to 6.7 mm off (median 3.8)
    path = camera_path(scene_model(sc.spec), sc.spec.seed, "dynamic", float(sc.dynamic.timestamps[-1]), sc.spec.dynamic_path)
    inside = dyn.timestamps >= lag
    truth = np.linalg.inv(sc.truth.canonical_from_dynamic_session) @ path.world_from_camera(dyn.timestamps[inside] - lag)
    off = np.linalg.norm(rgb_poses[inside, :3, 3] - truth[:, :3, 3], axis=1)
    chords = poses_on_rgb_clock(dyn.world_from_camera, dyn.timestamps, lag)[inside]
    assert off.max() < 1e-4 < np.linalg.norm(chords[:, :3, 3] - truth[:, :3, 3], axis=1).max(), off
    depth_q = to_rgb_clock(to_core(Joint, stored.joints[0]), dyn.timestamps, -lag).q
    for t in range(t_frames):
        np.testing.assert_allclose(rgb_calls[t][2], rgb_poses[t])
        np.testing.assert_allclose(rgb_calls[t][1], [hinge.q[t]])
        np.testing.assert_allclose(depth_calls[t][2], dyn.world_from_camera[t])
        np.testing.assert_allclose(depth_calls[t][1], [depth_q[t]])
    # The camera moves between frames, so the two clocks' poses differ.
    assert max(np.linalg.norm(rgb_poses[t][:3, 3] - dyn.world_from_camera[t][:3, 3]) for t in range(t_frames)) > 1e-3

    # At half the RGB resolution, on some frames: the hand leaves the coverage at that size (any pixel
    # of it makes a coarse pixel the hand's) and the depth wherever it spans a full-resolution hand pixel.
    h, w = dyn.rgb.shape[1:3]
    _, dh, dw = dyn.depth.shape
    hand = np.zeros(dyn.rgb.shape[:3], bool)
    hand[:, 11, 13] = True
    with_hand = masks.model_copy(update={"hand": hand})
    cfg = PredictViewsConfig(backend="cpu", max_side=w // 2, max_frames=4, run_frames=2)
    pred = td.predict_dynamic(ckpt, dyn, reg, with_hand, stored, cfg)
    assert pred.rgb.shape == (4, h // 2, w // 2, 3) and pred.depth.shape == (4, dh, dw)
    np.testing.assert_array_equal(pred.frame_ids, dyn.frame_ids[td.prediction_frames(t_frames, cfg)])
    assert (~pred.coverage).sum(axis=(1, 2)).tolist() == [1] * 4 and not pred.coverage[:, 5, 6].any()
    assert np.isnan(pred.depth).sum(axis=(1, 2)).tolist() == [1] * 4
    assert np.isnan(pred.depth[:, 11 * dh // h, 13 * dw // w]).all()
