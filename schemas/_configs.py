"""Stage configs: every hyperparameter a stage reads, frozen, hashed into its store key.

A stage config that feeds one core config is named after it with ``Stage`` inserted
(``TrackingStageConfig`` -> ``artitwin_core.tracking.TrackingConfig``); where each field acts in the
core is declared beside the stage (``tasks._convert.config_map``) and tested against the core's
defaults. The JSON keys of a pipeline config are the field names of ``PipelineConfig`` (``track``,
``registration``, ``frame_poses``), not the class names, so renaming a class leaves stored
configs readable.
"""

from __future__ import annotations

import re
from typing import Any

from pydantic import Field, field_validator, model_validator

from schemas._articulate import ArticulateConfig
from schemas._base import StageConfig
from schemas._diagnose import DiagnoseConfig, PredictViewsConfig
from schemas._effects import (
    DEFAULT_SCOPES,
    EFFECT_SCOPES,
    MODELLED,
    MODELLED_EFFECTS,
    PER_RECORDING_EFFECTS,
    modelled_in,
)
from schemas._export import ExportConfig
from schemas._parts import PartStageConfig
from schemas._reconstruct import PoseRefineStageConfig, ReconstructConfig


class IngestConfig(StageConfig):
    """How a recording is read into a capture artifact: which frames, at what RGB resolution.

    The working resolution and the keyframes are chosen here, before the images are decoded, so
    a long recording at a phone's native resolution never sits in memory whole (the presets set
    them for the hardware: ``PipelineConfig.preset``)."""

    stride: int = Field(default=1, ge=1, description="Keep every stride-th frame.")
    max_frames: int | None = Field(default=None, ge=1, description="Keep at most this many frames (after stride); None = all.")
    rgb_max_width: int | None = Field(
        default=None, ge=16, description="Downscale RGB to at most this width in pixels (intrinsics scaled to match); None = keep."
    )
    rgb_max_side: int | None = Field(
        default=None, ge=16,
        description="The working resolution: downscale RGB so its longer side is at most this many pixels, whatever "
        "the file holds (each frame as it is decoded; intrinsics scaled to match); None = the file's resolution.",
    )
    keyframes_max: int | None = Field(
        default=None, ge=2,
        description="A recording with more frames (after stride and max_frames) keeps at most this many keyframes, "
        "chosen from its poses and depth before any image is decoded: views spread evenly over the sweep, frames "
        "kept densely where the scene moves, frames that see what no other does (artitwin_core.capture."
        "select_keyframes). None = every frame.",
    )
    keyframe_view_step: float = Field(
        default=0.05, gt=0, description="Keyframes: weight of view change, camera travel over the median depth plus rotation (radians)."
    )
    keyframe_change_step: float = Field(
        default=0.03, gt=0, description="Keyframes: weight of scene change, the share of depth pixels that moved since the last keyframe."
    )
    keyframe_max_gap_s: float = Field(default=1.0, gt=0, description="Keyframes: at most this many seconds between keyframes (before the budget widens it).")


class CaptureCheckConfig(StageConfig):
    """Quality checks of an ingested capture."""

    min_valid_depth_frac: float = Field(
        default=0.2, ge=0, le=1, description="Warn about frames whose valid-depth fraction is below this."
    )
    max_speed_m_s: float = Field(default=2.0, gt=0, description="Warn about camera speeds above this (metres/second): tracking jumps.")


Gravity = tuple[float, float, float]


class RegistrationStageConfig(StageConfig):
    """Putting the dynamic recording into the canonical frame (artitwin_core.registration.RegistrationConfig
    and register_recordings; formerly ``RegisterConfig``)."""

    gravity: Gravity = Field(default=(0.0, -1.0, 0.0), description="Gravity direction in both session frames (ARKit: -y).")
    max_depth_m: float = Field(default=4.5, gt=0, description="Depth beyond this is ignored, metres.")
    yaw_step_deg: float = Field(default=2.0, gt=0, le=30, description="Step of the exhaustive yaw sweep about gravity, degrees.")
    photometric: bool = Field(
        default=True,
        description="Finish with a photometric refinement: the dynamic points' colours against the static images pin the "
        "slide along the furniture's front that the geometry leaves free. False skips it.",
    )
    refuse_unconvincing: bool = Field(
        default=True,
        description="Stop with an error naming the scores when no placement of the dynamic recording is convincing "
        "(too little overlap, space the static recording saw empty, two placements about as good). False registers "
        "anyway and keeps the scores in the artifact, for inspection: the later stages may then invent parts.",
    )


