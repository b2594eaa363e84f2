"""2D tracking of query points through a frame sequence, gated by the part and hand masks.

Two modes (``track_points_2d``):

Planar (a door, a drawer front: most query points on one 3D plane; ``_track_planar``). The
part's image motion is a homography of the query frame. Each step ``t -> t + d``: chained
pyramidal LK (started at the constant-velocity prediction, forward-backward checked) gives a
RANSAC homography; ``DenseAligner`` refines it over every pixel of the face (robust Gauss-Newton
with an exposure model); the two must agree (median ``anchor_max_shift_px``) or the direction
stops. Every point is then placed by the refined homography, so no error accumulates from
chaining, and LK's slide along a directional texture (a door's grain, parallel to its hinge,
which the joint fitter would read as screw motion) cannot enter the tracks. A point is reported
only if it falls in the allowed mask and its patch correlates with the warped template
(``ncc_min``; ``reacquire_ncc_min`` for a point coming back from occlusion).

Chained (anything else). LK frame to frame with the forward-backward check; a RANSAC homography
of the tracks warps the query frame into a template, against which each inlier is re-aligned by
LK (a drifted track moves by more than ``anchor_max_shift_px`` and stops; an occluded one fails
the NCC test); off-homography tracks keep their chained position; lost planar tracks can be
re-acquired with a stricter NCC and a round trip.

In both, a track must lie inside the (dilated) part mask and outside the (dilated) hand mask,
else it is lost in that frame: occluded points are reported lost, never slid onto the occluder.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class FlowParams:
    """The resolved pixel parameters of one tracking run (see ``TrackingConfig``)."""

    window_px: int
    pyramid_levels: int
    lk_iterations: int
    lk_min_eigen: float
    fb_threshold_px: float
    homography_threshold_px: float
    min_homography_points: int
    anchor_max_shift_px: float
    ncc_min: float
    reacquire: bool
    reacquire_ncc_min: float
    model_max_shift_px: float = 4.0


def to_gray(rgb: np.ndarray, reference: int | None) -> np.ndarray:
    """``[T, H, W, 3]`` uint8 -> ``[T, H, W]`` uint8 grey; with ``reference``, each frame's grey
    levels are scaled so that its median matches the reference frame's (exposure changes)."""
    gray = np.stack([cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY) for f in rgb])
    if reference is None:
        return gray
    med = np.array([max(float(np.median(g)), 1.0) for g in gray])
    gains = med[reference] / med
    out = np.empty_like(gray)
    for t, g in enumerate(gray):
        out[t] = g if abs(gains[t] - 1.0) < 1e-3 else np.clip(g * gains[t] + 0.5, 0, 255).astype(np.uint8)
    return out


def patches(image: np.ndarray, points: np.ndarray, radius: int) -> np.ndarray:
    """Bilinear patches ``[N, 2r+1, 2r+1]`` float32 of ``image`` centred on ``points [N, 2]``
    (zeros outside the image)."""
    k = 2 * radius + 1
    off = np.arange(-radius, radius + 1, dtype=np.float32)
    n = points.shape[0]
    mx = (points[:, 0, None, None].astype(np.float32) + off[None, None, :]) * np.ones((n, k, k), np.float32)
    my = (points[:, 1, None, None].astype(np.float32) + off[None, :, None]) * np.ones((n, k, k), np.float32)
    out = cv2.remap(
        image.astype(np.float32), mx.reshape(n * k, k), my.reshape(n * k, k), cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT, borderValue=0.0,
    )
    return out.reshape(n, k, k)


def ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation ``[N]`` of patch stacks ``[N, k, k]``. Two flat patches of the
    same grey level count as a match (1); one flat and one textured as no match (0)."""
    a = a.reshape(a.shape[0], -1).astype(np.float64)
    b = b.reshape(b.shape[0], -1).astype(np.float64)
    da = a - a.mean(1, keepdims=True)
    db = b - b.mean(1, keepdims=True)
    sa = np.sqrt((da**2).sum(1))
    sb = np.sqrt((db**2).sum(1))
    flat = 1.0 * np.sqrt(a.shape[1])  # ~1 grey level of standard deviation
    out = (da * db).sum(1) / np.maximum(sa * sb, 1e-9)
    both_flat = (sa < flat) & (sb < flat)
    out = np.where(both_flat, (np.abs(a.mean(1) - b.mean(1)) < 8.0).astype(float), out)
    out = np.where((sa < flat) ^ (sb < flat), 0.0, out)
    return out


def _lk(params: FlowParams, img0, img1, p0, p1=None, levels=None):
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, params.lk_iterations, 0.01)
    flags = 0
    if p1 is not None:
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        p1 = np.ascontiguousarray(p1, dtype=np.float32).reshape(-1, 1, 2).copy()
    out, st, _ = cv2.calcOpticalFlowPyrLK(
        img0, img1, np.ascontiguousarray(p0, dtype=np.float32).reshape(-1, 1, 2), p1,
        winSize=(params.window_px, params.window_px),
        maxLevel=params.pyramid_levels if levels is None else levels,
        criteria=crit, flags=flags, minEigThreshold=params.lk_min_eigen,
    )
    return out.reshape(-1, 2).astype(np.float64), st.reshape(-1).astype(bool)


def _inside(points: np.ndarray, width: int, height: int, margin: float = 0.0) -> np.ndarray:
    return (
        np.all(np.isfinite(points), axis=1)
        & (points[:, 0] >= margin) & (points[:, 0] <= width - 1 - margin)
        & (points[:, 1] >= margin) & (points[:, 1] <= height - 1 - margin)
    )


def _apply_h(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    ph = points @ h[:, :2].T + h[:, 2]
    return ph[:, :2] / ph[:, 2:3]


def _fit_homography(params: FlowParams, src: np.ndarray, dst: np.ndarray):
    if src.shape[0] < params.min_homography_points:
        return None, None
    h, inl = cv2.findHomography(
        src.astype(np.float64), dst.astype(np.float64), cv2.RANSAC, params.homography_threshold_px,
        maxIters=500, confidence=0.995,
    )
    if h is None or not np.all(np.isfinite(h)) or abs(h[2, 2]) < 1e-12:
        return None, None
    inl = inl.reshape(-1).astype(bool)
    # An orientation-reversing or degenerate warp is a failed fit (the face turned edge-on).
    if inl.sum() < params.min_homography_points or np.linalg.det(h[:2, :2] / h[2, 2]) <= 1e-4:
        return None, None
    return h, inl


def _sample(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples ``[M]`` of a float32 image at ``(u, v)`` (0 outside)."""
    return cv2.remap(
        image, u.astype(np.float32).reshape(-1, 1), v.astype(np.float32).reshape(-1, 1), cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT, borderValue=0.0,
    ).reshape(-1)


def _blur(image: np.ndarray, sigma: float) -> np.ndarray:
    img = image.astype(np.float32)
    return cv2.GaussianBlur(img, (0, 0), sigma) if sigma > 0 else img



