"""Tracks of points on a moving part through the dynamic recording, lifted to canonical 3D points.

``track_part_points`` picks the frame where the part is best seen, samples query points on it
(corners first, a grid where the part has little texture), tracks them through every frame with
``_flow.track_points_2d``, lifts each tracked pixel with the frame's depth and pose, and removes
3D samples that cannot be trusted (depth edges, low confidence, jumps faster than a hand moves a
part, tracks that are too short). A model-based 3D tracker (``_model_track``) aligns the part's
query-frame surface to every frame; it restarts the planar tracker's dense warp where chained LK
loses a fast-moving face, and where it is confident its placement of the query points replaces
the 2D tracks (which drift from frame to frame) and reaches frames the 2D tracker did not.
Whether a track is rigid with the rest of the part is left to
the joint estimator's RANSAC: filtering it here would only duplicate that work with less context.
"""

from __future__ import annotations

import cv2
import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.masks import MaskSequence
from artitwin_core.tracking._config import TrackingConfig
from artitwin_core.tracking._flow import FlowParams, to_gray, track_points_2d
from artitwin_core.tracking._lift import lift_pixels
from artitwin_core.tracking._model_track import RigidParams, track_rigid
from artitwin_core.tracking._types import Trajectories


def _disk(radius: int) -> np.ndarray:
    r = max(int(radius), 0)
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def _masks(capture: Capture, part_masks, part_label: int):
    """``(part [T, H, W] bool, other parts [T, H, W] bool, hand [T, H, W] bool or None,
    score [T])`` validated."""
    t_count, height, width = capture.rgb.shape[:3]
    if isinstance(part_masks, MaskSequence):
        labels, hand, score = part_masks.part, part_masks.hand, part_masks.score
    else:
        labels, hand, score = part_masks, None, None
    labels = np.asarray(labels)
    if labels.shape != (t_count, height, width):
        raise InputError(
            f"part masks have shape {labels.shape}; the capture's RGB frames need {(t_count, height, width)} "
            "(one label image per frame at RGB resolution)"
        )
    if hand is not None:
        hand = np.asarray(hand, dtype=bool)
        if hand.shape != labels.shape:
            raise InputError(f"MaskSequence.hand has shape {hand.shape}; expected {labels.shape} like .part")
    score = np.ones(t_count) if score is None else np.asarray(score, dtype=np.float64).reshape(-1)
    if score.shape != (t_count,):
        raise InputError(f"MaskSequence.score has {score.size} values; expected one per frame ({t_count})")
    return labels == part_label, (labels > 0) & (labels != part_label), hand, score


def choose_query_frame(
    part: np.ndarray, hand: np.ndarray | None, score: np.ndarray, erode_px: int, area_fraction: float = 1.0
) -> int:
    """The frame where the part is best seen: the first frame whose eroded, hand-free mask area
    times mask score reaches ``area_fraction`` of the best frame's.

    Args:
        part: ``[T, H, W]`` bool part mask.
        hand: ``[T, H, W]`` bool or None.
        score: ``[T]`` mask confidence in [0, 1].
        erode_px: erosion radius (pixels) applied before counting.
        area_fraction: 1 picks the largest area; less prefers earlier frames seen nearly as
            well (recordings start with the part closed).
    """
    kernel = _disk(erode_px)
    areas = np.zeros(part.shape[0])
    for t in range(part.shape[0]):
        m = part[t] if hand is None else part[t] & ~hand[t]
        areas[t] = cv2.erode(m.astype(np.uint8), kernel).sum() * max(float(score[t]), 0.0)
    return int(np.nonzero(areas >= area_fraction * areas.max())[0][0])


