"""Masks at a lower working resolution (stage IV's training resolution, the diagnosis's predictions)."""

from __future__ import annotations

import numpy as np

from artitwin_core.masks import MaskSequence, downscale_masks


def test_part_labels_are_sampled_at_pixel_centres_and_the_hand_grows():
    part = np.zeros((2, 8, 8), np.uint8)
    part[:, :, 4:] = 1  # a part on the right half
    part[1, 0:2, 0:2] = 2
    hand = np.zeros((2, 8, 8), bool)
    hand[0, 5, 1] = True  # one hand pixel
    masks = MaskSequence(part=part, hand=hand, score=np.ones(2, np.float32))
    small = downscale_masks(masks, (4, 4))
    assert small.part.shape == (2, 4, 4) and small.part.dtype == np.uint8 and small.hand.dtype == bool
    np.testing.assert_array_equal(small.part[0], np.repeat([[0, 0, 1, 1]], 4, axis=0))
    assert small.part[1, 0, 0] == 2  # a label is kept, never blended into another
    # The output pixel covering input rows 4-5, columns 0-1 is the hand's: one of its pixels is.
    assert small.hand[0].sum() == 1 and small.hand[0, 2, 0] and not small.hand[1].any()
    assert downscale_masks(masks, (8, 8)) is masks
