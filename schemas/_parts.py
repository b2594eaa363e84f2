"""Config sections of the part finder (``artitwin_core.change.segment_parts``), settable from a
pipeline config file as ``part_masks.parts``.

Each class mirrors one core dataclass field for field, with its default (``ChangeStageConfig`` ->
``ChangeConfig``, ``PartStageConfig`` -> ``PartConfig``): schemas does not import the core, so the
fields are written out here and ``tests/foundation/test_config_truth.py`` keeps the two in step.
"""

from __future__ import annotations

from pydantic import Field

from schemas._base import StageConfig


class ChangeStageConfig(StageConfig):
    """Depth and appearance change thresholds (``artitwin_core.change.ChangeConfig``)."""

    depth_tol_m: float = Field(default=0.03, ge=0, description="A depth difference counts as change beyond depth_tol_m + depth_tol_per_m2 * depth^2, metres.")
    depth_tol_per_m2: float = Field(default=0.01, ge=0, description="... the part of that tolerance growing with depth squared, 1/metres.")
    appearance_threshold: float = Field(default=0.45, ge=0, le=1, description="Appearance score in [0, 1] above which a pixel looks changed.")
    census_radius: int = Field(default=2, ge=1, description="Half-size of the census window, pixels.")
    min_region_px: int = Field(default=12, ge=0, description="Connected changed regions smaller than this are dropped, pixels.")


