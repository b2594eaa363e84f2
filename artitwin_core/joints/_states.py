"""Refining a joint from depth: each frame's state (doors and drawers), and a door's hinge line.

Point tracks end when a door's front face turns out of view, and ``estimate_joint`` then holds
``q``: the fitted opening saturates short of the true one. The part's pixels still carry depth
after that (the door's edge, then its inside face), so each frame's ``q`` is fitted here as a
1-DoF pose of a surface model of the part:

1. Lift the part's mask pixels (eroded, hand excluded) to the canonical frame with the frame's
   depth, as ``artitwin_core.tracking`` lifts track pixels, with their surface normals.
2. Build a closed-state (``q = 0``) point model from the frames whose tracked ``q`` is
   confident: undo the joint motion at ``q[t]``, merge on a voxel grid, PCA normals turned
   towards the cameras, each point moved onto its neighbours' plane. Each seed is first fitted
   against the other seeds (leave-one-out) so that a wrong one cannot vouch for itself.
3. For each frame, score ``q`` on a coarse grid then a fine one: move the frame's points back to
   the closed state at ``q``, take the point-to-plane distance to the nearest model point and
   subtract a free offset per viewing side (the robust median): a door seen from behind is a
   slab whose inside face lies one thickness behind the front face; without the offset that
   thickness would bias the angle by about ``thickness * mean(s) / mean(s^2)`` (~3 deg). A
   truncated quadratic loss counts points farther than ``gate_m`` from the model, or whose own
   normal turns more than ``normal_gate_deg`` from their match's (the door's edge face against
   the front face's border), as outliers.
4. Optionally (``grow``, off: it spread one frame's error to the next) frames
   fitted confidently add their points to the model.

A frame keeps its tracked ``q`` where that is confident and the depth fit agrees with it; the
depth fit replaces it where the tracks are absent or unsure and the fit is more confident;
frames that neither measured well (no mask depth, a door mostly out of view) are bridged from
the measured ones by a monotone cubic, keeping their input confidence. Before the first and
after the last anchor there is nothing to bridge to: there a depth fit with a small standard
error measures its frame even on few inliers (``tail_max_se_rad``: a door seen edge-on to the
end of the recording), and the nearest measured value is held otherwise.

A prismatic joint's states are fitted the same way without the free offsets: a drawer front's
normal is the joint axis, so its offset along the normal is the state (the angles of the config
read as distances at ``prismatic_lever_m``). Tracks on a drawer front pulled at a close-up camera
from above are lost under the hand for a third of the opening (generalization seed 26: ``q`` held
near 0 over six frames while the drawer moved 12-30 cm). Fixed joints are returned unchanged.

With ``refine_axis``, a slide within ``slide_front_max_deg`` of its front's normal takes that
normal as its axis where the tracks' axis disagrees with it beyond both errors: a drawer slides
along its front's normal, and tracks that a hand crosses drift sideways with it.

Then (``refine_axis``) a revolute part that is a slab gets its line from the planes its faces
show (``fit_line_from_planes``): the tracks on a weakly textured door slide along it and leave
its pivot a centimetre off, which no per-frame state can undo. The frames whose face plane was
measured keep the states that fit gives them, and the others are refitted as above with the
new line.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.interpolate import PchipInterpolator

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.joints._config import StateRefineConfig
from artitwin_core.joints._depth_fit import fit_line_from_planes, fit_slide_axis_from_front
from artitwin_core.joints._model import joint_motion
from artitwin_core.joints._surface import SurfaceModel, build_model, lift_frame, to_closed
from artitwin_core.joints._types import Joint
from artitwin_core.masks import MaskSequence


def _validate(joint: Joint, capture: Capture, masks: MaskSequence, part_label: int, c_from_s) -> np.ndarray:
    t_count = capture.num_frames
    part = np.asarray(masks.part)
    hand = np.asarray(masks.hand)
    rgb_shape = tuple(capture.rgb.shape[:3])
    if part.shape != rgb_shape:
        raise InputError(
            f"masks.part has shape {part.shape} but the capture's RGB frames are {rgb_shape} [T, H, W]; "
            "pass the part masks made for this dynamic recording."
        )
    if hand.shape != rgb_shape:
        raise InputError(
            f"masks.hand has shape {hand.shape} but the capture's RGB frames are {rgb_shape} [T, H, W]; "
            "pass the hand masks made for this dynamic recording."
        )
    q = np.asarray(joint.q)
    if q.shape != (t_count,):
        raise InputError(
            f"joint.q has shape {q.shape} but the capture has {t_count} frames; "
            "pass the joint fitted to this recording's tracks."
        )
    if not np.any(part == part_label):
        raise InputError(
            f"part_label {part_label} does not occur in masks.part (labels present: "
            f"{[int(v) for v in np.unique(part) if v > 0]}); pass the label the joint was fitted to."
        )
    c = np.asarray(c_from_s, dtype=np.float64)
    if c.shape != (4, 4) or not np.all(np.isfinite(c)):
        raise InputError(
            f"canonical_from_session must be a finite [4, 4] transform, got shape {c.shape}; "
            "pass the registration's canonical_from_session."
        )
    return c


def _frame_cost(
    model: SurfaceModel, closed: np.ndarray, cam: np.ndarray, normals: np.ndarray | None, cfg: StateRefineConfig,
    free_offset: bool = True,
):
    """Truncated point-to-plane cost per hypothesis of ``closed [Q, N, 3]`` seen from ``cam [Q, 3]``.

    ``normals [Q, N, 3]`` (the frame's own surface normals, moved like the points, or None): a
    point whose surface turns more than ``normal_gate_deg`` from its model match's is an outlier.
    A door's edge face, seen only once the door is open, matches the front face's border
    otherwise, at the largest lever arm, and tilts the fit.

    A frame point whose nearest model point was seen from the same side of the surface (the
    view directions agree with the model normal) and one seen from the other side (a door's
    inside face against its front face) each get their own free offset along the normal
    (``free_offset``; off for a slide, whose state is that offset).

    Returns cost ``[Q]`` (in units of ``robust_scale_m^2``), inlier counts ``[Q]`` and the RMS of
    inlier residuals ``[Q]`` metres.
    """
    q_count, n = closed.shape[:2]
    dist, idx = model.tree.query(closed.reshape(-1, 3), k=1, distance_upper_bound=cfg.gate_m, workers=-1)
    dist = dist.reshape(q_count, n)
    near = np.isfinite(dist)
    idx = np.where(near.reshape(-1), idx, 0).reshape(q_count, n)
    nrm = model.normals[idx]
    if normals is not None:
        near &= np.abs(np.einsum("qni,qni->qn", normals, nrm)) >= np.cos(np.radians(cfg.normal_gate_deg))
    r = np.einsum("qni,qni->qn", closed - model.points[idx], nrm)
    same = np.einsum("qni,qni->qn", cam[:, None, :] - closed, nrm) > 0
    if free_offset:
        dev = np.zeros((q_count, n))
        for group in (same, ~same):
            sel = near & group
            rows = sel.any(1)
            off = np.zeros(q_count)
            if rows.any():
                off[rows] = np.nanmedian(np.where(sel[rows], r[rows], np.nan), axis=1)
            dev = np.where(sel, r - off[:, None], dev)
    else:
        dev = np.where(near, r, 0.0)
    z2 = np.where(near, np.minimum((dev / cfg.robust_scale_m) ** 2, 1.0), 1.0)
    inl = near & (z2 < 1.0)
    cost = z2.sum(1)
    rms = np.sqrt(np.where(inl, dev**2, 0.0).sum(1) / np.maximum(inl.sum(1), 1))
    return cost, inl.sum(1), rms


def _fit_frame(
    joint: Joint,
    model: SurfaceModel,
    pts: np.ndarray,
    nrm: np.ndarray | None,
    cam: np.ndarray,
    lo: float,
    hi: float,
    cfg: StateRefineConfig,
    free_offset: bool = True,
):
    """Best ``q`` of one frame (points and normals ``[N, 3]``, camera centre ``[3]``), its standard error,
    inlier fraction and RMS residual."""

    def cost_at(qs, step=1):
        p, n = pts[::step], None if nrm is None else nrm[::step]
        rot = joint_motion(joint.joint_type, joint.axis, joint.pivot, qs, joint.pitch)[0]
        moved = None if n is None else np.einsum("qji,nj->qni", rot, n)
        return _frame_cost(
            model, to_closed(joint, p, qs), to_closed(joint, cam[None], qs)[:, 0], moved, cfg, free_offset
        )

    grid = np.arange(lo, hi + 0.5 * cfg.coarse_step_rad, cfg.coarse_step_rad)
    # The coarse grid only has to land in the right basin: a subsample of the points will do.
    cost, _, _ = cost_at(grid, max(1, pts.shape[0] // cfg.coarse_points))
    q0 = grid[int(np.argmin(cost))]
    half = cfg.coarse_step_rad * cfg.fine_span_steps
    fine = q0 + np.arange(-half, half + 1e-12, cfg.fine_step_rad)
    cost, n_in, rms = cost_at(fine)
    k = int(np.argmin(cost))
    q_best = fine[k]
    # Curvature of the cost about its minimum: a parabola through the fine grid's +-3 steps
    # (wider than one step: nearest-neighbour costs are piecewise and locally jagged).
    lo_k, hi_k = max(0, k - 3), min(fine.size, k + 4)
    curv = 0.0
    if hi_k - lo_k >= 3:
        coef = np.polyfit(fine[lo_k:hi_k] - q_best, cost[lo_k:hi_k], 2)
        curv = float(coef[0])
        if curv > 0 and abs(coef[1] / (2 * curv)) < cfg.fine_step_rad:
            q_best = q_best - coef[1] / (2 * curv)
    frac = float(n_in[k]) / max(pts.shape[0], 1)
    # cost = sum (r / s)^2 over inliers  =>  d2cost/dq2 = 2 sum (dr/dq)^2 / s^2, and the
    # standard error of q is sigma / sqrt(sum (dr/dq)^2), sigma = RMS inlier residual. Neighbouring
    # depth pixels are correlated (bilinear, smoothed sensor): count one in 16 as independent.
    if curv > 0 and n_in[k] > 0:
        info = 2.0 * curv * cfg.robust_scale_m**2 / 2.0
        se = float(rms[k]) / np.sqrt(info / 16.0)
    else:
        se = np.inf
    return float(q_best), se, frac, float(rms[k])


def refine_joint_states(
    joint: Joint,
    capture: Capture,
    masks: MaskSequence,
    part_label: int,
    canonical_from_session: np.ndarray,
    config: StateRefineConfig | None = None,
) -> Joint:
    """Refit each frame's ``q`` of a rotational or prismatic joint against the part's depth, and a
    door's line.

    Args:
        joint: the fitted joint (``estimate_joint``'s), canonical frame, ``q [T]``.
        capture: the dynamic recording the joint was fitted to (depth, intrinsics, session poses).
        masks: its part and hand masks ``[T, H, W]`` at RGB resolution.
        part_label: the label in ``masks.part`` of the part the joint moves.
        canonical_from_session: ``[4, 4]`` registration of the recording's session frame into the
            canonical frame (points in the canonical frame are ``canonical_from_session @
            world_from_camera[t]`` applied to camera points).
        config: hyperparameters; ``StateRefineConfig()`` when None.

    Returns:
        A ``Joint`` of the same type and pitch. Revolute, screw and (with ``prismatic_lever_m``)
        prismatic joints get a refined ``q``,
        ``q_range`` and ``confidence``; on frames whose ``q`` came from the depth fit,
        ``residual`` is its RMS point-to-surface distance (metres) instead of the tracks'. A
        revolute slab's axis and pivot are those of its face planes where ``refine_axis`` is on
        and that fit is trusted (else the input's).
        Frames that neither the tracks nor the depth measured confidently get ``q`` bridged
        from those that were, with their input confidence and residual. Confident tracked
        frames without mask depth keep their ``q``.
        Fixed joints come back unchanged.

    Raises:
        InputError: masks that do not match the capture, ``q`` of another length, a label that
            is not in the masks, or a malformed ``canonical_from_session``.
    """
    cfg = config if config is not None else StateRefineConfig()
    c_from_s = _validate(joint, capture, masks, part_label, canonical_from_session)
    slide = joint.joint_type == "prismatic" and cfg.prismatic_lever_m is not None
    if joint.joint_type not in ("revolute", "screw") and not slide:
        return joint
    lifted = [lift_frame(capture, masks, t, part_label, c_from_s, cfg) for t in range(capture.num_frames)]
    cams = (c_from_s @ np.asarray(capture.world_from_camera, dtype=np.float64))[:, :3, 3]
    if slide:
        refined = _refit_states(joint, lifted, cams, _as_lengths(cfg), free_offset=False)
        return _slide_along_front(refined, lifted, cams, cfg) if cfg.refine_axis and cfg.slide_front_max_deg > 0 else refined
    refined = _refit_states(joint, lifted, cams, cfg)
    if not cfg.refine_axis:
        return refined
    # Only eroded masks show a face's plane; an uneroded sliver is mostly its mixed outline.
    planar = [(p, n) if eroded else (np.zeros((0, 3)), None) for p, n, eroded in lifted]
    fit = fit_line_from_planes(refined, planar, cams, cfg)
    if fit is None:
        return refined
    # Second pass with the depth-fitted line: the frames the line was fitted on keep their
    # jointly fitted ``q`` as confident seeds; every other frame is refitted (or bridged) from
    # them, since its ``q`` was measured with the old line.
    conf = np.where(fit.fitted, fit.confidence, np.where(fit.rest, refined.confidence, 0.0))
    moved = replace(
        refined,
        axis=fit.axis,
        pivot=fit.pivot,
        q=np.where(fit.fitted, fit.q, refined.q),
        residual=np.where(fit.fitted, fit.residual_m, refined.residual),
        confidence=conf,
        axis_se_rad=fit.axis_se_rad,
        pivot_se_m=fit.pivot_se_m,
    )
    return _refit_states(moved, lifted, cams, cfg)


def _slide_along_front(joint: Joint, lifted, cams: np.ndarray, cfg: StateRefineConfig) -> Joint:
    """``joint`` (a slide, states refined) with its axis the normal of its front where the two
    disagree beyond their errors (``slide_front_*``), and its states refitted along it. Tracks
    crossed by a hand drift sideways with it, and depth cannot see a slide's in-plane direction
    (docs/accuracy.md)."""
    fit = fit_slide_axis_from_front(joint, lifted, cams, cfg)
    if fit is None:
        return joint
    axis = np.asarray(joint.axis, dtype=np.float64) / np.linalg.norm(joint.axis)
    apart = float(np.arccos(np.clip(axis @ fit.axis, -1.0, 1.0)))
    errors = float(np.hypot(joint.axis_se_rad or 0.0, fit.se_rad))
    if apart <= max(cfg.slide_front_z * errors, np.radians(cfg.slide_front_min_deg)):
        return joint
    along = replace(joint, axis=fit.axis, axis_se_rad=fit.se_rad)
    return _refit_states(along, lifted, cams, _as_lengths(cfg), free_offset=False)


def _as_lengths(cfg: StateRefineConfig) -> StateRefineConfig:
    """``cfg`` with its angles turned into the distances they move a point at ``prismatic_lever_m``."""
    lever = float(cfg.prismatic_lever_m or 0.0)
    names = ("coarse_step_rad", "search_below_rad", "search_above_rad", "fine_step_rad", "agree_rad",
             "q_tolerance_rad", "tail_max_se_rad")
    return replace(cfg, **{n: lever * getattr(cfg, n) for n in names})


def _refit_states(joint: Joint, lifted, cams: np.ndarray, cfg: StateRefineConfig, free_offset: bool = True) -> Joint:
    """One pass of the per-frame ``q`` fit (steps 1-3 of the module docstring) with the joint's line held
    (``free_offset``: see :func:`_frame_cost`)."""
    t_count = cams.shape[0]
    q_in = np.asarray(joint.q, dtype=np.float64)
    conf_in = np.nan_to_num(np.asarray(joint.confidence, dtype=np.float64))
    pts = [f[0] for f in lifted]
    has_depth = np.array([p.shape[0] >= cfg.min_points for p in pts])
    seeds = np.nonzero(has_depth & np.isfinite(q_in) & (conf_in >= cfg.seed_confidence))[0]
    if seeds.size == 0:
        return joint
    closed: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def add_frame(t: int, q: float) -> None:
        pts_closed = to_closed(joint, pts[t], np.array([q]))[0]
        cam = to_closed(joint, cams[t][None], np.array([q]))[0, 0]
        view = cam - pts_closed
        closed[t] = (pts_closed, view / np.linalg.norm(view, axis=1, keepdims=True))

    def model_of(frames) -> SurfaceModel | None:
        if not frames:
            return None
        return build_model(
            np.concatenate([closed[f][0] for f in frames]),
            np.concatenate([closed[f][1] for f in frames]),
            cfg,
        )

    seed_list = [int(t) for t in seeds]
    for t in seed_list:
        add_frame(t, float(q_in[t]))
    lo = float(np.min(q_in[seeds])) - cfg.search_below_rad
    hi = float(np.max(q_in[seeds])) + cfg.search_above_rad
    if joint.joint_type == "revolute":
        lo, hi = max(lo, -np.pi), min(hi, np.pi)

    q_out = q_in.copy()
    conf_out = conf_in.copy()
    res_in = np.asarray(joint.residual, dtype=np.float64)
    res_out = res_in.copy()
    # Frames whose ``q`` is vouched for: confident tracks (checked by depth where there is
    # depth) or a confident depth fit. The others are bridged from them at the end.
    anchor = np.isfinite(q_in) & (conf_in >= cfg.seed_confidence)
    # Depth fits precise enough to measure a frame beyond the anchors (``tail_max_se_rad``).
    tail_q = np.full(t_count, np.nan)
    tail_res = np.full(t_count, np.nan)

    def fit_and_decide(t: int, model: SurfaceModel) -> bool:
        """Fit frame ``t``; keep its tracked ``q`` if the depth agrees, else take the more
        confident of the two. True when the depth fit replaced ``q``."""
        q_d, se, frac, rms = _fit_frame(joint, model, pts[t], lifted[t][1], cams[t], lo, hi, cfg, free_offset)
        if se <= cfg.tail_max_se_rad and frac * pts[t].shape[0] >= cfg.tail_min_inliers:
            tail_q[t], tail_res[t] = q_d, rms
        conf_d = 0.0
        if frac >= cfg.min_inlier_fraction and np.isfinite(se):
            # Half the points unexplained is a guess (a door mostly out of view), not a fit: the
            # inlier term rises from 0 at ``min_inlier_fraction`` to 1 at ``full_inlier_fraction``.
            span = max(cfg.full_inlier_fraction - cfg.min_inlier_fraction, 1e-6)
            explained = min(1.0, (frac - cfg.min_inlier_fraction) / span)
            conf_d = float(explained / (1.0 + (se / cfg.q_tolerance_rad) ** 2))
        tracked_ok = np.isfinite(q_in[t]) and conf_in[t] >= cfg.seed_confidence
        if tracked_ok and abs(q_d - q_in[t]) <= cfg.agree_rad:
            conf_out[t] = max(conf_in[t], conf_d)
            anchor[t] = True
            return False
        if conf_d > conf_in[t] or not np.isfinite(q_in[t]):
            q_out[t], conf_out[t], res_out[t] = q_d, conf_d, rms
            anchor[t] = conf_d >= cfg.anchor_confidence
            return True
        anchor[t] = tracked_ok
        return False

    # 1. Each seed against a model of the other seeds: a wrong seed must not vouch for itself.
    kept = list(seed_list)
    for t in seed_list:
        others = model_of([f for f in seed_list if f != t])
        if others is not None and fit_and_decide(t, others):
            kept.remove(t)
    model = model_of(kept)
    if model is None:
        return joint
    # 2. Every other frame with depth against the seeds' model (grown as they are fitted).
    for t in range(t_count):
        if not has_depth[t] or t in seeds:
            continue
        if fit_and_decide(t, model) and cfg.grow and conf_out[t] >= cfg.grow_confidence:
            add_frame(t, float(q_out[t]))
            kept.append(t)
            model = model_of(kept) or model
    # Frames neither the tracks nor the depth measured well hold a stale ``q`` (the tracker's
    # last value, or a weak depth fit of a door mostly out of view): bridge them from the
    # anchors instead. Their confidence and residual stay the input's: nothing measured them.
    measured = anchor & np.isfinite(q_out)
    tail = np.zeros(t_count, bool)
    if measured.any():
        # Before the first and after the last anchor, a precise depth fit is the only
        # measurement there is (``tail_max_se_rad``); between anchors the monotone bridge
        # below is the better guess.
        known = np.nonzero(measured)[0]
        frames = np.arange(t_count)
        tail = np.isfinite(tail_q) & ((frames < known[0]) | (frames > known[-1]))
        q_out[tail], res_out[tail] = tail_q[tail], tail_res[tail]
    stale = ~(measured | tail)
    conf_out[stale], res_out[stale] = conf_in[stale], res_in[stale]
    measured |= tail
    if measured.any() and stale.any():
        # Monotone cubic through the measured frames: a hand eases a door in and out, so a
        # straight line between the neighbours of a gap cuts the corner (3 deg on ``tiny``).
        known = np.nonzero(measured)[0]
        gaps = np.nonzero(stale)[0]
        if known.size >= 2:
            q_out[gaps] = PchipInterpolator(known, q_out[known], extrapolate=False)(gaps)
        # Before the first and after the last measured frame: hold the nearest measured value.
        q_out[gaps] = np.where(np.isfinite(q_out[gaps]), q_out[gaps], np.interp(gaps, known, q_out[known]))
    finite = q_out[np.isfinite(q_out)]
    q_range = np.array([finite.min(), finite.max()]) if finite.size else np.asarray(joint.q_range)
    return replace(joint, q=q_out, q_range=q_range, residual=res_out, confidence=conf_out)