class DenseAligner:
    """Dense, robust refinement of the query-to-frame homography over the part's pixels.

    Sparse LK tracks on a directional texture (wood grain, stripes) slide along the texture, and a
    homography fitted to them inherits the slide (it accumulates frame after frame). Every pixel of
    the part constrains the warp through its own gradient, so the whole region (grain wiggles,
    handle, panel edges) pins all eight parameters. Gauss-Newton on
    ``I_t(H x) - (a(x) T(x) + b)`` over the template pixels ``x`` (``a``: a gain affine in ``x``,
    for exposure and for shading that changes across the face as it moves; ``b`` an offset), Huber weights against occluders and off-plane pixels, and pixels whose warped
    position is not allowed (hand, outside the part) left out.
    """

    def __init__(self, template: np.ndarray, region: np.ndarray, max_pixels: int = 20000,
                 blur_sigmas: tuple[float, ...] = (0.7,)):
        ys, xs = np.nonzero(region)
        stride = max(1, int(np.ceil(np.sqrt(xs.size / max_pixels))))
        keep = (xs % stride == 0) & (ys % stride == 0)
        self.xy = np.stack([xs[keep], ys[keep]], -1).astype(np.float64)
        # One stage per blur: blur widens the basin of convergence, but blurring the template and
        # the frame with the same isotropic kernel is not warp-invariant under foreshortening
        # (refining from the true warp on the tiny door at 0.2-0.5 rad: median error 0.4 px with
        # sigma 1, 0.2 px with sigma 0.7; an unblurred last stage was worse on aliased renders).
        self.blur_sigmas = blur_sigmas
        self.values = [
            _blur(template, sigma)[ys[keep], xs[keep]].astype(np.float64) for sigma in blur_sigmas
        ]
        centre = self.xy.mean(0) if self.xy.size else np.zeros(2)
        scale = float(self.xy.std()) if self.xy.size else 1.0
        # Normalised template coordinates keep the normal equations well conditioned.
        self.norm = np.array([[1 / scale, 0, -centre[0] / scale], [0, 1 / scale, -centre[1] / scale], [0, 0, 1.0]])
        self.xn = self.xy @ self.norm[:2, :2].T + self.norm[:2, 2]

    def refine(self, frame: np.ndarray, allowed: np.ndarray, h: np.ndarray, iterations: int = 30):
        """``(h_refined [3, 3], fraction of pixels used)`` for ``frame`` (grey), starting at ``h``."""
        used = 0.0
        for stage in range(len(self.blur_sigmas)):
            h, used = self._refine_stage(stage, frame, allowed, h, iterations)
            if used == 0.0:
                break
        return h, used

    def _refine_stage(self, stage: int, frame: np.ndarray, allowed: np.ndarray, h: np.ndarray, iterations: int):
        n_px = self.xy.shape[0]
        if n_px < 64:
            return h, 0.0
        height, width = frame.shape
        img = _blur(frame, self.blur_sigmas[stage])
        values = self.values[stage]
        gx_img = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        gy_img = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        hn = h @ np.linalg.inv(self.norm)
        hn = hn / hn[2, 2]
        gain, offset = np.array([1.0, 0.0, 0.0]), 0.0
        x, y = self.xn[:, 0], self.xn[:, 1]
        used = 0.0
        for it in range(iterations):
            d = hn[2, 0] * x + hn[2, 1] * y + 1.0
            u = (hn[0, 0] * x + hn[0, 1] * y + hn[0, 2]) / d
            v = (hn[1, 0] * x + hn[1, 1] * y + hn[1, 2]) / d
            ok = (d > 0) & (u >= 1) & (u <= width - 2) & (v >= 1) & (v <= height - 2)
            iu = np.clip(np.rint(u), 0, width - 1).astype(np.int64)
            iv = np.clip(np.rint(v), 0, height - 1).astype(np.int64)
            ok &= allowed[iv, iu]
            used = float(ok.mean())
            if ok.sum() < 64:
                return h, used
            uo, vo, do, xo, yo, to = u[ok], v[ok], d[ok], x[ok], y[ok], values[ok]
            val = _sample(img, uo, vo)
            gx, gy = _sample(gx_img, uo, vo), _sample(gy_img, uo, vo)
            r = val - ((gain[0] + gain[1] * xo + gain[2] * yo) * to + offset)
            mad = float(np.median(np.abs(r - np.median(r)))) * 1.4826
            if it < 3:
                k = 1.345 * max(mad, 0.5)
                w = np.where(np.abs(r) <= k, 1.0, k / np.maximum(np.abs(r), 1e-12))
            else:
                # Redescending (Cauchy) once converging: a hand or revealed background must not
                # pull the warp, however many pixels it covers.
                w = 1.0 / (1.0 + (r / (2.385 * max(mad, 0.5))) ** 2)
            gp = -(gx * uo + gy * vo) / do
            jac = np.stack(
                [gx * xo / do, gx * yo / do, gx / do, gy * xo / do, gy * yo / do, gy / do,
                 gp * xo, gp * yo, -to, -to * xo, -to * yo, -np.ones_like(to)], -1,
            )
            jw = jac * w[:, None]
            a = jw.T @ jac
            b = -(jw.T @ r)
            scale = np.sqrt(np.maximum(np.diag(a), 1e-12))
            a_s = a / scale[:, None] / scale[None, :] + 1e-6 * np.eye(a.shape[0])
            try:
                delta = np.linalg.solve(a_s, b / scale) / scale
            except np.linalg.LinAlgError:
                return h, used
            hn = hn + np.array([[delta[0], delta[1], delta[2]], [delta[3], delta[4], delta[5]], [delta[6], delta[7], 0.0]])
            gain, offset = gain + delta[8:11], offset + delta[11]
            d2 = hn[2, 0] * x + hn[2, 1] * y + 1.0
            moved = np.hypot((hn[0, 0] * x + hn[0, 1] * y + hn[0, 2]) / d2 - u, (hn[1, 0] * x + hn[1, 1] * y + hn[1, 2]) / d2 - v)
            if not np.all(np.isfinite(hn)):
                return h, used
            if float(np.max(moved[ok])) < 1e-3:
                break
        out = hn @ self.norm
        return out / out[2, 2], used



