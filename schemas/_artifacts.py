"""Every artifact the pipeline passes between stages, with units and frames in each field.

Field names match the dataclasses in ``artitwin_core`` (the ``tasks`` layer converts between the
two by name). Frames: "canonical" is the static recording's world frame; "session" is a
recording's own AR world frame; cameras use OpenCV axes (x right, y down, z forward).
"""

from __future__ import annotations

import math

from pydantic import Field

from schemas._base import Array, Artifact
from schemas._vocab import Fate, JointType

# ----------------------------------------------------------------------------------------------
# Captures and poses
# ----------------------------------------------------------------------------------------------


class CaptureArtifact(Artifact):
    """One RGB-D recording as read from its files (mirrors ``artitwin_core.capture.Capture``)."""

    kind = "capture"
    schema_version = 2

    rgb: Array("uint8", "T H W 3") = Field(description="sRGB frames, [T, H, W, 3] uint8.")
    depth: Array("float32", "T h w") = Field(
        description="z-depth along the optical axis in metres at depth resolution, [T, h, w]; NaN = no measurement."
    )
    confidence: Array("uint8", "T h w") | None = Field(
        default=None, description="ARKit depth confidence 0 (low), 1, 2 (high), [T, h, w]; None if the format has none."
    )
    rgb_intrinsics: Array("float64", "T 4") = Field(
        description="Pinhole (fx, fy, cx, cy) in pixels at RGB resolution, per frame, [T, 4]."
    )
    depth_intrinsics: Array("float64", "T 4") = Field(
        description="Pinhole (fx, fy, cx, cy) in pixels at depth resolution, per frame, [T, 4]."
    )
    world_from_camera: Array("float64", "T 4 4") = Field(
        description="Camera-to-world rigid transforms in the recording's session frame, metres, OpenCV camera axes, [T, 4, 4]."
    )
    timestamps: Array("float64", "T") = Field(description="Seconds since the recording's first frame, [T].")
    frame_ids: Array("int64", "T") = Field(description="Frame numbers in the source files (may have gaps), [T].")
    distortion: Array("float64", "K") | None = Field(
        default=None, description="OpenCV distortion k1 k2 p1 p2 [k3 ...] of the RGB images; None = pinhole."
    )
    source_format: str = Field(description="Reader that produced it: record3d-r3d, record3d-exr, nerfstudio, stray, synthetic.")
    source_path: str = Field(default="", description="Path of the recording as given by the user (informational, not hashed).")
    stream_world_from_camera: Array("float64", "S 4 4") | None = Field(
        default=None,
        description="Every pose the recording holds, the frames' and those of frames not read (removed, strided, not "
        "keyframes), as recorded, [S, 4, 4]; None when it holds none beyond the frames'. Read by the pose-lag stages.",
    )
    stream_timestamps: Array("float64", "S") | None = Field(
        default=None, description="Seconds of the stream's poses on the frames' clock, increasing, [S]."
    )
    stream_frame_ids: Array("int64", "S") | None = Field(default=None, description="Frame numbers of the stream's poses, [S].")


class CameraPoses(Artifact):
    """Camera poses of a recording in some world frame (e.g. refined or registered)."""

    kind = "camera_poses"
    schema_version = 1

    world_from_camera: Array("float64", "T 4 4") = Field(
        description="Camera-to-world rigid transforms, metres, OpenCV camera axes, [T, 4, 4], in the frame named by `frame`."
    )
    frame_ids: Array("int64", "T") = Field(description="Frame numbers of the recording these poses belong to, [T].")
    frame: str = Field(description="World frame of the poses: 'canonical' or 'session'.")
    correction_translation: Array("float64", "T") | None = Field(
        default=None, description="Per-frame size of the change from the input poses, metres, [T] (None if none was made)."
    )
    correction_rotation: Array("float64", "T") | None = Field(
        default=None, description="Per-frame rotation change from the input poses, degrees, [T] (None if none was made)."
    )


