"""How well a part moved to a joint state explains one frame's observed depth
(``motion_score``), and the joint state near a given one that explains a frame best.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from artitwin_core.change._config import PartConfig
from artitwin_core.change._detect import depth_tolerance
from artitwin_core.change._views import FrameView, PartModel, _depth_pixels, _to_world


def _frame_cloud(view: FrameView, config: PartConfig):
    """Observed points of a frame (canonical frame), whether each is a change, and a KD-tree."""
    if view.cache.get("cloud") is None:
        valid = np.isfinite(view.observed_depth)
        pts = _to_world(view, view.observed_depth, valid)
        diff = (view.rendered_depth - view.observed_depth)[valid]
        tol = depth_tolerance(view.observed_depth[valid], config.change)
        # Unknown canonical depth (never seen in the static recording) is not evidence of change.
        changed = np.isfinite(diff) & (np.abs(diff) > tol)
        view.cache["cloud"] = (pts, changed, cKDTree(pts) if len(pts) else None)
    return view.cache["cloud"]


def motion_score(
    view: FrameView, moved: np.ndarray, closed: np.ndarray, config: PartConfig, *, still_supports: bool = True
) -> tuple[float, int, int]:
    """How well part samples moved to ``moved [N, 3]`` (from ``closed [N, 3]``, canonical frame)
    explain one frame's observation.

    A visible sample supports the motion when an observed point lies within
    ``support_distance_m`` of it in 3D (3D, not along the ray: a thin part seen at a grazing angle
    shows its back face far along the ray) and that observed point is a change, unless the
    sample has not moved (a closed part matches the canonical surface). It contradicts the
    motion when the observation lies behind it (we see through where the part would be).

    ``still_supports=False``: a sample that has not moved (less than 3 cm) supports nothing. The
    static scene then lends no support, and what is left measures how much of the observed change
    the motion explains: the test for a surface that may only have been hidden (by the hand, the
    arm), where a small motion about an axis through it keeps most samples on the static scene.

    Returns:
        score (supporting minus weighted see-through samples), supporting count, see-through count.
    """
    cam = (moved - view.world_from_camera[:3, 3]) @ view.world_from_camera[:3, :3]
    u, v, z, ok = _depth_pixels(view, cam)
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        return 0.0, 0, 0
    pix = v[idx] * view.observed_depth.shape[1] + u[idx]
    # One vote per pixel: the nearest sample (the part hides its own back).
    order = np.lexsort((z[idx], pix))
    first = np.ones(len(order), bool)
    first[1:] = pix[order][1:] != pix[order][:-1]
    idx = idx[order][first]
    obs = view.observed_depth[v[idx], u[idx]]
    tol = depth_tolerance(z[idx], config.change)
    through = int(np.sum(obs > z[idx] + tol))
    pts, changed, tree = _frame_cloud(view, config)
    if tree is None:
        return -config.violation_weight * through, 0, through
    # A sample supports only with an observed point nearer than its reach (never beyond 0.2 m), so
    # the search stops there: samples far from every observation (a wrong state) cost no more than
    # near ones. The result is the same as with the 0.2 m bound.
    reach = config.support_distance_m + 0.005 * z[idx] ** 2
    dist, nn = tree.query(moved[idx], distance_upper_bound=min(0.2, float(reach.max())))
    near = dist < reach
    still = np.linalg.norm(moved[idx] - closed[idx], axis=1) < 0.03
    moved_onto_change = changed[np.minimum(nn, len(changed) - 1)]
    support = int(np.sum(near & ((still | moved_onto_change) if still_supports else (~still & moved_onto_change))))
    return support - config.violation_weight * through, support, through


def _scoring_subset(points: np.ndarray, n: int = 1500) -> np.ndarray:
    """At most ``n`` of ``points``, evenly strided (deterministic), to keep scoring cheap."""
    step = max(1, int(np.ceil(len(points) / n)))
    return points[::step]


def _observed_cloud(view: FrameView) -> o3d.geometry.PointCloud:
    pts = _to_world(view, view.observed_depth, np.isfinite(view.observed_depth))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).voxel_down_sample(0.01)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.04, max_nn=30))
    return pc


def in_place(model: PartModel, view: FrameView, cfg: PartConfig) -> np.ndarray:
    """``[N]`` bool over ``_scoring_subset(model.closed_points)``: samples that ``view`` observes
    where they sit closed (visible, an observed point within reach). In the reference frame,
    where the part has moved, these are static surface the candidate took in, not the part."""
    sub = _scoring_subset(model.closed_points)
    cam = (sub - view.world_from_camera[:3, 3]) @ view.world_from_camera[:3, :3]
    u, v, z, ok = _depth_pixels(view, cam)
    out = np.zeros(len(sub), bool)
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        return out
    obs = view.observed_depth[v[idx], u[idx]]
    tol = depth_tolerance(z[idx], cfg.change)
    out[idx] = np.abs(obs - z[idx]) <= tol
    return out


def _best_state(
    model: PartModel, view: FrameView, centre_q: float, cfg: PartConfig, after_reference: bool = False,
    static: np.ndarray | None = None,
) -> tuple[float, float]:
    """Joint state near ``centre_q`` (and closed) that best explains ``view``; and its score in [0, 1].

    ``after_reference``: ``view`` comes after the model's reference frame, which was not the
    last, so the part may open further than there. ``static``: ``[N]`` over the scored samples
    (:func:`in_place`), those left out of the score where they are under half of them: static
    surface the candidate took in is seen through once moved out with the part, and with the
    see-through penalty it sinks the true state below the closed one near a close-up camera
    (docs/generalization.md)."""
    span = cfg.search_window * abs(model.reference_q)
    # A drawer's reference frame need not be where it is most open (a tilting drawer is fitted
    # short of its full travel); a door's usually is, and searching past it invites
    # grazing-angle states. After a reference frame that is not the last (the door seen best on
    # its way past the camera's line of sight) the state goes on to the hypotheses' limit.
    reach = cfg.max_rotation_rad if model.joint_type == "revolute" else cfg.max_translation_m
    far = model.reference_q * (cfg.door_search_overshoot if model.joint_type == "revolute" else cfg.drawer_search_overshoot)
    if after_reference:
        far = float(np.sign(model.reference_q)) * max(abs(far), reach)
    lo, hi = sorted((0.0, far))
    grid = np.unique(np.clip(np.concatenate([np.linspace(centre_q - span, centre_q + span, cfg.state_grid_points), [0.0]]), lo, hi))

    sub = _scoring_subset(model.closed_points)
    if static is not None and static.any() and static.mean() < 0.5:
        sub = sub[~static]

    def evaluate(q):
        m = model.motion(q)
        return motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, cfg)

    scores = [evaluate(q) for q in grid]
    i = int(np.argmax([s[0] for s in scores]))
    q = float(grid[i])
    step = (grid[1] - grid[0]) if len(grid) > 1 else 0.0
    for q2 in np.linspace(q - step, q + step, cfg.state_fine_points):
        if lo <= q2 <= hi:
            s2 = evaluate(q2)
            if s2[0] > scores[i][0]:
                q, scores[i] = float(q2), s2
    _, sup, thr = scores[i]
    if sup + thr == 0:
        return centre_q, 0.0  # out of view: keep the state
    return q, sup / (sup + thr)
