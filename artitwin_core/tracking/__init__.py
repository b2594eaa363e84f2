"""Point tracking: 2D tracks of a moving part's points through a recording, lifted to 3D world points.

``track_part_points(capture, part_masks, canonical_from_session)`` is the entry point; it gives
``Trajectories`` for ``artitwin_core.joints.estimate_joint``. ``lift_pixels`` turns RGB pixels of
one frame into world points with the frame's depth (lower resolution than RGB is fine).
``estimate_frame_poses`` measures each frame's pose error on the recording's static background,
which the tracks would otherwise carry into the joint.
"""

from artitwin_core.tracking._config import FramePoseConfig, TrackingConfig
from artitwin_core.tracking._frame_poses import FramePoseFit, estimate_frame_poses
from artitwin_core.tracking._lift import lift_pixels
from artitwin_core.tracking._metrics import track_errors_m, true_track_positions
from artitwin_core.tracking._track import track_part_points
from artitwin_core.tracking._types import Trajectories

__all__ = [
    "FramePoseConfig",
    "FramePoseFit",
    "TrackingConfig",
    "Trajectories",
    "estimate_frame_poses",
    "lift_pixels",
    "track_errors_m",
    "track_part_points",
    "true_track_positions",
]
