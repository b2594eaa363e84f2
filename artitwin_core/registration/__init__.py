"""Registration of a dynamic recording's AR-session frame onto the static (canonical) frame.

``register_recordings(static, dynamic, gravity=...)`` -> :class:`RegistrationResult`: hypotheses
from the recorded poses and a yaw sweep about the shared gravity, refined by robust point-to-plane
ICP that keeps gravity and scored by where they put the dynamic points in what the static
recording saw; then finer ICP (a tilt within the sensors' bound) and a photometric refinement
against the static images. It raises :class:`RegistrationError` when no hypothesis is
convincing, or when the refined placement lays other texture on the static surfaces than theirs
(the same shapes, other surfaces). ``fused_cloud`` and ``frame_points`` turn a capture's depth
into points, for the other stages that need them. ``estimate_session_drift`` fits a recording's
linear pose drift against the canonical model, once its moving parts are masked.
"""

from artitwin_core.registration._clouds import backproject, frame_points, fused_cloud
from artitwin_core.registration._config import RegistrationConfig, SessionDriftConfig
from artitwin_core.registration._drift import SessionDrift, estimate_session_drift
from artitwin_core.registration._register import register_recordings
from artitwin_core.registration._types import (
    HypothesisScore,
    RegistrationError,
    RegistrationResult,
)

__all__ = [
    "HypothesisScore",
    "RegistrationConfig",
    "RegistrationError",
    "RegistrationResult",
    "SessionDrift",
    "SessionDriftConfig",
    "backproject",
    "estimate_session_drift",
    "frame_points",
    "fused_cloud",
    "register_recordings",
]
