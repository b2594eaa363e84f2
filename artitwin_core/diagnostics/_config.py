"""Hyperparameters of the diagnosis (:class:`DiagnoseConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DiagnoseConfig:
    """Thresholds of ``diagnose``.

    Attributes:
        min_explained: an effect must explain at least this fraction of its target to be enabled.
        min_gain_over_floor: ... and reduce its target's energy by at least this many noise floors.
        structure_ratio: a target whose energy stays above this many noise floors holds structure.
        max_rounds: at most this many effects are enabled.
        min_correlation: a correlation ratio (eta^2) below this is not worth naming.
        heldout_every: hold out every n-th frame to check the enabled effects on frames they were
            not fitted on (0: no check).
        min_gain_over_null: an effect with ``null_columns`` must cut the held-out residual the
            twin-geometry null leaves by at least this share (``surface_null_check``).
        min_world_fixed: remaining depth structure of which the static per-surface correction
            explains at least this share (held out) is the twin's own geometry, not an effect.
    """

    min_explained: float = 0.2
    min_gain_over_floor: float = 0.5
    structure_ratio: float = 2.0
    max_rounds: int = 4
    min_correlation: float = 0.05
    heldout_every: int = 4
    min_gain_over_null: float = 0.3
    min_world_fixed: float = 0.5
