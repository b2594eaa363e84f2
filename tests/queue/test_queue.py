"""Many scenes through a real Prefect server, work pool and process worker on 127.0.0.1.

The tests share one server and worker (tests/queue/conftest.py) and run in file order; the
SIGKILL test comes last because it replaces the worker.
"""

from __future__ import annotations

import json
import time
import uuid
from pathlib import Path

import pytest
from typer.testing import CliRunner

from infra.deploy import QUEUES, requeue, submit_nightly, submit_scene, wait_for_runs
from infra.store import ArtifactStore

RUN_TIMEOUT_S = 300  # a tiny scene takes ~20 s per run here; generous for a loaded 2-core machine
# The queue machinery does not depend on which stages run: the tests run the two capture stages
# (ingest and capture_check, for the static and the dynamic recording) to stay fast.
STAGES = ["ingest", "capture_check"]


def _fault(cluster, name: str, **spec) -> Path:
    path = cluster.faults / f"{name}.json"
    path.write_text(json.dumps(spec))
    return path


def _fired(path: Path) -> bool:
    return not path.exists() and any(path.parent.glob(path.name + ".fired-*"))


def _wait_until(cond, what: str, timeout_s: float = RUN_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.5)


def _client():
    from prefect import get_client

    return get_client(sync_client=True)


def _task_runs(name: str, *, flow_run_id: str | None = None, running: bool = False) -> list:
    """Task runs called ``name`` (in the scene subflows of ``flow_run_id`` when given)."""
    from prefect.client.schemas.filters import (
        FlowRunFilter,
        FlowRunFilterId,
        FlowRunFilterParentFlowRunId,
        TaskRunFilter,
        TaskRunFilterName,
        TaskRunFilterState,
        TaskRunFilterStateType,
    )
    from prefect.client.schemas.objects import StateType

    with _client() as c:
        flow_filter = None
        if flow_run_id is not None:
            subflows = c.read_flow_runs(flow_run_filter=FlowRunFilter(parent_flow_run_id=FlowRunFilterParentFlowRunId(any_=[uuid.UUID(flow_run_id)])))
            flow_filter = FlowRunFilter(id=FlowRunFilterId(any_=[f.id for f in subflows]))
        state = TaskRunFilterState(type=TaskRunFilterStateType(any_=[StateType.RUNNING])) if running else None
        return c.read_task_runs(flow_run_filter=flow_filter, task_run_filter=TaskRunFilter(name=TaskRunFilterName(any_=[name]), state=state))


def _message(flow_run_id: str) -> str:
    with _client() as c:
        return c.read_flow_run(uuid.UUID(flow_run_id)).state.message or ""


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def test_pool_queues_serve_interactive_first_and_limit_nightly(cluster):
    with _client() as c:
        got = {q.name: q for q in c.read_work_queues(work_pool_name="artitwin")}
    for spec in QUEUES:
        assert got[spec.name].priority == spec.priority
        assert got[spec.name].concurrency_limit == spec.concurrency_limit
    assert got["interactive"].priority < got["nightly"].priority  # lower number = served first


@pytest.mark.slow
def test_three_scenes_transient_retried_bad_capture_fails_fast(cluster, scenes, tmp_path):
    store = str(tmp_path / "store")
    flaky = _fault(cluster, "alpha-flaky", stage="ingest", label="static", path_contains=str(scenes["alpha"]), action="transient")
    # gamma's stages run on a local Dask cluster (the task-runner option), the others on threads
    runner = {"alpha": "threads", "beta": "threads", "gamma": "dask"}
    subs = {name: submit_scene(scenes[name], store=store, out=tmp_path / name, task_runner=runner[name], stages=STAGES) for name in runner}
    assert not any(s.reused for s in subs.values())
    again = submit_scene(scenes["alpha"], store=store, out=tmp_path / "alpha", stages=STAGES)
    assert again.reused and again.flow_run_id == subs["alpha"].flow_run_id  # deduplicated by capture key

    states = wait_for_runs([s.flow_run_id for s in subs.values()], timeout_s=RUN_TIMEOUT_S)
    assert {n: states[s.flow_run_id] for n, s in subs.items()} == {"alpha": "COMPLETED", "beta": "FAILED", "gamma": "COMPLETED"}

    # alpha: one injected transient failure, retried once by Prefect, then computed
    assert _fired(flaky)
    (attempt,) = _task_runs("ingest[static]", flow_run_id=subs["alpha"].flow_run_id)
    assert attempt.run_count == 2
    assert all(s["status"] == "computed" for s in _summary(tmp_path / "alpha")["stages"].values())

    # beta: the truncated recording fails at once, names the file and says what to do, no retry
    msg = _message(subs["beta"].flow_run_id)
    assert "static.r3d" in msg and "not a readable .r3d" in msg and "Export the recording" in msg
    (attempt,) = _task_runs("ingest[static]", flow_run_id=subs["beta"].flow_run_id)
    assert attempt.run_count == 1

    # gamma ran to the end beside the failure
    assert all(s["status"] == "computed" for s in _summary(tmp_path / "gamma")["stages"].values())

    # a failed capture does not block resubmitting it (it fails again, on its own)
    retry = submit_scene(scenes["beta"], store=store, stages=STAGES)
    assert not retry.reused and retry.flow_run_id != subs["beta"].flow_run_id
    assert wait_for_runs([retry.flow_run_id], timeout_s=RUN_TIMEOUT_S)[retry.flow_run_id] == "FAILED"

    # the dataset view: alpha and gamma fully cached, beta's static ingest failed with the reason
    from artitwin.cli import app

    dataset = scenes["alpha"].parent
    result = CliRunner().invoke(app, ["status", str(dataset), "--store", store, "--stages", ",".join(STAGES)])
    assert result.exit_code == 0, result.output
    rows = [line for line in result.output.splitlines() if "│" in line]
    beta_rows = [r for r in rows if "beta" in r]
    assert any("ingest/static" in r and "failed" in r for r in beta_rows)
    assert "not a readable .r3d" in result.output
    assert any("capture_check/static" in r and "missing" in r for r in beta_rows)
    assert sum("cached" in r for r in rows if "alpha" in r or "gamma" in r) == 8  # 4 stages x 2 scenes
    assert "2/3 scene(s) up to date" in result.output


