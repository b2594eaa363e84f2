"""Find the parts that moved, fit their rigid motion, and label them in every dynamic frame.

The closed part is the canonical surface that vanished: in the dynamic frames, where we now see
farther than the canonical surface, that surface has moved away. Votes over frames collect it
(``find_moved_parts``). At a few candidate frames (the most open ones, and those where it is a
quarter to three quarters open: a door swung past the camera's line of sight is seen best on
its way there) its motion is found by scoring door and drawer hypotheses (hinges on either
outline edge, slides along the front normal) against the observed depth, then refined by robust
ICP; the best-explained fit gives the 1-DOF joint, and the most open frame whose fit agrees is
the reference (``segment_part_at_frame``). Going backwards from the last frame, each frame's joint
state is searched near the next frame's, so the part closes smoothly in the labels
(``propagate_masks_backwards``). A pixel is part k when the moved part model is the first
surface there and the observed depth agrees; it is hand when the observation lies in front of
everything the model predicts. The hand cannot be labelled part by moving rigidly with it, since
only the rigid model decides what is part. Where the sensor gives no depth (both sides of every
depth edge, so the hand's outline), a pixel takes the depth of the measured pixels around it
that look like it, so the model does not decide alone there.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.change._canonical import CanonicalMesh
from artitwin_core.change._detect import ChangeConfig, depth_tolerance, remove_small
from artitwin_core.geometry import axis_angle_to_matrix, make_se3
from artitwin_core.masks import MaskSequence
from artitwin_core.parts import PartFate
from artitwin_core.registration import backproject


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
        sample_m: spacing of the part's surface samples (metres).
        max_rotation_rad, max_translation_m: range of the door / drawer hypotheses.
        support_distance_m: an observed point this close (3D, plus 5 mm per m^2 of depth)
            supports a part sample.
        violation_weight: how much a see-through pixel (observed behind the part) costs in the
            score relative to a supporting pixel.
        num_refined: best coarse hypotheses refined by ICP at the reference frame.
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
            stayed inside the front's outline (``drawer_footprint_m``), 6 frames lifted the
            benchmark drawers' median IoU (door+drawer 0.873 -> 0.892, non-ideal-joints 0.846 ->
            0.859, drawer 0.912 -> 0.944); before, non-ideal-joints' drawer, which tilts as it
            slides, lost 0.31 (its growth ran into the door above it).
        outline_margin_m: a drawer's growth takes, without a surface path to the front, changed
            points that moved back lie this far inside the front's outline (metres).
        see_through_m: closed samples that, at the reference state, lie this far (plus the
            depth tolerance) in front of the observation are dropped (another part's surface).
        front_fill_reach_m: a drawer's front is filled from the canonical mesh up to this far
            outside the outline of its vanished samples (metres): the rim its box's sides hid as
            it slid out never vanished. On the door+drawer benchmark's drawer, median IoU 0.775
            without it, 0.816 with 0.02 (0.799 with 0.03; the door's fill, whose rim vanishes
            with it, does not reach: 0.02 there cost the door 0.01).
        front_seen_min_q_m: a drawer fitted at least this far open (metres) takes its front's
            outline from the reference frame, where the whole front stands clear of the carcass
            (:func:`_front_seen_open`), and fills the upright rectangle it spans; the fill then
            does not reach past it. On the benchmark, drawer median IoU door+drawer 0.813 ->
            0.873, non-ideal-joints 0.792 -> 0.846, drawer 0.893 -> 0.912 (with the axis along
            the front normal, 6 growth frames off).
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
    sample_m: float = 0.01
    max_rotation_rad: float = 2.0
    max_translation_m: float = 0.7
    violation_weight: float = 2.0
    support_distance_m: float = 0.025
    search_window: float = 0.35
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
    front_plane_tol_m: float = 0.01
    front_clear_m: float = 0.05
    see_through_m: float = 0.05
    fill_radius_px: int = 2
    fill_sigma_colour: float = 20.0
    fill_model_weight: float = 0.135


@dataclass(frozen=True)
class PartModel:
    """One moving part: its closed surface samples and its 1-DOF motion.

    Attributes:
        closed_points: ``[N, 3]`` metres, samples of the part's surface when closed (canonical).
        joint_type: ``"revolute"`` or ``"prismatic"``.
        axis: ``[3]`` unit joint axis (canonical frame).
        pivot: ``[3]`` a point on the axis (revolute), metres.
        reference_frame: the frame whose motion defined the joint.
        reference_q: the joint state there (radians or metres, signed along ``axis``).
        onset_frame: first frame in which the part was seen to have moved.
        front_normal: ``[3]`` unit outward normal of the closed front face (canonical frame).
    """

    closed_points: np.ndarray
    joint_type: str
    axis: np.ndarray
    pivot: np.ndarray
    reference_frame: int
    reference_q: float
    onset_frame: int
    front_normal: np.ndarray

    def motion(self, q: float) -> np.ndarray:
        """``[4, 4]`` canonical-from-closed transform at joint state ``q``."""
        if self.joint_type == "prismatic":
            return make_se3(np.eye(3), self.axis * q)
        rot = axis_angle_to_matrix(self.axis, q)
        return make_se3(rot, self.pivot - rot @ self.pivot)


@dataclass
class FrameView:
    """One dynamic frame in the canonical frame: observed depth and the canonical rendering.

    Attributes:
        world_from_camera: ``[4, 4]`` camera pose in the canonical frame.
        depth_intrinsics: ``(fx, fy, cx, cy)`` at depth resolution.
        observed_depth, rendered_depth: ``[h, w]`` float32 metres, NaN invalid.
        timestamp_s: seconds since the recording's first frame (NaN: unknown, frames are then
            taken as 1/15 s apart).
    """

    world_from_camera: np.ndarray
    depth_intrinsics: np.ndarray
    observed_depth: np.ndarray
    rendered_depth: np.ndarray
    timestamp_s: float = float("nan")
    cache: dict = field(default_factory=dict, repr=False)


def frame_views(dynamic: Capture, canonical_from_session: np.ndarray, mesh: CanonicalMesh) -> list[FrameView]:
    """Render the canonical mesh at every dynamic pose (depth resolution)."""
    h, w = dynamic.depth.shape[1:]
    out = []
    for t in range(dynamic.num_frames):
        pose = canonical_from_session @ dynamic.world_from_camera[t]
        _, depth, _ = mesh.render(pose, dynamic.depth_intrinsics[t], w, h)
        obs = np.where(dynamic.depth[t] > 0, dynamic.depth[t], np.nan).astype(np.float32)
        out.append(FrameView(pose, dynamic.depth_intrinsics[t], obs, depth, float(dynamic.timestamps[t])))
    return out


def _to_world(view: FrameView, depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    d = np.where(mask, depth, np.nan)
    pts, _ = backproject(d, view.depth_intrinsics)
    return pts @ view.world_from_camera[:3, :3].T + view.world_from_camera[:3, 3]


def find_moved_parts(views: list[FrameView], config: PartConfig | None = None) -> list[tuple[np.ndarray, int]]:
    """Closed surfaces of the parts that moved: canonical surface seen vanished in several frames;
    where none vanished, canonical surface hidden by something nearer in several frames
    (``min_occluded_frames``).

    Returns:
        per part, best first in onset order: closed surface samples ``[N, 3]`` (canonical frame,
        metres) and the onset frame index.
    """
    cfg = config or PartConfig()
    parts = _changed_surfaces(views, cfg, nearer=False)
    if not parts and cfg.min_occluded_frames > 0:
        parts = _changed_surfaces(views, cfg, nearer=True)
    return parts


def _changed_surfaces(views: list[FrameView], cfg: PartConfig, nearer: bool) -> list[tuple[np.ndarray, int]]:
    """:func:`find_moved_parts` for canonical surface seen vanished (observed farther than
    rendered), or with ``nearer``, hidden by something nearer."""
    vox = cfg.vanish_voxel_m
    keys, frames, points = [], [], []
    kernel = np.ones((2 * cfg.vanish_opening_px + 1,) * 2, np.uint8)
    for t, v in enumerate(views):
        diff = v.rendered_depth - v.observed_depth
        tolerance = depth_tolerance(v.rendered_depth, cfg.change)
        changed = np.isfinite(diff) & ((diff > tolerance) if nearer else (diff < -tolerance))
        if cfg.vanish_opening_px > 0:
            # Opening drops thin strips along depth edges, where small pose errors look like change;
            # it also drops the thin hole a drawer seen head-on leaves, so it is off by default and
            # the votes over frames and the cluster size reject the edge noise instead.
            changed = cv2.morphologyEx(changed.astype(np.uint8), cv2.MORPH_OPEN, kernel).astype(bool)
        if not changed.any():
            continue
        p = _to_world(v, v.rendered_depth, changed)
        k = np.floor(p / vox).astype(np.int64)
        keys.append(k)
        frames.append(np.full(len(k), t))
        points.append(p)
    if not keys:
        return []
    keys_all = np.concatenate(keys)
    frames_all = np.concatenate(frames)
    points_all = np.concatenate(points)
    # Count distinct frames per voxel.
    pairs = np.unique(np.concatenate([keys_all, frames_all[:, None]], 1), axis=0)
    vkeys, inv_pairs, counts = np.unique(pairs[:, :3], axis=0, return_inverse=True, return_counts=True)
    good = counts >= (cfg.min_occluded_frames if nearer else cfg.min_vanish_frames)
    if good.sum() < cfg.min_part_voxels:
        return []
    first_frame = np.full(len(vkeys), np.iinfo(np.int64).max)
    np.minimum.at(first_frame, inv_pairs.ravel(), pairs[:, 3])
    centres = (vkeys[good] + 0.5) * vox
    good_keys = vkeys[good]
    good_first = first_frame[good]
    times = np.array([v.timestamp_s for v in views], dtype=np.float64)
    if not (np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)):
        times = np.arange(len(views)) / 15.0
    labels = _split_by_onset(centres, times[good_first], cfg)
    # Map each vanished point to its voxel's cluster label.
    lut = {tuple(k): i for i, k in enumerate(good_keys)}
    pk = np.floor(points_all / vox).astype(np.int64)
    idx = np.array([lut.get(tuple(k), -1) for k in pk])
    parts = []
    for lab in range(labels.max() + 1 if len(labels) else 0):
        members = labels == lab
        if members.sum() < cfg.min_part_voxels:
            continue
        sel = idx >= 0
        sel[sel] = labels[idx[sel]] == lab
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_all[sel])).voxel_down_sample(cfg.sample_m)
        # Onset: the frame by which a tenth of the part's voxels had vanished.
        onset = int(np.quantile(good_first[members], 0.1))
        parts.append((np.asarray(pc.points), onset))
    parts.sort(key=lambda p: (p[1], -len(p[0])))
    return parts


def _dbscan(points: np.ndarray, eps: float, min_points: int = 4) -> np.ndarray:
    """``[N]`` DBSCAN labels (-1 noise) of ``points [N, D]``, any dimension (Open3D's is 3D only)."""
    tree = cKDTree(points)
    pairs = tree.query_pairs(eps, output_type="ndarray")
    n = len(points)
    degree = np.bincount(pairs.ravel(), minlength=n) + 1  # counting the point itself
    core = degree >= min_points
    both = core[pairs[:, 0]] & core[pairs[:, 1]]
    graph = coo_matrix((np.ones(both.sum()), (pairs[both, 0], pairs[both, 1])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    labels = np.where(core, comp, -1)
    # Border points join the cluster of a core neighbour.
    for i, j in pairs[core[pairs[:, 0]] != core[pairs[:, 1]]]:
        c, b = (i, j) if core[i] else (j, i)
        if labels[b] < 0:
            labels[b] = comp[c]
    _, labels_dense = np.unique(labels, return_inverse=True)
    return np.where(labels >= 0, labels_dense - (labels < 0).any(), -1)


def _split_by_onset(centres: np.ndarray, onset_s: np.ndarray, cfg: PartConfig) -> np.ndarray:
    """``[V]`` part label per vanished voxel (-1 noise): space clusters split where onsets differ.

    Two parts side by side (a door above a drawer, a divider of a couple of centimetres between
    them) leave one connected vanished surface, but they open at different times. Clustering in
    space and onset time (``onset_m_per_s`` apart per second) separates them; the onset of a
    voxel only seen late (hidden by the hand, out of view) can lag its part's, so voxels of such
    small spatio-temporal clusters go to the nearest large cluster of their space cluster.
    """
    labels = _dbscan(centres, cfg.cluster_eps_m)
    if cfg.onset_m_per_s <= 0 or len(labels) == 0:
        return labels
    out = np.full(len(labels), -1)
    next_label = 0
    for lab in range(labels.max() + 1):
        members = np.nonzero(labels == lab)[0]
        if len(members) < cfg.min_part_voxels:
            continue
        st = np.concatenate([centres[members], cfg.onset_m_per_s * onset_s[members, None]], 1)
        sub = _dbscan(st, cfg.cluster_eps_m)
        sizes = np.bincount(sub[sub >= 0], minlength=1)
        seeds = [i for i in range(len(sizes)) if sizes[i] >= cfg.min_part_voxels]
        if len(seeds) <= 1:
            out[members] = next_label
            next_label += 1
            continue
        seed_pts = [centres[members[sub == i]] for i in seeds]
        dist = np.stack([cKDTree(p).query(centres[members])[0] for p in seed_pts], 1)
        out[members] = next_label + np.argmin(dist, 1)
        next_label += len(seeds)
    return out


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
    view: FrameView, moved: np.ndarray, closed: np.ndarray, config: PartConfig
) -> tuple[float, int, int]:
    """How well part samples moved to ``moved [N, 3]`` (from ``closed [N, 3]``, canonical frame)
    explain one frame's observation.

    A visible sample supports the motion when an observed point lies within
    ``support_distance_m`` of it in 3D (3D, not along the ray: a thin part seen at a grazing angle
    shows its back face far along the ray) and that observed point is a change, unless the
    sample has not moved (a closed part matches the canonical surface). It contradicts the
    motion when the observation lies behind it (we see through where the part would be).

    Returns:
        score (supporting minus weighted see-through samples), supporting count, see-through count.
    """
    cam = (moved - view.world_from_camera[:3, 3]) @ view.world_from_camera[:3, :3]
    fx, fy, cx, cy = view.depth_intrinsics
    z = cam[:, 2]
    ok = z > 0.05
    zs = np.where(ok, z, 1.0)
    u = np.rint(cam[:, 0] / zs * fx + cx).astype(np.int64)
    v = np.rint(cam[:, 1] / zs * fy + cy).astype(np.int64)
    h, w = view.observed_depth.shape
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        return 0.0, 0, 0
    pix = v[idx] * w + u[idx]
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
    dist, nn = tree.query(moved[idx], distance_upper_bound=0.2)
    near = dist < config.support_distance_m + 0.005 * z[idx] ** 2
    still = np.linalg.norm(moved[idx] - closed[idx], axis=1) < 0.03
    support = int(np.sum(near & (still | changed[np.minimum(nn, len(changed) - 1)])))
    return support - config.violation_weight * through, support, through


def _scoring_subset(points: np.ndarray, n: int = 1500) -> np.ndarray:
    """At most ``n`` of ``points``, evenly strided (deterministic), to keep scoring cheap."""
    step = max(1, int(np.ceil(len(points) / n)))
    return points[::step]


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
        # normals tilted the mean of the drawer benchmark's front by 10 degrees (median: 1.5).
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
    for q in np.arange(0.02, cfg.max_translation_m + 1e-9, 0.01):
        out.append(("prismatic", n, c, float(q)))
    side = np.cross(up, n)
    if np.linalg.norm(side) > 0.3:
        side /= np.linalg.norm(side)
        hinge_dirs = [(up, side), (side, up)]  # vertical hinge at a side edge; horizontal at top/bottom
    else:
        hinge_dirs = []
    angles = np.deg2rad(np.arange(3.0, np.rad2deg(cfg.max_rotation_rad) + 1e-9, 3.0))
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


def _observed_cloud(view: FrameView) -> o3d.geometry.PointCloud:
    pts = _to_world(view, view.observed_depth, np.isfinite(view.observed_depth))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).voxel_down_sample(0.01)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.04, max_nn=30))
    return pc


