"""A moved part's rigid motion and the 1-DOF joint it implies (``fit_part_motion``).

At a few candidate frames (the most open ones, and those where it is a quarter to three quarters
open: a door swung past the camera's line of sight is seen best on its way there) its motion is
found by scoring door and drawer hypotheses (hinges on either outline edge, slides along the front
normal) against the observed depth, then refined by robust ICP; the best-explained fit gives the
1-DOF joint, and the most open frame whose fit agrees is the reference.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from artitwin_core._errors import InputError
from artitwin_core.change._canonical import CanonicalMesh
from artitwin_core.change._config import PartConfig
from artitwin_core.change._detect import depth_tolerance
from artitwin_core.change._grow import _front_seen_open, _grow_part, _open_reach, _plane_axes
from artitwin_core.change._score import _best_state, _observed_cloud, _scoring_subset, motion_score
from artitwin_core.change._views import FrameView, PartModel, _depth_pixels, _to_world
from artitwin_core.geometry import axis_angle_to_matrix, make_se3


def _front_normal(
    points: np.ndarray, towards: np.ndarray, mesh: CanonicalMesh | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normal of a closed part's front (towards ``towards``) and its centroid.

    From the median of the canonical mesh's normals where given (a thin strip of vanished
    surface, as a drawer seen head-on leaves, has no reliable PCA normal), else the PCA of the
    samples."""
    centroid = points.mean(0)
    n = None
    if mesh is not None:
        res = mesh._scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
        normals = res["primitive_normals"].numpy().astype(np.float64)
        normals *= np.sign(normals @ (towards - centroid))[:, None] + (normals @ (towards - centroid) == 0)[:, None]
        # The median, not the mean: samples on the rim and the handle see side faces, and their
        # normals tilt the mean of a drawer's front by degrees where the median barely moves.
        mean = np.median(normals, axis=0)
        if np.linalg.norm(mean) > 0.5:
            n = mean / np.linalg.norm(mean)
    if n is None:
        _, vecs = np.linalg.eigh(np.cov((points - centroid).T))
        n = vecs[:, 0]
    if n @ (towards - centroid) < 0:
        n = -n
    return n, centroid


def _hypotheses(points: np.ndarray, n: np.ndarray, up: np.ndarray, cfg: PartConfig):
    """Door, flap and drawer motions ``(type, axis, pivot, q)`` of a closed front surface.

    Parts open outwards: a drawer slides along the front normal, a door or flap swings its free
    edge out of the furniture (the other way it would pass through the carcass).
    """
    c = points.mean(0)
    out = []
    for q in np.arange(cfg.slide_grid_start_m, cfg.max_translation_m + 1e-9, cfg.slide_grid_step_m):
        out.append(("prismatic", n, c, float(q)))
    side = np.cross(up, n)
    if np.linalg.norm(side) > 0.3:
        side /= np.linalg.norm(side)
        hinge_dirs = [(up, side), (side, up)]  # vertical hinge at a side edge; horizontal at top/bottom
    else:
        hinge_dirs = []
    step = cfg.swing_grid_step_deg
    angles = np.deg2rad(np.arange(step, np.rad2deg(cfg.max_rotation_rad) + 1e-9, step))
    for axis, across in hinge_dirs:
        s = (points - c) @ across
        for edge in (s.min(), s.max()):
            pivot = c + across * edge
            # Small rotation: the centroid moves along axis x (c - pivot); keep the outward sign.
            sign = 1.0 if np.cross(axis, c - pivot) @ n > 0 else -1.0
            for a in angles:
                out.append(("revolute", axis, pivot, float(sign * a)))
    return out


def _joint_from_motion(m: np.ndarray, centre: np.ndarray):
    """A 1-DOF joint ``(type, axis, pivot, q)`` reproducing the rigid motion ``m`` [4, 4]."""
    rot, t = m[:3, :3], m[:3, 3]
    angle = float(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1)))
    if angle < np.deg2rad(3.0):
        dist = float(np.linalg.norm(t))
        return "prismatic", t / max(dist, 1e-9), centre.copy(), dist
    axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    axis /= np.linalg.norm(axis)
    # Pivot: least-squares solution of (I - R) p = t, moved to the point nearest the part.
    p = np.linalg.lstsq(np.eye(3) - rot, t, rcond=None)[0]
    p = p + axis * (axis @ (centre - p))
    return "revolute", axis, p, angle


