"""Model-based tracking of a rigid part: its query-frame surface aligned to every other frame.

The part's surface at the query frame (pixels of its eroded mask lifted with depth, with normals
and grey levels) is the model. Each frame ``t`` gets the rigid motion ``world_from_query`` that
aligns the model with frame ``t`` by robust Gauss-Newton on two terms: projective point-to-plane
distances to the frame's depth (which pin the part's plane whatever the texture) and grey-level
differences against the frame's image with an affine exposure model (which pin the motion
within the plane). Only pixels inside the frame's part mask (dilated, hand removed) count, and
the coarse levels' blur leaves out the hand and the other parts, so that neither they nor the
background pull the motion. Frames are visited walking away from the query frame; each starts
from the better of the previous motion and its constant-velocity prediction, so a door swung
by 0.2 rad between frames stays within the basin of convergence.

Unlike chained 2D tracking, nothing here needs frame-to-frame image similarity: a frame is
aligned to the model directly, so a frame that fails (hand over the part, motion blur) does not
end the track; the next frame starts again from the prediction. After such a gap the part kept
moving, so the starts also carry the last motion further along its screw and extrapolate the
velocity over the gap.

An alignment is trusted only if (a) most visible model points fit the depth, (b) on a textured
part its grey levels correlate with the frame's, patch by patch (depth cannot tell a plane from
itself slid or flipped within the plane), (c) it stayed within ``max_correction_rad`` of the
prediction it started from and (d) the moved model explains most of what the frame shows of
the part. Without (b) and (c), a door whose front had turned out of view was "found" on its
back face, flipped 180 degrees, and its tracks came back with wrong identities. Without (d), a
drawer slid down its own grain while a door swung in front of it, its points leaving the part's
mask (where they no longer counted), and stayed there once the drawer was in full view. After a
frame without a trusted alignment, the query frame's pose is among the starts too, so that a
walk that went astray can come back.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from artitwin_core.geometry import backproject, unique_rows
from artitwin_core.tracking._lift import lift_pixels


@dataclass(frozen=True)
class RigidTrackResult:
    """Per-frame rigid motions of the part.

    Attributes:
        motions: ``[T, 4, 4]`` float64 ``world_from_query``: maps a part point's world position at
            the query frame to frame ``t`` (identity at the query frame; NaN where not aligned).
        confident: ``[T]`` bool, the alignment passed the inlier and residual checks.
        inlier_fraction: ``[T]`` fraction of the model's visible points that are depth inliers.
        depth_rms_m: ``[T]`` robust RMS point-to-plane residual of the inliers, metres.
    """

    motions: np.ndarray
    confident: np.ndarray
    inlier_fraction: np.ndarray
    depth_rms_m: np.ndarray


def _hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _exp_se3(xi: np.ndarray) -> np.ndarray:
    """``[4, 4]`` of the twist ``xi = (v, w)`` (left perturbation in the world frame)."""
    v, w = xi[:3], xi[3:]
    th = float(np.linalg.norm(w))
    k = _hat(w)
    if th < 1e-9:
        r = np.eye(3) + k
        vmat = np.eye(3) + 0.5 * k
    else:
        r = np.eye(3) + np.sin(th) / th * k + (1 - np.cos(th)) / th**2 * (k @ k)
        vmat = np.eye(3) + (1 - np.cos(th)) / th**2 * k + (th - np.sin(th)) / th**3 * (k @ k)
    out = np.eye(4)
    out[:3, :3] = r
    out[:3, 3] = vmat @ v
    return out


def _normals(points: np.ndarray, k: int = 12) -> np.ndarray:
    """Unit normals ``[M, 3]`` of ``points [M, 3]`` by PCA over the ``k`` nearest neighbours."""
    k = min(k, points.shape[0])
    _, idx = cKDTree(points).query(points, k=k)
    nb = points[idx] - points[idx].mean(1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", nb, nb)
    return np.linalg.eigh(cov)[1][:, :, 0]


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return cv2.remap(
        image, u.astype(np.float32).reshape(-1, 1), v.astype(np.float32).reshape(-1, 1), cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"),
    ).reshape(-1)


def _masked_blur(gray: np.ndarray, mask: np.ndarray | None, sigma: float) -> np.ndarray:
    """``gray [H, W]`` blurred by ``sigma`` pixels over ``mask [H, W] bool`` only (normalised
    convolution: the blur of ``gray * mask`` over the blur of ``mask``; unblurred where the mask
    has no weight; a plain blur when ``mask`` is None), float32."""
    img = gray.astype(np.float32)
    if sigma <= 0:
        return img
    if mask is None:
        return cv2.GaussianBlur(img, (0, 0), sigma)
    m = mask.astype(np.float32)
    num = cv2.GaussianBlur(img * m, (0, 0), sigma)
    den = cv2.GaussianBlur(m, (0, 0), sigma)
    return np.where(den > 1e-3, num / np.maximum(den, 1e-3), img).astype(np.float32)


class _Frame:
    """One frame's images prepared for alignment (blurred grey, its gradients, depth).

    ``occluders [H, W]`` bool (or None): pixels of things that move on their own (the hand,
    the other parts), left out of the blur. A plain blur mixes into the part's grey levels
    whatever lies beside it: a door swinging in front of a drawer pulled the coarse levels'
    alignment down the drawer's grain, where the sharp level has nothing to pull it back
    (docs/accuracy.md). The static scene around the part stays in the blur: its contrast with
    the part's outline pins the part along its grain (leaving out everything but the part's
    mask set an open drawer low).
    """

    def __init__(self, gray, depth, allowed, pose, k_rgb, k_depth, sigmas, occluders=None):
        self.depth = np.asarray(depth, np.float32)
        self.allowed = allowed
        self.cam_from_world = np.linalg.inv(pose)
        self.k_rgb, self.k_depth = k_rgb, k_depth
        self.levels = []
        support = None if occluders is None else ~np.asarray(occluders, bool)
        for s in sigmas:
            img = _masked_blur(gray, support, s)
            gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
            gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
            self.levels.append((img, gx, gy))


def _evaluate(frame: _Frame, level: int, motion, xq, nq, tq, gain, need_jac: bool):
    """Residuals of the model under ``motion``: depth (metres) and grey (levels), with Jacobians.

    Returns ``(rd [M], jd [M, 6], rp [M], jp [M, 8], ok_d [M], ok_p [M], visible [M])``.
    """
    xw = xq @ motion[:3, :3].T + motion[:3, 3]
    nw = nq @ motion[:3, :3].T
    rcw, tcw = frame.cam_from_world[:3, :3], frame.cam_from_world[:3, 3]
    pc = xw @ rcw.T + tcw
    nc = nw @ rcw.T
    z = pc[:, 2]
    front = z > 1e-3
    zs = np.where(front, z, 1.0)
    fx, fy, cx, cy = frame.k_rgb
    u = fx * pc[:, 0] / zs + cx
    v = fy * pc[:, 1] / zs + cy
    height, width = frame.allowed.shape
    inside = front & (u >= 1) & (u <= width - 2) & (v >= 1) & (v <= height - 2)
    # A face seen edge-on gives neither a reliable depth nor texture.
    facing = np.sum(nc * pc, axis=1) < -0.15 * np.linalg.norm(pc, axis=1)
    iu = np.clip(np.rint(u), 0, width - 1).astype(np.int64)
    iv = np.clip(np.rint(v), 0, height - 1).astype(np.int64)
    visible = inside & facing & frame.allowed[iv, iu]
    # Depth: the depth pixel on the point's ray, lifted, against the model plane at the point.
    fxd, fyd, cxd, cyd = frame.k_depth
    ud = fxd * pc[:, 0] / zs + cxd
    vd = fyd * pc[:, 1] / zs + cyd
    dz = _bilinear(frame.depth, ud, vd)
    ok_d = visible & np.isfinite(dz) & (dz > 0)
    dzs = np.where(ok_d, dz, 1.0)
    qc = backproject(dzs, frame.k_depth, ud, vd)
    rd = np.where(ok_d, np.sum(nc * (pc - qc), axis=1), 0.0)
    img, gx_img, gy_img = frame.levels[level]
    val = _bilinear(img, u, v)
    ok_p = visible & np.isfinite(val)
    pred = (gain[0] * tq + gain[1])
    rp = np.where(ok_p, val - pred, 0.0)
    if not need_jac:
        return rd, None, rp, None, ok_d, ok_p, visible
    # Left perturbation xw -> exp(xi) xw: d xw / d xi = [I, -[xw]x].
    jd = np.concatenate([nw, np.cross(xw, nw)], axis=1)
    gx, gy = _bilinear(gx_img, u, v), _bilinear(gy_img, u, v)
    gx, gy = np.nan_to_num(gx), np.nan_to_num(gy)
    # d(u, v) / d pc, then through rcw to world.
    du = np.stack([fx / zs, np.zeros_like(zs), -fx * pc[:, 0] / zs**2], -1)
    dv = np.stack([np.zeros_like(zs), fy / zs, -fy * pc[:, 1] / zs**2], -1)
    gw = (gx[:, None] * du + gy[:, None] * dv) @ rcw  # d I / d xw  [M, 3]
    jp = np.concatenate([gw, np.cross(xw, gw), -tq[:, None], -np.ones((tq.size, 1))], axis=1)
    return rd, jd, rp, jp, ok_d, ok_p, visible


def _robust(r: np.ndarray, ok: np.ndarray, floor: float, redescend: bool):
    """Weights ``[M]`` (Huber, or Tukey once converging) and the robust scale of ``r``."""
    if ok.sum() < 10:
        return np.zeros_like(r), floor
    a = np.abs(r[ok])
    scale = max(1.4826 * float(np.median(a)), floor)
    if redescend:
        c = 4.685 * scale
        w = np.where(np.abs(r) < c, (1 - (r / c) ** 2) ** 2, 0.0)
    else:
        c = 1.345 * scale
        w = np.where(np.abs(r) <= c, 1.0, c / np.maximum(np.abs(r), 1e-12))
    return np.where(ok, w, 0.0), scale


def _align(frame: _Frame, motion, xq, nq, tq, params: RigidParams, patches: np.ndarray):
    """Gauss-Newton from ``motion``; returns ``(motion, cost, inlier_fraction, depth_rms, ncc)``
    (``ncc``: ``_appearance`` at the depth inliers over the model's ``patches [M]``, with the
    fitted exposure gain removed by the correlation's normalisation)."""
    gain = np.array([1.0, 0.0])
    motion = motion.copy()
    n_levels = len(frame.levels)
    for level in range(n_levels):
        for it in range(params.iterations):
            rd, jd, rp, jp, ok_d, ok_p, _ = _evaluate(frame, level, motion, xq, nq, tq, gain, True)
            if ok_d.sum() < params.min_points:
                return motion, np.inf, 0.0, np.inf, -1.0
            late = it >= 3
            wd, sd = _robust(rd, ok_d, params.depth_floor_m, late)
            wp, sp = _robust(rp, ok_p, params.grey_floor, late)
            wd, wp = wd / sd**2, params.photometric_weight * wp / sp**2
            jd8 = np.concatenate([jd, np.zeros((jd.shape[0], 2))], axis=1)
            a = (jd8 * wd[:, None]).T @ jd8 + (jp * wp[:, None]).T @ jp
            b = (jd8 * wd[:, None]).T @ rd + (jp * wp[:, None]).T @ rp
            a += 1e-9 * np.trace(a) / 8 * np.eye(8)
            try:
                delta = -np.linalg.solve(a, b)
            except np.linalg.LinAlgError:
                return motion, np.inf, 0.0, np.inf, -1.0
            motion = _exp_se3(delta[:6]) @ motion
            gain = gain + delta[6:]
            if np.linalg.norm(delta[3:6]) < 1e-6 and np.linalg.norm(delta[:3]) < 1e-6:
                break
    rd, _, rp, _, ok_d, ok_p, visible = _evaluate(frame, n_levels - 1, motion, xq, nq, tq, gain, False)
    if ok_d.sum() < params.min_points:
        return motion, np.inf, 0.0, np.inf, -1.0
    inl = ok_d & (np.abs(rd) < params.inlier_m)
    frac = float(inl.sum() / max(visible.sum(), 1))
    rms = float(np.sqrt(np.mean(rd[inl] ** 2))) if inl.any() else np.inf
    # Truncated cost for choosing between starts: inliers' squared residual, outliers capped.
    cost = float(np.mean(np.minimum(rd[ok_d] ** 2, params.inlier_m**2))) + params.inlier_m**2 * (
        1.0 - ok_d.sum() / max(xq.shape[0], 1)
    )
    ncc = _appearance(rp + gain[0] * tq + gain[1], tq, ok_p & inl, patches, params.min_points, params.texture_floor,
                      params.min_patch_points)
    return motion, cost, frac, rms, ncc


def _patches(u: np.ndarray, v: np.ndarray, size_px: float) -> np.ndarray:
    """``[M]`` int: the square of side ``size_px`` of the query image's pixel grid that holds each
    model point (its query-frame pixel ``(u [M], v [M])``)."""
    keys = np.stack([np.floor(u / size_px), np.floor(v / size_px)], -1).astype(np.int64)
    return unique_rows(keys)[1]


def _appearance(
    seen: np.ndarray, tq: np.ndarray, ok: np.ndarray, patches: np.ndarray | None, min_points: int,
    texture_floor: float = 3.0, min_patch_points: int = 8,
) -> float:
    """Correlation of the model's grey levels ``tq [M]`` with the frame's ``seen [M]`` at the
    aligned points ``ok [M]``, patch by patch: each patch (``patches [M]``, a patch index per
    point; None: the whole part is one) is normalised on its own and the patches' correlations
    are averaged, weighted by their points. -1 when too few points are seen, NaN when the
    model's grey levels vary by less than ``texture_floor``: nothing to compare.

    A plane's depth cannot tell a door from the same door slid or turned within its plane (a
    180 degree flip about its normal fits depth perfectly): only appearance can. Patches make
    the score blind to illumination that differs across the part: an open door's shadow across
    half a drawer's front dropped the whole front's correlation at the true pose under
    ``min_ncc``, so no frame of the drawer's slide was trusted.
    """
    if ok.sum() < min_points:
        return -1.0
    a, b = tq[ok], seen[ok]
    sa, sb = float(np.std(a)), float(np.std(b))
    if sa < texture_floor:
        return float("nan")  # an untextured part: appearance can tell nothing
    if patches is None:
        return -1.0 if sb < 1e-6 else float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))
    c = np.unique(patches[ok], return_inverse=True)[1].reshape(-1)
    n = np.bincount(c).astype(np.float64)
    da, db = a - (np.bincount(c, a) / n)[c], b - (np.bincount(c, b) / n)[c]
    va, vb, cov = np.bincount(c, da * da) / n, np.bincount(c, db * db) / n, np.bincount(c, da * db) / n
    # A patch of the model without grey-level variation has nothing to correlate.
    use = (n >= min_patch_points) & (va >= 1.0)
    if not use.any():
        return _appearance(seen, tq, ok, None, min_points, texture_floor)
    r = np.where(vb[use] > 1e-12, cov[use] / np.sqrt(va[use] * np.maximum(vb[use], 1e-12)), 0.0)
    return float(np.sum(n[use] * r) / np.sum(n[use]))