def _hole_counts(closed_points: np.ndarray, views: list[FrameView], cfg: PartConfig) -> np.ndarray:
    """``[T]`` how many pixels per frame see through the part's closed surface (how open and how
    visible the part is there)."""
    tree = cKDTree(closed_points)
    counts = np.zeros(len(views), int)
    for t, v in enumerate(views):
        diff = v.rendered_depth - v.observed_depth
        farther = np.isfinite(diff) & (diff < -depth_tolerance(v.rendered_depth, cfg.change))
        if farther.any():
            d, _ = tree.query(_to_world(v, v.rendered_depth, farther), distance_upper_bound=0.03)
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
    closed_points: np.ndarray, views: list[FrameView], gravity, reference_frame: int | None, cfg: PartConfig
) -> tuple[np.ndarray, list[int]]:
    """Unit up ``[3]`` and the candidate reference frames of :func:`fit_part_motion`."""
    up = -np.asarray(gravity, dtype=np.float64)
    up /= np.linalg.norm(up)
    if reference_frame is not None:
        return up, [int(reference_frame)]
    counts = _hole_counts(closed_points, views, cfg)
    frames = [len(views) - 1] + [int(t) for t in np.argsort(-counts)[:2] if counts[t] > 0]
    # Where the part is most open it may be seen worst: a door swung past the camera's line of
    # sight shows only its edge in the last frames, where no hinge explains anything and a
    # flap at 107 deg "won" with 17 supporting samples (strong-hand-occlusion at seed 105). On
    # its way there it is seen well: the first frames where the vanished surface reaches a
    # quarter, a half and three quarters of its largest extent are candidates too.
    if counts.max() > 0:
        frames += [int(np.argmax(counts >= f * counts.max())) for f in (0.25, 0.5, 0.75)]
    return up, frames


