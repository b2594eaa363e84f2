"""Content-addressed, immutable artifact store on a local directory or an fsspec URL."""

from infra.store._keys import canonical_json, library_versions, manifest_key, stage_key
from infra.store._store import (
    ArtifactStore,
    CorruptArtifactError,
    Lease,
    LeaseLostError,
    MissingArtifactError,
    Problem,
    RefInfo,
    StoreError,
)

__all__ = [
    "ArtifactStore",
    "CorruptArtifactError",
    "Lease",
    "LeaseLostError",
    "MissingArtifactError",
    "Problem",
    "RefInfo",
    "StoreError",
    "canonical_json",
    "library_versions",
    "manifest_key",
    "stage_key",
]
