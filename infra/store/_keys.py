"""Content keys: what an artifact's identity is made of.

A stage output's key hashes everything that can change it: the stage's name and explicit
version, the output schema's version, the stage config, the keys of its inputs, and the versions
of the libraries whose numerics it depends on. A raw recording's key hashes its file manifest
(relative paths, sizes, SHA-256 of contents), so renaming the folder does not invalidate it but
changing one byte does.
"""

from __future__ import annotations

import hashlib
import json
import os
from importlib import metadata
from pathlib import Path
from typing import Any

# Libraries whose numerics change results. Versions are read from package metadata, not by
# importing them (importing torch or open3d to compute a key would cost seconds).
NUMERICS_LIBRARIES = (
    "numpy",
    "scipy",
    "torch",
    "open3d-cpu",
    "open3d",
    "opencv-python-headless",
    "pycolmap",
    "numba",
    "gsplat",
)


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no whitespace: equal values give equal text."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=True)


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def library_versions(names: tuple[str, ...] = NUMERICS_LIBRARIES) -> dict[str, str]:
    """Installed versions of ``names``; missing ones are left out."""
    out = {}
    for name in names:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


def stage_key(
    *,
    stage: str,
    stage_version: int,
    schema_kind: str,
    schema_version: int,
    config: dict[str, Any],
    inputs: dict[str, str],
    libraries: dict[str, str],
) -> tuple[str, dict[str, Any]]:
    """The key of a stage's output and the record it was hashed from (kept in the ref)."""
    record = {
        "stage": stage,
        "stage_version": stage_version,
        "schema": {"kind": schema_kind, "version": schema_version},
        "config": config,
        "inputs": dict(sorted(inputs.items())),
        "libraries": dict(sorted(libraries.items())),
    }
    return sha256_text(canonical_json(record)), record


def file_sha256(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def manifest_key(root: Path, files: list[Path]) -> tuple[str, dict[str, Any]]:
    """Key of a raw input made of ``files`` (absolute or relative to ``root``).

    Paths are recorded relative to ``root`` so that moving the folder keeps the key.
    """
    root = Path(root)
    base = root if root.is_dir() else root.parent
    entries = []
    for f in sorted(Path(p) for p in files):
        full = f if f.is_absolute() else base / f
        rel = os.path.relpath(full, base)
        entries.append({"path": Path(rel).as_posix(), "size": full.stat().st_size, "sha256": file_sha256(full)})
    record = {"raw_input": True, "files": entries}
    return sha256_text(canonical_json(record)), record