def _fit_ungrown(
    closed_points: np.ndarray, onset_frame: int, views: list[FrameView], up: np.ndarray, frames: list[int],
    cfg: PartConfig, mesh: CanonicalMesh | None,
) -> PartModel:
    """The part's motion fitted at the best of ``frames``, before its growth.

    The best-supported frame's fit says which joint moved the part; the reference is then the
    most open frame whose own fit found the same joint (``_same_joint``), since the masks are
    propagated from the reference and never search far past its state."""
    fits = [_fit_at(closed_points, onset_frame, views[r], r, up, cfg, mesh) for r in dict.fromkeys(frames)]
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


def _reference_support(model: PartModel, view: FrameView, cfg: PartConfig) -> int:
    """How many of the part's samples (scoring subset) the reference frame's observation
    supports at the fitted state."""
    sub = _scoring_subset(model.closed_points)
    m = model.motion(model.reference_q)
    return motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, cfg)[1]


def _drop_see_through(model: PartModel, view: FrameView, cfg: PartConfig) -> PartModel:
    """The part without the closed samples that, moved to the reference state, lie in view well
    in front of what is observed there (we see through them): surface of a neighbouring part
    that the vanished-surface clustering gave to this one. The door above a drawer and its
    coplanar front leave one vanished surface; the door's bottom strip went to the drawer,
    whose label then covered the door while it swung past (90-220 pixels a frame on the
    door+drawer benchmark) and its tracks followed the door. Moved with the drawer, that strip
    floats 25 cm out in front of the carcass, where the camera sees the floor."""
    m = model.motion(model.reference_q)
    moved = model.closed_points @ m[:3, :3].T + m[:3, 3]
    cam = (moved - view.world_from_camera[:3, 3]) @ view.world_from_camera[:3, :3]
    fx, fy, cx, cy = view.depth_intrinsics
    z = cam[:, 2]
    ok = z > 0.05
    zs = np.where(ok, z, 1.0)
    u = np.rint(cam[:, 0] / zs * fx + cx).astype(np.int64)
    v = np.rint(cam[:, 1] / zs * fy + cy).astype(np.int64)
    h, w = view.observed_depth.shape
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
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
        for dist in (0.08, 0.04):
            init = _icp_point_to_plane(closed_points, tgt_pts, tgt_nrm, tgt_tree, init, dist)
        jt, axis, pivot, q = _joint_from_motion(init, closed_points.mean(0))
        if jt == "prismatic":
            # A drawer slides along its front's normal. ICP slides a flat front freely in its own
            # plane (only its rim and handle hold it there): it took door+drawer's drawer 6.5 deg
            # off the normal, and the front seen at this frame 2.8 cm sideways once moved back.
            axis, q = normal, float(init[:3, 3] @ normal)
        candidates.append(PartModel(closed_points, jt, axis, pivot, r, q, onset_frame, normal))
        for cand in candidates:
            m = cand.motion(cand.reference_q)
            score = motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, cfg)[0]
            if score > best_score:
                best, best_score = cand, score
    return _refine_state_by_depth(best, view, sub), best_score


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
        d, nn = tree.query(p, distance_upper_bound=max_dist_m)
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
    fx, fy, cx, cy = view.depth_intrinsics
    z = cam[:, 2]
    ok = z > 0.05
    zs = np.where(ok, z, 1.0)
    u = np.rint(cam[:, 0] / zs * fx + cx).astype(np.int64)
    v = np.rint(cam[:, 1] / zs * fy + cy).astype(np.int64)
    h, w = view.observed_depth.shape
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    if not ok.any():
        return float("nan")
    obs = view.observed_depth[v[ok], u[ok]]
    res = np.abs(obs - z[ok])
    return float(np.mean(np.where(np.isfinite(res), np.minimum(res, cap_m), cap_m)))


