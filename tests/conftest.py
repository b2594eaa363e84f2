"""Shared test settings: one embedded-Prefect home per test session, quiet, no analytics.

Applied before any test module imports prefect (which reads its settings at import time).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

_HOME = tempfile.mkdtemp(prefix="artitwin-test-home-")

# The suite runs on pytest-xdist workers (``-n 2`` in pyproject.toml): each takes its share of the
# cores, or their OpenMP/BLAS pools oversubscribe them and spin while the other worker computes.
# Set in the workers only (the controller's environment is theirs), before numpy, torch or numba
# is imported; subprocesses the tests start inherit it.
if "PYTEST_XDIST_WORKER_COUNT" in os.environ:
    _share = str(max(1, (os.cpu_count() or 1) // int(os.environ["PYTEST_XDIST_WORKER_COUNT"])))
    for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ.setdefault(_var, _share)
os.environ.setdefault("ARTITWIN_HOME", _HOME)
if "PYTEST_XDIST_WORKER" in os.environ:
    # The controller's homes came with its environment: each worker keeps its own below them
    # (its own embedded Prefect server and SQLite database).
    for _var in ("ARTITWIN_HOME", "PREFECT_HOME"):
        if _var in os.environ:
            os.environ[_var] = os.path.join(os.environ[_var], os.environ["PYTEST_XDIST_WORKER"])

from flows._env import apply_prefect_defaults  # noqa: E402

apply_prefect_defaults()


# Seconds each test file took in a full run (``pytest --store-durations`` rewrites it).
DURATIONS = Path(__file__).with_name("durations.json")
_seconds: dict[str, float] = {}


def pytest_addoption(parser):
    parser.addoption("--store-durations", action="store_true",
                     help=f"write the seconds of each test file run to {DURATIONS.name} (the workers' file order)")


def _file_of(nodeid: str) -> str:
    return nodeid.split("::")[0]


def _stored_durations() -> dict[str, float]:
    return json.loads(DURATIONS.read_text()) if DURATIONS.is_file() else {}


def pytest_collection_modifyitems(items):
    """The longest files first (``durations.json``), each file's tests in order.

    The workers take a file at a time in collection order; a long file left for last runs alone
    while the other worker idles. Longest first keeps both busy to the end. A file not in
    ``durations.json`` yet counts 20 s per slow test (``@pytest.mark.slow``) and 1 s per other."""
    known = _stored_durations()
    guess: dict[str, float] = {}
    for item in items:
        guess[_file_of(item.nodeid)] = guess.get(_file_of(item.nodeid), 0.0) + (20.0 if "slow" in item.keywords else 1.0)
    items.sort(key=lambda item: -known.get(_file_of(item.nodeid), guess[_file_of(item.nodeid)]))  # stable


def pytest_runtest_logreport(report):
    _seconds[_file_of(report.nodeid)] = _seconds.get(_file_of(report.nodeid), 0.0) + report.duration


def pytest_sessionfinish(session):
    # The controller (or a run without workers) sees every test's report; a worker only its own.
    if session.config.getoption("store_durations") and not hasattr(session.config, "workerinput"):
        known = _stored_durations()
        known.update({f: round(s, 1) for f, s in _seconds.items()})  # the files this run ran; others as they were
        DURATIONS.write_text(json.dumps(dict(sorted(known.items())), indent=1) + "\n")
