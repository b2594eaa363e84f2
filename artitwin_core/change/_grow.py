"""Growing a part beyond the canonical surface that vanished.

That surface misses the part's rim (depth edges) and everything the closed part hid (a drawer's
sides and inside): changed observed points that move with the part join it (``_grow_part``), and a
drawer's front is filled up to the outline the frames show (``_front_fill``, ``_front_seen_open``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import open3d as o3d
from scipy.spatial import ConvexHull, QhullError, cKDTree

from artitwin_core.change._canonical import CanonicalMesh
from artitwin_core.change._config import PartConfig
from artitwin_core.change._detect import depth_tolerance
from artitwin_core.change._score import _frame_cloud, _observed_cloud
from artitwin_core.change._views import FrameView, PartModel, _depth_pixels


def _grow_part(
    model: PartModel, view: FrameView, cfg: PartConfig, mesh: CanonicalMesh | None, interior_only: bool = False
) -> PartModel:
    """Add the observed changed surface that moves with the part at the reference frame.

    The vanished canonical surface misses the part's rim (depth edges) and everything the
    closed part hid (a drawer's sides and inside). Changed observed points next to the moved part
    join it if, moved back to the closed state, they lie behind the front face (inside the
    furniture): a hand on the handle lies in front of it and stays out. With ``interior_only``
    (a drawer at other frames, whose state is less certain) only what lies at least a centimetre
    behind the front joins, and the front is not filled again: a state a centimetre off must not
    pull the hand on the handle in.
    """
    pts, changed, _ = _frame_cloud(view, cfg)
    cand = pts[changed]
    if len(cand) == 0:
        return model
    m = model.motion(model.reference_q)
    inv_rot, inv_t = m[:3, :3].T, -m[:3, :3].T @ m[:3, 3]
    back = cand @ inv_rot.T + inv_t
    n = model.front_normal
    front_level = np.quantile(model.closed_points @ n, 0.9)
    behind = back @ n < front_level + 0.01
    # Only a part-sized neighbourhood: the growth must not run along the whole room.
    centre = model.closed_points.mean(0)
    near = np.linalg.norm(back - centre, axis=1) < cfg.max_part_radius_m
    ok = behind & near
    if model.joint_type == "revolute":
        # A door is a slab: what turns with it lies within a few centimetres behind its front.
        # Deeper points are another part that moved beside it (a sagging door took samples of
        # the drawer opened below it, and covered the drawer with its label).
        ok &= back @ n > front_level - cfg.door_slab_m
    if mesh is not None and ok.any():
        ok[ok] = mesh.signed_distance(back[ok]) < cfg.grow_free_space_m
    members = model.closed_points
    front = members[np.abs(members @ n - front_level) < 0.03]
    if interior_only:
        ok &= back @ n < front_level - 0.01
    elif mesh is not None:
        # A drawer's front is short of its real outline by the rim its box's sides hid as it
        # slid out (never seen to vanish): its fill reaches past the outline. A door's rim
        # vanishes with it.
        reach = cfg.front_fill_reach_m if model.joint_type == "prismatic" else 0.0
        outline, rect = model.closed_points, None
        if model.joint_type == "prismatic" and abs(model.reference_q) >= cfg.front_seen_min_q_m:
            seen = _front_seen_open(model, view, front_level, mesh, cfg)
            if len(seen):
                members = np.concatenate([members, seen])
                outline = np.concatenate([seen, front[np.abs(front @ n - np.median(seen @ n)) < cfg.front_plane_tol_m]])
                front = np.concatenate([front, seen])
                reach, rect = 0.0, _open_reach(model, view, outline, cfg)
        members = np.concatenate([members, _front_fill(outline, n, mesh, cfg.sample_m, reach, extend_m=rect)])
    added = np.zeros(len(back), bool)
    if model.joint_type == "prismatic" and cfg.drawer_footprint_m is not None:
        # What slides with a drawer lies within its front's outline, seen along the slide: growth
        # past it ran into the door above a tilting drawer, at other frames' states.
        ok &= _behind_outline(back, front, n, -cfg.drawer_footprint_m)
    if model.joint_type == "prismatic":
        # A drawer's box and what stands in it are seen over the front's top edge, cut off from
        # the front by the front itself: no surface path joins them. But they slid out with the
        # front, so moved back they lie behind it, inside its outline (and inside the furniture).
        added = ok & _behind_outline(back, front, n, cfg.outline_margin_m)
    for _ in range(15):  # region growing, a few centimetres per round
        tree = cKDTree(np.concatenate([members, back[added]]))
        d, _ = tree.query(back, distance_upper_bound=cfg.grow_distance_m)
        new = ok & ~added & np.isfinite(d)
        if not new.any():
            break
        added |= new
    if not added.any() and len(members) == len(model.closed_points):
        return model
    grown = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate([members, back[added]])))
    grown = np.asarray(grown.voxel_down_sample(cfg.sample_m).points)
    return replace(model, closed_points=grown)


def _front_seen_open(
    model: PartModel, view: FrameView, front_level: float, mesh: CanonicalMesh, cfg: PartConfig
) -> np.ndarray:
    """``[M, 3]`` closed-state samples of a drawer's front as the reference frame sees it, slid out.

    The vanished canonical surface misses the front's rim: where the front overlaps the carcass
    (its sides, the bottom board) the surface behind it is only a couple of centimetres farther,
    too little to count as vanished, and the open drawer itself hides the front's lower part of
    the closed position from a camera above. Slid out, the whole front stands clear of
    everything else, so its outline is seen: observed surface that, moved back to the closed
    state, lies on the front's plane (within ``front_plane_tol_m``), faces along the front
    normal, lies on the canonical surface, and joins the front samples through such surface.
    The carcass around the opening, the floor and a neighbouring door are not on that plane
    once moved back by the drawer's travel."""
    pc = _observed_cloud(view)
    pts, nrm = np.asarray(pc.points), np.asarray(pc.normals)
    if len(pts) == 0:
        return np.zeros((0, 3))
    m = model.motion(model.reference_q)
    back = (pts - m[:3, 3]) @ m[:3, :3]
    n = model.front_normal
    facing = np.abs((nrm @ m[:3, :3]) @ n) > 0.8
    # ``front_level`` (a high quantile of the samples, the handle among them) lies up to a
    # centimetre in front of the face; the face is the median of what faces along the normal near it.
    near_level = facing & (np.abs(back @ n - front_level) < 0.03)
    if not near_level.any():
        return np.zeros((0, 3))
    front_level = float(np.median(back[near_level] @ n))
    on = facing & (np.abs(back @ n - front_level) < cfg.front_plane_tol_m)
    on &= np.linalg.norm(back - model.closed_points.mean(0), axis=1) < cfg.max_part_radius_m
    if on.any():
        on[on] = np.abs(mesh.signed_distance(back[on])) < cfg.front_plane_tol_m + 0.01
    cand = back[on]
    seeds = model.closed_points[np.abs(model.closed_points @ n - front_level) < cfg.front_plane_tol_m]
    if len(cand) == 0 or len(seeds) == 0:
        return np.zeros((0, 3))
    added = np.zeros(len(cand), bool)
    tree = cKDTree(cand)
    frontier = seeds
    for _ in range(60):  # region growing over the plane, ``2 * sample_m`` per round
        hits = tree.query_ball_point(frontier, 2.0 * cfg.sample_m)
        idx = np.unique(np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])) if len(hits) else np.zeros(0, int)
        idx = idx[~added[idx]]
        if len(idx) == 0:
            break
        added[idx] = True
        frontier = cand[idx]
    return cand[added]


