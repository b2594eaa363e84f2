"""Running one stage through the store: key, get-or-compute, timing.

This is the caching mechanism every flow uses. A stage's output key hashes the stage identity,
its config and the keys of its inputs (see ``infra.store.stage_key``); if the store has the key the
stage function is not called. Inputs and outputs are passed as references (keys), never arrays.
"""

from __future__ import annotations

import json
import os
import threading
import time
import traceback
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from artitwin_core import ArtiTwinError, TransientError, progress
from infra.store import ArtifactStore, library_versions, manifest_key, stage_key
from schemas import Artifact, StageConfig
from tasks import STAGES, Stage

# Lease time-to-live when the caller gives none: how long a dead worker's claim on a key blocks
# others. Tests and small clusters shorten it through the environment.
DEFAULT_LEASE_TTL_S = 120.0


@dataclass(frozen=True)
class RawInput:
    """A user file or folder given to a stage, identified by the hash of its contents."""

    path: str
    key: str


@dataclass(frozen=True)
class StageRun:
    """What running a stage produced: a reference to its output and how it got there."""

    stage: str
    label: str
    key: str
    kind: str
    status: str  # "computed" or "cached"
    seconds: float


@dataclass(frozen=True)
class StageFailure:
    """A stage that produced no output: it raised (``failed``), or an input's stage did not
    complete so it never ran (``skipped``). A scene run collects these beside its ``StageRun`` s
    and still writes its summary (``flows._pipeline.build_summary``)."""

    stage: str
    label: str
    status: str  # "failed" or "skipped"
    error: str  # "ExceptionType: message" (failed), or which input was missing (skipped)
    seconds: float = 0.0
    traceback: str = ""  # the innermost frames of an unexpected exception (a bug, not bad input)

    @staticmethod
    def of(stage: str, label: str, error: BaseException, seconds: float = 0.0) -> StageFailure:
        """The failure of ``stage`` that raised ``error``; a traceback is kept unless the error is
        one the project raises on purpose (``ArtiTwinError``: its message says what to do)."""
        tb = "" if isinstance(error, ArtiTwinError) else "".join(traceback.format_exception(error, limit=-4))
        return StageFailure(stage, label, "failed", f"{type(error).__name__}: {error}", seconds, tb)


def raw_input(path: str | Path, files: list[Path]) -> RawInput:
    """Reference a raw recording by the manifest of its ``files``."""
    key, _ = manifest_key(Path(path), files)
    return RawInput(str(path), key)


def input_ref(value: RawInput | StageRun) -> str:
    return value.key


def output_key(stage: Stage, config: StageConfig, inputs: dict[str, RawInput | StageRun]) -> tuple[str, dict]:
    missing = set(stage.inputs) - set(inputs)
    if missing:
        raise TypeError(f"stage {stage.name!r} is missing inputs {sorted(missing)}")
    return stage_key(
        stage=stage.name,
        stage_version=stage.version,
        schema_kind=stage.output_type.kind,
        schema_version=stage.output_type.schema_version,
        config=config.model_dump(mode="json"),
        inputs={name: input_ref(v) for name, v in inputs.items()},
        libraries=library_versions(),
    )


