"""The per-scene Prefect flow: one Prefect task per stage, cached through the artifact store."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from prefect import flow, task
from prefect.artifacts import create_markdown_artifact
from prefect.futures import PrefectFuture
from prefect.tasks import exponential_backoff

from artitwin_core import InputError, TransientError, add_sink
from flows._env import default_store_url
from flows._pipeline import (
    SceneFailed,
    finish_scene,
    hardware_preset,
    scene_pipeline,
)
from flows._progress import PrefectSink
from flows._runner import StageFailure, StageRun, run_stage, skipped
from flows._runs import rank_findings, rerun_effects
from infra.store import ArtifactStore, StoreError
from schemas import DiagnosisReport, PipelineConfig, StageConfig, StageReport
from tasks import STAGES

# Loops with steps inside a stage's task run show as progress artifacts in the Prefect UI.
add_sink(PrefectSink())

# Errors worth retrying: storage hiccups and lock contention. Bad input and bugs are not.
TRANSIENT = (TransientError, ConnectionError, TimeoutError)


def _retry_transient_only(task: Any, task_run: Any, state: Any) -> bool:
    exc = state.data if isinstance(state.data, BaseException) else None
    if exc is None:
        try:
            state.result(raise_on_failure=True)
        except BaseException as e:  # noqa: BLE001 (we only classify it)
            exc = e
    if isinstance(exc, InputError | StoreError) and not isinstance(exc, TransientError):
        return False
    return isinstance(exc, TRANSIENT)


@task(
    name="stage",
    retries=3,
    retry_delay_seconds=exponential_backoff(backoff_factor=2),
    retry_jitter_factor=0.5,
    retry_condition_fn=_retry_transient_only,
    persist_result=False,
)
def stage_task(store_url: str, stage_name: str, config: StageConfig, inputs: dict[str, Any], label: str) -> StageRun:
    return _run_and_publish(store_url, stage_name, config, inputs, label)


def _run_and_publish(store_url: str, stage_name: str, config: StageConfig, inputs: dict[str, Any], label: str) -> StageRun:
    # A module-level function, so a task runner that pickles the task body (Dask) ships a
    # reference to it; the body itself is pickled by value with its globals, which would copy
    # the stage registry and lose the stage functions' annotation namespace.
    store = ArtifactStore(store_url)
    run = run_stage(store, STAGES[stage_name], config, inputs, label=label)
    _publish_ui_artifact(store, run)
    return run


def diagnosis_markdown(report: DiagnosisReport, top: int = 8) -> list[str]:
    """The diagnosis as Markdown for the Prefect UI: the verdict, the ranked effects, what to rerun with."""
    lines = [""] + [f"- {c}" for c in report.conclusion]
    lines += ["", "| # | scope | effect | target | explained | significant | enabled |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for i, f in enumerate(rank_findings(report.findings)[:top]):
        lines.append(f"| {i + 1} | {f.scope} | {f.name} | {f.target} | {100 * f.explained_frac:.0f}% | "
                     f"{'yes' if f.significant else 'no'} | {'yes' if f.enabled else ''} |")
    modelled, _ = rerun_effects(report, [])
    if modelled:
        lines += ["", "Rerun with the effect modelled: `artitwin run SCENE " + " ".join(f"--effect {e}" for e in modelled) + "`"]
    return lines


def _publish_ui_artifact(store: ArtifactStore, run: StageRun) -> None:
    lines = [f"### {run.stage} ({run.label})", "", f"- key: `{run.key}`", f"- status: {run.status} in {run.seconds:.2f} s"]
    if run.kind == StageReport.kind:
        report = store.get(run.key, StageReport)
        lines += ["", "| metric | value |", "| --- | --- |"]
        lines += [f"| {k} | {v:.6g} |" for k, v in sorted(report.metrics.items())]
        lines += [f"- note: {n}" for n in report.notes]
    elif run.kind == DiagnosisReport.kind:
        lines += diagnosis_markdown(store.get(run.key, DiagnosisReport))
    create_markdown_artifact(
        "\n".join(lines),
        key=f"{run.stage}-{run.label}".replace("_", "-").lower(),
        description=f"{run.stage} {run.label}",
    )


class _Submitted:
    """A Prefect future with the stage it runs, so a failure can be reported by name."""

    def __init__(self, future: PrefectFuture, stage: str, label: str) -> None:
        self.future, self.stage, self.label = future, stage, label


class PrefectExecutor:
    """Submits each stage as a Prefect task; dependencies pass as futures of references.

    A stage whose input's task failed is not run by Prefect (its state is ``NotReady``); ``result``
    reports it as skipped and a failed one as failed (``StageFailure``), so the scene's summary
    still gets written."""

    def __init__(self, store_url: str) -> None:
        self.store_url = store_url

    def submit(self, stage_name: str, config: StageConfig, inputs: dict[str, Any], label: str) -> _Submitted | StageFailure:
        missing = [v for v in inputs.values() if isinstance(v, StageFailure)]
        if missing:
            return skipped(stage_name, label, missing[0])
        named = stage_task.with_options(name=stage_name, task_run_name=f"{stage_name}[{label}]")
        args = {k: v.future if isinstance(v, _Submitted) else v for k, v in inputs.items()}
        return _Submitted(named.submit(self.store_url, stage_name, config, args, label), stage_name, label)

    def result(self, handle: _Submitted | StageFailure) -> StageRun | StageFailure:
        if isinstance(handle, StageFailure):
            return handle
        try:
            return handle.future.result()
        except Exception as e:  # noqa: BLE001 (reported in the summary)
            if handle.future.state.name == "NotReady":
                return StageFailure(handle.stage, handle.label, "skipped", "not run: an input's stage did not complete")
            return StageFailure.of(handle.stage, handle.label, e)


@flow(name="reconstruct-scene", log_prints=True)
def reconstruct_scene(
    scene: str,
    config: PipelineConfig | None = None,
    store: str | None = None,
    out: str | None = None,
) -> dict[str, Any]:
    """Run every stage for the scene folder ``scene``; return (and write to ``out``) the summary.

    Raises:
        SceneFailed: a stage failed; ``summary.json`` was written all the same.
    """
    started = time.time()
    config = config or hardware_preset("default")
    store_url = store or default_store_url()
    ex = PrefectExecutor(store_url)
    handles = scene_pipeline(scene, config, ex)
    return finish_scene(scene, config, ex, handles, ArtifactStore(store_url), started, out)


def run_scene_inline(
    scene: str | Path,
    config: PipelineConfig | None = None,
    store: str | None = None,
    out: str | Path | None = None,
    workers: int = 1,
) -> dict[str, Any]:
    """The same pipeline without Prefect (scripts, benchmarks of raw stage cost); with ``out``,
    writes the exports and ``summary.json`` there as ``reconstruct_scene`` does, and like it raises
    ``SceneFailed`` when a stage failed. ``workers > 1`` runs independent stages at the same time
    in that many threads (``ParallelExecutor``), as Prefect's task runner does."""
    from flows._runner import InlineExecutor, ParallelExecutor

    started = time.time()
    st = ArtifactStore(store or default_store_url())
    ex = ParallelExecutor(st, workers) if workers > 1 else InlineExecutor(st)
    config = config or hardware_preset("default")
    try:
        return finish_scene(scene, config, ex, scene_pipeline(scene, config, ex), st, started, out)
    finally:
        if workers > 1:
            ex.shutdown()


__all__ = ["PrefectExecutor", "SceneFailed", "finish_scene", "reconstruct_scene", "run_scene_inline", "stage_task"]
