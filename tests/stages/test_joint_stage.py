"""The fit_joints stage: one joint per part, from one trajectories artifact."""

from __future__ import annotations

import numpy as np

from artitwin_core.joints import joint_errors, random_part_joint, simulate_trajectories
from schemas import JointParams, MaskSequenceArtifact, TrajectoriesArtifact
from tasks.joints import JointConfig, fit_joints


def _tracks_of_parts(trajs) -> TrajectoriesArtifact:
    """One trajectories artifact holding each simulated part's tracks, part ``k``'s with part id ``k``."""
    return TrajectoriesArtifact(
        points_in_world=np.concatenate([t.points_in_world for t in trajs], axis=1),
        pixels=np.concatenate([t.pixels for t in trajs], axis=1).astype(np.float32),
        valid=np.concatenate([t.valid for t in trajs], axis=1),
        part_ids=np.repeat(np.arange(len(trajs), dtype=np.int32), [t.valid.shape[1] for t in trajs]),
    )


def test_two_parts_get_their_own_joints():
    rng = np.random.default_rng(7)
    truths, trajs = [], []
    for kind in ("revolute", "prismatic"):
        joint, closed = random_part_joint(kind, 150, 20, rng)
        traj, _ = simulate_trajectories(joint, closed, rng, noise_m=0.001, outlier_fraction=0.1)
        truths.append(joint)
        trajs.append(traj)
    art = _tracks_of_parts(trajs)
    t = art.valid.shape[0]
    labels = np.zeros((t, 2, 3), np.uint8)
    labels[:, 0, 0], labels[:, 1, 1], labels[:, 1, 2] = 1, 2, 3  # label 3 has no tracks at all
    masks = MaskSequenceArtifact(part=labels, hand=np.zeros(labels.shape, bool), score=np.ones(t, np.float32))
    out = fit_joints(art, masks, JointConfig())
    assert [j.name for j in out.joints] == ["joint_0", "joint_1"] and out.mask_labels == [1, 2]
    # The candidate without tracks gets no joint and a fate saying why; the others are fitted.
    assert [(f.candidate, f.label, f.fate, f.stage) for f in out.fates] == [(2, 3, "dropped", "fit_joints")]
    assert "no point could be tracked" in out.fates[0].reason
    for est, truth in zip(out.joints, truths, strict=True):
        from artitwin_core.joints import Joint
        from tasks import to_core

        err = joint_errors(to_core(Joint, est), truth)
        assert err.type_correct, (est.joint_type, truth.joint_type)
        # 1 mm noise, 150 tracks, 20 frames: the unit tests of the estimator see < 0.2 deg here
        assert err.axis_angle_deg < 0.5
        assert "bic_revolute" in out.selection[est.name]
    # The revolute's line carries its standard errors into the artifact (and through the store).
    door, drawer = out.joints
    assert door.joint_type == "revolute" and 0 < door.pivot_se_m < 0.01 and 0 < door.axis_se_rad < np.radians(0.5)
    assert drawer.pivot_se_m is None
    import zarr
    from zarr.storage import MemoryStore

    from schemas import JointSet

    group = zarr.open_group(MemoryStore(), mode="w")
    out.to_zarr(group)
    back = JointSet.from_zarr(group).joints
    assert back[0].pivot_se_m == door.pivot_se_m and back[1].pivot_se_m is None


