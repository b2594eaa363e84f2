"""Labelling one frame: part labels and the hand mask at the parts' joint states (``label_frame``).

A pixel is part k when the moved part model is the first surface there and the observed depth
agrees; it is hand when the observation lies in front of everything the model predicts. The hand
cannot be labelled part by moving rigidly with it, since only the rigid model decides what is part.
Where the sensor gives no depth (both sides of every depth edge, so the hand's outline), a pixel
takes the depth of the measured pixels around it that look like it, so the model does not decide
alone there (``fill_depth_by_colour``).
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from artitwin_core.change._canonical import CanonicalMesh
from artitwin_core.change._config import PartConfig
from artitwin_core.change._detect import depth_tolerance, remove_small
from artitwin_core.change._views import PartModel
from artitwin_core.geometry import pixel_rays


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
                ray = pixel_rays((fx, fy, cx, cy), uu, vv)
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
        # were labelled part wherever the model is drawn (most of a hand's outline, most of an
        # edge-on door's spurious pixels; docs/accuracy.md). Each takes the depth of the nearby measured
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
