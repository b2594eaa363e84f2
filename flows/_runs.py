"""Read finished runs back (their summary.json and the store it points to) for `artitwin
diagnose` and `artitwin compare`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from artitwin_core import InputError
from artitwin_core.diagnostics._runs import RunComparison, RunRecord, compare_runs, comparison_html
from artitwin_core.reconstruction import split_frames
from infra.store import ArtifactStore
from schemas import DiagnosisReport

STATIC_SCOPE = "static recording"


def read_summary(path: str | Path) -> tuple[Path, dict[str, Any]]:
    """``(run folder, summary)`` of a run folder or its summary.json; ``InputError`` naming the path."""
    path = Path(path)
    file = path / "summary.json" if path.is_dir() else path
    if not file.is_file():
        raise InputError(f"{file}: no summary.json here; give a run folder written by `artitwin run --out DIR`.")
    try:
        summary = json.loads(file.read_text())
        summary["stages"]  # noqa: B018 (the one field every summary has)
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{file}: not an ArtiTwin run summary ({e}); rerun the scene to rewrite it.") from None
    return file.parent, summary


def diagnosis_of(summary: dict[str, Any], where: Path) -> DiagnosisReport | None:
    """The run's diagnosis report from its store (None when the run had no diagnose stage)."""
    entry = summary["stages"].get("diagnose")
    if entry is None:
        return None
    try:
        return ArtifactStore(summary["store"]).get(entry["key"], DiagnosisReport)
    except (KeyError, FileNotFoundError, OSError) as e:
        raise InputError(
            f"{where}: the diagnosis {entry.get('key', '?')[:16]} is not in the store {summary.get('store')!r} ({e}); "
            "pass the run's --store or rerun the scene."
        ) from None


def run_record(path: str | Path) -> RunRecord:
    """A run reduced to what ``compare_runs`` needs: metrics, per-frame curves, held-out frames."""
    where, summary = read_summary(path)
    metrics: dict[str, float] = {}
    for stage, entry in summary["stages"].items():
        for k, v in (entry.get("metrics") or {}).items():
            if v is not None:
                metrics[f"{stage}/{k}"] = float(v)
    per_frame: dict[str, list[float]] = {}
    heldout: dict[str, list[int]] = {}
    report = diagnosis_of(summary, where)
    holdout_every = ((summary.get("config") or {}).get("reconstruct") or {}).get("holdout_every")
    if report is not None:
        for k, v in report.per_frame.items():
            if not k.endswith("_before"):  # "_after" is the diagnosis's what-if, not the twin
                continue
            name = f"diagnose/{k[: -len('_before')]}"
            per_frame[name] = [float("nan") if x is None else float(x) for x in v]
            if k.startswith(STATIC_SCOPE + "/") and holdout_every is not None:
                heldout[name] = split_frames(len(v), int(holdout_every))[1]
    return RunRecord(
        name=str(where), effects=list(summary.get("effects", [])), metrics=metrics, per_frame=per_frame, heldout=heldout
    )


def compare_run_folders(a: str | Path, b: str | Path, html_out: str | Path | None = None) -> RunComparison:
    """Compare run ``b`` with run ``a``; write the HTML report to ``html_out`` when given."""
    cmp = compare_runs(run_record(a), run_record(b))
    if html_out is not None:
        out = Path(html_out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(comparison_html(cmp), encoding="utf-8")
    return cmp