@dataclass(frozen=True)
class RigidParams:
    """Resolved parameters of the model-based tracker (see ``TrackingConfig``)."""

    blur_sigmas: tuple[float, ...] = (3.0, 1.5, 0.7)
    iterations: int = 12
    min_points: int = 30
    depth_floor_m: float = 0.002
    grey_floor: float = 2.0
    photometric_weight: float = 1.0
    inlier_m: float = 0.015
    min_inlier_fraction: float = 0.5
    max_model_points: int = 3000
    min_ncc: float = 0.5
    # Grey-level spread (levels) below which appearance is not checked: a weakly textured
    # part's correlation at the true pose is too weak to vouch for anything (docs/accuracy.md).
    texture_floor: float = 10.0
    # Appearance is correlated in patches of the query image this many pixels wide, each
    # normalised on its own (``_appearance``).
    patch_px: float = 16.0
    min_patch_points: int = 8
    # Least share of the frame's part (its mask's points with depth) that a trusted alignment
    # explains (``_explained``): alignments within 1 cm of the truth explain more, wrong ones
    # less, apart from a part half hidden by another that swings in front (docs/accuracy.md).
    min_explained: float = 0.6
    reacquire_scales: tuple[float, ...] = (0.5, 0.75, 1.25, 1.5, 2.0, 2.5, 3.0)
    max_gap_steps: int = 8
    max_correction_rad: float = 0.35


