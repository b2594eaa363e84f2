"""Typed contracts: pydantic models for every artifact and stage config, and their zarr I/O.

Every artifact class writes itself to a zarr group (``to_zarr``) and reads itself back
(``Artifact.from_zarr``) exactly. Field descriptions carry units and frames.
"""

from schemas._artifacts import (
    CameraPoses,
    CaptureArtifact,
    GaussianCheckpoint,
    JointParams,
    JointSet,
    MaskSequenceArtifact,
    Registration,
    ReportImage,
    StageReport,
    TrajectoriesArtifact,
)
from schemas._base import (
    Array,
    ArraySpec,
    Artifact,
    SchemaError,
    StageConfig,
    all_artifact_classes,
    artifact_class,
)
from schemas._configs import (
    CaptureCheckConfig,
    IngestConfig,
    JointConfig,
    PartMasksConfig,
    PipelineConfig,
    RegisterConfig,
    TrackConfig,
)
from schemas._reconstruct import PoseRefineStageConfig, ReconstructConfig

__all__ = [
    "Array",
    "ArraySpec",
    "Artifact",
    "CameraPoses",
    "CaptureArtifact",
    "CaptureCheckConfig",
    "GaussianCheckpoint",
    "IngestConfig",
    "JointConfig",
    "PartMasksConfig",
    "PoseRefineStageConfig",
    "ReconstructConfig",
    "RegisterConfig",
    "TrackConfig",
    "JointParams",
    "JointSet",
    "MaskSequenceArtifact",
    "PipelineConfig",
    "Registration",
    "ReportImage",
    "SchemaError",
    "StageConfig",
    "StageReport",
    "TrajectoriesArtifact",
    "all_artifact_classes",
    "artifact_class",
]
