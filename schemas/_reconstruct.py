"""Configs of the canonical-reconstruction stages (pose refinement, 3DGS training, its report).

Each field maps onto a field of the frozen dataclasses in ``artitwin_core.reconstruction``
(``PoseRefineConfig``, ``InitConfig``, ``TrainConfig``); the defaults are theirs.
"""

from __future__ import annotations

from pydantic import Field

from schemas._base import StageConfig
from schemas._effects import SensorEffect
from schemas._vocab import BackendName


class PoseRefineStageConfig(StageConfig):
    """Refining the static recording's camera poses (COLMAP features + depth-aware bundle adjustment)."""

    enabled: bool = Field(default=True, description="False keeps the capture poses (corrections reported as None).")
    max_features: int | None = Field(
        default=4096, ge=64,
        description="SIFT features per RGB frame; None = scaled with the working resolution (4 sqrt(W H), 1024..8192).",
    )
    exhaustive_max_frames: int = Field(
        default=80, ge=2, description="Match every frame pair up to this many frames; sequential matching beyond."
    )
    sequential_overlap: int = Field(default=10, ge=1, description="Sequential matching: frames matched with each frame.")
    loop_closure_pairs: int = Field(
        default=0, ge=0,
        description="Sequential matching: each frame is also matched with up to this many frames outside its window whose "
        "views overlap (by the capture poses): loop closures of a sweep that comes back.",
    )
    prior_position_std_m: float = Field(
        default=0.05, gt=0, description="Std of the capture camera centres used as priors in bundle adjustment, metres."
    )
    iterations: int = Field(default=2, ge=1, le=5, description="Rounds of triangulate-then-adjust.")
    min_track_points: int = Field(default=15, ge=3, description="A frame is refined only if it sees this many points.")
    max_correction_m: float = Field(default=0.15, gt=0, description="Larger corrections are rejected (frame kept), metres.")
    max_correction_deg: float = Field(default=8.0, gt=0, description="Larger rotation corrections are rejected, degrees.")
    num_threads: int = Field(
        default=1, ge=1, description="CPU threads COLMAP and Ceres may use to match and adjust; 1 gives the same poses on every run."
    )
    extraction_threads: int = Field(
        default=1, ge=0, description="CPU threads extracting SIFT features (0 = every available core; the features are the same)."
    )
    seed: int = Field(
        default=0, ge=0, description="COLMAP's random seed (the RANSACs of match verification and triangulation): the same "
        "recording gives the same poses on every run."
    )


class ReconstructConfig(StageConfig):
    """Seeding and training the canonical 3D Gaussian splatting model, and its evaluation split."""

    holdout_every: int = Field(
        default=8, ge=0, description="Frames 0, k, 2k, ... are held out for evaluation (0 = none held out); k >= 2."
    )
    low_psnr_note_db: float = Field(
        default=25.0, description="The report notes visible artefacts when the held-out PSNR is below this, dB."
    )
    voxel_size_m: float | None = Field(
        default=None, gt=0, description="Seeding voxel edge in metres; None = ~1.5 pixel footprints at the median depth."
    )
    max_init_points: int = Field(default=30_000, ge=100, description="Upper bound on the depth-seeded Gaussians.")
    min_confidence: int = Field(default=1, ge=0, le=2, description="Depth pixels with lower ARKit confidence are ignored.")
    max_depth_m: float = Field(default=5.0, gt=0, description="Depth beyond this is ignored, metres.")
    steps: int = Field(default=1500, ge=1, description="Optimisation steps (one training view each).")
    lambda_dssim: float = Field(default=0.2, ge=0, le=1, description="Weight of D-SSIM in the photometric loss.")
    depth_weight: float = Field(default=0.5, ge=0, description="Weight of the confidence-weighted L1 depth loss (metres).")
    sh_degree: int = Field(default=3, ge=0, le=3, description="Final spherical-harmonic degree.")
    max_gaussians: int = Field(default=60_000, ge=1000, description="Densification stops adding beyond this many Gaussians.")
    grad_threshold: float = Field(default=2e-4, gt=0, description="Densification threshold on the mean NDC gradient norm.")
    backend: BackendName = Field(default="auto", description="Rasterizer backend: auto, cpu or cuda (or reference, the plain torch one).")
    train_max_side: int | None = Field(
        default=None, ge=16,
        description="Train on the frames downscaled to at most this many pixels on the long side (a CPU budget: a "
        "step's cost grows with the pixels); None = the capture's resolution. Evaluation stays at the capture's.",
    )
    seed: int = Field(default=0, description="Seed of the view order and split samples.")
    sensor_effects: list[SensorEffect] = Field(
        default_factory=list,
        description="Camera effects learned with the Gaussians (see docs/effects.md): per-frame exposure and white "
        "balance, vignetting, an affine depth error. Empty = an ideal camera. The diagnosis names the ones a "
        "recording needs; `artitwin run --effect NAME` enables one.",
    )