class PartMasksConfig(StageConfig):
    """Finding the moved parts and labelling them in every dynamic frame (see artitwin_core.change)."""

    gravity: Gravity = Field(default=(0.0, -1.0, 0.0), description="Gravity direction in the canonical frame.")
    tsdf_voxel_m: float = Field(default=0.02, gt=0, description="Voxel of the canonical TSDF model, metres.")
    tsdf_max_frames: int = Field(default=20, ge=1, description="Static frames fused into the canonical TSDF.")
    max_depth_m: float = Field(default=4.5, gt=0, description="Depth beyond this is ignored, metres.")
    sam2_checkpoint: str | None = Field(
        default=None,
        description="Path of a local SAM2 checkpoint (.pt). When set, the last frame's part labels from the geometric "
        "backend are propagated backwards through the recording by SAM2's video predictor (the 'sam2' package must "
        "import; nothing is downloaded); hand pixels stay the geometric backend's. Unset: geometric backend only.",
    )
    sam2_model_config: str = Field(
        default="configs/sam2.1/sam2.1_hiera_l.yaml", description="SAM2 config name matching sam2_checkpoint."
    )
    parts: PartStageConfig = Field(
        default_factory=PartStageConfig,
        description="The geometric part finder: change tolerances, vanished-surface clustering, door and drawer "
        "hypotheses, growth and hand masks (artitwin_core.change.PartConfig).",
    )


class DepthCalibrationConfig(StageConfig):
    """Finding the depth sensor's error from the static recording and correcting both recordings'
    depth by it, when the effect depth_scale_offset is modelled (artitwin_core.capture.estimate_depth_calibration)."""

    frame_gaps: tuple[int, ...] = Field(
        default=(2, 4, 8), min_length=1, description="Each static frame's depth is compared with the frames this many later."
    )
    max_depth_m: float = Field(default=4.5, gt=0, description="Depth beyond this is not used, metres.")
    min_confidence: int = Field(
        default=1, ge=0, le=2, description="Depth whose ARKit confidence is below this (0 low, 1 medium, 2 high) is not used."
    )
    max_scale_error: float = Field(
        default=0.2, gt=0, le=1, description="An estimated scale further than this from 1 is implausible and not applied."
    )
    max_offset_m: float = Field(default=0.2, gt=0, description="An estimated offset larger than this (metres) is implausible and not applied.")
    max_error_se_m: float = Field(
        default=0.01, gt=0,
        description="The estimate is applied only when the standard error of the depth error it implies at the recording's "
        "median depth is at most this (metres): drifting or jittering poses make it uncertain, and then wrong.",
    )


class PoseDriftConfig(StageConfig):
    """Modelling each recording's pose drift (the effect pose_drift): a turn about gravity and a translation, both
    growing linearly from the first frame (artitwin_core.capture.PoseDrift). The static recording's drift is fitted
    from its own frames (with the sensor's depth error as a nuisance: the two bend the frames' agreement alike), the
    dynamic recording's against the canonical model once its parts are masked
    (artitwin_core.registration.estimate_session_drift)."""

    model: bool = Field(default=False, description="Model the drift (set by the effect pose_drift); off: poses as recorded.")
    gravity: Gravity = Field(default=(0.0, -1.0, 0.0), description="Gravity direction in both recordings' frames.")
    min_displacement_m: float = Field(
        default=0.01, ge=0,
        description="A drift is applied only if it moves a point ahead of the first camera (at the median depth) at least "
        "this far by the last frame, metres.",
    )
    min_z_score: float = Field(
        default=3.0, ge=0, description="... and by at least this many standard errors (frame-block jackknife)."
    )
    max_half_disagreement: float = Field(
        default=1.0, gt=0,
        description="... and the drift rates fitted on each half of the recording alone differ by at most this fraction of "
        "the fitted rate (per-frame jitter or the canonical model's own errors fake trends that change with the frames).",
    )
    mask_dilation_px: int = Field(default=6, ge=0, description="Part and hand masks are grown by this many pixels before they exclude depth and keypoints.")
    max_association_m: float = Field(
        default=0.03, gt=0,
        description="Dynamic depth further than this from the canonical surface ray-cast through its pixel is left out, metres.",
    )
    tsdf_voxel_m: float = Field(default=0.02, gt=0, description="Voxel of the canonical TSDF the dynamic depth is fitted to, metres.")
    tsdf_max_frames: int = Field(default=20, ge=1, description="Static frames fused into that TSDF.")