def run_stage(
    store: ArtifactStore,
    stage: Stage,
    config: StageConfig,
    inputs: dict[str, RawInput | StageRun],
    *,
    label: str = "",
    lease_ttl_s: float | None = None,
) -> StageRun:
    """Return the stage's output reference, computing it only if the store lacks it."""
    if not isinstance(config, stage.config_type):
        raise TypeError(f"stage {stage.name!r} takes a {stage.config_type.__name__}, got {type(config).__name__}")
    if lease_ttl_s is None:
        lease_ttl_s = float(os.environ.get("ARTITWIN_LEASE_TTL_S", DEFAULT_LEASE_TTL_S))
    key, record = output_key(stage, config, inputs)
    record = {**record, "label": label}
    start = time.perf_counter()

    def compute() -> Artifact:
        inject_faults(stage.name, label, inputs)
        args: dict[str, Any] = {}
        for name, ref in inputs.items():
            if name in stage.raw_inputs:
                args[name] = Path(ref.path)
            else:
                args[name] = store.get(ref.key, _input_type(stage, name))
        with progress(f"{stage.name}[{label}]" if label else stage.name):
            out = stage.fn(**args, config=config)
        if not isinstance(out, stage.output_type):
            raise TypeError(f"stage {stage.name!r} returned {type(out).__name__}, expected {stage.output_type.__name__}")
        return out

    try:
        _, hit = store.get_or_compute(key, compute, record=record, lease_ttl_s=lease_ttl_s)
    except Exception as e:
        store.record_failure(key, f"{type(e).__name__}: {e}", record)
        raise
    return StageRun(
        stage=stage.name,
        label=label,
        key=key,
        kind=stage.output_type.kind,
        status="cached" if hit else "computed",
        seconds=time.perf_counter() - start,
    )


def inject_faults(stage_name: str, label: str, inputs: dict[str, RawInput | StageRun]) -> None:
    """Documented fault injection for failure drills (docs/scaling.md); a no-op unless
    ``$ARTITWIN_FAULTS`` names a directory.

    Each ``*.json`` file there is one fault: ``{"stage": ..., "label": ..., "path_contains": ...,
    "action": "transient" | "fail" | "hold", "until": FILE, "timeout_s": S}`` (all match fields
    optional). The first computation that matches claims the file by renaming it (exactly one
    process wins, so a fault fires once across workers), then raises a ``TransientError``, raises a
    ``RuntimeError`` (``fail``), or holds, under the key's lease, until ``until`` exists.
    """
    folder = os.environ.get("ARTITWIN_FAULTS")
    if not folder or not os.path.isdir(folder):
        return
    paths = " ".join(v.path for v in inputs.values() if isinstance(v, RawInput))
    for name in sorted(os.listdir(folder)):
        if not name.endswith(".json"):
            continue
        spec_path = os.path.join(folder, name)
        try:
            with open(spec_path) as f:
                spec = json.load(f)
        except (OSError, ValueError):
            continue
        if spec.get("stage", stage_name) != stage_name or spec.get("label", label) != label:
            continue
        if spec.get("path_contains", "") not in paths:
            continue
        try:
            os.rename(spec_path, f"{spec_path}.fired-{os.getpid()}")
        except FileNotFoundError:
            continue  # another process claimed it
        if spec.get("action", "transient") == "hold":
            deadline = time.monotonic() + float(spec.get("timeout_s", 300))
            while not os.path.exists(spec["until"]) and time.monotonic() < deadline:
                time.sleep(0.1)
            return
        if spec.get("action") == "fail":
            raise RuntimeError(f"injected failure in {stage_name}[{label}] ({name})")
        raise TransientError(f"injected transient fault in {stage_name}[{label}] ({name})")


def _input_type(stage: Stage, name: str) -> type[Artifact]:
    import inspect
    import typing

    hints = typing.get_type_hints(stage.fn)
    hint = hints.get(name, Artifact)
    return hint if inspect.isclass(hint) and issubclass(hint, Artifact) else Artifact


class Executor(Protocol):
    """Runs stages for a pipeline: inline (tests, scripts) or as Prefect tasks (flows)."""

    def submit(self, stage_name: str, config: StageConfig, inputs: dict[str, Any], label: str) -> Any: ...

    def result(self, handle: Any) -> StageRun: ...


