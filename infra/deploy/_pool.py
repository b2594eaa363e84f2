"""The work pool, its queues, the two deployments, and submitting scenes to them.

One process work pool (``artitwin``) with two queues: ``interactive`` (priority 1, what users
submit) and ``nightly`` (priority 10, concurrency-limited, the dataset reprocessing). A worker
polling the pool takes interactive runs first. Deployments use module-path entry points
(``flows.nightly.process_scene``), so a worker host needs only the installed package, no copy of
a source folder. Everything here talks to the server in ``PREFECT_API_URL``.
"""

from __future__ import annotations

import hashlib
import os
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from artitwin_core import ArtiTwinError
from flows.nightly import NIGHTLY_DEPLOYMENT, SCENE_DEPLOYMENT, capture_key, nightly, process_scene
from schemas import PipelineConfig

POOL = "artitwin"
FAILED_STATES = ("FAILED", "CRASHED", "CANCELLED", "CANCELLING")
FINAL_STATES = ("COMPLETED", "FAILED", "CRASHED", "CANCELLED")


@dataclass(frozen=True)
class QueueSpec:
    """A work queue of the pool: lower ``priority`` numbers are served first."""

    name: str
    priority: int
    concurrency_limit: int | None
    description: str


QUEUES = (
    QueueSpec("interactive", 1, None, "Scenes submitted by people (artitwin submit): served first."),
    QueueSpec("nightly", 10, 2, "Nightly dataset reprocessing: at most 2 scenes at once, after interactive work."),
)


@dataclass(frozen=True)
class Submission:
    """One scene handed to the queue: the flow run that will (or did) process it."""

    scene: str
    capture_key: str
    flow_run_id: str
    state: str
    reused: bool  # True when an equal submission was already queued, running or done


def require_server() -> str:
    """The API URL of the Prefect server, or an error that says how to get one."""
    from prefect.settings import PREFECT_API_URL

    url = PREFECT_API_URL.value()
    if not url:
        raise ArtiTwinError(
            "no Prefect server configured: set PREFECT_API_URL (e.g. http://127.0.0.1:4200/api) to a server "
            "started with `prefect server start` or infra/compose.yaml"
        )
    return url


def setup_pool(pool: str = POOL, *, concurrency_limit: int | None = None, queues: tuple[QueueSpec, ...] = QUEUES) -> None:
    """Create (or update) the process work pool and its queues with their priorities and limits."""
    from prefect import get_client
    from prefect.client.schemas.actions import WorkPoolCreate, WorkPoolUpdate
    from prefect.exceptions import ObjectAlreadyExists, ObjectNotFound
    from prefect.workers.process import ProcessWorker

    require_server()
    with get_client(sync_client=True) as client:
        try:
            client.create_work_pool(
                WorkPoolCreate(
                    name=pool,
                    type="process",
                    base_job_template=ProcessWorker.get_default_base_job_template(),
                    concurrency_limit=concurrency_limit,
                )
            )
        except ObjectAlreadyExists:
            client.update_work_pool(pool, WorkPoolUpdate(concurrency_limit=concurrency_limit))
        for q in queues:
            try:
                existing = client.read_work_queue_by_name(q.name, work_pool_name=pool)
            except ObjectNotFound:
                client.create_work_queue(
                    name=q.name,
                    work_pool_name=pool,
                    priority=q.priority,
                    concurrency_limit=q.concurrency_limit,
                    description=q.description,
                )
            else:
                client.update_work_queue(existing.id, priority=q.priority, concurrency_limit=q.concurrency_limit, description=q.description)


def register_deployments(
    pool: str = POOL,
    *,
    nightly_dataset: str | None = None,
    nightly_cron: str = "0 2 * * *",
    timezone: str = "UTC",
    nightly_parameters: dict[str, Any] | None = None,
) -> dict[str, str]:
    """Create or update ``process-scene/scene`` (interactive queue) and ``nightly-dataset/nightly``
    (nightly queue; scheduled by ``nightly_cron`` when ``nightly_dataset`` is given). Returns ids."""
    from prefect import get_client
    from prefect.client.schemas.actions import DeploymentScheduleCreate
    from prefect.client.schemas.schedules import CronSchedule
    from prefect.utilities.callables import parameter_schema

    require_server()
    out = {}
    specs = [
        (process_scene, SCENE_DEPLOYMENT, "interactive", "flows.nightly.process_scene", {}, []),
        (nightly, NIGHTLY_DEPLOYMENT, "nightly", "flows.nightly.nightly", {}, []),
    ]
    if nightly_dataset:
        specs[1] = (
            nightly,
            NIGHTLY_DEPLOYMENT,
            "nightly",
            "flows.nightly.nightly",
            {"dataset": str(Path(nightly_dataset).resolve()), **(nightly_parameters or {})},
            [DeploymentScheduleCreate(schedule=CronSchedule(cron=nightly_cron, timezone=timezone), active=True)],
        )
    with get_client(sync_client=True) as client:
        for fl, full_name, queue, entrypoint, params, schedules in specs:
            flow_id = client.create_flow_from_name(fl.name)
            dep_id = client.create_deployment(
                flow_id=flow_id,
                name=full_name.split("/")[1],
                entrypoint=entrypoint,
                path=None,
                pull_steps=[],
                work_pool_name=pool,
                work_queue_name=queue,
                parameters=params,
                parameter_openapi_schema=parameter_schema(fl.fn).model_dump_for_openapi(),
                enforce_parameter_schema=False,
                schedules=schedules,
                tags=["artitwin"],
                description=(fl.fn.__doc__ or "").strip().splitlines()[0],
            )
            out[full_name] = str(dep_id)
    return out