class PoseLagStageConfig(StageConfig):
    """Each recording's pose lag (the poses late or early against both RGB and depth, as phone exports can be),
    estimated from how well its frames' depth agrees at poses shifted in time (artitwin_core.capture.estimate_pose_lag)
    and corrected right after ingest, before anything is built on the poses: the static recording's before the pose
    refinement and the 3DGS, the dynamic recording's before the registration and the part masks (lagging poses make
    the static background look moved, and phantom parts). Applied only where the evidence is significant."""

    correct: bool = Field(
        default=True,
        description="Correct the poses by the estimated lag where it passes the gate below. Off: the lag is still "
        "estimated and reported (summary.json, the diagnosis), the poses stay as recorded and the correcting stage is "
        "left out of the graph (every later stage keeps its store key).",
    )
    model: bool = Field(
        default=False,
        description="Apply the estimated lag whatever the gate says (set by the effect pose_lag), as long as one was "
        "estimated inside the search range. Needs correct.",
    )
    max_lag_frames: float = Field(
        default=4.0, gt=0, le=20,
        description="Lags from -this to +this many frame intervals (the median spacing of the timestamps) are searched; "
        "shorter on short recordings.",
    )
    min_lag_frames: float = Field(
        default=0.2, ge=0, description="A lag is applied only if it is at least this many frame intervals,"
    )
    min_z_score: float = Field(default=3.0, ge=0, description="... at least this many standard errors from 0,")
    min_agreement_z: float = Field(
        default=2.0,
        description="... and the frames' depth agrees better at it than at the poses as recorded by at least this "
        "z-score (a lag that does not improve agreement is left alone).",
    )
    max_depth_m: float = Field(default=4.5, gt=0, description="Depth beyond this is not compared, metres.")

    @model_validator(mode="after")
    def _model_needs_correct(self) -> PoseLagStageConfig:
        if self.model and not self.correct:
            raise ValueError(
                "pose_lag.model (the effect pose_lag) forces the correction but pose_lag.correct is off; turn correct on "
                "or drop the effect."
            )
        return self


class TrackingStageConfig(StageConfig):
    """Tracking points on each moving part and lifting them to 3D (artitwin_core.tracking.TrackingConfig;
    formerly ``TrackConfig``)."""

    max_tracks: int = Field(default=1000, ge=10, description="Query points per part.")


class JointConfig(StageConfig):
    """How joints are fitted to trajectories (see artitwin_core.joints.JointFitConfig)."""

    reference_frame: int = Field(
        default=0, description="Dynamic frame that defines the closed state q = 0 (the recording starts closed)."
    )
    ransac_iterations: int = Field(default=200, ge=10, description="Minimal 3-point samples per frame.")
    ransac_threshold_m: float = Field(default=0.03, gt=0, description="First inlier threshold on 3D residuals, metres.")
    min_motion_m: float = Field(default=0.002, ge=0, description="Below this RMS displacement the part counts as not moving, metres.")
    screw_bic_margin: float = Field(default=10.0, ge=0, description="BIC units a screw joint must beat a revolute one by.")
    seed: int = Field(default=0, description="RANSAC random seed.")
    model_screw: bool = Field(
        default=False,
        description="Fit every rotating part as a screw joint (rotation with coupled travel along its axis) instead "
        "of testing the pitch for significance: the 'screw_joint' effect enabled without a joint.",
    )
    screw_joints: list[str] = Field(
        default_factory=list,
        description="Fit these joints only as screw joints ('joint_0', ...: this stage's names, joint_<candidate "
        "label - 1>; `artitwin run` translates the diagnosis's settled names): the effect 'joint_0:screw_joint'.",
    )

    @field_validator("screw_joints")
    @classmethod
    def _joint_names(cls, v: list[str]) -> list[str]:
        bad = [n for n in v if not re.fullmatch(r"joint_\d+", n)]
        if bad:
            raise ValueError(f"screw_joints: {bad} are not joint names; give joint_0, joint_1, ...")
        return sorted(set(v), key=lambda n: int(n[6:]))