class Registration(Artifact):
    """Rigid transform that puts the dynamic recording into the canonical frame."""

    kind = "registration"
    schema_version = 4

    canonical_from_session: Array("float64", "4 4") = Field(
        description="Maps points from the dynamic recording's session frame to the canonical frame (metres), [4, 4]."
    )
    residual_m: float = Field(description="Robust RMS point-to-plane residual after refinement, metres.")
    inlier_fraction: float = Field(description="Fraction of dynamic depth points within the inlier distance, in [0, 1].")
    method: str = Field(description="How it was found, e.g. 'fpfh-ransac+icp+photometric'.")
    covariance: Array("float64", "6 6") | None = Field(
        default=None,
        description=(
            "Covariance of the transform's error (w, v): the small motion x -> x + w x x + v (radians, metres, "
            "canonical frame) that would correct it, from a spatial block jackknife, [6, 6]; None = not estimated."
        ),
    )
    hypothesis: str = Field(default="", description="Which hypothesis won, e.g. 'identity' or 'yaw sweep 132 deg'.")
    support: float = Field(
        default=float("nan"),
        description="The winner's score: per dynamic frame (early frames weighted more), points on static surfaces minus "
        "points in space the static recording saw through minus rays through static surfaces, per point; at most 1.",
    )
    rival_support: float = Field(
        default=float("nan"),
        description="The same score of the best hypothesis placing the dynamic points elsewhere (over 0.5 m RMS away); "
        "NaN if none.",
    )
    overlap: float = Field(
        default=float("nan"), description="Fraction of the dynamic points that fall where the static recording looked, in [0, 1]."
    )
    overlap_inlier_ratio: float = Field(
        default=float("nan"), description="Of those, the fraction on static surfaces (the rest in its free space), in [0, 1]."
    )
    weakest_constraint: float = Field(
        default=float("nan"),
        description="How well the matched points pin the yaw-and-translation motion in its weakest direction "
        "(1/3 for three orthogonal planes in equal shares, 0 for one plane).",
    )
    tilt_deg: float = Field(
        default=0.0, description="Angle between gravity and gravity mapped through canonical_from_session, degrees."
    )
    colour_agreement: float = Field(
        default=float("nan"),
        description="Correlation (-1 to 1) of the winner's matched dynamic colours with the static surface's, each about "
        "its surface's mean: about 0 when the shapes match but the surfaces are other ones (a corner onto another "
        "corner); NaN when there was no texture to compare.",
    )
    colour_contrast: float = Field(
        default=0.0, description="RMS of the static intensity (0-1) about each matched surface's mean: the texture the "
        "colour agreement was measured on.",
    )


class DepthCalibrationResult(Artifact):
    """The depth sensor's affine error, ``measured = scale * true + offset_m``, and how well the
    recording's frames agree once it is undone."""

    kind = "depth_calibration"
    schema_version = 1

    scale: float = Field(description="Scale error of the sensor's depth (1 = none).")
    offset_m: float = Field(description="Offset error of the sensor's depth, metres (0 = none).")
    residual_m: float = Field(description="Robust spread of the frames' point-to-plane disagreement after calibration, metres.")
    points_count: int = Field(description="Point pairs in the final fit.")
    method: str = Field(description="How it was found, e.g. 'multi-view-depth-consistency'.")
    scale_se: float = Field(default=float("nan"), description="Standard error of scale (frame-block jackknife); NaN if unknown.")
    offset_m_se: float = Field(default=float("nan"), description="Standard error of offset_m, metres; NaN if unknown.")
    reference_depth_m: float = Field(default=float("nan"), description="Median depth of the points fitted, metres.")
    error_se_m: float = Field(
        default=float("nan"), description="Standard error of the depth error (scale - 1) z + offset at reference_depth_m, metres."
    )
    applied: bool = Field(
        default=True, description="Whether calibrate_depth corrects the depth with it (False: too uncertain or implausible)."
    )
    note: str = Field(default="", description="Why it is not applied, in words; empty when it is.")


