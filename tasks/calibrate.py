"""Stages: find the depth sensor's error from the static recording, and undo it in either recording.

They run right after ingest when the effect ``depth_scale_offset`` is modelled. One sensor made
both recordings, so the error found from the static sweep (whose frames see the room from many
places) corrects the dynamic recording too; every later stage, the 3DGS included, then reads
metric depth, so the Gaussians and the joints fitted to the tracks share one geometry.
"""

from __future__ import annotations

from artitwin_core.capture import Capture, calibrate_depth, estimate_depth_calibration
from artitwin_core.capture import DepthCalibrationConfig as CoreConfig
from schemas import CaptureArtifact, DepthCalibrationConfig, DepthCalibrationResult
from tasks._convert import config_map, to_core, to_core_config
from tasks._stage import stage

config_map(
    DepthCalibrationConfig,
    {CoreConfig: "frame_gaps max_depth_m min_confidence"},
    stage_only={
        "max_scale_error": "a plausibility gate on the estimate, applied by the stage",
        "max_offset_m": "a plausibility gate on the estimate, applied by the stage",
        "max_error_se_m": "a significance gate on the estimate, applied by the stage",
    },
)


@stage(name="depth_calibration", version=1, config=DepthCalibrationConfig, output=DepthCalibrationResult)
def estimate_capture_depth_calibration(capture: CaptureArtifact, config: DepthCalibrationConfig) -> DepthCalibrationResult:
    """The sensor's ``measured = scale * true + offset_m``, from how the recording's depth maps
    disagree at its own poses (``estimate_depth_calibration``).

    An estimate that is implausible (beyond ``max_scale_error`` / ``max_offset_m``) or uncertain
    (``error_se_m`` above ``max_error_se_m``: the poses drift or jitter, and the estimate is then
    wrong too) is stored with ``applied = False`` and a ``note``; ``calibrate_depth`` then leaves
    the depth as measured.

    Raises:
        InputError: a recording that cannot separate a scale from an offset (too few frames,
            one viewing distance).
    """
    cal = estimate_depth_calibration(
        to_core(Capture, capture),
        config=to_core_config(CoreConfig, config),
    )
    where = capture.source_path or "the static recording"
    note = ""
    if abs(cal.scale - 1.0) > config.max_scale_error or abs(cal.offset_m) > config.max_offset_m:
        note = (
            f"The depth error found in {where} (scale {cal.scale:.4f}, offset {1e3 * cal.offset_m:.1f} mm) is beyond "
            f"depth_calibration.max_scale_error {config.max_scale_error} / max_offset_m {config.max_offset_m} m: not "
            "applied. The recording's poses may be inconsistent; check its capture report."
        )
    elif not cal.error_se_m <= config.max_error_se_m:
        note = (
            f"The depth error found in {where} ({1e3 * ((cal.scale - 1.0) * cal.reference_depth_m + cal.offset_m):.1f} mm "
            f"at {cal.reference_depth_m:.2f} m) is uncertain: standard error {1e3 * cal.error_se_m:.1f} mm, over "
            f"depth_calibration.max_error_se_m {1e3 * config.max_error_se_m:.0f} mm. Not applied: the poses drift or "
            "jitter too much for the frames' depth to show the sensor's error (docs/add_and_rerun.md)."
        )
    return DepthCalibrationResult(
        scale=cal.scale, offset_m=cal.offset_m, residual_m=cal.residual_m, points_count=cal.points,
        method="multi-view-depth-consistency", scale_se=cal.scale_se, offset_m_se=cal.offset_m_se,
        reference_depth_m=cal.reference_depth_m, error_se_m=cal.error_se_m, applied=not note, note=note,
    )


@stage(name="calibrate_depth", version=1, config=DepthCalibrationConfig, output=CaptureArtifact)
def calibrate_capture_depth(
    capture: CaptureArtifact, calibration: DepthCalibrationResult, config: DepthCalibrationConfig
) -> CaptureArtifact:
    """``capture`` with its depth corrected: ``(measured - offset_m) / scale``; every other field
    as ingested. A calibration that was not ``applied`` leaves the capture as it is."""
    if not calibration.applied:
        return capture
    corrected = calibrate_depth(to_core(Capture, capture), calibration.scale, calibration.offset_m)
    return capture.model_copy(update={"depth": corrected.depth})