class SettlePartsConfig(StageConfig):
    """Which candidate parts are parts: kept, merged into the part whose motion explains them, or dropped
    (see artitwin_core.parts.SettleConfig, whose fields these are)."""

    min_depth_points: int = Field(
        default=40, ge=0,
        description="A part needs at least this many distinct depth pixels inside its mask (hand excluded) over the "
        "recording: fewer build no mesh and no inertia, and it is dropped.",
    )
    max_points_per_frame: int = Field(default=600, ge=10, description="Points lifted per frame for the motion tests.")
    min_frame_points: int = Field(default=10, ge=3, description="A frame takes part in the motion tests with at least this many points.")
    merge_max_misfit_m: float = Field(
        default=0.02, gt=0,
        description="A candidate with no joint of its own merges into a neighbouring part when its points, in the frames "
        "that part's motion moved, moved back to the closed state by it lie this close to its closed surface (median "
        "nearest-neighbour distance, metres)...",
    )
    merge_min_ratio: float = Field(
        default=2.0, ge=1, description="... and at least this many times closer than held still (the reverse: it did not move)."
    )
    min_discrimination_m: float = Field(
        default=0.03, gt=0,
        description="Only frames in which the neighbour's motion moves the candidate this far beyond its closed frames (metres) can tell.",
    )
    confirm_min_ratio: float = Field(
        default=1.5, ge=1,
        description="A candidate's own joint is confirmed by its depth when its points, moved back to the closed state by it, lie "
        "at least this many times closer to its closed surface than held still...",
    )
    confirm_min_margin_m: float = Field(
        default=0.01, ge=0,
        description="... and at least this much closer (metres). An unconfirmed joint counts as no joint of its own.",
    )
    min_range_m: float = Field(
        default=0.02, ge=0,
        description="A fitted slide whose states span less than this (metres) is no motion of its own (tracks drifting by millimetres).",
    )
    min_range_deg: float = Field(default=3.0, ge=0, description="... and a fitted turn spanning less than this (degrees).")
    same_axis_deg: float = Field(default=10.0, gt=0, description="Two fitted joints are one when their axes are this close, degrees...")
    same_line_m: float = Field(default=0.05, gt=0, description="... their lines (rotations) pass this close at the candidate, metres...")
    same_state_frac: float = Field(
        default=0.15, ge=0, description="... and their states agree within this fraction of the range (median over frames)"
    )
    same_state_floor: float = Field(default=0.02, ge=0, description="... or within this (radians or metres).")
    adjacency_px: int = Field(default=4, ge=0, description="Candidates whose masks, grown by this many pixels, overlap in a frame are neighbours.")


