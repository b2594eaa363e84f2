"""Prefect flows over the pure stages in ``tasks``; caching goes through the artifact store.

Importing this package applies the embedded-Prefect defaults (``flows._env``) before prefect
itself is imported.
"""

from flows import _env  # noqa: F401  (must run before prefect is imported)
from flows._pipeline import build_summary, gpu_available, hardware_preset, scene_pipeline, write_summary
from flows._runner import (
    InlineExecutor,
    ParallelExecutor,
    PlanExecutor,
    RawInput,
    StageRun,
    raw_input,
    run_stage,
)

__all__ = [
    "InlineExecutor",
    "ParallelExecutor",
    "PlanExecutor",
    "RawInput",
    "StageRun",
    "build_summary",
    "gpu_available",
    "hardware_preset",
    "raw_input",
    "run_stage",
    "scene_pipeline",
    "write_summary",
]