def test_joint_states_stage_refits_the_held_door_state():
    """joint_0 is refined against the part labelled 1; refine_from_depth=False passes through."""
    from dataclasses import replace

    from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
    from schemas import CaptureArtifact, JointSet, JointStateConfig, MaskSequenceArtifact, Registration
    from tasks import to_artifact
    from tasks.joints import refine_states

    scene = generate_scene(BENCHMARK_SCENES["tiny"])
    truth = scene.truth
    true = truth.joints[0]
    cut = np.radians(55.0)
    held = replace(true, q=np.minimum(true.q, cut), confidence=np.where(true.q < cut, 1.0, 0.0))
    joints = JointSet(joints=[to_artifact(JointParams, held, name="joint_0")], selection={"joint_0": {"bic_revolute": 1.0}})
    inputs = dict(
        joints=joints,
        dynamic=to_artifact(CaptureArtifact, scene.dynamic),
        masks=MaskSequenceArtifact(
            part=truth.part_masks, hand=truth.hand_masks, score=np.ones(len(true.q), np.float32)
        ),
        registration=Registration(
            canonical_from_session=truth.canonical_from_dynamic_session, residual_m=0.0, inlier_fraction=1.0,
            method="ground truth",
        ),
    )
    out = refine_states(**inputs, config=JointStateConfig())
    q = out.joints[0].q
    assert np.degrees(np.abs(held.q - true.q).max()) > 5.0
    assert np.degrees(np.abs(q - true.q).max()) < 1.0, np.degrees(q - true.q).round(2)
    assert out.selection["joint_0"]["state_frames_changed"] >= 2
    assert out.selection["joint_0"]["bic_revolute"] == 1.0
    same = refine_states(**inputs, config=JointStateConfig(refine_from_depth=False))
    np.testing.assert_array_equal(same.joints[0].q, held.q)
    # The registration's covariance joins the joint's standard errors (2 mm per axis here), with
    # or without the depth refit.
    fitted = replace(held, axis_se_rad=0.001, pivot_se_m=0.001)
    inputs["joints"] = JointSet(joints=[to_artifact(JointParams, fitted, name="joint_0")], selection={})
    inputs["registration"] = inputs["registration"].model_copy(update={"covariance": np.diag([0.0] * 3 + [0.002**2] * 3)})
    for cfg in (JointStateConfig(refine_line=False), JointStateConfig(refine_from_depth=False)):
        joint = refine_states(**inputs, config=cfg).joints[0]
        assert np.isclose(joint.pivot_se_m, np.hypot(0.001, 0.002)) and np.isclose(joint.axis_se_rad, 0.001)
    # The effect time_offset moves every state to its frame's RGB time (here without the refit):
    # states read 20 ms late are interpolated back between the frames.
    late_set = refine_states(**inputs, config=JointStateConfig(refine_from_depth=False, rgb_time_offset_s=0.02))
    late = late_set.joints[0]
    ts = scene.dynamic.timestamps
    np.testing.assert_allclose(late.q, np.interp(ts, ts + 0.02, held.q))
    assert np.abs(late.q - held.q).max() > np.radians(0.5)
    # The set says which clock its states are on (the diagnosis moves them back for the tracks).
    assert late_set.rgb_time_offset_s == 0.02 and np.array_equal(late_set.timestamps, ts)
    np.testing.assert_array_equal(late_set.depth_clock_q, np.asarray(held.q)[None])  # the states as measured
    assert same.rgb_time_offset_s == 0.0 and same.timestamps is None and same.depth_clock_q is None


def test_screw_joint_named_for_one_joint_models_that_joint_only():
    """`--effect joint_1:screw_joint` makes joint_1 a screw and leaves joint_0 a revolute; a bare
    `screw_joint` makes every rotating part one (issue 28: the scope used to be ignored)."""
    rng = np.random.default_rng(3)
    trajs = []
    for _ in range(2):
        joint, closed = random_part_joint("revolute", 120, 20, rng)
        trajs.append(simulate_trajectories(joint, closed, rng, noise_m=0.001, outlier_fraction=0.05)[0])
    art = _tracks_of_parts(trajs)
    t = art.valid.shape[0]
    labels = np.zeros((t, 1, 2), np.uint8)
    labels[:, 0, 0], labels[:, 0, 1] = 1, 2
    masks = MaskSequenceArtifact(part=labels, hand=np.zeros(labels.shape, bool), score=np.ones(t, np.float32))
    from schemas import PipelineConfig

    def types(config):
        return [j.joint_type for j in fit_joints(art, masks, config).joints]

    assert types(JointConfig()) == ["revolute", "revolute"]  # no pitch: the significance test says revolute
    one = PipelineConfig().with_effects(["joint_1:screw_joint"]).fit_joints
    assert types(one) == ["revolute", "screw"]
    assert types(PipelineConfig().with_effects(["screw_joint"]).fit_joints) == ["screw", "screw"]
