"""Stage: read a recording's files into a capture artifact, and report on its quality."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from artitwin_core.capture import Capture, KeyframeConfig, ReadOptions, read_capture, select_keyframes
from artitwin_core.diagnostics import capture_quality
from schemas import CaptureArtifact, CaptureCheckConfig, IngestConfig, StageReport
from tasks._convert import config_map, to_artifact, to_core, to_core_config
from tasks._stage import stage

log = logging.getLogger(__name__)

config_map(
    IngestConfig,
    {
        ReadOptions: "stride max_frames rgb_max_width rgb_max_side",
        KeyframeConfig: {
            "keyframes_max": "max_frames", "keyframe_view_step": "view_step",
            "keyframe_change_step": "change_step", "keyframe_max_gap_s": "max_gap_s",
        },
    },
    differs={"keyframes_max": "None (the default) selects no keyframes; KeyframeConfig needs a number when it runs."},
)
config_map(
    CaptureCheckConfig,
    {},
    stage_only={
        "min_valid_depth_frac": "a warning threshold on capture_quality's result, applied by the stage",
        "max_speed_m_s": "a warning threshold on capture_quality's result, applied by the stage",
    },
)


def keyframe_config(config: IngestConfig) -> KeyframeConfig:
    """The core dataclass for a stage config's keyframe fields (``keyframes_max`` set)."""
    return to_core_config(KeyframeConfig, config)


@stage(name="ingest", version=2, config=IngestConfig, output=CaptureArtifact, raw_inputs=("recording",))
def ingest_recording(recording: Path, config: IngestConfig) -> CaptureArtifact:
    """Read the recording at ``recording`` (any supported format) into a capture artifact, at the
    working resolution and, for a long recording, its keyframes only (chosen from a first read of
    the poses and depth alone, so the images of the other frames are never decoded)."""
    options = to_core_config(ReadOptions, config)
    if config.keyframes_max is not None:
        geometry = read_capture(Path(recording), replace(options, skip_rgb=True))
        if geometry.num_frames > config.keyframes_max:
            chosen = select_keyframes(geometry, keyframe_config(config))
            log.info("ingest %s: %d of %d frames kept as keyframes (%d for coverage)", Path(recording).name,
                     len(chosen.frames), geometry.num_frames, len(chosen.added_for_coverage))
            options = replace(options, frames=tuple(int(f) for f in chosen.frames))
        del geometry
    capture = read_capture(Path(recording), options)
    return to_artifact(CaptureArtifact, capture, source_path=str(recording))


@stage(name="capture_check", version=1, config=CaptureCheckConfig, output=StageReport)
def check_capture(capture: CaptureArtifact, config: CaptureCheckConfig) -> StageReport:
    """Depth coverage and camera motion of a capture, with warnings a user can act on."""
    q = capture_quality(to_core(Capture, capture))
    notes = []
    sparse = np.flatnonzero(q.valid_depth_frac < config.min_valid_depth_frac)
    if sparse.size:
        notes.append(
            f"{sparse.size} frame(s) have less than {config.min_valid_depth_frac:.0%} valid depth "
            f"(first: frame {int(capture.frame_ids[sparse[0]])}); move closer or add light."
        )
    fast = np.flatnonzero(q.speed_m_s > config.max_speed_m_s)
    if fast.size:
        notes.append(
            f"camera moves faster than {config.max_speed_m_s} m/s in {fast.size} frame(s) "
            f"(first: frame {int(capture.frame_ids[fast[0]])}): expect motion blur or pose jumps."
        )
    rgb_w, rgb_h = capture.rgb.shape[2], capture.rgb.shape[1]
    depth_w, depth_h = capture.depth.shape[2], capture.depth.shape[1]
    return StageReport(
        stage="capture_check",
        metrics={
            "frames_count": float(len(capture.rgb)),
            "duration_s": q.duration_s,
            "path_length_m": q.path_length_m,
            "valid_depth_frac": float(np.mean(q.valid_depth_frac)),
            "median_depth_m": float(np.nanmedian(q.median_depth_m)) if np.isfinite(q.median_depth_m).any() else float("nan"),
            "max_speed_m_s": float(np.max(q.speed_m_s)),
            "rgb_width_px": float(rgb_w),
            "rgb_height_px": float(rgb_h),
            "depth_width_px": float(depth_w),
            "depth_height_px": float(depth_h),
        },
        notes=notes,
        per_frame={
            "valid_depth_frac": q.valid_depth_frac.tolist(),
            "speed_m_s": q.speed_m_s.tolist(),
            "angular_speed_deg_s": q.angular_speed_deg_s.tolist(),
        },
    )
