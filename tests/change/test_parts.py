"""Part and hand masks on a synthetic door scene against its exact labels.

Measured on this scene (192x144 RGB, 96x72 depth, default noise, a hand opens the door, true
registration): median part IoU 0.923 (0.89-0.93 per frame), hand pixels labelled part 0.9 %,
true hand pixels labelled hand 85 %, joint angle at the last frame 1.184 rad (truth 1.2), closed
frames within 0.013 rad of closed. (Before pixels without depth were filled from look-alike
neighbours: 0.917, 3.3 %, 63 %; before the surfel splats, the drawer changes and the part's own
ICP: 0.88, 5.8 %, 1.196 rad, 0.03 rad.)
The issue 5 targets (IoU >= 0.85, hand-as-part <= 5 %) are for the benchmark scenes at
256x192; this lower resolution meets them too.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from artitwin_core import InputError
from artitwin_core.change import build_canonical_tsdf, propagate_masks_sam2, segment_parts
from artitwin_core.change._motion import _icp_point_to_plane
from artitwin_core.geometry import axis_angle_to_matrix, make_se3
from artitwin_core.masks import MaskSequence
from artitwin_core.synth import SceneSpec, generate_scene

SPEC = SceneSpec(
    furniture="door", static_frames=14, dynamic_frames=12, static_stride=8, dynamic_stride=5,
    rgb_size=(192, 144), depth_size=(96, 72), seed=21,
)


@pytest.fixture(scope="module")
def door():
    scene = generate_scene(SPEC)
    mesh = build_canonical_tsdf(scene.static)
    seg = segment_parts(scene.dynamic, scene.truth.canonical_from_dynamic_session, mesh)
    return scene, seg


def test_masks_have_the_mask_sequence_contract(door):
    scene, seg = door
    t, h, w = scene.truth.part_masks.shape
    assert isinstance(seg.masks, MaskSequence)
    assert seg.masks.part.shape == (t, h, w) and seg.masks.part.dtype == np.uint8
    assert seg.masks.hand.shape == (t, h, w) and seg.masks.hand.dtype == bool
    assert seg.masks.score.shape == (t,) and np.all((seg.masks.score >= 0) & (seg.masks.score <= 1))


def test_part_iou_and_hand_separation(door):
    scene, seg = door
    gt, pred = scene.truth.part_masks, seg.masks.part
    ious = [
        np.sum((gt[t] == 1) & (pred[t] == 1)) / np.sum((gt[t] == 1) | (pred[t] == 1))
        for t in range(len(gt))
        if np.sum(gt[t] == 1) > 30
    ]
    assert len(ious) >= 10
    assert np.median(ious) >= 0.85  # measured 0.923
    assert min(ious) >= 0.75  # measured 0.887
    hand = scene.truth.hand_masks
    assert np.sum(hand & (pred > 0)) / np.sum(hand) <= 0.05  # measured 0.009 (0.033 before the fill)
    # The hand is found, too: most true hand pixels are labelled hand.
    assert np.sum(hand & seg.masks.hand) / np.sum(hand) >= 0.75  # measured 0.85 (0.63 before the fill)


def test_joint_and_states_follow_the_door(door):
    scene, seg = door
    assert len(seg.models) == 1
    model = seg.models[0]
    truth = scene.truth.joints[0]
    assert model.joint_type == "revolute"
    assert abs(abs(model.axis @ truth.axis) - 1.0) < 0.01  # axis within ~8 degrees
    q_true = truth.q
    q = seg.states[:, 0] * np.sign(model.axis @ truth.axis)
    assert abs(q[-1] - q_true[-1]) < 0.05  # radians; measured 0.016
    closed = q_true == 0
    assert closed.sum() >= 3 and np.all(np.abs(q[closed]) < 0.06)  # measured <= 0.013


def test_part_icp_recovers_a_rigid_motion_and_repeats_exactly():
    # segment_parts must give the same masks for the same input (tracking reacts to a changed
    # pixel). Open3D's ICP summed its normal equations in a varying order: 29 distinct transforms
    # in 30 runs on one dynamic frame of the door+drawer benchmark. The part ICP sums in order.
    rng = np.random.default_rng(0)
    # Three faces of a box corner, so no sliding direction is free.
    u, v = rng.random((2, 1500)) * 0.4
    face = np.repeat(np.arange(3), 500)
    zero = np.zeros(1500)
    pts = np.where(face[:, None] == 0, np.stack([u, v, zero], 1),
                   np.where(face[:, None] == 1, np.stack([zero, u, v], 1), np.stack([u, zero, v], 1)))
    normals = np.eye(3)[[2, 0, 1]][face]
    truth = make_se3(axis_angle_to_matrix(np.array([0.3, 1.0, 0.2]), 0.05), np.array([0.02, -0.015, 0.01]))
    src = (pts - truth[:3, 3]) @ truth[:3, :3]  # truth maps src onto pts
    tree = cKDTree(pts)
    first = _icp_point_to_plane(src, pts, normals, tree, np.eye(4), 0.08)
    assert np.allclose(first, truth, atol=1e-6)  # the same samples moved: exact (measured 2e-16)
    assert np.array_equal(_icp_point_to_plane(src, pts, normals, tree, np.eye(4), 0.08), first)


def test_sam2_backend_without_checkpoint_is_a_clear_input_error(tmp_path):
    rgb = np.zeros((3, 8, 8, 3), np.uint8)
    mask = np.zeros((8, 8), np.uint8)
    with pytest.raises(InputError, match="checkpoint .* does not exist"):
        propagate_masks_sam2(rgb, mask, tmp_path / "missing.pt")


def test_sam2_backend_without_package_is_a_clear_input_error(tmp_path, monkeypatch):
    ckpt = tmp_path / "sam2.pt"
    ckpt.write_bytes(b"not really weights")
    import sys

    monkeypatch.setitem(sys.modules, "sam2", None)  # makes "import sam2..." raise ImportError
    monkeypatch.setitem(sys.modules, "sam2.build_sam", None)
    with pytest.raises(InputError, match="'sam2' package does not import"):
        propagate_masks_sam2(np.zeros((3, 8, 8, 3), np.uint8), np.zeros((8, 8), np.uint8), ckpt)
    with pytest.raises(InputError, match="rgb must be"):
        propagate_masks_sam2(np.zeros((3, 8, 8), np.uint8), np.zeros((8, 8), np.uint8), ckpt)


@pytest.mark.slow
def test_door_seen_edge_on_at_the_end_is_fitted_where_it_is_seen():
    """"strong-hand-occlusion" drawn at seed 105: the door swings past the camera's line of
    sight, so the last frames show only its edge. Fitted there (the last frame and the two most
    open ones) no hinge explained anything and a flap about a horizontal axis "won" at 107 deg
    with 17 supporting samples; from frame 12 on the door went to the hand (up to 9,400 pixels
    a frame) and then out of the labels, so its tracks stopped at 17 deg. Frames where the door
    is a quarter to three quarters open now compete as well; the vertical hinge wins and the
    reference is the most open frame that agrees (frame 21, 59 deg), from which the door is
    tracked forwards past its reference state. True registration."""
    from dataclasses import replace

    from artitwin_core.synth import BENCHMARK_SCENES

    scene = generate_scene(replace(BENCHMARK_SCENES["strong-hand-occlusion"], seed=105))
    truth = scene.truth
    mesh = build_canonical_tsdf(scene.static)
    seg = segment_parts(scene.dynamic, truth.canonical_from_dynamic_session, mesh)
    assert len(seg.models) == 1
    model, joint_true = seg.models[0], truth.joints[0]
    assert model.joint_type == "revolute"
    assert abs(float(model.axis @ joint_true.axis)) > np.cos(np.radians(3.0))  # measured 0.0 deg off (the flap: 90)
    q_err = np.degrees(np.abs(np.abs(seg.states[:, 0]) - joint_true.q))
    # Tracked forwards past the reference too: the door goes on to 68.8 deg.
    assert q_err.max() < 3.0, q_err.round(1)  # measured 2.4 (the last frames held at 64.9: 3.9)
    part = seg.masks.part == 1
    true_part = truth.part_masks == 1
    iou = (part & true_part).sum((1, 2)) / np.maximum((part | true_part).sum((1, 2)), 1)
    seen = np.arange(23)  # the door is seen until it turns edge-on
    assert np.median(iou[seen]) > 0.85, iou.round(2)  # measured 0.91
    assert iou[23:].min() > 0.4, iou.round(2)  # the edge-on sliver: measured 0.59-0.70 (held: 0.12-0.38)
    # The door is not handed to the hand once it opens.
    hand_on_door = (seg.masks.hand & true_part).sum((1, 2)) / np.maximum(true_part.sum((1, 2)), 1)
    assert hand_on_door[seen].max() < 0.1, hand_on_door.round(2)  # measured 0.011
