"""The content-addressed artifact store.

Layout under the root::

    refs/<k[:2]>/<key>.json      commit marker, created only once; names the object and its manifest
    objects/<key>/<uuid>/        the artifact's zarr group, immutable once a ref points at it
    staging/<uuid>/              objects being written (local roots; remote roots stage in /tmp)
    leases/<key>/<gen>.json      who is computing <key>, until when
    quarantine/<key>.<ts>.json   refs moved aside by ``verify(repair=True)``
    failures/<key>.json          the last error of a failed computation of <key> (informational)

Writing: the artifact goes to a fresh staging directory, its files are measured (size, SHA-256),
the directory is published under ``objects/<key>/<uuid>`` (a unique name, so two writers never
collide), and only then the ref is created with create-only semantics. The ref is the commit: a
reader that finds it finds a complete object; a writer killed at any point leaves at most an
unreferenced directory that ``gc`` removes. If two writers race, the first ref wins and the
second discards its own object and uses the winner's (stage outputs are deterministic given
their key, so either is right).
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeVar

import zarr
from zarr.storage import LocalStore

from artitwin_core import ArtiTwinError, TransientError
from infra.store._backend import FsspecBackend, LocalBackend, open_backend
from schemas import Artifact, SchemaError

A = TypeVar("A", bound=Artifact)


class StoreError(ArtiTwinError):
    """Base of store errors."""


class MissingArtifactError(StoreError, KeyError):
    def __str__(self) -> str:  # KeyError quotes its message otherwise
        return str(self.args[0])


class CorruptArtifactError(StoreError):
    """A stored object does not match its manifest (bytes lost or changed after publishing)."""


class LeaseLostError(TransientError):
    """Another worker took over this key's lease (ours expired): the result will be theirs."""


@dataclass(frozen=True)
class RefInfo:
    key: str
    kind: str
    schema_version: int
    object_path: str
    files: dict[str, list]  # relpath -> [size, sha256]
    record: dict[str, Any]  # what the key was hashed from (stage, config, inputs, ...)
    created: float

    @property
    def size_bytes(self) -> int:
        return sum(int(v[0]) for v in self.files.values())

    @classmethod
    def from_json(cls, key: str, data: bytes) -> RefInfo:
        try:
            d = json.loads(data)
            return cls(
                key=d["key"],
                kind=d["kind"],
                schema_version=int(d["schema_version"]),
                object_path=d["object"],
                files=d["files"],
                record=d.get("record", {}),
                created=float(d.get("created", 0.0)),
            )
        except (ValueError, KeyError, TypeError) as e:
            raise CorruptArtifactError(f"ref of {key} is unreadable ({e}); run `artitwin store verify --repair`") from e


@dataclass(frozen=True)
class Problem:
    key: str
    what: str


def _ref_path(key: str) -> str:
    return f"refs/{key[:2]}/{key}.json"


