"""Conversion between core dataclasses and schema artifacts, by field name.

Schemas mirror the core dataclasses field for field, so one generic converter serves every pair;
a field present on only one side must be given explicitly (``extra``) or has a default.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from schemas import Artifact

A = TypeVar("A", bound=Artifact)
T = TypeVar("T")


def to_artifact(cls: type[A], obj: Any, **extra: Any) -> A:
    """Build artifact ``cls`` from the same-named fields of dataclass ``obj`` (plus ``extra``)."""
    values = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.name in cls.model_fields}
    values.update(extra)
    return cls(**values)


def to_core(cls: type[T], artifact: Artifact, **extra: Any) -> T:
    """Build core dataclass ``cls`` from the same-named fields of ``artifact`` (plus ``extra``)."""
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    values = {n: getattr(artifact, n) for n in names if n in type(artifact).model_fields}
    values.update(extra)
    return cls(**values)
