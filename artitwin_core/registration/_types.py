"""Configuration and result of registering a dynamic recording onto the static one."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class RegistrationConfig:
    """Hyperparameters of :func:`register_recordings`.

    Attributes:
        max_depth_m: depth beyond this is ignored (LiDAR noise grows with range).
        min_confidence: keep depth pixels whose ARKit confidence is at least this (0 keeps all).
        pixel_stride: use every n-th depth pixel each way when fusing clouds.
        early_frame_weight: the first third of the dynamic frames (part most likely still closed,
            hand not yet in view) keep all their points; the rest keep ``1 / early_frame_weight``
            of them, so the moved part and the hand weigh less in the fused cloud.
        yaw_step_deg: step of the exhaustive yaw sweep about gravity (degrees).
        grid_cell_m: cell size of the top-down occupancy grids correlated for translation.
        height_bin_m: bin size of the height histograms correlated for the vertical offset.
        num_slabs: height slabs (channels) of the top-down grids.
        num_candidates: best (yaw, translation) hypotheses refined by ICP.
        icp_voxels_m: coarse-to-fine voxel sizes of the point-to-plane ICP (Tukey kernel).
        colored_icp_voxel_m: voxel size of the final coloured ICP, or 0 to skip it.
        colored_icp_lambda_geometric: weight of the point-to-plane term in the coloured ICP (the
            colour term gets ``1 - lambda``). Open3D applies one robust kernel (a Tukey of
            ``1.5 * colored_icp_voxel_m``, metres) to both residuals, so this also sets which
            intensity differences count as outliers: at 0.9 the colour term outweighed the
            geometry ~100x and every intensity difference above ~0.05 was dropped (three quarters
            of the correspondences at the true pose on the strong-hand-occlusion scene), which left
            minima ~1.5 cm either side of the truth along the cabinet front (that scene slid 15 mm,
            from the truth too); at 0.99 the two terms balance and differences up to ~0.15 count
            (0.995-0.999 fit the benchmark scenes as well but let the high-noise one slide 13 mm).
        inlier_distance_m: a dynamic point is an inlier when its point-to-plane distance to the
            static surface is below this; sets the reported inlier fraction and residual.
        consistent_frame_margin: after the coarse stages, the fine stages use the dynamic frames
            whose share of points more than 5 cm from the static cloud is at most the lowest
            share plus this (frames where nothing has moved yet).
        min_consistent_frames: use at least this many frames (the most consistent ones).
        normal_noise_radii: normals are estimated within this many times the static cloud's
            surface noise (its spread about local planes), or 3 voxels if that is wider; 0
            keeps 3 voxels. Noisy depth tilts normals fitted over too small a patch, and
            point-to-plane ICP slides along the tilt.
        uncertainty_blocks: the result's covariance is a jackknife over this many spatial
            blocks of the dynamic cloud (each left out in turn, the finest ICP rerun); 0 skips
            it. Blocks, not points: the misfit of one surface (a wall slightly curved by the
            depth noise model, a door's edge) is shared by its points.
    """

    max_depth_m: float = 4.5
    min_confidence: int = 1
    pixel_stride: int = 2
    early_frame_weight: float = 3.0
    yaw_step_deg: float = 2.0
    grid_cell_m: float = 0.05
    height_bin_m: float = 0.02
    num_slabs: int = 4
    num_candidates: int = 6
    icp_voxels_m: tuple[float, ...] = (0.08, 0.04, 0.02, 0.01)
    colored_icp_voxel_m: float = 0.01
    colored_icp_lambda_geometric: float = 0.99
    inlier_distance_m: float = 0.02
    consistent_frame_margin: float = 0.03
    min_consistent_frames: int = 3
    normal_noise_radii: float = 6.0
    uncertainty_blocks: int = 10


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
            ``"colored"``) a dict with
            its fitness, inlier RMSE (metres), seconds, and for the global stage the chosen yaw
            (degrees) and score of each refined candidate.
    """

    canonical_from_session: np.ndarray
    residual_m: float
    inlier_fraction: float
    diagnostics: dict = field(default_factory=dict)
    covariance: np.ndarray | None = None