def _hole_counts(
    closed_points: np.ndarray, views: list[FrameView], cfg: PartConfig, hidden: bool = False
) -> np.ndarray:
    """``[T]`` how many pixels per frame see through the part's closed surface (how open and how
    visible the part is there); with ``hidden``, how many see something nearer in front of it (a
    part that moved only towards the camera hides its closed surface instead)."""
    tree = cKDTree(closed_points)
    counts = np.zeros(len(views), int)
    for t, v in enumerate(views):
        diff = v.rendered_depth - v.observed_depth
        tol = depth_tolerance(v.rendered_depth, cfg.change)
        changed = np.isfinite(diff) & ((diff > tol) if hidden else (diff < -tol))
        if changed.any():
            d, _ = tree.query(_to_world(v, v.rendered_depth, changed), distance_upper_bound=0.03)
            counts[t] = int(np.isfinite(d).sum())
    return counts


def fit_part_motion(
    closed_points: np.ndarray,
    onset_frame: int,
    views: list[FrameView],
    *,
    gravity=(0.0, -1.0, 0.0),
    reference_frame: int | None = None,
    mesh: CanonicalMesh | None = None,
    config: PartConfig | None = None,
) -> PartModel:
    """Fit the part's motion at a reference frame and the 1-DOF joint it implies.

    Args:
        closed_points: ``[N, 3]`` closed surface samples (canonical frame, metres).
        onset_frame: first frame the part had moved.
        views: every dynamic frame (:func:`frame_views`).
        gravity: ``[3]`` gravity direction in the canonical frame.
        reference_frame: frame to fit at. Default: the joint is fitted at the last frame, the
            two frames where most of the part's former surface is seen through, and the first
            frames where a quarter, a half and three quarters of it are; the best-explained fit
            gives the joint, and the most open frame whose fit agrees is the reference (at the
            last frame a door may be edge-on or out of view).
        mesh: the canonical mesh; keeps the part's growth out of the static free space.
    """
    cfg = config or PartConfig()
    up, frames = _fit_setup(closed_points, views, gravity, reference_frame, cfg)
    best = _fit_ungrown(closed_points, onset_frame, views, up, frames, cfg, mesh)
    return _fit_slide_and_grow(best, views, cfg, mesh)


def _fit_setup(
    closed_points: np.ndarray, views: list[FrameView], gravity, reference_frame: int | None, cfg: PartConfig,
    hidden: bool = False,
) -> tuple[np.ndarray, list[int]]:
    """Unit up ``[3]`` and the candidate reference frames of :func:`fit_part_motion`; ``hidden``:
    the samples are surface hidden by something nearer (``find_moved_parts(..., hidden=True)``),
    whose frames are ranked by how much of it is hidden, since nothing of it is seen through."""
    up = -np.asarray(gravity, dtype=np.float64)
    up /= np.linalg.norm(up)
    if reference_frame is not None:
        return up, [int(reference_frame)]
    counts = _hole_counts(closed_points, views, cfg, hidden)
    frames = [len(views) - 1] + [int(t) for t in np.argsort(-counts)[:2] if counts[t] > 0]
    # Where the part is most open it may be seen worst: a door swung past the camera's line of
    # sight shows only its edge in the last frames, where no hinge explains anything and a
    # flap far past the truth can "win" with a handful of supporting samples. On
    # its way there it is seen well: the first frames where the vanished surface reaches a
    # quarter, a half and three quarters of its largest extent are candidates too.
    if counts.max() > 0:
        frames += [int(np.argmax(counts >= f * counts.max())) for f in cfg.reference_extent_fractions]
    return up, frames