class PartStageConfig(StageConfig):
    """The geometric part finder and its mask propagation (``artitwin_core.change.PartConfig``, whose
    docstring says more on each field)."""

    change: ChangeStageConfig = Field(default_factory=ChangeStageConfig, description="Depth tolerances shared with the change detector.")
    vanish_voxel_m: float = Field(default=0.02, gt=0, description="Voxel for voting on vanished canonical surface, metres.")
    min_vanish_frames: int = Field(default=2, ge=1, description="A voxel belongs to a moved part when it vanished in this many frames.")
    vanish_opening_px: int = Field(default=0, ge=0, description="Radius of a morphological opening of each frame's vanished pixels.")
    cluster_eps_m: float = Field(default=0.05, gt=0, description="Vanished voxels closer than this belong to the same part, metres.")
    onset_m_per_s: float = Field(
        default=0.15, ge=0,
        description="In the clustering, one second between two voxels' vanishing onsets counts as this distance (metres): "
        "neighbouring parts that open at different times come out apart; 0 clusters in space only.",
    )
    min_part_voxels: int = Field(default=60, ge=1, description="Smaller clusters are ignored (noise at depth edges).")
    min_occluded_frames: int = Field(
        default=4, ge=1,
        description="When no canonical surface vanished, a voxel hidden by something nearer in this many frames is a "
        "candidate's closed surface (a part moved only towards the camera).",
    )
    hidden_parallel_deg: float = Field(
        default=15.0, ge=0,
        description="Surface counts as hidden only where the nearer surface faces its way within this angle, degrees "
        "(a front slid along its normal; a hand, an arm or a turned door hides surface at an angle); 90 or more: any.",
    )
    hidden_max_tilt_deg: float = Field(
        default=30.0, ge=0, le=90,
        description="Hidden surface is a drawer's front, which slides level: one whose slide would leave the horizontal by "
        "more than this, degrees, is dropped.",
    )
    min_hidden_part_voxels: int = Field(default=20, ge=1, description="min_part_voxels for hidden surface.")
    sample_m: float = Field(default=0.01, gt=0, description="Spacing of a part's surface samples, metres.")
    max_rotation_rad: float = Field(default=2.0, gt=0, description="Range of the door hypotheses, radians.")
    max_translation_m: float = Field(default=0.7, gt=0, description="Range of the drawer hypotheses, metres.")
    violation_weight: float = Field(default=2.0, ge=0, description="Cost of a see-through pixel relative to a supporting one.")
    support_distance_m: float = Field(
        default=0.025, gt=0, description="An observed point this close (plus 5 mm per m^2 of depth) supports a part sample, metres."
    )
    search_window: float = Field(
        default=0.35, gt=0, description="Backward propagation searches the state within this fraction of the reference state."
    )
    num_refined: int = Field(default=6, ge=1, description="Best coarse hypotheses refined by ICP at the reference frame.")
    hand_min_px: int = Field(default=30, ge=0, description="Hand regions smaller than this are dropped (pixels, RGB resolution).")
    hand_border_px: int = Field(default=1, ge=0, description="Part pixels within this many pixels of the hand mask are not part.")
    part_thickness_m: float = Field(
        default=0.02, ge=0, description="How far in front of the front-face samples the part's back or edges may be seen, metres."
    )
    part_depth_tol_m: float = Field(
        default=0.015, ge=0, description="How much nearer than the part model an observation may be and still be the part, metres..."
    )
    part_depth_tol_per_m2: float = Field(default=0.005, ge=0, description="... plus this times the depth squared, 1/metres.")
    grow_distance_m: float = Field(
        default=0.03, ge=0, description="At the reference frame, changed points within this of the moved part join it, metres."
    )
    grow_free_space_m: float = Field(
        default=0.015, ge=0, description="Grown points, moved back to closed, lie at most this far outside the canonical surface, metres."
    )
    max_part_radius_m: float = Field(default=1.2, gt=0, description="Grown points stay within this distance of the part's centre, metres.")
    outline_margin_m: float = Field(
        default=0.01, ge=0, description="A drawer's growth takes changed points this far inside its front's outline, metres."
    )
    grow_frames: int = Field(default=6, ge=0, description="A drawer also grows from this many other open frames (0: the reference frame only).")
    front_fill_reach_m: float = Field(
        default=0.02, ge=0, description="A drawer's front is filled from the canonical mesh up to this far outside its vanished outline, metres."
    )
    front_seen_min_q_m: float = Field(
        default=0.08, ge=0, description="A drawer fitted at least this far open takes its front's outline from the reference frame, metres."
    )
    door_slab_m: float = Field(default=0.06, gt=0, description="What grows onto a door lies at most this far behind its front, metres.")
    min_part_support: int = Field(
        default=20, ge=0, description="A vanished surface becomes a part only if this many of its samples are supported."
    )
    host_reach_m: float = Field(
        default=0.03, ge=0, description="A vanished surface this close to a part found before it may merge into it, metres..."
    )
    host_min_support_frac: float = Field(
        default=0.5, ge=0, le=1, description="... when that part's motion supports this fraction of its samples."
    )
    drawer_footprint_m: float | None = Field(
        default=0.02, ge=0,
        description="What grows onto a drawer lies inside its front's outline seen along the slide, or at most this far "
        "outside it, metres; None: anywhere.",
    )
    max_outline_drift: float = Field(
        default=0.2, ge=0,
        description="A drawer's outline drifting in its front's plane by more than this (metres per metre of travel) is not "
        "taken as its slide's direction: a sagging drawer tilts by a few degrees.",
    )
    front_plane_tol_m: float = Field(default=0.01, ge=0, description="The observed front, moved back, lies this close to the front's plane, metres.")
    front_clear_m: float = Field(
        default=0.05, ge=0,
        description="A drawer front's plane is seen through past its edge where the depth lies this far behind it, metres.",
    )
    see_through_m: float = Field(
        default=0.05, ge=0, description="Closed samples this far in front of the observation at the reference state are dropped, metres."
    )
    slide_grid_start_m: float = Field(default=0.02, gt=0, description="The drawer hypotheses slide from this far out, metres.")
    slide_grid_step_m: float = Field(default=0.01, gt=0, description="... in these steps up to max_translation_m, metres.")
    swing_grid_step_deg: float = Field(default=3.0, gt=0, description="The door and flap hypotheses turn in steps of this many degrees.")
    reference_extent_fractions: tuple[float, ...] = Field(
        default=(0.25, 0.5, 0.75),
        description="Frames where the vanished surface first reaches these fractions of its largest extent are candidate reference frames.",
    )
    icp_distances_m: tuple[float, ...] = Field(
        default=(0.08, 0.04), description="Correspondence distances of the part's robust ICP, coarse to fine, metres."
    )
    local_slide_span_m: float = Field(default=0.03, ge=0, description="A drawer hypothesis is refined within +- this slide, metres ...")
    local_slide_step_m: float = Field(default=0.005, gt=0, description="... in these steps, metres.")
    local_pivot_span_m: float = Field(default=0.06, ge=0, description="A hinge hypothesis is refined by shifting the hinge across the front within +- this, metres ...")
    local_pivot_step_m: float = Field(default=0.02, gt=0, description="... in these steps, metres ...")
    local_pivot_behind_m: tuple[float, ...] = Field(
        default=(-0.03, -0.015, 0.0), description="... and along the front's normal by these offsets, metres ..."
    )
    local_swing_deg: tuple[float, ...] = Field(
        default=(-6.0, -4.0, -2.0, 0.0, 2.0, 4.0, 6.0), description="... and its angle by these offsets, degrees."
    )
    depth_refine_span_m: float = Field(default=0.03, ge=0, description="A drawer's reference state is fine-tuned to depth within +- this, metres ...")
    depth_refine_points: int = Field(default=25, ge=1, description="... at this many evenly spaced states.")
    door_search_overshoot: float = Field(default=1.1, gt=0, description="A door's state is searched up to this multiple of its reference state.")
    drawer_search_overshoot: float = Field(default=1.35, gt=0, description="A drawer's state is searched up to this multiple of its reference state.")
    state_grid_points: int = Field(default=41, ge=2, description="Evenly spaced states in a frame's state search window.")
    state_fine_points: int = Field(default=9, ge=1, description="States of the finer search around the best grid state.")
    min_state_score: float = Field(
        default=0.5, ge=0, le=1, description="A tracked state scored lower is not used to grow a drawer or measure its front's drift."
    )
    fill_radius_px: int = Field(default=2, ge=0, description="Invalid depth is filled from measured depth pixels within this radius.")
    fill_sigma_colour: float = Field(default=20.0, gt=0, description="... weighted by colour likeness (Gaussian, RMS in 0-255 units),")
    fill_model_weight: float = Field(default=0.135, ge=0, description="... or from the model's first surface with this weight.")