def _refine_state_by_depth(model: PartModel, view: FrameView, sub: np.ndarray) -> PartModel:
    """A prismatic part's reference state fine-tuned (+-3 cm) to fit the observed depth.

    The support score counts samples within a few centimetres of an observed point, so it is
    flat over a couple of centimetres of joint state; a drawer fitted 2.5 cm short leaves its
    front, moved back to the closed state, in front of the closed front, and the growth then
    drops it. The truncated depth residual has its minimum at the true state."""
    if model.joint_type != "prismatic":
        return model  # a door is often seen edge-on, where grazing samples dominate the residual
    span = 0.03
    best, best_cost = model, np.inf
    for dq in np.linspace(-span, span, 25):
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
        for dq in np.arange(-0.03, 0.0301, 0.005):
            cand = replace(model, reference_q=model.reference_q + dq)
            sc = score(cand)
            if sc > best_score:
                best, best_score = cand, sc
        return best
    across = np.cross(model.axis, model.front_normal)
    across /= max(np.linalg.norm(across), 1e-9)
    for da in np.arange(-0.06, 0.0601, 0.02):
        for dn in (-0.03, -0.015, 0.0):
            pivot = model.pivot + across * da + model.front_normal * dn
            for dq in np.radians([-6.0, -4.0, -2.0, 0.0, 2.0, 4.0, 6.0]):
                cand = replace(model, pivot=pivot, reference_q=model.reference_q + dq)
                sc = score(cand)
                if sc > best_score:
                    best, best_score = cand, sc
    return best


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
        # Deeper points are another part that moved beside it (non-ideal-joints' sagging door
        # took 81 samples of the drawer opened below it, and covered the drawer with its label).
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
        # past it ran into the door above non-ideal-joints' drawer, at other frames' states.
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
    slides. A drawer that dips as it slides (non-ideal-joints: 0.04 rad at full travel, its
    front 1.4 cm lower at the reference frame) does not: its outline seen slid out and moved
    back along the normal landed 1.85 cm low (1.4 cm of dip, 0.4 cm from the fitted normal's
    1 degree of upward tilt), and the front's top face seen from above, which the closed frames
    show once the door above is open, went with it, inside the front. The 6-DOF motion ICP
    finds at the reference frame does not tell (a flat front slides in its own plane: 2-16
    degrees and 1-2 cm off on the benchmark drawers). The outline's edges that the frames see
    clear (the plane is seen through just past them, :func:`_open_reach`) do: each moves linearly with the state, its slope is the
    drift (a shared slope per in-plane axis, an offset per edge, least squares; at least three
    edge positions over ``front_seen_min_q_m / 2`` of travel). On the ideal benchmark drawers it
    comes out under 2 cm per metre."""
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
            elif score >= 0.5:
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
    if not drift.any():
        return model
    axis = n + drift[0] * e1 + drift[1] * e2
    # Same travel along the normal at the reference state.
    return replace(model, axis=axis / np.linalg.norm(axis), reference_q=model.reference_q * float(np.linalg.norm(axis)))


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
    outline overshoots: measured 0.04 lower IoU on the drawer benchmark scene.) With
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
    fx, fy, cx, cy = view.depth_intrinsics
    h, w = view.observed_depth.shape
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
            z = cam[..., 2]
            ok = z > 0.05
            zs = np.where(ok, z, 1.0)
            u = np.rint(cam[..., 0] / zs * fx + cx).astype(np.int64)
            v = np.rint(cam[..., 1] / zs * fy + cy).astype(np.int64)
            ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
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
    states, measured 0.11 lower IoU on the door+drawer benchmark scene.) Frames where the part is less
    than a third as open as at the reference frame, or tracked with a score below 0.5, are
    skipped (there the moved surface is close to the static one, or the state is uncertain)."""
    q_ref = abs(model.reference_q)
    ok = np.nonzero((np.abs(states) > q_ref / 3) & (scores >= 0.5))[0]
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