def _fit_ungrown(
    closed_points: np.ndarray, onset_frame: int, views: list[FrameView], up: np.ndarray, frames: list[int],
    cfg: PartConfig, mesh: CanonicalMesh | None, still_supports: bool = True,
) -> PartModel:
    """The part's motion fitted at the best of ``frames``, before its growth.

    The best-supported frame's fit says which joint moved the part; the reference is then the
    most open frame whose own fit found the same joint (``_same_joint``), since the masks are
    propagated from the reference and never search far past its state.

    ``still_supports=False`` (surface that was hidden, not seen vanished): the frames' fits are
    compared by the support of their moved samples only (``motion_score``). Hidden surface
    takes in the static surface around the part that the hand and arm hid; a small swing about
    a hinge through that surface keeps it on the static scene, where it is supported, and beats
    the true slide at a frame where the part is barely open."""
    fits = [_fit_at(closed_points, onset_frame, views[r], r, up, cfg, mesh) for r in dict.fromkeys(frames)]
    if not still_supports:
        fits = [(m, _reference_support(m, views[m.reference_frame], cfg, still_supports=False, score=True)) for m, _ in fits]
    best, _ = max(fits, key=lambda f: f[1])
    same = [m for m, score in fits if score > 0 and _same_joint(m, best)]
    best = max(same, key=lambda m: abs(m.reference_q), default=best)
    return _drop_see_through(best, views[best.reference_frame], cfg)


def _same_joint(a: PartModel, b: PartModel, max_angle_rad: float = np.radians(10.0), max_offset_m: float = 0.05) -> bool:
    """Whether two fits found the same joint: one type, axes within ``max_angle_rad`` and, for
    hinges, lines within ``max_offset_m`` of each other at the part."""
    if a.joint_type != b.joint_type or abs(float(a.axis @ b.axis)) < np.cos(max_angle_rad):
        return False
    if a.joint_type == "prismatic":
        return True
    c = a.closed_points.mean(0)
    d = []
    for m in (a, b):
        off = c - m.pivot
        d.append(off - (off @ m.axis) * m.axis)
    return float(np.linalg.norm(d[0] - d[1])) <= max_offset_m


def _reference_support(
    model: PartModel, view: FrameView, cfg: PartConfig, still_supports: bool = True, score: bool = False
) -> int | float:
    """How many of the part's samples (scoring subset) the reference frame's observation
    supports at the fitted state (with ``score``: the score, see-through samples counted
    against it); ``still_supports`` as in :func:`motion_score`."""
    sub = _scoring_subset(model.closed_points)
    m = model.motion(model.reference_q)
    out = motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, cfg, still_supports=still_supports)
    return out[0] if score else out[1]


def _drop_see_through(model: PartModel, view: FrameView, cfg: PartConfig) -> PartModel:
    """The part without the closed samples that, moved to the reference state, lie in view well
    in front of what is observed there (we see through them): surface of a neighbouring part
    that the vanished-surface clustering gave to this one. The door above a drawer and its
    coplanar front leave one vanished surface; the door's bottom strip went to the drawer,
    whose label then covered the door while it swung past, and its tracks followed the door.
    Moved with the drawer, that strip
    floats 25 cm out in front of the carcass, where the camera sees the floor."""
    m = model.motion(model.reference_q)
    moved = model.closed_points @ m[:3, :3].T + m[:3, 3]
    cam = (moved - view.world_from_camera[:3, 3]) @ view.world_from_camera[:3, :3]
    u, v, z, ok = _depth_pixels(view, cam)
    obs = np.full(len(z), np.nan)
    obs[ok] = view.observed_depth[v[ok], u[ok]]
    through = np.isfinite(obs) & (obs > z + depth_tolerance(z, cfg.change) + cfg.see_through_m)
    if not through.any() or through.mean() > 0.5:
        return model  # a state that far off is not evidence against the samples
    return replace(model, closed_points=model.closed_points[~through])


