"""The content-addressed store: atomic publication, crash safety, races, leases, corruption."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from infra.store import ArtifactStore, CorruptArtifactError, MissingArtifactError, stage_key
from schemas import StageReport
from tests.foundation._store_worker import big_checkpoint

REPO = Path(__file__).resolve().parents[2]
KEY = "ab" + "0" * 62


def _roots(tmp_path):
    # A plain directory, the same directory through fsspec's file://, and an in-memory fsspec fs.
    return [str(tmp_path / "local"), f"file://{tmp_path / 'fsspec'}", f"memory://store-{tmp_path.name}"]


def _spawn(root, key, phase, marker, seed=0):
    return subprocess.Popen(
        [sys.executable, "-m", "tests.foundation._store_worker", root, key, phase, str(marker), str(seed)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for(path: Path, proc, timeout=60.0):
    end = time.monotonic() + timeout
    while not path.exists():
        if proc.poll() is not None:
            raise AssertionError(f"worker exited early: {proc.stderr.read()}")
        if time.monotonic() > end:
            raise AssertionError("worker never reached the pause point")
        time.sleep(0.02)


def test_put_get_and_existing_key_is_never_overwritten(tmp_path):
    for root in _roots(tmp_path):
        store = ArtifactStore(root)
        first = StageReport(stage="a", metrics={"x_m": 1.0})
        assert store.put(KEY, first)
        assert not store.put(KEY, StageReport(stage="b"))
        assert store.get(KEY, StageReport).equals(first)
        assert [i.key for i in store.ls()] == [KEY]
        with pytest.raises(MissingArtifactError, match="no artifact"):
            store.get("ff" * 32)


def test_get_or_compute_calls_compute_once(tmp_path):
    store = ArtifactStore(tmp_path)
    calls = []

    def compute():
        calls.append(1)
        return StageReport(stage="a")

    assert store.get_or_compute(KEY, compute) == (KEY, False)
    assert store.get_or_compute(KEY, compute) == (KEY, True)
    assert len(calls) == 1


@pytest.mark.parametrize("phase", ["writing", "published"])
@pytest.mark.parametrize("kind", ["local", "fsspec"])
def test_sigkill_mid_write_leaves_nothing_visible_and_rerun_completes(tmp_path, phase, kind):
    root = str(tmp_path / "s") if kind == "local" else f"file://{tmp_path / 's'}"
    marker = tmp_path / "marker"
    proc = _spawn(root, KEY, phase, marker)
    _wait_for(marker, proc)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    store = ArtifactStore(root)
    assert not store.has(KEY)
    assert list(store.keys()) == []
    assert store.verify() == []
    # the dead writer's lease expires (ttl 1.5 s) and a rerun completes
    expected = big_checkpoint(0)
    key, hit = store.get_or_compute(KEY, lambda: expected, lease_ttl_s=1.5, poll_s=0.05)
    assert not hit
    assert store.get(KEY).equals(expected)
    leftovers = store.gc(grace_s=0)
    if phase == "published":
        assert any(r.startswith(f"objects/{KEY}/") for r in leftovers)  # the orphaned object
    assert store.get(KEY).equals(expected)  # gc never touches the live object
    assert store.verify() == []


def test_two_processes_computing_one_key_produce_one_consistent_result(tmp_path):
    root = str(tmp_path / "s")
    procs = [_spawn(root, KEY, "none", tmp_path / f"m{i}", seed=0) for i in range(2)]
    for p in procs:
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
    store = ArtifactStore(root)
    assert list(store.keys()) == [KEY]
    assert store.get(KEY).equals(big_checkpoint(0))
    assert len(list((tmp_path / "s" / "objects" / KEY).iterdir())) == 1  # the loser discarded its copy


def test_racing_writers_with_different_bytes_keep_the_first(tmp_path):
    store_a, store_b = ArtifactStore(tmp_path), ArtifactStore(tmp_path)
    a, b = StageReport(stage="a"), StageReport(stage="b")
    # b checked has() before a published, then lost the ref race
    store_b.has = lambda key: False  # type: ignore[method-assign]
    assert store_a.put(KEY, a)
    assert not store_b.put(KEY, b)
    assert ArtifactStore(tmp_path).get(KEY).equals(a)
    assert len(list((tmp_path / "objects" / KEY).iterdir())) == 1


def test_dead_workers_lease_expires_and_another_takes_over(tmp_path):
    root = str(tmp_path / "s")
    marker = tmp_path / "marker"
    proc = _spawn(root, KEY, "computing", marker)
    _wait_for(marker, proc)
    store = ArtifactStore(root)
    assert store.try_lease(KEY, 10.0) is None  # held and renewed by the live worker
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    start = time.monotonic()
    expected = big_checkpoint(3)
    _, hit = store.get_or_compute(KEY, lambda: expected, lease_ttl_s=1.5, poll_s=0.05)
    waited = time.monotonic() - start
    assert not hit and store.get(KEY).equals(expected)
    assert waited < 10.0, "the expired lease should be taken over within its TTL"


def test_a_waiter_reuses_the_holders_result(tmp_path):
    root = str(tmp_path / "s")
    marker = tmp_path / "marker"
    proc = _spawn(root, KEY, "computing", marker)
    _wait_for(marker, proc)
    store = ArtifactStore(root)
    # the holder sleeps inside compute; pretend it finished by publishing its result ourselves
    # under its lease is not possible, so instead check the waiter does not compute while held
    calls = []
    with pytest.raises(Exception, match="timed out"):
        store.get_or_compute(KEY, lambda: calls.append(1) or StageReport(stage="x"), wait_timeout_s=1.0, poll_s=0.05)
    assert calls == []
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()


@pytest.mark.parametrize("damage", ["flip", "truncate", "delete"])
def test_corruption_is_detected_and_repair_forces_recompute(tmp_path, damage):
    store = ArtifactStore(tmp_path)
    art = big_checkpoint(1, n=5000)
    store.put(KEY, art)
    info = store.info(KEY)
    rel = max(info.files, key=lambda r: info.files[r][0])  # the largest chunk
    path = tmp_path / info.object_path / rel
    data = bytearray(path.read_bytes())
    if damage == "flip":
        data[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(data))
        with pytest.raises(CorruptArtifactError, match="SHA-256"):
            store.get(KEY, verify="checksum")
    elif damage == "truncate":
        path.write_bytes(bytes(data[:-10]))
        with pytest.raises(CorruptArtifactError, match="bytes, expected"):
            store.get(KEY)
    else:
        path.unlink()
        with pytest.raises(CorruptArtifactError, match="missing"):
            store.get(KEY)
    problems = store.verify(repair=True)
    assert problems and problems[0].key == KEY
    assert not store.has(KEY)
    assert store.get_or_compute(KEY, lambda: art) == (KEY, False)
    assert store.get(KEY, verify="checksum").equals(art)


def test_unreadable_ref_is_reported_as_corrupt(tmp_path):
    store = ArtifactStore(tmp_path)
    store.put(KEY, StageReport(stage="a"))
    (tmp_path / "refs" / KEY[:2] / f"{KEY}.json").write_text("{not json")
    with pytest.raises(CorruptArtifactError, match="unreadable"):
        store.get(KEY)


def test_stage_key_depends_on_everything_that_changes_results():
    base = dict(stage="s", stage_version=1, schema_kind="k", schema_version=1,
                config={"a": 1, "b": [1.5, 2]}, inputs={"x": "1" * 64}, libraries={"numpy": "2.0"})
    k0, record = stage_key(**base)
    assert json.loads(json.dumps(record))["config"] == {"a": 1, "b": [1.5, 2]}
    assert stage_key(**{**base, "config": {"b": [1.5, 2], "a": 1}})[0] == k0  # order-free
    for change in [
        {"stage_version": 2},
        {"schema_version": 2},
        {"config": {"a": 2, "b": [1.5, 2]}},
        {"inputs": {"x": "2" * 64}},
        {"libraries": {"numpy": "2.1"}},
        {"stage": "t"},
    ]:
        assert stage_key(**{**base, **change})[0] != k0, change


def test_gc_keeps_young_leftovers_within_grace(tmp_path):
    store = ArtifactStore(tmp_path)
    (tmp_path / "staging" / "deadbeef").mkdir(parents=True)
    assert store.gc(grace_s=3600) == []
    assert store.gc(grace_s=0) == ["staging/deadbeef"]
    assert not (tmp_path / "staging" / "deadbeef").exists()


def test_large_arrays_round_trip_through_fsspec_memory():
    store = ArtifactStore("memory://big")
    art = big_checkpoint(5, n=70_000)  # more than one row chunk
    store.put(KEY, art)
    assert store.get(KEY, verify="checksum").equals(art)
    assert np.array_equal(store.get(KEY).means, art.means)