class PoseDriftResult(Artifact):
    """A recording's fitted pose drift (artitwin_core.capture.PoseDrift) and whether it is applied:
    ``corrected(t) = G(t) @ recorded(t)``, ``G(t) = G_rate(t - t0_s) @ G_offset``, rigid motions about
    ``pivot``, in the recording's own world frame."""

    kind = "pose_drift"
    schema_version = 1

    recording: str = Field(description="Which recording: 'static' or 'dynamic'.")
    pivot: Array("float64", "3") = Field(description="The point the correction turns about (the first camera), metres, [3].")
    t0_s: float = Field(description="Time at which the rate part is zero, seconds (the recording's clock).")
    rot0_rad: Array("float64", "3") = Field(description="Constant part: rotation vector, radians, [3].")
    trans0_m: Array("float64", "3") = Field(description="Constant part: translation, metres, [3].")
    rot_rate_rad_per_s: Array("float64", "3") = Field(description="Rate part: rotation vector per second, [3].")
    trans_rate_m_per_s: Array("float64", "3") = Field(description="Rate part: translation per second, metres, [3].")
    point: Array("float64", "3") = Field(
        description="Reference point ahead of the first camera at the median depth, metres, [3] (the canonical frame for "
        "the dynamic recording)."
    )
    displacement_m: Array("float64", "3") = Field(description="How far the rate part moves the point by the last frame, metres, [3].")
    displacement_se_m: Array("float64", "3") = Field(description="Its standard errors (frame-block jackknife), metres, [3].")
    z_score: float = Field(description="The displacement's size over its standard error along it.")
    rate_m_per_s: Array("float64", "3") = Field(description="How fast the drift moves the point, m/s, [3].")
    half_rates_m_per_s: Array("float64", "2 3") | None = Field(
        default=None, description="The same rate fitted on each half of the recording alone, [2, 3]; None if not fitted."
    )
    residual_m: float = Field(description="Robust spread of the depth terms after the fit, metres.")
    method: str = Field(description="How it was fitted.")
    applied: bool = Field(description="Whether correct_pose_drift corrects the poses with it.")
    note: str = Field(default="", description="Why it is not applied, in words; empty when it is.")


class PoseLagResult(Artifact):
    """How late a recording's poses are against its RGB-D frames (``artitwin_core.capture.estimate_pose_lag``)
    and whether ``correct_pose_lag`` corrects them: the camera's pose at ``timestamps[i]`` is the
    recorded trajectory's at ``timestamps[i] + lag_s``."""

    kind = "pose_lag"
    schema_version = 1

    estimated: bool = Field(description="Whether a lag was estimated (False: too few frames, or the stage was turned off).")
    lag_s: float = Field(description="The lag, seconds: positive when the poses are late, negative when early; 0 when not estimated.")
    lag_frames: float = Field(description="The lag in frame intervals (lag_s / frame_interval_s).")
    lag_se_s: float = Field(description="Standard error of lag_s (frame-block jackknife), seconds; NaN when not estimated.")
    frame_interval_s: float = Field(description="The median spacing of the recording's timestamps, seconds (one 'frame').")
    pose_interval_s: float = Field(
        default=math.nan,
        description="The median spacing of the poses the corrected trajectory is read off between, seconds: the pose "
        "stream's (a phone records one per frame, kept or not) when the capture has one, else frame_interval_s; NaN when "
        "not estimated or stored before it was recorded.",
    )
    z_score: float = Field(description="|lag_s| over its standard error; 0 when not estimated.")
    agreement_z: float = Field(
        description="How much better the frames' depth agrees at the lag than at the poses as recorded, in standard errors "
        "of that difference (frame-block jackknife); 0 when not estimated."
    )
    disagreement_zero: float = Field(
        description="Fraction of projected depth that disagrees (robust, 0 to 1) at the poses as recorded; NaN when not estimated."
    )
    disagreement_lag: float = Field(description="The same at the lag; NaN when not estimated.")
    residual_zero_m: float = Field(
        description="Median absolute depth misfit of the agreeing points at the poses as recorded, metres; NaN when not estimated."
    )
    residual_lag_m: float = Field(description="The same at the lag, metres; NaN when not estimated.")
    lags_frames: Array("float64", "N") = Field(description="The lags scored, frame intervals, increasing, [N]; empty when not estimated.")
    disagreement: Array("float64", "N") = Field(description="The disagreement at each of them (0 to 1), [N].")
    searched_frames: float = Field(description="The lags searched: -searched_frames to +searched_frames frame intervals.")
    frames_used: int = Field(description="Frames whose depth was compared (those kept clear of the recording's ends).")
    pairs: int = Field(description="Frame pairs compared.")
    method: str = Field(description="How it was estimated.")
    significant: bool = Field(
        description="Whether it passed the gate (PoseLagStageConfig: its size, its z-score, and the frames' depth agreeing "
        "better at it)."
    )
    applied: bool = Field(description="Whether correct_pose_lag corrects the poses by it.")
    forced: bool = Field(
        default=False, description="Whether it was applied because the effect pose_lag is modelled, whatever the gate said."
    )
    note: str = Field(default="", description="What was done and why, in words (why it was not applied, or that it was forced).")


