"""The in-memory form of per-frame masks."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class MaskSequence:
    """Per-frame labels of the dynamic recording at RGB resolution.

    Attributes:
        part: ``[T, H, W]`` uint8, 0 = not a moving part, k + 1 = part k.
        hand: ``[T, H, W]`` bool, hand and arm pixels.
        score: ``[T]`` float32 in [0, 1], per-frame confidence of the part mask.
    """

    part: np.ndarray
    hand: np.ndarray
    score: np.ndarray


def downscale_masks(masks: MaskSequence, size: tuple[int, int]) -> MaskSequence:
    """``masks`` at the RGB size ``size = (width, height)`` pixels (a lower working resolution).

    A part label is the one under the output pixel's centre (nearest, pixel-centre convention);
    a pixel is the hand's if any input pixel it covers is, so hand pixels stay out of every
    loss and comparison at the lower resolution too.
    """
    t, h, w = masks.part.shape
    nw, nh = int(size[0]), int(size[1])
    if (nw, nh) == (w, h):
        return masks
    part = np.empty((t, nh, nw), np.uint8)
    hand = np.empty((t, nh, nw), bool)
    for i in range(t):
        part[i] = cv2.resize(np.asarray(masks.part[i], np.uint8), (nw, nh), interpolation=cv2.INTER_NEAREST_EXACT)
        hand[i] = cv2.resize(np.asarray(masks.hand[i], np.float32), (nw, nh), interpolation=cv2.INTER_AREA) > 0
    return MaskSequence(part=part, hand=hand, score=masks.score)
