"""Where the core's progress reports go (``artitwin_core.progress``).

- :class:`LineSink`: plain lines for logs, CI and workers (output that is not a terminal): one when
  a stage starts, one when it ends, and a step count at most every ``every_s`` seconds.
- :class:`RichSink`: a rich progress display on a terminal: a spinner per running stage, a bar per
  loop with steps.
- :class:`PrefectSink`: each loop with steps inside a Prefect task run becomes a progress artifact
  in the Prefect UI, updated at most every ``every_s`` seconds.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any, TextIO

from artitwin_core import ProgressTask, add_sink, remove_sink


def _eta(task: ProgressTask) -> str:
    if not task.total or task.done <= 0:
        return ""
    left = task.elapsed_s * (task.total - task.done) / task.done
    return f", ~{left:.0f} s left"


class LineSink:
    """Timestamped lines on ``stream`` (default stderr); step counts at most every ``every_s`` seconds per task."""

    def __init__(self, stream: TextIO | None = None, every_s: float = 10.0) -> None:
        self.stream = stream
        self.every_s = every_s
        self._last: dict[int, float] = {}
        self._lock = threading.Lock()

    def __enter__(self) -> LineSink:
        add_sink(self)
        return self

    def __exit__(self, *exc) -> None:
        remove_sink(self)

    def _write(self, text: str) -> None:
        stream = self.stream or sys.stderr
        with self._lock:
            stream.write(f"{time.strftime('%H:%M:%S')} {text}\n")
            stream.flush()

    def start(self, task: ProgressTask) -> None:
        self._last[id(task)] = time.monotonic()
        if task.total is None:
            self._write(f"{task.name} ...")
        else:
            self._write(f"  {task.name}: {task.total} steps")

    def update(self, task: ProgressTask) -> None:
        now = time.monotonic()
        if now - self._last.get(id(task), 0.0) < self.every_s:
            return
        self._last[id(task)] = now
        total = f"/{task.total} ({100 * task.done / task.total:.0f} %)" if task.total else ""
        info = f", {task.info}" if task.info else ""
        self._write(f"  {task.name}: {task.done}{total}, {task.elapsed_s:.0f} s{_eta(task)}{info}")

    def finish(self, task: ProgressTask, status: str) -> None:
        self._last.pop(id(task), None)
        what = f"{task.name}" if task.total is None else f"  {task.name}: {task.done} steps"
        self._write(f"{what} {status} in {task.elapsed_s:.1f} s")


class RichSink:
    """A live rich progress display (a terminal): spinners for stages, bars for loops with steps."""

    def __init__(self, console: Any = None) -> None:
        from rich.progress import (
            BarColumn,
            Progress,
            SpinnerColumn,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.progress = Progress(
            SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
            TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=False,
        )  # fmt: skip
        self._ids: dict[int, Any] = {}
        self._lock = threading.Lock()

    def __enter__(self) -> RichSink:
        self.progress.start()
        add_sink(self)
        return self

    def __exit__(self, *exc) -> None:
        remove_sink(self)
        self.progress.stop()

    def start(self, task: ProgressTask) -> None:
        with self._lock:
            self._ids[id(task)] = self.progress.add_task(task.name, total=task.total)

    def update(self, task: ProgressTask) -> None:
        tid = self._ids.get(id(task))
        if tid is not None:
            self.progress.update(tid, completed=task.done)

    def finish(self, task: ProgressTask, status: str) -> None:
        with self._lock:
            tid = self._ids.pop(id(task), None)
        if tid is None:
            return
        if task.total is None:
            self.progress.update(tid, total=1, completed=1, description=f"{task.name} {status} in {task.elapsed_s:.1f} s")
        else:
            self.progress.remove_task(tid)


class PrefectSink:
    """Loops with steps inside a Prefect task run as progress artifacts (the Prefect UI's step counts)."""

    def __init__(self, every_s: float = 5.0) -> None:
        self.every_s = every_s
        self._artifacts: dict[int, tuple[Any, float]] = {}

    @staticmethod
    def _in_task() -> bool:
        from prefect.context import TaskRunContext

        return TaskRunContext.get() is not None

    def start(self, task: ProgressTask) -> None:
        if task.total is None or not self._in_task():
            return
        from prefect.artifacts import create_progress_artifact

        try:
            aid = create_progress_artifact(progress=0.0, description=f"{task.name}: {task.total} steps")
        except Exception:  # noqa: BLE001 -- the UI's progress must never fail a stage
            return
        self._artifacts[id(task)] = (aid, time.monotonic())

    def update(self, task: ProgressTask) -> None:
        entry = self._artifacts.get(id(task))
        if entry is None or time.monotonic() - entry[1] < self.every_s:
            return
        self._artifacts[id(task)] = (entry[0], time.monotonic())
        self._set(task, entry[0])

    def finish(self, task: ProgressTask, status: str) -> None:
        entry = self._artifacts.pop(id(task), None)
        if entry is not None:
            self._set(task, entry[0])

    @staticmethod
    def _set(task: ProgressTask, aid: Any) -> None:
        from prefect.artifacts import update_progress_artifact

        try:
            update_progress_artifact(aid, progress=100.0 * task.done / max(task.total or 1, 1))
        except Exception:  # noqa: BLE001 -- the UI's progress must never fail a stage
            pass


def terminal_sink(stream: TextIO | None = None) -> LineSink | RichSink:
    """A :class:`RichSink` when ``stream`` (default stderr) is a terminal, else a :class:`LineSink`."""
    stream = stream or sys.stderr
    if stream.isatty():
        from rich.console import Console

        return RichSink(Console(file=stream))
    return LineSink(stream)
