"""Embedded-Prefect defaults, applied before prefect is imported.

A laptop run needs no server: with no ``PREFECT_API_URL`` Prefect starts a temporary local server
backed by SQLite. Its state goes under the project's ``.artitwin/prefect`` unless the user set
``PREFECT_HOME``; analytics are off. Anything the user set in the environment wins.
"""

from __future__ import annotations

import os
from pathlib import Path


def artitwin_home() -> Path:
    """Where local state lives: ``$ARTITWIN_HOME`` or ``./.artitwin``."""
    return Path(os.environ.get("ARTITWIN_HOME", ".artitwin")).expanduser().resolve()


def default_store_url() -> str:
    return os.environ.get("ARTITWIN_STORE", str(artitwin_home() / "store"))


def apply_prefect_defaults() -> None:
    os.environ.setdefault("PREFECT_HOME", str(artitwin_home() / "prefect"))
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_ALLOW_EPHEMERAL_MODE", "true")
    # The embedded server takes ~10 s to start on 2 cores; Prefect's default patience is tighter.
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "90")
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    # The embedded server dies silently (a start-up time-out) if its home's parent is missing.
    Path(os.environ["PREFECT_HOME"]).expanduser().mkdir(parents=True, exist_ok=True)


apply_prefect_defaults()
