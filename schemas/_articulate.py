"""Config of the articulation stages (stage IV: articulation-conditioned optimisation and its report).

Each field maps onto a field of the frozen ``artitwin_core.articulation.ArticulationConfig`` (or
its ``PartitionConfig``); the defaults are theirs.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from schemas._base import StageConfig
from schemas._vocab import BackendName


class ArticulateConfig(StageConfig):
    """Partitioning the canonical Gaussians into background / interior / parts and optimising them
    against the dynamic recording with the parts moved by their joints."""

    holdout_every: int = Field(
        default=5,
        ge=0,
        description="Dynamic frames 0, k, 2k, ... are held out for evaluation (0 = none); k >= 2.",
    )
    phase1_steps: int = Field(
        default=300, ge=0, description="Phase I steps: dynamic views, only interior and part Gaussians train."
    )
    phase2_steps: int = Field(
        default=150,
        ge=0,
        description="Phase II steps: static and dynamic views, every Gaussian trains, joints fixed.",
    )
    lambda_dssim: float = Field(
        default=0.2, ge=0, le=1, description="Weight of D-SSIM in the photometric loss."
    )
    depth_weight: float = Field(
        default=0.5, ge=0, description="Weight of the confidence-weighted L1 depth loss (metres)."
    )
    region_dilate_px: int = Field(
        default=4,
        ge=0,
        description="Phase-I loss region: the part mask dilated by this many pixels, plus the closed part.",
    )
    dynamic_weight: float = Field(
        default=0.3, ge=0, description="Phase II: weight of the dynamic views' loss (static views weigh 1)."
    )
    partition_depth_tol_m: float = Field(
        default=0.03,
        gt=0,
        description="A Gaussian centre within this of the sensor depth lies on the surface, metres.",
    )
    seed_depth_tol_m: float = Field(
        default=0.03,
        gt=0,
        description="New Gaussians where the model's depth lies this far behind the sensor's, metres.",
    )
    seed_max_points: int = Field(
        default=15_000, ge=0, description="At most this many new (revealed-surface) Gaussians."
    )
    seed_background: bool = Field(
        default=True,
        description="Also seed and train background Gaussians where the dynamic views see static surface "
        "that the canonical model leaves transparent (never seen by the static recording).",
    )
    seed_background_max_points: int = Field(
        default=15_000, ge=0, description="At most this many new background Gaussians."
    )
    appearance_knots: int = Field(
        default=0,
        ge=0,
        description="Knots of each part's brightness curve over its joint state (0 = none). Off here until "
        "the twin artifact stores the curves: trained curves that are dropped would darken the parts.",
    )
    lr_means: float = Field(
        default=1.6e-4, gt=0, description="Position learning rate, times the scene extent (metres)."
    )
    backend: BackendName = Field(default="auto", description="Rasterizer backend: auto, cpu or cuda (or reference, the plain torch one).")
    train_max_side: int | None = Field(
        default=None, ge=16,
        description="Train on both recordings downscaled to at most this many pixels on the long side, the masks "
        "with them (a CPU budget: a step's cost grows with the pixels); None = the captures' resolution.",
    )
    seed: int = Field(default=0, description="Seed of the view order.")
    sensor_effects: list[Literal["exposure_white_balance", "vignetting"]] = Field(
        default_factory=list,
        description="The dynamic recording's own camera effects, modelled here (docs/effects.md): per-frame exposure "
        "and white balance, vignetting, fitted against the twin on the training frames (held-out frames "
        "interpolated) and stored with the twin for predict_dynamic. Empty = the static recording's camera. "
        "`artitwin run --effect dynamic:NAME` enables one.",
    )