@pytest.mark.slow
def test_interactive_run_overtakes_queued_nightly_run(cluster, scenes, tmp_path):
    """With one slot in the pool, a run queued on ``nightly`` first still starts after one
    queued on ``interactive`` later."""
    from prefect.client.schemas.actions import WorkPoolUpdate

    with _client() as c:
        c.update_work_pool("artitwin", WorkPoolUpdate(is_paused=True))
    try:
        night = submit_scene(scenes["alpha"], queue="nightly", store=str(tmp_path / "s1"), force=True, stages=STAGES)
        time.sleep(1.0)  # strictly later creation (and expected start) for the interactive run
        inter = submit_scene(scenes["gamma"], queue="interactive", store=str(tmp_path / "s2"), force=True, stages=STAGES)
        with _client() as c:
            c.update_work_pool("artitwin", WorkPoolUpdate(is_paused=False, concurrency_limit=1))
        states = wait_for_runs([night.flow_run_id, inter.flow_run_id], timeout_s=RUN_TIMEOUT_S)
    finally:
        with _client() as c:
            c.update_work_pool("artitwin", WorkPoolUpdate(is_paused=False, concurrency_limit=None))
    assert set(states.values()) == {"COMPLETED"}
    with _client() as c:
        n, i = (c.read_flow_run(uuid.UUID(x.flow_run_id)) for x in (night, inter))
    assert n.expected_start_time < i.expected_start_time
    assert i.start_time < n.start_time and i.end_time <= n.start_time  # served first, one at a time


@pytest.mark.slow
def test_nightly_twice_without_change_recomputes_nothing(cluster, scenes, tmp_path):
    import shutil

    dataset = tmp_path / "dataset"
    for name in ("alpha", "gamma"):
        shutil.copytree(scenes[name], dataset / name)
    store = tmp_path / "store"

    first = submit_nightly(dataset, store=str(store), out=tmp_path / "n1", stages=STAGES)
    assert wait_for_runs([first], timeout_s=RUN_TIMEOUT_S)[first] == "COMPLETED"
    report = json.loads((tmp_path / "n1" / "nightly.json").read_text())["scenes"]
    assert {n: r["state"] for n, r in report.items()} == {"alpha": "submitted", "gamma": "submitted"}
    children = [r["flow_run_id"] for r in report.values()]
    assert set(wait_for_runs(children, timeout_s=RUN_TIMEOUT_S).values()) == {"COMPLETED"}
    for name in ("alpha", "gamma"):
        assert all(s["status"] == "computed" for s in _summary(tmp_path / "n1" / name)["stages"].values())
    refs_before = {i.key: i.created for i in ArtifactStore(store).ls()}
    assert len(refs_before) == 8

    second = submit_nightly(dataset, store=str(store), out=tmp_path / "n2", stages=STAGES)
    assert wait_for_runs([second], timeout_s=RUN_TIMEOUT_S)[second] == "COMPLETED"
    report = json.loads((tmp_path / "n2" / "nightly.json").read_text())["scenes"]
    assert {n: r["state"] for n, r in report.items()} == {"alpha": "up to date", "gamma": "up to date"}
    assert all(set(r["stages"].values()) == {"cached"} for r in report.values())
    assert {i.key: i.created for i in ArtifactStore(store).ls()} == refs_before  # nothing written


