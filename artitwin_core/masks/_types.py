"""The in-memory form of per-frame masks."""

from __future__ import annotations

from dataclasses import dataclass

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
