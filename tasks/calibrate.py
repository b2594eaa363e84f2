"""Stages: find the depth sensor's error from the static recording, and undo it in either recording.

They run right after ingest when the effect ``depth_scale_offset`` is modelled. One sensor made
both recordings, so the error found from the static sweep (whose frames see the room from many
places) corrects the dynamic recording too; every later stage, the 3DGS included, then reads
metric depth, so the Gaussians and the joints fitted to the tracks share one geometry.
"""

from __future__ import annotations

from artitwin_core import InputError
from artitwin_core.capture import Capture, calibrate_depth, estimate_depth_calibration
from artitwin_core.capture import DepthCalibrationConfig as CoreConfig
from schemas import CaptureArtifact, DepthCalibrationConfig, DepthCalibrationResult
from tasks._convert import to_core
from tasks._stage import stage


@stage(name="depth_calibration", version=1, config=DepthCalibrationConfig, output=DepthCalibrationResult)
def estimate_capture_depth_calibration(capture: CaptureArtifact, config: DepthCalibrationConfig) -> DepthCalibrationResult:
    """The sensor's ``measured = scale * true + offset_m``, from how the recording's depth maps
    disagree at its own poses (``estimate_depth_calibration``).

    Raises:
        InputError: an estimate beyond ``config``'s bounds, or a recording that cannot separate a
            scale from an offset (too few frames, one viewing distance).
    """
    cal = estimate_depth_calibration(
        to_core(Capture, capture), config=CoreConfig(frame_gaps=tuple(config.frame_gaps), max_depth_m=config.max_depth_m)
    )
    if abs(cal.scale - 1.0) > config.max_scale_error or abs(cal.offset_m) > config.max_offset_m:
        raise InputError(
            f"depth_calibration: the depth error found in {capture.source_path or 'the static recording'} (scale "
            f"{cal.scale:.4f}, offset {1e3 * cal.offset_m:.1f} mm) is beyond depth_calibration.max_scale_error "
            f"{config.max_scale_error} / max_offset_m {config.max_offset_m} m; its poses may be inconsistent. Check "
            "the capture report, or rerun without the effect depth_scale_offset."
        )
    return DepthCalibrationResult(
        scale=cal.scale, offset_m=cal.offset_m, residual_m=cal.residual_m, points_count=cal.points,
        method="multi-view-depth-consistency",
    )


@stage(name="calibrate_depth", version=1, config=DepthCalibrationConfig, output=CaptureArtifact)
def calibrate_capture_depth(
    capture: CaptureArtifact, calibration: DepthCalibrationResult, config: DepthCalibrationConfig
) -> CaptureArtifact:
    """``capture`` with its depth corrected: ``(measured - offset_m) / scale``; every other field
    as ingested."""
    corrected = calibrate_depth(to_core(Capture, capture), calibration.scale, calibration.offset_m)
    return capture.model_copy(update={"depth": corrected.depth})