def _fit_at(
    closed_points: np.ndarray, onset_frame: int, view: FrameView, r: int, up: np.ndarray, cfg: PartConfig,
    mesh: CanonicalMesh | None,
) -> tuple[PartModel, float]:
    sub = _scoring_subset(closed_points)
    # Coarse: a loose support distance, since the hinge and front found from the vanished surface
    # are a few centimetres off; the best few hypotheses then go through robust ICP.
    loose = replace(cfg, support_distance_m=2.5 * cfg.support_distance_m)
    normal, _ = _front_normal(closed_points, view.world_from_camera[:3, 3], mesh)
    hyps = []
    for jt, axis, pivot, q in _hypotheses(closed_points, normal, up, cfg):
        model = PartModel(closed_points, jt, axis, pivot, r, q, onset_frame, normal)
        m = model.motion(q)
        hyps.append((motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, loose)[0], model))
    if not hyps:
        raise InputError("fit_part_motion: no part hypotheses; the part's surface samples are empty.")
    hyps.sort(key=lambda h: -h[0])
    tgt = _observed_cloud(view)
    tgt_pts, tgt_nrm = np.asarray(tgt.points), np.asarray(tgt.normals)
    tgt_tree = cKDTree(tgt_pts)
    best, best_score = hyps[0][1], -np.inf
    for _, coarse in hyps[: cfg.num_refined]:
        model = _local_refine(coarse, view, sub, cfg)
        init = model.motion(model.reference_q)
        candidates = [model]
        for dist in cfg.icp_distances_m:
            init = _icp_point_to_plane(closed_points, tgt_pts, tgt_nrm, tgt_tree, init, dist)
        jt, axis, pivot, q = _joint_from_motion(init, closed_points.mean(0))
        if jt != "prismatic" and cfg.max_rotation_rad <= 0.0:
            # Slides only (hidden surface): ICP's turn is a slide whose front it tilted; its
            # travel is the samples' centre's along the front's normal.
            centre = closed_points.mean(0)
            jt, axis, q = "prismatic", normal, float((init[:3, :3] @ centre + init[:3, 3] - centre) @ normal)
        elif jt == "prismatic":
            # A drawer slides along its front's normal. ICP slides a flat front freely in its own
            # plane (only its rim and handle hold it there), degrees off the normal and
            # centimetres sideways.
            axis, q = normal, float(init[:3, 3] @ normal)
        candidates.append(PartModel(closed_points, jt, axis, pivot, r, q, onset_frame, normal))
        for cand in candidates:
            m = cand.motion(cand.reference_q)
            score = motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, cfg)[0]
            if score > best_score:
                best, best_score = cand, score
    return _refine_state_by_depth(best, view, sub, cfg), best_score


def _icp_point_to_plane(
    src: np.ndarray, tgt: np.ndarray, tgt_normals: np.ndarray, tree: cKDTree, init: np.ndarray, max_dist_m: float,
    tukey_k_m: float = 0.02, max_iterations: int = 40,
) -> np.ndarray:
    """``[4, 4]`` rigid transform aligning ``src [N, 3]`` to the surface ``tgt [M, 3]`` (unit
    normals ``tgt_normals [M, 3]``, KD-tree ``tree``), starting from ``init``: point-to-plane ICP
    with Tukey weights (scale ``tukey_k_m``) over nearest neighbours within ``max_dist_m``.

    Open3D's ``registration_icp`` does the same, but sums its normal equations in parallel in an
    order that varies from run to run: 29 distinct transforms in 30 runs on identical inputs, so
    ``segment_parts`` did not return the same masks twice. Here the sums run in a fixed order."""
    t = np.array(init, dtype=np.float64)
    prev = None
    for _ in range(max_iterations):
        p = src @ t[:3, :3].T + t[:3, 3]
        d, nn = tree.query(p, distance_upper_bound=max_dist_m, workers=-1)
        ok = np.isfinite(d)
        if ok.sum() < 6:
            break
        p, q, n = p[ok], tgt[nn[ok]], tgt_normals[nn[ok]]
        r = np.sum((p - q) * n, axis=1)
        w = np.where(np.abs(r) < tukey_k_m, (1.0 - (r / tukey_k_m) ** 2) ** 2, 0.0)
        fitness, rmse = ok.mean(), float(np.sqrt(np.mean(d[ok] ** 2)))
        if prev is not None and abs(prev[0] - fitness) < 1e-6 and abs(prev[1] - rmse) < 1e-6:
            break
        prev = (fitness, rmse)
        jac = np.concatenate([np.cross(p, n), n], axis=1)  # d r / d (rotation, translation)
        # einsum, not BLAS: a threaded BLAS may also split the sums by thread count.
        jtj = np.einsum("ni,nj->ij", jac * w[:, None], jac)
        jtr = np.einsum("ni,n->i", jac * w[:, None], r)
        try:
            x = -np.linalg.solve(jtj, jtr)
        except np.linalg.LinAlgError:
            break
        angle = float(np.linalg.norm(x[:3]))
        rot = axis_angle_to_matrix(x[:3] / angle, angle) if angle > 1e-12 else np.eye(3)
        t = make_se3(rot, x[3:]) @ t
    return t


