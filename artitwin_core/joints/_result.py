"""What :func:`estimate_joint` returns: the chosen joint and every hypothesis's score.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artitwin_core.joints._types import Joint, JointType


@dataclass(frozen=True)
class HypothesisScore:
    """How well one joint type explains the trajectories.

    Attributes:
        joint_type: one of ``JOINT_TYPES``.
        bic: robust BIC on the common inlier set (lower is better).
        n_parameters: joint parameters counted by the BIC (per-frame ``q`` included).
        n_inlier_tracks: tracks this hypothesis's fit kept.
        n_inlier_points: observations (track x frame) of the common set within the inlier gate.
        rms_residual_m: RMS 3D residual over this fit's inlier observations, metres.
        converged: the alternation settled (False for hypotheses screened out early, whose BIC
            was already worse than the best by more than ``refine_bic_margin``).
        joint: this hypothesis's fitted joint (same post-processing as the chosen one).
    """

    joint_type: JointType
    bic: float
    n_parameters: int
    n_inlier_tracks: int
    n_inlier_points: int
    rms_residual_m: float
    converged: bool
    joint: Joint


@dataclass(frozen=True)
class JointFit:
    """The result of ``estimate_joint``.

    Attributes:
        joint: the chosen joint.
        hypotheses: one ``HypothesisScore`` per joint type, in ``JOINT_TYPES`` order.
        inlier_mask: ``[N]`` bool, tracks the chosen fit treats as the moving part.
        rigid_motions: ``[T, 4, 4]`` float64, per frame the RANSAC-refined rigid motion mapping a
            part point's reference-frame position to its frame-t position (identity at the
            reference frame, NaN where fewer than 3 tracks were shared with it).
        points_closed: ``[N, 3]`` metres, latent closed-state (q = 0) positions of the inlier
            tracks, NaN for the others.
        noise_sigma_m: robust per-coordinate noise estimate of one observation, metres.
        reference_frame: the frame defined as ``q = 0``.
    """

    joint: Joint
    hypotheses: tuple[HypothesisScore, ...]
    inlier_mask: np.ndarray
    rigid_motions: np.ndarray
    points_closed: np.ndarray
    noise_sigma_m: float
    reference_frame: int

    def score(self, joint_type: str) -> HypothesisScore:
        """The ``HypothesisScore`` of ``joint_type``."""
        for h in self.hypotheses:
            if h.joint_type == joint_type:
                return h
        raise KeyError(joint_type)