class ArtifactStore:
    """Immutable artifacts by content key, on a local directory or an fsspec URL.

    Args:
        root: a directory path, or a URL such as ``s3://bucket/prefix`` or ``memory://x``.
        verify: what reads check against the manifest: ``"size"`` (every file present with its
            recorded size; cheap) or ``"checksum"`` (SHA-256 of every file).
    """

    def __init__(
        self,
        root: str | os.PathLike,
        *,
        verify: Literal["size", "checksum"] = "size",
        storage_options: dict | None = None,
    ) -> None:
        self.backend: LocalBackend | FsspecBackend = open_backend(root, storage_options)
        self.verify_mode = verify

    @property
    def url(self) -> str:
        return self.backend.url

    # --- reading ----------------------------------------------------------------------------
    def has(self, key: str) -> bool:
        return self.backend.exists(_ref_path(key))

    def info(self, key: str) -> RefInfo:
        try:
            data = self.backend.read(_ref_path(key))
        except FileNotFoundError:
            raise MissingArtifactError(f"no artifact {key} in store {self.url}") from None
        return RefInfo.from_json(key, data)

    def get(self, key: str, cls: type[A] = Artifact, *, verify: Literal["size", "checksum"] | None = None) -> A:
        """Read the artifact stored under ``key``, checked against its manifest first."""
        info = self.info(key)
        problems = self._check_object(info, verify or self.verify_mode)
        if problems:
            raise CorruptArtifactError(
                f"artifact {key} ({info.kind}) in {self.url} is corrupt: {'; '.join(problems[:3])}"
                f"{' ...' if len(problems) > 3 else ''}. Run `artitwin store verify --repair` to set it "
                "aside, then rerun: it will be recomputed."
            )
        try:
            artifact = cls.from_zarr(self.backend.zarr_group(info.object_path))
        except SchemaError:
            raise
        except Exception as e:  # a decode error in bytes that passed the size check
            raise CorruptArtifactError(f"artifact {key} in {self.url} could not be decoded: {e}") from e
        return artifact  # type: ignore[return-value]

    def keys(self) -> Iterator[str]:
        for prefix in self.backend.listdir("refs"):
            for name in self.backend.listdir(f"refs/{prefix}"):
                if name.endswith(".json"):
                    yield name[: -len(".json")]

    def ls(self) -> list[RefInfo]:
        out = []
        for key in self.keys():
            try:
                out.append(self.info(key))
            except StoreError:
                continue
        return sorted(out, key=lambda r: r.created)

    # --- writing ----------------------------------------------------------------------------
    def put(self, key: str, artifact: Artifact, record: dict[str, Any] | None = None) -> bool:
        """Store ``artifact`` under ``key``. Returns False if the key already existed (nothing
        written: the existing artifact stands)."""
        if self.has(key):
            return False
        staging = self.backend.staging_dir()
        try:
            group = zarr.open_group(LocalStore(staging), mode="w")
            artifact.to_zarr(group)
            files = _manifest(staging)
            object_path = f"objects/{key}/{uuid.uuid4().hex}"
            self.backend.publish_dir(staging, object_path)
        except BaseException:
            self.backend.discard_staging(staging)
            raise
        ref = {
            "key": key,
            "kind": artifact.kind,
            "schema_version": artifact.schema_version,
            "object": object_path,
            "files": files,
            "record": record or {},
            "created": time.time(),
            "writer": f"{socket.gethostname()}:{os.getpid()}",
        }
        if self.backend.create_only(_ref_path(key), json.dumps(ref, indent=1).encode()):
            return True
        self.backend.remove(object_path)  # lost the race: the first writer's object stands
        return False

    # --- computing once ---------------------------------------------------------------------
    def get_or_compute(
        self,
        key: str,
        compute: Callable[[], Artifact],
        *,
        record: dict[str, Any] | None = None,
        lease_ttl_s: float = 120.0,
        poll_s: float = 0.5,
        wait_timeout_s: float | None = None,
    ) -> tuple[str, bool]:
        """Return ``(key, hit)``, computing and storing the artifact unless it is there.

        Concurrent callers with the same key: one computes under a lease (renewed in the
        background while it runs); the others wait for its ref, or take the lease over if the
        holder stops renewing (a dead worker), so nobody hangs on a dead lock.
        """
        deadline = None if wait_timeout_s is None else time.monotonic() + wait_timeout_s
        while True:
            if self.has(key):
                return key, True
            lease = self.try_lease(key, lease_ttl_s)
            if lease is not None:
                with lease:
                    if self.has(key):  # finished by someone between our check and the lease
                        return key, True
                    artifact = compute()
                    lease.check()
                    created = self.put(key, artifact, record)
                return key, not created
            if deadline is not None and time.monotonic() > deadline:
                raise TransientError(f"timed out waiting for another worker to compute {key}")
            time.sleep(poll_s)

    def try_lease(self, key: str, ttl_s: float) -> Lease | None:
        """Take the lease on ``key`` if nobody holds a live one; None if someone does."""
        prefix = f"leases/{key}"
        gens = [int(n[:-5]) for n in self.backend.listdir(prefix) if n.endswith(".json") and n[:-5].isdigit()]
        if gens:
            latest = max(gens)
            try:
                held = json.loads(self.backend.read(f"{prefix}/{latest:08d}.json"))
            except (FileNotFoundError, ValueError):
                held = {"expires": 0.0}  # half-visible lease file: treat as expired
            if float(held.get("expires", 0.0)) > time.time():
                return None
            gen = latest + 1
        else:
            gen = 0
        lease = Lease(self, key, gen, ttl_s)
        if not self.backend.create_only(lease.path, lease.payload()):
            return None  # another worker took this generation first
        return lease

    # --- failures ---------------------------------------------------------------------------
    def record_failure(self, key: str, error: str, record: dict[str, Any] | None = None) -> None:
        """Remember why computing ``key`` failed (shown by ``artitwin status``; not a result:
        the key stays missing and the next run tries again)."""
        payload = {"key": key, "error": error[:4000], "record": record or {}, "time": time.time()}
        self.backend.replace(f"failures/{key}.json", json.dumps(payload).encode())

    def failure(self, key: str) -> dict[str, Any] | None:
        """The last recorded failure of ``key`` if it has no artifact yet, else None."""
        if self.has(key):
            return None
        try:
            return json.loads(self.backend.read(f"failures/{key}.json"))
        except (FileNotFoundError, ValueError):
            return None

    # --- maintenance ------------------------------------------------------------------------
    def verify(self, *, keys: list[str] | None = None, repair: bool = False, checksum: bool = True) -> list[Problem]:
        """Check every (or the given) artifact against its manifest. With ``repair``, move the
        refs of corrupt ones to ``quarantine/`` so the next run recomputes them."""
        problems = []
        for key in keys if keys is not None else list(self.keys()):
            try:
                info = self.info(key)
                issues = self._check_object(info, "checksum" if checksum else "size")
            except CorruptArtifactError as e:
                issues = [str(e)]
            for what in issues:
                problems.append(Problem(key, what))
            if issues and repair:
                self.backend.rename(_ref_path(key), f"quarantine/{key}.{int(time.time())}.json")
        return problems

    def gc(self, *, grace_s: float = 3600.0, dry_run: bool = False) -> list[str]:
        """Remove what no ref points to: objects of crashed or losing writers, stale staging
        directories, and finished or long-expired leases. ``grace_s`` protects writes in flight."""
        now = time.time()
        removed = []
        for key in self.backend.listdir("objects"):
            live = None
            if self.has(key):
                try:
                    live = self.info(key).object_path
                except CorruptArtifactError:
                    live = None
            for name in self.backend.listdir(f"objects/{key}"):
                rel = f"objects/{key}/{name}"
                if rel != live and now - self._age_ref(rel) > grace_s:
                    removed.append(rel)
            if live is None and not self.backend.listdir(f"objects/{key}"):
                removed.append(f"objects/{key}")
        for name in self.backend.listdir("staging"):
            rel = f"staging/{name}"
            if now - self._age_ref(rel) > grace_s:
                removed.append(rel)
        for key in self.backend.listdir("leases"):
            gens = self.backend.listdir(f"leases/{key}")
            expires = 0.0
            for g in gens:
                try:
                    expires = max(expires, float(json.loads(self.backend.read(f"leases/{key}/{g}"))["expires"]))
                except (FileNotFoundError, ValueError, KeyError):
                    continue
            if self.has(key) or now - expires > grace_s:
                removed.append(f"leases/{key}")
        for name in self.backend.listdir("failures"):
            if name.endswith(".json") and self.has(name[:-5]):
                removed.append(f"failures/{name}")
        if not dry_run:
            for rel in removed:
                self.backend.remove(rel)
        return removed

    # --- internals --------------------------------------------------------------------------
    def _age_ref(self, rel: str) -> float:
        try:
            return self.backend.mtime(rel)
        except (FileNotFoundError, OSError):
            return 0.0

    def _check_object(self, info: RefInfo, mode: str) -> list[str]:
        try:
            present = self.backend.sizes(info.object_path)
        except FileNotFoundError:
            present = {}
        problems = []
        for rel, (size, digest) in info.files.items():
            got = present.get(rel)
            if got is None:
                problems.append(f"{info.object_path}/{rel} is missing")
            elif got != size:
                problems.append(f"{info.object_path}/{rel} has {got} bytes, expected {size}")
            elif mode == "checksum":
                h = hashlib.sha256()
                with self.backend.open_read(f"{info.object_path}/{rel}") as f:
                    while block := f.read(1 << 20):
                        h.update(block)
                if h.hexdigest() != digest:
                    problems.append(f"{info.object_path}/{rel} content changed (SHA-256 mismatch)")
        return problems