class FramePoseCorrections(Artifact):
    """Per-frame corrections of a recording's poses measured on its static background
    (``artitwin_core.tracking.estimate_frame_poses``): ``corrected[t] = corrections[t] @ recorded[t]``,
    in the recording's own world frame."""

    kind = "frame_pose_corrections"
    schema_version = 1

    recording: str = Field(description="Which recording: 'dynamic' (the static one is refined by refine_poses).")
    corrections: Array("float64", "T 4 4") = Field(
        description="Rigid motions applied to each frame's world_from_camera, session frame, metres, [T, 4, 4]; identity "
        "where not applied."
    )
    pivot: Array("float64", "3") = Field(description="The point the corrections' rotations are taken about, session frame, metres, [3].")
    rotation_rad: Array("float64", "T 3") = Field(description="Each frame's fitted correction: rotation vector, radians, [T, 3].")
    translation_m: Array("float64", "T 3") = Field(description="... and how far it moves the pivot, metres, [T, 3].")
    rotation_se_rad: Array("float64", "T") = Field(description="Standard error of each frame's rotation (RMS over components), radians, [T]; inf where unmeasured.")
    translation_se_m: Array("float64", "T") = Field(description="Standard error of each frame's translation (RMS over components), metres, [T]; inf where unmeasured.")
    pairs: int = Field(description="Keyframe-to-frame alignments tried.")
    pairs_used: int = Field(description="Alignments that passed the checks and were not down-weighted as outliers.")
    chi2_per_dof: float = Field(description="The fitted corrections against their standard errors, chi-square per degree of freedom.")
    fast_chi2_per_dof: float = Field(
        description="The same for their frame-to-frame part (less a straight line in time over FramePoseStageConfig.slow_frames frames)."
    )
    whiteness: float = Field(
        description="How much the corrections change from frame to frame against how much they vary overall: about 1 for "
        "white jitter, near 0 for a slow error such as drift or a sensor defect that moves with the viewpoint."
    )
    depth_agreement: float = Field(
        default=0.0,
        description="How much better the frames' depth agrees at the corrected poses than at the recorded ones, a z-score "
        "(negative: the grey levels disagree with depth and pose, as with an RGB lag); 0 when not measured.",
    )
    applied: bool = Field(description="Whether correct_frame_poses corrects the poses with them (any part).")
    applied_part: str = Field(
        default="none",
        description="Which part 'corrections' holds: 'all' (jitter alone), 'frame-to-frame' (the slow part, which looks "
        "like drift or a sensor defect, left alone) or 'none'.",
    )
    note: str = Field(default="", description="What was not applied and why, in words; empty when everything was.")


# ----------------------------------------------------------------------------------------------
# Masks and tracks
# ----------------------------------------------------------------------------------------------


class PartFateArtifact(Artifact):
    """What became of one candidate part (mirrors ``artitwin_core.parts.PartFate``)."""

    kind = "part_fate"
    schema_version = 1

    candidate: int = Field(description="The candidate's index in the part finder's list (onset order).")
    fate: Fate = Field(description="'kept' (a part with a joint of its own), 'merged' (into the part whose motion explains it) or 'dropped'.")
    stage: str = Field(description="The stage that decided: part_masks, fit_joints or settle_parts.")
    reason: str = Field(default="", description="Why, in words with the numbers that decided; empty when kept.")
    into: int | None = Field(default=None, description="Merged: the candidate it joined; else None.")
    part: int | None = Field(
        default=None, description="The final part it is or joined (joint k, final mask label k + 1, link part_k); None when dropped."
    )
    label: int = Field(default=0, description="Its mask label in part_masks' masks; 0 when it was never labelled.")


class MaskSequenceArtifact(Artifact):
    """Per-frame part and hand masks of the dynamic recording (mirrors ``artitwin_core.masks.MaskSequence``).

    ``part_masks`` labels its candidate parts (``candidates`` says which); ``final_masks`` relabels
    them to the settled parts (label k + 1 = joint k), and carries every candidate's fate."""

    kind = "mask_sequence"
    schema_version = 3  # 3: depth_joints

    part: Array("uint8", "T H W") = Field(description="Part labels at RGB resolution: 0 = not a moving part, k + 1 = part k, [T, H, W].")
    hand: Array("bool", "T H W") = Field(description="Hand and arm pixels at RGB resolution, [T, H, W].")
    score: Array("float32", "T") = Field(description="Per-frame confidence of the part mask in [0, 1], [T].")
    candidates: Array("int32", "K") | None = Field(
        default=None,
        description="The part finder's candidate index of each label (label k + 1 is candidates[k]), [K]; None: label - 1.",
    )
    fates: list[PartFateArtifact] = Field(
        default_factory=list,
        description="Candidates that are not (or not only) a label here, and why: those the part finder merged or dropped "
        "before labelling; in the final masks, every candidate.",
    )
    depth_joints: list[JointParams] = Field(
        default_factory=list,
        description="The part finder's joint of each label (label k + 1 is depth_joints[k]), fitted to the change in "
        "depth, with its states as the masks were propagated: a second opinion beside the joint fitted to the tracks. "
        "Empty where not recorded.",
    )


