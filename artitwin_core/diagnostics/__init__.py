"""Model against measurement: quality of captures, residuals of the twin, physical-effect plugins.

``make_residual_data`` puts a twin's predictions beside a recording; ``compare_frames`` gives
residual maps and per-frame error curves; ``diagnose`` ranks the registered ``Effect`` plugins by
the residual they explain and checks the enabled ones on held-out frames (``evaluate_heldout``);
``write_html_report`` writes it all for a user; ``compare_runs`` sets two runs of one scene side
by side. User effects are loaded by ``discover_effects`` (entry points ``artitwin.effects``, env
var ``ARTITWIN_EFFECTS``).
"""

from artitwin_core.diagnostics import _camera as _camera  # registers the camera effects
from artitwin_core.diagnostics import _catalog as _catalog  # registers the built-in effects
from artitwin_core.diagnostics._camera import (
    LensDistortion,
    PoseDrift,
    RollingShutter,
    TimeOffset,
    image_velocity,
)
from artitwin_core.diagnostics._capture_quality import CaptureQuality, capture_quality
from artitwin_core.diagnostics._catalog import (
    AxisTilt,
    DepthNoise,
    DepthScaleOffset,
    DrawerTilt,
    ExposureWhiteBalance,
    ScrewJoint,
    Vignetting,
)
from artitwin_core.diagnostics._compare import FrameComparison, compare_frames
from artitwin_core.diagnostics._config import DiagnoseConfig
from artitwin_core.diagnostics._diagnose import Diagnosis, Structure, diagnose
from artitwin_core.diagnostics._heldout import ERROR_OF_TARGET, HeldOut, HeldOutCheck, evaluate_heldout
from artitwin_core.diagnostics._plugin import (
    ENTRY_POINT_GROUP,
    ENV_VAR,
    Effect,
    Evidence,
    Signature,
    discover_effects,
    register_effect,
    registered_effects,
)
from artitwin_core.diagnostics._report import render_html, write_html_report
from artitwin_core.diagnostics._residuals import (
    TARGETS,
    ResidualData,
    TrackModel,
    make_residual_data,
    noise_floor,
    per_frame_errors,
    target_energy,
    track_model_from_joint,
)
from artitwin_core.diagnostics._runs import RunComparison, RunRecord, compare_runs, comparison_html

__all__ = [
    "RunComparison",
    "RunRecord",
    "compare_runs",
    "comparison_html",
    "ENTRY_POINT_GROUP",
    "ENV_VAR",
    "ERROR_OF_TARGET",
    "TARGETS",
    "AxisTilt",
    "CaptureQuality",
    "DepthNoise",
    "DepthScaleOffset",
    "DiagnoseConfig",
    "FrameComparison",
    "Diagnosis",
    "DrawerTilt",
    "Effect",
    "Evidence",
    "ExposureWhiteBalance",
    "HeldOut",
    "HeldOutCheck",
    "LensDistortion",
    "PoseDrift",
    "ResidualData",
    "RollingShutter",
    "ScrewJoint",
    "Signature",
    "Structure",
    "TimeOffset",
    "TrackModel",
    "Vignetting",
    "capture_quality",
    "compare_frames",
    "diagnose",
    "discover_effects",
    "evaluate_heldout",
    "image_velocity",
    "make_residual_data",
    "noise_floor",
    "per_frame_errors",
    "register_effect",
    "registered_effects",
    "render_html",
    "target_energy",
    "track_model_from_joint",
    "write_html_report",
]
