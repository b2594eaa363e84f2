"""The closed surfaces of the parts that moved: canonical surface that vanished.

In the dynamic frames, where we now see farther than the canonical surface, that surface has moved
away. Votes over frames collect it (``find_moved_parts``), clustered in space and in the time it
vanished, so neighbouring parts that open at different times come out apart.
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from artitwin_core.change._canonical import CanonicalMesh
from artitwin_core.change._config import PartConfig
from artitwin_core.change._detect import depth_tolerance
from artitwin_core.change._views import FrameView, _to_world
from artitwin_core.geometry import depth_normals, unique_rows


def find_moved_parts(
    views: list[FrameView], config: PartConfig | None = None, *, hidden: bool = False,
    explained: list[np.ndarray] | None = None, mesh: CanonicalMesh | None = None,
) -> list[tuple[np.ndarray, int]]:
    """Closed surfaces of the parts that moved: canonical surface seen vanished in several frames;
    with ``hidden``, canonical surface hidden by something nearer in several frames
    (``min_occluded_frames``) instead.

    A part that moved only towards the camera (a drawer pulled out straight at a close-up camera)
    hides its closed front and reveals nothing behind it: it leaves no vanished surface, only a
    hidden one. Only surface hidden by a nearer one facing its way counts
    (``hidden_parallel_deg``: a hand, an arm or a turned door hides surface at an angle), and it
    is taken where the nearer surface, moved back along the hidden one's normal, meets it: the
    front's closed place. With the canonical ``mesh``, a nearer surface seen over another one (a
    front pulled out past its closed outline, seen over the floor or the carcass's side) is moved
    back along its own normal to the first canonical surface there, and counts where that surface
    faces its way. These are candidates of last resort: :func:`screen_candidates` turns
    to them when no vanished one is explained by a motion, :func:`segment_parts` where the parts
    found do not explain them (``explained``).

    Args:
        explained: per frame, ``[h, w]`` bool at depth resolution: pixels whose change is
            already accounted for (the parts found, where they are seen), left out of the votes.

    Returns:
        per part, best first in onset order: closed surface samples ``[N, 3]`` (canonical frame,
        metres) and the onset frame index.
    """
    cfg = config or PartConfig()
    if hidden:
        return _changed_surfaces(views, cfg, True, explained, mesh) if cfg.min_occluded_frames > 0 else []
    return _changed_surfaces(views, cfg, False, explained)


def _changed_surfaces(
    views: list[FrameView], cfg: PartConfig, nearer: bool, explained: list[np.ndarray] | None = None,
    mesh: CanonicalMesh | None = None,
) -> list[tuple[np.ndarray, int]]:
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
        normals = None
        beside = np.zeros_like(changed)
        if nearer and cfg.hidden_parallel_deg < 90.0:
            parallel, normals, seen_normals = _parallel(v, cfg.hidden_parallel_deg)
            if mesh is not None:
                beside = changed & ~parallel
            changed &= parallel
        if explained is not None:
            changed &= ~explained[t]
            beside &= ~explained[t]
        p = _to_world(v, v.rendered_depth, changed)
        if normals is not None and changed.any():
            # The nearer surface faces the hidden one's way: a front slid along its normal. Its
            # closed place is the observed point moved back along that normal onto the canonical
            # surface's plane (not the surface behind it along the ray, which an oblique view
            # puts beside the front, on whatever lies there).
            n = normals[changed] @ v.world_from_camera[:3, :3].T
            o = _to_world(v, v.observed_depth, changed)
            p = o - n * ((o - p) * n).sum(-1, keepdims=True)
        if beside.any():
            p = np.concatenate([p, _moved_back_along_normal(v, beside, seen_normals, mesh, cfg)])
        if not len(p):
            continue
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
    pairs = unique_rows(np.concatenate([keys_all, frames_all[:, None]], 1))[0]
    vkeys, inv_pairs, counts = unique_rows(pairs[:, :3])
    good = counts >= (cfg.min_occluded_frames if nearer else cfg.min_vanish_frames)
    min_voxels = cfg.min_hidden_part_voxels if nearer else cfg.min_part_voxels
    if good.sum() < min_voxels:
        return []
    first_frame = np.full(len(vkeys), np.iinfo(np.int64).max)
    np.minimum.at(first_frame, inv_pairs.ravel(), pairs[:, 3])
    centres = (vkeys[good] + 0.5) * vox
    good_keys = vkeys[good]
    good_first = first_frame[good]
    times = np.array([v.timestamp_s for v in views], dtype=np.float64)
    if not (np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)):
        times = np.arange(len(views)) / 15.0
    labels = _split_by_onset(centres, times[good_first], cfg, min_voxels)
    # Map each vanished point to its voxel's cluster label.
    lut = {tuple(k): i for i, k in enumerate(good_keys)}
    pk = np.floor(points_all / vox).astype(np.int64)
    idx = np.array([lut.get(tuple(k), -1) for k in pk])
    parts = []
    for lab in range(labels.max() + 1 if len(labels) else 0):
        members = labels == lab
        if members.sum() < min_voxels:
            continue
        sel = idx >= 0
        sel[sel] = labels[idx[sel]] == lab
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_all[sel])).voxel_down_sample(cfg.sample_m)
        # Onset: the frame by which a tenth of the part's voxels had vanished.
        onset = int(np.quantile(good_first[members], 0.1))
        parts.append((np.asarray(pc.points), onset))
    parts.sort(key=lambda p: (p[1], -len(p[0])))
    return parts


def _parallel(view: FrameView, max_deg: float, smooth_px: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``[h, w]`` bool: pixels whose observed surface faces the same way as the canonical one
    there, within ``max_deg`` (normals of both depth maps, averaged over ``smooth_px`` pixels:
    depth noise tilts single-pixel normals); and the canonical and the observed surface's unit
    normals ``[h, w, 3]`` (camera frame)."""
    def normals(z: np.ndarray) -> np.ndarray:
        n = np.nan_to_num(depth_normals(z, view.depth_intrinsics)).astype(np.float32)
        n = cv2.blur(n, (smooth_px, smooth_px))
        return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)

    rendered, observed = normals(view.rendered_depth), normals(view.observed_depth)
    cos = (observed * rendered).sum(-1)
    return cos > np.cos(np.radians(max_deg)), rendered, observed


