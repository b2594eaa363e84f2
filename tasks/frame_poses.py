"""Stages: measure the dynamic recording's per-frame pose errors on its static background, and
correct its poses with them.

They run after ``part_masks`` (the parts and the hand must be masked out of the background) and
after any drift correction; every later stage (tracks, joint states, the twin) reads the
corrected poses. Corrections that do not stand out from their standard errors are stored with
``applied = False`` and a note, and the poses stay as recorded.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.tracking import FramePoseConfig, estimate_frame_poses
from schemas import CaptureArtifact, FramePoseCorrections, FramePoseStageConfig, MaskSequenceArtifact
from tasks._convert import config_map, to_core, to_core_config
from tasks._stage import stage

config_map(
    FramePoseStageConfig,
    {
        FramePoseConfig: "keyframe_step reach mask_dilation_px model_points min_ncc min_chi2_per_dof slow_frames "
        "min_whiteness min_depth_agreement",
    },
    stage_only={"enabled": "off: the stage fits nothing and stores identity corrections"},
)


@stage(name="frame_poses", version=1, config=FramePoseStageConfig, output=FramePoseCorrections)
def fit_frame_poses(
    dynamic: CaptureArtifact, masks: MaskSequenceArtifact, config: FramePoseStageConfig
) -> FramePoseCorrections:
    """Each frame's pose correction of ``dynamic`` (``estimate_frame_poses``), in its session frame.

    Raises:
        InputError: masks that do not match the recording's frames.
    """
    capture = to_core(Capture, dynamic)
    t_count = capture.num_frames
    if not config.enabled:
        identity = np.tile(np.eye(4), (t_count, 1, 1))
        return FramePoseCorrections(
            recording="dynamic",
            corrections=identity,
            pivot=np.zeros(3),
            rotation_rad=np.zeros((t_count, 3)),
            translation_m=np.zeros((t_count, 3)),
            rotation_se_rad=np.full(t_count, np.inf),
            translation_se_m=np.full(t_count, np.inf),
            pairs=0,
            pairs_used=0,
            chi2_per_dof=0.0,
            fast_chi2_per_dof=0.0,
            whiteness=0.0,
            applied=False,
            note="Per-frame pose corrections are turned off (frame_poses.enabled = false).",
        )
    fit = estimate_frame_poses(
        capture,
        np.asarray(masks.part),
        np.asarray(masks.hand),
        to_core_config(FramePoseConfig, config),
    )
    slow = (
        f"Their slow part (whiteness {fit.whiteness:.2f} < {config.min_whiteness:g}: they change little from frame to "
        "frame) looks like drift or a sensor defect that moves with the viewpoint, not jitter, and is left alone; if the "
        "diagnosis names one, model it (pose_drift, depth_scale_offset, time_offset)."
    )
    if fit.applied == "all":
        note = ""
    elif fit.applied == "frame-to-frame":
        note = "Only the corrections' frame-to-frame part is applied. " + slow
    elif (
        fit.depth_agreement < config.min_depth_agreement and fit.fast_chi2_per_dof >= config.min_chi2_per_dof
    ):
        note = (
            f"The corrections are not applied: the frames' depth does not agree better at the corrected poses (z "
            f"{fit.depth_agreement:.1f} < {config.min_depth_agreement:g}). The grey levels then moved where depth and pose "
            "did not, as when the RGB is exposed at another time than the depth and pose (time_offset, rolling shutter) "
            "or through an undeclared lens."
        )
    elif fit.pairs_used == 0:
        note = (
            f"No alignment of the background between frames could be used ({fit.pairs} tried: too little texture or "
            "depth outside the masks); the poses stay as recorded."
        )
    else:
        note = (
            f"The corrections' frame-to-frame part does not stand out from its standard errors (chi-square per degree "
            f"of freedom {fit.fast_chi2_per_dof:.1f} < {config.min_chi2_per_dof:g}); the poses stay as recorded."
        )
        if fit.chi2_per_dof >= config.min_chi2_per_dof:
            note += " " + slow
    return FramePoseCorrections(
        recording="dynamic",
        corrections=fit.corrections,
        pivot=fit.pivot,
        rotation_rad=fit.rotation_rad,
        translation_m=fit.translation_m,
        rotation_se_rad=fit.rotation_se_rad,
        translation_se_m=fit.translation_se_m,
        pairs=fit.pairs,
        pairs_used=fit.pairs_used,
        chi2_per_dof=fit.chi2_per_dof,
        fast_chi2_per_dof=fit.fast_chi2_per_dof,
        whiteness=fit.whiteness,
        depth_agreement=fit.depth_agreement,
        applied=fit.significant,
        applied_part=fit.applied,
        note=note,
    )


@stage(name="correct_frame_poses", version=1, config=FramePoseStageConfig, output=CaptureArtifact)
def correct_frame_poses(
    capture: CaptureArtifact, corrections: FramePoseCorrections, config: FramePoseStageConfig
) -> CaptureArtifact:
    """``capture`` with each frame's pose corrected (every other field as it was); corrections that
    were not ``applied`` leave the capture as it is."""
    if not corrections.applied:
        return capture
    poses = np.einsum("tij,tjk->tik", corrections.corrections, capture.world_from_camera)
    return capture.model_copy(update={"world_from_camera": poses})
