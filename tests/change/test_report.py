"""The change report's figures from masks with known content: what is counted, which frames are
shown, and how the overlay draws parts and the hand."""

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.change import HAND_COLOUR, PART_COLOURS, mask_overlay, summarize_masks
from artitwin_core.masks import MaskSequence


def _masks(t_count=10, h=20, w=30):
    part = np.zeros((t_count, h, w), np.uint8)
    hand = np.zeros((t_count, h, w), bool)
    part[3:, 2:12, 2:12] = 1  # part 1: 100 px from frame 3 on
    part[7:, 12:18, 15:25] = 2  # part 2: 60 px from frame 7 on
    part[9, 12:18, 25:30] = 2  # ... and 90 px at the last frame
    hand[5:8, 0:4, 20:30] = True
    hand[6, 2:4, 2:12] = True  # two rows of the hand over part 1 at frame 6 (not hidden from the count)
    return MaskSequence(part=part, hand=hand, score=np.ones(t_count, np.float32))


def test_summary_counts_and_frames():
    m = _masks()
    s = summarize_masks(m, min_pixels=50, max_images=6)
    pixels = 20 * 30
    np.testing.assert_allclose(s.part_fraction[0, 3], 100 / pixels)
    np.testing.assert_allclose(s.part_fraction[1, 9], 90 / pixels)
    assert s.part_fraction[1, 6] == 0
    np.testing.assert_array_equal(s.first_seen, [3, 7])
    np.testing.assert_array_equal(s.peak_frame, [3, 9])
    np.testing.assert_allclose(s.hand_fraction[6], 60 / pixels)
    np.testing.assert_allclose(s.hand_overlap[6], 20 / 60)
    assert s.hand_overlap[5] == 0 and s.hand_overlap[0] == 0
    assert s.frames[0] == 0 and s.frames[-1] == 9 and {3, 7} <= set(s.frames)
    assert len(s.frames) <= 6 and s.frames == sorted(set(s.frames))


def test_summary_of_masks_without_parts():
    t_count, h, w = 4, 8, 8
    s = summarize_masks(MaskSequence(np.zeros((t_count, h, w), np.uint8), np.zeros((t_count, h, w), bool), np.ones(t_count)))
    assert s.part_fraction.shape == (0, t_count)
    assert s.frames == [0, 1, 2, 3]


def test_overlay_tints_parts_and_hand_and_keeps_the_rest():
    m = _masks()
    rgb = np.full((20, 30, 3), 100, np.uint8)
    out = mask_overlay(rgb, m.part[9], m.hand[9], alpha=0.5)
    assert out.dtype == np.uint8 and out.shape == rgb.shape
    np.testing.assert_array_equal(out[19, 0], rgb[19, 0])  # unlabelled: unchanged
    np.testing.assert_array_equal(out[6, 6], np.rint(0.5 * 100 + 0.5 * PART_COLOURS[0].astype(float)))  # inside part 1
    np.testing.assert_array_equal(out[2, 2], PART_COLOURS[0])  # its outline is opaque
    out = mask_overlay(rgb, m.part[6], m.hand[6], alpha=0.5)
    np.testing.assert_array_equal(out[3, 25], HAND_COLOUR)  # the hand's outline
    np.testing.assert_array_equal(out[1, 25], np.rint(0.5 * 100 + 0.5 * HAND_COLOUR.astype(float)))


def test_bad_shapes_name_the_field():
    m = _masks()
    with pytest.raises(InputError, match="mask_overlay"):
        mask_overlay(np.zeros((20, 30), np.uint8), m.part[0], m.hand[0])
    with pytest.raises(InputError, match="masks.part"):
        summarize_masks(MaskSequence(m.part, m.hand[:, :5], m.score))