class TrajectoriesArtifact(Artifact):
    """Point tracks over a recording, padded (mirrors ``artitwin_core.tracking.Trajectories``)."""

    kind = "trajectories"
    schema_version = 2

    points_in_world: Array("float64", "T N 3") = Field(
        description="3D track positions in the canonical frame, metres, [T, N, 3]; NaN where invalid."
    )
    pixels: Array("float32", "T N 2") = Field(description="Track positions (x, y) in RGB pixels, [T, N, 2]; NaN where invalid.")
    valid: Array("bool", "T N") = Field(description="True where the track has a reliable 3D position in that frame, [T, N].")
    query_frame: int = Field(default=0, description="Index (into T) of the frame the tracks were seeded in.")
    part_ids: Array("int32", "N") | None = Field(
        default=None, description="Moving part of each track (0 = mask label 1), [N]; None when all are on one part."
    )
    notes: list[str] = Field(default_factory=list, description="Parts whose tracking failed, and why.")


# ----------------------------------------------------------------------------------------------
# Joints
# ----------------------------------------------------------------------------------------------


class JointParams(Artifact):
    """One estimated joint in the canonical frame (mirrors ``artitwin_core.joints.Joint``)."""

    kind = "joint"
    schema_version = 2

    joint_type: JointType = Field(description="'revolute', 'prismatic', 'screw' or 'fixed'.")
    axis: Array("float64", "3") = Field(description="Unit axis direction in the canonical frame, [3].")
    pivot: Array("float64", "3") = Field(description="A point on the axis line in the canonical frame, metres, [3].")
    q: Array("float64", "T") = Field(
        description="Joint state per dynamic frame: radians (revolute, screw) or metres (prismatic); 0 = closed/canonical, [T]."
    )
    q_range: Array("float64", "2") = Field(description="(q_min, q_max) range of motion, same units as q, [2].")
    residual: Array("float64", "T") = Field(
        description="Per-frame RMS distance of tracked part points to their joint-predicted positions, metres, [T]; NaN = no tracks."
    )
    confidence: Array("float64", "T") = Field(description="Per-frame confidence of q in [0, 1], [T].")
    pitch: float = Field(default=0.0, description="Screw joints: axial translation per radian, metres/radian; 0 otherwise.")
    axis_se_rad: float | None = Field(
        default=None,
        description="Standard error of the axis direction, radians, from the frames' scatter about the fit; None = not estimated.",
    )
    pivot_se_m: float | None = Field(
        default=None,
        description="Standard error of the axis line's position across the axis, metres (worse direction); None = not estimated.",
    )
    name: str = Field(default="joint_0", description="Joint name (sanitised for URDF/MJCF on export).")


class JointSet(Artifact):
    """All joints of a scene (one per moving part), with the fit's model-selection evidence.

    ``fit_joints`` fits the candidate parts (``mask_labels``: whose tracks each joint was fitted to);
    ``settle_parts`` keeps, merges or drops each candidate and numbers the kept ones again (joint
    k moves final mask label k + 1; ``label_map`` maps the candidate labels onto those)."""

    kind = "joint_set"
    schema_version = 4

    joints: list[JointParams] = Field(description="One joint per moving part, in the canonical frame.")
    selection: dict[str, dict[str, float]] = Field(
        default_factory=dict,
        description="Per joint name: score of each joint-type hypothesis (e.g. BIC, lower is better).",
    )
    rgb_time_offset_s: float = Field(
        default=0.0,
        description="0: each state is the part's at its frame's depth map and pose. Else the states are on the RGB "
        "clock (the effect time_offset): the part's at the frame's RGB exposure, its depth map and pose (and tracks "
        "lifted with them) being this many seconds later.",
    )
    timestamps: Array("float64", "T") | None = Field(
        default=None, description="The frames' RGB times (seconds) when rgb_time_offset_s is not 0, [T]; else None."
    )
    depth_clock_q: Array("float64", "J T") | None = Field(
        default=None,
        description="When rgb_time_offset_s is not 0: each joint's states as measured, on its frames' depth-map clock "
        "(joints order), [J, T], for comparisons with the depth and the tracks lifted from it; else None.",
    )
    mask_labels: list[int] | None = Field(
        default=None,
        description="The candidate mask label (part_masks' masks, and the tracks' part_ids + 1) of each joint; None: "
        "joint k is label k + 1.",
    )
    label_map: Array("int32", "L") | None = Field(
        default=None,
        description="Settled sets: the final mask label (k + 1 = joint k, 0 = not a part) of each candidate mask label, "
        "[L] (index 0 unused); None: the candidate labels are final.",
    )
    fates: list[PartFateArtifact] = Field(
        default_factory=list, description="What became of the candidate parts: every candidate once settled."
    )
    notes: list[str] = Field(default_factory=list, description="Per-part problems the stage contained (a failed fit or refinement), in words.")


