"""Measurements of a recording that tell a user whether it can make a good twin."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.geometry import matrix_to_quat_wxyz


@dataclass(frozen=True)
class CaptureQuality:
    """Per-frame and summary measurements of one capture.

    Attributes:
        valid_depth_frac: ``[T]`` fraction of depth pixels with a finite, positive value.
        median_depth_m: ``[T]`` median valid depth in metres (NaN for frames without depth).
        speed_m_s: ``[T]`` camera speed in metres/second (backward difference; 0 for frame 0).
        angular_speed_deg_s: ``[T]`` camera rotation speed in degrees/second.
        path_length_m: total camera path length in metres.
        duration_s: time from first to last frame in seconds.
    """

    valid_depth_frac: np.ndarray
    median_depth_m: np.ndarray
    speed_m_s: np.ndarray
    angular_speed_deg_s: np.ndarray
    path_length_m: float
    duration_s: float


def capture_quality(capture: Capture) -> CaptureQuality:
    """Measure depth coverage and camera motion of ``capture``."""
    depth = capture.depth
    valid = np.isfinite(depth) & (depth > 0)
    valid_frac = valid.reshape(len(depth), -1).mean(axis=1)
    median = np.array([np.median(d[v]) if v.any() else np.nan for d, v in zip(depth, valid, strict=True)])
    centres = capture.world_from_camera[:, :3, 3]
    step = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    dt = np.diff(capture.timestamps)
    dt = np.where(dt > 0, dt, np.nan)
    quats = matrix_to_quat_wxyz(capture.world_from_camera[:, :3, :3])
    dots = np.clip(np.abs(np.sum(quats[1:] * quats[:-1], axis=1)), 0.0, 1.0)
    rot_step_deg = np.degrees(2 * np.arccos(dots))
    speed = np.concatenate([[0.0], step / dt])
    ang_speed = np.concatenate([[0.0], rot_step_deg / dt])
    return CaptureQuality(
        valid_depth_frac=valid_frac,
        median_depth_m=median,
        speed_m_s=speed,
        angular_speed_deg_s=ang_speed,
        path_length_m=float(step.sum()),
        duration_s=float(capture.timestamps[-1] - capture.timestamps[0]) if len(capture.timestamps) else 0.0,
    )