def track_points_2d(
    gray: np.ndarray,
    allowed: Callable[[int], np.ndarray],
    query_frame: int,
    query_points: np.ndarray,
    params: FlowParams,
    query_region: np.ndarray | None = None,
    align_allowed: Callable[[int], np.ndarray] | None = None,
    model_homographies: np.ndarray | None = None,
) -> np.ndarray:
    """Track query points through every frame.

    Args:
        gray: ``[T, H, W]`` uint8 frames.
        allowed: ``t -> [H, W] bool``, where a track may be in frame ``t`` (the dilated part mask
            minus the dilated hand mask).
        query_frame: the frame the query points are in.
        query_points: ``[N, 2]`` (x, y) pixels in the query frame.
        params: resolved parameters.
        query_region: ``[H, W]`` bool, the planar face in the query frame: when given, planar
            mode (every point placed by the dense homography over this region; the query points
            must lie on that plane), else chained mode (see the module docstring).
        align_allowed: ``t -> [H, W] bool``, where the dense aligner may use pixels in frame
            ``t`` (planar mode; default ``allowed``): wider than ``allowed`` when the masks stop
            short of the part's outline, whose gradients pin the warp.
        model_homographies: ``[T, 3, 3]`` query-to-frame homographies predicted by the
            model-based 3D tracker (NaN where it did not align): planar mode starts the dense
            warp there, and vouches for it, where the chained LK fails (fast motion).

    Returns:
        ``[T, N, 2]`` float64 pixel positions, NaN where the track is lost.
    """
    t_count, height, width = gray.shape
    n = query_points.shape[0]
    pix = np.full((t_count, n, 2), np.nan)
    pts_q = np.asarray(query_points, dtype=np.float64)
    pix[query_frame] = pts_q
    radius = params.window_px // 2
    aligner = DenseAligner(gray[query_frame], query_region) if query_region is not None else None
    for step in (1, -1):
        if aligner is not None:
            _track_planar(gray, allowed, align_allowed or allowed, query_frame, pts_q, params, aligner, pix, step,
                          radius, model_homographies)
            continue
        on_plane = np.ones(n, bool)  # homography inlier when last seen (re-acquisition needs it)
        t = query_frame
        while 0 <= t + step < t_count:
            s = t + step
            allowed_s = allowed(s)
            new = np.full((n, 2), np.nan)
            idx_ok, p1 = _chain_step(params, gray[t], gray[s], pix[t], None)
            h, inl = _fit_homography(params, pts_q[idx_ok], p1)
            if h is None:
                new[idx_ok] = p1
            else:
                warped = cv2.warpPerspective(gray[query_frame], h, (width, height), flags=cv2.INTER_LINEAR)
                a_idx = idx_ok[inl]
                pred = _apply_h(h, pts_q[a_idx])
                pa, sta = _lk(params, warped, gray[s], pred, pred, levels=1)
                good = sta & (np.linalg.norm(pa - p1[inl], axis=1) < params.anchor_max_shift_px)
                good &= _inside(pa, width, height)
                if good.any():
                    corr = ncc(patches(warped, pred[good], radius), patches(gray[s], pa[good], radius))
                    good[np.nonzero(good)[0][corr < params.ncc_min]] = False
                new[a_idx[good]] = pa[good]
                # Off-plane points (a knob, a drawer's side) keep their chained position.
                new[idx_ok[~inl]] = p1[~inl]
                on_plane[a_idx] = True
                on_plane[idx_ok[~inl]] = False
                if params.reacquire:
                    _reacquire(params, gray[s], warped, h, pts_q, new, on_plane, allowed_s, radius)
            pix[s] = _gate(new, allowed_s)
            t = s
    return pix


