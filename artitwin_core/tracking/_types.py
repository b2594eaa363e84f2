"""The in-memory form of point trajectories."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Trajectories:
    """N point tracks over T frames, padded: a track need not be valid in every frame.

    Attributes:
        points_in_world: ``[T, N, 3]`` float64 metres in the canonical frame (NaN where invalid).
        pixels: ``[T, N, 2]`` float32 (x, y) pixel positions at RGB resolution (NaN where invalid).
        valid: ``[T, N]`` bool, True where the track has a reliable 3D position in that frame.
        query_frame: index of the frame the tracks were seeded in.
        part_ids: ``[N]`` int32 which moving part each track is on (0 = part 0, i.e. mask label 1);
            ``None`` when all tracks are on one part.
    """

    points_in_world: np.ndarray
    pixels: np.ndarray
    valid: np.ndarray
    query_frame: int = 0
    part_ids: np.ndarray | None = None