def track_rigid(
    gray: np.ndarray,
    depth: np.ndarray,
    poses: np.ndarray,
    rgb_intrinsics: np.ndarray,
    depth_intrinsics: np.ndarray,
    allowed: Callable[[int], np.ndarray],
    query_frame: int,
    model_points: np.ndarray,
    params: RigidParams,
    init_motions: np.ndarray | None = None,
    occluders: Callable[[int], np.ndarray] | None = None,
) -> RigidTrackResult:
    """Align the part's query-frame surface to every frame.

    Args:
        gray: ``[T, H, W]`` uint8 grey frames (exposure-normalised).
        depth: ``[T, h, w]`` metres, NaN invalid.
        poses: ``[T, 4, 4]`` world_from_camera (canonical frame).
        rgb_intrinsics, depth_intrinsics: ``[T, 4]`` ``(fx, fy, cx, cy)``.
        allowed: ``t -> [H, W] bool`` where the part may be seen in frame ``t``.
        query_frame: the model's frame.
        model_points: ``[M, 3]`` world points of the part at the query frame.
        params: resolved parameters.
        init_motions: ``[T, 4, 4]`` optional starting motions (NaN where none), e.g. from 2D tracks.
        occluders: ``t -> [H, W] bool``, pixels in frame ``t`` of things that move on their own
            (the hand, the other parts), kept out of the grey levels' blur; None: a plain blur.
    """
    t_count = gray.shape[0]
    motions = np.full((t_count, 4, 4), np.nan)
    conf = np.zeros(t_count, bool)
    frac = np.zeros(t_count)
    rms = np.full(t_count, np.inf)
    motions[query_frame] = np.eye(4)
    conf[query_frame] = True
    frac[query_frame] = 1.0
    rms[query_frame] = 0.0
    xq = np.asarray(model_points, np.float64)
    if xq.shape[0] < params.min_points:
        return RigidTrackResult(motions, conf, frac, rms)
    if xq.shape[0] > params.max_model_points:
        xq = xq[np.random.default_rng(0).choice(xq.shape[0], params.max_model_points, replace=False)]
    nq = _normals(xq)
    cam_q = poses[query_frame][:3, 3]
    flip = np.sum(nq * (cam_q - xq), axis=1) < 0
    nq[flip] *= -1
    # The model's grey levels at every blur level, sampled at its query-frame pixels.
    q_frame = _Frame(gray[query_frame], depth[query_frame], allowed(query_frame), poses[query_frame],
                     rgb_intrinsics[query_frame], depth_intrinsics[query_frame], params.blur_sigmas,
                     None if occluders is None else occluders(query_frame))
    pc = xq @ q_frame.cam_from_world[:3, :3].T + q_frame.cam_from_world[:3, 3]
    fx, fy, cx, cy = rgb_intrinsics[query_frame]
    uq, vq = fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy
    tq_levels = [np.nan_to_num(_bilinear(img, uq, vq)) for img, _, _ in q_frame.levels]
    patches = _patches(uq, vq, params.patch_px)
    tree = cKDTree(xq)

    for step in (1, -1):
        prev, prev2 = np.eye(4), None
        gap = 0  # frames since the last confident one
        t = query_frame + step
        while 0 <= t < t_count:
            frame = _Frame(gray[t], depth[t], allowed(t), poses[t], rgb_intrinsics[t], depth_intrinsics[t],
                           params.blur_sigmas, None if occluders is None else occluders(t))
            starts = [prev]
            if prev2 is not None:
                vel = prev @ np.linalg.inv(prev2)
                starts.append(vel @ prev)
                starts.append(vel @ vel @ prev)
                # Re-acquisition after frames without a confident alignment (a hand over the
                # part, the face seen edge-on): the part kept moving meanwhile, so the motion
                # is predicted along its current screw (the last motion scaled), and the
                # constant velocity is extrapolated over the gap.
                for j in range(3, min(gap, params.max_gap_steps) + 3):
                    starts.append(np.linalg.matrix_power(vel, j) @ prev)
            if gap > 0:
                starts.extend(_scaled_motion(prev, f) for f in params.reacquire_scales)
                # Or the part is where it was in the query frame (a closed part stays closed
                # while another is opened), and the walk that led here had gone astray.
                starts.append(np.eye(4))
            if init_motions is not None and np.all(np.isfinite(init_motions[t])):
                starts.append(init_motions[t])
            seen = _seen_points(depth[t], allowed(t), poses[t], rgb_intrinsics[t], depth_intrinsics[t],
                                params.max_model_points)
            best, best_key = None, None
            for s in starts:
                out = _align_levels(frame, s, xq, nq, tq_levels, params, patches)
                # A start is a prediction of the motion; an alignment that wandered far from
                # every prediction is another surface that happens to fit (a door's back face,
                # seen once the door turned past the camera, fits its front face flipped
                # 180 degrees, grain and all), not the tracked one.
                ok = _passes(out, params) and _rotation_between(out[0], s) <= params.max_correction_rad
                ok = ok and _explained(seen, out[0], tree, xq, nq, params) >= params.min_explained
                # Passing alignments rank by appearance (depth cannot rank a plane's in-plane
                # slides and flips), the others by depth cost.
                key = (0, -_ncc_or(out[4], 1.0), out[1]) if ok else (1, out[1], 0.0)
                if best is None or key < best_key:
                    best, best_key = out, key
            m, _, f, r, _ = best
            motions[t], frac[t], rms[t] = m, f, r
            conf[t] = best_key[0] == 0
            if conf[t]:
                prev2, prev = prev, m
                gap = 0
            else:
                gap += 1
            t += step
    return RigidTrackResult(motions, conf, frac, rms)