def _gate(new: np.ndarray, allowed_s: np.ndarray) -> np.ndarray:
    """``new [N, 2]`` with the points outside the image or outside ``allowed_s`` set to NaN."""
    height, width = allowed_s.shape
    inside = _inside(new, width, height)
    keep = np.zeros(new.shape[0], bool)
    if inside.any():
        ij = np.rint(new[inside]).astype(np.int64)
        keep[np.nonzero(inside)[0]] = allowed_s[ij[:, 1], ij[:, 0]]
    out = new.copy()
    out[~keep] = np.nan
    return out


def _chain_step(params, img0, img1, pos0, guess):
    """Frame-to-frame LK of the finite rows of ``pos0 [N, 2]`` (``guess [N, 2]``: initial positions
    in ``img1`` or None) with the forward-backward check: ``(indices [M], positions [M, 2])``."""
    height, width = img1.shape
    idx = np.nonzero(np.isfinite(pos0[:, 0]))[0]
    if idx.size == 0:
        return idx, np.zeros((0, 2))
    p0 = pos0[idx]
    p1, st1 = _lk(params, img0, img1, p0, None if guess is None else guess[idx])
    pb, st2 = _lk(params, img1, img0, p1, p0 if guess is not None else None)
    ok = st1 & st2 & (np.linalg.norm(pb - p0, axis=1) < params.fb_threshold_px)
    ok &= _inside(p1, width, height)
    return idx[ok], p1[ok]