class JointStateConfig(StageConfig):
    """Refining each joint's per-frame state from depth (see artitwin_core.joints.refine_joint_states)."""

    refine_from_depth: bool = Field(
        default=True,
        description="Refit q(t) of revolute, screw and prismatic joints against the part's depth inside its mask: "
        "the point tracks end when a door's front face turns away or a hand covers a drawer front, and q would be "
        "held from there.",
    )
    max_points: int = Field(default=1500, ge=100, description="Part points lifted per frame.")
    refine_line: bool = Field(
        default=True,
        description="Also fit a revolute slab's (a door's) axis and pivot to the planes its faces show in depth, "
        "where that fit's standard errors are small: tracks on a weakly textured door leave its pivot ~1 cm off.",
    )
    second_opinion: bool = Field(
        default=True,
        description="Where the joint fitted to a part's tracks is unsure (standard errors over the two limits below), "
        "try the part finder's joint, fitted to the change in depth, and keep whichever explains the part's depth "
        "better (artitwin_core.parts.prefer_depth_joint): tracks on a weakly textured door drift.",
    )
    unsure_axis_se_deg: float = Field(
        default=2.0, gt=0, description="A tracks' joint whose axis standard error exceeds this is unsure (degrees)."
    )
    unsure_pivot_se_m: float = Field(
        default=0.03, gt=0, description="A tracks' rotational joint whose line's standard error exceeds this is unsure (m)."
    )
    rgb_time_offset_s: float = Field(
        default=0.0,
        ge=-0.5,
        le=0.5,
        description="Seconds by which the dynamic recording's depth maps and poses are recorded after its RGB "
        "exposures (the diagnosis's time_offset 'seconds'; the effect time_offset). Every state is read from a "
        "frame's depth and pose, so it is moved back to the RGB exposure's time, where the twin is rendered "
        "(artitwin_core.joints.to_rgb_clock). 0: the streams are in sync.",
    )


# The stage whose forward model gains each catalog effect when a user enables it
# (``PipelineConfig.with_effects``), and the effects modelled with a value the diagnosis fits
# (``NAME=VALUE``): the parameter it reports and the stage config field the value sets. Both are
# read off the one table, schemas._effects.MODELLED_EFFECTS (each effect's default scope); where
# each can be modelled is its EFFECT_SCOPES. The other catalog effects are diagnosed only.
EFFECT_STAGES: dict[str, str] = {name: e.stage for name, e in MODELLED.items()}
EFFECT_VALUES: dict[str, tuple[str, str]] = {name: (e.param, e.field) for name, e in MODELLED.items() if e.param}
RECORDING_SCOPES = {"static recording": "static", "dynamic recording": "dynamic"}


def effect_scope(scope: str) -> str:
    """The ``--effect`` scope of a diagnosis scope or a short one (``"dynamic recording"`` ->
    ``"dynamic"``, ``"joint_0"`` stays); ``ValueError`` naming the valid scopes."""
    s = RECORDING_SCOPES.get(scope, scope)
    if s in ("static", "dynamic") or re.fullmatch(r"joint_\d+", s):
        return s
    raise ValueError(
        f"unknown scope {scope!r}; give static, dynamic or a joint (joint_0, joint_1, ...), "
        "as `artitwin diagnose` names them"
    )


def scope_kind(scope: str) -> str:
    """The kind of an ``--effect`` scope as ``EFFECT_SCOPES`` lists it: ``joint_0`` -> ``joint``."""
    return "joint" if scope.startswith("joint_") else scope


def split_effect(entry: str) -> tuple[str | None, str, str | None]:
    """``(scope or None, name, value or None)`` of an ``--effect`` entry ``[SCOPE:]NAME[=VALUE]``;
    the scope is checked (``effect_scope``) and must be one the effect can be modelled in."""
    head, sep, raw = str(entry).partition("=")
    scope, colon, name = head.rpartition(":")
    if not colon:
        return None, name, raw if sep else None
    short = effect_scope(scope)
    kind = scope_kind(short)
    valid = EFFECT_SCOPES.get(name)
    if valid is not None and kind not in valid:
        where = ", ".join("a joint (joint_0, ...)" if v == "joint" else v for v in valid)
        raise ValueError(f"{entry!r}: {name} can be modelled in {where}, not in {scope}")
    return short, name, raw if sep else None


