"""Many scenes: the per-scene deployment's flow, the nightly dataset fan-out, and dataset planning.

A dataset is a folder of scene folders. A scene's *capture key* hashes the manifests of its two
recordings and the pipeline config: two submissions with the same key would compute the same
artifacts, so the queue runs only one of them. Planning (which stages the store already holds)
computes keys without running anything, so a nightly pass over an unchanged dataset submits
nothing and computes nothing.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from prefect import flow, get_run_logger
from prefect.deployments import run_deployment
from prefect.runtime import flow_run
from prefect.task_runners import ThreadPoolTaskRunner

from artitwin_core import ArtiTwinError
from artitwin_core.capture import find_scene_recordings, recording_files
from flows._env import default_store_url
from flows._pipeline import PipelineHandles, scene_pipeline
from flows._runner import Executor, PlanExecutor, StageRun, raw_input
from flows.scene import PrefectExecutor, finish_scene
from infra.store import ArtifactStore, canonical_json
from schemas import PipelineConfig

SCENE_DEPLOYMENT = "process-scene/scene"
Stages = list[str] | None  # stage names to run (None: all); a stage runs if listed and all its inputs ran
NIGHTLY_DEPLOYMENT = "nightly-dataset/nightly"


class SelectedExecutor:
    """Submits only the listed stages to ``inner``; a stage whose input was not submitted is
    skipped too (its handle is None). Quick checks and the queue tests run the capture stages only."""

    def __init__(self, inner: Executor, stages: Stages = None) -> None:
        self.inner, self.stages = inner, None if stages is None else set(stages)

    def submit(self, stage_name: str, config: Any, inputs: dict[str, Any], label: str) -> Any:
        if self.stages is not None and (stage_name not in self.stages or any(v is None for v in inputs.values())):
            return None
        return self.inner.submit(stage_name, config, inputs, label)

    def result(self, handle: Any) -> StageRun:
        return self.inner.result(handle)


def select_pipeline(scene: str | Path, config: PipelineConfig, ex: Executor, stages: Stages = None) -> PipelineHandles:
    """``scene_pipeline`` restricted to ``stages``: handles by ``stage/label`` of what was submitted."""
    handles = scene_pipeline(scene, config, SelectedExecutor(ex, stages))
    out = PipelineHandles({name: h for name, h in handles.items() if h is not None})
    out.static_capture = handles.static_capture
    return out


@dataclass(frozen=True)
class StageState:
    """One stage of one scene: ``cached``, ``failed`` (with the recorded error) or ``missing``."""

    name: str  # "stage/label", as in summary.json
    key: str
    state: str
    error: str = ""


@dataclass(frozen=True)
class SceneStatus:
    """A scene folder and its stages; ``error`` is set when the folder itself is unusable."""

    scene: Path
    stages: tuple[StageState, ...] = ()
    error: str = ""

    @property
    def up_to_date(self) -> bool:
        return not self.error and all(s.state == "cached" for s in self.stages)


def list_scenes(dataset: str | Path) -> list[Path]:
    """The scene folders of ``dataset`` (its non-hidden sub-folders), sorted by name."""
    root = Path(dataset)
    if not root.is_dir():
        raise ArtiTwinError(f"dataset folder {root} does not exist; give a folder of scene folders")
    return sorted(p.resolve() for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))


def capture_key(scene: str | Path, config: PipelineConfig | None = None) -> str:
    """SHA-256 of the scene's recordings (file manifests) and the pipeline config."""
    rec = find_scene_recordings(Path(scene))
    parts = {
        "static": raw_input(rec.static, recording_files(rec.static)).key,
        "dynamic": raw_input(rec.dynamic, recording_files(rec.dynamic)).key,
        "config": (config or PipelineConfig()).model_dump(mode="json"),
    }
    return hashlib.sha256(canonical_json(parts).encode()).hexdigest()


def scene_plan(scene: str | Path, store: ArtifactStore, config: PipelineConfig | None = None, stages: Stages = None) -> dict[str, StageRun]:
    """Every stage's output key and store state (cached / failed / missing) for ``scene``."""
    return select_pipeline(scene, config or PipelineConfig(), PlanExecutor(store), stages)


def scene_status(scene: str | Path, store: ArtifactStore, config: PipelineConfig | None = None, stages: Stages = None) -> SceneStatus:
    try:
        plan = scene_plan(scene, store, config, stages)
    except ArtiTwinError as e:
        return SceneStatus(Path(scene), error=str(e))
    rows = []
    for name, run in plan.items():
        failure = store.failure(run.key) if run.status == "failed" else None
        rows.append(StageState(name, run.key, run.status, (failure or {}).get("error", "")))
    return SceneStatus(Path(scene), tuple(rows))


def dataset_status(dataset: str | Path, store: ArtifactStore, config: PipelineConfig | None = None, stages: Stages = None) -> list[SceneStatus]:
    """The status of every scene in ``dataset`` (what ``artitwin status`` prints)."""
    return [scene_status(s, store, config, stages) for s in list_scenes(dataset)]


