"""Shared test settings: one embedded-Prefect home per test session, quiet, no analytics.

Applied before any test module imports prefect (which reads its settings at import time).
"""

from __future__ import annotations

import os
import tempfile

_HOME = tempfile.mkdtemp(prefix="artitwin-test-home-")
os.environ.setdefault("ARTITWIN_HOME", _HOME)

from flows._env import apply_prefect_defaults  # noqa: E402

apply_prefect_defaults()
