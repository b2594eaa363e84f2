"""Queue throughput: scenes per hour with 1 vs 2 process workers, and a no-change nightly pass.

Starts a Prefect server (SQLite) on 127.0.0.1 and process workers (``artitwin worker``, one flow
run at a time each) as subprocesses, submits N distinct tiny synthetic scenes to a fresh store,
and times submission to the last completed run (worker start-up excluded: workers are online
first). Then it runs the nightly deployment over the same, now fully stored, dataset and times
it: the cost of a pass that finds nothing to do (planning = hashing every recording).

    python bench/bench_queue.py [--scenes 4] [--repeats 1] [--stages ingest,capture_check | --stages all]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._common import print_table, write_results  # noqa: E402
from tests.queue._harness import Server, Worker  # noqa: E402


def _online_workers(pool: str) -> int:
    from prefect import get_client

    with get_client(sync_client=True) as c:
        return sum(w.status.value == "ONLINE" for w in c.read_workers_for_work_pool(pool))


def _make_dataset(root: Path, n: int) -> Path:
    from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene

    for i in range(n):
        spec = dataclasses.replace(BENCHMARK_SCENES["tiny"], seed=1000 + i)
        write_scene(generate_scene(spec), root / "dataset" / f"scene{i:02d}")
    return root / "dataset"


def _run_batch(dataset: Path, store: Path, stages: list[str] | None) -> float:
    from infra.deploy import submit_scene, wait_for_runs

    t0 = time.perf_counter()
    ids = [submit_scene(s, store=str(store), stages=stages).flow_run_id for s in sorted(dataset.iterdir())]
    states = wait_for_runs(ids, timeout_s=1800, poll_s=0.5)
    wall = time.perf_counter() - t0
    if set(states.values()) != {"COMPLETED"}:
        raise RuntimeError(f"runs did not all complete: {states}")
    return wall


def _nightly_pass(dataset: Path, store: Path, out: Path, stages: list[str] | None) -> dict:
    from prefect import get_client

    from infra.deploy import submit_nightly, wait_for_runs

    t0 = time.perf_counter()
    fid = submit_nightly(dataset, store=str(store), out=out, stages=stages)
    state = wait_for_runs([fid], timeout_s=600, poll_s=0.5)[fid]
    wall = time.perf_counter() - t0
    report = json.loads((out / "nightly.json").read_text())["scenes"]
    with get_client(sync_client=True) as c:
        fr = c.read_flow_run(uuid.UUID(fid))
    return {
        "state": state,
        "submit_to_done_s": wall,
        "flow_run_s": fr.total_run_time.total_seconds(),
        "up_to_date": sum(r["state"] == "up to date" for r in report.values()),
        "submitted": sum(r["state"] == "submitted" for r in report.values()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--stages", default="ingest,capture_check", help="comma-separated stages, or 'all'")
    args = ap.parse_args()
    stages = None if args.stages == "all" else args.stages.split(",")

    from prefect.settings import PREFECT_API_URL, temporary_settings

    root = Path(tempfile.mkdtemp(prefix="bench-queue-"))
    load_before = os.getloadavg()
    dataset = _make_dataset(root, args.scenes)
    scene_mb = sum(p.stat().st_size for p in dataset.rglob("*") if p.is_file()) / 1e6
    server = Server(root / "server")
    rows, workers = [], []
    try:
        server.wait_ready()
        with temporary_settings({PREFECT_API_URL: server.api_url}):
            from infra.deploy import register_deployments, setup_pool

            setup_pool()
            register_deployments()
            env = {"ARTITWIN_HOME": str(root / "home")}
            for n_workers in (1, 2):
                while len(workers) < n_workers:
                    workers.append(Worker(root / "worker", server.api_url, env, limit=1, name=f"w{len(workers) + 1}"))
                deadline = time.monotonic() + 300
                while _online_workers("artitwin") < n_workers and time.monotonic() < deadline:
                    time.sleep(1)
                walls = [_run_batch(dataset, root / f"store-{n_workers}-{r}", stages) for r in range(args.repeats)]
                wall = statistics.median(walls)
                rows.append(
                    {
                        "case": f"{n_workers} worker(s), 1 run each",
                        "scenes": args.scenes,
                        "wall_s": wall,
                        "scenes_per_hour": 3600 * args.scenes / wall,
                        "s_per_scene": wall / args.scenes,
                    }
                )
            nightly = [_nightly_pass(dataset, root / "store-2-0", root / f"nightly-{r}", stages) for r in range(max(2, args.repeats))]
            for r, n in enumerate(nightly):
                if n["state"] != "COMPLETED" or n["submitted"]:
                    raise RuntimeError(f"no-change nightly pass {r} did work: {n}")
            rows.append(
                {
                    "case": "no-change nightly pass",
                    "scenes": args.scenes,
                    "wall_s": statistics.median(n["submit_to_done_s"] for n in nightly),
                    "scenes_per_hour": None,
                    "s_per_scene": statistics.median(n["flow_run_s"] for n in nightly) / args.scenes,
                }
            )
    finally:
        for w in workers:
            w.stop()
        server.stop()
    print_table(rows, ["case", "scenes", "wall_s", "scenes_per_hour", "s_per_scene"])
    print(f"(no-change nightly: s_per_scene is the nightly flow run's own time per scene; dataset {scene_mb:.1f} MB)")
    path = write_results(
        "queue",
        rows,
        {
            "scene": "tiny synthetic (BENCHMARK_SCENES['tiny'], distinct seeds)",
            "stages": args.stages,
            "dataset_mb": scene_mb,
            "load_average_before": load_before,
            "load_average_after": os.getloadavg(),
            "cpu_count": os.cpu_count(),
            "note": "shared 2-core machine; other sessions' jobs were running (see load averages)",
        },
    )
    print(path)


if __name__ == "__main__":
    main()