def _seen_points(depth, allowed, pose, k_rgb, k_depth, max_points: int) -> np.ndarray:
    """``[N, 3]`` world points of the frame's allowed pixels with a depth (at most ``max_points``,
    a fixed random subset)."""
    ys, xs = np.nonzero(allowed)
    if xs.size > max_points:
        pick = np.random.default_rng(0).choice(xs.size, max_points, replace=False)
        xs, ys = xs[pick], ys[pick]
    pts, ok = lift_pixels(np.stack([xs, ys], -1).astype(np.float64), depth, None, k_rgb, k_depth, pose)
    return pts[ok]


def _explained(seen, motion, tree, xq, nq, params: RigidParams) -> float:
    """Share of the frame's part that the model moved by ``motion`` explains (1 when the frame
    shows too little of the part to tell).

    ``seen [N, 3]``: world points of the frame's part mask (``_seen_points``); ``tree``: a KD-tree
    of the model's points ``xq [M, 3]`` with normals ``nq [M, 3]`` (towards the query camera).
    A seen point is explained when it lies within ``inlier_m`` of a model point. Points farther
    than that behind the model's nearest surface are left out: they are parts of the part that
    the model does not hold (a drawer's inside, seen once it is open).
    """
    if seen.shape[0] < params.min_points:
        return 1.0
    inv = np.linalg.inv(motion)
    p = seen @ inv[:3, :3].T + inv[:3, 3]
    dist, idx = tree.query(p)
    near = dist < params.inlier_m
    counted = near | (np.sum((p - xq[idx]) * nq[idx], axis=1) > -params.inlier_m)
    if counted.sum() < params.min_points:
        return 1.0
    return float(near.sum() / counted.sum())


