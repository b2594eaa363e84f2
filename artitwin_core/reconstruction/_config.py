"""Every hyperparameter of the canonical reconstruction, in small frozen dataclasses.

One dataclass per step (initialisation, pose refinement, training) plus the bundle of the three;
each is hashable and printable, so a run is described by its config alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.gaussians import BackendName, DensifyStrategy
from artitwin_core.reconstruction._sensor import check_sensor_effects


@dataclass(frozen=True)
class InitConfig:
    """Seeding Gaussians from back-projected sensor depth.

    Attributes:
        voxel_size_m: voxel edge for downsampling the back-projected points, metres; ``None``
            picks about 1.5 pixel footprints at the median depth, clamped to [0.01, 0.03] m.
        max_points: upper bound on the initial Gaussians; the voxel grows until it holds.
        min_confidence: depth pixels with ARKit confidence below this are dropped (0 keeps all).
        max_depth_m: depth beyond this is ignored (the LiDAR is unreliable far away), metres.
        opacity: initial opacity of every Gaussian, in (0, 1).
        frame_stride: back-project every n-th training frame (1 = all).
    """

    voxel_size_m: float | None = None
    max_points: int = 30_000
    min_confidence: int = 1
    max_depth_m: float = 5.0
    opacity: float = 0.3
    frame_stride: int = 1


@dataclass(frozen=True)
class PoseRefineConfig:
    """Refining the capture's camera poses with COLMAP (SIFT, matching, triangulation, BA).

    Attributes:
        enabled: False keeps the capture poses untouched.
        max_features: SIFT features per image; ``None`` scales them with the image:
            ``4 sqrt(W H)`` clamped to [1024, 8192] (1774 at 512x384, 2217 at 640x480, 6651 at
            1920x1440), since a smaller image holds fewer distinct keypoints.
        sift_peak_threshold: SIFT's contrast threshold (COLMAP's default 0.0067; lower finds
            more features in small or low-contrast frames).
        sequential_overlap: frames matched against each following frame when the recording
            has more than ``exhaustive_max_frames`` frames (else every pair is matched).
        exhaustive_max_frames: up to this many frames every pair is matched.
        loop_closure_pairs: with sequential matching, each frame is also matched with up to this
            many frames outside its sequential window whose views overlap (cameras close and
            looking the same way, by the capture poses): the loops of a sweep that returns.
        prior_position_std_m: standard deviation of the capture camera centres used as position
            priors in bundle adjustment, metres (they hold the world frame and metric scale).
        iterations: rounds of (triangulate from the current poses, adjust with depth).
        min_track_points: a frame whose pose is refined must observe at least this many
            triangulated points; others keep their capture pose.
        max_correction_m, max_correction_deg: a refined pose that moved more than this from the
            capture pose is not trusted (kept as captured, reported).
        min_refined_frac: if fewer than this fraction of frames could be refined, the whole
            refinement is abandoned and the capture poses kept.
        num_threads: CPU threads COLMAP may use to match, triangulate and adjust. 1 (the
            default), with ``seed``, makes the result deterministic: with more, COLMAP's threads
            race (RANSAC, Ceres) and the same recording's poses differed by centimetres between
            runs, at about the same run time on 2 cores.
        extraction_threads: CPU threads extracting SIFT features (0 = every available core).
            Each image's features do not depend on the thread that extracts them.
        seed: COLMAP's random seed (its RANSACs in the matches' verification and in
            triangulation). COLMAP's own default draws one per run: the tiny scene's poses then
            came out one of two ways, 3 cm apart, from one run to the next in one process.
    """

    enabled: bool = True
    max_features: int | None = 4096
    sift_peak_threshold: float = 0.0067
    sequential_overlap: int = 10
    exhaustive_max_frames: int = 80
    loop_closure_pairs: int = 0
    prior_position_std_m: float = 0.05
    iterations: int = 2
    min_track_points: int = 15
    max_correction_m: float = 0.15
    max_correction_deg: float = 8.0
    min_refined_frac: float = 0.5
    num_threads: int = 1
    extraction_threads: int = 1
    seed: int = 0

    def features_for(self, width: int, height: int) -> int:
        """SIFT features per image of ``width x height`` pixels (``max_features``, or scaled)."""
        if self.max_features is not None:
            return int(self.max_features)
        return int(np.clip(round(4.0 * np.sqrt(width * height)), 1024, 8192))


@dataclass(frozen=True)
class TrainConfig:
    """Optimising the Gaussians (3DGS schedule, compressed to a few thousand steps).

    Learning rates are those of the reference 3DGS code; the position rate is multiplied by
    the scene extent (the radius of the camera centres) and decays exponentially to
    ``lr_means_final`` over ``steps``.

    Attributes:
        steps: optimisation steps (one training view each).
        lambda_dssim: weight of D-SSIM in ``(1 - l) L1 + l (1 - SSIM)``.
        depth_weight: weight of the confidence-weighted L1 depth loss (metres).
        lr_means, lr_means_final: position learning rate at the first and last step, times extent.
        lr_sh_dc, lr_sh_rest, lr_opacity, lr_scales, lr_quats: Adam learning rates.
        sh_degree: final spherical-harmonic degree (0..3).
        sh_degree_every: the degree grows by one every this many steps.
        densify_from, densify_until, densify_every: densification window and period (steps).
        grad_threshold: densify where the mean view-space gradient norm of a Gaussian's centre
            exceeds this, in NDC units as 3DGS measures it.
        percent_dense: Gaussians larger than this fraction of the extent are split, smaller
            ones cloned.
        max_gaussians: densification stops adding beyond this many (CPU budget).
        min_opacity: prune Gaussians with opacity below this.
        max_screen_radius_px: after the first opacity reset, prune Gaussians whose footprint
            exceeded this many pixels.
        max_world_scale: prune Gaussians whose largest axis exceeds this fraction of the extent.
        opacity_reset_every: steps between opacity resets (0 = never).
        opacity_reset_value: opacity is clamped to this at a reset.
        background: RGB in [0, 1] behind everything.
        backend: rasterizer backend (``"auto"``, ``"cpu"``, ``"cuda"``).
        max_side: train on the RGB frames downscaled to at most this many pixels on the long
            side (None: as the capture holds them); a CPU budget: a step's cost grows with the
            pixels. The model is still evaluated and rendered at any resolution.
        seed: random view order and split samples.
        sensor_effects: camera effects learned with the Gaussians (``_sensor.SENSOR_EFFECTS``:
            exposure_white_balance, vignetting, depth_scale_offset); empty = an ideal camera.
        lr_sensor: Adam learning rate of the sensor parameters (the depth scale and offset take a tenth).
    """

    steps: int = 1500
    lambda_dssim: float = 0.2
    depth_weight: float = 0.5
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20.0
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    sh_degree: int = 3
    sh_degree_every: int = 250
    densify_from: int = 150
    densify_until: int = 975
    densify_every: int = 60
    grad_threshold: float = 2e-4
    percent_dense: float = 0.01
    max_gaussians: int = 60_000
    min_opacity: float = 0.005
    max_screen_radius_px: float = 40.0
    max_world_scale: float = 0.1
    opacity_reset_every: int = 600
    opacity_reset_value: float = 0.01
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    backend: BackendName = "auto"
    max_side: int | None = None
    seed: int = 0
    sensor_effects: tuple[str, ...] = ()
    lr_sensor: float = 0.01

    @classmethod
    def with_schedule(cls, steps: int, **overrides) -> TrainConfig:
        """A config whose densification, SH and opacity-reset schedule is the default one
        stretched to ``steps`` (densify from 10 % to 65 % of the run, 15 densifications, SH
        degree +1 every sixth of the run, one opacity reset at 40 % for runs of 1000+ steps)."""
        steps = int(steps)
        sched = {
            "steps": steps,
            "densify_from": max(1, steps // 10),
            "densify_until": max(1, int(0.65 * steps)),
            "densify_every": max(10, steps // 25),
            "sh_degree_every": max(1, steps // 6),
            "opacity_reset_every": int(0.4 * steps) if steps >= 1000 else 0,
        }
        sched.update(overrides)
        return cls(**sched)

    def densify_strategy(self) -> DensifyStrategy:
        """This config's densification, pruning and opacity-reset settings as the strategy takes them."""
        return DensifyStrategy(**{f.name: getattr(self, f.name) for f in fields(DensifyStrategy)})

    def __post_init__(self) -> None:
        if self.steps < 1:
            raise InputError(f"TrainConfig.steps is {self.steps}; give at least 1.")
        if not 0 <= self.sh_degree <= 3:
            raise InputError(f"TrainConfig.sh_degree is {self.sh_degree}; use 0..3.")
        if not 0.0 <= self.lambda_dssim <= 1.0:
            raise InputError(f"TrainConfig.lambda_dssim is {self.lambda_dssim}; use a value in [0, 1].")
        try:
            object.__setattr__(self, "sensor_effects", check_sensor_effects(self.sensor_effects))
        except ValueError as e:
            raise InputError(f"TrainConfig.{e}") from None


