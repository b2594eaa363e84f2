"""Shared test settings: one embedded-Prefect home per test session, quiet, no analytics.

Applied before any test module imports prefect (which reads its settings at import time).
"""

from __future__ import annotations

import os
import tempfile

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


def pytest_collection_modifyitems(items):
    """Files with the most slow tests (``@pytest.mark.slow``) first, each file's tests in order.

    The workers take a file at a time in collection order; a slow file left for last runs alone
    while the other worker idles. Longest first keeps both busy to the end."""
    def file_of(item) -> str:
        return item.nodeid.split("::")[0]

    slow: dict[str, int] = {}
    for item in items:
        slow[file_of(item)] = slow.get(file_of(item), 0) + ("slow" in item.keywords)
    items.sort(key=lambda item: -slow[file_of(item)])  # stable: collection order among equals
