"""Hyperparameters of joint estimation (:class:`JointFitConfig`) and of the joint-state
refinement from depth (:class:`StateRefineConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JointFitConfig:
    """Hyperparameters of ``estimate_joint`` (lengths in metres, angles in radians).

    Attributes:
        ransac_iterations: minimal 3-point samples per frame.
        ransac_threshold_m: first inlier threshold on the 3D residual; adapted to the noise after.
        min_inlier_threshold_m: the adapted threshold never goes below this (noise-free data).
        inlier_sigmas: inlier gate on the 3D residual norm in noise standard deviations (4.0
            keeps 99.9% of Gaussian inliers: the chi-3 quantile).
        min_track_inlier_fraction: a track is part of the part if it is an inlier in at least this
            fraction of its valid frames (rejects tracks that slid onto the background or hand).
        robust_scale_sigmas: scale of the Cauchy loss on the 3D residual, in noise sigmas.
        screening_iterations: alternations every hypothesis gets before the BIC screening.
        refine_bic_margin: hypotheses within this BIC of the best screened one are run to
            convergence (the others keep their screening fit and score).
        max_iterations: further alternations of joint parameters / latent points / weights.
        max_pivot_distance_m: a rotational fit whose axis runs farther than this from the part
            is stopped (a tiny rotation about a far axis is a translation; prismatic explains it
            with fewer parameters).
        tolerance: stop when the relative change of the weighted cost is below this.
        screw_bic_margin: BIC units by which the screw must beat the revolute (10 = "very
            strong" evidence in Kass and Raftery's scale).
        min_screw_travel_m: the screw's axial travel over the observed range must exceed this
            (a plain hinge's tracks can drift millimetres along it, linearly with q: a trend no
            frame-level test can tell from a pitch; docs/accuracy.md).
        screw_min_pitch_t: the screw's pitch must stand this many standard errors above zero
            when the frames' displacements along the revolute fit's axis are regressed on its
            states (frames, not points, are the independent samples, and the null model's axis
            cannot tilt to fake a pitch: see ``_pitch_significance``).
        min_rotation_rad: a revolute or screw fit must turn the part by at least this much over
            the recording, else it is not considered (a near-zero rotation about a far axis is a
            translation).
        max_pivot_part_ratio: a revolute or screw fit whose axis runs farther from the part's
            centroid than this many part radii (90th percentile of the inlier points' distances
            to their centroid across the axis) ...
        max_tilt_rad: ... and that turns the part by less than this over the recording is a
            slide with a tilt, not a hinge, and is not considered. Over a small angle a rotation
            about an axis at distance ``R`` moves the part along an arc of sagitta
            ``R dq^2 / 8`` (1.3 mm for a drawer tilting 0.04 rad over 0.25 m, i.e. ``R`` = 6 m),
            which no tracker tells from a straight slide with the same tilt; a hinge sits at the
            part (a door's axis is about one part radius from its centroid) and a slide's tilt is
            small, so only the combination of both is read as a tilt.
        min_motion_m: below this RMS displacement of the part's points, the joint is "fixed".
        noise_floor_m: lower bound on the noise estimate (keeps the BIC finite on clean data).
        q_tolerance_rad: standard error of a revolute ``q`` at which confidence is 0.5.
        q_tolerance_m: standard error of a prismatic ``q`` at which confidence is 0.5.
        smooth_below_confidence: frames under this confidence get a smoothed ``q``.
        smoothing_half_window: frames on each side used by the smoother.
        frame_gls_iterations: reweightings of the revolute's frame-level refit
            (``_refine_frame_level``); 0 keeps the point-level fit.
        frame_floor_rad: lower bound on the frames' rotation error spread (a component the
            joint absorbs, the turn about the axis, measures zero spread).
        frame_floor_m: lower bound on the frames' translation error spread.
        slide_along_face: a prismatic joint slides along its part's face normal (the dominant
            plane of its closed points) where the frames' displacements across the fitted
            direction cannot tell the two apart (``_slide_along_face``).
        face_min_fraction: the share of the part's inlier points the face plane must hold.
        face_max_angle_rad: the face normal must be within this of the fitted direction.
        face_chi2: the test's threshold (chi-square, 2 degrees of freedom; 9.21 is its 99%
            quantile): above it the tracks' direction stands.
        slide_floor_rad: systematic error of the tracks' slide direction, added in quadrature to
            the standard error their frames' scatter gives in that test: the pipeline's tracks of
            ideal drawers run up to a degree off the truth while their frames regress tightly
            on ``q`` (tracker errors correlated over frames, which the scatter does not show).
        tilt_chi2, tilt_min_rad: a slide whose frames turn significantly (chi-square over 3 axes
            at least ``tilt_chi2``, 11.34 its 99% quantile) and by at least ``tilt_min_rad``
            over the travel is a tilting slide: its direction is its closed face's normal if the
            turn explains the tracks' disagreement with it (``_slide_along_face``).
        tilt_explain_sigmas: the turn explains the tracks' direction when their gap from the
            face normal, along the turn's axis, is within this many of their standard errors.
        face_fit_min_points, face_fit_iterations, face_fit_band_m: the face plane's robust fit
            (least points, RANSAC samples, and the band in metres its score counts points in).
        min_frame_tracks: a frame with fewer usable tracks takes the global noise scale
            instead of its own median residual.
        pitch_min_support, pitch_support_fraction: the screw's pitch test uses the frames whose
            rigid motion rests on at least this many RANSAC inliers, and on at least this
            fraction of the median frame's.
        seed: RANSAC random seed.
    """

    ransac_iterations: int = 200
    ransac_threshold_m: float = 0.03
    min_inlier_threshold_m: float = 1e-4
    inlier_sigmas: float = 4.0
    min_track_inlier_fraction: float = 0.7
    robust_scale_sigmas: float = 4.0
    screening_iterations: int = 6
    refine_bic_margin: float = 100.0
    max_iterations: int = 30
    max_pivot_distance_m: float = 10.0
    tolerance: float = 1e-8
    screw_bic_margin: float = 10.0
    min_screw_travel_m: float = 0.015
    screw_min_pitch_t: float = 5.0
    min_rotation_rad: float = 0.05
    max_pivot_part_ratio: float = 4.0
    max_tilt_rad: float = 0.25
    min_motion_m: float = 0.002
    noise_floor_m: float = 1e-5
    q_tolerance_rad: float = float(np.deg2rad(0.5))
    q_tolerance_m: float = 0.002
    smooth_below_confidence: float = 0.5
    smoothing_half_window: int = 3
    frame_gls_iterations: int = 6
    frame_floor_rad: float = 1e-4
    frame_floor_m: float = 1e-5
    slide_along_face: bool = True
    face_min_fraction: float = 0.6
    face_max_angle_rad: float = float(np.deg2rad(10.0))
    face_chi2: float = 9.21
    slide_floor_rad: float = float(np.deg2rad(0.7))
    tilt_chi2: float = 11.34
    tilt_min_rad: float = float(np.deg2rad(0.5))
    tilt_explain_sigmas: float = 3.0
    face_fit_min_points: int = 20
    face_fit_iterations: int = 200
    face_fit_band_m: float = 0.01
    min_frame_tracks: int = 10
    pitch_min_support: float = 10.0
    pitch_support_fraction: float = 0.2
    seed: int = 0

    def __post_init__(self) -> None:
        for name in (
            "ransac_threshold_m",
            "min_inlier_threshold_m",
            "inlier_sigmas",
            "robust_scale_sigmas",
            "noise_floor_m",
            "q_tolerance_rad",
            "q_tolerance_m",
            "max_pivot_part_ratio",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"JointFitConfig.{name} must be > 0, got {getattr(self, name)}")
        if self.ransac_iterations < 1 or self.max_iterations < 1:
            raise ValueError("JointFitConfig.ransac_iterations and max_iterations must be >= 1")
        if not 0 < self.min_track_inlier_fraction <= 1:
            raise ValueError("JointFitConfig.min_track_inlier_fraction must be in (0, 1]")


@dataclass(frozen=True)
class StateRefineConfig:
    """Hyperparameters of :func:`refine_joint_states`.

    Attributes:
        max_points: mask pixels lifted per frame at most (an even subsample).
        min_points: frames with fewer lifted points are not fitted (see ``anchor_confidence``).
        mask_erode_px: the part mask is eroded by this many RGB pixels (mixed depth at borders).
        hand_dilate_depth_px: the hand mask is grown by this many depth pixels (at the RGB/depth
            size ratio, in RGB pixels) before it is excluded. A hand mask found in depth misses
            the hand's outline, whose depth pixels mix hand and part, and the lift samples depth
            bilinearly, one depth pixel farther. The hand's depth leaking into the part's points
            pulls a frame's ``q``; 2.5 gave the lowest state error (wider leaves less of the
            door near the hand; docs/accuracy.md).
        edge_rel: depth neighbours may spread by this fraction of the depth (the tracker's 0.05
            rejects a surface seen at 65+ deg from its normal, which is how a door's inside
            face is often seen; the silhouette's mixed pixels spread far more).
        min_depth_confidence: ARKit depth confidence each depth neighbour needs (0-2).
        voxel_m: the closed-state model keeps one point per voxel of this size, metres.
        normal_neighbours: points used for each model normal (local PCA).
        gate_m: a frame point farther than this from every model point is an outlier, metres.
        robust_scale_m: point-to-plane residual at which the truncated quadratic loss saturates.
        seed_confidence: tracked ``q`` with at least this confidence seeds the model.
        coarse_step_rad: step of the first grid over ``q``.
        coarse_points: about this many of a frame's points score the first grid.
        search_below_rad, search_above_rad: the grid spans the seeds' range widened by these.
        fine_step_rad: step of the second grid around the coarse minimum.
        fine_span_steps: the second grid spans this many coarse steps each side of it.
        agree_rad: a confident tracked ``q`` within this of the depth fit is kept as it is.
        q_tolerance_rad: depth-fit standard error at which its confidence is 0.5.
        min_inlier_fraction: depth fits with fewer inliers get no confidence.
        full_inlier_fraction: depth fits with this many inliers or more lose nothing for outliers.
        grow_confidence: depth fits at least this confident add their points to the model.
        anchor_confidence: a depth fit this confident anchors its frame; weaker fits, like
            frames without depth whose tracks were unsure, are bridged from the anchors by a
            monotone cubic (held beyond the first and last anchor, unless a tail fit below
            measured them).
        tail_max_se_rad, tail_min_inliers: beyond the first and last anchor, a depth fit with
            a standard error within ``tail_max_se_rad`` on at least ``tail_min_inliers`` inlier
            points measures its frame, whatever its inlier fraction: nothing else measured it,
            and holding the nearest anchor claims the part stopped there. A door seen edge-on
            at the end of a recording (opened past the camera's line of sight) is such a
            sliver: most of its points are the door's edge face, which the closed model lacks
            (the normal gate rejects them), so its inlier fraction is 0.1-0.4 while the face
            points still pin the state: such fits came within a few degrees of the truth where
            holding left them far short (docs/accuracy.md).
        grow: whether depth-fitted frames add their points to the model at all.
        smooth_model: move each model point onto its neighbours' plane.
        normal_gate_deg: a frame point whose own normal (PCA of ``frame_normal_neighbours`` of
            the frame's points) is farther than this from its model match's is an outlier
            (90 turns the gate off).
        normal_oversample: frame normals are estimated on this many times ``max_points`` pixels.
        prismatic_lever_m: prismatic joints' states are fitted too, each angle above
            (``*_rad``) read as the distance a point at this lever arm moves through it (0.25 m:
            a coarse step of 6.5 mm, a search from 87 mm below to 0.44 m above the seeds, a fine
            step of 0.44 mm, agreement within 6.5 mm). A drawer front's offset along its normal
            is its state, so no free offset per viewing side is fitted. None leaves prismatic
            joints as they are.
        refine_axis: after the per-frame pass, fit a door's line (axis and pivot) to the planes
            its faces show in depth (``fit_line_from_planes``), then refit the other frames'
            ``q`` with that line.
        rest_rad: frames whose confident ``q`` is within this of 0 are at rest; their points
            make the rest plane the turned faces are compared with.
        plane_normal_tol_deg: a frame's face plane must turn no more than this from where the
            per-frame state puts it.
        plane_ransac_iterations, plane_ransac_band_m: RANSAC of each face plane (samples, and
            the band in metres its score counts points in) before the robust refinement.
        plane_min_fraction: the share of a frame's points its plane must hold (and of the rest
            points, or the part is not a slab and its line is left to the tracks).
        plane_outlier_z: a frame whose plane misses the fitted line by more than this many
            standard errors is dropped and the line refitted (up to a third of the frames).
        axis_min_frames: turned frames with a face plane the line fit needs.
        axis_min_span_rad: the angle those frames must span.
        axis_max_se_rad, axis_max_pivot_se_m: the line fit is used only when its standard
            errors (axis direction, radians; line position, metres) are within these.
        axis_max_change_rad, axis_max_shift_m: ... and when it turned the axis and moved the
            line by no more than these from the input joint's (larger moves mean the model or
            the matches are wrong, not the tracks).
        slide_front_max_deg: with ``refine_axis``, a slide whose axis is within this of the
            normal of its front (the planes its frames show, ``fit_slide_axis_from_front``) is a
            drawer, and a drawer slides along its front's normal: the axis becomes that normal
            where the two disagree beyond their errors (0 turns this off; a sliding door, whose
            front is parallel to its slide, is never touched)...
        slide_front_z, slide_front_min_deg: ... by more than this many standard errors (the
            tracks' and the planes' together) and more than this many degrees.
    """

    max_points: int = 1500
    min_points: int = 60
    mask_erode_px: int = 2
    hand_dilate_depth_px: float = 2.5
    edge_rel: float = 0.25
    min_depth_confidence: int = 1
    voxel_m: float = 0.008
    normal_neighbours: int = 30
    gate_m: float = 0.04
    robust_scale_m: float = 0.012
    seed_confidence: float = 0.3
    coarse_step_rad: float = float(np.radians(1.5))
    coarse_points: int = 400
    search_below_rad: float = float(np.radians(20.0))
    search_above_rad: float = float(np.radians(100.0))
    fine_step_rad: float = float(np.radians(0.1))
    fine_span_steps: float = 1.5
    agree_rad: float = float(np.radians(1.5))
    q_tolerance_rad: float = float(np.radians(1.0))
    min_inlier_fraction: float = 0.4
    full_inlier_fraction: float = 0.8
    grow_confidence: float = 0.5
    anchor_confidence: float = 0.3
    tail_max_se_rad: float = float(np.radians(2.0))
    tail_min_inliers: int = 15
    grow: bool = False
    smooth_model: bool = True
    normal_gate_deg: float = 20.0
    frame_normal_neighbours: int = 12
    normal_oversample: int = 4
    prismatic_lever_m: float | None = 0.25
    refine_axis: bool = True
    rest_rad: float = float(np.radians(0.3))
    plane_normal_tol_deg: float = 20.0
    plane_ransac_iterations: int = 200
    plane_ransac_band_m: float = 0.01
    plane_min_fraction: float = 0.6
    plane_outlier_z: float = 4.0
    axis_min_frames: int = 3
    axis_min_span_rad: float = float(np.radians(10.0))
    axis_max_se_rad: float = float(np.radians(0.5))
    axis_max_pivot_se_m: float = 0.005
    axis_max_change_rad: float = float(np.radians(10.0))
    axis_max_shift_m: float = 0.05
    slide_front_max_deg: float = 25.0
    slide_front_z: float = 3.0
    slide_front_min_deg: float = 1.0
