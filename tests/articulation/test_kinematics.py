"""world_from_part reproduces the synthetic truth; moved Gaussians keep their shape relative to the part."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from artitwin_core.articulation import articulate_tensors, part_motions, world_from_part
from artitwin_core.gaussians import LABEL_BACKGROUND, LABEL_INTERIOR, LABEL_PART
from artitwin_core.joints import Joint
from artitwin_core.synth import SceneSpec, generate_scene


def _joint(kind: str, axis, pivot, pitch: float = 0.0) -> Joint:
    a = np.asarray(axis, np.float64)
    return Joint(kind, a / np.linalg.norm(a), np.asarray(pivot, np.float64), np.zeros(1), np.zeros(2),
                 np.zeros(1), np.ones(1), pitch)  # fmt: skip


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def test_world_from_part_matches_the_true_door_motion(tiny_scene):
    truth = tiny_scene.truth
    joint = truth.joints[0]
    assert joint.joint_type == "revolute"
    motions = world_from_part(joint, joint.q)
    assert motions.shape == (len(joint.q), 4, 4)
    np.testing.assert_allclose(motions, truth.part_world_from_closed[0], atol=1e-9, rtol=0)


def test_world_from_part_matches_the_true_drawer_motion():
    spec = SceneSpec(
        furniture="drawer", static_frames=4, dynamic_frames=6, rgb_size=(32, 24), depth_size=(16, 12), seed=2
    )
    truth = generate_scene(spec).truth
    joint = truth.joints[0]
    assert joint.joint_type == "prismatic" and np.ptp(joint.q) > 0.1
    for t, q in enumerate(joint.q):
        np.testing.assert_allclose(
            world_from_part(joint, q), truth.part_world_from_closed[0, t], atol=1e-9, rtol=0
        )


@pytest.mark.parametrize("kind,pitch", [("revolute", 0.0), ("prismatic", 0.0), ("screw", 0.05)])
def test_motion_is_a_one_parameter_group_that_fixes_the_axis(kind, pitch):
    rng = np.random.default_rng(3)
    j = _joint(kind, rng.normal(size=3), rng.normal(size=3), pitch)
    a, b = 0.3, -0.7
    np.testing.assert_allclose(
        world_from_part(j, a) @ world_from_part(j, b), world_from_part(j, a + b), atol=1e-12
    )
    np.testing.assert_allclose(world_from_part(j, 0.0), np.eye(4), atol=1e-15)
    moved_pivot = world_from_part(j, a) @ np.append(j.pivot, 1.0)
    along = {"revolute": 0.0, "prismatic": a, "screw": pitch * a}[kind]
    np.testing.assert_allclose(moved_pivot[:3], j.pivot + along * j.axis, atol=1e-12)


def test_articulate_tensors_moves_only_parts_and_rotates_their_frames():
    rng = np.random.default_rng(0)
    joints = [_joint("revolute", [0, 1, 0], [0.2, 0, 0]), _joint("prismatic", [0, 0, 1], [0, 0, 0])]
    n = 40
    means = torch.tensor(rng.normal(size=(n, 3)), requires_grad=True)
    quats = torch.tensor(rng.normal(size=(n, 4)), requires_grad=True)
    labels = torch.tensor(rng.integers(0, LABEL_PART + 2, n), dtype=torch.int32)
    motions = part_motions(joints, [0.8, 0.1])
    m2, q2 = articulate_tensors(means, quats, labels, motions)
    for i in range(n):
        lab = int(labels[i])
        motion = np.eye(4) if lab in (LABEL_BACKGROUND, LABEL_INTERIOR) else motions[lab - LABEL_PART]
        x = means[i].detach().numpy()
        np.testing.assert_allclose(m2[i].detach().numpy(), motion[:3, :3] @ x + motion[:3, 3], atol=1e-12)
        # The Gaussian's rotation composes with the part's: R(q') = R_part R(q).
        r0, r1 = _quat_to_matrix(quats[i].detach().numpy()), _quat_to_matrix(q2[i].detach().numpy())
        np.testing.assert_allclose(r1, motion[:3, :3] @ r0, atol=1e-12)
    # Gradients reach the canonical parameters through the motion.
    (m2.sum() + q2.sum()).backward()
    part = (labels >= LABEL_PART).numpy()
    assert means.grad is not None and torch.all(means.grad[~part] == 1.0)
    assert not torch.allclose(means.grad[part], torch.ones_like(means.grad[part]))
