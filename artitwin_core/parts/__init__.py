"""Candidate parts and their fates: which of the part finder's candidates are parts.

``settle_parts`` decides, once each candidate's tracks and joint fit are known, whether it is
kept (a part with a joint of its own), merged into the part whose motion explains it, or dropped
with the reason (``PartFate``); ``relabel`` applies the decision to the masks.
``prefer_depth_joint`` says whether the part finder's joint, fitted to the change in depth,
should replace an unsure joint fitted to the tracks.
"""

from artitwin_core.parts._config import SettleConfig
from artitwin_core.parts._second import depth_misfit, prefer_depth_joint, uncertain_joint
from artitwin_core.parts._settle import PartDecision, relabel, settle_parts
from artitwin_core.parts._types import FATES, Fate, PartFate

__all__ = [
    "FATES",
    "Fate",
    "PartDecision",
    "PartFate",
    "SettleConfig",
    "depth_misfit",
    "prefer_depth_joint",
    "relabel",
    "settle_parts",
    "uncertain_joint",
]