def sample_query_points(
    gray: np.ndarray,
    region: np.ndarray,
    max_points: int,
    min_distance_px: float,
    corner_quality: float,
) -> np.ndarray:
    """Query points ``[N, 2]`` (x, y) in ``region [H, W] bool``: Shi-Tomasi corners first (the
    points LK tracks best), then a regular grid over what is left of the region (low-texture
    parts), at least ``min_distance_px`` from every corner."""
    if not region.any():
        return np.zeros((0, 2))
    corners = cv2.goodFeaturesToTrack(
        gray, maxCorners=max_points, qualityLevel=corner_quality, minDistance=min_distance_px,
        mask=region.astype(np.uint8), blockSize=5,
    )
    pts = np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2).astype(np.float64)
    left = max_points - pts.shape[0]
    if left > 0:
        area = float(region.sum())
        spacing = max(min_distance_px, np.sqrt(area / max_points))
        ys, xs = np.mgrid[0:region.shape[0]:spacing, 0:region.shape[1]:spacing]
        grid = np.stack([xs.ravel(), ys.ravel()], -1)
        gx = np.clip(np.rint(grid[:, 0]).astype(int), 0, region.shape[1] - 1)
        gy = np.clip(np.rint(grid[:, 1]).astype(int), 0, region.shape[0] - 1)
        grid = grid[region[gy, gx]]
        if pts.shape[0] and grid.shape[0]:
            d2 = ((grid[:, None, :] - pts[None, :, :]) ** 2).sum(-1).min(1)
            grid = grid[d2 >= min_distance_px**2]
        pts = np.concatenate([pts, grid[:left]], 0)
    return pts


def _dominant_plane(points: np.ndarray, threshold_m: float, seed: int) -> np.ndarray | None:
    """``[4]`` plane ``(n, d)`` with ``n . x + d = 0`` (unit ``n``) holding most of ``points [N, 3]``
    within ``threshold_m`` (3-point RANSAC, least-squares refit on the inliers), or None."""
    n = points.shape[0]
    if n < 3:
        return None
    rng = np.random.default_rng(seed)
    best, best_count = None, 0
    for _ in range(200):
        a, b, c = points[rng.choice(n, 3, replace=False)]
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal)
        if norm < 1e-12:
            continue
        normal /= norm
        count = int(np.sum(np.abs((points - a) @ normal) < threshold_m))
        if count > best_count:
            best, best_count = np.append(normal, -normal @ a), count
    if best is None:
        return None
    inl = np.abs(points @ best[:3] + best[3]) < threshold_m
    centre = points[inl].mean(0)
    normal = np.linalg.svd(points[inl] - centre)[2][2]
    return np.append(normal, -normal @ centre)


def _reject_jumps(points: np.ndarray, valid: np.ndarray, times: np.ndarray, q: int, cfg: TrackingConfig) -> None:
    """Walking away from the query frame, drop samples farther from the last accepted one than the
    part can move in the elapsed time (in place). The query sample anchors each track."""
    t_count = points.shape[0]
    for step in (1, -1):
        last = points[q].copy()
        last_t = np.full(points.shape[1], times[q])
        t = q + step
        while 0 <= t < t_count:
            v = valid[t]
            limit = cfg.max_speed_m_per_s * np.abs(times[t] - last_t) + cfg.jump_margin_m
            jump = np.linalg.norm(points[t] - last, axis=1)
            bad = v & ~(jump <= limit)
            valid[t] &= ~bad
            upd = valid[t]
            last[upd] = points[t, upd]
            last_t[upd] = times[t]
            t += step


def _project(points: np.ndarray, world_from_camera: np.ndarray, intrinsics: np.ndarray, distortion) -> np.ndarray:
    """RGB pixels ``[N, 2]`` of world points ``[N, 3]`` (NaN behind the camera)."""
    cam_from_world = np.linalg.inv(world_from_camera)
    pc = points @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    out = np.full((points.shape[0], 2), np.nan)
    front = pc[:, 2] > 1e-6
    if not front.any():
        return out
    if distortion is None:
        out[front] = np.stack([fx * pc[front, 0] / pc[front, 2] + cx, fy * pc[front, 1] / pc[front, 2] + cy], -1)
        return out
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    uv, _ = cv2.projectPoints(pc[front], np.zeros(3), np.zeros(3), k, np.asarray(distortion, np.float64))
    out[front] = uv.reshape(-1, 2)
    return out