def test_same_scene_twice_at_once_computes_each_stage_once(cluster, scenes, tmp_path):
    store = tmp_path / "store"
    release = tmp_path / "release"
    hold = _fault(cluster, "alpha-hold", stage="ingest", label="static", path_contains=str(scenes["alpha"]), action="hold", until=str(release), timeout_s=240)
    a = submit_scene(scenes["alpha"], store=str(store), out=tmp_path / "a", force=True, stages=STAGES)
    b = submit_scene(scenes["alpha"], store=str(store), out=tmp_path / "b", force=True, stages=STAGES)
    assert a.flow_run_id != b.flow_run_id
    # both runs inside ingest[static] at once: one holds the key's lease, the other waits on it
    _wait_until(lambda: _fired(hold) and len(_task_runs("ingest[static]", running=True)) == 2, "both runs in ingest[static]")
    release.touch()
    states = wait_for_runs([a.flow_run_id, b.flow_run_id], timeout_s=RUN_TIMEOUT_S)
    assert set(states.values()) == {"COMPLETED"}
    sa, sb = _summary(tmp_path / "a")["stages"], _summary(tmp_path / "b")["stages"]
    assert sa.keys() == sb.keys() and len(sa) == 4
    for name in sa:
        assert sa[name]["key"] == sb[name]["key"]
        assert sorted([sa[name]["status"], sb[name]["status"]]) == ["cached", "computed"], name
    st = ArtifactStore(store)
    for key in (s["key"] for s in sa.values()):
        assert len(st.backend.listdir(f"objects/{key}")) == 1  # one object written per stage


@pytest.mark.slow
def test_sigkilled_worker_run_resumes_from_store_with_equal_artifacts(cluster, scenes, tmp_path):
    from flows import InlineExecutor
    from flows.nightly import scene_plan, select_pipeline
    from schemas import PipelineConfig

    store = tmp_path / "store"
    never = tmp_path / "never"
    hold = _fault(cluster, "gamma-hold", stage="capture_check", label="static", path_contains="", action="hold", until=str(never), timeout_s=600)
    sub = submit_scene(scenes["gamma"], store=str(store), out=tmp_path / "out", force=True, stages=STAGES)
    st = ArtifactStore(store)
    held_key = scene_plan(scenes["gamma"], st, stages=STAGES)["capture_check/static"].key
    _wait_until(lambda: _fired(hold) and held_key in st.backend.listdir("leases"), "the run to be inside capture_check[static]")
    assert st.has(scene_plan(scenes["gamma"], st, stages=STAGES)["ingest/static"].key)  # its input was committed

    cluster.worker.kill()  # the worker and its flow-run process, SIGKILL: no clean-up runs
    assert not st.has(held_key)  # the held stage: leased, never committed
    cluster.start_worker()
    requeue(sub.flow_run_id)
    assert wait_for_runs([sub.flow_run_id], timeout_s=RUN_TIMEOUT_S)[sub.flow_run_id] == "COMPLETED"

    resumed = _summary(tmp_path / "out")["stages"]
    assert resumed["ingest/static"]["status"] == "cached"  # finished before the kill: not recomputed
    assert resumed["capture_check/static"]["status"] == "computed"  # taken over after the lease expired
    assert resumed["capture_check/static"]["key"] == held_key

    ref = ArtifactStore(tmp_path / "clean")  # the same stages, uninterrupted, in this process
    clean = select_pipeline(scenes["gamma"], PipelineConfig(), InlineExecutor(ref), STAGES)
    assert {n: r.key for n, r in clean.items()} == {n: s["key"] for n, s in resumed.items()}
    for s in resumed.values():  # same files, byte for byte (SHA-256 per file)
        assert st.info(s["key"]).files == ref.info(s["key"]).files


def test_prefect_yaml_declares_the_same_deployments(cluster, tmp_path):
    """``prefect deploy`` on infra/prefect.yaml registers the deployments the code registers."""
    import os
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PREFECT_API_URL": cluster.server.api_url, "ARTITWIN_NIGHTLY_DATASET": str(tmp_path)}
    cmd = [sys.executable, "-m", "prefect", "--no-prompt", "deploy", "--all", "--prefect-file", str(repo / "infra" / "prefect.yaml")]
    done = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    with _client() as c:
        scene = c.read_deployment_by_name("process-scene/scene")
        night = c.read_deployment_by_name("nightly-dataset/nightly")
    assert (scene.entrypoint, scene.work_queue_name) == ("flows.nightly.process_scene", "interactive")
    assert (night.entrypoint, night.work_queue_name) == ("flows.nightly.nightly", "nightly")
    assert night.parameters == {"dataset": str(tmp_path)}
    assert [s.schedule.cron for s in night.schedules] == ["0 2 * * *"]