class FramePoseStageConfig(StageConfig):
    """Per-frame pose corrections of the dynamic recording, measured on its static background after part_masks
    (artitwin_core.tracking.estimate_frame_poses): recorded poses jitter by millimetres from frame to frame and the
    part's tracks carry that jitter into the joint. Applied only when the corrections stand out from their
    standard errors (artitwin_core.tracking.FramePoseConfig; formerly ``FramePosesConfig``)."""

    enabled: bool = Field(default=True, description="Fit the corrections (applied only if significant); off: poses as recorded.")
    keyframe_step: int = Field(default=5, ge=1, description="A keyframe every this many frames (and the last frame).")
    reach: int = Field(default=10, ge=1, description="Frames up to this many before and after a keyframe are aligned to it.")
    mask_dilation_px: int = Field(default=8, ge=0, description="Part and hand masks are grown by this many pixels before they exclude the background.")
    model_points: int = Field(default=3000, ge=50, description="Static points per keyframe model.")
    min_ncc: float = Field(default=0.5, ge=-1, le=1, description="Least patch-wise grey-level correlation of a usable alignment.")
    min_chi2_per_dof: float = Field(
        default=10.0, ge=0,
        description="The corrections are applied only if the chi-square of their frame-to-frame part against its standard "
        "errors, per degree of freedom, is at least this (1.3-5.6 on exact poses with or without sensor defects, 110-480 "
        "with 3 mm / 3 mrad of jitter).",
    )
    slow_frames: int = Field(
        default=15, ge=3, description="The corrections' slow part is a straight line in time fitted to this many frames around each frame."
    )
    min_whiteness: float = Field(
        default=0.9, ge=0,
        description="All of the corrections are applied only if they look like white jitter (whiteness at least this); "
        "otherwise only their frame-to-frame part, leaving a slow error (drift, a sensor defect) to the effect that models it.",
    )
    min_depth_agreement: float = Field(
        default=3.0,
        description="... and nothing is applied unless the frames' depth agrees better at the corrected poses, by at least "
        "this z-score (about +10 with jitter; -13 where the RGB lags depth and pose by 33 ms).",
    )


# The CPU budget of the "default" preset (PipelineConfig.preset): a CPU 3DGS step's cost grows with
# the pixels trained on, the diagnosis's with the pixels compared (docs/performance.md: what each costs).
CPU_RECONSTRUCT = {"train_max_side": 384, "steps": 800, "max_init_points": 15_000, "max_gaussians": 30_000}
CPU_ARTICULATE = {"train_max_side": 256, "phase1_steps": 200, "phase2_steps": 100}
# The diagnosis's prediction, on a GPU too: the renders are the GPU's, but the effect fits that read
# them are numpy on the CPU, and their cost grows with the frames and pixels compared (scene (a):
# 29 s at this size against 164 s for every frame at full size, on 2 cores; docs/performance.md).
DIAGNOSIS_PREDICT = {"max_side": 256, "max_frames": 16, "run_frames": 4}