class PlanExecutor:
    """Computes every stage's key and whether the store has it, without running anything.

    Keys depend only on raw-input manifests, configs and stage identities, so the whole plan of
    a scene is known before any stage runs (``artitwin status`` uses this).
    """

    def __init__(self, store: ArtifactStore) -> None:
        self.store = store

    def submit(self, stage_name: str, config: StageConfig, inputs: dict[str, Any], label: str) -> StageRun:
        stage = STAGES[stage_name]
        key, _ = output_key(stage, config, inputs)
        if self.store.has(key):
            status = "cached"
        elif self.store.failure(key) is not None:
            status = "failed"
        else:
            status = "missing"
        return StageRun(stage=stage_name, label=label, key=key, kind=stage.output_type.kind, status=status, seconds=0.0)

    def result(self, handle: StageRun) -> StageRun:
        return handle


class InlineExecutor:
    """Runs each stage immediately in this process, no Prefect involved.

    A stage that raises becomes a ``StageFailure`` handle instead of an exception, and every stage
    that needs its output is skipped: the rest of the scene runs and the summary says what failed."""

    def __init__(self, store: ArtifactStore) -> None:
        self.store = store

    def submit(self, stage_name: str, config: StageConfig, inputs: dict[str, Any], label: str) -> StageRun | StageFailure:
        missing = [v for v in inputs.values() if isinstance(v, StageFailure)]
        if missing:
            return skipped(stage_name, label, missing[0])
        start = time.perf_counter()
        try:
            return run_stage(self.store, STAGES[stage_name], config, inputs, label=label)
        except Exception as e:  # noqa: BLE001 (a failed stage is reported, not raised: see the class)
            return StageFailure.of(stage_name, label, e, time.perf_counter() - start)

    def result(self, handle: StageRun | StageFailure) -> StageRun | StageFailure:
        return handle


class ParallelExecutor:
    """Runs stages in ``workers`` threads of this process as soon as their inputs are ready, no
    Prefect involved: independent branches of a scene (the static 3DGS beside the dynamic
    recording's registration, masks and tracks) overlap, as under Prefect's task runner.

    Handles are futures; a stage whose input failed is skipped, as :class:`InlineExecutor` does
    (``inline`` runs each stage, and may be replaced by another executor of the same kind, e.g. one
    that times them). The stages' numerics release the GIL for most of their time (torch, numba,
    OpenCV, COLMAP)."""

    def __init__(self, store: ArtifactStore, workers: int = 2) -> None:
        self.inline: Any = InlineExecutor(store)
        self.pool = ThreadPoolExecutor(max_workers=max(1, int(workers)), thread_name_prefix="stage")

    def submit(self, stage_name: str, config: StageConfig, inputs: dict[str, Any], label: str) -> Future:
        deps = [v for v in inputs.values() if isinstance(v, Future)]

        def run() -> StageRun | StageFailure:
            ready = {k: v.result() if isinstance(v, Future) else v for k, v in inputs.items()}
            return self.inline.submit(stage_name, config, ready, label)

        if not deps:
            return self.pool.submit(run)
        # A stage waits for its inputs without holding a worker: it is queued when the last one ends.
        out: Future = Future()
        left = [len(deps)]
        lock = threading.Lock()

        def one_done(_done: Future) -> None:
            with lock:
                left[0] -= 1
                if left[0]:
                    return
            self.pool.submit(run).add_done_callback(lambda f: _relay(f, out))

        for d in deps:
            d.add_done_callback(one_done)
        return out

    def result(self, handle: Future) -> StageRun | StageFailure:
        return handle.result()

    def shutdown(self) -> None:
        self.pool.shutdown(wait=True)


def _relay(done: Future, out: Future) -> None:
    exc = done.exception()
    if exc is not None:
        out.set_exception(exc)
    else:
        out.set_result(done.result())


def skipped(stage_name: str, label: str, cause: StageFailure) -> StageFailure:
    """``stage_name`` not run because the stage of one of its inputs did not complete."""
    origin = cause.error if cause.status == "skipped" else f"{cause.stage} failed"
    return StageFailure(stage_name, label, "skipped", origin if origin.startswith("not run") else f"not run: {origin}")
