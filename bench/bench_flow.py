"""Cold run vs cached rerun of the whole scene flow, and Prefect's per-task overhead.

    python bench/bench_flow.py [--scene tiny] [--tasks 20]

Prints a table and writes bench/results/flow.json.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._common import print_table, write_results  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scene", default="tiny", help="synthetic benchmark scene name")
    parser.add_argument("--tasks", type=int, default=20, help="trivial tasks for the overhead measurement")
    args = parser.parse_args()

    import os

    home = tempfile.mkdtemp(prefix="artitwin-bench-")
    os.environ.setdefault("ARTITWIN_HOME", home)

    from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene
    from flows.scene import reconstruct_scene, run_scene_inline

    scene_dir = Path(home) / "scene"
    write_scene(generate_scene(BENCHMARK_SCENES[args.scene]), scene_dir)
    rows = []

    # The first flow in a process starts Prefect's embedded server; measure that apart.
    from prefect import flow, task

    @flow
    def warm_up() -> int:
        return 1

    t0 = time.perf_counter()
    warm_up()
    rows.append({"what": "embedded prefect server start (first flow)", "seconds": time.perf_counter() - t0, "stages": "", "statuses": ""})
    for mode in ("prefect", "inline"):
        store = str(Path(home) / f"store-{mode}")
        for attempt in ("cold", "cached"):
            t0 = time.perf_counter()
            if mode == "prefect":
                summary = reconstruct_scene(str(scene_dir), store=store)
            else:
                summary = run_scene_inline(scene_dir, store=store)
            dt = time.perf_counter() - t0
            statuses = sorted({s["status"] for s in summary["stages"].values()})
            rows.append({"what": f"{mode} {attempt} run", "seconds": dt, "stages": len(summary["stages"]), "statuses": "/".join(statuses)})

    # Per-task overhead: N trivial tasks in one flow.
    @task
    def noop(i: int) -> int:
        return i

    @flow
    def many(n: int) -> int:
        return sum(f.result() for f in [noop.submit(i) for i in range(n)])

    many(2)  # warm: the embedded server is already up from the runs above
    t0 = time.perf_counter()
    many(args.tasks)
    per_task = (time.perf_counter() - t0) / args.tasks
    rows.append({"what": f"prefect overhead per task ({args.tasks} tasks)", "seconds": per_task, "stages": "", "statuses": ""})

    print_table(rows)
    print(f"results: {write_results('flow', rows, {'scene': args.scene})}")


if __name__ == "__main__":
    main()
