"""The model-based rigid tracker on the "tiny" scene (the door's query-frame surface aligned to
every frame) and on "large-session-offset"'s drawer, against the part's true motion
(ground-truth masks and registration)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
from artitwin_core.tracking import lift_pixels
from artitwin_core.tracking._flow import to_gray
from artitwin_core.tracking._model_track import (
    RigidParams,
    _align_levels,
    _bilinear,
    _Frame,
    _normals,
    _passes,
    _patches,
    track_rigid,
)


@pytest.fixture(scope="module")
def tiny():
    return generate_scene(BENCHMARK_SCENES["tiny"])


def test_model_follows_the_door_through_fast_frames(tiny):
    d, truth = tiny.dynamic, tiny.truth
    poses = truth.canonical_from_dynamic_session @ d.world_from_camera
    part, hand = truth.part_masks == 1, truth.hand_masks
    q = 0

    def allowed(t):
        m = cv2.dilate(part[t].astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        return m & ~cv2.dilate(hand[t].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)

    ys, xs = np.nonzero(part[q] & ~hand[q])
    pts, ok = lift_pixels(np.stack([xs, ys], -1).astype(float), d.depth[q], d.confidence[q] if d.confidence is not None
                          else None, d.rgb_intrinsics[q], d.depth_intrinsics[q], poses[q])
    res = track_rigid(to_gray(d.rgb, q), d.depth, poses, d.rgb_intrinsics, d.depth_intrinsics, allowed, q, pts[ok],
                      RigidParams())
    motion_true = truth.part_world_from_closed[0]
    x = pts[ok]
    errs = {}
    for t in np.nonzero(res.confident)[0]:
        g = motion_true[t] @ np.linalg.inv(motion_true[q])
        m = res.motions[t]
        errs[int(t)] = np.median(np.linalg.norm((x @ m[:3, :3].T + m[:3, 3]) - (x @ g[:3, :3].T + g[:3, 3]), axis=1))
    q_true = truth.joints[0].q
    # The door swings 0.28-0.31 rad between frames 5, 6 and 7; the chained 2D tracker stops at
    # frame 5. Measured: confident through frame 7 (true q 0.81 rad); frame 8 on shows the door's
    # back, which the front's model cannot align.
    assert max(q_true[t] for t in errs) > 0.75
    assert not res.confident[9:].any()
    # Measured median point error <= 1.1 mm for frames 1-5, 4.5 mm at 6, 12.1 mm at frame 7 (face nearly
    # edge-on, 128x96 pixels).
    assert max(errs[t] for t in errs if q_true[t] < 0.4) < 0.003
    assert max(errs.values()) < 0.02


def _tiny_model(tiny, hidden=()):
    """``(result, model points [M, 3], true world_from_query [T, 4, 4])`` with the part mask
    emptied (a hand over the whole part) in the ``hidden`` frames."""
    d, truth = tiny.dynamic, tiny.truth
    poses = truth.canonical_from_dynamic_session @ d.world_from_camera
    part, hand = truth.part_masks == 1, truth.hand_masks
    q = 0

    def allowed(t):
        if t in hidden:
            return np.zeros(part.shape[1:], bool)
        m = cv2.dilate(part[t].astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        return m & ~cv2.dilate(hand[t].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)

    ys, xs = np.nonzero(part[q] & ~hand[q])
    pts, ok = lift_pixels(np.stack([xs, ys], -1).astype(float), d.depth[q], d.confidence[q] if d.confidence is not None
                          else None, d.rgb_intrinsics[q], d.depth_intrinsics[q], poses[q])
    res = track_rigid(to_gray(d.rgb, q), d.depth, poses, d.rgb_intrinsics, d.depth_intrinsics, allowed, q, pts[ok],
                      RigidParams())
    g = truth.part_world_from_closed[0]
    return res, pts[ok], g @ np.linalg.inv(g[q])


def test_model_reacquires_the_door_after_an_occlusion(tiny):
    # The part is hidden in frame 6 while the door keeps swinging (true q 0.22 -> 0.81 rad over
    # frames 5-7): the tracker must pick the door up again at frame 7 from the motion it predicts
    # along the part's current screw, not lose it or lock onto another pose.
    res, x, true = _tiny_model(tiny, hidden=(6,))
    assert not res.confident[6]
    q_true = tiny.truth.joints[0].q
    assert q_true[7] - q_true[5] > 0.5

    def err(t):
        m, g = res.motions[t], true[t]
        return float(np.median(np.linalg.norm((x @ m[:3, :3].T + m[:3, 3]) - (x @ g[:3, :3].T + g[:3, 3]), axis=1)))

    # Measured: 12 mm at frame 7 (face nearly edge-on at 128x96 pixels), as without the gap.
    assert res.confident[7]
    assert err(7) < 0.02
    # Whatever the model reports with confidence is right (the back face, seen from frame 8 on,
    # fits the front flipped; it must not be taken for it).
    for t in np.nonzero(res.confident)[0]:
        assert err(t) < 0.02, (t, err(t))


def test_model_refuses_a_pose_that_fits_depth_but_not_appearance(tiny):
    # The door turned 180 degrees about an axis normal to it through its points' centre lies in
    # the same plane: aligned from there it fits the depth as well as the truth does (the old
    # depth-only test, >= 50% inliers and RMS < 7.5 mm, accepted it), but its grey levels do not
    # match. A door's back face seen once the door turned past the camera is the same trap
    # (non-ideal-joints: tracks came back 111 degrees off after the door's front went out of view).
    d, truth = tiny.dynamic, tiny.truth
    poses = truth.canonical_from_dynamic_session @ d.world_from_camera
    part, hand = truth.part_masks == 1, truth.hand_masks
    q = 0
    ys, xs = np.nonzero(part[q] & ~hand[q])
    pts, ok = lift_pixels(np.stack([xs, ys], -1).astype(float), d.depth[q], None, d.rgb_intrinsics[q],
                          d.depth_intrinsics[q], poses[q])
    x = pts[ok]
    centre = x.mean(0)
    normal = np.linalg.svd(x - centre)[2][2]
    flip = np.eye(4)
    flip[:3, :3] = 2.0 * np.outer(normal, normal) - np.eye(3)
    flip[:3, 3] = centre - flip[:3, :3] @ centre
    g = truth.part_world_from_closed[0]
    true = g @ np.linalg.inv(g[q])
    params = RigidParams()
    gray = to_gray(d.rgb, q)
    nq = _normals(x)
    nq[np.sum(nq * (poses[q][:3, 3] - x), 1) < 0] *= -1

    def frame(t):
        m = cv2.dilate(part[t].astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        m &= ~cv2.dilate(hand[t].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        return _Frame(gray[t], d.depth[t], m, poses[t], d.rgb_intrinsics[t], d.depth_intrinsics[t], params.blur_sigmas)

    fq = frame(q)
    pc = x @ fq.cam_from_world[:3, :3].T + fq.cam_from_world[:3, 3]
    fx, fy, cx, cy = d.rgb_intrinsics[q]
    u, v = fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy
    grey = [np.nan_to_num(_bilinear(img, u, v)) for img, _, _ in fq.levels]
    patches = _patches(u, v, params.patch_px)
    for t in (1, 3, 5):
        right = _align_levels(frame(t), true[t], x, nq, grey, params, patches)
        wrong = _align_levels(frame(t), true[t] @ flip, x, nq, grey, params, patches)
        moved = x @ wrong[0][:3, :3].T + wrong[0][:3, 3]
        assert np.median(np.linalg.norm(moved - (x @ true[t][:3, :3].T + true[t][:3, 3]), axis=1)) > 0.1
        # Measured: the flip keeps 92-96% depth inliers at 2.9-3.4 mm RMS, grey correlation (patch
        # by patch) <= 0.06; the truth correlates at 0.99.
        assert wrong[2] >= params.min_inlier_fraction and wrong[3] < params.inlier_m / 2
        assert wrong[4] < 0.2 and not _passes(wrong, params)
        assert right[4] > 0.9 and _passes(right, params)


@pytest.fixture(scope="module")
def door_over_drawer():
    # The benchmark scene's dynamic recording, without rendering its static sweep (the dynamic
    # recording does not depend on it).
    return generate_scene(dataclasses.replace(BENCHMARK_SCENES["large-session-offset"], static_frames=2))


def test_model_keeps_the_drawer_while_the_door_swings_across_it(door_over_drawer):
    # The door above the drawer opens first: in frames 9-12 it swings in front of the drawer (frame
    # 10 shows only a strip of the drawer's front, half its model), then its shadow lies across
    # half the drawer's front while the drawer slides out (frames 26-35). The pipeline's tracks
    # of the drawer came out 120-150 mm low from frame 10 on (axis 27 deg off): the coarse
    # levels' blur mixed the swinging door into the strip and slid the model down the front's
    # vertical grain, and under the shadow the whole front's grey levels no longer correlated
    # with the model's (one exposure for the whole part), so no frame of the slide was trusted
    # again.
    d, truth = door_over_drawer.dynamic, door_over_drawer.truth
    poses = truth.canonical_from_dynamic_session @ d.world_from_camera
    part, hand = truth.part_masks == 2, truth.hand_masks
    q = 3  # the pipeline's query frame: the drawer closed, the door not yet open

    def allowed(t):
        m = cv2.dilate(part[t].astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        return m & ~cv2.dilate(hand[t].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)

    def occluders(t):  # the hand and the door
        return (truth.part_masks[t] == 1) | hand[t]

    ys, xs = np.nonzero(part[q] & ~hand[q])
    pts, ok = lift_pixels(np.stack([xs, ys], -1).astype(float), d.depth[q], d.confidence[q], d.rgb_intrinsics[q],
                          d.depth_intrinsics[q], poses[q])
    x = pts[ok]
    res = track_rigid(to_gray(d.rgb, q), d.depth, poses, d.rgb_intrinsics, d.depth_intrinsics, allowed, q, x,
                      RigidParams(), occluders=occluders)
    g = truth.part_world_from_closed[1]
    true = g @ np.linalg.inv(g[q])
    q_true = truth.joints[1].q
    assert q_true.max() > 0.2 and np.all(q_true[:20] == 0)
    # Before: not trusted from frame 14 on. Measured: every frame of the slide trusted.
    assert res.confident[q_true > 0].all()
    errs = np.array([
        np.median(np.linalg.norm((x @ res.motions[t][:3, :3].T + res.motions[t][:3, 3])
                                 - (x @ true[t][:3, :3].T + true[t][:3, 3]), axis=1))
        for t in np.nonzero(res.confident)[0]
    ])
    # Before: 98 mm at frame 11 (trusted), 149 mm at frame 10. Measured: median point error 7 mm
    # at frame 10, 42 mm at frame 14 (the door's shadow edge first crosses the drawer: one
    # exposure for the whole part does not fit it), 0.6-27 mm elsewhere, median 5.5 mm.
    assert errs.max() < 0.05
    assert np.median(errs) < 0.008
