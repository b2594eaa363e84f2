"""Stages of the canonical reconstruction: refine the static recording's poses, train the 3DGS
model, and report on it.

Three stages rather than one so that each result is cached on exactly what it depends on:
changing a training hyperparameter reuses the (slow, COLMAP) pose refinement, and re-reporting
never retrains. Training time is the ``seconds`` of the ``reconstruct`` stage run.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.gaussians import GaussianParams
from artitwin_core.reconstruction import (
    InitConfig,
    PoseRefineConfig,
    ReconstructionConfig,
    SensorModel,
    TrainConfig,
    evaluate_views,
    refine_poses,
    split_frames,
    start_training,
    train,
)
from schemas import CameraPoses, CaptureArtifact, GaussianCheckpoint, StageReport
from schemas._reconstruct import PoseRefineStageConfig, ReconstructConfig
from tasks._convert import config_map, core_values, to_artifact, to_core, to_core_config
from tasks._stage import stage

config_map(PoseRefineStageConfig, {PoseRefineConfig: " ".join(PoseRefineStageConfig.model_fields)})  # every field, by its name
config_map(
    ReconstructConfig,
    {
        ReconstructionConfig: "holdout_every",
        InitConfig: {"voxel_size_m": "voxel_size_m", "max_init_points": "max_points", "min_confidence": "min_confidence",
                     "max_depth_m": "max_depth_m"},
        TrainConfig: {**{n: n for n in "steps lambda_dssim depth_weight sh_degree max_gaussians grad_threshold backend "
                         "seed sensor_effects".split()}, "train_max_side": "max_side"},
    },
    stage_only={"low_psnr_note_db": "a gate the report stage applies to the core's held-out PSNR (a note, no core setting)"},
)


def pose_config(config: PoseRefineStageConfig) -> PoseRefineConfig:
    """The core dataclass for a stage config."""
    return to_core_config(PoseRefineConfig, config)


def init_config(config: ReconstructConfig) -> InitConfig:
    return to_core_config(InitConfig, config)


def train_config(config: ReconstructConfig) -> TrainConfig:
    """The training config, its densification and SH schedule stretched to ``steps``."""
    return TrainConfig.with_schedule(**core_values(TrainConfig, config))


def sensor_fields(model: SensorModel | None) -> dict:
    """A learned sensor model as ``GaussianCheckpoint`` fields (none for an ideal camera)."""
    if model is None:
        return {}
    return {
        "sensor_effects": list(model.effects),
        "sensor_frames": model.frames.astype(np.int64),
        "sensor_log_gain": model.log_gain,
        "sensor_offset": model.offset,
        "sensor_vignetting": None if model.vignetting is None else list(model.vignetting),
        "depth_scale": model.depth_scale,
        "depth_offset_m": model.depth_offset_m,
        "sensor_distortion": None if model.distortion is None else list(model.distortion),
    }


def sensor_model(checkpoint: GaussianCheckpoint) -> SensorModel | None:
    """The sensor model stored with a checkpoint, None when it was trained for an ideal camera."""
    if not checkpoint.sensor_effects and checkpoint.sensor_distortion is None:
        return None
    return SensorModel(
        effects=tuple(checkpoint.sensor_effects),
        frames=np.zeros(0, np.int64) if checkpoint.sensor_frames is None else np.asarray(checkpoint.sensor_frames),
        log_gain=checkpoint.sensor_log_gain,
        offset=checkpoint.sensor_offset,
        vignetting=None if checkpoint.sensor_vignetting is None else tuple(checkpoint.sensor_vignetting),
        depth_scale=checkpoint.depth_scale,
        depth_offset_m=checkpoint.depth_offset_m,
        distortion=None if checkpoint.sensor_distortion is None else tuple(checkpoint.sensor_distortion),
    )


@stage(name="refine_poses", version=3, config=PoseRefineStageConfig, output=CameraPoses)
def refine_capture_poses(capture: CaptureArtifact, config: PoseRefineStageConfig) -> CameraPoses:
    """Refined camera poses of the static recording, in its own (= the canonical) world frame.

    When COLMAP cannot refine (low texture, too few matches) the capture poses come back
    unchanged with ``correction_translation = None``; it never fails on such data.
    """
    result = refine_poses(to_core(Capture, capture), pose_config(config))
    refined = result.status != "fallback"
    return CameraPoses(
        world_from_camera=result.world_from_camera.astype(np.float64),
        frame_ids=np.asarray(capture.frame_ids, np.int64),
        frame="canonical",
        correction_translation=result.correction_translation_m.astype(np.float64) if refined else None,
        correction_rotation=result.correction_rotation_deg.astype(np.float64) if refined else None,
    )


def _with_poses(capture: CaptureArtifact, poses: CameraPoses) -> Capture:
    if poses.world_from_camera.shape[0] != capture.world_from_camera.shape[0]:
        raise ValueError(
            f"reconstruct: {poses.world_from_camera.shape[0]} poses for a capture of "
            f"{capture.world_from_camera.shape[0]} frames; refine the poses of this capture."
        )
    return to_core(Capture, capture, world_from_camera=poses.world_from_camera)


# 3: the exposure model learns per-frame gains only (no offset).
# 4: the vignetting is measured from the training frames themselves and kept fixed.
@stage(name="reconstruct", version=4, config=ReconstructConfig, output=GaussianCheckpoint)
def reconstruct_canonical(capture: CaptureArtifact, poses: CameraPoses, config: ReconstructConfig) -> GaussianCheckpoint:
    """Train the canonical 3DGS model of the static recording with the refined ``poses``.

    Every ``holdout_every``-th frame is left out of seeding and training (see ``reconstruct_report``).
    """
    cap = _with_poses(capture, poses)
    train_frames, _ = split_frames(cap.num_frames, config.holdout_every)
    state, views, tcfg = start_training(cap, cap.world_from_camera, train_frames, init_config(config), train_config(config))
    train(state, views, tcfg)
    return to_artifact(GaussianCheckpoint, state.to_params(), step=state.step, **sensor_fields(state.sensor_model()))


@stage(name="reconstruct_report", version=2, config=ReconstructConfig, output=StageReport)
def reconstruct_report(
    capture: CaptureArtifact, poses: CameraPoses, gaussians: GaussianCheckpoint, config: ReconstructConfig
) -> StageReport:
    """Held-out PSNR, SSIM and depth error of the model, and the pose corrections."""
    cap = _with_poses(capture, poses)
    params = to_core(GaussianParams, gaussians)
    _, test_frames = split_frames(cap.num_frames, config.holdout_every)
    sensor = sensor_model(gaussians)
    ev = evaluate_views(params, cap, cap.world_from_camera, test_frames, backend=config.backend, sensor=sensor)
    summary = ev.summary()
    metrics = {
        "gaussians_count": float(params.num_gaussians),
        "steps_count": float(gaussians.step),
        "heldout_frames_count": float(len(test_frames)),
        "heldout_psnr_db": summary["psnr_db"],
        "heldout_ssim": summary["ssim"],
        "heldout_depth_mae_m": summary["depth_mae_m"],
    }
    notes = []
    per_frame: dict[str, list[float]] = {}
    if sensor is not None:
        if sensor.effects:
            notes.append(f"Sensor model learned with the Gaussians: {', '.join(sensor.effects)}.")
        if sensor.log_gain is not None:
            stops = sensor.log_gain.mean(1) / np.log(2.0)
            metrics["sensor_exposure_stops_std"] = float(np.std(stops))
            metrics["sensor_white_balance_rb_std"] = float(np.std(np.exp(sensor.log_gain[:, [0, 2]] - sensor.log_gain[:, 1:2])))
            per_frame["sensor_exposure_stops"] = stops.tolist()
        if sensor.vignetting is not None:
            metrics["sensor_vignetting_corner_falloff"] = float(-(sensor.vignetting[0] + sensor.vignetting[1]))
        if "depth_scale_offset" in sensor.effects:
            metrics["sensor_depth_scale"] = sensor.depth_scale
            metrics["sensor_depth_offset_m"] = sensor.depth_offset_m
        if sensor.distortion is not None:
            for name, value in zip(("k1", "k2", "p1", "p2"), sensor.distortion, strict=True):
                metrics[f"sensor_lens_{name}"] = value
            notes.append("The capture records lens distortion; the renders were distorted with it before comparison.")
    if poses.correction_translation is None:
        notes.append("Pose refinement did not run or fell back (low texture?): the capture poses were used.")
    else:
        metrics["pose_correction_mean_m"] = float(np.mean(poses.correction_translation))
        metrics["pose_correction_max_m"] = float(np.max(poses.correction_translation))
        metrics["pose_correction_mean_deg"] = float(np.mean(poses.correction_rotation))
        metrics["pose_correction_max_deg"] = float(np.max(poses.correction_rotation))
        per_frame["pose_correction_m"] = poses.correction_translation.tolist()
        per_frame["pose_correction_deg"] = poses.correction_rotation.tolist()
    if not test_frames:
        notes.append("No frame was held out (holdout_every = 0 or too few frames): no evaluation.")
    elif summary["psnr_db"] < config.low_psnr_note_db:
        notes.append(
            f"Held-out PSNR is {summary['psnr_db']:.1f} dB: expect visible artefacts; more training steps, or a "
            "slower, steadier recording, usually help."
        )
    return StageReport(stage="reconstruct_report", metrics=metrics, notes=notes, per_frame=per_frame)
