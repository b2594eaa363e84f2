"""A subprocess that writes to the store and can be told to stop at a given point.

Usage: python -m tests.foundation._store_worker ROOT KEY PHASE MARKER [SEED]

PHASE picks where it signals (by creating MARKER) and then sleeps, so the parent test can SIGKILL it
exactly there: "writing" (half the arrays written to staging), "published" (object published,
ref not yet created), "computing" (inside get_or_compute, holding the lease), or "none" (runs to
the end).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from infra.store import ArtifactStore
from infra.store import _store as store_mod
from schemas import GaussianCheckpoint


def big_checkpoint(seed: int, n: int = 200_000) -> GaussianCheckpoint:
    rng = np.random.default_rng(seed)
    return GaussianCheckpoint(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=rng.normal(size=(n, 3)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(size=(n, 4, 3)).astype(np.float32),
        labels=np.zeros(n, np.int32),
    )


def pause(marker: str) -> None:
    Path(marker).write_text("here")
    time.sleep(60)


def main() -> None:
    root, key, phase, marker = sys.argv[1:5]
    seed = int(sys.argv[5]) if len(sys.argv) > 5 else 0
    store = ArtifactStore(root)
    art = big_checkpoint(seed)
    if phase == "writing":
        original = store_mod._manifest

        def slow_manifest(directory):
            pause(marker)  # staging holds every array, nothing is published
            return original(directory)

        store_mod._manifest = slow_manifest
    elif phase == "published":
        original_publish = store.backend.publish_dir

        def publish_then_pause(staging, rel):
            original_publish(staging, rel)
            pause(marker)

        store.backend.publish_dir = publish_then_pause
    if phase == "computing":

        def compute():
            pause(marker)
            return art

        store.get_or_compute(key, compute, lease_ttl_s=1.5, poll_s=0.05)
    else:
        store.get_or_compute(key, lambda: art, lease_ttl_s=1.5, poll_s=0.05)
    print("done")


if __name__ == "__main__":
    main()