def _best_state(
    model: PartModel, view: FrameView, centre_q: float, cfg: PartConfig, after_reference: bool = False
) -> tuple[float, float]:
    """Joint state near ``centre_q`` (and closed) that best explains ``view``; and its score in [0, 1].

    ``after_reference``: ``view`` comes after the model's reference frame, which was not the
    last, so the part may open further than there."""
    span = cfg.search_window * abs(model.reference_q)
    # A drawer's reference frame need not be where it is most open (non-ideal-joints' drawer was
    # fitted at 0.207 m and opens to 0.25 m); a door's usually is, and searching past it invites
    # grazing-angle states. After a reference frame that is not the last (the door seen best on
    # its way past the camera's line of sight) the state goes on to the hypotheses' limit.
    reach = cfg.max_rotation_rad if model.joint_type == "revolute" else cfg.max_translation_m
    far = model.reference_q * (1.1 if model.joint_type == "revolute" else 1.35)
    if after_reference:
        far = float(np.sign(model.reference_q)) * max(abs(far), reach)
    lo, hi = sorted((0.0, far))
    grid = np.unique(np.clip(np.concatenate([np.linspace(centre_q - span, centre_q + span, 41), [0.0]]), lo, hi))

    sub = _scoring_subset(model.closed_points)

    def evaluate(q):
        m = model.motion(q)
        return motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, cfg)

    scores = [evaluate(q) for q in grid]
    i = int(np.argmax([s[0] for s in scores]))
    q = float(grid[i])
    step = (grid[1] - grid[0]) if len(grid) > 1 else 0.0
    for q2 in np.linspace(q - step, q + step, 9):
        if lo <= q2 <= hi:
            s2 = evaluate(q2)
            if s2[0] > scores[i][0]:
                q, scores[i] = float(q2), s2
    _, sup, thr = scores[i]
    if sup + thr == 0:
        return centre_q, 0.0  # out of view: keep the state
    return q, sup / (sup + thr)


def sample_normals(points: np.ndarray, radius_m: float = 0.03) -> np.ndarray:
    """``[N, 3]`` unit normals of surface samples ``[N, 3]`` (PCA of neighbours within
    ``radius_m``; sign arbitrary). Samples without enough neighbours get a zero normal."""
    if len(points) < 3:
        return np.zeros_like(points, dtype=np.float64)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=20))
    normals = np.asarray(pc.normals, dtype=np.float64)
    counts = np.array([len(x) for x in cKDTree(points).query_ball_point(points, radius_m)])
    normals[counts < 4] = 0.0
    return normals


