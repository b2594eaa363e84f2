"""Hyperparameters of the capture stages: depth calibration (:class:`DepthCalibrationConfig`),
the vignetting test (:class:`VignettingConfig`), keyframe selection (:class:`KeyframeConfig`) and the pose-lag fit (:class:`PoseLagConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass

from artitwin_core._errors import InputError


@dataclass(frozen=True)
class DepthCalibrationConfig:
    """Hyperparameters of :func:`estimate_depth_calibration`.

    Attributes:
        frame_gaps: each frame is compared with the frames this many frames later.
        pixel_stride: every n-th depth pixel each way is used.
        max_depth_m: depth beyond this is not used.
        min_confidence: depth whose ARKit confidence (0 low, 1 medium, 2 high) is below this is
            not used, in either frame of a pair (0 uses all; captures without confidence use all).
        min_facing_cos: surfaces seen more obliquely than this (cosine of the angle between the
            surface normal and the viewing ray) are not used: their depth is the least certain.
        edge_m: a projected point whose four neighbouring depths span more than this lies on a
            depth edge and is not used.
        iterations: re-associations (each a weighted least-squares solve), at most.
        step_tolerance_m: stop before ``iterations`` once a re-association moves the answer by
            less than this (metres): the depth correction at 2 m and the drift's displacement
            by the last frame, 2 m ahead of the first camera. 0 (the default): always run
            ``iterations``. The diagnosis's self-consistency test uses 0.1 mm, a hundredth of
            its gates; the reassociations then oscillate by hundredths of a millimetre.
        jackknife_blocks: the standard errors come from leaving out this many blocks of
            consecutive frames in turn (a frame's points share its pose and depth-map errors, so
            points are not independent).
        estimate_depth: fit the depth error (False: take the depth as metric and fit the drift
            alone).
        pose_drift: fit the poses' linear drift (a turn about ``gravity`` and a translation, both
            growing with time from the first frame) with the depth error. Drift bends the frames'
            agreement as a depth error does, so the two are fitted together; SIFT matches between
            frames (``feature_gaps`` apart) fix the drift along surfaces, where depth is blind.
        gravity: direction of gravity in the recording's world frame.
    """

    frame_gaps: tuple[int, ...] = (2, 4, 8)
    pixel_stride: int = 2
    max_depth_m: float = 4.5
    min_confidence: int = 1
    min_facing_cos: float = 0.5
    edge_m: float = 0.02
    iterations: int = 8
    step_tolerance_m: float = 0.0
    jackknife_blocks: int = 8
    estimate_depth: bool = True
    pose_drift: bool = False
    gravity: tuple[float, float, float] = (0.0, -1.0, 0.0)
    feature_gaps: tuple[int, ...] = (2, 4, 8, 16)


@dataclass(frozen=True)
class VignettingConfig:
    """Hyperparameters of :func:`estimate_vignetting`.

    Attributes:
        frame_gaps: each frame is compared with the frames this many frames later (farther
            frames see a surface at more different radii, nearer ones overlap more).
        pixel_stride: every n-th depth pixel each way is used.
        max_side: the RGB frames are compared at most this many pixels on the long side (the
            vignetting is smooth; finer pixels add only pose and depth error).
        max_depth_m: depth beyond this is not used.
        min_confidence: depth whose ARKit confidence is below this is not used.
        occlusion_rel: a point whose depth in the second frame differs from that frame's own
            depth by more than this share of it is hidden there (or moved) and not used.
        max_srgb: pixels with a channel at or above this sRGB value are clipped and not used.
        min_linear: pixels with a channel at or below this linear value are too dark (noise
            dominates their log) and not used.
        max_log_gradient: pixels where the log intensity changes by more than this per pixel
            (an edge or texture) are not used: a pixel's misplacement moves their value most.
        min_pair_points: a frame pair with fewer usable points is skipped.
        iterations: reweighted least-squares solves.
        jackknife_blocks: the standard error comes from leaving out this many blocks of
            consecutive frames in turn.
    """

    frame_gaps: tuple[int, ...] = (2, 4, 8)
    pixel_stride: int = 2
    max_side: int = 320
    max_depth_m: float = 4.5
    min_confidence: int = 1
    occlusion_rel: float = 0.03
    max_srgb: float = 0.97
    min_linear: float = 0.004
    max_log_gradient: float = 0.05
    min_pair_points: int = 50
    iterations: int = 5
    jackknife_blocks: int = 8

    def __post_init__(self) -> None:
        if not self.frame_gaps or min(self.frame_gaps) < 1:
            raise InputError(f"VignettingConfig.frame_gaps must be positive frame counts, got {self.frame_gaps}.")
        if self.pixel_stride < 1 or self.max_side < 8:
            raise InputError(
                f"VignettingConfig: pixel_stride {self.pixel_stride} must be >= 1 and max_side {self.max_side} >= 8."
            )


@dataclass(frozen=True)
class KeyframeConfig:
    """How keyframes are chosen (see the module docstring).

    Attributes:
        max_frames: keep at most this many frames; a recording this long or shorter is kept whole.
        view_step: relative weight of view change: a keyframe per this much camera travel over the
            median depth plus rotation in radians (0.05: 5 cm at 1 m, or 2.9 degrees).
        change_step: relative weight of scene change: a keyframe per this share of the depth
            pixels that moved by more than ``depth_tol_m`` (+2 % of the depth) since the last one.
        max_gap_s: never more than this many seconds between keyframes (before the thresholds
            are scaled to meet ``max_frames``, which may widen it).
        depth_tol_m: depth agreement tolerance of the scene-change test, metres.
        grid_px: depth maps are sampled every this many pixels for the tests.
        coverage_voxel_m: voxel edge of the coverage test, metres.
        min_new_coverage: a frame is added back when at least this share of its voxels is seen
            by no keyframe (at most ``max_frames // 10`` such frames, best first).
    """

    max_frames: int = 120
    view_step: float = 0.05
    change_step: float = 0.03
    max_gap_s: float = 1.0
    depth_tol_m: float = 0.03
    grid_px: int = 4
    coverage_voxel_m: float = 0.1
    min_new_coverage: float = 0.25

    def __post_init__(self) -> None:
        if self.max_frames < 2:
            raise InputError(f"KeyframeConfig.max_frames is {self.max_frames}; keep at least 2 frames.")
        if self.view_step <= 0 or self.change_step <= 0 or self.max_gap_s <= 0:
            raise InputError("KeyframeConfig.view_step, change_step and max_gap_s must be positive.")


@dataclass(frozen=True)
class PoseLagConfig:
    """Hyperparameters of :func:`estimate_pose_lag`.

    Attributes:
        max_lag_frames: the lags searched, ``[-max, +max]`` frame intervals (the median spacing of
            the timestamps); shrunk on short recordings so that at least ``min_frames`` frames
            keep their poses inside the recorded span at every lag.
        coarse_step_frames: step of the search over the whole range, frame intervals.
        fine_step_frames: step of the second search, within ``fine_half_width_frames`` of the
            coarse minimum.
        fine_half_width_frames: half-width of the second search, frame intervals.
        fit_half_width_frames: the lag is the vertex of a parabola fitted to the scores within
            this many frame intervals of the best one.
        frame_gaps: each frame's depth is projected into the frames this many frames before and
            after it.
        points_per_frame: depth pixels drawn per frame and pair (fewer when ``max_points`` binds).
        max_points: at most this many projected points per lag, over all pairs (bounds the time
            on long recordings).
        robust_scale_m: a point whose depth misses by this much scores half of a point that is
            missed entirely (Geman-McClure scale), metres; the fine search and the agreement test
            count only points within this of the other frame's depth.
        max_depth_m: depth beyond this is not used, metres.
        min_confidence: depth whose ARKit confidence (0 low, 1 medium, 2 high) is below this is not
            used, in either frame of a pair (captures without confidence use all).
        edge_m: a projected point whose four neighbouring depths span more than this lies on a
            depth edge and is missed, metres.
        min_frames: the fewest frames that must be compared.
        jackknife_blocks: the standard errors come from leaving out this many blocks of
            consecutive frames in turn (a frame's points share its pose error).
        seed: draws the depth pixels.
    """

    max_lag_frames: float = 4.0
    coarse_step_frames: float = 0.25
    fine_step_frames: float = 0.05
    fine_half_width_frames: float = 0.5
    fit_half_width_frames: float = 0.2
    frame_gaps: tuple[int, ...] = (1, 2, 4, 8)
    points_per_frame: int = 500
    max_points: int = 150_000
    robust_scale_m: float = 0.02
    max_depth_m: float = 4.5
    min_confidence: int = 1
    edge_m: float = 0.05
    min_frames: int = 6
    jackknife_blocks: int = 8
    seed: int = 0
