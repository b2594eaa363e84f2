"""Stage caching through the store: what reruns and what does not."""

from __future__ import annotations

import dataclasses

import pytest

from flows import raw_input, run_stage
from infra.store import ArtifactStore
from schemas import StageReport
from tasks import STAGES
from tests.flows._toy import CALLS, ToyConfig


def _chain(store, folder, cfg_a=ToyConfig(), cfg_b=ToyConfig(), stages=None):
    stages = stages or STAGES
    raw = raw_input(folder, sorted(p for p in folder.rglob("*") if p.is_file()))
    a = run_stage(store, stages["toy_measure"], cfg_a, {"recording": raw})
    b = run_stage(store, stages["toy_double"], cfg_b, {"report": a})
    return a, b


@pytest.fixture
def folder(tmp_path):
    d = tmp_path / "rec"
    d.mkdir()
    (d / "a.bin").write_bytes(b"x" * 100)
    (d / "b.bin").write_bytes(b"y" * 50)
    CALLS.clear()
    return d


def test_rerun_hits_the_cache_and_calls_no_stage(tmp_path, folder):
    store = ArtifactStore(tmp_path / "store")
    a, b = _chain(store, folder)
    assert (a.status, b.status) == ("computed", "computed")
    assert store.get(b.key, StageReport).metrics["bytes_count"] == 300.0
    CALLS.clear()
    a2, b2 = _chain(store, folder)
    assert (a2.status, b2.status) == ("cached", "cached")
    assert (a2.key, b2.key) == (a.key, b.key)
    assert sum(CALLS.values()) == 0


def test_config_change_recomputes_that_stage_and_later_only(tmp_path, folder):
    store = ArtifactStore(tmp_path / "store")
    _chain(store, folder)
    CALLS.clear()
    a, b = _chain(store, folder, cfg_b=ToyConfig(scale=3.0))
    assert (a.status, b.status) == ("cached", "computed")
    assert dict(CALLS) == {"toy_double": 1}
    assert store.get(b.key, StageReport).metrics["bytes_count"] == 900.0
    CALLS.clear()
    a, b = _chain(store, folder, cfg_a=ToyConfig(scale=2.0))
    assert (a.status, b.status) == ("computed", "computed")


def test_input_change_recomputes_everything_downstream(tmp_path, folder):
    store = ArtifactStore(tmp_path / "store")
    a0, b0 = _chain(store, folder)
    (folder / "a.bin").write_bytes(b"z" * 100)  # same size, different content
    CALLS.clear()
    a, b = _chain(store, folder)
    assert (a.status, b.status) == ("computed", "computed")
    assert a.key != a0.key and b.key != b0.key
    # renaming the folder keeps the content key: nothing recomputes
    moved = folder.rename(folder.parent / "moved")
    CALLS.clear()
    a2, b2 = _chain(store, moved)
    assert (a2.status, b2.status) == ("cached", "cached")


def test_stage_version_bump_recomputes_that_stage_and_later(tmp_path, folder):
    store = ArtifactStore(tmp_path / "store")
    _chain(store, folder)
    bumped = dict(STAGES)
    bumped["toy_double"] = dataclasses.replace(STAGES["toy_double"], version=2)
    CALLS.clear()
    a, b = _chain(store, folder, stages=bumped)
    assert (a.status, b.status) == ("cached", "computed")
    bumped["toy_measure"] = dataclasses.replace(STAGES["toy_measure"], version=2)
    a, b = _chain(store, folder, stages=bumped)
    assert (a.status, b.status) == ("computed", "computed")


def test_wrong_config_type_is_rejected(tmp_path, folder):
    from schemas import IngestConfig

    store = ArtifactStore(tmp_path / "store")
    raw = raw_input(folder, [folder / "a.bin"])
    with pytest.raises(TypeError, match="takes a ToyConfig"):
        run_stage(store, STAGES["toy_measure"], IngestConfig(), {"recording": raw})


def test_plan_knows_every_key_before_running_and_remembers_failures(tmp_path, folder):
    from flows import PlanExecutor

    store = ArtifactStore(tmp_path / "store")
    raw = raw_input(folder, sorted(folder.iterdir()))
    plan = PlanExecutor(store)
    a = plan.submit("toy_measure", ToyConfig(), {"recording": raw}, "")
    b = plan.submit("toy_double", ToyConfig(), {"report": a}, "")
    assert (a.status, b.status) == ("missing", "missing")
    from tests.flows._toy import FAILURES

    FAILURES["toy_measure"] = 1
    with pytest.raises(Exception, match="flaky"):
        run_stage(store, STAGES["toy_measure"], ToyConfig(), {"recording": raw})
    assert plan.submit("toy_measure", ToyConfig(), {"recording": raw}, "").status == "failed"
    assert "flaky" in store.failure(a.key)["error"]
    real_a, real_b = _chain(store, folder)
    assert (real_a.key, real_b.key) == (a.key, b.key)  # the plan's keys are the real ones
    assert plan.submit("toy_measure", ToyConfig(), {"recording": raw}, "").status == "cached"
    assert store.failure(a.key) is None
    assert f"failures/{a.key}.json" in store.gc(grace_s=0)


def test_parallel_executor_gives_the_inline_results_and_skips_after_a_failure(tmp_path, folder):
    """ParallelExecutor (run_scene_inline(workers=2), bench_end_to_end --workers) runs a stage once
    its inputs are done; a failed input skips what reads it, as InlineExecutor does."""
    from flows import ParallelExecutor
    from tests.flows._toy import FAILURES

    store = ArtifactStore(tmp_path / "store")
    raw = raw_input(folder, sorted(folder.iterdir()))
    ex = ParallelExecutor(store, workers=2)
    try:
        a = ex.submit("toy_measure", ToyConfig(), {"recording": raw}, "")
        b = ex.submit("toy_double", ToyConfig(), {"report": a}, "b")
        c = ex.submit("toy_double", ToyConfig(scale=3.0), {"report": a}, "c")
        runs = [ex.result(h) for h in (a, b, c)]
    finally:
        ex.shutdown()
    assert [r.status for r in runs] == ["computed"] * 3
    assert [store.get(r.key, StageReport).metrics["bytes_count"] for r in runs[1:]] == [300.0, 900.0]
    inline_a, inline_b = _chain(ArtifactStore(tmp_path / "other"), folder)
    assert (inline_a.key, inline_b.key) == (runs[0].key, runs[1].key)

    FAILURES["toy_measure"] = 1
    ex = ParallelExecutor(ArtifactStore(tmp_path / "third"), workers=2)
    try:
        a = ex.submit("toy_measure", ToyConfig(), {"recording": raw}, "")
        b = ex.submit("toy_double", ToyConfig(), {"report": a}, "b")
        failed, skipped = ex.result(a), ex.result(b)
    finally:
        ex.shutdown()
    assert (failed.status, skipped.status) == ("failed", "skipped")


def test_each_stage_run_is_reported_as_progress_lines(tmp_path, folder):
    """Output that is not a terminal (logs, CI, workers) gets a line when a stage starts and when it ends."""
    import io

    from flows._progress import LineSink

    stream = io.StringIO()
    with LineSink(stream):
        _chain(ArtifactStore(tmp_path / "store"), folder)
    lines = stream.getvalue().splitlines()
    assert [line.split(" ", 1)[1].split(" in ")[0] for line in lines] == [
        "toy_measure ...", "toy_measure done", "toy_double ...", "toy_double done"]
