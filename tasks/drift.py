"""Stages: fit each recording's pose drift and correct its poses (the effect ``pose_drift``).

The static recording's drift is fitted from its own frames (their depth and keypoints agree only
at the right poses); the dynamic recording's against the canonical model, once its moving parts
and the hand are masked, so it runs after ``part_masks`` and every later stage reads the corrected
poses. A fitted drift is applied only if it is large, certain and seen by both halves of the
recording alike (``PoseDriftConfig``); otherwise it is stored with ``applied = False`` and a note.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture, DriftSignificance, PoseDrift, estimate_depth_calibration
from artitwin_core.capture import DepthCalibrationConfig as CoreCalibrationConfig
from artitwin_core.change import build_canonical_tsdf
from artitwin_core.registration import SessionDriftConfig, estimate_session_drift
from schemas import CaptureArtifact, MaskSequenceArtifact, PoseDriftConfig, PoseDriftResult, Registration
from tasks._convert import config_map, core_kwargs, to_core, to_core_config
from tasks._stage import stage

config_map(
    PoseDriftConfig,
    {
        CoreCalibrationConfig: "gravity",
        SessionDriftConfig: "gravity mask_dilation_px max_association_m",
        build_canonical_tsdf: {"tsdf_voxel_m": "voxel_m", "tsdf_max_frames": "max_frames"},
        DriftSignificance.why_not: {
            "min_displacement_m": "min_displacement_m", "min_z_score": "min_z",
            "max_half_disagreement": "max_half_disagreement",
        },
    },
    stage_only={"model": "the effect pose_drift: whether the flow runs the drift stages at all"},
)


def _result(recording: str, drift: PoseDrift, sig: DriftSignificance, residual_m: float, method: str, config: PoseDriftConfig) -> PoseDriftResult:
    why = sig.why_not(**core_kwargs(DriftSignificance.why_not, config))
    return PoseDriftResult(
        recording=recording, pivot=drift.pivot, t0_s=drift.t0_s, rot0_rad=drift.rot0_rad, trans0_m=drift.trans0_m,
        rot_rate_rad_per_s=drift.rot_rate_rad_per_s, trans_rate_m_per_s=drift.trans_rate_m_per_s,
        point=sig.point, displacement_m=sig.displacement_m, displacement_se_m=sig.displacement_se_m,
        z_score=sig.z_score, rate_m_per_s=sig.rate_m_per_s, half_rates_m_per_s=sig.half_rates_m_per_s,
        residual_m=residual_m, method=method, applied=not why,
        note=f"The {recording} recording's pose drift is not applied: {why}." if why else "",
    )


@stage(name="static_drift", version=1, config=PoseDriftConfig, output=PoseDriftResult)
def fit_static_drift(capture: CaptureArtifact, config: PoseDriftConfig) -> PoseDriftResult:
    """The static recording's linear pose drift, from how its frames' depth and SIFT keypoints
    disagree at its poses (``estimate_depth_calibration`` with ``pose_drift``). The sensor's depth
    error is fitted with it, whether or not ``depth_scale_offset`` is modelled: the two bend the
    frames' agreement alike, so a drift fitted alone would absorb a depth error. It runs on the
    recording as ingested, before ``depth_calibration``, which then sees drift-free poses.

    Raises:
        InputError: a recording whose frames do not overlap enough to fit anything.
    """
    cal = estimate_depth_calibration(
        to_core(Capture, capture),
        config=to_core_config(CoreCalibrationConfig, config, pose_drift=True),
    )
    return _result("static", cal.drift, cal.drift_significance, cal.residual_m, "depth-consistency+sift-reprojection", config)


@stage(name="session_drift", version=1, config=PoseDriftConfig, output=PoseDriftResult)
def fit_session_drift(
    static: CaptureArtifact, dynamic: CaptureArtifact, registration: Registration, masks: MaskSequenceArtifact,
    config: PoseDriftConfig,
) -> PoseDriftResult:
    """The dynamic recording's pose correction: a constant part (what the registration left) and a
    linear drift, fitted against the canonical TSDF of ``static`` with the parts and the hand
    masked (``estimate_session_drift``). Stored in the dynamic recording's own frame; ``point``,
    ``displacement_m`` and the rates are in the canonical frame.

    Raises:
        InputError: masks that do not match the recording, or too little unmasked evidence.
    """
    static_capture = to_core(Capture, static)
    mesh = build_canonical_tsdf(static_capture, **core_kwargs(build_canonical_tsdf, config))
    fit = estimate_session_drift(
        to_core(Capture, dynamic), registration.canonical_from_session, mesh, np.asarray(masks.part), np.asarray(masks.hand),
        static_capture,
        to_core_config(SessionDriftConfig, config),
    )
    return _result("dynamic", fit.drift, fit.significance, fit.residual_m, "projective-depth-to-canonical+sift", config)


@stage(name="correct_pose_drift", version=1, config=PoseDriftConfig, output=CaptureArtifact)
def correct_pose_drift(capture: CaptureArtifact, drift: PoseDriftResult, config: PoseDriftConfig) -> CaptureArtifact:
    """``capture`` with its poses corrected by ``drift`` (every other field as it was); a drift
    that was not ``applied`` leaves the capture as it is."""
    if not drift.applied:
        return capture
    model = PoseDrift(
        pivot=drift.pivot, t0_s=drift.t0_s, rot0_rad=drift.rot0_rad, trans0_m=drift.trans0_m,
        rot_rate_rad_per_s=drift.rot_rate_rad_per_s, trans_rate_m_per_s=drift.trans_rate_m_per_s,
    )
    return capture.model_copy(update={"world_from_camera": model.apply(capture.world_from_camera, capture.timestamps)})