def _ncc_or(value: float, default: float) -> float:
    return default if not np.isfinite(value) else value


def _passes(out, params: RigidParams) -> bool:
    """An alignment is trusted when most visible model points fit the depth and, on a textured
    part, the grey levels agree too."""
    _, cost, f, r, ncc = out
    return bool(
        np.isfinite(cost) and f >= params.min_inlier_fraction and r < params.inlier_m / 2
        and _ncc_or(ncc, 1.0) >= params.min_ncc
    )


def _rotation_between(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (radians) of the rotation taking ``b``'s orientation to ``a``'s."""
    c = (np.trace(a[:3, :3] @ b[:3, :3].T) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def _scaled_motion(motion: np.ndarray, factor: float) -> np.ndarray:
    """``exp(factor log(motion))``: the same screw motion carried ``factor`` times as far."""
    rotvec = Rotation.from_matrix(motion[:3, :3]).as_rotvec()
    th = float(np.linalg.norm(rotvec))
    k = _hat(rotvec)
    if th < 1e-9:
        v = motion[:3, 3]
    else:
        vinv = np.eye(3) - 0.5 * k + (1 - th * np.sin(th) / (2 * (1 - np.cos(th)))) / th**2 * (k @ k)
        v = vinv @ motion[:3, 3]
    return _exp_se3(factor * np.concatenate([v, rotvec]))


def _align_levels(frame: _Frame, motion, xq, nq, tq_levels, params: RigidParams, patches: np.ndarray):
    """``_align`` with the model's grey levels taken at the matching blur level."""
    # _align runs every level with one grey vector; give it the level-wise vectors by running
    # one level at a time on a one-level view of the frame.
    out = (motion, np.inf, 0.0, np.inf, -1.0)
    levels = frame.levels
    m = motion
    for i in range(len(levels)):
        frame.levels = [levels[i]]
        out = _align(frame, m, xq, nq, tq_levels[i], params, patches)
        m = out[0]
        if not np.isfinite(out[1]):
            break
    frame.levels = levels
    return out
