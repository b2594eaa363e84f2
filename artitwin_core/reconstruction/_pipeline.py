"""The canonical reconstruction end to end: refine poses, seed from depth, train, evaluate."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture, downscale_rgb, estimate_vignetting
from artitwin_core.gaussians import GaussianParams, resolve_backend
from artitwin_core.reconstruction._config import InitConfig, ReconstructionConfig, TrainConfig, split_frames
from artitwin_core.reconstruction._evaluate import EvalResult, evaluate_views
from artitwin_core.reconstruction._init import init_gaussians
from artitwin_core.reconstruction._poses import PoseRefinement, refine_poses
from artitwin_core.reconstruction._sensor import SensorModel, SensorParams
from artitwin_core.reconstruction._train import TrainState, TrainViews, make_views, scene_extent, train


@dataclass(frozen=True)
class Reconstruction:
    """The result of :func:`reconstruct`.

    Attributes:
        params: the trained Gaussians in the capture's world frame.
        poses: the pose refinement (refined ``world_from_camera`` and per-frame corrections).
        train_frames, test_frames: frame indices used for training and held out.
        evaluation: held-out metrics (empty arrays when nothing is held out).
        initial_gaussians: how many Gaussians the depth seeding produced.
        steps: optimisation steps taken.
        losses: ``[steps]`` training loss per step.
        seconds: wall time per phase: ``poses``, ``init``, ``train``, ``evaluate``.
        sensor: the learned sensor model (``TrainConfig.sensor_effects``), None for an ideal camera.
    """

    params: GaussianParams
    poses: PoseRefinement
    train_frames: list[int]
    test_frames: list[int]
    evaluation: EvalResult
    initial_gaussians: int
    steps: int
    losses: np.ndarray
    seconds: dict[str, float]
    sensor: SensorModel | None = None


def start_training(
    capture: Capture,
    world_from_camera: np.ndarray,
    frames: list[int],
    init: InitConfig,
    config: TrainConfig,
) -> tuple[TrainState, TrainViews, TrainConfig]:
    """Seed Gaussians from the depth of ``frames`` and put the state and the views (at the
    training resolution, ``config.max_side``) on the device ``config.backend`` resolves to
    (``resolve_backend``: ``"auto"`` is CUDA with gsplat when present). Returns ``(state, views,
    config)`` with ``config.backend`` resolved, for ``train``."""
    backend = resolve_backend(config.backend)
    config = replace(config, backend=backend.name)
    capture = downscale_rgb(capture, config.max_side)
    params0 = init_gaussians(capture, world_from_camera, frames, init, config.sh_degree)
    views = make_views(capture, world_from_camera, frames, init.min_confidence, device=backend.device)
    state = TrainState.from_params(params0, scene_extent(world_from_camera[frames]), device=backend.device)
    if "vignetting" in config.sensor_effects:
        state.sensor = SensorParams(config.sensor_effects, views.frames, views.intrinsics, *views.size, views.distortion,
                                    device=backend.device, vignetting=measured_vignetting(capture, world_from_camera, frames))
    return state, views, config


def measured_vignetting(capture: Capture, world_from_camera: np.ndarray, frames: list[int]) -> tuple[float, float] | None:
    """The camera's vignetting as the training ``frames`` themselves show it (``estimate_vignetting``:
    the same surfaces at different image radii), ``(c1, c2)`` of the sensor model, which keeps it
    fixed (see ``_sensor``); None when they cannot show it (too little overlap): it is then
    learned with the Gaussians. The held-out frames are not used, as for every fitted parameter."""
    sel = capture.select_frames(sorted(frames))
    try:
        est = estimate_vignetting(sel, np.asarray(world_from_camera, np.float64)[sorted(frames)])
    except InputError:
        return None
    return est.gain


def reconstruct(
    capture: Capture,
    config: ReconstructionConfig = ReconstructionConfig(),
    *,
    gt_depth: np.ndarray | None = None,
    callback: Callable[[TrainState], None] | None = None,
) -> Reconstruction:
    """Reconstruct the static recording ``capture`` as 3D Gaussians.

    Args:
        capture: the static RGB-D recording (poses in its world frame, OpenCV axes, metres).
        config: every hyperparameter.
        gt_depth: optional ``[T, H, W]`` ground-truth z-depth at RGB resolution (synthetic data),
            for the evaluation's ``depth_mae_gt_m``.
        callback: called after every training step with the state (progress, checkpoints).
    """
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    poses = refine_poses(capture, config.poses)
    seconds["poses"] = time.perf_counter() - t0

    train_frames, test_frames = split_frames(capture.num_frames, config.holdout_every)
    t0 = time.perf_counter()
    state, views, train_config = start_training(capture, poses.world_from_camera, train_frames, config.init, config.train)
    initial = state.num_gaussians
    seconds["init"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    train(state, views, train_config, callback=callback)
    seconds["train"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    params = state.to_params()
    sensor = state.sensor_model()
    evaluation = evaluate_views(
        params, capture, poses.world_from_camera, test_frames, gt_depth=gt_depth,
        background=config.train.background, backend=train_config.backend, sensor=sensor,
    )  # fmt: skip
    seconds["evaluate"] = time.perf_counter() - t0
    return Reconstruction(
        params=params,
        poses=poses,
        train_frames=train_frames,
        test_frames=test_frames,
        evaluation=evaluation,
        initial_gaussians=initial,
        steps=state.step,
        losses=np.asarray(state.losses),
        seconds=seconds,
        sensor=sensor,
    )
