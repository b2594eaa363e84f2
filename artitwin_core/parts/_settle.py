"""Keep, merge or drop each candidate part once its tracks and joint fit are known.

A real capture gives the part finder spurious candidates beside the real parts: the strip of a
door along its hinge, which vanishes later than the rest of the door and is clustered apart; a
piece of static surface at a depth edge; a region too small or too thin to track or to fuse. Each
must end as one of three fates, and never take the run down:

- **kept**: a part with a joint of its own (a fit that moves more than a couple of centimetres or
  degrees, that its own depth confirms, and depth enough to build its mesh). Where its tracks
  show no motion (fitted fixed, or a joint that hardly moves), could not be fitted at all, or
  fitted a joint its depth refutes, the part finder's joint, fitted to the part's change in
  depth, stands in for theirs if the depth confirms it: on a weakly textured door the tracks
  stick to the static edges around it and say "fixed" while the door swings. A screw is kept as the slide or turn its
  depth explains nearly as well, unless the user asked for the screw: a drawer front turning in
  its own plane looks the same in depth, and tracks that a hand crosses can carry that turn;
- **merged** into a kept part: it has the same joint and states as that part, or that part's
  motion explains its depth (its points, moved back to a common state by that part's joint,
  agree where held still they do not), whether or not it was fitted a joint of its own: a strip
  of a door with a slide fitted to its few tracks is the door;
- **dropped**, with the reason: too few depth points, no tracks or no fit, no motion of its own
  (fitted fixed, a joint that hardly moves, or one its depth does not confirm), or nothing
  explains it.

The kept parts are numbered again in the candidates' order (joint ``k``, final mask label
``k + 1``); ``relabel`` applies the decision to the masks, so that masks, joints, the twin and the
export agree on one set of parts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.spatial import cKDTree

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.joints import Joint, StateRefineConfig, joint_transforms, refine_joint_states
from artitwin_core.masks import MaskSequence
from artitwin_core.parts._config import SettleConfig
from artitwin_core.parts._types import Fate, PartFate
from artitwin_core.tracking._lift import lift_pixels, pixel_rays


@dataclass(frozen=True)
class PartDecision:
    """What :func:`settle_parts` decided.

    Attributes:
        fates: one per candidate, in candidate order; ``part`` filled for kept and merged ones.
        kept_labels: the candidate mask label of each final part, in final order (joint ``k``).
        label_map: ``[M + 1]`` int32, the final mask label (``k + 1``, 0 = not a part) of each
            candidate mask label (index 0 is 0).
        replaced: kept candidate label -> its joint, where that is not the one given for it:
            the part finder's (``depth_joints``, its states refitted to the part's depth, a door's
            line to its face planes), or a screw reduced to the slide or turn its depth prefers.
        from_depth: the labels of ``replaced`` whose joint is the part finder's.
    """

    fates: tuple[PartFate, ...]
    kept_labels: tuple[int, ...]
    label_map: np.ndarray
    replaced: dict[int, Joint] = field(default_factory=dict)
    from_depth: tuple[int, ...] = ()


@dataclass
class _Candidate:
    label: int
    index: int
    joint: Joint | None
    tracks: int
    frames: list[tuple[int, np.ndarray]]  # (frame, canonical points [N, 3])
    depth_px: int
    depth_frames: int
    from_depth: str = ""  # the joint is the part finder's: why the tracks' could not serve, and the depth's evidence
    refused: str = ""  # the part finder's joint was offered and refused: why
    reduced: str = ""  # a screw replaced by the simpler joint its depth prefers: why


def settle_parts(
    dynamic: Capture,
    masks: MaskSequence,
    canonical_from_session: np.ndarray,
    joints: dict[int, Joint],
    *,
    candidates: np.ndarray | None = None,
    tracks: dict[int, int] | None = None,
    earlier: Sequence[PartFate] = (),
    depth_joints: dict[int, Joint] | None = None,
    screws_asked: Sequence[int] = (),
    config: SettleConfig | None = None,
) -> PartDecision:
    """Decide every candidate part's fate.

    Args:
        dynamic: the dynamic recording (its session frame), for the candidates' depth.
        masks: the candidate part labels ``[T, H, W]`` (1..M) and hand masks of its frames.
        canonical_from_session: ``[4, 4]`` the registration.
        joints: candidate mask label -> the joint fitted to its tracks (canonical frame); a label
            with no entry got none.
        candidates: ``[M]`` the part finder's candidate index of each mask label; None: label - 1.
        tracks: candidate mask label -> its valid tracks (for the reasons and which of two
            same-joint candidates absorbs the other).
        earlier: fates already decided (the part finder's, for candidates it never labelled; the
            joint fit's, for labels it could not fit): kept in the result, their ``part`` filled.
        depth_joints: candidate mask label -> the part finder's joint, fitted to the change in
            depth (canonical frame): it stands in for a candidate whose tracks gave no joint, a
            fixed one, one that hardly moves (``min_range_*``) or one its depth refutes, where the
            candidate's depth confirms it (``confirm_min_ratio``, ``confirm_min_margin_m``).
        screws_asked: candidate mask labels whose screw the user asked for (the effect
            ``screw_joint``): left a screw even where the depth prefers a slide or a turn.
        config: thresholds.

    Returns:
        A :class:`PartDecision` covering every candidate.
    """
    cfg = config or SettleConfig()
    part = np.asarray(masks.part)
    if part.ndim != 3 or part.shape[0] != dynamic.num_frames:
        raise InputError(
            f"settle_parts: the masks are {part.shape} for a recording of {dynamic.num_frames} frames; "
            "give the part masks of this recording."
        )
    n_labels = int(part.max()) if part.size else 0
    if candidates is not None:
        candidates = np.asarray(candidates, dtype=np.int64)
        if candidates.shape[0] < n_labels:
            raise InputError(f"settle_parts: {candidates.shape[0]} candidate indices for mask labels up to {n_labels}.")
        n_labels = candidates.shape[0]
    earlier_by_label = {f.label: f for f in earlier if f.label}
    c_from_s = np.asarray(canonical_from_session, dtype=np.float64)
    cands = {
        lab: _lift_candidate(dynamic, masks, lab, lab - 1 if candidates is None else int(candidates[lab - 1]), joints.get(lab), (tracks or {}).get(lab, 0), c_from_s, cfg)
        for lab in range(1, n_labels + 1)
    }
    for lab, c in cands.items():
        if (depth := (depth_joints or {}).get(lab)) is None:
            continue
        if c.joint is None or c.joint.joint_type == "fixed":
            _stand_in(c, depth, earlier_by_label.get(lab), cfg, dynamic, masks, c_from_s)
        elif _too_small(c.joint, cfg) and not _too_small(depth, cfg):
            # Tracks held by the static edges around a part (or by the hand) drift a little with
            # it: a joint that hardly moves is no motion of its own, as a fixed one.
            _stand_in(c, depth, None, cfg, dynamic, masks, c_from_s,
                      f"the {c.joint.joint_type} joint fitted to its {c.tracks} tracks moves it by only {_range(c.joint, cfg)}")
    decided: dict[int, PartFate] = {}
    kept: list[int] = []
    unconfirmed: dict[int, str] = {}  # a joint that is no motion of its own, and why
    # A joint of its own, and depth enough: kept, unless it is the same joint as a kept neighbour's.
    for lab, c in cands.items():
        if c.depth_px < cfg.min_depth_points:
            decided[lab] = _fate(c, "dropped", f"too few depth points: {c.depth_px} depth pixels inside its mask over "
                                 f"{c.depth_frames} frames (at least {cfg.min_depth_points} are needed to build its mesh)")
            continue
        if c.joint is None or c.joint.joint_type == "fixed":
            continue
        if _too_small(c.joint, cfg):
            unconfirmed[lab] = f"the {c.joint.joint_type} joint fitted to its {c.tracks} tracks moves it by only {_range(c.joint, cfg)}"
            continue
        finder = (depth_joints or {}).get(lab)
        if not c.from_depth and finder is not None and finder.joint_type != "fixed" and _too_small(finder, cfg):
            # The part finder fitted the change in its depth with hardly any motion: the change
            # is not a part moving (the fringe of the static model, seen from nearer), whatever
            # short tracks on the background say.
            unconfirmed[lab] = (f"the part finder's fit to its change in depth moves it by only {_range(finder, cfg)}, "
                                f"although the {c.joint.joint_type} joint fitted to its {c.tracks} tracks spans "
                                f"{_range(c.joint, cfg, limit=False)}")
            continue
        twin = next((k for k in kept if _adjacent(part, k, lab, cfg) and _same_joint(cands[k], c, cfg)), None)
        if twin is None:
            kept.append(lab)
            continue
        big, small = (twin, lab) if cands[twin].tracks >= c.tracks else (lab, twin)
        if big == lab:
            kept[kept.index(twin)] = lab
        decided[small] = _fate(cands[small], "merged", f"the same joint as candidate {cands[big].index} and moving "
                               f"with it ({cands[small].tracks} tracks against {cands[big].tracks})", into=cands[big])
    # A joint its own depth does not confirm (its points, moved back by it, agree with its closed
    # surface no better than held still, or it never moves them far enough to tell) is no motion
    # of its own: a planar patch "turning" in its plane, a fit to drifting tracks. It is treated
    # below as a candidate with no joint.
    for lab in list(kept):
        c = cands[lab]
        fit = _misfits(c, _joint(c), cfg)
        if fit is None or not _confirms(fit, cfg):
            # Tracks that the hand drags over a part, or that stick to the static edges around it,
            # can fit a joint its depth refutes; the part finder's joint, fitted to that depth,
            # stands in where the depth confirms it, as for a part whose tracks saw no motion.
            refuted = _refutation(c, fit, cfg)
            if not c.from_depth and (depth := (depth_joints or {}).get(lab)) is not None:
                _stand_in(c, depth, None, cfg, dynamic, masks, c_from_s, refuted)
            if not c.from_depth:
                kept.remove(lab)
                unconfirmed[lab] = refuted
        elif _joint(c).joint_type == "screw" and lab not in screws_asked:
            _reduce_screw(c, fit, cfg)
            if _joint(c).joint_type == "screw" and (depth := (depth_joints or {}).get(lab)) is not None:
                _stand_in_for_screw(c, fit, depth, cfg, dynamic, masks, c_from_s)
    # A piece of a bigger part fitted with a joint of its own (a strip along a door's edge): merged
    # when the bigger neighbour's motion explains its depth too. One joint explains both; two would
    # export a spurious link. Smallest first, into a neighbour with more tracks that is still kept.
    for lab in sorted(kept, key=lambda k: cands[k].tracks):
        c = cands[lab]
        for k in sorted(kept, key=lambda k: -cands[k].tracks):
            if k == lab or cands[k].tracks <= c.tracks or not _adjacent(part, k, lab, cfg):
                continue
            fit = _misfits(c, _joint(cands[k]), cfg)
            if fit is not None and _explains(fit, cfg):
                kept.remove(lab)
                decided[lab] = _fate(c, "merged", f"candidate {cands[k].index}'s motion explains its depth as well as its "
                                     f"own {_joint(c).joint_type} joint ({1e3 * fit[0]:.0f} mm from its closed surface moved "
                                     f"back with it, {1e3 * fit[1]:.0f} mm held still): one part, not two", into=cands[k])
                break
    # No joint of its own: merged into the kept neighbour whose motion explains its depth, or dropped.
    for lab, c in cands.items():
        if lab in decided or lab in kept:
            continue
        why = unconfirmed.get(lab) or _no_joint_reason(c, earlier_by_label.get(lab))
        why += f"; {c.refused}" if c.refused else ""
        decided[lab] = _explain_or_drop(c, why, [cands[k] for k in kept if _adjacent(part, k, lab, cfg)], cfg)
    return _resolve(cands, decided, kept, earlier, n_labels)


def _refutation(c: _Candidate, fit: tuple[float, float] | None, cfg: SettleConfig) -> str:
    """Why ``c``'s own joint, with its misfits ``fit`` (:func:`_misfits`), is not confirmed."""
    if fit is None:
        # Its motion never carries its points min_discrimination_m beyond where it sits closed
        # in a frame with depth: nothing confirms it moves (a piece of the arm beside a part,
        # fitted a small turn about its own corner).
        return (f"the {_joint(c).joint_type} joint fitted to its {c.tracks} tracks never moves its points "
                f"{1e3 * cfg.min_discrimination_m:.0f} mm beyond where they sit closed in a frame with depth, "
                "so its depth cannot confirm it")
    return f"its depth does not confirm the {_joint(c).joint_type} joint fitted to its {c.tracks} tracks ({_own_misfits(fit)})"


def _stand_in(
    c: _Candidate, depth: Joint, earlier: PartFate | None, cfg: SettleConfig, dynamic: Capture, masks: MaskSequence,
    c_from_s: np.ndarray, why: str = "",
) -> None:
    """Give ``c`` (no joint from its tracks, a fixed one, or one its depth refutes: ``why``) the
    part finder's joint ``depth`` where :func:`_confirmed_depth_joint` finds ``c``'s depth
    confirms it; the tests of :func:`settle_parts` then treat it like any fitted joint."""
    found = _confirmed_depth_joint(c, depth, cfg, dynamic, masks, c_from_s)
    if found is None:
        return
    why = why or _no_joint_reason(c, earlier)  # of the tracks' joint: before it is replaced
    c.joint, fit = found
    c.from_depth = (f"{why}; the part finder's {depth.joint_type} joint, fitted to its change in depth, stands in"
                    f"{' (its line refitted to its face planes)' if depth.joint_type in ('revolute', 'screw') else ''}: its depth confirms it "
                    f"({_own_misfits(fit)})")


def _confirmed_depth_joint(
    c: _Candidate, depth: Joint, cfg: SettleConfig, dynamic: Capture, masks: MaskSequence, c_from_s: np.ndarray
) -> tuple[Joint, tuple[float, float]] | None:
    """The part finder's joint ``depth`` with its states refitted to ``c``'s depth, and its
    misfits there (:func:`_misfits`), where that depth confirms it; else None, with why in
    ``c.refused``. A door's line must be confirmed by its face planes too: its states are free
    per frame, so a line on the wrong edge of the door can still move its depth back near its
    closed surface."""
    if depth.joint_type == "fixed" or c.depth_px < cfg.min_depth_points:
        return None
    line = StateRefineConfig(
        rest_rad=max(StateRefineConfig.rest_rad, cfg.stand_in_rest_frac * _span(depth)),
        axis_max_shift_m=cfg.stand_in_max_shift_m, axis_max_change_rad=float(np.radians(cfg.stand_in_max_turn_deg)),
    )  # fmt: skip
    try:
        joint = refine_joint_states(depth, dynamic, masks, c.label, c_from_s, line)
    except Exception as e:  # noqa: BLE001 (no stand-in; the candidate is settled without it, saying why)
        c.refused = f"the part finder's {depth.joint_type} joint could not be refitted to its depth ({type(e).__name__}: {e})"
        return None
    if depth.joint_type in ("revolute", "screw") and joint.axis_se_rad is None:
        c.refused = (f"the part finder's {depth.joint_type} joint was not taken: its face planes do not confirm its line "
                     "(too few turned frames showing one plane, or none closed)")
        return None
    fit = _misfits(c, joint, cfg)
    if fit is None or not _confirms(fit, cfg):
        told = "no frame moves it enough to tell" if fit is None else _own_misfits(fit)
        c.refused = f"the part finder's {depth.joint_type} joint was not taken: its depth does not confirm it ({told})"
        return None
    return joint, fit


def _reduce_screw(c: _Candidate, fit: tuple[float, float], cfg: SettleConfig) -> None:
    """Replace ``c``'s screw by its slide (the screw's travel along its axis) or its turn (the
    screw without pitch) where ``c``'s depth explains that nearly as well (``screw_keep_ratio``).
    Furniture hardly ever screws; tracks on a drawer that a hand or a door crosses can carry a turn
    the drawer does not make."""
    screw = _joint(c)
    q = np.asarray(screw.q, np.float64)
    slide_q = screw.pitch * q
    options = [
        replace(screw, joint_type="prismatic", q=slide_q, q_range=np.array([np.nanmin(slide_q), np.nanmax(slide_q)]),
                pitch=0.0),
        replace(screw, joint_type="revolute", pitch=0.0),
    ]  # fmt: skip
    tests = [(j, m) for j in options if (m := _misfits(c, j, cfg)) is not None and _confirms(m, cfg)]
    if not tests:
        return
    simpler, (moving, still) = min(tests, key=lambda jm: jm[1][0])
    if fit[0] < cfg.screw_keep_ratio * moving:
        return
    c.joint = simpler
    c.reduced = (f"kept as a {simpler.joint_type} joint: its depth explains that ({1e3 * moving:.0f} mm from its closed "
                 f"surface moved back by it) about as well as the screw fitted to its {c.tracks} tracks "
                 f"({1e3 * fit[0]:.0f} mm; a screw is kept only below {cfg.screw_keep_ratio:g} of the simpler joint's)")


def _stand_in_for_screw(
    c: _Candidate, fit: tuple[float, float], depth: Joint, cfg: SettleConfig, dynamic: Capture, masks: MaskSequence,
    c_from_s: np.ndarray,
) -> None:
    """Replace ``c``'s screw (its misfits ``fit``), which nobody asked for and neither its slide
    nor its turn explains, by the part finder's joint ``depth`` (:func:`_confirmed_depth_joint`)
    where that explains ``c``'s depth better by ``screw_keep_ratio``. Tracks on a door that the
    hand pulling a drawer below it crosses mix the two parts' motions into a screw."""
    found = _confirmed_depth_joint(c, depth, cfg, dynamic, masks, c_from_s)
    if found is None or fit[0] < cfg.screw_keep_ratio * found[1][0]:
        return
    c.joint, own = found
    c.from_depth = (f"neither the slide nor the turn of the screw fitted to its {c.tracks} tracks explains its depth "
                    f"({_own_misfits(fit)} under the screw); the part finder's {depth.joint_type} joint, fitted to its "
                    f"change in depth, explains it better: {_own_misfits(own)}")


def _own_misfits(fit: tuple[float, float]) -> str:
    """A candidate's misfits under its own joint (:func:`_misfits`), in words."""
    return f"{1e3 * fit[0]:.0f} mm from its closed surface moved back by it, {1e3 * fit[1]:.0f} mm held still"


def _confirms(fit: tuple[float, float], cfg: SettleConfig) -> bool:
    """Whether a joint's own misfits ``(moved back, held still)`` (:func:`_misfits`) confirm it."""
    moving, still = fit
    return still >= cfg.confirm_min_ratio * moving and still - moving >= cfg.confirm_min_margin_m


def relabel(part: np.ndarray, label_map: np.ndarray) -> np.ndarray:
    """``[T, H, W]`` uint8 candidate labels -> final labels by ``label_map`` (``PartDecision``)."""
    lut = np.zeros(256, np.uint8)
    lut[: len(label_map)] = np.asarray(label_map, dtype=np.uint8)
    return lut[np.asarray(part, dtype=np.uint8)]


def _joint(c: _Candidate) -> Joint:
    """The joint of a kept candidate (only candidates with a joint are kept)."""
    if c.joint is None:
        raise RuntimeError(f"candidate {c.index} was kept without a joint")
    return c.joint


def _fate(c: _Candidate, fate: Fate, reason: str = "", into: _Candidate | None = None) -> PartFate:
    return PartFate(candidate=c.index, fate=fate, stage="settle_parts", reason=reason,
                    into=None if into is None else into.index, label=c.label)


def _lift_candidate(
    dynamic: Capture, masks: MaskSequence, label: int, index: int, joint: Joint | None, tracks: int,
    c_from_s: np.ndarray, cfg: SettleConfig,
) -> _Candidate:
    """The candidate's canonical depth points per frame (hand excluded) and its distinct depth pixels."""
    frames, depth_px, depth_frames = [], 0, 0
    for t in range(dynamic.num_frames):
        v, u = np.nonzero((masks.part[t] == label) & ~np.asarray(masks.hand[t], bool))
        if u.size == 0:
            continue
        pix = np.stack([u, v], -1).astype(np.float64)
        pts, ok = lift_pixels(
            pix, np.asarray(dynamic.depth[t]),
            None if dynamic.confidence is None else np.asarray(dynamic.confidence[t]),
            np.asarray(dynamic.rgb_intrinsics[t]), np.asarray(dynamic.depth_intrinsics[t]),
            c_from_s @ np.asarray(dynamic.world_from_camera[t], np.float64), dynamic.distortion,
        )
        if not ok.any():
            continue
        # Distinct depth pixels: the RGB mask is finer than the depth map.
        rays = pixel_rays(pix[ok], dynamic.rgb_intrinsics[t], dynamic.distortion)
        fx, fy, cx, cy = (float(x) for x in dynamic.depth_intrinsics[t])
        cells = np.unique(np.rint(np.stack([rays[:, 0] * fx + cx, rays[:, 1] * fy + cy], -1)).astype(np.int64), axis=0)
        depth_px += len(cells)
        depth_frames += 1
        pts = pts[ok]
        if len(pts) > cfg.max_points_per_frame:
            pts = pts[np.linspace(0, len(pts) - 1, cfg.max_points_per_frame).astype(np.int64)]
        frames.append((t, pts))
    return _Candidate(label, index, joint, tracks, frames, depth_px, depth_frames)


def _adjacent(part: np.ndarray, a: int, b: int, cfg: SettleConfig) -> bool:
    """Whether candidates ``a`` and ``b`` touch (masks grown by ``adjacency_px``) in some frame."""
    k = np.ones((2 * cfg.adjacency_px + 1,) * 2, np.uint8)
    for t in range(part.shape[0]):
        mb = part[t] == b
        if not mb.any() or not (part[t] == a).any():
            continue
        if (cv2.dilate((part[t] == a).astype(np.uint8), k).astype(bool) & mb).any():
            return True
    return False


def _same_joint(a: _Candidate, b: _Candidate, cfg: SettleConfig) -> bool:
    """Whether ``b``'s fitted joint is ``a``'s: type, axis, line (rotations) and states agree."""
    ja, jb = a.joint, b.joint
    if ja is None or jb is None or ja.joint_type != jb.joint_type:
        return False
    ax_a = np.asarray(ja.axis, np.float64) / np.linalg.norm(ja.axis)
    ax_b = np.asarray(jb.axis, np.float64) / np.linalg.norm(jb.axis)
    cos = float(ax_a @ ax_b)
    if abs(cos) < np.cos(np.radians(cfg.same_axis_deg)):
        return False
    if ja.joint_type != "prismatic":
        at = np.concatenate([p for _, p in b.frames]).mean(0) if b.frames else np.asarray(jb.pivot, np.float64)
        d = []
        for j, ax in ((ja, ax_a), (jb, ax_b)):
            off = at - np.asarray(j.pivot, np.float64)
            d.append(off - (off @ ax) * ax)
        if np.linalg.norm(d[0] - d[1]) > cfg.same_line_m:
            return False
    # Opposite axes describe the same motion with opposite states.
    qa, qb = np.asarray(ja.q, np.float64), np.sign(cos) * np.asarray(jb.q, np.float64)
    both = np.isfinite(qa) & np.isfinite(qb)
    if not both.any():
        return False
    span = float(np.nanmax(np.abs(qa))) if np.isfinite(qa).any() else 0.0
    return float(np.median(np.abs(qa[both] - qb[both]))) <= max(cfg.same_state_frac * span, cfg.same_state_floor)


def _no_joint_reason(c: _Candidate, earlier: PartFate | None) -> str:
    if c.joint is not None and c.joint.joint_type == "fixed":
        return f"its {c.tracks} tracks show no motion of its own (fitted as fixed)"
    if earlier is not None and earlier.reason:
        return earlier.reason
    return "no joint could be fitted" if c.tracks else "no point could be tracked on it"


def _explain_or_drop(c: _Candidate, why: str, neighbours: list[_Candidate], cfg: SettleConfig) -> PartFate:
    """Merged into the neighbour whose motion explains ``c``'s depth, or dropped saying why."""
    tests = [(n, m) for n in neighbours if (m := _misfits(c, _joint(n), cfg)) is not None]
    if not tests:
        where = "no kept part touches it" if not neighbours else "it is not seen both closed and moved by its neighbours"
        return _fate(c, "dropped", f"{why}; {where}, so nothing tells whether it moves")
    n, (moving, still) = min(tests, key=lambda nm: nm[1][0])
    mm = (f"{1e3 * moving:.0f} mm from its closed surface moved back with candidate {n.index}, "
          f"{1e3 * still:.0f} mm held still")
    if _explains((moving, still), cfg):
        return _fate(c, "merged", f"{why}; candidate {n.index}'s motion explains its depth ({mm})", into=n)
    if still <= cfg.merge_max_misfit_m and cfg.merge_min_ratio * still <= moving:
        return _fate(c, "dropped", f"{why}; it did not move while its neighbour did ({mm})")
    return _fate(c, "dropped", f"{why}; no kept part's motion explains its depth ({mm})")


def _too_small(joint: Joint, cfg: SettleConfig) -> bool:
    """Whether ``joint``'s states span less than ``min_range_m`` (slides) or ``min_range_deg``."""
    return _span(joint) < (cfg.min_range_m if joint.joint_type == "prismatic" else np.radians(cfg.min_range_deg))


def _range(joint: Joint, cfg: SettleConfig, limit: bool = True) -> str:
    """``joint``'s span in words, with the limit it is held to."""
    if joint.joint_type == "prismatic":
        return f"{1e3 * _span(joint):.0f} mm" + (f" (min_range_m {1e3 * cfg.min_range_m:.0f} mm)" if limit else "")
    return f"{np.degrees(_span(joint)):.1f} deg" + (f" (min_range_deg {cfg.min_range_deg:g})" if limit else "")


def _span(joint: Joint) -> float:
    """The range of a joint's states over the recording (metres or radians)."""
    q = np.asarray(joint.q, np.float64)
    q = q[np.isfinite(q)]
    return float(q.max() - q.min()) if q.size else 0.0


def _explains(fit: tuple[float, float], cfg: SettleConfig) -> bool:
    """Whether a motion's misfits ``(moved back, held still)`` (:func:`_misfits`) say it moved ``c``."""
    moving, still = fit
    return moving <= cfg.merge_max_misfit_m and cfg.merge_min_ratio * moving <= still


def _misfits(c: _Candidate, joint: Joint, cfg: SettleConfig) -> tuple[float, float] | None:
    """How well ``joint``'s motion explains ``c``'s depth, against ``c`` holding still.

    The frames in which ``joint`` has hardly moved ``c``'s points (less than a third of
    ``min_discrimination_m``; at least the least moved frame) show its closed surface. Each frame
    in which the motion moves its points at least ``min_discrimination_m`` is moved back to the
    closed state by the joint: returns the median nearest-neighbour distance (metres) of those
    points to the closed surface, and the same for the points held still. None when no frame
    moves it enough."""
    frames = [(t, p) for t, p in c.frames if len(p) >= cfg.min_frame_points and np.isfinite(joint.q[t])]
    if len(frames) < 2:
        return None
    ts = np.array([t for t, _ in frames])
    motions = joint_transforms(joint.joint_type, joint.axis, joint.pivot, np.asarray(joint.q, np.float64)[ts], joint.pitch)
    closed, moved = [], []
    for (_, pts), m in zip(frames, motions, strict=True):
        back = (pts - m[:3, 3]) @ m[:3, :3]  # x = R c + t  =>  c = R^T (x - t)
        closed.append(back)
        moved.append(float(np.median(np.linalg.norm(pts - back, axis=1))))
    moved_by = np.asarray(moved)
    ref = moved_by <= max(cfg.min_discrimination_m / 3.0, float(moved_by.min()))
    test = moved_by >= float(moved_by[ref].max()) + cfg.min_discrimination_m
    if not test.any():
        return None
    tree = cKDTree(np.concatenate([closed[i] for i in np.flatnonzero(ref)]))
    moving = [float(np.median(tree.query(closed[i])[0])) for i in np.flatnonzero(test)]
    still = [float(np.median(tree.query(frames[i][1])[0])) for i in np.flatnonzero(test)]
    return float(np.median(moving)), float(np.median(still))


def _resolve(
    cands: dict[int, _Candidate], decided: dict[int, PartFate], kept: list[int], earlier: Sequence[PartFate], n_labels: int
) -> PartDecision:
    """Number the kept parts, follow merges to the part they end in, and list every candidate."""
    part_of_label = {lab: k for k, lab in enumerate(kept)}
    label_of_index = {c.index: lab for lab, c in cands.items()}

    def final(lab: int, seen: int = 0) -> int | None:
        if lab in part_of_label:
            return part_of_label[lab]
        f = decided.get(lab)
        if f is None or f.fate != "merged" or f.into is None or seen > n_labels:
            return None
        return final(label_of_index[f.into], seen + 1)

    fates = [PartFate(candidate=cands[lab].index, fate="kept", stage="settle_parts", part=k, label=lab,
                      reason="; ".join(r for r in (cands[lab].from_depth, cands[lab].reduced) if r))
             for k, lab in enumerate(kept)]
    fates += [replace(f, part=final(lab)) for lab, f in decided.items()]
    for f in earlier:
        if f.label:
            continue  # a labelled candidate: decided above
        into = label_of_index.get(f.into) if f.into is not None else None
        fates.append(replace(f, part=None if into is None else final(into)))
    label_map = np.zeros(n_labels + 1, np.int32)
    for lab in range(1, n_labels + 1):
        k = final(lab)
        label_map[lab] = 0 if k is None else k + 1
    replaced = {lab: _joint(cands[lab]) for lab in kept if cands[lab].from_depth or cands[lab].reduced}
    from_depth = tuple(lab for lab in kept if cands[lab].from_depth)
    return PartDecision(tuple(sorted(fates, key=lambda f: f.candidate)), tuple(kept), label_map, replaced, from_depth)
