"""Two toy stages chained like the real ones, with call counters, for testing the machinery."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from pydantic import Field

from artitwin_core import InputError, TransientError
from schemas import StageConfig, StageReport
from tasks import stage

CALLS: Counter = Counter()
FAILURES: dict[str, int] = {}  # stage name -> transient failures still to raise


class ToyConfig(StageConfig):
    scale: float = Field(default=1.0, description="Multiplies the measured size.")


@stage(name="toy_measure", version=1, config=ToyConfig, output=StageReport, raw_inputs=("recording",))
def toy_measure(recording: Path, config: ToyConfig) -> StageReport:
    CALLS["toy_measure"] += 1
    if FAILURES.get("toy_measure", 0) > 0:
        FAILURES["toy_measure"] -= 1
        raise TransientError("simulated flaky mount")
    if not Path(recording).exists():
        raise InputError(f"{recording} does not exist; check the path")
    size = sum(p.stat().st_size for p in Path(recording).rglob("*") if p.is_file())
    return StageReport(stage="toy_measure", metrics={"bytes_count": size * config.scale})


@stage(name="toy_double", version=1, config=ToyConfig, output=StageReport)
def toy_double(report: StageReport, config: ToyConfig) -> StageReport:
    CALLS["toy_double"] += 1
    return StageReport(stage="toy_double", metrics={"bytes_count": 2 * report.metrics["bytes_count"] * config.scale})
