"""Hyperparameters of the part point tracker."""

from __future__ import annotations

from dataclasses import dataclass

from artitwin_core._errors import InputError


@dataclass(frozen=True)
class TrackingConfig:
    """Hyperparameters of ``track_part_points`` (pixels at RGB resolution, metres, seconds).

    Attributes:
        query_area_fraction: the query frame is the first whose (eroded, hand-free) part area
            times mask score reaches this fraction of the best frame's. Earlier frames are
            preferred because recordings start with the part closed, the frame ``estimate_joint``
            takes as reference, and a closed drawer's outline (flush with the cabinet) pins the
            dense warp best: 0.6 tracked drawers two to five times closer than 1.0 (largest
            area, the open drawer; docs/accuracy.md).
        max_points: query points sampled in the query frame (fewer on small or untextured parts).
        min_distance_px: least spacing between query points; ``None`` = ``max(2, W / 128)``.
        erode_px: the part mask is eroded by this before sampling (keeps query points off its
            boundary, where LK windows straddle the background); ``None`` = ``max(1, W / 128)``.
        hand_margin_px: pixels this close to the hand are neither sampled nor tracked;
            ``None`` = ``max(2, W / 64)``.
        mask_dilate_px: a track must stay inside the part mask dilated by this (masks from a
            segmenter are a few pixels off); ``None`` = ``max(1, W / 128)``.
        align_margin_px: planar mode's dense aligner uses the part mask dilated by this (a
            segmenter's mask may miss the part's outline, whose gradients pin the warp across a
            directional texture); ``None`` = ``max(2, W / 32)``.
        corner_quality: Shi-Tomasi quality level (fraction of the best corner's min eigenvalue).
        window_px: LK window side (odd); ``None`` = ``W / 16`` clipped to [9, 31].
        pyramid_levels: LK pyramid levels above the full-resolution image.
        lk_iterations: LK iterations per level.
        lk_min_eigen: LK's ``minEigThreshold`` (OpenCV's normalised units): flat patches fail.
        fb_threshold_px: a frame-to-frame step is kept when the backward flow returns within this
            many pixels of where it started (forward-backward consistency).
        homography_threshold_px: RANSAC threshold of the query-to-frame homography that predicts
            the part's warp (drift anchoring and re-acquisition work on its inliers only).
        min_homography_points: fewest tracks for fitting that homography.
        anchor_max_shift_px: the query-frame template, warped by the homography, must agree with
            the chained position within this many pixels, else the track has drifted and stops.
        ncc_min: normalised cross-correlation between the warped query patch and the current
            patch below which the track stops (occluded by a hand, or slid off its point).
        reacquire: re-find tracks lost to occlusion once their point is visible again, by
            homography prediction plus template alignment (tracks on the homography's plane only).
        reacquire_ncc_min: the stricter NCC a re-acquired point must reach.
        plane_threshold_m: query points within this distance of the part's dominant plane count
            as on it (depth noise is ~3 mm at 1 m on an iPhone LiDAR).
        min_plane_fraction: if at least this fraction of the query points is on one plane, the
            part is tracked in planar mode: a dense homography over the part's pixels places every
            track, and points off the plane are not tracked; otherwise tracks are chained LK
            points re-aligned to the query frame one by one.
        normalize_exposure: scale each frame's grey levels to the query frame's median (LK is
            not invariant to exposure changes).
        depth_edge_rel: the 2x2 depth neighbours of a sample may differ by at most this fraction
            of its depth (larger spreads are depth edges or flying pixels).
        min_confidence: depth confidence (0/1/2) a sample needs; 1 rejects ARKit's "low".
        max_speed_m_per_s: a point faster than this between valid frames is a depth outlier
            (generous: a door edge swung by hand moves at ~1-2 m/s).
        jump_margin_m: added to ``max_speed * dt`` (depth noise on both ends).
        min_valid_frames: tracks with fewer valid 3D frames are dropped.
        model_tracking: also align the part's query-frame surface (depth + grey levels, robust
            Gauss-Newton over its 6-DOF motion) to every frame (``_model_track``). Planar mode
            then restarts the dense warp from the model's homography where the chained LK loses
            a fast-moving face, and frames the 2D tracker did not reach get the query points
            moved by the model's motion: tracks of a fast-swinging door reach its full opening
            instead of a fifth of it.
        model_points: most surface points in that model (a random subset beyond).
        patch_px: the model tracker's appearance test correlates grey levels in square patches
            of the query image this many pixels wide, each normalised on its own, so that a
            shadow cast over part of the face does not fail it; ``None`` = ``max(16, W / 16)``.
        model_depth_gate_m: a model-placed track's depth sample must lie this close to the moved
            query point (else it is occluded or off the surface); a 2D track farther than this
            from the model's prediction is replaced by it.
        seed: random seed of the plane RANSAC.
    """

    max_points: int = 1000
    query_area_fraction: float = 0.6
    min_distance_px: float | None = None
    erode_px: int | None = None
    hand_margin_px: int | None = None
    mask_dilate_px: int | None = None
    align_margin_px: int | None = None
    corner_quality: float = 0.005
    window_px: int | None = None
    pyramid_levels: int = 3
    lk_iterations: int = 30
    lk_min_eigen: float = 1e-4
    fb_threshold_px: float = 1.0
    homography_threshold_px: float = 2.0
    min_homography_points: int = 12
    anchor_max_shift_px: float = 2.0
    ncc_min: float = 0.6
    reacquire: bool = True
    reacquire_ncc_min: float = 0.85
    plane_threshold_m: float = 0.012
    min_plane_fraction: float = 0.5
    normalize_exposure: bool = True
    depth_edge_rel: float = 0.05
    min_confidence: int = 1
    max_speed_m_per_s: float = 3.0
    jump_margin_m: float = 0.05
    min_valid_frames: int = 3
    model_tracking: bool = True
    model_points: int = 3000
    patch_px: int | None = None
    model_depth_gate_m: float = 0.02
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.query_area_fraction <= 1.0:
            raise ValueError(f"TrackingConfig.query_area_fraction must be in (0, 1], got {self.query_area_fraction}")
        if self.max_points < 3:
            raise ValueError(f"TrackingConfig.max_points must be >= 3, got {self.max_points}")
        for name in ("fb_threshold_px", "homography_threshold_px", "anchor_max_shift_px",
                     "depth_edge_rel", "max_speed_m_per_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TrackingConfig.{name} must be > 0, got {getattr(self, name)}")
        if self.window_px is not None and (self.window_px < 5 or self.window_px % 2 == 0):
            raise ValueError(f"TrackingConfig.window_px must be odd and >= 5, got {self.window_px}")
        if not -1.0 <= self.ncc_min <= 1.0 or not -1.0 <= self.reacquire_ncc_min <= 1.0:
            raise ValueError("TrackingConfig.ncc_min and reacquire_ncc_min must be in [-1, 1]")
        if self.model_points < 30 or not self.model_depth_gate_m > 0:
            raise ValueError("TrackingConfig.model_points must be >= 30 and model_depth_gate_m > 0")
        if self.patch_px is not None and self.patch_px < 2:
            raise ValueError(f"TrackingConfig.patch_px must be >= 2 pixels, got {self.patch_px}")
        if self.pyramid_levels < 0 or self.lk_iterations < 1 or self.min_valid_frames < 1:
            raise ValueError("TrackingConfig.pyramid_levels >= 0, lk_iterations >= 1, min_valid_frames >= 1")

    def scaled(self, width: int) -> dict[str, float]:
        """The pixel sizes left as ``None``, resolved for images ``width`` pixels wide."""
        win = self.window_px
        if win is None:
            win = int(min(31, max(9, width // 16)))
            win += 1 - win % 2
        return {
            "min_distance_px": self.min_distance_px if self.min_distance_px is not None else max(2.0, width / 128),
            "erode_px": self.erode_px if self.erode_px is not None else max(1, round(width / 128)),
            "hand_margin_px": self.hand_margin_px if self.hand_margin_px is not None else max(2, round(width / 64)),
            "mask_dilate_px": self.mask_dilate_px if self.mask_dilate_px is not None else max(1, round(width / 128)),
            "align_margin_px": self.align_margin_px if self.align_margin_px is not None else max(2, round(width / 64)),
            "window_px": win,
            "patch_px": self.patch_px if self.patch_px is not None else max(16.0, width / 16),
        }


@dataclass(frozen=True)
class FramePoseConfig:
    """Hyperparameters of :func:`estimate_frame_poses`.

    Attributes:
        keyframe_step: a keyframe every this many frames (and the last frame).
        reach: frames up to this many before and after a keyframe are aligned to it.
        mask_dilation_px: part and hand masks are grown by this many RGB pixels before they
            exclude the background (their edges are a few pixels loose).
        min_confidence: depth below this ARKit confidence is not used.
        max_depth_m: depth beyond this is not used.
        model_points: static points per keyframe model (a fixed random subset).
        min_ncc: an alignment counts only if the keyframe's grey levels correlate with the frame's
            at least this well, patch by patch (depth alone lets a wall slide within itself).
        min_inlier_fraction: ... and at least this share of the model's visible points fits the
            frame's depth.
        max_rotation_rad, max_translation_m: ... and it moved the keyframe no further than this
            (larger motions are not jitter but a failed alignment).
        min_chi2_per_dof: the corrections are applied only if the chi-square of their
            frame-to-frame part against its standard errors, per degree of freedom, is at least
            this.
        slow_frames: the slow part of the corrections is a straight line in time fitted to this
            many frames around each frame.
        min_whiteness: below this whiteness (``FramePoseFit.whiteness``) only the frame-to-frame
            part is applied.
        min_depth_agreement: ... and nothing is applied unless the frames' depth agrees better
            at the corrected poses, by at least this z-score (``FramePoseFit.depth_agreement``).
        prior_rotation_rad, prior_translation_m: a loose zero-mean prior on each frame's error,
            which holds frames that no alignment reached (and splits of the recording that no
            keyframe links) at their recorded poses.
    """

    keyframe_step: int = 5
    reach: int = 10
    mask_dilation_px: int = 8
    min_confidence: int = 1
    max_depth_m: float = 4.0
    model_points: int = 3000
    min_ncc: float = 0.5
    min_inlier_fraction: float = 0.5
    max_rotation_rad: float = 0.03
    max_translation_m: float = 0.05
    min_chi2_per_dof: float = 10.0
    slow_frames: int = 15
    min_whiteness: float = 0.9
    min_depth_agreement: float = 3.0
    prior_rotation_rad: float = 0.02
    prior_translation_m: float = 0.02

    def __post_init__(self) -> None:
        if self.keyframe_step < 1 or self.reach < 1:
            raise InputError("FramePoseConfig.keyframe_step and reach must be at least 1.")
        if self.slow_frames < 3:
            raise InputError("FramePoseConfig.slow_frames must be at least 3 (a line needs them).")
        if self.model_points < 50:
            raise InputError("FramePoseConfig.model_points must be at least 50.")
        for name in ("max_rotation_rad", "max_translation_m", "prior_rotation_rad", "prior_translation_m"):
            if not getattr(self, name) > 0:
                raise InputError(f"FramePoseConfig.{name} must be positive.")