def _depth_cost(view: FrameView, moved: np.ndarray, cap_m: float = 0.03) -> float:
    """Mean truncated distance along the rays between moved part samples ``[N, 3]`` and the
    observed depth (see-through and far misses cost ``cap_m``); NaN when none is in view."""
    cam = (moved - view.world_from_camera[:3, 3]) @ view.world_from_camera[:3, :3]
    u, v, z, ok = _depth_pixels(view, cam)
    if not ok.any():
        return float("nan")
    obs = view.observed_depth[v[ok], u[ok]]
    res = np.abs(obs - z[ok])
    return float(np.mean(np.where(np.isfinite(res), np.minimum(res, cap_m), cap_m)))


def _refine_state_by_depth(model: PartModel, view: FrameView, sub: np.ndarray, cfg: PartConfig) -> PartModel:
    """A prismatic part's reference state fine-tuned (+-``depth_refine_span_m``) to fit the observed depth.

    The support score counts samples within a few centimetres of an observed point, so it is
    flat over a couple of centimetres of joint state; a drawer fitted 2.5 cm short leaves its
    front, moved back to the closed state, in front of the closed front, and the growth then
    drops it. The truncated depth residual has its minimum at the true state."""
    if model.joint_type != "prismatic":
        return model  # a door is often seen edge-on, where grazing samples dominate the residual
    span = cfg.depth_refine_span_m
    best, best_cost = model, np.inf
    for dq in np.linspace(-span, span, cfg.depth_refine_points):
        cand = replace(model, reference_q=model.reference_q + dq)
        m = cand.motion(cand.reference_q)
        cost = _depth_cost(view, sub @ m[:3, :3].T + m[:3, 3])
        if cost < best_cost:
            best, best_cost = cand, cost
    return best


def _local_refine(model: PartModel, view: FrameView, sub: np.ndarray, cfg: PartConfig) -> PartModel:
    """Best nearby variant of a coarse hypothesis under the strict score: the hinge shifted a few
    centimetres across and behind the front (the vanished surface misses the rim, and hinges sit
    at the back of the door), the angle or slide a little changed."""

    def score(m: PartModel) -> float:
        t = m.motion(m.reference_q)
        return motion_score(view, sub @ t[:3, :3].T + t[:3, 3], sub, cfg)[0]

    best, best_score = model, score(model)
    if model.joint_type == "prismatic":
        span, step = cfg.local_slide_span_m, cfg.local_slide_step_m
        for dq in np.arange(-span, span + 0.5 * step, step):
            cand = replace(model, reference_q=model.reference_q + dq)
            sc = score(cand)
            if sc > best_score:
                best, best_score = cand, sc
        return best
    across = np.cross(model.axis, model.front_normal)
    across /= max(np.linalg.norm(across), 1e-9)
    span, step = cfg.local_pivot_span_m, cfg.local_pivot_step_m
    for da in np.arange(-span, span + 0.5 * step, step):
        for dn in cfg.local_pivot_behind_m:
            pivot = model.pivot + across * da + model.front_normal * dn
            for dq in np.radians(list(cfg.local_swing_deg)):
                cand = replace(model, pivot=pivot, reference_q=model.reference_q + dq)
                sc = score(cand)
                if sc > best_score:
                    best, best_score = cand, sc
    return best


