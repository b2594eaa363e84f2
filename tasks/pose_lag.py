"""Stages: estimate how late each recording's poses are against its RGB-D frames, and correct them.

They run right after ``ingest``, before anything reads the poses: the static recording's lag is
corrected before its drift, depth calibration, pose refinement and 3DGS; the dynamic recording's
before the registration and the part masks (lagging poses make the static background look moved,
and phantom parts). A lag is estimated from the recording alone (its frames' depth agrees only at
the right poses), so nothing downstream is needed. One that does not pass the gate
(``PoseLagStageConfig``) is stored with ``applied = False`` and a note, and the poses stay as
recorded; the effect ``pose_lag`` forces it.
"""

from __future__ import annotations

import math

import numpy as np

from artitwin_core import InputError
from artitwin_core.capture import Capture, PoseLag, estimate_pose_lag, lag_corrected
from artitwin_core.capture import PoseLagConfig as CorePoseLagConfig
from schemas import CaptureArtifact, PoseLagResult, PoseLagStageConfig
from tasks._convert import config_map, core_kwargs, to_core, to_core_config
from tasks._stage import stage

config_map(
    PoseLagStageConfig,
    {
        CorePoseLagConfig: "max_lag_frames max_depth_m",
        PoseLag.why_not: {"min_lag_frames": "min_lag_frames", "min_z_score": "min_z", "min_agreement_z": "min_agreement_z"},
    },
    stage_only={
        "correct": "whether the stage applies a significant lag (and whether the flow runs correct_pose_lag)",
        "model": "the effect pose_lag: apply an estimated lag whatever the gates say",
    },
)

METHOD = "depth-consistency-between-frames"


def _not_estimated(capture: CaptureArtifact, note: str) -> PoseLagResult:
    ts = np.asarray(capture.timestamps, np.float64)
    interval = float(np.median(np.diff(ts))) if ts.size > 1 else math.nan
    return PoseLagResult(
        estimated=False, lag_s=0.0, lag_frames=0.0, lag_se_s=math.nan, frame_interval_s=interval,
        pose_interval_s=math.nan,
        z_score=0.0, agreement_z=0.0, disagreement_zero=math.nan, disagreement_lag=math.nan,
        residual_zero_m=math.nan, residual_lag_m=math.nan, lags_frames=np.zeros(0), disagreement=np.zeros(0),
        searched_frames=0.0, frames_used=0, pairs=0, method=METHOD, significant=False, applied=False, note=note,
    )


def _describe(lag: PoseLag) -> str:
    direction = "late" if lag.lag_s >= 0 else "early"
    return (
        f"{1e3 * abs(lag.lag_s):.0f} ms {direction} ({lag.lag_frames:+.2f} frames, standard error "
        f"{lag.lag_se_s / lag.frame_interval_s:.2f})"
    )


@stage(name="pose_lag", version=3, config=PoseLagStageConfig, output=PoseLagResult)
def fit_pose_lag(capture: CaptureArtifact, config: PoseLagStageConfig) -> PoseLagResult:
    """How late ``capture``'s poses are against its RGB-D frames (``estimate_pose_lag``) and
    whether ``correct_pose_lag`` applies it: when it is at least ``min_lag_frames``,
    ``min_z_score`` standard errors, and the frames' depth agrees better at it by
    ``min_agreement_z``; or, with ``model`` (the effect ``pose_lag``), whenever one was found at
    least one standard error from 0.

    A recording too short to search is reported (``estimated = False``, a note), not refused: the
    lag is an optional correction and the run goes on with the poses as recorded.
    """
    core = to_core_config(CorePoseLagConfig, config)
    try:
        lag = estimate_pose_lag(to_core(Capture, capture), core)
    except InputError as e:
        return _not_estimated(capture, f"The pose lag was not estimated: {e}")
    why = lag.why_not(**core_kwargs(PoseLag.why_not, config))
    in_range = math.isfinite(lag.lag_s) and not lag.at_range_end
    # Forced, a lag within one standard error of zero is not applied: it is indistinguishable
    # from none, and shifting the poses by it only adds noise to every later stage.
    may_force = bool(config.model and why and in_range)
    noise = may_force and lag.z_score < 1.0
    forced = may_force and lag.lag_s != 0.0 and not noise
    applied = bool(config.correct and (not why or forced))
    said = f"The poses are {_describe(lag)} against the images"
    if noise:
        note = (f"{said}; not corrected although the effect pose_lag is modelled: it is within one standard "
                f"error of 0 ({lag.z_score:.1f}), no lag that the frames can tell from none.")
    elif applied and not forced:
        note = (
            f"{said}; corrected (the frames' depth misfit {1e3 * lag.residual_zero_m:.1f} -> {1e3 * lag.residual_lag_m:.1f} mm, "
            f"agreement {lag.agreement_z:.1f} standard errors better)."
        )
    elif forced:
        note = f"{said}; corrected because the effect pose_lag is modelled, although {why}."
    elif not config.correct:
        note = f"{said}; not corrected: pose_lag.correct is off" + (f" (and {why})." if why else ".")
    else:
        note = f"{said}; not corrected: {why}."
    return PoseLagResult(
        estimated=True, lag_s=lag.lag_s, lag_frames=lag.lag_frames, lag_se_s=lag.lag_se_s,
        frame_interval_s=lag.frame_interval_s, pose_interval_s=lag.pose_interval_s, z_score=lag.z_score, agreement_z=lag.agreement_z,
        disagreement_zero=lag.disagreement_zero, disagreement_lag=lag.disagreement_lag,
        residual_zero_m=lag.residual_zero_m, residual_lag_m=lag.residual_lag_m,
        lags_frames=lag.lags_frames, disagreement=lag.disagreement, searched_frames=lag.searched_frames,
        frames_used=lag.frames_used, pairs=lag.pairs, method=METHOD, significant=not why, applied=applied, forced=forced,
        note=note,
    )


@stage(name="correct_pose_lag", version=2, config=PoseLagStageConfig, output=CaptureArtifact)
def correct_pose_lag(capture: CaptureArtifact, lag: PoseLagResult, config: PoseLagStageConfig) -> CaptureArtifact:
    """``capture`` with each frame's pose, and its pose stream, read off its recorded trajectory
    (the pose stream when it has one) ``lag.lag_s`` later (``artitwin_core.capture.lag_corrected``;
    every other field as it was); a lag that was not ``applied`` leaves the capture as it is."""
    if not lag.applied:
        return capture
    fixed = lag_corrected(to_core(Capture, capture), lag.lag_s)
    return capture.model_copy(update={"world_from_camera": fixed.world_from_camera,
                                      "stream_world_from_camera": fixed.stream_world_from_camera})
