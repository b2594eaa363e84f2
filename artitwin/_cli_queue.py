"""Queue commands: ``submit`` scenes to a Prefect server, run a ``worker``, ``deploy``, and show a
dataset's ``status`` from the store. Registered on the main app by ``register(app)``."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from artitwin._cli_common import StoreOpt, _fail, _load_config
from artitwin_core import ArtiTwinError

PoolOpt = Annotated[str, typer.Option("--pool", help="Prefect work pool.")]
StagesOpt = Annotated[
    str | None,
    typer.Option("--stages", help="Comma-separated stage names to run (a stage runs only if its inputs ran); default all."),
]


def _stages(value: str | None) -> list[str] | None:
    if value is None:
        return None
    from tasks import STAGES

    names = [v.strip() for v in value.split(",") if v.strip()]
    unknown = [n for n in names if n not in STAGES]
    if unknown:
        _fail(f"unknown stage(s) {unknown}; known: {', '.join(STAGES)}")
    return names


def _config(path: Path | None):
    """The queue's config: the file's, or the stage defaults (``PipelineConfig()``), which is what
    ``submit_scene``, ``dataset_status`` and the nightly deployment use without one, so that
    ``status`` finds the runs ``submit`` and the API queued (``artitwin run`` sizes its own for the
    machine instead)."""
    from schemas import PipelineConfig

    return _load_config(path) if path is not None else PipelineConfig()


def submit(
    captures: Annotated[list[Path], typer.Argument(help="Scene folders (each with a static and a dynamic recording).")],
    queue: Annotated[str, typer.Option("--queue", help="Work queue: interactive (served first) or nightly.")] = "interactive",
    store: StoreOpt = None,
    config: Annotated[Path | None, typer.Option("--config", help="Pipeline config (JSON or YAML).")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write each scene's summary.json under OUT/<scene name>.")] = None,
    task_runner: Annotated[str, typer.Option("--task-runner", help="threads, dask, or a Dask scheduler tcp://host:port.")] = "threads",
    force: Annotated[bool, typer.Option("--force", help="Queue even if an equal capture is queued, running or done.")] = False,
    wait: Annotated[bool, typer.Option("--wait", help="Wait for the runs to finish; exit 1 if any failed.")] = False,
    stages: StagesOpt = None,
) -> None:
    """Queue scenes on the Prefect server in $PREFECT_API_URL, deduplicated by capture key."""
    from infra.deploy import submit_scene, wait_for_runs

    cfg = _config(config)
    subs = []
    try:
        for cap in captures:
            subs.append(
                submit_scene(
                    cap,
                    queue=queue,
                    store=store,
                    config=cfg,
                    out=(out / cap.resolve().name) if out else None,
                    task_runner=task_runner,
                    force=force,
                    stages=_stages(stages),
                )
            )
    except ArtiTwinError as e:
        _fail(str(e))
    table = Table(title=f"queue {queue}")
    for col in ("scene", "capture key", "flow run", "submission"):
        table.add_column(col)
    for s in subs:
        table.add_row(s.scene, s.capture_key[:12], s.flow_run_id, f"reused ({s.state.lower()})" if s.reused else "new")
    Console().print(table)
    if wait:
        states = wait_for_runs([s.flow_run_id for s in subs])
        for s in subs:
            typer.echo(f"{s.flow_run_id} {states[s.flow_run_id]} {s.scene}")
        if any(v != "COMPLETED" for v in states.values()):
            raise typer.Exit(1)


def worker(
    pool: PoolOpt = "artitwin",
    limit: Annotated[int | None, typer.Option("--limit", help="At most this many flow runs at once on this worker.")] = None,
    name: Annotated[str | None, typer.Option("--name", help="Worker name (default: Prefect's).")] = None,
    queue: Annotated[list[str] | None, typer.Option("--queue", help="Only these queues (default: all, by priority).")] = None,
    setup: Annotated[bool, typer.Option("--setup/--no-setup", help="Create the pool, queues and deployments first.")] = True,
) -> None:
    """Start a process worker on the Prefect server in $PREFECT_API_URL (runs until stopped)."""
    from infra.deploy import register_deployments, setup_pool, worker_command, worker_env

    try:
        if setup:
            setup_pool(pool)
            register_deployments(pool)
    except ArtiTwinError as e:
        _fail(str(e))
    cmd = worker_command(pool, limit=limit, name=name, queues=tuple(queue or ()))
    sys.stdout.flush()
    os.execve(cmd[0], cmd, worker_env())  # the worker replaces this process: signals reach it directly


def deploy(
    pool: PoolOpt = "artitwin",
    pool_limit: Annotated[int | None, typer.Option("--pool-limit", help="Concurrency limit of the whole pool.")] = None,
    nightly_dataset: Annotated[Path | None, typer.Option("--nightly-dataset", help="Dataset the nightly schedule reprocesses.")] = None,
    cron: Annotated[str, typer.Option("--cron", help="Nightly schedule (cron, UTC).")] = "0 2 * * *",
    store: StoreOpt = None,
) -> None:
    """Create or update the work pool, its queues and the per-scene and nightly deployments."""
    from infra.deploy import register_deployments, setup_pool

    try:
        setup_pool(pool, concurrency_limit=pool_limit)
        ids = register_deployments(
            pool,
            nightly_dataset=str(nightly_dataset) if nightly_dataset else None,
            nightly_cron=cron,
            nightly_parameters={"store": store} if store else None,
        )
    except ArtiTwinError as e:
        _fail(str(e))
    for full_name, dep_id in ids.items():
        typer.echo(f"{full_name} {dep_id}")


def nightly(
    dataset: Annotated[Path, typer.Argument(help="Folder of scene folders.")],
    store: StoreOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write nightly.json and per-scene summaries here.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Submit every scene, even those fully in the store.")] = False,
    stages: StagesOpt = None,
) -> None:
    """Run the nightly deployment on DATASET now (instead of waiting for its schedule)."""
    from infra.deploy import submit_nightly

    try:
        typer.echo(submit_nightly(dataset, store=store, out=out, force=force, stages=_stages(stages)))
    except ArtiTwinError as e:
        _fail(str(e))


def requeue(flow_run: Annotated[str, typer.Argument(help="Id of a run whose worker died.")]) -> None:
    """Schedule a run again after its worker died; its stages resume from the store."""
    from infra.deploy import requeue as _requeue

    _requeue(flow_run)
    typer.echo(f"{flow_run} scheduled again")


def status(
    dataset: Annotated[Path, typer.Argument(help="A folder of scene folders, or one scene folder.")],
    store: StoreOpt = None,
    config: Annotated[Path | None, typer.Option("--config", help="Pipeline config the runs used.")] = None,
    stages: StagesOpt = None,
) -> None:
    """List the scenes of DATASET with each stage's state in the store: cached, failed (with the
    error) or missing. Reads the store only; no server needed."""
    from artitwin_core.capture import find_scene_recordings
    from flows._env import default_store_url
    from flows.nightly import dataset_status, scene_status
    from infra.store import ArtifactStore

    cfg = _config(config)
    selected = _stages(stages)
    st = ArtifactStore(store or default_store_url())
    try:
        find_scene_recordings(dataset)
        scenes = [scene_status(dataset.resolve(), st, cfg, selected)]
    except ArtiTwinError:
        try:
            scenes = dataset_status(dataset, st, cfg, selected)
        except ArtiTwinError as e:
            _fail(str(e))
    table = Table(title=f"{dataset} in {st.url}")
    for col in ("scene", "stage", "state", "key", "error"):
        table.add_column(col, overflow="fold")
    colour = {"cached": "green", "failed": "red", "missing": "yellow"}
    for s in scenes:
        if s.error:
            table.add_row(s.scene.name, "", "[red]unusable[/]", "", s.error)
        for stage in s.stages:
            table.add_row(s.scene.name, stage.name, f"[{colour[stage.state]}]{stage.state}[/]", stage.key[:12], stage.error)
    Console(width=200).print(table)
    done = sum(s.up_to_date for s in scenes)
    typer.echo(f"{done}/{len(scenes)} scene(s) up to date")


def register(app: typer.Typer) -> None:
    """Add the queue commands to the ``artitwin`` app."""
    for fn in (submit, worker, deploy, nightly, requeue, status):
        app.command(fn.__name__)(fn)