def _model_homographies(model, q, query, points_q, poses, capture) -> np.ndarray:
    """``[T, 3, 3]`` query-to-frame homographies of the query points moved by the model's
    motions (least squares over the points; NaN where the model did not align)."""
    t_count = model.motions.shape[0]
    out = np.full((t_count, 3, 3), np.nan)
    for t in range(t_count):
        if not model.confident[t] or query.shape[0] < 8:
            continue
        m = model.motions[t]
        uv = _project(points_q @ m[:3, :3].T + m[:3, 3], poses[t], capture.rgb_intrinsics[t], capture.distortion)
        ok = np.all(np.isfinite(uv), axis=1)
        if ok.sum() < 8:
            continue
        h, _ = cv2.findHomography(query[ok], uv[ok], 0)
        if h is not None and np.all(np.isfinite(h)):
            out[t] = h
    return out


def _fill_from_model(res, q, points_q, pix, points, valid, allowed, lift, capture, poses, cfg) -> None:
    """Tracks in frames where the model-based tracker aligned the part (in place).

    Where the model is confident, a query point moved by the frame's rigid motion gives its
    pixel; its 3D sample is the frame's depth at that pixel (measured, like any track), kept
    only when it lies within ``model_depth_gate_m`` of the moved point (else the point is
    occluded or off the surface). Such a sample replaces the 2D track's: the model is aligned to
    each frame directly, while the 2D chain accumulates drift from frame to frame (a drawer's
    tracks crept 1 px up as it slid out, 5-7 mm at 0.25 m, and tilted its axis 1.2 deg; 0.08
    with the model's samples). A 2D track that disagrees
    with the model by more than the gate and has no model sample is dropped.
    """
    t_count = pix.shape[0]
    for t in range(t_count):
        if not res.confident[t] or t == q:
            continue
        m = res.motions[t]
        moved = points_q @ m[:3, :3].T + m[:3, 3]
        uv = _project(moved, poses[t], capture.rgb_intrinsics[t], capture.distortion)
        allowed_t = allowed(t)
        h_img, w_img = allowed_t.shape
        inside = np.all(np.isfinite(uv), 1) & (uv[:, 0] >= 0) & (uv[:, 0] <= w_img - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h_img - 1)
        ij = np.rint(np.where(inside[:, None], uv, 0)).astype(np.int64)
        inside &= allowed_t[ij[:, 1], ij[:, 0]]
        p, ok = lift(t, np.where(inside[:, None], uv, np.nan))
        ok &= inside & (np.linalg.norm(p - moved, axis=1) < cfg.model_depth_gate_m)
        disagree = valid[t] & (np.linalg.norm(np.nan_to_num(points[t]) - moved, axis=1) >= cfg.model_depth_gate_m)
        fill = ok
        pix[t, fill] = uv[fill]
        points[t, fill] = p[fill]
        valid[t, fill] = True
        drop = disagree & ~fill
        valid[t, drop] = False


