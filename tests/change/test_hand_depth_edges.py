"""Pixels without depth are labelled by what they look like, not by the part model alone.

A depth sensor drops the pixels on both sides of every depth edge (the synthetic sensor does, as
ARKit does), so the outline of a hand in front of a door, and a thin arm all across, have no
depth. Taken as "no evidence against the model", such pixels were labelled part wherever the door
model is drawn. On the tiny benchmark scene (128x96 RGB, 64x48 depth, true registration) hand
pixels labelled part measured 10.2 % before (three quarters of them without depth), 0.7 % with
the colour-guided fill; true hand pixels labelled hand 51 % -> 88 %; door IoU median 0.879 ->
0.886. The issue 5 target is hand-as-part <= 5 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core.change import build_canonical_tsdf, fill_depth_by_colour, segment_parts
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene

WOOD, SKIN, BLUE = (150, 100, 50), (230, 180, 160), (40, 40, 200)


def _drop_edges(depth: np.ndarray, jump_m: float = 0.1) -> np.ndarray:
    """Both sides of every depth jump invalid, as the sensor leaves them."""
    out = depth.copy()
    edge = np.zeros(depth.shape, bool)
    dy = np.abs(np.diff(depth, axis=0)) > jump_m
    dx = np.abs(np.diff(depth, axis=1)) > jump_m
    edge[1:] |= dy
    edge[:-1] |= dy
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    out[edge] = np.nan
    return out


def test_invalid_pixels_take_the_depth_of_the_side_they_look_like():
    # A hand (skin, 1.0 m) in front of a door (wood, 1.5 m); RGB at twice the depth resolution.
    depth = np.full((12, 16), 1.5)
    depth[3:9, 4:10] = 1.0
    rgb = np.empty((24, 32, 3), np.uint8)
    rgb[:] = WOOD
    rgb[6:18, 8:20] = SKIN
    filled = fill_depth_by_colour(_drop_edges(depth), rgb, radius_px=2, sigma_colour=20.0)
    skin = np.all(rgb == SKIN, axis=-1)
    assert np.all(np.isfinite(filled))
    assert np.allclose(filled[skin], 1.0) and np.allclose(filled[~skin], 1.5)
    # Labelled by the part model alone, the hand's outline (20 of its 36 depth pixels here) would
    # have been the door.
    assert np.isnan(_drop_edges(depth)[3:9, 4:10]).sum() == 20


def test_where_no_measured_neighbour_looks_alike_the_model_decides():
    # A door seen edge-on: one depth pixel wide, invalid across its width, in front of the wall.
    depth = np.full((12, 16), 1.5)
    depth[:, 7] = 1.2
    rgb = np.empty((24, 32, 3), np.uint8)
    rgb[:] = WOOD
    rgb[:, 14:16] = BLUE
    invalid = _drop_edges(depth)
    assert np.isnan(invalid[:, 7]).all()
    predicted = np.full((24, 32), 1.5)
    predicted[:, 14:16] = 1.2
    strip = np.all(rgb == BLUE, axis=-1)
    # Without the model the strip takes the wall's depth behind it; with it, the model's.
    assert np.allclose(fill_depth_by_colour(invalid, rgb, 2, 20.0)[strip], 1.5)
    filled = fill_depth_by_colour(invalid, rgb, 2, 20.0, predicted, 0.135)
    assert np.allclose(filled[strip], 1.2) and np.allclose(filled[~strip], 1.5)


@pytest.fixture(scope="module")
def tiny():
    scene = generate_scene(BENCHMARK_SCENES["tiny"])
    mesh = build_canonical_tsdf(scene.static)
    seg = segment_parts(scene.dynamic, scene.truth.canonical_from_dynamic_session, mesh)
    return scene, seg


def test_hand_on_the_tiny_scene_is_hand_not_part(tiny):
    scene, seg = tiny
    hand, gt, pred = scene.truth.hand_masks, scene.truth.part_masks, seg.masks.part
    assert hand.sum() > 2000
    assert np.sum(hand & (pred > 0)) / np.sum(hand) <= 0.03  # measured 0.007 (0.102 before)
    assert np.sum(hand & seg.masks.hand) / np.sum(hand) >= 0.75  # measured 0.88 (0.51 before)
    ious = [np.sum((gt[t] == 1) & (pred[t] == 1)) / np.sum((gt[t] == 1) | (pred[t] == 1))
            for t in range(len(gt)) if np.sum(gt[t] == 1) > 50]
    assert np.median(ious) >= 0.85  # measured 0.886 (0.879 before)