_FACING = 0.7  # |cos| between a triangle's normal and the front's normal for it to be on the front


_RECT_EXTEND_M = 0.05  # how far a drawer front's rectangle may widen past its samples (metres)


def _front_fill(
    front: np.ndarray, normal: np.ndarray, mesh: CanonicalMesh, spacing: float, reach_m: float = 0.0,
    extend_m: np.ndarray | None = None,
) -> np.ndarray:
    """``[M, 3]`` samples of the canonical surface on the closed front's plane and inside its
    outline, about ``spacing`` apart: the parts of the front never seen to vanish (behind the
    hand that pulled it, out of view when it moved), which the part would otherwise lack when
    closed. (Filling the outline's plane instead also fills where the front is not flat or the
    outline overshoots, which lowered a drawer's IoU.) With
    ``extend_m`` (``[2, 2]`` metres, see :func:`_front_rectangle`) the outline is the upright
    rectangle of :func:`_front_rectangle`."""
    level = float(np.median(front @ normal))
    tris = mesh.triangles
    corners = mesh.vertices[tris]  # [F, 3, 3]
    centroids = corners.mean(1)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    # On the plane and facing along its normal: a surface crossing the plane (the floor a bottom
    # drawer's front stands on) has a strip within the band too.
    facing = np.abs(cross @ normal) > _FACING * np.linalg.norm(cross, axis=1)
    on_plane = (np.abs(centroids @ normal - level) < 0.015) & facing
    e1, e2 = _plane_axes(normal)
    if extend_m is not None:
        f2 = np.stack([front @ e1, front @ e2], 1)
        c2 = np.stack([centroids[on_plane] @ e1, centroids[on_plane] @ e2], 1)
        wide = extend_m + 0.03  # whole triangles reaching as far as each edge may move
        on_plane[on_plane] = np.all((c2 >= np.percentile(f2, 1, axis=0) - wide[:, 0])
                                    & (c2 <= np.percentile(f2, 99, axis=0) + wide[:, 1]), axis=1)
    else:
        on_plane[on_plane] = _behind_outline(centroids[on_plane], front, normal, -reach_m)
    if not on_plane.any():
        return np.zeros((0, 3))
    corners = corners[on_plane]
    area = 0.5 * np.linalg.norm(cross[on_plane], axis=1)
    count = np.maximum(np.ceil(2.0 * area / spacing**2), 1).astype(np.int64)
    rng = np.random.default_rng(0)  # deterministic masks for the same inputs
    face = np.repeat(np.arange(len(corners)), count)
    a, b = rng.random(len(face)), rng.random(len(face))
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    c = corners[face]
    pts = c[:, 0] + a[:, None] * (c[:, 1] - c[:, 0]) + b[:, None] * (c[:, 2] - c[:, 0])
    pts = pts[np.abs(pts @ normal - level) < 0.015]
    if extend_m is None:
        return pts[_behind_outline(pts, front, normal, -reach_m)]
    lo, hi = _front_rectangle(front, normal, pts, spacing, extend_m)
    p2 = np.stack([pts @ e1, pts @ e2], 1)
    return pts[np.all((p2 >= lo - reach_m) & (p2 <= hi + reach_m), axis=1)]


