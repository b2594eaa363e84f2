"""A second opinion on a part's joint: the part finder's, fitted to the change in depth.

``fit_joints`` fits each part's joint to its point tracks. On a weakly textured door the tracks
slide and drift, and the fit comes out uncertain and wrong: generalization seed 21 (a plain door
walked past, a gloved hand from above) got an axis 11 deg off and a line 12 cm away, with standard
errors of 3.6 deg and 65 mm, and the bench counted it as a spurious part, while the part finder
had fitted the door's swing to the vanished and reappeared depth to 0.0 deg and 4 mm. Where the
tracks are sure of their joint they are the better measurement (seed 1: the part finder's line
is 3 cm off, the tracks' 0.4 mm), so the part finder's joint replaces the tracks' only where the
tracks' standard errors say they are unsure, and only if it explains the part's depth better
once both joints' states are refitted to it.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.joints import Joint
from artitwin_core.masks import MaskSequence
from artitwin_core.parts._config import SettleConfig
from artitwin_core.parts._settle import _lift_candidate, _misfits


def uncertain_joint(joint: Joint, *, max_axis_se_rad: float, max_pivot_se_m: float) -> bool:
    """Whether ``joint``'s own standard errors call it unsure (an unknown error is not unsure)."""
    axis = joint.axis_se_rad is not None and joint.axis_se_rad > max_axis_se_rad
    line = joint.joint_type in ("revolute", "screw") and joint.pivot_se_m is not None and joint.pivot_se_m > max_pivot_se_m
    return bool(axis or line)


def depth_misfit(
    dynamic: Capture, masks: MaskSequence, label: int, joint: Joint, canonical_from_session: np.ndarray,
    config: SettleConfig | None = None,
) -> float | None:
    """How far (metres, a median) the points of part ``label`` in the frames ``joint`` moves them,
    moved back to the closed state by it, lie from those it leaves closed (``settle_parts``'
    confirmation test); None where no frame moves the part enough to tell."""
    cfg = config or SettleConfig()
    c = _lift_candidate(dynamic, masks, label, label - 1, joint, 0, np.asarray(canonical_from_session, np.float64), cfg)
    fit = _misfits(c, joint, cfg)
    return None if fit is None else fit[0]


def prefer_depth_joint(
    tracks: Joint, depth: Joint, dynamic: Capture, masks: MaskSequence, label: int, canonical_from_session: np.ndarray,
    *, max_axis_se_rad: float, max_pivot_se_m: float, max_misfit_ratio: float = 0.8,
    config: SettleConfig | None = None,
) -> tuple[bool, str]:
    """Whether the part finder's joint ``depth`` should replace the tracks' joint ``tracks`` of part
    ``label`` (both with their states refitted to depth), and a sentence saying why or why not.

    Yes when the tracks' joint is unsure (:func:`uncertain_joint`), the two are of one type, and
    ``depth`` moves the part's points back onto its closed surface at most ``max_misfit_ratio``
    as far from it as ``tracks`` does (:func:`depth_misfit`)."""
    if not uncertain_joint(tracks, max_axis_se_rad=max_axis_se_rad, max_pivot_se_m=max_pivot_se_m):
        return False, ""
    if depth.joint_type != tracks.joint_type:
        return False, (f"the tracks' {tracks.joint_type} joint is unsure, but the part finder fitted a {depth.joint_type} "
                       "joint: kept the tracks'")
    se = f"axis +-{np.degrees(tracks.axis_se_rad or 0.0):.1f} deg" + (
        f", line +-{1e3 * tracks.pivot_se_m:.0f} mm" if tracks.pivot_se_m is not None else "")
    m_t = depth_misfit(dynamic, masks, label, tracks, canonical_from_session, config)
    m_d = depth_misfit(dynamic, masks, label, depth, canonical_from_session, config)
    told = "not measured" if m_t is None else f"{1e3 * m_t:.0f} mm"
    if m_d is None or (m_t is not None and m_d > max_misfit_ratio * m_t):
        return False, (f"the tracks leave the joint unsure ({se}); the part finder's depth fit explains the part's depth "
                       f"no better ({'not measured' if m_d is None else f'{1e3 * m_d:.0f} mm'} against {told}): "
                       "kept the tracks'")
    return True, (f"the tracks leave the joint unsure ({se}) and the part finder's depth fit explains the part's depth "
                  f"better ({1e3 * m_d:.0f} mm from its closed surface once moved back, against {told}): the joint "
                  f"fitted to the depth replaces the tracks'")
