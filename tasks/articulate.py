"""Stage IV: the articulation-conditioned optimisation of the canonical model, and its report.

Two stages so that re-reporting never retrains. Training time is the ``seconds`` of the
``articulate`` stage run; the phase-by-phase PSNR curve is in ``bench/bench_articulation.py``.
"""

from __future__ import annotations

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.articulation import (
    ArticulationConfig,
    articulate,
    dynamic_views,
    evaluate_psnr,
    label_counts,
)
from artitwin_core.capture import Capture
from artitwin_core.gaussians import LABEL_BACKGROUND, GaussianParams, resolve_backend
from artitwin_core.joints import Joint
from artitwin_core.masks import MaskSequence
from artitwin_core.reconstruction import split_frames
from schemas import (
    CameraPoses,
    CaptureArtifact,
    GaussianCheckpoint,
    JointSet,
    MaskSequenceArtifact,
    Registration,
    StageReport,
)
from schemas._articulate import ArticulateConfig
from tasks._convert import config_map, to_artifact, to_core, to_core_config
from tasks._stage import stage
from tasks.reconstruct import sensor_fields

config_map(
    ArticulateConfig,
    {
        ArticulationConfig: {
            **{n: n for n in "holdout_every phase1_steps phase2_steps lambda_dssim depth_weight region_dilate_px "
               "dynamic_weight seed_depth_tol_m seed_max_points seed_background seed_background_max_points "
               "appearance_knots lr_means backend seed".split()},
            "partition_depth_tol_m": "partition.depth_tol_m",
            "train_max_side": "max_side",
            "sensor_effects": "camera_effects",
        },
    },
)


def core_config(config: ArticulateConfig) -> ArticulationConfig:
    """The core dataclass for a stage config."""
    return to_core_config(ArticulationConfig, config)


def core_joints(joints: JointSet) -> list[Joint]:
    return [to_core(Joint, j) for j in joints.joints]


def _static(static: CaptureArtifact, poses: CameraPoses) -> Capture:
    if poses.world_from_camera.shape[0] != static.world_from_camera.shape[0]:
        raise InputError(
            f"articulate: {poses.world_from_camera.shape[0]} static poses for a capture of "
            f"{static.world_from_camera.shape[0]} frames; refine the poses of the static capture."
        )
    return to_core(Capture, static, world_from_camera=poses.world_from_camera)


def _dynamic(dynamic: CaptureArtifact, registration: Registration) -> Capture:
    """The dynamic recording with its poses mapped into the canonical frame."""
    canonical = registration.canonical_from_session @ np.asarray(dynamic.world_from_camera, np.float64)
    return to_core(Capture, dynamic, world_from_camera=canonical)


# 3: the twin carries the dynamic recording's camera when ArticulateConfig.sensor_effects asks for it.
@stage(name="articulate", version=3, config=ArticulateConfig, output=GaussianCheckpoint)
def articulate_twin(
    canonical: GaussianCheckpoint,
    static: CaptureArtifact,
    static_poses: CameraPoses,
    dynamic: CaptureArtifact,
    registration: Registration,
    masks: MaskSequenceArtifact,
    joints: JointSet,
    config: ArticulateConfig,
) -> GaussianCheckpoint:
    """The labelled (0 background, 1 interior, 2 + k part k) and optimised twin, parts closed.

    The dynamic frames held out (every ``holdout_every``-th) train nothing; see ``articulate_report``.
    With ``config.sensor_effects``, the checkpoint's sensor fields are the dynamic recording's
    camera (frame indices are positions in the dynamic recording), which ``predict_dynamic`` applies.
    """
    st = _static(static, static_poses)
    dyn = _dynamic(dynamic, registration)
    result = articulate(
        to_core(GaussianParams, canonical), st, st.world_from_camera, dyn, dyn.world_from_camera,
        to_core(MaskSequence, masks), core_joints(joints), core_config(config),
    )  # fmt: skip
    steps = int(canonical.step) + config.phase1_steps + config.phase2_steps
    return to_artifact(GaussianCheckpoint, result.params, step=steps, **sensor_fields(result.camera))


@stage(name="articulate_report", version=1, config=ArticulateConfig, output=StageReport)
def articulate_report(
    canonical: GaussianCheckpoint,
    twin: GaussianCheckpoint,
    dynamic: CaptureArtifact,
    registration: Registration,
    masks: MaskSequenceArtifact,
    joints: JointSet,
    config: ArticulateConfig,
) -> StageReport:
    """Held-out dynamic-frame PSNR of the twin (hand pixels excluded) against the canonical model
    rendered unmoved, and how many Gaussians each label holds."""
    dyn = _dynamic(dynamic, registration)
    js = core_joints(joints)
    seq = to_core(MaskSequence, masks)
    params = to_core(GaussianParams, twin)
    canon = to_core(GaussianParams, canonical)
    canon = GaussianParams(
        **{**canon.__dict__, "labels": np.full(canon.num_gaussians, LABEL_BACKGROUND, np.int32)}
    )
    _, test = split_frames(dyn.num_frames, config.holdout_every)
    counts = label_counts(params.labels, len(js))
    metrics = {
        "gaussians_count": float(params.num_gaussians),
        "num_background_gaussians_count": float(counts["background"]),
        "num_interior_gaussians_count": float(counts["interior"]),
        "num_part_gaussians_count": float(params.num_gaussians - counts["background"] - counts["interior"]),
        "heldout_frames_count": float(len(test)),
    }
    notes: list[str] = []
    per_frame: dict[str, list[float]] = {}
    if not test:
        notes.append("No dynamic frame was held out (holdout_every = 0 or too few frames): no evaluation.")
    else:
        cc = core_config(config)
        av = dynamic_views(dyn, dyn.world_from_camera, seq, js, test, resolve_backend(cc.backend).device)
        twin_psnr = evaluate_psnr(params, av, js, cc)
        canon_psnr = evaluate_psnr(canon, av, js, cc)
        metrics["psnr_holdout_db"] = float(np.mean(twin_psnr))
        metrics["psnr_canonical_db"] = float(np.mean(canon_psnr))
        metrics["psnr_gain_db"] = metrics["psnr_holdout_db"] - metrics["psnr_canonical_db"]
        per_frame["psnr_holdout_db"] = twin_psnr.tolist()
        if metrics["psnr_holdout_db"] < 24.0:
            notes.append(
                f"Held-out dynamic PSNR is {metrics['psnr_holdout_db']:.1f} dB: check the joint fit and the part "
                "masks (a mislabelled part leaves pieces behind when it moves)."
            )
    for k in range(len(js)):
        metrics[f"part_{k}_gaussians_count"] = float(counts[f"part_{k}"])
        if counts[f"part_{k}"] == 0:
            notes.append(f"No Gaussian was labelled part {k}: its mask never matched the canonical surface.")
    return StageReport(stage="articulate_report", metrics=metrics, notes=notes, per_frame=per_frame)
