"""What became of each candidate part."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

Fate = Literal["kept", "merged", "dropped"]
FATES: tuple[Fate, ...] = get_args(Fate)


@dataclass(frozen=True)
class PartFate:
    """One candidate part's fate.

    Candidates are the surfaces the part finder saw vanish from the canonical model, numbered in
    the order it found them (onset order). Those it labels in the dynamic frames get mask labels
    ``1..M`` in the part-mask artifact; the final parts are numbered again (joint ``k``, final
    mask label ``k + 1``, export link ``part_k``) once every candidate has been decided.

    Attributes:
        candidate: the candidate's index in the part finder's list.
        fate: ``"kept"`` (a part with a joint of its own), ``"merged"`` (its pixels belong to the
            part whose motion explains them) or ``"dropped"`` (not a moving part).
        stage: the pipeline stage that decided (``part_masks``, ``fit_joints``, ``settle_parts``).
        reason: why, in words with the numbers that decided; empty when kept on its tracks' joint
            (kept on the part finder's joint: why, with the depth's evidence).
        into: merged: the candidate it joined; else None.
        part: the final part it is (kept) or belongs to (merged); None when dropped or not yet
            settled.
        label: its mask label in the part-mask artifact (0: never labelled).
    """

    candidate: int
    fate: Fate
    stage: str
    reason: str = ""
    into: int | None = None
    part: int | None = None
    label: int = 0

    def __post_init__(self) -> None:
        if self.fate not in FATES:
            raise ValueError(f"PartFate.fate is {self.fate!r}; use one of {FATES}")
