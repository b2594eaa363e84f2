"""Configuration and result of registering a dynamic recording onto the static one."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from artitwin_core._errors import InputError


@dataclass(frozen=True)
class HypothesisScore:
    """One refined registration hypothesis and the evidence for it.

    Attributes:
        name: where it came from (``"identity"``, ``"yaw sweep 132 deg"``, ...).
        canonical_from_session: ``[4, 4]`` after the yaw-and-translation ICP.
        support: the ranking score, at most 1: per scored dynamic frame, (points on static
            surfaces - points in space the static recording saw through - pixels whose ray
            passed through a static surface) / points; their mean, the early frames weighted as
            in ``RegistrationConfig.early_frame_weight``.
        overlap: fraction of the dynamic points that fall where the static recording looked
            (on its surfaces or in space it saw through).
        inlier_ratio: of those, the fraction on its surfaces (frames weighted as for support).
        constraint: how well the dynamic points on static surfaces pin the motion in its
            weakest direction (``weakest_constraint``).
        colour_agreement: Pearson correlation (-1 to 1) of the dynamic points' intensity with the
            static surface's where they match, each taken about its surface's mean (see
            :mod:`._texture`); frames weighted as for support times their matches. NaN when
            no frame had texture to compare.
        colour_contrast: RMS of the static intensity (0-1) about each matched surface's mean,
            averaged the same way: how much texture the agreement was measured on.
    """

    name: str
    canonical_from_session: np.ndarray
    support: float
    overlap: float
    inlier_ratio: float
    constraint: float
    colour_agreement: float = float("nan")
    colour_contrast: float = 0.0

    def as_dict(self) -> dict:
        return {"name": self.name, "support": self.support, "overlap": self.overlap,
                "inlier_ratio": self.inlier_ratio, "constraint": self.constraint,
                "colour_agreement": self.colour_agreement, "colour_contrast": self.colour_contrast}


class RegistrationError(InputError):
    """No registration hypothesis is convincing: the recordings do not overlap enough, or the
    overlap admits two placements. ``hypotheses`` holds the scored hypotheses (best first) and
    ``failed`` the refusal tests that failed, each a sentence with its numbers."""

    def __init__(self, message: str, hypotheses: tuple[HypothesisScore, ...] = (), failed: tuple[str, ...] = ()):
        super().__init__(message)
        self.hypotheses = hypotheses
        self.failed = failed

    def __reduce__(self):  # keep the scores through pickling (process pools, Prefect results)
        return (type(self), (str(self), self.hypotheses, self.failed))

@dataclass(frozen=True)
class RegistrationResult:
    """Where the dynamic recording's session frame lies in the canonical (static) frame.

    Attributes:
        canonical_from_session: ``[4, 4]`` float64 rigid transform; apply it on the left of the
            dynamic ``world_from_camera`` to get canonical poses.
        residual_m: median absolute point-to-plane distance (metres) of the inlier dynamic
            points to the static surface after the final stage.
        inlier_fraction: fraction in [0, 1] of dynamic points within ``inlier_distance_m``.
        covariance: ``[6, 6]`` covariance of the transform's error ``(w, v)``, the small rigid
            motion ``x -> x + w x x + v`` (radians, metres; canonical frame) that would correct
            it, from a spatial block jackknife; ``None`` where not estimated. The error at a
            point ``p`` has covariance ``J C J^T`` with ``J = [-[p]_x, I]``.
        diagnostics: per stage (``"fuse"``, ``"global"``, ``"frames"``, ``"icp_0.02"``, ...,
            ``"photometric"``, ``"final"``) a dict with its fitness, inlier RMSE (metres), seconds;
            the global stage lists every refined hypothesis with its scores, and ``"final"``
            the chosen one's scores at the finest level and its tilt.
        hypotheses: the distinct refined hypotheses, best first (the first is the one refined
            into ``canonical_from_session``; its scores are from before the fine stages).
        tilt_deg: angle (degrees) between gravity and gravity mapped through
            ``canonical_from_session``: the sessions' gravity disagreement it assumes.
    """

    canonical_from_session: np.ndarray
    residual_m: float
    inlier_fraction: float
    diagnostics: dict = field(default_factory=dict)
    covariance: np.ndarray | None = None
    hypotheses: tuple[HypothesisScore, ...] = ()
    tilt_deg: float = 0.0
