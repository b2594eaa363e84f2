"""Stage descriptors: a pure function plus the identity the store keys it by.

A stage function takes typed artifacts (by parameter name) and a config, and returns one typed
artifact. It does no I/O of its own beyond reading raw input files it is handed. The descriptor
adds what orchestration needs to know without touching the function: its name, its explicit
version (bump it whenever the output could change for the same inputs and config), its config
and output types, and its inputs.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field

from schemas import Artifact, StageConfig


@dataclass(frozen=True)
class Stage:
    name: str
    version: int
    fn: Callable[..., Artifact]
    config_type: type[StageConfig]
    output_type: type[Artifact]
    raw_inputs: tuple[str, ...] = ()  # parameters that take raw input paths, not artifacts
    inputs: tuple[str, ...] = field(default=())

    def __call__(self, *args, **kwargs) -> Artifact:
        return self.fn(*args, **kwargs)


STAGES: dict[str, Stage] = {}


def stage(
    *,
    name: str,
    version: int,
    config: type[StageConfig],
    output: type[Artifact],
    raw_inputs: tuple[str, ...] = (),
) -> Callable[[Callable[..., Artifact]], Stage]:
    """Register ``fn`` as a pipeline stage. Its parameters other than ``config`` are its inputs."""

    def wrap(fn: Callable[..., Artifact]) -> Stage:
        params = [p for p in inspect.signature(fn).parameters if p != "config"]
        st = Stage(name, version, fn, config, output, tuple(raw_inputs), tuple(params))
        if name in STAGES and STAGES[name].fn.__qualname__ != fn.__qualname__:
            raise TypeError(f"stage {name!r} registered twice")
        STAGES[name] = st
        return st

    return wrap
