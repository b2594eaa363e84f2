"""refine_joint_states on the ``tiny`` synthetic scene: the door's state past the tracker's reach.

The tracker loses a door once its front face turns away (about 55 deg of 68.75 here) and
``estimate_joint`` holds ``q`` from there. These tests give the refinement the true axis and
pivot with ``q`` cut at 55 deg (confidence 0 beyond, as the fitted joint reports it) and check
the state it recovers from depth. Measured on ``tiny`` (true masks and registration): worst frame
error 0.54 deg (the held input was off by up to 7.9 deg); the bound is 1 deg. They test the
per-frame pass with the line held (``refine_axis=False``); fitting the line itself is
``test_line_from_planes.py``.
"""

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.joints import StateRefineConfig, refine_joint_states
from artitwin_core.masks import MaskSequence
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene

CUT_RAD = np.radians(55.0)
HELD_LINE = StateRefineConfig(refine_axis=False)


@pytest.fixture(scope="module")
def tiny():
    scene = generate_scene(BENCHMARK_SCENES["tiny"])
    truth = scene.truth
    masks = MaskSequence(
        part=truth.part_masks,
        hand=truth.hand_masks,
        score=np.ones(scene.dynamic.num_frames, np.float32),
    )
    return scene, masks


def _held_joint(joint_true):
    """The true joint with ``q`` held at the cut, as the tracker leaves it."""
    tracked = joint_true.q < CUT_RAD
    q = np.where(tracked, joint_true.q, CUT_RAD)
    return replace(
        joint_true,
        q=q,
        q_range=np.array([0.0, q.max()]),
        residual=np.where(tracked, 1e-3, np.nan),
        confidence=np.where(tracked, 1.0, 0.0),
    )


def test_state_past_the_tracked_angle_is_recovered(tiny):
    scene, masks = tiny
    truth = scene.truth
    joint_true = truth.joints[0]
    held = _held_joint(joint_true)
    assert np.degrees(np.abs(held.q - joint_true.q).max()) > 5.0  # the input really is wrong
    out = refine_joint_states(held, scene.dynamic, masks, 1, truth.canonical_from_dynamic_session, HELD_LINE)

    in_view = (truth.part_masks == 1).reshape(len(joint_true.q), -1).sum(1) > 0
    err = np.degrees(np.abs(out.q - joint_true.q))
    assert in_view.sum() == len(joint_true.q)
    assert err[in_view].max() < 1.0, err.round(2)
    assert abs(np.degrees(out.q_range[1] - joint_true.q.max())) < 1.0
    # Frames past the cut were measured from depth, and say so.
    past = joint_true.q >= CUT_RAD
    measured = past & (out.confidence > 0.5)
    assert measured.sum() >= 2
    assert np.all(np.isfinite(out.residual[measured]))
    # Axis, pivot and type are held fixed.
    assert out.joint_type == held.joint_type
    np.testing.assert_array_equal(out.axis, held.axis)
    np.testing.assert_array_equal(out.pivot, held.pivot)


def test_confident_frames_that_agree_are_kept(tiny):
    scene, masks = tiny
    truth = scene.truth
    held = _held_joint(truth.joints[0])
    out = refine_joint_states(held, scene.dynamic, masks, 1, truth.canonical_from_dynamic_session, HELD_LINE)
    tracked = held.confidence > 0
    np.testing.assert_array_equal(out.q[tracked], held.q[tracked])


def test_confident_frame_without_mask_depth_keeps_its_state(tiny):
    scene, masks = tiny
    truth = scene.truth
    held = _held_joint(truth.joints[0])
    part = masks.part.copy()
    part[5] = 0
    blank = MaskSequence(part=part, hand=masks.hand, score=masks.score)
    # Shift frame 5's state: with no depth to check it against, the refinement must keep it.
    q = held.q.copy()
    q[5] += 0.02
    held = replace(held, q=q)
    out = refine_joint_states(held, scene.dynamic, blank, 1, truth.canonical_from_dynamic_session, HELD_LINE)
    assert out.q[5] == q[5]


def test_wrong_confident_state_is_not_kept_when_depth_disagrees(tiny):
    scene, masks = tiny
    truth = scene.truth
    held = _held_joint(truth.joints[0])
    q = held.q.copy()
    q[6] += np.radians(6.0)  # a confident but wrong frame
    conf = held.confidence.copy()
    conf[6] = 0.4
    held = replace(held, q=q, confidence=conf)
    out = refine_joint_states(held, scene.dynamic, masks, 1, truth.canonical_from_dynamic_session, HELD_LINE)
    assert abs(np.degrees(out.q[6] - truth.joints[0].q[6])) < 1.0


def test_prismatic_joint_is_returned_unchanged_without_a_lever(tiny):
    scene, masks = tiny
    truth = scene.truth
    drawer = replace(_held_joint(truth.joints[0]), joint_type="prismatic")
    out = refine_joint_states(drawer, scene.dynamic, masks, 1, truth.canonical_from_dynamic_session,
                              replace(HELD_LINE, prismatic_lever_m=None))
    assert out is drawer


