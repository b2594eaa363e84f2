"""One Prefect server (SQLite, 127.0.0.1) and one process worker shared by the queue tests.

Starting a server costs ~30-60 s and a worker ~20 s on this 2-core machine, so the module gets
one of each. The worker runs with a short lease TTL (so a killed worker's claim expires within
seconds) and a fault-injection folder (``ARTITWIN_FAULTS``, see docs/scaling.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from tests.queue._harness import Server, Worker

LEASE_TTL_S = 4.0


@dataclass
class Cluster:
    root: Path
    server: Server
    worker_env: dict[str, str]
    faults: Path
    workers: list[Worker] = field(default_factory=list)

    @property
    def worker(self) -> Worker:
        return self.workers[-1]

    def start_worker(self, limit: int = 3) -> Worker:
        w = Worker(self.root / "worker", self.server.api_url, self.worker_env, limit=limit, name=f"w{len(self.workers) + 1}")
        self.workers.append(w)
        return w


@pytest.fixture(scope="session")
def scenes(tmp_path_factory) -> dict[str, Path]:
    """Two distinct tiny scenes (different seeds) and a third with a truncated static .r3d.

    Each scene has its own content: were beta a copy of alpha, beta's dynamic recording (intact)
    could be ingested by beta's run first and alpha would find it cached."""
    from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene

    root = tmp_path_factory.mktemp("scenes")
    out = {}
    for name, seed in (("alpha", 101), ("gamma", 102), ("beta", 103)):
        spec = dataclasses.replace(BENCHMARK_SCENES["tiny"], seed=seed)
        write_scene(generate_scene(spec), root / name)
        out[name] = root / name
    bad = out["beta"]
    data = (bad / "static.r3d").read_bytes()
    (bad / "static.r3d").write_bytes(data[: len(data) // 3])  # a copy interrupted a third of the way
    return out


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    from prefect.settings import PREFECT_API_URL, temporary_settings

    root = tmp_path_factory.mktemp("cluster")
    faults = root / "faults"
    faults.mkdir()
    server = Server(root / "server")
    try:
        server.wait_ready()
        env = {
            "ARTITWIN_HOME": str(root / "artitwin-home"),
            "ARTITWIN_FAULTS": str(faults),
            "ARTITWIN_LEASE_TTL_S": str(LEASE_TTL_S),
            "ARTITWIN_DASK_WORKERS": "1",  # the Dask run needs to work, not to be fast
        }
        c = Cluster(root, server, env, faults)
        with temporary_settings({PREFECT_API_URL: server.api_url}):
            from infra.deploy import register_deployments, setup_pool

            setup_pool()
            register_deployments()
            c.start_worker()
            try:
                yield c
            finally:
                for w in c.workers:
                    w.stop()
    finally:
        server.stop()
