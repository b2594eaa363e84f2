"""Part and hand masks over the frames of a recording."""

from artitwin_core.masks._types import MaskSequence, downscale_masks

__all__ = ["MaskSequence", "downscale_masks"]
