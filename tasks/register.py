"""Stages: register the dynamic recording to the canonical frame, then label its moving parts."""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.change import PartConfig, build_canonical_tsdf, segment_parts
from artitwin_core.registration import RegistrationConfig, register_recordings
from schemas import (
    CameraPoses,
    CaptureArtifact,
    MaskSequenceArtifact,
    PartMasksConfig,
    RegisterConfig,
    Registration,
)
from tasks._convert import to_artifact, to_core
from tasks._stage import stage


@stage(name="register", version=1, config=RegisterConfig, output=Registration)
def register_dynamic(static: CaptureArtifact, dynamic: CaptureArtifact, config: RegisterConfig) -> Registration:
    """``canonical_from_session`` of the dynamic recording (yaw sweep about gravity, ICP, coloured ICP)."""
    cfg = RegistrationConfig(
        max_depth_m=config.max_depth_m, yaw_step_deg=config.yaw_step_deg, colored_icp_voxel_m=config.colored_icp_voxel_m
    )
    result = register_recordings(to_core(Capture, static), to_core(Capture, dynamic), gravity=config.gravity, config=cfg)
    return Registration(
        canonical_from_session=np.asarray(result.canonical_from_session, dtype=np.float64),
        residual_m=float(result.residual_m),
        inlier_fraction=float(result.inlier_fraction),
        method="yaw-sweep+tukey-point-to-plane-icp" + ("+colored-icp" if config.colored_icp_voxel_m > 0 else ""),
    )


@stage(name="part_masks", version=6, config=PartMasksConfig, output=MaskSequenceArtifact)
def label_parts(
    static: CaptureArtifact,
    static_poses: CameraPoses,
    dynamic: CaptureArtifact,
    registration: Registration,
    config: PartMasksConfig,
) -> MaskSequenceArtifact:
    """Part and hand masks of every dynamic frame against the canonical (static) geometry."""
    canonical = build_canonical_tsdf(
        to_core(Capture, static),
        voxel_m=config.tsdf_voxel_m,
        max_depth_m=config.max_depth_m,
        max_frames=config.tsdf_max_frames,
        world_from_camera=static_poses.world_from_camera,
    )
    seg = segment_parts(
        to_core(Capture, dynamic),
        registration.canonical_from_session,
        canonical,
        gravity=config.gravity,
        config=PartConfig(),
    )
    return to_artifact(MaskSequenceArtifact, seg.masks)