class Lease:
    """A time-limited claim on computing one key; renewed by a background thread while held."""

    def __init__(self, store: ArtifactStore, key: str, gen: int, ttl_s: float) -> None:
        self.store, self.key, self.gen, self.ttl_s = store, key, gen, ttl_s
        self.path = f"leases/{key}/{gen:08d}.json"
        self.owner = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def payload(self, expires: float | None = None) -> bytes:
        exp = time.time() + self.ttl_s if expires is None else expires
        return json.dumps({"owner": self.owner, "expires": exp}).encode()

    def lost(self) -> bool:
        """True if a newer generation exists (our lease expired and someone took over)."""
        names = self.store.backend.listdir(f"leases/{self.key}")
        return any(n.endswith(".json") and n[:-5].isdigit() and int(n[:-5]) > self.gen for n in names)

    def check(self) -> None:
        if self.lost():
            raise LeaseLostError(f"lease on {self.key} expired and was taken over by another worker")

    def _renew_loop(self) -> None:
        while not self._stop.wait(self.ttl_s / 3):
            if self.lost():
                return
            self.store.backend.replace(self.path, self.payload())

    def __enter__(self) -> Lease:
        self._thread = threading.Thread(target=self._renew_loop, name=f"lease-{self.key[:8]}", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if not self.lost():
            self.store.backend.replace(self.path, self.payload(expires=0.0))  # released


def _manifest(directory: Path) -> dict[str, list]:
    out = {}
    for path in sorted(Path(directory).rglob("*")):
        if path.is_file():
            h = hashlib.sha256()
            with open(path, "rb") as f:
                while block := f.read(1 << 20):
                    h.update(block)
            out[path.relative_to(directory).as_posix()] = [path.stat().st_size, h.hexdigest()]
    return out