# ----------------------------------------------------------------------------------------------
# Gaussians
# ----------------------------------------------------------------------------------------------


class GaussianCheckpoint(Artifact):
    """3D Gaussian splatting parameters in the canonical frame (mirrors ``artitwin_core.gaussians.GaussianParams``)."""

    kind = "gaussian_checkpoint"
    schema_version = 1

    means: Array("float32", "N 3") = Field(description="Gaussian centres in the canonical frame, metres, [N, 3].")
    quats_wxyz: Array("float32", "N 4") = Field(description="Rotations as scalar-first quaternions (w, x, y, z), unnormalised, [N, 4].")
    log_scales: Array("float32", "N 3") = Field(description="Natural log of per-axis standard deviations in metres, [N, 3].")
    opacity_logits: Array("float32", "N") = Field(description="Logit of opacity (opacity = sigmoid), [N].")
    sh: Array("float32", "N K 3") = Field(
        description="Spherical-harmonic RGB coefficients, K = (degree + 1)^2, DC first (colour = 0.5 + C0 * sh_dc), [N, K, 3]."
    )
    labels: Array("int32", "N") = Field(description="Part label per Gaussian: 0 background, 1 interior, 2 + k part k, [N].")
    step: int = Field(default=0, description="Optimisation steps taken to produce it.")
    sensor_effects: list[str] = Field(
        default_factory=list, description="Camera effects learned with the Gaussians (empty = an ideal camera)."
    )
    sensor_frames: Array("int64", "V") | None = Field(
        default=None, description="Frame indices (positions in the capture) the per-frame gains belong to, ascending, [V]."
    )
    sensor_log_gain: Array("float64", "V 3") | None = Field(
        default=None, description="Natural log of the per-frame linear-RGB gain, [V, 3] (exposure and white balance)."
    )
    sensor_offset: Array("float64", "V 3") | None = Field(default=None, description="Per-frame linear-RGB offset, [V, 3].")
    sensor_vignetting: list[float] | None = Field(
        default=None, description="(c1, c2) of the radial gain 1 + c1 r^2 + c2 r^4, r = 1 at the farthest corner."
    )
    depth_scale: float = Field(default=1.0, description="The depth sensor's scale error: measured = scale * true + offset.")
    depth_offset_m: float = Field(default=0.0, description="The depth sensor's offset error, metres.")
    sensor_distortion: list[float] | None = Field(
        default=None,
        description="OpenCV k1 k2 p1 p2 of the RGB lens the renders were distorted with (learned, or as the capture "
        "records it); None = pinhole.",
    )


# ----------------------------------------------------------------------------------------------
# Reports
# ----------------------------------------------------------------------------------------------


class ReportImage(Artifact):
    """One image of a report (a mask overlay, a residual map)."""

    kind = "report_image"
    schema_version = 1

    pixels: Array("uint8", "H W 3") = Field(description="sRGB image, [H, W, 3] uint8.")
    caption: str = Field(description="What the image shows, one line.")


class StageReport(Artifact):
    """What a stage measured about its own result, for people and dashboards."""

    kind = "stage_report"
    schema_version = 1

    stage: str = Field(description="Stage name, e.g. 'ingest'.")
    metrics: dict[str, float] = Field(
        default_factory=dict, description="Named scalar metrics; the unit is the name's suffix (_m, _deg, _db, _s, _frac, _count)."
    )
    notes: list[str] = Field(default_factory=list, description="Warnings and remarks for the user, one line each.")
    per_frame: dict[str, list[float]] = Field(
        default_factory=dict, description="Named per-frame curves (same unit convention as metrics)."
    )
    images: list[ReportImage] = Field(default_factory=list, description="Images for the UI.")
