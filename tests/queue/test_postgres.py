"""A scene run recorded by a Prefect server on PostgreSQL (as in infra/compose.yaml).

Uses the PostgreSQL server binaries when the machine has them (Debian: ``apt-get install
postgresql``); the test does not install packages itself and skips, saying why, without them.
A throw-away cluster is created in a temporary folder on a free loopback port and stopped after.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.queue._harness import Server, free_port


def _pg_bin() -> Path | None:
    found = shutil.which("initdb")
    if found:
        return Path(os.path.realpath(found)).parent
    hits = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    return Path(hits[-1]).parent if hits else None


@pytest.fixture(scope="module")
def postgres(tmp_path_factory):
    bindir = _pg_bin()
    if bindir is None:
        pytest.skip("PostgreSQL server binaries (initdb, pg_ctl) not found; `apt-get install postgresql` to run this test")
    prefix: list[str] = []
    root = tmp_path_factory.mktemp("pg")
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root: run it as the postgres user
        try:
            pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user to run PostgreSQL as")
        if shutil.which("runuser") is None:
            pytest.skip("running as root without runuser to drop to the postgres user")
        os.chmod(root, 0o777)
        for parent in list(root.parents)[:3]:
            os.chmod(parent, os.stat(parent).st_mode | 0o011)  # let postgres traverse to its data dir
        prefix = ["runuser", "-u", "postgres", "--"]
    data, port = root / "data", free_port()
    run = lambda *cmd: subprocess.run([*prefix, *cmd], check=True, capture_output=True, text=True, timeout=120)  # noqa: E731
    run(str(bindir / "initdb"), "-D", str(data), "-A", "trust", "-U", "prefect", "--no-sync")
    opts = f"-h 127.0.0.1 -p {port} -k {root} -c fsync=off"
    run(str(bindir / "pg_ctl"), "-D", str(data), "-o", opts, "-l", str(root / "pg.log"), "-w", "-t", "60", "start")
    try:
        run(str(bindir / "createdb"), "-h", "127.0.0.1", "-p", str(port), "-U", "prefect", "prefect")
        yield {"url": f"postgresql+asyncpg://prefect@127.0.0.1:{port}/prefect", "port": port, "bindir": bindir, "prefix": prefix}
    finally:
        subprocess.run([*prefix, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "-w", "stop"], capture_output=True, timeout=60)


def test_scene_run_on_postgres_backed_server(postgres, scenes, tmp_path):
    from prefect.settings import PREFECT_API_URL, temporary_settings

    from flows.nightly import process_scene

    server = Server(tmp_path / "server", database_url=postgres["url"])
    try:
        server.wait_ready()
        with temporary_settings({PREFECT_API_URL: server.api_url}):
            # the capture stages only: the database, not the stages, is under test here
            summary = process_scene(str(scenes["gamma"]), store=str(tmp_path / "store"), stages=["ingest", "capture_check"])
    finally:
        server.stop()
    assert len(summary["stages"]) == 4 and all(s["status"] == "computed" for s in summary["stages"].values())
    # the run and its stage tasks are rows in PostgreSQL, not in a SQLite file
    psql = [*postgres["prefix"], str(postgres["bindir"] / "psql"), "-h", "127.0.0.1", "-p", str(postgres["port"]), "-U", "prefect", "-tA", "prefect"]
    query = "select name, state_type from task_run order by name"
    rows = subprocess.run([*psql, "-c", query], check=True, capture_output=True, text=True, timeout=60).stdout.split()
    stage_rows = [r for r in rows if "[" in r]  # one task run per stage; the subflow call adds its own
    assert stage_rows == [f"{n}[{label}]|COMPLETED" for n in ("capture_check", "ingest") for label in ("dynamic", "static")]
    assert all(r.endswith("|COMPLETED") for r in rows)
    query = "select f.name from flow_run r join flow f on f.id = r.flow_id order by f.name"
    flows = subprocess.run([*psql, "-c", query], check=True, capture_output=True, text=True, timeout=60).stdout
    assert flows.split() == ["process-scene", "scene-stages"]
    assert not list((tmp_path / "server").glob("*.db"))