def _splat(
    points: np.ndarray, pose: np.ndarray, intr, width: int, height: int, spacing: float,
    normals: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer ``[H, W]`` of surface samples drawn as discs (surfels) about their spacing wide,
    NaN where empty; and ``[H, W]`` the cosine between the ray and the drawn sample's normal
    (NaN where empty or the normal is unknown).

    With ``normals`` ``[N, 3]`` (canonical frame, sign arbitrary; zero: unknown) a pixel of a
    sample's footprint gets the depth where its ray meets the sample's tangent plane, and only
    if that point lies within the disc: seen at a grazing angle (a door edge-on) a flat square
    would put the near depth of the disc over pixels that see the surface several centimetres
    farther, and the observation would then look behind the part. Without normals the discs face
    the camera (a flat square at the sample's depth).
    """
    empty = np.full((height, width), np.nan)
    cam = (points - pose[:3, 3]) @ pose[:3, :3]
    nrm = np.zeros_like(cam) if normals is None else normals @ pose[:3, :3]
    fx, fy, cx, cy = intr
    z = cam[:, 2]
    keep = z > 0.05
    cam, z, nrm = cam[keep], z[keep], nrm[keep]
    if len(z) == 0:
        return empty, empty.copy()
    u = cam[:, 0] / z * fx + cx
    v = cam[:, 1] / z * fy + cy
    disc = 1.5 * spacing  # the discs lie in the surface, so overlap costs no depth accuracy
    has_n = np.linalg.norm(nrm, axis=1) > 0.5
    square = np.ceil(0.6 * spacing * fx / z).astype(np.int64)
    rad = np.where(has_n, np.maximum(np.ceil(disc * fx / z), square), square).astype(np.int64)
    pix_all, z_all, cos_all = [], [], []
    for r in np.unique(rad):
        sel = rad == r
        ui, vi, zi = np.rint(u[sel]).astype(np.int64), np.rint(v[sel]).astype(np.int64), z[sel]
        pi, ni, hi, sq = cam[sel], nrm[sel], has_n[sel], square[sel]
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                uu, vv = ui + dx, vi + dy
                ok = (uu >= 0) & (uu < width) & (vv >= 0) & (vv < height)
                ray = np.stack([(uu - cx) / fx, (vv - cy) / fy, np.ones(len(uu))], 1)
                denom = np.sum(ni * ray, 1)
                safe = hi & (np.abs(denom) > 1e-6)
                zp = np.where(safe, np.sum(ni * pi, 1) / np.where(safe, denom, 1.0), zi)
                inside = safe & (zp > 0.05) & (np.linalg.norm(ray * zp[:, None] - pi, axis=1) < disc)
                # Within the sample's own pixel square the pixel is always drawn (a slightly wrong
                # normal seen edge-on moves the plane's hit far along the surface and would leave
                # holes), its depth kept within a few centimetres of the sample's.
                own = (np.abs(dx) <= sq) & (np.abs(dy) <= sq)
                zp = np.where(own & ~inside, np.clip(zp if safe.any() else zi, zi - 0.03, zi + 0.03), zp)
                zp = np.where(np.isfinite(zp) & (zp > 0.05), zp, zi)
                ok &= ~hi | inside | own
                pix_all.append(vv[ok] * width + uu[ok])
                z_all.append(zp[ok])
                cos_all.append(np.where(hi, np.abs(denom) / np.linalg.norm(ray, axis=1), np.nan)[ok])
    pix, zz, cos = np.concatenate(pix_all), np.concatenate(z_all), np.concatenate(cos_all)
    order = np.lexsort((zz, pix))
    first = np.ones(len(order), bool)
    first[1:] = pix[order][1:] != pix[order][:-1]
    win = order[first]
    depth, cosine = empty.ravel().copy(), empty.ravel().copy()
    depth[pix[win]] = zz[win]
    cosine[pix[win]] = cos[win]
    return depth.reshape(height, width), cosine.reshape(height, width)


def label_frame(
    models: list[PartModel],
    states: list[float],
    pose: np.ndarray,
    rgb_intrinsics,
    rgb_size: tuple[int, int],
    observed_depth: np.ndarray,
    static_depth: np.ndarray,
    config: PartConfig | None = None,
    normals: list[np.ndarray] | None = None,
    observed_rgb: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Part labels and hand mask of one frame at RGB resolution.

    Args:
        models, states: the parts and their joint states at this frame.
        pose: ``[4, 4]`` camera in the canonical frame.
        rgb_intrinsics: ``(fx, fy, cx, cy)`` at RGB resolution.
        rgb_size: ``(width, height)``.
        observed_depth: ``[h, w]`` observed depth (metres), resampled to RGB resolution here.
        static_depth: ``[H, W]`` canonical model depth with the parts' closed surfaces removed
            (NaN there and where nothing is).
        normals: per model, ``[N, 3]`` normals of its closed samples (:func:`sample_normals`);
            without them the samples are drawn facing the camera.
        observed_rgb: ``[H, W, 3]`` uint8 frame; where the depth is invalid its pixels take the
            depth of nearby pixels of similar colour (:func:`fill_depth_by_colour`). Without
            it, the part model alone decides there.

    Returns:
        part ``[H, W]`` uint8 (k + 1 for part k) and hand ``[H, W]`` bool.
    """
    cfg = config or PartConfig()
    width, height = rgb_size
    obs = cv2.resize(observed_depth.astype(np.float32), (width, height), interpolation=cv2.INTER_NEAREST)
    best = np.full((height, width), np.inf)
    label = np.zeros((height, width), np.uint8)
    margin = np.zeros((height, width))
    slope = np.zeros((height, width))
    for k, (model, q) in enumerate(zip(models, states, strict=True)):
        m = model.motion(q)
        moved = model.closed_points @ m[:3, :3].T + m[:3, 3]
        nrm = None if normals is None else normals[k] @ m[:3, :3].T
        d, cos_px = _splat(moved, pose, rgb_intrinsics, width, height, cfg.sample_m, nrm)
        nearer = np.isfinite(d) & (d < best)
        best[nearer] = d[nearer]
        label[nearer] = k + 1
        # The samples lie on one face; seen at a grazing angle, the part's other face or edge is
        # up to thickness / cos(incidence) nearer along the ray. The incidence is the drawn
        # sample's own where its normal is known, else that of the front at the part's centre.
        c = model.closed_points.mean(0)
        ray = m[:3, :3] @ c + m[:3, 3] - pose[:3, 3]
        cos_front = abs((m[:3, :3] @ model.front_normal) @ ray) / max(np.linalg.norm(ray), 1e-9)
        cos = np.where(np.isfinite(cos_px), cos_px, cos_front)
        margin[nearer] = np.minimum(cfg.part_thickness_m / np.maximum(cos[nearer], 0.2), 0.1)
        slope[nearer] = np.sqrt(1.0 - np.minimum(cos[nearer], 1.0) ** 2) / np.maximum(cos[nearer], 0.1)
    if observed_rgb is not None:
        # Depth sensors drop the pixels on both sides of a depth edge: the outline of a hand in
        # front of the part, a door seen edge-on. Taken as no evidence against the model, they
        # were labelled part wherever the model is drawn: three quarters of the hand pixels
        # labelled part on the tiny benchmark scene, and most of the spurious pixels of the
        # edge-on door in large-session-offset. Each takes the depth of the nearby measured
        # pixels that look like it (the hand's skin, not the wood behind it); where none does
        # (a thin edge-on door is invalid across its width), the model's first surface decides.
        first = np.fmin(np.where(np.isfinite(best), best, np.nan), static_depth)
        obs = fill_depth_by_colour(observed_depth, observed_rgb, cfg.fill_radius_px, cfg.fill_sigma_colour,
                                   first, cfg.fill_model_weight)
    # The observed depth is nearest-neighbour upsampled: over one depth pixel a surface seen at
    # incidence theta changes depth by (pixel footprint) * tan(theta), in either direction.
    footprint = np.where(np.isfinite(best), best, 0.0) * (width / observed_depth.shape[1]) / rgb_intrinsics[0]
    quant = np.minimum(footprint * slope, 0.1)
    tol_static = depth_tolerance(static_depth, cfg.change)
    in_front_of_static = ~np.isfinite(static_depth) | (best < static_depth + tol_static)
    tol = depth_tolerance(np.where(np.isfinite(best), best, 0.0), cfg.change)
    tight = cfg.part_depth_tol_m + cfg.part_depth_tol_per_m2 * np.where(np.isfinite(best), best, 0.0) ** 2
    agrees = ~np.isfinite(obs) | ((obs < best + tol + quant) & (obs > best - tight - margin))
    part = np.where((label > 0) & in_front_of_static & agrees, label, 0).astype(np.uint8)
    part_closed = cv2.morphologyEx(part, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    part = np.where((part == 0) & (part_closed > 0) & (label == part_closed), part_closed, part)

    predicted = np.fmin(np.where(np.isfinite(best), best, np.nan), static_depth)
    hand = np.isfinite(obs) & np.isfinite(predicted) & (obs < predicted - depth_tolerance(predicted, cfg.change))
    hand &= part == 0
    hand = cv2.morphologyEx(hand.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)
    hand = remove_small(hand, cfg.hand_min_px)
    if cfg.hand_border_px > 0:
        # The depth is coarser than the labels: along the hand's outline a depth pixel that sees
        # the part behind also covers some of the hand. Part pixels that close to the hand go.
        size = 2 * cfg.hand_border_px + 1
        near_hand = cv2.dilate(hand.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)
        part = np.where(near_hand & ~hand, 0, part).astype(np.uint8)
    return part, hand


def fill_depth_by_colour(
    depth: np.ndarray,
    rgb: np.ndarray,
    radius_px: int,
    sigma_colour: float,
    predicted: np.ndarray | None = None,
    predicted_weight: float = 0.0,
) -> np.ndarray:
    """``[H, W]`` depth at the RGB resolution (nearest-neighbour upsampled) whose invalid pixels
    take the weighted median of the valid depth pixels within ``radius_px`` depth pixels,
    weighted by how alike their colours are and how near they are (a joint bilateral fill): an
    invalid pixel on a depth edge takes the depth of the side it looks like.

    Args:
        depth: ``[h, w]`` float metres, NaN invalid, with the RGB aspect ratio.
        rgb: ``[H, W, 3]`` uint8 frame; each depth pixel's colour is its footprint's mean.
        radius_px: half-size of the square window, in depth pixels (the work per invalid pixel
            does not grow with the RGB resolution).
        sigma_colour: colour Gaussian scale (RMS over channels, 0-255 units); the spatial one is
            one depth pixel.
        predicted: ``[H, W]`` depth a model predicts (metres, NaN none); it joins the vote with
            ``predicted_weight`` (a measured neighbour of the same colour at distance zero
            weighs 1), so it decides where no measured neighbour looks alike.

    Pixels without a candidate stay NaN.
    """
    height, width = rgb.shape[:2]
    h, w = depth.shape
    up = cv2.resize(depth.astype(np.float32), (width, height), interpolation=cv2.INTER_NEAREST)
    holes = np.flatnonzero(~np.isfinite(up))
    if len(holes) == 0 or radius_px < 1:
        return up
    ys, xs = np.divmod(holes, width)
    # Where each invalid RGB pixel lies on the depth grid (continuous, pixel centres at integers)
    # and the depth pixel the nearest-neighbour upsampling gave it.
    yc, xc = (ys + 0.5) * h / height - 0.5, (xs + 0.5) * w / width - 0.5
    yd, xd = np.clip(np.rint(yc).astype(np.int64), 0, h - 1), np.clip(np.rint(xc).astype(np.int64), 0, w - 1)
    colour = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA).reshape(-1, 3).astype(np.float32)
    own = rgb.reshape(-1, 3)[holes].astype(np.float32)
    flat = depth.astype(np.float32).ravel()
    cands, weights = [], []
    for dy in range(-radius_px, radius_px + 1):
        for dx in range(-radius_px, radius_px + 1):
            y, x = yd + dy, xd + dx
            inside = (y >= 0) & (y < h) & (x >= 0) & (x < w)
            j = np.where(inside, y * w + x, 0)
            d = np.where(inside, flat[j], np.nan)
            c2 = np.mean((colour[j] - own) ** 2, axis=1)
            wt = np.exp(-0.5 * c2 / sigma_colour**2 - 0.5 * ((y - yc) ** 2 + (x - xc) ** 2))
            ok = np.isfinite(d)
            cands.append(np.where(ok, d, np.inf))
            weights.append(np.where(ok, wt, 0.0))
    if predicted is not None:
        d = predicted.ravel()[holes]
        cands.append(np.where(np.isfinite(d), d, np.inf))
        weights.append(np.where(np.isfinite(d), predicted_weight, 0.0))
    cand, wts = np.stack(cands, 1), np.stack(weights, 1)
    order = np.argsort(cand, axis=1, kind="stable")
    cand = np.take_along_axis(cand, order, 1)
    cum = np.cumsum(np.take_along_axis(wts, order, 1), axis=1)
    total = cum[:, -1]
    pick = np.argmax(cum >= 0.5 * total[:, None], axis=1)
    out = up.ravel()
    out[holes] = np.where(total > 1e-12, cand[np.arange(len(holes)), pick], np.nan)
    return out.reshape(height, width)


def _static_depth_without_parts(
    mesh: CanonicalMesh, part_triangles: np.ndarray, pose: np.ndarray, intr, width: int, height: int
) -> np.ndarray:
    _, depth, tri = mesh.render(pose, intr, width, height)
    hit_part = np.zeros_like(tri, dtype=bool)
    ok = tri >= 0
    hit_part[ok] = part_triangles[tri[ok]]
    return np.where(hit_part, np.nan, depth)


def part_triangles(mesh: CanonicalMesh, models: list[PartModel], radius_m: float = 0.03) -> np.ndarray:
    """``[F]`` bool: canonical triangles lying on a part's closed surface (within ``radius_m``)."""
    out = np.zeros(len(mesh.triangles), bool)
    if not models:
        return out
    centroids = mesh.vertices[mesh.triangles].mean(1)
    tree = cKDTree(np.concatenate([m.closed_points for m in models]))
    d, _ = tree.query(centroids, distance_upper_bound=radius_m)
    return np.isfinite(d)


@dataclass(frozen=True)
class PartSegmentation:
    """What ``segment_parts`` found.

    Attributes:
        masks: per-frame part labels, hand masks and scores (RGB resolution).
        models: the moving parts, in onset order (label k + 1 is ``models[k]``).
        states: ``[T, K]`` joint state of each part per frame (radians or metres).
        candidates: ``[K]`` the candidate index (:func:`find_moved_parts` order) of each part.
        fates: the candidates that are not a part of their own, and why (:func:`screen_candidates`).
    """

    masks: MaskSequence
    models: list[PartModel]
    states: np.ndarray
    candidates: np.ndarray | None = None
    fates: tuple[PartFate, ...] = ()


def segment_part_at_frame(
    views: list[FrameView],
    frame: int | None = None,
    *,
    gravity=(0.0, -1.0, 0.0),
    mesh: CanonicalMesh | None = None,
    config: PartConfig | None = None,
) -> list[PartModel]:
    """Find the moved parts and fit each one's motion at ``frame`` (default: the last frame).

    The changed region at that frame is explained by rigid part motions only; what is in front
    of the moved parts and the static scene (hand, arm) is not part.

    Args:
        views: every dynamic frame (:func:`frame_views`), canonical frame.
        frame: the reference frame.
        gravity: ``[3]`` gravity direction in the canonical frame.
        mesh: the canonical mesh (optional; sharper part extents).

    Returns:
        the parts in onset order; empty when nothing moved (:func:`screen_candidates` also says
        what became of the candidates that are not among them).
    """
    return screen_candidates(views, frame, gravity=gravity, mesh=mesh, config=config)[0]


def screen_candidates(
    views: list[FrameView],
    frame: int | None = None,
    *,
    gravity=(0.0, -1.0, 0.0),
    mesh: CanonicalMesh | None = None,
    config: PartConfig | None = None,
) -> tuple[list[PartModel], list[int], list[PartFate]]:
    """:func:`segment_part_at_frame`, with every candidate accounted for.

    Each vanished surface (:func:`find_moved_parts`, candidates numbered in its order) is fitted;
    one that touches a part kept before it and moves with that part (the same joint, or that
    part's motion explains what its reference frame sees of it) is merged into it: a door's strip
    along its hinge vanishes later than the rest of it and is clustered apart. One that no motion
    explains (too little of it supported at its fitted state) is dropped.

    Returns:
        the kept parts, the candidate index of each, and the fates of the others.
    """
    cfg = config or PartConfig()
    models: list[PartModel] = []
    kept: list[int] = []
    fates: list[PartFate] = []
    for i, (pts, onset) in enumerate(find_moved_parts(views, cfg)):
        up, frames = _fit_setup(pts, views, gravity, frame, cfg)
        model = _fit_ungrown(pts, onset, views, up, frames, cfg, mesh)
        host = _host_part(model, models, views, cfg)
        if host is not None:
            k, why = host
            models[k] = replace(models[k], closed_points=np.concatenate([models[k].closed_points, model.closed_points]))
            fates.append(PartFate(candidate=i, fate="merged", stage="part_masks", into=kept[k], reason=why))
            continue
        support = _reference_support(model, views[model.reference_frame], cfg)
        if support < cfg.min_part_support:
            # No motion of this surface explains what the reference frame sees: it vanished for
            # another reason. strong-hand-occlusion's cabinet side, seen edge-on, vanished from
            # the first frame on and came out as a second part with no support at all.
            fates.append(PartFate(
                candidate=i, fate="dropped", stage="part_masks",
                reason=f"no motion of its {len(model.closed_points)} surface samples explains what frame "
                f"{model.reference_frame} sees ({support} supported at its best fit; {cfg.min_part_support} needed)",
            ))
            continue
        models.append(_fit_slide_and_grow(model, views, cfg, mesh))
        kept.append(i)
    return models, kept, fates


def _host_part(
    model: PartModel, kept: list[PartModel], views: list[FrameView], cfg: PartConfig
) -> tuple[int, str] | None:
    """The kept part ``model``'s surface belongs to, with the reason, or None.

    It must touch that part (closed samples within ``host_reach_m``) and move with it: the same
    joint (``_same_joint``), or that part's motion at its reference state explains most of what
    the reference frame sees of ``model``'s samples (supported, not seen through, and better than
    the samples held still)."""
    sub = _scoring_subset(model.closed_points)
    for k, host in enumerate(kept):
        gap = float(cKDTree(host.closed_points).query(sub, distance_upper_bound=cfg.host_reach_m)[0].min())
        if not np.isfinite(gap):
            continue
        if _same_joint(model, host):
            return k, f"it touches candidate part {k}'s surface ({1e3 * gap:.0f} mm) and was fitted with the same joint"
        view = views[host.reference_frame]
        m = host.motion(host.reference_q)
        score, support, through = motion_score(view, sub @ m[:3, :3].T + m[:3, 3], sub, cfg)
        still, _, _ = motion_score(view, sub, sub, cfg)
        if support >= cfg.host_min_support_frac * len(sub) and score > max(still, 0.0):
            return k, (f"it touches candidate part {k}'s surface ({1e3 * gap:.0f} mm) and that part's motion explains "
                       f"{support} of its {len(sub)} samples in frame {host.reference_frame} ({through} seen through)")
    return None


def propagate_masks_backwards(
    models: list[PartModel],
    views: list[FrameView],
    dynamic: Capture,
    mesh: CanonicalMesh,
    config: PartConfig | None = None,
) -> PartSegmentation:
    """Label every frame, from the reference frame (normally the last) back to the first,
    tracking each part's joint state.

    Each frame's state is searched near the following frame's (within ``search_window`` of the
    reference state, and closed), so the labels follow the part as it closes. Frames after a
    reference frame that is not the last are tracked forwards the same way.

    Args:
        models: the parts (:func:`segment_part_at_frame`), fitted at the last frame.
        views: every dynamic frame (:func:`frame_views`).
        dynamic: the dynamic recording (RGB frames, size and intrinsics).
        mesh: the canonical mesh (for what the parts hide or reveal).
    """
    cfg = config or PartConfig()
    n = len(views)
    if n != dynamic.num_frames:
        raise InputError(f"propagate_masks_backwards: {n} views for a recording of {dynamic.num_frames} frames.")
    tris = part_triangles(mesh, models, radius_m=1.5 * cfg.vanish_voxel_m)
    states = np.zeros((n, len(models)))
    scores = np.zeros((n, len(models)))
    for k, model in enumerate(models):
        r = min(model.reference_frame, n - 1)
        order = list(range(r, -1, -1)) + list(range(r + 1, n))
        current = model.reference_q
        for t in order:
            if t == r + 1:
                current = states[r, k]  # forwards again from the reference state
            current, scores[t, k] = _best_state(model, views[t], current, cfg, after_reference=t > r)
            states[t, k] = current
    if cfg.grow_frames > 0:
        models = [_grow_over_frames(model, views, states[:, k], scores[:, k], mesh, cfg)
                  for k, model in enumerate(models)]
    part, hand = _label_frames(models, states, views, dynamic, mesh, tris, cfg)
    score = scores.min(1) if len(models) else np.zeros(n)
    return PartSegmentation(MaskSequence(part, hand, score.astype(np.float32)), models, states)


def _label_frames(
    models: list[PartModel], states: np.ndarray, views: list[FrameView], dynamic: Capture, mesh: CanonicalMesh,
    tris: np.ndarray, cfg: PartConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Part labels ``[T, H, W]`` uint8 and hand masks ``[T, H, W]`` bool of every frame at the
    parts' states ``states [T, K]``; ``tris`` are the canonical triangles on the parts."""
    width, height = dynamic.rgb_size
    n = len(views)
    part = np.zeros((n, height, width), np.uint8)
    hand = np.zeros((n, height, width), bool)
    normals = [sample_normals(m.closed_points) for m in models]
    for t in range(n):
        static_d = _static_depth_without_parts(mesh, tris, views[t].world_from_camera, dynamic.rgb_intrinsics[t],
                                               width, height)
        part[t], hand[t] = label_frame(models, list(states[t]), views[t].world_from_camera,
                                       dynamic.rgb_intrinsics[t], (width, height), views[t].observed_depth,
                                       static_d, cfg, normals, observed_rgb=dynamic.rgb[t])
    return part, hand


def segment_parts(
    dynamic: Capture,
    canonical_from_session: np.ndarray,
    mesh: CanonicalMesh,
    *,
    gravity=(0.0, -1.0, 0.0),
    config: PartConfig | None = None,
) -> PartSegmentation:
    """Part and hand masks for every dynamic frame, with the default geometric backend.

    Args:
        dynamic: the dynamic recording (its own session frame).
        canonical_from_session: ``[4, 4]`` from :func:`register_recordings`.
        mesh: the canonical model (:func:`build_canonical_tsdf`).
        gravity: ``[3]`` gravity direction in the canonical frame.
    """
    cfg = config or PartConfig()
    views = frame_views(dynamic, np.asarray(canonical_from_session, dtype=np.float64), mesh)
    models, kept, fates = screen_candidates(views, None, gravity=gravity, mesh=mesh, config=cfg)
    seg = propagate_masks_backwards(models, views, dynamic, mesh, cfg)
    return replace(seg, candidates=np.asarray(kept, dtype=np.int32), fates=tuple(fates))