class PipelineConfig(StageConfig):
    """The configs of every stage of one scene run."""

    ingest: IngestConfig = Field(default_factory=IngestConfig, description="Reading both recordings.")
    capture_check: CaptureCheckConfig = Field(default_factory=CaptureCheckConfig, description="Capture quality report.")
    refine_poses: PoseRefineStageConfig = Field(default_factory=PoseRefineStageConfig, description="Static pose refinement.")
    reconstruct: ReconstructConfig = Field(default_factory=ReconstructConfig, description="Canonical 3DGS training.")
    calibrate_depth: DepthCalibrationConfig = Field(
        default_factory=DepthCalibrationConfig,
        description="The depth sensor's error found from the static recording, and both recordings' depth corrected "
        "by it, when depth_scale_offset is modelled.",
    )
    registration: RegistrationStageConfig = Field(default_factory=RegistrationStageConfig, description="Dynamic-to-canonical registration.")
    part_masks: PartMasksConfig = Field(default_factory=PartMasksConfig, description="Part and hand masks.")
    pose_drift: PoseDriftConfig = Field(
        default_factory=PoseDriftConfig, description="Both recordings' pose drift, when pose_drift is modelled."
    )
    pose_lag: PoseLagStageConfig = Field(
        default_factory=PoseLagStageConfig,
        description="Each recording's pose lag against its images, estimated and corrected right after ingest.",
    )
    frame_poses: FramePoseStageConfig = Field(
        default_factory=FramePoseStageConfig, description="Per-frame pose corrections of the dynamic recording from its static background."
    )
    track: TrackingStageConfig = Field(default_factory=TrackingStageConfig, description="3D point tracks on the parts.")
    fit_joints: JointConfig = Field(default_factory=JointConfig, description="Joint fitting.")
    settle_parts: SettlePartsConfig = Field(
        default_factory=SettlePartsConfig, description="Which candidate parts are kept, merged or dropped (and why)."
    )
    joint_states: JointStateConfig = Field(
        default_factory=JointStateConfig, description="Per-frame joint states refined from depth."
    )
    articulate: ArticulateConfig = Field(
        default_factory=ArticulateConfig, description="Stage IV: part/interior/background split and articulated training."
    )
    predict_views: PredictViewsConfig = Field(
        default_factory=PredictViewsConfig, description="Rendering the twin at the static recording's poses."
    )
    diagnose: DiagnoseConfig = Field(default_factory=DiagnoseConfig, description="Model against measurement: effect ranking.")
    export: ExportConfig = Field(default_factory=ExportConfig, description="URDF / MJCF / splat export and the simulator check.")

    def with_effects(self, names) -> PipelineConfig:
        """This config with the physical effects ``names`` (from the diagnosis catalog) enabled in
        the stages that model them (``EFFECT_STAGES``), each ``[SCOPE:]NAME[=VALUE]``: the scope
        (``EFFECT_SCOPES``) says where: ``dynamic:exposure_white_balance`` models the dynamic
        recording's exposure in articulate, ``static:vignetting`` the static one's in reconstruct;
        a bare name takes ``DEFAULT_SCOPES`` (callers that have a diagnosis resolve it first,
        ``flows._runs.scope_bare_effects``). Only those stages' configs change, so a rerun
        reuses every cached artifact upstream of them. An effect the stage cannot fit itself takes
        the value the diagnosis fitted as ``NAME=VALUE`` (``EFFECT_VALUES``: ``time_offset=0.033``).
        ``ValueError`` names an effect no stage models, or a value that is missing or not a number."""
        values: dict[str, float] = {}
        plain = []
        scoped: dict[str, set[str]] = {}  # per-recording effect -> recordings
        joints: dict[str, set[str]] = {}  # per-joint effect -> the joints named (joint_0, ...)
        bare: set[str] = set()  # effects named without a joint (a joint effect then models every joint)
        for entry in names:
            scope, name, raw = split_effect(str(entry))
            if name in EFFECT_VALUES:
                param = EFFECT_VALUES[name][0]
                if raw is None:
                    raise ValueError(
                        f"the effect {name} needs its {param}, as the diagnosis reports it: {name}=VALUE "
                        f"(e.g. {name}=0.033)"
                    )
                try:
                    values[name] = float(raw)
                except ValueError:
                    raise ValueError(f"{entry!r}: the {param} of {name} must be a number (e.g. {name}=0.033)") from None
            elif raw is not None:
                raise ValueError(f"{entry!r}: only {sorted(EFFECT_VALUES)} take a value; give {name} by name alone")
            plain.append(name)
            if name in PER_RECORDING_EFFECTS:
                scoped.setdefault(name, set()).add(scope or DEFAULT_SCOPES[name])
            elif scope is not None and scope_kind(scope) == "joint":
                joints.setdefault(name, set()).add(scope)
            else:
                bare.add(name)
        names = list(dict.fromkeys(plain))
        unknown = [n for n in names if n not in MODELLED]
        if unknown:
            raise ValueError(
                f"no stage models the effect(s) {unknown} yet; effects that can be enabled: {sorted(MODELLED)} "
                "(the diagnosis still ranks the others and reports their fitted parameters)."
            )
        update: dict = {}
        for name in names:
            # An effect with a model per recording goes to each recording asked for; others to their one row.
            kinds = sorted(scoped.get(name, ())) if name in PER_RECORDING_EFFECTS else [DEFAULT_SCOPES[name]]
            for kind in kinds:
                effect = modelled_in(name, kind)
                if effect is None:  # split_effect checks scopes; a bare name takes its default
                    raise ValueError(f"{name} cannot be modelled in the {kind} scope; it can in {EFFECT_SCOPES[name]}")
                current = update.get(effect.stage, getattr(self, effect.stage))
                set_to: dict[str, Any] = dict(effect.also)
                if effect.joint_field is not None and name in joints:  # these joints only
                    set_to[effect.joint_field] = sorted(set(getattr(current, effect.joint_field)) | joints[name])
                if effect.joint_field is None or name in bare:
                    now = getattr(current, effect.field)
                    set_to[effect.field] = sorted(set(now) | {name}) if isinstance(now, list) else (
                        values[name] if effect.param else True)
                # validated: bounds and cross-field rules hold
                update[effect.stage] = current.model_validate({**current.model_dump(), **set_to})
        return self.model_copy(update=update)

    def enabled_effects(self) -> list[str]:
        """The catalog effects this config models (the inverse of ``with_effects``); those with a
        model per recording (``PER_RECORDING_EFFECTS``) with their scope: ``dynamic:vignetting``."""
        out = []
        for effect in MODELLED_EFFECTS:
            value = getattr(getattr(self, effect.stage), effect.field)
            if isinstance(value, list):
                if effect.name in value:
                    out.append(f"{effect.scopes[0]}:{effect.name}" if effect.name in PER_RECORDING_EFFECTS else effect.name)
            elif effect.param:
                if value != 0.0:
                    out.append(f"{effect.name}={value:g}")
            elif value:
                out.append(effect.name)
            if effect.joint_field is not None:
                out += [f"{j}:{effect.name}" for j in getattr(getattr(self, effect.stage), effect.joint_field)]
        return sorted(out)

    @classmethod
    def preset(cls, name: str, gpu: bool = False) -> PipelineConfig:
        """A named starting point:

        - ``"default"``: real captures (a phone recording of hundreds of frames at 1920x1440) on
          the hardware at hand. ``gpu=False`` (a laptop's CPU): RGB worked at 640 pixels on the
          long side whatever the file holds, at most 100 keyframes a recording, SIFT features
          scaled to that resolution with sequential and loop-closure matching beyond 40 frames,
          and 3DGS budgets (steps, Gaussians, training resolution) sized for minutes on 2 cores.
          ``gpu=True`` (CUDA with gsplat; the caller says, e.g. ``flows.gpu_available()``):
          native resolution, 300 keyframes, and a GPU budget (1M Gaussians, 7000 steps); the
          diagnosis's prediction is bounded as on the CPU (16 frames at 256 px), since its effect
          fits run on the CPU whatever renders the prediction.
        - ``"quick"``: the built-in example and the tests: small scenes, a short 3DGS schedule,
          fewer features.
        - ``"full"``: every stage config's own defaults (no resolution cap, no keyframes, the
          original 3DGS schedule), as before presets sized runs for the hardware.
        """
        if name == "full":
            return cls()
        if name == "default":
            return cls._real_capture(gpu)
        if name == "quick":
            return cls(
                refine_poses=PoseRefineStageConfig(max_features=1024),
                reconstruct=ReconstructConfig(steps=300, max_init_points=8000, max_gaussians=15000, sh_degree=1),
                articulate=ArticulateConfig(phase1_steps=120, phase2_steps=60),
            )
        raise ValueError(f"unknown pipeline preset {name!r}; known: default, quick, full")

    @classmethod
    def _real_capture(cls, gpu: bool) -> PipelineConfig:
        poses = PoseRefineStageConfig(max_features=None, exhaustive_max_frames=40, loop_closure_pairs=5, extraction_threads=0)
        if gpu:
            return cls(
                ingest=IngestConfig(rgb_max_side=None, keyframes_max=300),
                refine_poses=poses,
                reconstruct=ReconstructConfig(steps=7000, max_init_points=200_000, max_gaussians=1_000_000),
                articulate=ArticulateConfig(phase1_steps=1500, phase2_steps=750, seed_max_points=100_000,
                                            seed_background_max_points=100_000),
                predict_views=PredictViewsConfig(**DIAGNOSIS_PREDICT),
            )
        return cls(
            ingest=IngestConfig(rgb_max_side=640, keyframes_max=100),
            refine_poses=poses,
            reconstruct=ReconstructConfig(**CPU_RECONSTRUCT),
            articulate=ArticulateConfig(**CPU_ARTICULATE),
            predict_views=PredictViewsConfig(**DIAGNOSIS_PREDICT),
        )