def _front_rectangle(
    front: np.ndarray, normal: np.ndarray, plane_points: np.ndarray, spacing: float, extend_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The upright rectangle ``(lo, hi)`` (``[2]`` each, along ``_plane_axes(normal)``) a drawer
    front covers: the 1st to 99th percentiles of its samples ``front [M, 3]``, each edge moved
    out (up to ``extend_m [2, 2]`` metres: per axis, lo and hi side) as far as the canonical
    surface ``plane_points [P, 3]`` continues on the front's plane across the front's full
    extent along that edge. A drawer front is a rectangle; a strip at its side that was hidden
    at the reference frame and overlaps the carcass (so it never vanished) is found so, since
    the carcass beside it is a couple of centimetres back; so is the bottom of a bottom
    drawer's front that dipped to the floor as it slid out (the floor is not on the plane).
    Each edge moves from the percentile rectangle."""
    e1, e2 = _plane_axes(normal)
    f2 = np.stack([front @ e1, front @ e2], 1)
    lo, hi = np.percentile(f2, 1, axis=0), np.percentile(f2, 99, axis=0)
    out_lo, out_hi = lo.copy(), hi.copy()
    if len(plane_points) == 0:
        return out_lo, out_hi
    p2 = np.stack([plane_points @ e1, plane_points @ e2], 1)
    for axis in (0, 1):
        other = 1 - axis
        if hi[other] - lo[other] < 4 * spacing:
            continue
        band = p2[(p2[:, other] >= lo[other]) & (p2[:, other] <= hi[other])]
        bins = np.append(np.arange(lo[other], hi[other], 2 * spacing), hi[other])

        def full_extent(a0: float, a1: float, band=band, axis=axis, other=other, bins=bins) -> bool:
            line = band[(band[:, axis] >= a0) & (band[:, axis] < a1), other]
            return len(line) > 0 and np.mean(np.histogram(line, bins=bins)[0] > 0) >= 0.8

        for side, sign in ((0, -1.0), (1, 1.0)):
            edge = lo[axis] if side == 0 else hi[axis]
            for _ in range(int(round(extend_m[axis, side] / spacing))):
                a0, a1 = sorted((edge, edge + sign * spacing))
                if not full_extent(a0, a1):
                    break
                edge += sign * spacing
            if side == 0:
                out_lo[axis] = edge
            else:
                out_hi[axis] = edge
    return out_lo, out_hi


def _open_reach(model: PartModel, view: FrameView, front: np.ndarray, cfg: PartConfig) -> np.ndarray:
    """``[2, 2]`` metres: how far past each edge of a drawer front's rectangle (per axis of
    ``_plane_axes(front_normal)``, lo and hi side; the percentiles of ``front [M, 3]``, closed
    state) the front may go on as ``view`` sees it at the part's reference state, in steps of
    ``sample_m`` up to ``_RECT_EXTEND_M``: up to the first strip along the edge where the plane
    is seen through (on most of its rays with a measured depth, the depth lies at least
    ``front_clear_m`` behind the plane). Past a free edge of a slid-out drawer the camera sees
    into the drawer, the carcass or the room: 0 there, unless the samples stop short of the
    edge (then the front itself is seen on the plane first). Where something in front hides
    the plane (the floor a bottom drawer dips to as it slides, a door, the hand) or nothing is
    measured, the front may go on, and the canonical surface decides (:func:`_front_rectangle`).
    Points past the edge in the plane's own coordinates would not do: the drawer's sides lie
    behind its front within its outline, past an edge of samples short of the real one."""
    n = model.front_normal
    e1, e2 = _plane_axes(n)
    f2 = np.stack([front @ e1, front @ e2], 1)
    lo, hi = np.percentile(f2, 1, axis=0), np.percentile(f2, 99, axis=0)
    level = float(np.median(front @ n))
    m = model.motion(model.reference_q)
    corner = 2.0 * cfg.sample_m  # rays near a corner pass beside the other edge too
    steps = int(round(_RECT_EXTEND_M / cfg.sample_m))
    look = steps + 3  # strips looked at: a few past the farthest reach
    reach = np.full((2, 2), steps * cfg.sample_m)
    for axis in (0, 1):
        other = 1 - axis
        along = np.arange(lo[other] + corner, hi[other] - corner, cfg.sample_m)
        if len(along) == 0:
            continue
        for side, sign in ((0, -1.0), (1, 1.0)):
            edge = lo[axis] if side == 0 else hi[axis]
            across = edge + sign * (np.arange(look) + 0.5) * cfg.sample_m
            a, b = np.meshgrid(across, along, indexing="ij")  # [look, len(along)]
            coords = (a, b) if axis == 0 else (b, a)
            closed = level * n + coords[0][..., None] * e1 + coords[1][..., None] * e2
            cam = (closed @ m[:3, :3].T + m[:3, 3] - view.world_from_camera[:3, 3]) @ view.world_from_camera[:3, :3]
            u, v, z, ok = _depth_pixels(view, cam)
            obs = np.full(z.shape, np.nan)
            obs[ok] = view.observed_depth[v[ok], u[ok]]
            measured = np.isfinite(obs)
            through = measured & (obs > z + depth_tolerance(z, cfg.change) + cfg.front_clear_m)
            in_view, n_measured = ok.sum(1), measured.sum(1)
            # Per strip: 1 seen through, 0 the plane or something in front of it is seen, -1 in
            # view but mostly without depth, None out of view.
            seen = [None if in_view[k] < 3 else -1 if n_measured[k] < 0.5 * in_view[k]
                    else int(through[k].sum() >= 0.5 * n_measured[k]) for k in range(look)]
            for k in range(steps):
                if seen[k] == 1:
                    reach[axis, side] = k * cfg.sample_m
                    break
                # The sensor gives no depth on either side of a depth edge: a run of strips
                # without depth followed by one seen through holds the front's edge (not when
                # something in front follows: that is its outline, the front may go on behind).
                run = next((j for j in range(k, look) if seen[j] != -1), look)
                if seen[k] == -1 and run < look and seen[run] == 1:
                    reach[axis, side] = k * cfg.sample_m
                    break
    return reach


def _plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = np.cross(normal, [0.0, 1.0, 0.0] if abs(normal[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)


def _grow_over_frames(
    model: PartModel, views: list[FrameView], states: np.ndarray, scores: np.ndarray,
    mesh: CanonicalMesh | None, cfg: PartConfig,
) -> PartModel:
    """A drawer's inside grown (:func:`_grow_part`) at up to ``grow_frames`` more frames, each
    at its tracked state ``states [T]``: one frame shows only some of the drawer's inside and
    the frames the camera passes by show the rest. (Growing a door so, from its less certain
    states, lowered its IoU.) Frames where the part is less
    than a third as open as at the reference frame, or tracked with a score below ``min_state_score``, are
    skipped (there the moved surface is close to the static one, or the state is uncertain)."""
    q_ref = abs(model.reference_q)
    ok = np.nonzero((np.abs(states) > q_ref / 3) & (scores >= cfg.min_state_score))[0]
    ok = ok[ok != model.reference_frame]
    if len(ok) == 0 or model.joint_type != "prismatic":
        return model
    frames = ok[np.unique(np.linspace(0, len(ok) - 1, min(cfg.grow_frames, len(ok))).round().astype(int))]
    grown = model
    for t in frames:
        at_t = replace(grown, reference_frame=int(t), reference_q=float(states[t]))
        grown = replace(_grow_part(at_t, views[t], cfg, mesh, interior_only=True), reference_frame=model.reference_frame,
                        reference_q=model.reference_q)
    return grown


def _behind_outline(points: np.ndarray, front: np.ndarray, normal: np.ndarray, margin_m: float) -> np.ndarray:
    """``[N]`` bool: ``points [N, 3]`` lie within the outline of the closed front ``front [M, 3]``
    seen along ``normal``, at least ``margin_m`` inside it. The outline is the convex hull of the
    front's samples between their 1st and 99th percentiles across (stray samples widen it)."""
    e1, e2 = _plane_axes(normal)
    f2 = np.stack([front @ e1, front @ e2], 1)
    lo, hi = np.percentile(f2, 1, axis=0), np.percentile(f2, 99, axis=0)
    f2 = f2[np.all((f2 >= lo) & (f2 <= hi), axis=1)]
    if len(f2) < 3 or np.any(hi - lo < 2 * margin_m):
        return np.zeros(len(points), bool)
    try:
        hull = ConvexHull(f2)
    except QhullError:
        return np.zeros(len(points), bool)
    p2 = np.stack([points @ e1, points @ e2], 1)
    # Hull facets: a . x + b <= 0 inside; unit a, so -(a . x + b) is the distance inside.
    inside = p2 @ hull.equations[:, :2].T + hull.equations[:, 2]
    return np.all(inside <= -margin_m, axis=1)
