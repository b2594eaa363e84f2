"""Part and hand masks over the frames of a recording."""

from artitwin_core.masks._types import MaskSequence

__all__ = ["MaskSequence"]