def _moved_back_along_normal(
    view: FrameView, pixels: np.ndarray, seen_normals: np.ndarray, mesh: CanonicalMesh, cfg: PartConfig
) -> np.ndarray:
    """``[N, 3]`` canonical points: the observed surface at ``pixels [h, w]`` (nearer than the
    canonical surface along their rays, and not facing its way there) moved back along its own
    normal (``seen_normals``, camera frame) to the first canonical surface, where that surface
    faces the same way (``hidden_parallel_deg``), lies beyond the depth tolerance and within
    ``max_translation_m``. A front pulled out past its closed outline is seen over the floor or
    the carcass's side; along its normal it meets its closed place, which faces its way."""
    o = _to_world(view, view.observed_depth, pixels)
    n = seen_normals[pixels].astype(np.float64) @ view.world_from_camera[:3, :3].T
    n *= np.where(((view.world_from_camera[:3, 3] - o) * n).sum(-1) < 0, -1.0, 1.0)[:, None]  # towards the camera
    ok = np.linalg.norm(n, axis=1) > 0.5
    o, n = o[ok], n[ok]
    hit = mesh._scene.cast_rays(o3d.core.Tensor(np.concatenate([o, -n], 1).astype(np.float32)))
    dist = hit["t_hit"].numpy().astype(np.float64)
    facing = np.abs((hit["primitive_normals"].numpy().astype(np.float64) * n).sum(-1))
    keep = (np.isfinite(dist) & (dist > cfg.change.depth_tol_m) & (dist <= cfg.max_translation_m)
            & (facing > np.cos(np.radians(cfg.hidden_parallel_deg))))
    return o[keep] - n[keep] * dist[keep, None]


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


def _split_by_onset(centres: np.ndarray, onset_s: np.ndarray, cfg: PartConfig, min_voxels: int) -> np.ndarray:
    """``[V]`` part label per vanished voxel (-1 noise): space clusters split where onsets differ.

    Two parts side by side (a door above a drawer, a divider of a couple of centimetres between
    them) leave one connected vanished surface, but they open at different times. Clustering in
    space and onset time (``onset_m_per_s`` apart per second) separates them; the onset of a
    voxel only seen late (hidden by the hand, out of view) can lag its part's, so voxels of such
    small spatio-temporal clusters go to the nearest large cluster of their space cluster
    (large: ``min_voxels``).
    """
    labels = _dbscan(centres, cfg.cluster_eps_m)
    if cfg.onset_m_per_s <= 0 or len(labels) == 0:
        return labels
    out = np.full(len(labels), -1)
    next_label = 0
    for lab in range(labels.max() + 1):
        members = np.nonzero(labels == lab)[0]
        if len(members) < min_voxels:
            continue
        st = np.concatenate([centres[members], cfg.onset_m_per_s * onset_s[members, None]], 1)
        sub = _dbscan(st, cfg.cluster_eps_m)
        sizes = np.bincount(sub[sub >= 0], minlength=1)
        seeds = [i for i in range(len(sizes)) if sizes[i] >= min_voxels]
        if len(seeds) <= 1:
            out[members] = next_label
            next_label += 1
            continue
        seed_pts = [centres[members[sub == i]] for i in seeds]
        dist = np.stack([cKDTree(p).query(centres[members])[0] for p in seed_pts], 1)
        out[members] = next_label + np.argmin(dist, 1)
        next_label += len(seeds)
    return out
