"""Every hyperparameter of stage IV (partition, phase I, phase II, evaluation) in frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass, field

from artitwin_core._errors import InputError
from artitwin_core.gaussians import BackendName


@dataclass(frozen=True)
class PartitionConfig:
    """Labelling the canonical Gaussians as background, interior or part k.

    Each Gaussian centre is tested in every dynamic frame under two hypotheses, "static" (it
    stays put) and "part k" (it moves with joint k to ``q_k(t)``); where the moved centre lies on
    the observed surface (sensor depth within ``depth_tol_m``) the mask label agrees or disagrees
    with the hypothesis, and where it lies in front of the observed surface (free space) the
    hypothesis is contradicted.

    Attributes:
        depth_tol_m: a centre within this of the sensor depth is on the observed surface, metres.
        min_agree: a part label needs at least this many agreeing observations (counting
            contradictions of the "static" hypothesis as evidence too labelled floor and floaters
            near the door as part and cost 0.5 dB held-out PSNR on the door benchmark).
        free_space_weight: weight of a free-space contradiction relative to a label disagreement.
        closed_frac: a frame counts as closed for joint k when ``|q_k| <= closed_frac * max|q_k|``.
        interior_visible_frac: a Gaussian hidden behind closed part k in the closed frames is
            interior when it was seen (on the surface, outside the masks) in at most this
            fraction of those frames.
    """

    depth_tol_m: float = 0.03
    min_agree: int = 1
    free_space_weight: float = 1.0
    closed_frac: float = 0.03
    interior_visible_frac: float = 0.2

    def __post_init__(self) -> None:
        if self.depth_tol_m <= 0:
            raise InputError(
                f"PartitionConfig.depth_tol_m is {self.depth_tol_m}; give a positive distance in metres."
            )
        if self.min_agree < 1:
            raise InputError(f"PartitionConfig.min_agree is {self.min_agree}; give at least 1.")


@dataclass(frozen=True)
class ArticulationConfig:
    """Phase I (dynamic frames, part and interior Gaussians only) and phase II (everything).

    Learning rates are those of the canonical reconstruction (3DGS reference values); the
    position rate is multiplied by the scene extent and decays to 1 % of itself over each phase.

    Attributes:
        partition: how the canonical Gaussians are labelled.
        holdout_every: dynamic frames 0, k, 2k, ... are held out for evaluation (0 = none, else >= 2).
        phase1_steps: steps of phase I (one dynamic training view each).
        phase2_steps: steps of phase II (one static or dynamic view each).
        lambda_dssim: weight of D-SSIM in ``(1 - l) L1 + l (1 - SSIM)``.
        depth_weight: weight of the confidence-weighted L1 depth loss (metres).
        region_dilate_px: the phase-I loss region is the part mask dilated by this many pixels,
            plus the pixels the part covered when closed.
        phase2_lr_scale: phase II multiplies every learning rate by this. Phase II restarts
            the position rate's decay, so at 1 it already ends 100x smaller; 0.3 measured
            0.4 dB lower held-out PSNR on the tiny door scene (80 + 60 steps).
        dynamic_weight: phase II's weight of the dynamic views' loss (static views weigh 1).
        seed_depth_tol_m: a pixel is unexplained when the model is transparent there or its
            depth lies more than this behind the sensor depth, metres.
        seed_voxel_m: voxel edge merging the seeded points, metres (None: 1.5 pixel footprints
            at the median depth, clamped to [0.005, 0.03] m).
        seed_max_points: at most this many new Gaussians (the voxel grows until it holds).
        seed_opacity: opacity of seeded Gaussians.
        seed_background: also seed background Gaussians where the dynamic views see static
            surface the model leaves transparent (outside the part region), and train them in
            phase I with the parts.
        seed_background_max_points: at most this many of those.
        appearance_knots: knots of each part's brightness curve over its joint range (0 = no
            curve: parts keep their closed-state colours at every state; see ``PartAppearance``).
            0 by default, as the pipeline runs it, until the twin artifact stores the curves
            (trained curves that are dropped would darken the parts); 8 is a tested setting.
        lr_part_gain: Adam learning rate of the curves' log gains.
        lr_means, lr_sh_dc, lr_sh_rest, lr_opacity, lr_scales, lr_quats: Adam learning rates.
        min_opacity: after each phase, trained Gaussians fainter than this are pruned.
        background: RGB in [0, 1] behind everything.
        backend: rasterizer backend (``"auto"``, ``"cpu"``, ``"cuda"``).
        max_side: train (and seed, and measure the held-out PSNR) on both recordings' RGB
            downscaled to at most this many pixels on the long side, the masks with them (None:
            as the captures hold them); a CPU budget: a step's cost grows with the pixels.
        seed: random view order.
        camera_effects: the dynamic recording's own camera effects to model (``RECORDING_EFFECTS``
            of ``_camera``: per-frame exposure and white balance, vignetting), fitted against the
            twin; empty: the dynamic recording is taken to have the static recording's camera.
    """

    partition: PartitionConfig = field(default_factory=PartitionConfig)
    holdout_every: int = 5
    phase1_steps: int = 300
    phase2_steps: int = 150
    lambda_dssim: float = 0.2
    depth_weight: float = 0.5
    region_dilate_px: int = 4
    phase2_lr_scale: float = 1.0
    dynamic_weight: float = 0.3
    seed_depth_tol_m: float = 0.03
    seed_voxel_m: float | None = None
    seed_max_points: int = 15_000
    seed_opacity: float = 0.5
    seed_background: bool = True
    seed_background_max_points: int = 15_000
    appearance_knots: int = 0
    lr_part_gain: float = 0.02
    lr_means: float = 1.6e-4
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20.0
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    min_opacity: float = 0.005
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    backend: BackendName = "auto"
    max_side: int | None = None
    seed: int = 0
    camera_effects: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.holdout_every < 0 or self.holdout_every == 1:
            raise InputError(
                f"ArticulationConfig.holdout_every is {self.holdout_every}; use 0 (no hold-out) or >= 2."
            )
        if self.phase1_steps < 0 or self.phase2_steps < 0:
            raise InputError("ArticulationConfig.phase1_steps and phase2_steps must be >= 0.")
        if not 0.0 <= self.lambda_dssim <= 1.0:
            raise InputError(
                f"ArticulationConfig.lambda_dssim is {self.lambda_dssim}; use a value in [0, 1]."
            )
        if self.appearance_knots < 0 or self.appearance_knots == 1:
            raise InputError(
                f"ArticulationConfig.appearance_knots is {self.appearance_knots}; use 0 (no curve) or >= 2."
            )
        unknown = sorted(set(self.camera_effects) - {"exposure_white_balance", "vignetting"})
        if unknown:
            raise InputError(
                f"ArticulationConfig.camera_effects: {unknown} cannot be modelled for the dynamic recording; "
                "give exposure_white_balance and/or vignetting."
            )
        if not 0.0 < self.seed_opacity < 1.0:
            raise InputError(
                f"ArticulationConfig.seed_opacity is {self.seed_opacity}; use a value in (0, 1)."
            )
