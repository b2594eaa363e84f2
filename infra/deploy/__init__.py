"""Deploying the pipeline on a Prefect server: work pool and queues, deployments, submissions."""

from infra.deploy._pool import (
    POOL,
    QUEUES,
    QueueSpec,
    Submission,
    register_deployments,
    requeue,
    require_server,
    setup_pool,
    submit_nightly,
    submit_scene,
    wait_for_runs,
    worker_command,
    worker_env,
)

__all__ = [
    "POOL",
    "QUEUES",
    "QueueSpec",
    "Submission",
    "register_deployments",
    "require_server",
    "requeue",
    "setup_pool",
    "submit_nightly",
    "submit_scene",
    "wait_for_runs",
    "worker_command",
    "worker_env",
]
