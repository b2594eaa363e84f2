"""Part masks of an opened drawer against its exact labels: the drawer's box and what stands in
it are part, not only its front.

Measured on this scene (192x144 RGB, 96x72 depth, 12 frames, default noise, a hand pulls the
drawer out 25 cm, true registration): median IoU 0.940, IoU over the frames with the drawer
more than 60 % open >= 0.927, true part pixels missed 5.1 %, hand pixels labelled part 0.2 %
(0.926, 0.922, 4.0 % and 3.6 % before pixels without depth were filled from look-alike
neighbours). Before the drawer's inside was joined to the part (growth inside
the front's outline and over frames, median front normal, surfel splats) the same scene
measured median 0.844 and 0.747-0.781 over the last four frames. At this resolution the
reference frame alone shows little of the inside; the drawer also grows over six other frames
(``grow_frames``, default 6 since its growth stays inside the front's outline; without it the
same scene measured median 0.864, 0.76-0.83 on the open frames).
"""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core.change import build_canonical_tsdf, segment_parts
from artitwin_core.synth import SceneSpec, generate_scene

SPEC = SceneSpec(
    furniture="drawer", static_frames=14, dynamic_frames=12, static_stride=8, dynamic_stride=5,
    rgb_size=(192, 144), depth_size=(96, 72), seed=2,
)


@pytest.fixture(scope="module")
def drawer():
    scene = generate_scene(SPEC)
    mesh = build_canonical_tsdf(scene.static)
    seg = segment_parts(scene.dynamic, scene.truth.canonical_from_dynamic_session, mesh)
    return scene, seg


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sum(a & b) / max(np.sum(a | b), 1))


def test_open_drawer_box_and_contents_are_part(drawer):
    scene, seg = drawer
    gt, pred = scene.truth.part_masks, seg.masks.part
    assert [m.joint_type for m in seg.models] == ["prismatic"]
    visible = [t for t in range(len(gt)) if np.sum(gt[t] == 1) > 50]
    assert len(visible) >= 10
    ious = np.array([_iou(gt[t] == 1, pred[t] == 1) for t in visible])
    assert np.median(ious) >= 0.88  # measured 0.940 (0.844 before the drawer's inside)
    # Open frames show the box, its sides and the objects in it; a front-only mask misses them.
    q = scene.truth.joints[0].q
    open_frames = [i for i, t in enumerate(visible) if q[t] > 0.6 * q.max()]
    assert len(open_frames) >= 3
    assert ious[open_frames].min() >= 0.85  # measured 0.927 (0.747 before the drawer's inside)
    missed = np.sum((gt == 1) & (pred != 1)) / np.sum(gt == 1)
    assert missed <= 0.10  # measured 0.051


def test_hand_pulling_the_drawer_is_not_part(drawer):
    scene, seg = drawer
    hand = scene.truth.hand_masks
    assert hand.sum() > 500
    assert np.sum(hand & (seg.masks.part > 0)) / np.sum(hand) <= 0.05  # measured 0.002 (0.036 before the fill)