def _fit_slide_and_grow(
    model: PartModel, views: list[FrameView], cfg: PartConfig, mesh: CanonicalMesh | None
) -> PartModel:
    """The part grown at its reference frame (:func:`_grow_part`); a drawer first gets the slide
    direction its front's outline shows over the frames (:func:`_slide_from_outline`)."""
    grown = _grow_part(model, views[model.reference_frame], cfg, mesh)
    if model.joint_type != "prismatic" or mesh is None:
        return grown
    slid = _slide_from_outline(model, grown, views, mesh, cfg)
    return grown if slid is model else _grow_part(slid, views[model.reference_frame], cfg, mesh)


def _slide_from_outline(
    model: PartModel, grown: PartModel, views: list[FrameView], mesh: CanonicalMesh, cfg: PartConfig
) -> PartModel:
    """The drawer ``model`` (ungrown) sliding along its front's normal plus the drift of its
    front's outline in the front's plane per metre of travel, measured over the frames where it
    is open at least ``front_seen_min_q_m`` (states tracked from the reference frame with
    ``grown``); ``model`` itself when the drift cannot be measured.

    The slide along the normal alone assumes the front keeps its place in its plane as it
    slides. A drawer that dips as it slides does not: its outline seen slid out and moved
    back along the normal lands low (the dip plus the fitted normal's tilt; docs/accuracy.md),
    and the front's top face seen from above, which the closed frames
    show once the door above is open, went with it, inside the front. The 6-DOF motion ICP
    finds at the reference frame does not tell (a flat front slides in its own plane: degrees
    and centimetres off). The outline's edges that the frames see
    clear (the plane is seen through just past them, :func:`_open_reach`) do: each moves linearly with the state, its slope is the
    drift (a shared slope per in-plane axis, an offset per edge, least squares; at least three
    edge positions over ``front_seen_min_q_m / 2`` of travel). On an ideal drawer it comes out
    near zero."""
    if abs(model.reference_q) < cfg.front_seen_min_q_m:
        return model
    r = model.reference_frame
    # States of the open frames next to the reference frame, tracked as the masks are.
    states = {r: model.reference_q}
    for step in (-1, 1):
        current, t = model.reference_q, r + step
        while 0 <= t < len(views):
            q, score = _best_state(grown, views[t], current, cfg)
            if abs(q) < cfg.front_seen_min_q_m:
                if step < 0:
                    break  # earlier frames are less open still
            elif score >= cfg.min_state_score:
                states[t] = q
            current, t = q, t + step
    n = model.front_normal
    e1, e2 = _plane_axes(n)
    front_level = np.quantile(model.closed_points @ n, 0.9)
    edges: list[tuple[int, int, float, float]] = []  # (axis, side, state, position)
    for t in sorted(states):
        at_t = replace(model, reference_frame=t, reference_q=float(states[t]))
        seen = _front_seen_open(at_t, views[t], front_level, mesh, cfg)
        if len(seen) < cfg.min_part_support:
            continue
        clear = _open_reach(at_t, views[t], seen, cfg) <= cfg.sample_m
        f2 = np.stack([seen @ e1, seen @ e2], 1)
        ends = np.percentile(f2, [1, 99], axis=0)  # [side, axis]
        edges += [(a, side, states[t], ends[side, a]) for a in (0, 1) for side in (0, 1) if clear[a, side]]
    drift = np.zeros(2)
    for a in (0, 1):
        obs = np.array([e[1:] for e in edges if e[0] == a]).reshape(-1, 3)
        if len(obs) < 3 or np.ptp(obs[:, 1]) < cfg.front_seen_min_q_m / 2:
            continue
        num = den = 0.0
        for side in (0, 1):
            q, x = obs[obs[:, 0] == side, 1], obs[obs[:, 0] == side, 2]
            if len(q) < 2:
                continue
            num += float((q - q.mean()) @ (x - x.mean()))
            den += float((q - q.mean()) @ (q - q.mean()))
        if den > 0:
            drift[a] = num / den
    if not drift.any() or np.linalg.norm(drift) > cfg.max_outline_drift:
        # Beyond a sagging drawer's few degrees the outline did not follow the front: a hand
        # over its edge, or edges seen clear in too few frames.
        return model
    axis = n + drift[0] * e1 + drift[1] * e2
    # Same travel along the normal at the reference state.
    return replace(model, axis=axis / np.linalg.norm(axis), reference_q=model.reference_q * float(np.linalg.norm(axis)))