def _track_planar(gray, allowed, align_allowed, query_frame, pts_q, params, aligner, pix, step, radius,
                  model_h=None) -> None:
    """Planar mode, one direction (``step`` = +1 or -1), filling ``pix`` in place.

    The dense homography places every point; the chained LK only initialises it (RANSAC) and
    vouches for it (the two must agree). A point is reported where the homography puts it if it
    falls inside the allowed mask and its patch correlates with the warped template (``ncc_min``
    for a point seen in the previous frame, ``reacquire_ncc_min`` for one coming back from
    occlusion). A frame where the dense warp fails or disagrees with the chain ends the
    direction's tracking: every later frame would be predicted from an unverified warp.

    The template stays the query frame: replacing it by a later frame (a keyframe) when the
    face's image area changed by 1.5x made a closing drawer drift several times farther and
    did not extend a door's coverage.
    """
    t_count, height, width = gray.shape
    h_cur, h_old = np.eye(3), None
    t = query_frame
    while 0 <= t + step < t_count:
        s = t + step
        allowed_s = allowed(s)
        # Constant-velocity prediction of the warp: LK starts near the answer under fast motion.
        h_pred = h_cur if h_old is None else h_cur @ np.linalg.inv(h_old) @ h_cur
        guess = _apply_h(h_pred, pts_q)
        idx_ok, p1 = _chain_step(params, gray[t], gray[s], pix[t], guess)
        h0, _ = _fit_homography(params, pts_q[idx_ok], p1)
        init = h0 if h0 is not None else h_pred
        h, _ = _dense_warp(params, aligner, gray[s], align_allowed(s), init, pts_q, idx_ok, p1)
        if h is None and model_h is not None and np.all(np.isfinite(model_h[s])):
            # The chain lost the part (a door swung fast): the 3D model's alignment starts the
            # dense warp and vouches for it in the chain's place.
            hm = model_h[s]
            h, used = aligner.refine(gray[s], align_allowed(s), hm)
            shift = np.linalg.norm(_apply_h(h, pts_q) - _apply_h(hm, pts_q), axis=1)
            if used < 0.25 or not np.median(shift) < params.model_max_shift_px:
                h = None
        if h is None:
            return
        h_old, h_cur = h_cur, h
        warped = cv2.warpPerspective(gray[query_frame], h, (width, height), flags=cv2.INTER_LINEAR)
        pred = _apply_h(h, pts_q)
        new = _gate(pred, allowed_s)
        cand = np.nonzero(np.isfinite(new[:, 0]) & _inside(pred, width, height, margin=radius + 1))[0]
        new[:] = np.nan
        if cand.size:
            corr = ncc(patches(warped, pred[cand], radius), patches(gray[s], pred[cand], radius))
            seen = np.isfinite(pix[t, cand, 0])
            need = np.where(seen, params.ncc_min, params.reacquire_ncc_min if params.reacquire else np.inf)
            ok = corr >= need
            new[cand[ok]] = pred[cand[ok]]
        pix[s] = new
        t = s


def _dense_warp(params, aligner, frame, allowed_s, h_init, pts_q, idx_ok, p1):
    """The densely refined homography and the chained tracks that agree with it, or ``(None,
    None)`` when the chain and the dense warp disagree: one of them has slid (a face turning
    edge-on, a texture without structure across it), so the frame is not trusted."""
    if idx_ok.size < params.min_homography_points:
        return None, None
    h, used = aligner.refine(frame, allowed_s, h_init)
    if used < 0.25:
        return None, None
    err = np.linalg.norm(_apply_h(h, pts_q[idx_ok]) - p1, axis=1)
    inl = err < params.homography_threshold_px
    if np.median(err) >= params.anchor_max_shift_px:
        return None, None
    return h, inl


def _reacquire(params, frame, warped, h, pts_q, new, on_plane, allowed_s, radius) -> None:
    """Chained mode: fill lost tracks (in ``new``, in place) whose point the homography puts back
    in view, aligned to the warped template by LK with a round trip and a strict NCC."""
    height, width = frame.shape
    cand = np.nonzero(~np.isfinite(new[:, 0]) & on_plane)[0]
    if cand.size == 0:
        return
    pred = _apply_h(h, pts_q[cand])
    ok = _inside(pred, width, height, margin=radius + 1)
    ij = np.rint(np.where(ok[:, None], pred, 0)).astype(np.int64)
    ok &= allowed_s[ij[:, 1], ij[:, 0]]
    cand, pred = cand[ok], pred[ok]
    if cand.size == 0:
        return
    pa, sta = _lk(params, warped, frame, pred, pred, levels=1)
    pb, stb = _lk(params, frame, warped, pa, pred, levels=1)
    good = sta & stb & _inside(pa, width, height)
    good &= np.linalg.norm(pa - pred, axis=1) < params.anchor_max_shift_px
    good &= np.linalg.norm(pb - pred, axis=1) < params.fb_threshold_px
    if good.any():
        corr = ncc(patches(warped, pred[good], radius), patches(frame, pa[good], radius))
        good[np.nonzero(good)[0][corr < params.reacquire_ncc_min]] = False
    new[cand[good]] = pa[good]
