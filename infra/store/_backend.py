"""Filesystem backends of the artifact store: a local directory, or any fsspec URL.

The store needs few primitives from storage: create a small file only if it does not exist (the
commit marker), replace a small file atomically (lease renewal), list and remove, and publish a
directory written elsewhere. A local directory does them with POSIX calls; an fsspec filesystem
(object storage, a memory fs for tests, ``file://``) with ``open(mode="xb")`` and ``put``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
from pathlib import Path

import fsspec
import zarr
from zarr.storage import FsspecStore, LocalStore


class LocalBackend:
    """A store rooted at a local directory."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root).expanduser().resolve()
        self.url = str(self.root)

    def _p(self, rel: str) -> Path:
        return self.root / rel

    def create_only(self, rel: str, data: bytes) -> bool:
        """Write ``data`` at ``rel`` unless something is there; True if this call created it.

        Written to a temporary name, then hard-linked into place: link() fails if the target
        exists, so the file appears complete or not at all, and only one writer wins.
        """
        path = self._p(rel)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.parent / f".{path.name}.{uuid.uuid4().hex}.tmp"
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        try:
            os.link(tmp, path)
            return True
        except FileExistsError:
            return False
        finally:
            tmp.unlink(missing_ok=True)

    def replace(self, rel: str, data: bytes) -> None:
        path = self._p(rel)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.parent / f".{path.name}.{uuid.uuid4().hex}.tmp"
        tmp.write_bytes(data)
        os.replace(tmp, path)

    def read(self, rel: str) -> bytes:
        return self._p(rel).read_bytes()

    def exists(self, rel: str) -> bool:
        return self._p(rel).exists()

    def listdir(self, rel: str) -> list[str]:
        path = self._p(rel)
        if not path.is_dir():
            return []
        return sorted(p.name for p in path.iterdir() if not p.name.startswith("."))

    def sizes(self, rel: str) -> dict[str, int]:
        """Relative path (under ``rel``) -> size in bytes of every file below ``rel``."""
        base = self._p(rel)
        out = {}
        for dirpath, _, files in os.walk(base):
            for name in files:
                full = Path(dirpath) / name
                out[full.relative_to(base).as_posix()] = full.stat().st_size
        return out

    def open_read(self, rel: str):
        return open(self._p(rel), "rb")

    def mtime(self, rel: str) -> float:
        return self._p(rel).stat().st_mtime

    def remove(self, rel: str) -> None:
        path = self._p(rel)
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)

    def rename(self, src: str, dst: str) -> None:
        self._p(dst).parent.mkdir(parents=True, exist_ok=True)
        os.replace(self._p(src), self._p(dst))

    def staging_dir(self) -> Path:
        """A fresh directory to write an object into, on the same filesystem as the store."""
        path = self._p(f"staging/{uuid.uuid4().hex}")
        path.mkdir(parents=True)
        return path

    def publish_dir(self, staging: Path, rel: str) -> None:
        self._p(rel).parent.mkdir(parents=True, exist_ok=True)
        os.rename(staging, self._p(rel))  # atomic within one filesystem

    def discard_staging(self, staging: Path) -> None:
        shutil.rmtree(staging, ignore_errors=True)

    def zarr_group(self, rel: str) -> zarr.Group:
        return zarr.open_group(LocalStore(self._p(rel), read_only=True), mode="r")


class FsspecBackend:
    """A store rooted at an fsspec URL (``s3://bucket/prefix``, ``memory://x``, ``file:///p``)."""

    def __init__(self, url: str, storage_options: dict | None = None) -> None:
        opts = dict(storage_options or {})
        if url.startswith("file://"):
            opts.setdefault("auto_mkdir", True)
        self.fs, root = fsspec.core.url_to_fs(url, **opts)
        self.root = root.rstrip("/")
        self.url = url
        self._opts = opts

    def _p(self, rel: str) -> str:
        return f"{self.root}/{rel}"

    def create_only(self, rel: str, data: bytes) -> bool:
        path = self._p(rel)
        self.fs.makedirs(self.fs._parent(path), exist_ok=True)
        try:
            with self.fs.open(path, "xb") as f:  # exclusive create (conditional put on object stores)
                f.write(data)
            return True
        except FileExistsError:
            return False

    def replace(self, rel: str, data: bytes) -> None:
        path = self._p(rel)
        self.fs.makedirs(self.fs._parent(path), exist_ok=True)
        self.fs.pipe_file(path, data)

    def read(self, rel: str) -> bytes:
        return self.fs.cat_file(self._p(rel))

    def exists(self, rel: str) -> bool:
        return self.fs.exists(self._p(rel))

    def listdir(self, rel: str) -> list[str]:
        path = self._p(rel)
        if not self.fs.isdir(path):
            return []
        names = [p.rstrip("/").rsplit("/", 1)[-1] for p in self.fs.ls(path, detail=False)]
        return sorted(n for n in names if not n.startswith("."))

    def sizes(self, rel: str) -> dict[str, int]:
        base = self._p(rel).rstrip("/")
        found = self.fs.find(base, detail=True)
        out = {}
        for path, info in found.items():
            rel_path = path[len(base) :].lstrip("/") if path.startswith(base) else path.rsplit(base, 1)[-1].lstrip("/")
            out[rel_path] = int(info["size"])
        return out

    def open_read(self, rel: str):
        return self.fs.open(self._p(rel), "rb")

    def mtime(self, rel: str) -> float:
        info = self.fs.info(self._p(rel))
        for k in ("mtime", "LastModified", "created"):
            if k in info:
                v = info[k]
                return v.timestamp() if hasattr(v, "timestamp") else float(v)
        return 0.0

    def remove(self, rel: str) -> None:
        path = self._p(rel)
        if self.fs.exists(path):
            self.fs.rm(path, recursive=True)

    def rename(self, src: str, dst: str) -> None:
        self.fs.mv(self._p(src), self._p(dst), recursive=True)

    def staging_dir(self) -> Path:
        return Path(tempfile.mkdtemp(prefix="artitwin-staging-"))

    def publish_dir(self, staging: Path, rel: str) -> None:
        dest = self._p(rel)
        for local in sorted(staging.rglob("*")):
            if local.is_file():
                target = f"{dest}/{local.relative_to(staging).as_posix()}"
                self.fs.makedirs(self.fs._parent(target), exist_ok=True)
                self.fs.put_file(str(local), target)
        shutil.rmtree(staging, ignore_errors=True)

    def discard_staging(self, staging: Path) -> None:
        shutil.rmtree(staging, ignore_errors=True)

    def zarr_group(self, rel: str) -> zarr.Group:
        store = FsspecStore.from_url(f"{self.url.rstrip('/')}/{rel}", read_only=True, storage_options=self._opts)
        return zarr.open_group(store, mode="r")


def open_backend(root: str | os.PathLike, storage_options: dict | None = None) -> LocalBackend | FsspecBackend:
    """A local directory for plain paths, an fsspec backend for anything with ``://``."""
    text = str(root)
    if "://" in text:
        return FsspecBackend(text, storage_options)
    return LocalBackend(text)
