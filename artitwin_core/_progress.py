"""Progress of long-running work, reported to whatever sinks the application installed.

The core only says what it is doing (``with progress("3DGS training", total=steps) as p:
p.advance()``); where that goes is the application's choice (the CLI draws a progress bar on a
terminal and writes periodic lines otherwise, a Prefect task updates a progress artifact). With
no sink installed, reporting costs one attribute lookup per update.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Protocol


@dataclass
class ProgressTask:
    """One unit of reported work. ``total`` is None for work without steps (a stage, say)."""

    name: str
    total: int | None = None
    done: int = 0
    started: float = field(default_factory=time.monotonic)
    info: str = ""

    @property
    def elapsed_s(self) -> float:
        return time.monotonic() - self.started


class ProgressSink(Protocol):
    """Receives every task's start, updates and end (from any thread)."""

    def start(self, task: ProgressTask) -> None: ...

    def update(self, task: ProgressTask) -> None: ...

    def finish(self, task: ProgressTask, status: str) -> None: ...


_SINKS: list[ProgressSink] = []
_LOCK = threading.Lock()


def add_sink(sink: ProgressSink) -> None:
    with _LOCK:
        _SINKS.append(sink)


def remove_sink(sink: ProgressSink) -> None:
    with _LOCK:
        if sink in _SINKS:
            _SINKS.remove(sink)


class _Reporter:
    def __init__(self, task: ProgressTask) -> None:
        self.task = task

    def advance(self, steps: int = 1, info: str = "") -> None:
        self.task.done += steps
        if info:
            self.task.info = info
        for sink in list(_SINKS):
            sink.update(self.task)

    def set(self, done: int, info: str = "") -> None:
        self.advance(done - self.task.done, info)


@contextmanager
def progress(name: str, total: int | None = None) -> Iterator[_Reporter]:
    """Report the work ``name`` (``total`` steps, or None) to the installed sinks while in the block."""
    task = ProgressTask(name, total)
    for sink in list(_SINKS):
        sink.start(task)
    status = "failed"
    try:
        yield _Reporter(task)
        status = "done"
    finally:
        for sink in list(_SINKS):
            sink.finish(task, status)