def track_part_points(
    capture: Capture,
    part_masks: np.ndarray | MaskSequence,
    canonical_from_session: np.ndarray,
    *,
    part_label: int = 1,
    config: TrackingConfig | None = None,
) -> Trajectories:
    """Track points of one moving part through a recording and lift them to canonical 3D points.

    Args:
        capture: the dynamic recording (``rgb [T, H, W, 3]``, ``depth [T, h, w]`` metres, poses
            ``world_from_camera [T, 4, 4]`` in its session frame, OpenCV axes).
        part_masks: ``[T, H, W]`` uint8 labels at RGB resolution (0 = not a part, k + 1 = part k),
            or a ``MaskSequence`` (its hand mask then keeps tracks off the hand and its score
            weighs the choice of the query frame).
        canonical_from_session: ``[4, 4]`` maps the recording's session frame into the canonical
            frame (the registration's output).
        part_label: which label of ``part_masks`` to track (k + 1 for part k).
        config: hyperparameters; ``TrackingConfig()`` when None.

    Returns:
        ``Trajectories`` over the capture's frames (frame t = ``capture`` frame t):
        ``points_in_world [T, N, 3]`` metres in the canonical frame, ``pixels [T, N, 2]`` RGB
        pixels, both NaN where ``valid [T, N]`` is False, and ``query_frame``, where every track
        is valid. N may be 0 when nothing on the part could be tracked. The query frame is where
        the part is best seen (for a drawer, often open): ``estimate_joint`` defines ``q = 0`` at
        its ``reference_frame``, so pass it a closed frame that has tracks, not necessarily
        ``query_frame``. Tracks on a door's front stop once the front turns away from the camera;
        frames after that have no valid tracks.

    Raises:
        InputError: mask shapes do not match the capture, the label is absent from every frame,
            or ``canonical_from_session`` is not a 4x4 matrix.
    """
    cfg = config if config is not None else TrackingConfig()
    t_count, height, width = capture.rgb.shape[:3]
    c_from_s = np.asarray(canonical_from_session, dtype=np.float64)
    if c_from_s.shape != (4, 4) or not np.all(np.isfinite(c_from_s)):
        raise InputError(f"canonical_from_session must be a finite 4x4 matrix, got shape {c_from_s.shape}")
    part, others, hand, score = _masks(capture, part_masks, part_label)
    if not part.any():
        raise InputError(f"part label {part_label} appears in no frame of the masks; check part_label")
    sc = cfg.scaled(width)

    q = choose_query_frame(part, hand, score, int(sc["erode_px"]), cfg.query_area_fraction)
    gray = to_gray(capture.rgb, q if cfg.normalize_exposure else None)
    region = cv2.erode(part[q].astype(np.uint8), _disk(int(sc["erode_px"]))).astype(bool)
    if hand is not None:
        region &= ~cv2.dilate(hand[q].astype(np.uint8), _disk(int(sc["hand_margin_px"]))).astype(bool)
    # The dense warp uses the whole part, its outline included: the outline's gradients are what
    # pins the warp along a directional texture (a door's grain runs parallel to its hinge).
    # A segmenter's mask may stop short of the outline; the aligner's region is widened by
    # ``align_margin_px`` so that the outline is in it (what lies beyond is the static frame
    # around a closed part, coplanar with it, or is rejected as off-plane or by robust weights).
    align_region = cv2.dilate(part[q].astype(np.uint8), _disk(int(sc["align_margin_px"]))).astype(bool)
    if hand is not None:
        align_region &= ~cv2.dilate(hand[q].astype(np.uint8), _disk(int(sc["hand_margin_px"]))).astype(bool)
    query = sample_query_points(gray[q], region, cfg.max_points, float(sc["min_distance_px"]), cfg.corner_quality)

    poses = c_from_s @ np.asarray(capture.world_from_camera, dtype=np.float64)
    conf = capture.confidence

    def lift(t: int, pixels: np.ndarray):
        return lift_pixels(
            pixels, capture.depth[t], None if conf is None else conf[t], capture.rgb_intrinsics[t],
            capture.depth_intrinsics[t], poses[t], capture.distortion, cfg.depth_edge_rel, cfg.min_confidence,
        )

    # Query points need a trustworthy 3D position in the query frame: it anchors the track.
    points_q, ok_q = lift(q, query)
    query, points_q = query[ok_q], points_q[ok_q]

    # Planar mode: when most of the part's points lie on one plane (a door, a drawer front), its
    # image motion is a homography that the dense aligner can pin down; points off that plane
    # (a drawer's inside walls) would be placed wrongly by it, so they are not tracked then.
    plane = _dominant_plane(points_q, cfg.plane_threshold_m, cfg.seed)
    align = None
    if plane is not None and query.shape[0]:
        on = np.abs(points_q @ plane[:3] + plane[3]) < cfg.plane_threshold_m
        if on.mean() >= cfg.min_plane_fraction:
            query, points_q = query[on], points_q[on]
            ys, xs = np.nonzero(align_region)
            pts_all, ok_all = lift(q, np.stack([xs, ys], -1).astype(np.float64))
            off = ok_all & (np.abs(pts_all @ plane[:3] + plane[3]) >= cfg.plane_threshold_m)
            align = align_region.copy()
            align[ys[off], xs[off]] = False

    def allowed(t: int, dilate_px: int = int(sc["mask_dilate_px"])) -> np.ndarray:
        m = cv2.dilate(part[t].astype(np.uint8), _disk(dilate_px)).astype(bool)
        if hand is not None:
            m &= ~cv2.dilate(hand[t].astype(np.uint8), _disk(int(sc["hand_margin_px"]))).astype(bool)
        return m

    def align_allowed(t: int) -> np.ndarray:
        return allowed(t, int(sc["align_margin_px"]) + int(sc["mask_dilate_px"]))

    params = FlowParams(
        window_px=int(sc["window_px"]), pyramid_levels=cfg.pyramid_levels, lk_iterations=cfg.lk_iterations,
        lk_min_eigen=cfg.lk_min_eigen, fb_threshold_px=cfg.fb_threshold_px,
        homography_threshold_px=cfg.homography_threshold_px, min_homography_points=cfg.min_homography_points,
        anchor_max_shift_px=cfg.anchor_max_shift_px, ncc_min=cfg.ncc_min, reacquire=cfg.reacquire,
        reacquire_ncc_min=cfg.reacquire_ncc_min, model_max_shift_px=max(2.0, width / 64),
    )
    model = None
    if cfg.model_tracking and query.shape[0]:
        # The whole part, outline included (the outline's contrast pins motion along a
        # directional texture, such as grain parallel to a door's hinge).
        model_region = part[q] if hand is None else part[q] & ~hand[q]
        model_px = np.stack(np.nonzero(model_region)[::-1], -1).astype(np.float64)
        model_pts, model_ok = lift(q, model_px)

        def occluders(t: int) -> np.ndarray:
            # As labelled, without the hand's tracking margin: the margin covers the part's own
            # pixels around the hand (a drawer's handle), whose contrast pins the part (with it,
            # an open drawer sat low).
            return others[t] if hand is None else others[t] | hand[t]

        model = track_rigid(
            gray, capture.depth, poses, capture.rgb_intrinsics, capture.depth_intrinsics, allowed, q,
            model_pts[model_ok], RigidParams(max_model_points=cfg.model_points, patch_px=float(sc["patch_px"])),
            occluders=occluders,
        )
    model_h = None if model is None or align is None else _model_homographies(model, q, query, points_q, poses, capture)
    pix = (
        track_points_2d(gray, allowed, q, query, params, align, align_allowed, model_h)
        if query.shape[0] else np.zeros((t_count, 0, 2))
    )

    n = pix.shape[1]
    points = np.full((t_count, n, 3), np.nan)
    valid = np.zeros((t_count, n), bool)
    for t in range(t_count):
        tracked = np.isfinite(pix[t, :, 0])
        if tracked.any():
            p, ok = lift(t, pix[t, tracked])
            points[t, tracked] = p
            valid[t, tracked] = ok
    if model is not None and n:
        _fill_from_model(model, q, points_q, pix, points, valid, allowed, lift, capture, poses, cfg)
    times = np.asarray(capture.timestamps, dtype=np.float64)
    if times.shape != (t_count,) or not np.all(np.isfinite(times)):
        times = np.arange(t_count, dtype=np.float64) / 30.0
    _reject_jumps(points, valid, times, q, cfg)
    keep = valid.sum(0) >= min(cfg.min_valid_frames, t_count)
    points, valid, pix = points[:, keep], valid[:, keep], pix[:, keep]
    points[~valid] = np.nan
    pix = pix.astype(np.float32)
    pix[~valid] = np.nan
    return Trajectories(points_in_world=points, pixels=pix, valid=valid, query_frame=q)