def make_task_runner(spec: str = "threads") -> Any:
    """The task runner for stages inside one scene.

    ``"threads"``: Prefect's thread pool (``$ARTITWIN_THREADS`` workers, default 4). ``"dask"``: a
    local Dask cluster of ``$ARTITWIN_DASK_WORKERS`` single-threaded processes (default 2), which
    sidesteps the GIL for Python-heavy stages. ``"tcp://host:8786"``: an existing Dask scheduler,
    so one scene's stages spread over a Dask cluster.
    """
    if spec == "threads":
        return ThreadPoolTaskRunner(max_workers=int(os.environ.get("ARTITWIN_THREADS", "4")))
    from prefect_dask import DaskTaskRunner

    if spec == "dask":
        n = int(os.environ.get("ARTITWIN_DASK_WORKERS", "2"))
        return DaskTaskRunner(cluster_kwargs={"n_workers": n, "threads_per_worker": 1, "processes": True, "dashboard_address": None})
    if spec.startswith(("tcp://", "tls://")):
        return DaskTaskRunner(address=spec)
    raise ArtiTwinError(f"unknown task runner {spec!r}: use 'threads', 'dask' or a Dask scheduler address tcp://host:port")


@flow(name="scene-stages", log_prints=True)
def scene_stages(scene: str, config: PipelineConfig, store: str, out: str | None = None, stages: Stages = None) -> dict[str, Any]:
    """``reconstruct_scene`` restricted to ``stages``: one Prefect task per stage, cached in the store."""
    started = time.time()
    ex = PrefectExecutor(store)
    handles = select_pipeline(scene, config, ex, stages)
    return finish_scene(scene, config, ex, handles, ArtifactStore(store), started, out or None, exports=False)


@flow(name="process-scene", log_prints=True)
def process_scene(
    scene: str,
    store: str | None = None,
    config: dict[str, Any] | None = None,
    out: str | None = None,
    task_runner: str = "threads",
    stages: Stages = None,
) -> dict[str, Any]:
    """The per-scene deployment: the scene's stages with a chosen task runner; returns the summary."""
    cfg = PipelineConfig.model_validate(config or {})
    inner = scene_stages.with_options(task_runner=make_task_runner(task_runner))
    return inner(scene, cfg, store or default_store_url(), out, stages)


@flow(name="nightly-dataset", log_prints=True)
def nightly(
    dataset: str,
    store: str | None = None,
    config: dict[str, Any] | None = None,
    out: str | None = None,
    force: bool = False,
    queue: str = "nightly",
    deployment: str = SCENE_DEPLOYMENT,
    stages: Stages = None,
) -> dict[str, Any]:
    """Reprocess a dataset: one ``process-scene`` run per scene whose plan has anything missing.

    Scenes whose every stage is already in the store (inputs, config and code unchanged) are
    reported ``up to date`` and not submitted. Runs are submitted without waiting, so the nightly
    run holds a worker slot only while it plans. Writes ``out/nightly.json`` when ``out`` is given.
    """
    log = get_run_logger()
    st = ArtifactStore(store or default_store_url())
    cfg = PipelineConfig.model_validate(config or {})
    report: dict[str, Any] = {}
    for status in dataset_status(dataset, st, cfg, stages):
        name = status.scene.name
        if status.error:
            report[name] = {"state": "unusable", "error": status.error}
            log.warning("%s: %s", name, status.error)
            continue
        states = {s.name: s.state for s in status.stages}
        if status.up_to_date and not force:
            report[name] = {"state": "up to date", "stages": states}
            continue
        params = {"scene": str(status.scene), "store": st.url, "config": cfg.model_dump(mode="json"), "out": f"{out}/{name}" if out else None, "stages": stages}
        run = run_deployment(
            deployment,
            parameters=params,
            timeout=0,
            work_queue_name=queue,
            as_subflow=True,
            idempotency_key=f"nightly:{flow_run.get_id()}:{capture_key(status.scene, cfg)}",
            tags=["nightly"],
        )
        report[name] = {"state": "submitted", "flow_run_id": str(run.id), "stages": states}
        log.info("%s: submitted %s (%d stage(s) to compute)", name, run.id, sum(v != "cached" for v in states.values()))
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "nightly.json").write_text(json.dumps({"dataset": str(Path(dataset).resolve()), "scenes": report}, indent=2))
    return report


__all__ = [
    "NIGHTLY_DEPLOYMENT",
    "SCENE_DEPLOYMENT",
    "SceneStatus",
    "StageState",
    "capture_key",
    "dataset_status",
    "list_scenes",
    "make_task_runner",
    "nightly",
    "process_scene",
    "SelectedExecutor",
    "scene_plan",
    "scene_stages",
    "scene_status",
    "select_pipeline",
]