def test_drawer_state_past_the_tracks_is_recovered():
    """The tiny scene with a drawer: the tracks' state held at 60 % of the opening from there on
    (confidence 0, as the fit reports lost tracks) is measured from the front's depth. Measured:
    worst frame 0.3 mm, where the held state was more than 5 cm short."""
    scene = generate_scene(replace(BENCHMARK_SCENES["tiny"], furniture="drawer"))
    truth = scene.truth
    masks = MaskSequence(part=truth.part_masks, hand=truth.hand_masks, score=np.ones(scene.dynamic.num_frames, np.float32))
    true = truth.joints[0]
    cut = 0.6 * true.q.max()
    tracked = true.q < cut
    held = replace(true, q=np.where(tracked, true.q, cut), residual=np.where(tracked, 1e-3, np.nan),
                   confidence=np.where(tracked, 1.0, 0.0))
    assert np.abs(held.q - true.q).max() > 0.05  # the input really is wrong
    out = refine_joint_states(held, scene.dynamic, masks, 1, truth.canonical_from_dynamic_session, HELD_LINE)
    in_view = (truth.part_masks == 1).reshape(len(true.q), -1).sum(1) > 0
    err = np.abs(out.q - true.q)
    assert err[in_view].max() < 0.003, err.round(4)
    np.testing.assert_array_equal(out.axis, held.axis)


def test_a_drawer_slides_along_its_fronts_normal():
    """Tracks that a hand crosses drift sideways with it (generalization seeds 26 and 27: a slide
    14.5 and 18.5 deg off, standard errors 2-4 deg). The drawer's front shows a plane in every
    frame, and a drawer slides along its normal: a slide 15 deg off becomes that normal (within
    0.5 deg of the true axis), its states refitted along it; the true axis is left alone."""
    from artitwin_core.geometry import axis_angle_to_matrix

    scene = generate_scene(replace(BENCHMARK_SCENES["tiny"], furniture="drawer"))
    truth = scene.truth
    masks = MaskSequence(part=truth.part_masks, hand=truth.hand_masks, score=np.ones(scene.dynamic.num_frames, np.float32))
    true = truth.joints[0]
    tilted = replace(true, axis=axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), np.radians(15.0)) @ true.axis,
                     axis_se_rad=float(np.radians(3.0)))
    out = refine_joint_states(tilted, scene.dynamic, masks, 1, truth.canonical_from_dynamic_session)
    assert np.degrees(np.arccos(min(1.0, float(out.axis @ true.axis)))) < 0.5, out.axis
    in_view = (truth.part_masks == 1).reshape(len(true.q), -1).sum(1) > 0
    assert np.abs(out.q - true.q)[in_view].max() < 0.005
    kept = refine_joint_states(replace(true, axis_se_rad=1e-4), scene.dynamic, masks, 1, truth.canonical_from_dynamic_session)
    np.testing.assert_array_equal(kept.axis, true.axis)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ("mask_shape", "masks.part"),
        ("hand_shape", "masks.hand"),
        ("label", "part_label"),
        ("q_length", "joint.q"),
        ("registration", "canonical_from_session"),
    ],
)
def test_bad_input_names_the_field(tiny, change, field):
    scene, masks = tiny
    truth = scene.truth
    joint = _held_joint(truth.joints[0])
    label = 1
    c_from_s = truth.canonical_from_dynamic_session
    if change == "mask_shape":
        masks = MaskSequence(part=masks.part[:, ::2], hand=masks.hand, score=masks.score)
    elif change == "hand_shape":
        masks = MaskSequence(part=masks.part, hand=masks.hand[:-1], score=masks.score)
    elif change == "label":
        label = 7
    elif change == "q_length":
        joint = replace(joint, q=joint.q[:-1])
    else:
        c_from_s = np.eye(3)
    with pytest.raises(InputError, match=field):
        refine_joint_states(joint, scene.dynamic, masks, label, c_from_s, StateRefineConfig())


def test_door_seen_edge_on_to_the_end_is_not_held_short():
    """The pipeline's own masks and tracks (300 of them) of "door" drawn at seed 202, saved from
    bench_pipeline_joints: the door opens to 68.8 deg and its last 9 frames (60-69 deg) show it
    edge-on, a sliver of 900-1900 mask pixels that the mask erosion emptied. Every frame there
    was held at the last measured 55 deg (range 13 deg short, state RMSE 6.6 deg). Lifted
    uneroded, the sliver gives fits past the last anchor, the only measurement of those frames
    (StateRefineConfig.tail_max_se_rad): with these 300 tracks, worst frame 2.8 deg off,
    range +2.1 deg, state RMSE 1.2 deg. The sliver's fits are biased by a degree or two (their
    standard errors say 0.2 deg), which bounds what is claimed here."""
    from pathlib import Path

    from artitwin_core.joints import JointFitConfig, estimate_joint
    from artitwin_core.tracking import Trajectories

    data = np.load(Path(__file__).parent / "data" / "door_seed202_edge_on.npz")
    scene = generate_scene(replace(BENCHMARK_SCENES["door"], seed=202))
    joint_true = scene.truth.joints[0]
    shape = scene.dynamic.rgb.shape[:3]
    masks = MaskSequence(
        part=np.unpackbits(data["part"], axis=-1, count=shape[2]).astype(np.uint8),
        hand=np.unpackbits(data["hand"], axis=-1, count=shape[2]).astype(bool),
        score=data["score"],
    )
    pts = data["points_in_world"].astype(np.float64)
    traj = Trajectories(pts, np.zeros(pts.shape[:2] + (2,), np.float32), data["valid"], 0)
    fit = estimate_joint(traj, JointFitConfig(), reference_frame=0)
    edge_on = np.arange(21, 30)
    # The tracks end before the door turns edge-on: they cannot reach the last frames' state.
    assert not data["valid"][edge_on].any()
    out = refine_joint_states(fit.joint, scene.dynamic, masks, 1, data["canonical_from_session"])
    err = np.degrees(np.abs(out.q - joint_true.q))
    assert abs(np.degrees(out.q_range[1] - joint_true.q.max())) < 3.0, np.degrees(out.q_range)  # measured +2.1 (-13.5 held)
    assert err[edge_on].max() < 4.0, err.round(1)  # measured 2.8 (13.5 held)
    assert np.sqrt(np.mean(err**2)) < 1.5  # measured 1.16 (6.6 held)