@dataclass(frozen=True)
class ReconstructionConfig:
    """The whole canonical reconstruction: poses, seeding, training, evaluation split.

    Attributes:
        init, poses, train: the three steps' configs.
        holdout_every: every k-th frame (indices 0, k, 2k, ...) is held out for evaluation and
            used neither for seeding nor for training (0 = train on all, evaluate on none).
    """

    init: InitConfig = field(default_factory=InitConfig)
    poses: PoseRefineConfig = field(default_factory=PoseRefineConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    holdout_every: int = 8

    def __post_init__(self) -> None:
        if self.holdout_every < 0 or self.holdout_every == 1:
            raise InputError(
                f"ReconstructionConfig.holdout_every is {self.holdout_every}; use 0 (no hold-out) or >= 2."
            )


def split_frames(num_frames: int, holdout_every: int) -> tuple[list[int], list[int]]:
    """``(train, test)`` frame indices: every ``holdout_every``-th frame is a test frame.

    With fewer than two frames left for training, all frames train (and none test).
    """
    if holdout_every <= 0:
        return list(range(num_frames)), []
    test = [i for i in range(num_frames) if i % holdout_every == 0]
    train = [i for i in range(num_frames) if i % holdout_every != 0]
    if len(train) < 2:
        return list(range(num_frames)), []
    return train, test
