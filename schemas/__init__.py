"""Typed contracts: pydantic models for every artifact and stage config, and their zarr I/O.

Every artifact class writes itself to a zarr group (``to_zarr``) and reads itself back
(``Artifact.from_zarr``) exactly. Field descriptions carry units and frames.
"""

from schemas._articulate import ArticulateConfig
from schemas._artifacts import (
    CameraPoses,
    CaptureArtifact,
    DepthCalibrationResult,
    FramePoseCorrections,
    GaussianCheckpoint,
    JointParams,
    JointSet,
    MaskSequenceArtifact,
    PartFateArtifact,
    PoseDriftResult,
    PoseLagResult,
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
    DepthCalibrationConfig,
    FramePoseStageConfig,
    IngestConfig,
    JointConfig,
    JointStateConfig,
    PartMasksConfig,
    PipelineConfig,
    PoseDriftConfig,
    PoseLagStageConfig,
    RegistrationStageConfig,
    SettlePartsConfig,
    TrackingStageConfig,
)
from schemas._diagnose import (
    DiagnoseConfig,
    DiagnosisReport,
    EffectFinding,
    PredictViewsConfig,
    ViewPrediction,
)
from schemas._export import ExportBundle, ExportConfig, ExportFile
from schemas._parts import ChangeStageConfig, PartStageConfig
from schemas._reconstruct import PoseRefineStageConfig, ReconstructConfig

__all__ = [
    "ArticulateConfig",
    "Array",
    "ArraySpec",
    "Artifact",
    "CameraPoses",
    "CaptureArtifact",
    "CaptureCheckConfig",
    "ChangeStageConfig",
    "DiagnoseConfig",
    "DiagnosisReport",
    "EffectFinding",
    "ExportBundle",
    "ExportConfig",
    "ExportFile",
    "FramePoseCorrections",
    "FramePoseStageConfig",
    "GaussianCheckpoint",
    "IngestConfig",
    "JointConfig",
    "DepthCalibrationConfig",
    "PoseDriftConfig",
    "PoseLagStageConfig",
    "JointStateConfig",
    "PartMasksConfig",
    "PartStageConfig",
    "PoseRefineStageConfig",
    "PredictViewsConfig",
    "ReconstructConfig",
    "RegistrationStageConfig",
    "TrackingStageConfig",
    "JointParams",
    "JointSet",
    "MaskSequenceArtifact",
    "PartFateArtifact",
    "PipelineConfig",
    "SettlePartsConfig",
    "DepthCalibrationResult",
    "PoseDriftResult",
    "PoseLagResult",
    "Registration",
    "ReportImage",
    "SchemaError",
    "StageConfig",
    "StageReport",
    "TrajectoriesArtifact",
    "ViewPrediction",
    "all_artifact_classes",
    "artifact_class",
]
