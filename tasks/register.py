"""Stages: register the dynamic recording to the canonical frame, then label its moving parts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from artitwin_core import InputError
from artitwin_core.capture import Capture
from artitwin_core.change import (
    ChangeConfig,
    PartConfig,
    build_canonical_tsdf,
    mask_overlay,
    propagate_masks_sam2,
    segment_parts,
    summarize_masks,
)
from artitwin_core.masks import MaskSequence
from artitwin_core.registration import RegistrationConfig, register_recordings
from schemas import (
    CameraPoses,
    CaptureArtifact,
    ChangeStageConfig,
    JointParams,
    MaskSequenceArtifact,
    PartFateArtifact,
    PartMasksConfig,
    PartStageConfig,
    Registration,
    RegistrationStageConfig,
    ReportImage,
    StageReport,
)
from tasks._convert import config_map, core_kwargs, to_artifact, to_core, to_core_config
from tasks._stage import stage

config_map(
    RegistrationStageConfig,
    {RegistrationConfig: "max_depth_m yaw_step_deg refuse_unconvincing", register_recordings: "gravity"},
    stage_only={
        "photometric": "off: RegistrationConfig.photometric_blur_rad is () (no photometric refinement); on: its "
        "default levels",
    },
)
config_map(
    PartMasksConfig,
    {
        build_canonical_tsdf: {"tsdf_voxel_m": "voxel_m", "max_depth_m": "max_depth_m", "tsdf_max_frames": "max_frames"},
        segment_parts: {"gravity": "gravity", "parts": "config"},
        propagate_masks_sam2: {"sam2_checkpoint": "checkpoint", "sam2_model_config": "model_config"},
    },
    differs={"parts": "segment_parts takes config=None for PartConfig(); PartStageConfig's own map checks its defaults"},
)
config_map(PartStageConfig, {PartConfig: " ".join(PartStageConfig.model_fields)})  # every field, by its name
config_map(ChangeStageConfig, {ChangeConfig: " ".join(ChangeStageConfig.model_fields)})


@stage(name="register", version=9, config=RegistrationStageConfig, output=Registration)
def register_dynamic(static: CaptureArtifact, dynamic: CaptureArtifact, config: RegistrationStageConfig) -> Registration:
    """``canonical_from_session`` of the dynamic recording: hypotheses from the poses and a yaw sweep
    about gravity, scored against what the static recording saw, gravity-keeping ICP, a photometric
    refinement against the static images, and a check that the refined placement lays the same
    texture on the static surfaces.

    Raises :class:`artitwin_core.registration.RegistrationError` (an ``InputError``) when no
    hypothesis is convincing, so that part_masks never runs on a wrong placement."""
    cfg = to_core_config(RegistrationConfig, config, **({} if config.photometric else {"photometric_blur_rad": ()}))
    result = register_recordings(
        to_core(Capture, static), to_core(Capture, dynamic), config=cfg, **core_kwargs(register_recordings, config)
    )
    final = result.diagnostics["final"]  # the winner's scores once refined
    rival = result.diagnostics["verdict"].get("rival_support")
    return Registration(
        canonical_from_session=np.asarray(result.canonical_from_session, dtype=np.float64),
        residual_m=float(result.residual_m),
        inlier_fraction=float(result.inlier_fraction),
        method="pose+yaw-sweep-hypotheses+free-space-scoring+gravity-tukey-icp"
        + ("+photometric" if config.photometric else ""),
        covariance=result.covariance,
        hypothesis=str(final["name"]),
        support=float(final["support"]),
        rival_support=float("nan") if rival is None else float(rival),
        overlap=float(final["overlap"]),
        overlap_inlier_ratio=float(final["inlier_ratio"]),
        weakest_constraint=float(final["constraint"]),
        tilt_deg=float(result.tilt_deg),
        colour_agreement=float(final["colour_agreement"]),
        colour_contrast=float(final["colour_contrast"]),
    )


@stage(name="part_masks", version=17, config=PartMasksConfig, output=MaskSequenceArtifact)
def label_parts(
    static: CaptureArtifact,
    static_poses: CameraPoses,
    dynamic: CaptureArtifact,
    registration: Registration,
    config: PartMasksConfig,
) -> MaskSequenceArtifact:
    """Candidate part masks and hand masks of every dynamic frame against the canonical (static)
    geometry (``candidates``: which of the part finder's candidates each label is; ``fates``: those
    it merged or dropped, and why; ``depth_joints``: each label's joint as the part finder fitted
    it to the depth); with ``config.sam2_checkpoint``, the part labels propagated backwards from
    the last frame by SAM2."""
    if config.sam2_checkpoint and not Path(config.sam2_checkpoint).is_file():
        # Before the geometric work, not after it.
        raise InputError(
            f"part_masks.sam2_checkpoint {config.sam2_checkpoint!r} does not exist. Give the path of a downloaded "
            "SAM2 checkpoint (e.g. sam2.1_hiera_large.pt), or leave it unset for the geometric backend (no weights)."
        )
    canonical = build_canonical_tsdf(
        to_core(Capture, static), world_from_camera=static_poses.world_from_camera,
        **core_kwargs(build_canonical_tsdf, config),
    )
    capture = to_core(Capture, dynamic)
    seg = segment_parts(capture, registration.canonical_from_session, canonical, **core_kwargs(segment_parts, config))
    masks = seg.masks
    if config.sam2_checkpoint:
        part = propagate_masks_sam2(capture.rgb, masks.part[-1], **core_kwargs(propagate_masks_sam2, config))
        part[np.asarray(masks.hand, bool)] = 0
        masks = MaskSequence(part=part, hand=masks.hand, score=masks.score)
    return to_artifact(
        MaskSequenceArtifact, masks, candidates=seg.candidates, fates=[to_artifact(PartFateArtifact, f) for f in seg.fates],
        depth_joints=[to_artifact(JointParams, j, name=f"part_{k}") for k, j in enumerate(seg.joints())],
    )


@stage(name="part_masks_report", version=2, config=PartMasksConfig, output=StageReport)
def part_masks_report(
    dynamic: CaptureArtifact, masks: MaskSequenceArtifact, registration: Registration, config: PartMasksConfig
) -> StageReport:
    """The change report: how well the recording registered, which parts were found and when,
    per-frame part and hand shares, and the masks drawn over the frames that matter."""
    capture = to_core(Capture, dynamic)
    seq = to_core(MaskSequence, masks)
    summary = summarize_masks(seq)
    k_count = summary.part_fraction.shape[0]
    hand_px = float(np.asarray(seq.hand, bool).sum())
    metrics = {
        "parts_count": float(k_count),
        "registration_residual_m": float(registration.residual_m),
        "registration_inlier_frac": float(registration.inlier_fraction),
        "hand_labelled_part_frac": float((np.asarray(seq.hand, bool) & (seq.part > 0)).sum() / hand_px) if hand_px else 0.0,
        "mask_score_mean_frac": float(np.mean(seq.score)),
    }
    per_frame = {
        "hand_frac": summary.hand_fraction.tolist(),
        "mask_score_frac": np.asarray(seq.score, dtype=np.float64).tolist(),
    }
    notes = []
    for k in range(k_count):
        metrics[f"part_{k}_first_seen_index"] = float(summary.first_seen[k])
        metrics[f"part_{k}_peak_frac"] = float(summary.part_fraction[k].max())
        per_frame[f"part_{k}_frac"] = summary.part_fraction[k].tolist()
    if k_count == 0:
        notes.append(
            "No moving part was found: nothing in the dynamic recording departs from the static scene. Check that "
            "the part moved in view, and the registration residual."
        )
    if registration.inlier_fraction < 0.5:
        notes.append(
            f"Only {100 * registration.inlier_fraction:.0f}% of the dynamic points lie on the static surface after "
            "registration: the recordings may not show the same room, or the registration failed."
        )
    for fate in masks.fates:
        where = "dropped" if fate.into is None else f"merged into candidate {fate.into}"
        notes.append(f"Candidate part {fate.candidate}: {where}: {fate.reason}.")
    if k_count:
        notes.append("These are candidate parts: each is kept, merged or dropped once its tracks and joint are known "
                     "(settle_parts in the summary).")
    if config.sam2_checkpoint:
        notes.append(f"Part labels propagated by SAM2 ({config.sam2_checkpoint}).")
    images = []
    legend = ", ".join(f"part {k + 1} ({_COLOUR_NAMES[k % len(_COLOUR_NAMES)]})" for k in range(k_count))
    for t in summary.frames:
        shown = [f"part {k + 1} {100 * summary.part_fraction[k, t]:.1f}%" for k in range(k_count)]
        caption = f"frame {t}: " + ", ".join(shown + [f"hand {100 * summary.hand_fraction[t]:.1f}%"])
        images.append(ReportImage(pixels=mask_overlay(capture.rgb[t], seq.part[t], seq.hand[t]), caption=caption))
    if images and k_count:
        notes.append(f"Overlays: {legend}, hand (red).")
    return StageReport(stage="part_masks_report", metrics=metrics, notes=notes, per_frame=per_frame, images=images)


# Names of artitwin_core.change._report.PART_COLOURS, in order, for the legend.
_COLOUR_NAMES = ["orange", "blue", "purple", "green", "pink", "yellow"]
