"""Ground truth that the synthetic generator writes beside a capture."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from artitwin_core.joints import Joint


@dataclass(frozen=True)
class SceneGroundTruth:
    """Exact answers for one synthetic scene.

    Attributes:
        joints: one ``Joint`` per articulated part, in the canonical frame (the static
            recording's world frame); ``q`` is per dynamic frame, ``q = 0`` closed.
        part_masks: ``[T, H, W]`` uint8 at RGB resolution per dynamic frame: 0 = not a moving
            part, k + 1 = visible pixels of part k (occluded parts are not labelled).
        hand_masks: ``[T, H, W]`` bool, pixels of hand and arm per dynamic frame.
        static_world_from_camera: ``[Ts, 4, 4]`` true poses of the static recording, canonical frame.
        dynamic_world_from_camera: ``[Td, 4, 4]`` true poses of the dynamic recording in the
            canonical frame.
        canonical_from_dynamic_session: ``[4, 4]`` maps the dynamic recording's session frame into
            the canonical frame (what registration must recover).
        effects: the injected effects with their parameters (name -> parameters).
        part_world_from_closed: ``[K, T, 4, 4]`` the true rigid motion of part k at dynamic frame t
            (canonical frame, maps the closed part onto its pose at that frame). Equals the joint's
            transform at ``q[t]`` for an ideal joint; differs from it when a joint effect
            (``axis_sag``, ``drawer_tilt``) makes the real motion non-ideal. ``None`` if unknown.
        overlap_fraction: of the dynamic recording's depth pixels on the scene (the hand left
            out; a moving part's points taken back to where it sat closed), the fraction whose
            point the static recording saw too (within ~2 cm + 2 % of the depth; clean depth,
            true poses). About 0.9 for a full overlap; ``SceneSpec.static_shift_m`` lowers it.
            ``None`` if unknown (ground truth written before it was measured).
    """

    joints: list[Joint]
    part_masks: np.ndarray
    hand_masks: np.ndarray
    static_world_from_camera: np.ndarray
    dynamic_world_from_camera: np.ndarray
    canonical_from_dynamic_session: np.ndarray
    effects: dict = field(default_factory=dict)
    part_world_from_closed: np.ndarray | None = None
    overlap_fraction: float | None = None
