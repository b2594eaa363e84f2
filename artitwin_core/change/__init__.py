"""Change detection against the canonical model, and part / hand masks of the dynamic frames.

``detect_changes`` compares an observed RGB-D frame with the canonical model rendered at its
pose (any renderer). ``build_canonical_tsdf`` gives a geometric canonical model that needs no
training. ``segment_parts`` runs the default, weight-free mask backend: moved parts from the
vanished canonical surface (``segment_part_at_frame``), labelled backwards through the recording
(``propagate_masks_backwards``). ``propagate_masks_sam2`` is the optional SAM2 backend.
``summarize_masks`` and ``mask_overlay`` make the change report's curves and images.
"""

from artitwin_core.change._canonical import CanonicalMesh, build_canonical_tsdf
from artitwin_core.change._config import ChangeConfig, PartConfig
from artitwin_core.change._detect import ChangeMaps, detect_changes
from artitwin_core.change._label import fill_depth_by_colour
from artitwin_core.change._report import (
    HAND_COLOUR,
    PART_COLOURS,
    ChangeSummary,
    mask_overlay,
    summarize_masks,
)
from artitwin_core.change._sam2 import propagate_masks_sam2
from artitwin_core.change._segment import (
    PartSegmentation,
    propagate_masks_backwards,
    segment_part_at_frame,
    segment_parts,
)
from artitwin_core.change._vanish import find_moved_parts
from artitwin_core.change._views import FrameView, PartModel, frame_views

__all__ = [
    "HAND_COLOUR",
    "PART_COLOURS",
    "fill_depth_by_colour",
    "CanonicalMesh",
    "ChangeConfig",
    "ChangeMaps",
    "ChangeSummary",
    "FrameView",
    "PartConfig",
    "PartModel",
    "PartSegmentation",
    "build_canonical_tsdf",
    "detect_changes",
    "find_moved_parts",
    "frame_views",
    "mask_overlay",
    "propagate_masks_backwards",
    "propagate_masks_sam2",
    "segment_part_at_frame",
    "segment_parts",
    "summarize_masks",
]
