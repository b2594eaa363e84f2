"""Capture formats: one in-memory :class:`Capture`, readers and writers for each file format.

Readers: Record3D ``.r3d`` and EXR+JPG exports, nerfstudio ``transforms.json`` with depth, Stray
Scanner folders. All give OpenCV camera axes, camera-to-world poses in metres, intrinsics at RGB
and depth resolution, and raise :class:`artitwin_core.InputError` naming file and frame on bad input.
"""

from artitwin_core.capture._calibrate import (
    DepthCalibration,
    calibrate_depth,
    estimate_depth_calibration,
)
from artitwin_core.capture._common import depth_intrinsics_from_rgb, downscale_rgb, scale_intrinsics
from artitwin_core.capture._config import (
    DepthCalibrationConfig,
    KeyframeConfig,
    PoseLagConfig,
    VignettingConfig,
)
from artitwin_core.capture._detect import FORMATS, detect_format, read_capture, recording_files
from artitwin_core.capture._drift import DriftSignificance, PoseDrift, drift_significance
from artitwin_core.capture._keyframes import KeyframeSelection, select_keyframes
from artitwin_core.capture._lag import (
    PoseLag,
    beyond_recorded,
    correct_pose_lag,
    estimate_pose_lag,
    lag_corrected,
)
from artitwin_core.capture._nerfstudio import read_nerfstudio, write_nerfstudio
from artitwin_core.capture._options import ReadOptions
from artitwin_core.capture._r3d import read_r3d, write_r3d
from artitwin_core.capture._record3d_exr import read_record3d_exr, write_record3d_exr
from artitwin_core.capture._scene import SceneRecordings, find_scene_recordings
from artitwin_core.capture._stray import read_stray, write_stray
from artitwin_core.capture._types import Capture, intrinsics_matrix
from artitwin_core.capture._vignetting import VignettingEstimate, estimate_vignetting

__all__ = [
    "drift_significance",
    "FORMATS",
    "Capture",
    "KeyframeConfig",
    "KeyframeSelection",
    "DepthCalibration",
    "DepthCalibrationConfig",
    "DriftSignificance",
    "PoseDrift",
    "PoseLag",
    "PoseLagConfig",
    "ReadOptions",
    "SceneRecordings",
    "VignettingConfig",
    "VignettingEstimate",
    "beyond_recorded",
    "calibrate_depth",
    "correct_pose_lag",
    "lag_corrected",
    "depth_intrinsics_from_rgb",
    "detect_format",
    "downscale_rgb",
    "estimate_depth_calibration",
    "estimate_pose_lag",
    "estimate_vignetting",
    "find_scene_recordings",
    "intrinsics_matrix",
    "read_capture",
    "read_nerfstudio",
    "read_r3d",
    "read_record3d_exr",
    "read_stray",
    "recording_files",
    "scale_intrinsics",
    "select_keyframes",
    "write_nerfstudio",
    "write_r3d",
    "write_record3d_exr",
    "write_stray",
]
