"""The fit_joints stage: one joint per part, from one trajectories artifact."""

from __future__ import annotations

import numpy as np

from artitwin_core.joints import joint_errors, random_part_joint, simulate_trajectories
from schemas import TrajectoriesArtifact
from tasks.joints import JointConfig, fit_joints


def test_two_parts_get_their_own_joints():
    rng = np.random.default_rng(7)
    truths, trajs = [], []
    for kind in ("revolute", "prismatic"):
        joint, closed = random_part_joint(kind, 150, 20, rng)
        traj, _ = simulate_trajectories(joint, closed, rng, noise_m=0.001, outlier_fraction=0.1)
        truths.append(joint)
        trajs.append(traj)
    art = TrajectoriesArtifact(
        points_in_world=np.concatenate([t.points_in_world for t in trajs], axis=1),
        pixels=np.concatenate([t.pixels for t in trajs], axis=1).astype(np.float32),
        valid=np.concatenate([t.valid for t in trajs], axis=1),
        part_ids=np.repeat(np.arange(2, dtype=np.int32), [t.valid.shape[1] for t in trajs]),
    )
    out = fit_joints(art, JointConfig())
    assert [j.name for j in out.joints] == ["joint_0", "joint_1"]
    for est, truth in zip(out.joints, truths, strict=True):
        from artitwin_core.joints import Joint
        from tasks import to_core

        err = joint_errors(to_core(Joint, est), truth)
        assert err.type_correct, (est.joint_type, truth.joint_type)
        # 1 mm noise, 150 tracks, 20 frames: the unit tests of the estimator see < 0.2 deg here
        assert err.axis_angle_deg < 0.5
        assert "bic_revolute" in out.selection[est.name]
