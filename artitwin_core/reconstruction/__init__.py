"""Canonical reconstruction: 3D Gaussian splatting of the static recording, with refined poses.

``reconstruct(capture, ReconstructionConfig())`` refines the capture's camera poses (COLMAP
features and triangulation, depth-aware bundle adjustment, the capture's metric frame kept),
seeds Gaussians from the confidence-weighted sensor depth, trains them (L1 + D-SSIM + depth L1,
3DGS densification, pruning and opacity resets) and evaluates held-out frames. The steps are
also usable on their own; ``write_ply``/``read_ply`` exchange models with standard 3DGS viewers.
"""

from artitwin_core.reconstruction._config import (
    InitConfig,
    PoseRefineConfig,
    ReconstructionConfig,
    TrainConfig,
    split_frames,
)
from artitwin_core.reconstruction._evaluate import EvalResult, ModelRenderer, evaluate_views, render_view
from artitwin_core.reconstruction._init import init_gaussians
from artitwin_core.reconstruction._pipeline import Reconstruction, reconstruct, start_training
from artitwin_core.reconstruction._ply import read_ply, write_ply
from artitwin_core.reconstruction._poses import PoseRefinement, pose_difference, refine_poses
from artitwin_core.reconstruction._sensor import SENSOR_EFFECTS, SensorModel
from artitwin_core.reconstruction._train import (
    TrainState,
    TrainViews,
    make_views,
    scene_extent,
    train,
    train_step,
)

__all__ = [
    "SENSOR_EFFECTS",
    "SensorModel",
    "EvalResult",
    "InitConfig",
    "ModelRenderer",
    "PoseRefineConfig",
    "PoseRefinement",
    "Reconstruction",
    "ReconstructionConfig",
    "TrainConfig",
    "TrainState",
    "TrainViews",
    "evaluate_views",
    "init_gaussians",
    "make_views",
    "pose_difference",
    "read_ply",
    "reconstruct",
    "refine_poses",
    "render_view",
    "scene_extent",
    "split_frames",
    "start_training",
    "train",
    "train_step",
    "write_ply",
]