def submit_scene(
    scene: str | Path,
    *,
    queue: str = "interactive",
    store: str | None = None,
    config: PipelineConfig | None = None,
    out: str | Path | None = None,
    task_runner: str = "threads",
    force: bool = False,
    deployment: str = SCENE_DEPLOYMENT,
    stages: list[str] | None = None,
) -> Submission:
    """Queue one scene folder on the per-scene deployment, deduplicated by capture key.

    A submission whose capture key (recordings + config) and store equal those of a run that is
    scheduled, running or completed returns that run (``reused=True``) instead of a new one; a
    failed, crashed or cancelled earlier run does not block a new one. ``force`` always queues.
    ``stages`` runs only those stages (and only where their inputs ran); None runs all.
    """
    from prefect import get_client
    from prefect.client.schemas.filters import FlowRunFilter, FlowRunFilterIdempotencyKey

    require_server()
    scene = Path(scene).resolve()
    cfg = config or PipelineConfig()
    key = capture_key(scene, cfg)
    selected = ",".join(sorted(stages)) if stages is not None else "*"
    base = "scene:" + hashlib.sha256(f"{key}|{store or ''}|{selected}".encode()).hexdigest()[:40]
    params = {
        "scene": str(scene),
        "store": store,
        "config": cfg.model_dump(mode="json"),
        "out": str(Path(out).resolve()) if out else None,
        "task_runner": task_runner,
        "stages": stages,
    }
    with get_client(sync_client=True) as client:
        dep = client.read_deployment_by_name(deployment)
        for n in range(1000):
            idem = f"{base}:{uuid.uuid4().hex}" if force else (base if n == 0 else f"{base}#{n}")
            found = client.read_flow_runs(flow_run_filter=FlowRunFilter(idempotency_key=FlowRunFilterIdempotencyKey(any_=[idem])), limit=1)
            if found:
                run = found[0]
                if run.state_type is not None and run.state_type.value in FAILED_STATES:
                    continue  # a failed attempt does not stand for this capture: queue a fresh one
                return Submission(str(scene), key, str(run.id), run.state_type.value if run.state_type else "", True)
            run = client.create_flow_run_from_deployment(
                dep.id,
                parameters=params,
                idempotency_key=idem,
                work_queue_name=queue,
                tags=["artitwin", f"queue:{queue}"],
                name=f"{scene.name}-{key[:8]}",
            )
            return Submission(str(scene), key, str(run.id), run.state_type.value if run.state_type else "", False)
    raise ArtiTwinError(f"{scene}: 1000 failed runs with capture key {key[:12]}; use --force")


def submit_nightly(
    dataset: str | Path,
    *,
    store: str | None = None,
    out: str | Path | None = None,
    force: bool = False,
    stages: list[str] | None = None,
) -> str:
    """Start the nightly deployment now on ``dataset``; returns the flow run id."""
    from prefect import get_client

    require_server()
    params = {
        "dataset": str(Path(dataset).resolve()),
        "store": store,
        "out": str(Path(out).resolve()) if out else None,
        "force": force,
        "stages": stages,
    }
    with get_client(sync_client=True) as client:
        dep = client.read_deployment_by_name(NIGHTLY_DEPLOYMENT)
        run = client.create_flow_run_from_deployment(dep.id, parameters=params, tags=["artitwin", "nightly"])
    return str(run.id)


def wait_for_runs(flow_run_ids: list[str], *, timeout_s: float = 600.0, poll_s: float = 1.0) -> dict[str, str]:
    """Poll until every run is final; returns ``{id: state type}`` (``TIMEOUT`` for the rest)."""
    from prefect import get_client

    deadline = time.monotonic() + timeout_s
    states: dict[str, str] = {}
    with get_client(sync_client=True) as client:
        while True:
            for fid in flow_run_ids:
                if states.get(fid) not in FINAL_STATES:
                    fr = client.read_flow_run(uuid.UUID(fid))
                    states[fid] = fr.state_type.value if fr.state_type else ""
            if all(s in FINAL_STATES for s in states.values()) or time.monotonic() > deadline:
                return {fid: (s if s in FINAL_STATES else "TIMEOUT") for fid, s in states.items()}
            time.sleep(poll_s)


def requeue(flow_run_id: str) -> None:
    """Schedule a run again (after its worker died: the run still reads RUNNING). Its stages
    resume from the store; a stage the dead worker held waits for that lease to expire."""
    from prefect import get_client
    from prefect.states import Scheduled

    with get_client(sync_client=True) as client:
        client.set_flow_run_state(uuid.UUID(flow_run_id), Scheduled(), force=True)


def worker_command(pool: str = POOL, *, limit: int | None = None, name: str | None = None, queues: tuple[str, ...] = ()) -> list[str]:
    """The ``prefect worker start`` command line for a process worker on ``pool``."""
    cmd = [sys.executable, "-m", "prefect", "worker", "start", "--pool", pool, "--type", "process"]
    if limit:
        cmd += ["--limit", str(limit)]
    if name:
        cmd += ["--name", name]
    for q in queues:
        cmd += ["--work-queue", q]
    return cmd


def worker_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    """The environment a worker runs with: this one, plus a short poll interval by default."""
    env = {**os.environ, **(extra or {})}
    env.setdefault("PREFECT_WORKER_QUERY_SECONDS", "2")
    return env
