"""Hyperparameters of change detection (:class:`ChangeConfig`) and of the part finder and mask
propagation (:class:`PartConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class ChangeConfig:
    """Thresholds of :func:`detect_changes`.

    Attributes:
        depth_tol_m, depth_tol_per_m2: a depth difference counts as change beyond
            ``depth_tol_m + depth_tol_per_m2 * depth**2`` (metres).
        appearance_threshold: appearance score in [0, 1] above which a pixel looks changed.
        census_radius: half-size of the census window (pixels).
        min_region_px: connected changed regions smaller than this are dropped.
    """

    depth_tol_m: float = 0.03
    depth_tol_per_m2: float = 0.01
    appearance_threshold: float = 0.45
    census_radius: int = 2
    min_region_px: int = 12


@dataclass(frozen=True)
class PartConfig:
    """Hyperparameters of the part finder and mask propagation.

    Attributes:
        change: depth tolerances shared with :func:`detect_changes`.
        vanish_voxel_m: voxel size for voting on vanished canonical surface (metres).
        vanish_opening_px: radius of a morphological opening of each frame's vanished pixels.
        min_vanish_frames: a voxel is part of a moved part if it vanished in this many frames.
        cluster_eps_m: vanished voxels closer than this belong to the same part (metres).
        onset_m_per_s: in the clustering, one second between two voxels' vanishing onsets
            counts as this distance (metres), so neighbouring parts that open at different times
            (a door above a drawer) come out as two parts; 0 clusters in space only.
        min_part_voxels: smaller clusters are ignored (noise at depth edges).
        min_occluded_frames: when no canonical surface vanished, a part may have moved only
            towards the camera (a drawer pulled out straight at a close-up camera hides its
            closed front and reveals nothing behind it); then a voxel hidden by something nearer
            in this many frames is a candidate's closed surface. The hand hides surface too, but
            no motion of that surface explains what is seen, and the candidate is dropped.
        hidden_parallel_deg: a voxel counts as hidden only where the nearer surface faces the
            way the hidden one does, within this angle (degrees; 90 or more: any). A part that
            hid its closed surface without leaving any vanished was pulled along its front's
            normal, so its front, seen nearer, is parallel to the closed front it hides; a hand,
            an arm, or a door turned open hides surface at an angle.
        hidden_max_tilt_deg: hidden surface is a drawer's front, which slides level: one whose
            slide would leave the horizontal by more than this (degrees) is dropped (a flat
            surface held over a floor or a shelf hides surface facing its way too).
        min_hidden_part_voxels: ``min_part_voxels`` for hidden surface: only where the front
            is seen over its own closed place (and not behind the hand or another part) does
            it count, a strip of the front at an oblique view.
        sample_m: spacing of the part's surface samples (metres).
        max_rotation_rad, max_translation_m: range of the door / drawer hypotheses.
        support_distance_m: an observed point this close (3D, plus 5 mm per m^2 of depth)
            supports a part sample.
        violation_weight: how much a see-through pixel (observed behind the part) costs in the
            score relative to a supporting pixel.
        num_refined: best coarse hypotheses refined by ICP at the reference frame.
        slide_grid_start_m, slide_grid_step_m: the drawer hypotheses slide from this far out
            in these steps up to ``max_translation_m`` (metres).
        swing_grid_step_deg: the door and flap hypotheses turn in steps of this many degrees
            (from one step) up to ``max_rotation_rad``.
        reference_extent_fractions: besides the most open frames, the first frames where the
            vanished surface reaches these fractions of its largest extent are candidate
            reference frames (a door is seen best on its way past the line of sight).
        icp_distances_m: the part's robust ICP runs at these correspondence distances in turn,
            coarse to fine (metres).
        local_slide_span_m, local_slide_step_m: a drawer hypothesis is refined by changing its
            slide within +-span in these steps (metres).
        local_pivot_span_m, local_pivot_step_m: a hinge hypothesis is refined by shifting the
            hinge across the front within +-span in these steps (metres) ...
        local_pivot_behind_m: ... and along the front's normal by these offsets (metres;
            hinges sit at the back of a door) ...
        local_swing_deg: ... and its angle by these offsets (degrees).
        depth_refine_span_m, depth_refine_points: a drawer's reference state is fine-tuned to
            the observed depth over +-span (metres) at this many evenly spaced states.
        door_search_overshoot, drawer_search_overshoot: a frame's state is searched up to this
            multiple of the reference state (doors, drawers) unless the frame comes after a
            reference frame that was not the last.
        state_grid_points: evenly spaced states in a frame's state search window.
        state_fine_points: states of the finer search around the best grid state (over one
            grid step each side).
        min_state_score: a tracked state with a lower score (support share) is not trusted to
            grow a drawer from or to measure its front's drift at.
        search_window: backwards propagation searches the joint state within this fraction of
            the reference state around the next frame's state (and always tries closed).
        part_thickness_m: how far in front of the part's front-face samples its back face or
            edges may be seen (metres, before the grazing-angle factor).
        part_depth_tol_m, part_depth_tol_per_m2: how much nearer than the part model the
            observation may be and still be the part (a hand on the part is nearer).
        grow_distance_m: at the reference frame, changed observed points within this distance of
            the moved part (and behind its front face once moved back) join the part: edges,
            drawer sides and insides that the vanished canonical surface lacks.
        max_part_radius_m: grown points stay within this distance of the part's centre.
        grow_frames: after tracking, a drawer also grows from this many other frames where it
            is open, at their tracked states (0: only from the reference frame). Once growth
            stayed inside the front's outline (``drawer_footprint_m``), 6 frames raised every
            measured drawer's IoU (docs/accuracy.md, "Why the defaults are what they are").
        outline_margin_m: a drawer's growth takes, without a surface path to the front, changed
            points that moved back lie this far inside the front's outline (metres).
        see_through_m: closed samples that, at the reference state, lie this far (plus the
            depth tolerance) in front of the observation are dropped (another part's surface).
        front_fill_reach_m: a drawer's front is filled from the canonical mesh up to this far
            outside the outline of its vanished samples (metres): the rim its box's sides hid as
            it slid out never vanished. 0.02 was best for a drawer; a door's fill, whose rim
            vanishes with it, does not reach (docs/accuracy.md).
        front_seen_min_q_m: a drawer fitted at least this far open (metres) takes its front's
            outline from the reference frame, where the whole front stands clear of the carcass
            (:func:`_front_seen_open`), and fills the upright rectangle it spans; the fill then
            does not reach past it. It raised every measured drawer's IoU (docs/accuracy.md).
        max_outline_drift: a drawer's outline drifting in its front's plane by more than this
            (metres per metre of travel; 0.2 is 11 deg) is not taken as its slide's direction
            (:func:`_slide_from_outline`): a drawer that sags tilts its slide by a few degrees,
            and an outline that moves more is one the hand or the frames' few clear edges got wrong.
        front_plane_tol_m: the observed front, moved back, lies this close to the front's plane.
        door_slab_m: what grows onto a door lies at most this far behind its front (metres).
        drawer_footprint_m: what grows onto a drawer lies inside its front's outline seen along
            the slide, or at most this far outside it (metres; None: anywhere).
        min_part_support: a vanished surface becomes a part only if at least this many of its
            samples are supported at its fitted reference state.
        host_reach_m, host_min_support_frac: a vanished surface whose samples come this close
            (metres) to a part found before it, and of whose samples that part's motion supports
            this fraction at its reference state (or that was fitted with the same joint), is
            merged into that part: a door's strip along its hinge vanishes later than the rest of
            it and is clustered apart by its onset.
        grow_free_space_m: grown points, moved back to the closed state, lie at most this far
            outside the canonical surface (metres); the reference state's error adds to it.
        hand_min_px: hand regions smaller than this (pixels, RGB resolution) are dropped.
        hand_border_px: part pixels within this many pixels of the hand mask are not part
            (the depth's coarser pixels straddle the hand's outline).
        fill_radius_px, fill_sigma_colour, fill_model_weight: where the depth is invalid (both
            sides of a depth edge), a pixel takes the depth of the measured depth pixels within
            ``fill_radius_px`` whose colour is like its own (Gaussian, ``fill_sigma_colour``
            RMS in 0-255 units), or where none is, the model's first surface (as a measured
            neighbour 2 sigma off in colour: weight exp(-2) = 0.135). See
            :func:`fill_depth_by_colour`.
    """

    change: ChangeConfig = field(default_factory=ChangeConfig)
    vanish_voxel_m: float = 0.02
    min_vanish_frames: int = 2
    vanish_opening_px: int = 0
    cluster_eps_m: float = 0.05
    onset_m_per_s: float = 0.15
    min_part_voxels: int = 60
    min_occluded_frames: int = 4
    hidden_parallel_deg: float = 15.0
    hidden_max_tilt_deg: float = 30.0
    min_hidden_part_voxels: int = 20
    sample_m: float = 0.01
    max_rotation_rad: float = 2.0
    max_translation_m: float = 0.7
    violation_weight: float = 2.0
    support_distance_m: float = 0.025
    search_window: float = 0.35
    slide_grid_start_m: float = 0.02
    slide_grid_step_m: float = 0.01
    swing_grid_step_deg: float = 3.0
    reference_extent_fractions: tuple[float, ...] = (0.25, 0.5, 0.75)
    icp_distances_m: tuple[float, ...] = (0.08, 0.04)
    local_slide_span_m: float = 0.03
    local_slide_step_m: float = 0.005
    local_pivot_span_m: float = 0.06
    local_pivot_step_m: float = 0.02
    local_pivot_behind_m: tuple[float, ...] = (-0.03, -0.015, 0.0)
    local_swing_deg: tuple[float, ...] = (-6.0, -4.0, -2.0, 0.0, 2.0, 4.0, 6.0)
    depth_refine_span_m: float = 0.03
    depth_refine_points: int = 25
    door_search_overshoot: float = 1.1
    drawer_search_overshoot: float = 1.35
    state_grid_points: int = 41
    state_fine_points: int = 9
    min_state_score: float = 0.5
    num_refined: int = 6
    hand_min_px: int = 30
    hand_border_px: int = 1
    part_thickness_m: float = 0.02
    part_depth_tol_m: float = 0.015
    part_depth_tol_per_m2: float = 0.005
    grow_distance_m: float = 0.03
    grow_free_space_m: float = 0.015
    max_part_radius_m: float = 1.2
    outline_margin_m: float = 0.01
    grow_frames: int = 6
    front_fill_reach_m: float = 0.02
    front_seen_min_q_m: float = 0.08
    door_slab_m: float = 0.06
    min_part_support: int = 20
    host_reach_m: float = 0.03
    host_min_support_frac: float = 0.5
    drawer_footprint_m: float | None = 0.02
    max_outline_drift: float = 0.2
    front_plane_tol_m: float = 0.01
    front_clear_m: float = 0.05
    see_through_m: float = 0.05
    fill_radius_px: int = 2
    fill_sigma_colour: float = 20.0
    fill_model_weight: float = 0.135
