"""Hyperparameters of settling which candidate parts are kept (:class:`SettleConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SettleConfig:
    """Thresholds of :func:`settle_parts`.

    Attributes:
        min_depth_points: a part needs at least this many distinct depth pixels inside its mask
            (hand excluded) over the recording: fewer build no mesh and no inertia.
        max_points_per_frame: points lifted per frame for the motion tests.
        min_frame_points: a frame takes part in the motion tests with at least this many points.
        merge_max_misfit_m: a candidate with no joint of its own merges into a neighbouring part
            when its points, in the frames that part's motion moved, moved back to the closed
            state by that motion lie this close to its closed surface (seen in the frames the
            motion had not moved yet; median nearest-neighbour distance, metres).
        merge_min_ratio: ... and at least this many times closer than held still (the reverse:
            it did not move while its neighbour did).
        min_discrimination_m: only frames in which the part's motion moves the candidate's points
            at least this far (median, metres) beyond the closed frames' can tell.
        confirm_min_ratio, confirm_min_margin_m: a candidate's own joint is confirmed by its
            depth when its points, moved back to the closed state by that joint, lie at least
            this many times and this much (metres) closer to its closed surface than held still
            (the test of ``merge_max_misfit_m``, without its absolute bound: a wide door's
            interior and edge, seen once it is open, sit a few centimetres off its front).
            Unconfirmed, it counts as no joint of its own: a planar patch "turning" in its own
            plane agrees with its depth held still as well as moved.
        min_range_m, min_range_deg: a fitted joint whose states span less than this (metres
            for a slide, degrees for a turn) is no motion of its own: tracks on a foot, an
            edge or a shadow drift by millimetres, and a part opened that little cannot be told
            from them.
        same_axis_deg, same_line_m: two fitted joints are the same joint when their axes are this
            close (degrees) and, for rotations, their lines pass this close at the candidate (metres).
        same_state_frac, same_state_floor: ... and their states agree within this fraction of the
            part's range (median over frames), or within the floor (radians or metres).
        adjacency_px: two candidates are neighbours when their masks, grown by this many pixels,
            overlap in some frame.
        stand_in_rest_frac: a door kept on the part finder's joint (its tracks gave none) must
            have its line confirmed by its face planes (``fit_line_from_planes``); its closed
            frames are those within this fraction of its range of 0 (that joint's line is a
            coarse one, and the states it gives closed frames scatter by a few degrees)...
        stand_in_max_shift_m, stand_in_max_turn_deg: ... and the planes may move its line this far
            (metres) and turn it this much (degrees): the part finder may have put it on the
            wrong edge.
        screw_keep_ratio: a kept screw becomes the slide (its travel) or the turn (no pitch) that
            explains its depth best, unless its own misfit is below this fraction of that one's.
    """

    min_depth_points: int = 40
    max_points_per_frame: int = 600
    min_frame_points: int = 10
    merge_max_misfit_m: float = 0.02
    merge_min_ratio: float = 2.0
    min_discrimination_m: float = 0.03
    confirm_min_ratio: float = 1.5
    confirm_min_margin_m: float = 0.01
    min_range_m: float = 0.02
    min_range_deg: float = 3.0
    same_axis_deg: float = 10.0
    same_line_m: float = 0.05
    same_state_frac: float = 0.15
    same_state_floor: float = 0.02
    adjacency_px: int = 4
    stand_in_rest_frac: float = 0.04
    stand_in_max_shift_m: float = 1.0
    stand_in_max_turn_deg: float = 30.0
    screw_keep_ratio: float = 0.8
