"""Register the dynamic recording's session frame onto the canonical (static) frame.

Stages: fuse each recording's depth into a cloud; hypotheses come from the recorded poses (the
identity, a session begun where the other began or ended) and from a global yaw sweep about the
shared gravity (:mod:`._global`); each is refined by point-to-plane ICP with a Tukey kernel that
estimates yaw and translation only (:mod:`._gravity_icp`: both sessions measure gravity), and
scored by where its dynamic points fall in what the static recording saw (:mod:`._evidence`): on
its surfaces, in space it saw through, or where it never looked. The best-supported hypothesis
is refined at finer voxels, the finest letting the tilt move within the sensors' few tenths of a
degree; a photometric refinement against the static images finishes (:mod:`._photometric`), so
texture pins what the geometry leaves free (a slide along a cabinet front or a long wall). When
no hypothesis is convincing (too little overlap, space seen empty, a runner-up nearly as good,
or matches that leave a direction free) :class:`RegistrationError` says so with the numbers,
rather than handing the later stages a placement that turns the whole room into moving parts.
The refined placement must also carry the same texture as the static surfaces it lands on
(:mod:`._texture`): a corner of the room that the static sweep never saw fits another
corner's walls and floor perfectly, and only the texture tells them apart.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.geometry import axis_angle_to_matrix
from artitwin_core.registration._clouds import frame_points, fused_cloud
from artitwin_core.registration._config import RegistrationConfig
from artitwin_core.registration._evidence import (
    ScoringData,
    colour_agreement,
    depth_views,
    evenly_spaced,
    motion_scale,
    on_surface,
    score_hypothesis,
    seen_side,
    weakest_constraint,
)
from artitwin_core.registration._global import gravity_basis, pose_hypotheses, yaw_candidates
from artitwin_core.registration._gravity_icp import PlaneTarget, gravity_icp, tilt_of, tilt_vector
from artitwin_core.registration._photometric import photometric_refine
from artitwin_core.registration._texture import luminance, surface_groups
from artitwin_core.registration._types import (
    HypothesisScore,
    RegistrationError,
    RegistrationResult,
)

_reg = o3d.pipelines.registration


def _icp(source, target, init: np.ndarray, voxel: float, iterations: int = 30):
    est = _reg.TransformationEstimationPointToPlane(_reg.TukeyLoss(k=1.5 * voxel))
    crit = _reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=iterations)
    return _reg.registration_icp(source, target, 2.5 * voxel, init, est, crit)


def _point_to_plane_stats(source, target, transform: np.ndarray, inlier_m: float) -> tuple[float, float]:
    """Median |point-to-plane| distance of inliers (metres) and the inlier fraction."""
    pts = np.asarray(source.points) @ transform[:3, :3].T + transform[:3, 3]
    tree = o3d.geometry.KDTreeFlann(target)
    tp, tn = np.asarray(target.points), np.asarray(target.normals)
    dist = np.full(len(pts), np.inf)
    for i, p in enumerate(pts):
        k, idx, d2 = tree.search_knn_vector_3d(p, 1)
        if k and d2[0] < (3 * inlier_m) ** 2:
            dist[i] = abs((p - tp[idx[0]]) @ tn[idx[0]])
    inl = dist < inlier_m
    residual = float(np.median(dist[inl])) if inl.any() else float("inf")
    return residual, float(inl.mean())


def _surface_noise_m(cloud: o3d.geometry.PointCloud, voxel: float) -> float:
    """Robust spread (metres) of a fused cloud about its local planes: the median over points of
    the RMS distance of their neighbours within ``3 * voxel`` to the neighbours' best plane
    (depth noise left after voxel averaging, plus the surfaces' own curvature)."""
    pts = np.asarray(cloud.points)
    if len(pts) < 50:
        return 0.0
    rng = np.random.default_rng(0)
    sample = pts[rng.choice(len(pts), size=min(len(pts), 3000), replace=False)]
    tree = cKDTree(pts)
    spreads = []
    for p in sample:
        idx = tree.query_ball_point(p, 3 * voxel)
        if len(idx) < 10:
            continue
        nb = pts[idx] - pts[idx].mean(0)
        spreads.append(np.sqrt(max(np.linalg.eigvalsh(nb.T @ nb / len(idx))[0], 0.0)))
    return float(np.median(spreads)) if spreads else 0.0


def _consistent_frames(static_tree: cKDTree, dynamic: Capture, transform: np.ndarray, cfg: RegistrationConfig):
    """Dynamic frames whose share of points far (> 5 cm) from the static cloud is within
    ``consistent_frame_margin`` of the lowest share; at least ``min_consistent_frames``."""
    far = np.zeros(dynamic.num_frames)
    for t in range(dynamic.num_frames):
        p, _ = frame_points(dynamic, t, stride=2 * cfg.pixel_stride, max_depth_m=cfg.max_depth_m,
                            min_confidence=cfg.min_confidence)
        if len(p) == 0:
            far[t] = 1.0
            continue
        d, _ = static_tree.query(p @ transform[:3, :3].T + transform[:3, 3], workers=-1)
        far[t] = float(np.mean(d > 0.05))
    keep = np.nonzero(far <= far.min() + cfg.consistent_frame_margin)[0]
    if len(keep) < cfg.min_consistent_frames:
        keep = np.sort(np.argsort(far)[: cfg.min_consistent_frames])
    return keep


def _check_capture(capture: Capture, name: str) -> None:
    t = capture.num_frames
    if t < 1 or capture.depth.ndim != 3 or capture.world_from_camera.shape != (t, 4, 4):
        raise InputError(
            f"register_recordings: the {name} recording needs depth [T, h, w] and world_from_camera "
            f"[T, 4, 4] with T >= 1; got depth {capture.depth.shape}, poses {capture.world_from_camera.shape}."
        )


def register_recordings(
    static: Capture,
    dynamic: Capture,
    *,
    gravity=(0.0, -1.0, 0.0),
    config: RegistrationConfig | None = None,
) -> RegistrationResult:
    """Find ``canonical_from_session``: the dynamic recording's session frame in the static one's.

    Args:
        static: the recording before anything moved; its world frame is the canonical frame.
        dynamic: the recording in which a part moves, in its own AR session frame.
        gravity: ``[3]`` direction of gravity in both session frames (ARKit: ``(0, -1, 0)``).
        config: hyperparameters; defaults suit a room-scale LiDAR capture.

    Returns:
        A :class:`RegistrationResult` with the transform, the residual (metres), the inlier
        fraction, the scored hypotheses and per-stage diagnostics.

    Raises:
        RegistrationError: no hypothesis is convincing (see ``RegistrationConfig.min_overlap``
            and the tests after it); the message names the numbers and what to do.
        InputError: malformed recordings or gravity.
    """
    cfg = config or RegistrationConfig()
    _check_capture(static, "static")
    _check_capture(dynamic, "dynamic")
    g = np.asarray(gravity, dtype=np.float64)
    if g.shape != (3,) or not np.linalg.norm(g) > 0:
        raise InputError(f"register_recordings: gravity must be a non-zero 3-vector, got {gravity!r}.")
    up = -g / np.linalg.norm(g)
    diagnostics: dict = {}
    t0 = time.perf_counter()

    n_dyn = dynamic.num_frames
    keep = np.where(np.arange(n_dyn) < max(1, n_dyn // 3), 1.0, 1.0 / max(cfg.early_frame_weight, 1.0))
    clouds = _Clouds(static, dynamic, keep, up, cfg)
    diagnostics["fuse"] = {"seconds": time.perf_counter() - t0, "static_points": len(clouds.base_s.points),
                           "dynamic_points": len(clouds.base_d.points), "surface_noise_m": clouds.noise}
    best, rival, distinct, score = _global_placement(static, dynamic, clouds, g, up, keep, cfg, diagnostics)
    transform = _fine_placement(static, dynamic, clouds, best.canonical_from_session, score, up, cfg, diagnostics)

    final = score(best.name, transform)
    tilt_deg = float(np.rad2deg(tilt_of(transform, up)))
    diagnostics["final"] = {**final.as_dict(), "tilt_deg": tilt_deg, "yaw_deg": _yaw_deg(transform, up)}
    # The texture is compared at the refined placement: a few centimetres off, as the coarse
    # stages leave it, fine texture (poster stripes, floor boards) no longer lines up.
    failed = _texture_refusal(final, cfg)
    diagnostics["verdict"]["failed"] += failed
    if failed and cfg.refuse_unconvincing:
        raise RegistrationError(_refusal_message(final, rival, failed, cfg), (final, *distinct[1:]), tuple(failed))
    s, d = clouds.at(clouds.finest)
    residual, inliers = _point_to_plane_stats(d, s, transform, cfg.inlier_distance_m)
    covariance = None
    if cfg.uncertainty_blocks >= 3:
        t4 = time.perf_counter()
        covariance = _block_jackknife(d, s, np.asarray(transform), clouds.finest, cfg.uncertainty_blocks)
        diagnostics["uncertainty"] = {"seconds": time.perf_counter() - t4, "blocks": cfg.uncertainty_blocks}
    diagnostics["total_seconds"] = time.perf_counter() - t0
    return RegistrationResult(
        canonical_from_session=np.asarray(transform, dtype=np.float64),
        residual_m=residual,
        inlier_fraction=inliers,
        diagnostics=diagnostics,
        covariance=covariance,
        hypotheses=tuple(distinct),
        tilt_deg=tilt_deg,
    )


class _Clouds:
    """Both recordings' depth fused into clouds, with normals and plane targets at each ICP voxel
    size made on first use and kept (refusing the dynamic cloud from fewer frames clears them)."""

    def __init__(self, static: Capture, dynamic: Capture, keep: np.ndarray, up: np.ndarray, cfg: RegistrationConfig):
        self.cfg, self.up = cfg, up
        self.common = dict(stride=cfg.pixel_stride, max_depth_m=cfg.max_depth_m, min_confidence=cfg.min_confidence)
        self.clouds: dict[float, tuple] = {}
        self.targets: dict[float, PlaneTarget] = {}
        self.finest = min(cfg.icp_voxels_m)
        self.base_s = fused_cloud(static, range(static.num_frames), voxel_m=self.finest, **self.common)
        self.base_d = fused_cloud(dynamic, range(dynamic.num_frames), voxel_m=self.finest, keep_fraction=keep, **self.common)
        # Normals from neighbourhoods wide enough for the depth noise: a plane fitted within 3 voxels
        # of a surface whose noise is comparable tilts with the noise, and point-to-plane ICP then
        # slides (a centimetre off at the furniture at high depth noise with 3 cm neighbourhoods).
        self.noise = _surface_noise_m(self.base_s, self.finest) if cfg.normal_noise_radii > 0 else 0.0

    def at(self, voxel: float):
        """The static and dynamic clouds at ``voxel`` metres, with normals."""
        if voxel not in self.clouds:
            s = self.base_s if voxel == self.finest else self.base_s.voxel_down_sample(voxel)
            d = self.base_d if voxel == self.finest else self.base_d.voxel_down_sample(voxel)
            radius = max(3 * voxel, self.cfg.normal_noise_radii * self.noise)
            for c in (s, d):
                c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=int(30 * (radius / (3 * voxel)) ** 2)))
            self.clouds[voxel] = (s, d)
        return self.clouds[voxel]

    def target(self, voxel: float) -> PlaneTarget:
        """The static cloud at ``voxel`` as a point-to-plane target."""
        if voxel not in self.targets:
            s, _ = self.at(voxel)
            self.targets[voxel] = PlaneTarget.of(np.asarray(s.points), np.asarray(s.normals))
        return self.targets[voxel]

    def icp(self, voxel: float, init: np.ndarray):
        """Gravity-constrained ICP of the dynamic cloud onto the static one at ``voxel``."""
        _, d = self.at(voxel)
        return gravity_icp(np.asarray(d.points), self.target(voxel), init, self.up, max_distance_m=2.5 * voxel, kernel_m=1.5 * voxel)

    def refuse_dynamic(self, dynamic: Capture, frames) -> None:
        """Fuse the dynamic cloud again from ``frames`` only."""
        self.base_d = fused_cloud(dynamic, frames, voxel_m=self.finest, **self.common)
        self.clouds.clear()
        self.targets.clear()


def _global_placement(
    static: Capture,
    dynamic: Capture,
    clouds: _Clouds,
    g: np.ndarray,
    up: np.ndarray,
    keep: np.ndarray,
    cfg: RegistrationConfig,
    diagnostics: dict,
):
    """Global: hypotheses from the recorded poses and the yaw sweep, each refined (yaw and
    translation only) on the coarse clouds and scored against what the static recording saw.

    Returns the best distinct hypothesis, its rival (or None), the distinct hypotheses and the
    scoring function; raises :class:`RegistrationError` when the best is not convincing."""
    t1 = time.perf_counter()
    gs, gd = clouds.at(cfg.icp_voxels_m[0])
    cands = yaw_candidates(
        np.asarray(gs.points), np.asarray(gs.normals), np.asarray(gd.points), np.asarray(gd.normals), g,
        yaw_step_deg=cfg.yaw_step_deg, cell_m=cfg.grid_cell_m, height_bin_m=cfg.height_bin_m,
        num_slabs=cfg.num_slabs, num_candidates=cfg.num_candidates, peaks_per_yaw=cfg.peaks_per_yaw,
    )
    hypotheses = pose_hypotheses(static.world_from_camera, dynamic.world_from_camera, g)
    hypotheses += [(f"yaw sweep {c.yaw_deg:.0f} deg" + (f", peak {c.peak + 1}" if c.peak else ""), c.canonical_from_session)
                   for c in cands]
    score = _Scorer(_scoring_data(static, dynamic, clouds, up, keep, cfg), up, cfg)
    scored = []
    for name, m in hypotheses:
        for voxel in cfg.icp_voxels_m[:2]:
            m = clouds.icp(voxel, m).transform
        scored.append(score(name, m))
    scored.sort(key=lambda h: h.support, reverse=True)
    distinct = _distinct(scored, np.asarray(gd.points), cfg.distinct_hypothesis_m)
    rival = _rival(distinct, np.asarray(gd.points), cfg)
    best = distinct[0]
    diagnostics["global"] = {
        "seconds": time.perf_counter() - t1,
        "chosen": best.name,
        "yaw_deg": _yaw_deg(best.canonical_from_session, up),
        "hypotheses": [h.as_dict() for h in scored],
    }
    failed = _refusals(best, rival, cfg)
    diagnostics["verdict"] = {"failed": list(failed), "rival": rival.name if rival else None,
                              "rival_support": rival.support if rival else None, "rival_ratio": _ratio(best, rival)}
    if failed and cfg.refuse_unconvincing:
        raise RegistrationError(_refusal_message(best, rival, failed, cfg), tuple(distinct), tuple(failed))
    return best, rival, distinct, score


@dataclass(frozen=True)
class _Scorer:
    """Scores placements (canonical_from_session) against ``data``."""

    data: ScoringData
    up: np.ndarray
    cfg: RegistrationConfig

    def __call__(self, name: str, m: np.ndarray) -> HypothesisScore:
        return score_hypothesis(name, m, self.data, self.up, inlier_m=self.cfg.inlier_distance_m,
                                margin_m=self.cfg.free_space_margin_m, back_face_cos=self.cfg.back_face_cos)

    def colour(self, m: np.ndarray) -> tuple[float, float]:
        """``(colour agreement, contrast)`` of placement ``m`` (:func:`colour_agreement`)."""
        return colour_agreement(m, self.data, inlier_m=self.cfg.inlier_distance_m)


def _scoring_data(
    static: Capture, dynamic: Capture, clouds: _Clouds, up: np.ndarray, keep: np.ndarray, cfg: RegistrationConfig
) -> ScoringData:
    """What a hypothesis is scored against: the static surface and views, a few dynamic frames."""
    view_args = dict(stride=2 * cfg.pixel_stride, max_depth_m=cfg.max_depth_m, min_confidence=cfg.min_confidence)
    scored_frames = evenly_spaced(dynamic.num_frames, cfg.score_views)
    # Matched at the third level: normals fine enough for the point-to-plane inlier test.
    surface_voxel = cfg.icp_voxels_m[min(2, len(cfg.icp_voxels_m) - 1)]
    surface = clouds.target(surface_voxel)
    scored_points = [frame_points(dynamic, int(t), **view_args) for t in scored_frames]
    static_views = depth_views(static, cfg.score_views, **view_args)
    return ScoringData(
        static_surface=surface,
        static_views=static_views,
        static_points=np.asarray(clouds.at(cfg.icp_voxels_m[min(1, len(cfg.icp_voxels_m) - 1)])[0].points),
        dynamic_points=tuple(p for p, _ in scored_points),
        dynamic_views=depth_views(dynamic, cfg.score_views, **view_args),
        frame_weights=keep[scored_frames],
        static_luminance=luminance(np.asarray(clouds.at(surface_voxel)[0].colors)),
        static_groups=surface_groups(surface.points, surface.normals, up),
        dynamic_luminance=tuple(luminance(c) for _, c in scored_points),
        static_facing=seen_side(surface.points, depth_views(static, cfg.score_views, **view_args, farthest=True),
                                margin_m=cfg.free_space_margin_m) if cfg.back_face_cos is not None else None,
    )


def _fine_placement(
    static: Capture,
    dynamic: Capture,
    clouds: _Clouds,
    transform: np.ndarray,
    score: _Scorer,
    up: np.ndarray,
    cfg: RegistrationConfig,
    diagnostics: dict,
) -> np.ndarray:
    """The global placement ``transform`` refined on the consistent frames: full ICP at the finer
    voxel sizes, then the tilt, the texture search and the photometric refinement where
    configured."""
    # Frames in which the part has not moved yet agree with the static scene everywhere; frames
    # with the part open see new surface (the moved part, the inside). Those new surfaces lie
    # next to static ones (a door near its hinge), inside the robust kernel's reach, and bias the
    # fine alignment by a centimetre or two, so the fine stages use the consistent frames only.
    t_sel = time.perf_counter()
    static_tree = cKDTree(np.asarray(clouds.at(cfg.icp_voxels_m[0])[0].points))
    frames = _consistent_frames(static_tree, dynamic, transform, cfg)
    if len(frames) < dynamic.num_frames:
        clouds.refuse_dynamic(dynamic, frames)
    diagnostics["frames"] = {"seconds": time.perf_counter() - t_sel, "used": [int(t) for t in frames],
                             "dynamic_points": len(clouds.base_d.points)}

    for voxel in cfg.icp_voxels_m[2:]:
        t2 = time.perf_counter()
        r = clouds.icp(voxel, transform)
        transform = r.transform
        diagnostics[f"icp_{voxel:g}"] = {"seconds": time.perf_counter() - t2, "fitness": r.fitness,
                                         "inlier_rmse_m": r.inlier_rmse, "iterations": r.iterations}
    if cfg.max_tilt_deg > 0:
        t2 = time.perf_counter()
        voxel = cfg.icp_voxels_m[-1]
        transform, diagnostics["tilt"] = _tilt(np.asarray(clouds.at(voxel)[1].points), clouds.target(voxel), transform, up, voxel, cfg)
        diagnostics["tilt"]["seconds"] = time.perf_counter() - t2

    if cfg.texture_search_m > 0:
        t2 = time.perf_counter()
        transform, diagnostics["texture_search"] = _texture_search(transform, score, up, cfg)
        diagnostics["texture_search"]["seconds"] = time.perf_counter() - t2
    if cfg.photometric_blur_rad:
        t3 = time.perf_counter()
        voxel = cfg.icp_voxels_m[-1]
        transform, diagnostics["photometric"] = _photometric(
            static, dynamic, frames, np.asarray(clouds.at(voxel)[1].points), clouds.target(voxel), transform, score, up,
            voxel, cfg)
        diagnostics["photometric"]["seconds"] = time.perf_counter() - t3
    return transform


def _tilt(points: np.ndarray, target: PlaneTarget, transform: np.ndarray, up: np.ndarray, voxel: float,
          cfg: RegistrationConfig) -> tuple[np.ndarray, dict]:
    """The finest ICP again with the tilt free (clamped to ``max_tilt_deg``), kept only if the
    data show a tilt: where the recordings overlap in part, the tilt is poorly pinned and the
    free fit tilts by the misfit (measured 0.07-0.3 deg on synthetic scenes that have none). The
    tilt is kept when its squared Mahalanobis distance, against its spatial block-jackknife
    covariance (``tilt_test_blocks`` blocks of the dynamic cloud, each left out in turn), exceeds
    ``tilt_test_threshold``."""
    def fit(pts: np.ndarray, start: np.ndarray) -> np.ndarray:
        return gravity_icp(pts, target, start, up, max_distance_m=2.5 * voxel, kernel_m=1.5 * voxel,
                           max_tilt_rad=np.deg2rad(cfg.max_tilt_deg)).transform

    tilted = fit(points, transform)
    tau = tilt_vector(tilted, up)
    info = {"estimate_deg": float(np.rad2deg(np.arcsin(min(np.linalg.norm(tau), 1.0)))), "kept": True}
    if cfg.tilt_test_blocks >= 3:
        moved = points @ transform[:3, :3].T + transform[:3, 3]
        label = _spatial_blocks(moved, cfg.tilt_test_blocks)
        taus = np.stack([tilt_vector(fit(points[label != k], tilted), up) for k in range(cfg.tilt_test_blocks)
                         if np.any(label == k)])
        dev = taus - taus.mean(0)
        cov = (len(taus) - 1) / len(taus) * dev.T @ dev + np.eye(3) * 1e-12
        # tau is perpendicular to up: test it in that plane (two degrees of freedom).
        basis = gravity_basis(-up)[[0, 2]]
        t2, c2 = basis @ tau, basis @ cov @ basis.T
        info["mahalanobis_sq"] = float(t2 @ np.linalg.solve(c2, t2))
        info["se_deg"] = float(np.rad2deg(np.sqrt(np.trace(c2))))
        info["kept"] = info["mahalanobis_sq"] > cfg.tilt_test_threshold
    return (tilted if info["kept"] else transform), info


def _texture_search(transform: np.ndarray, score: _Scorer, up: np.ndarray, cfg: RegistrationConfig
                    ) -> tuple[np.ndarray, dict]:
    """Where the shapes leave a slide free and the texture on them disagrees, the slide the
    texture pins.

    A close-up of a cabinet front (a plane, a strip of floor) pins the placement everywhere but
    along the front, and point-to-plane ICP stops wherever it lands there: 8 cm off on
    generalization seed 26, beyond the photometric refinement's reach (its coarsest blur is
    about 2 cm at that distance), with colour agreement -0.11 where the true placement has 0.72.
    Only when the texture disagrees (agreement under ``min_colour_agreement`` on surfaces of
    contrast ``min_colour_contrast``), the placement is slid along the weakest direction of the
    geometric constraint (:func:`weakest_constraint`: yaw about the matches' centroid and
    translation) by up to ``texture_search_m`` each way, in ``texture_search_step_m`` steps, and
    the slide whose texture agrees best is kept if that agreement reaches
    ``min_colour_agreement`` and the geometric support does not drop by more than 0.02. Where
    the texture already agrees nothing moves."""
    agreement, contrast = score.colour(transform)
    info: dict = {"agreement_before": agreement, "contrast": contrast, "moved_m": 0.0, "accepted": False}
    if not contrast >= cfg.min_colour_contrast or agreement >= cfg.min_colour_agreement:
        return transform, info
    points = np.concatenate(score.data.dynamic_points) @ transform[:3, :3].T + transform[:3, 3]
    agree, matched = on_surface(points, score.data.static_surface, cfg.inlier_distance_m)
    points = points[agree]
    if len(points) < 10:
        return transform, info
    _, direction = weakest_constraint(points, score.data.static_surface.normals[matched[agree]], up)
    centre, radius = motion_scale(points, up)

    def slid(s: float) -> np.ndarray:
        step = np.eye(4)
        step[:3, :3] = axis_angle_to_matrix(up, s * direction[0] / radius)
        step[:3, 3] = centre - step[:3, :3] @ centre + s * direction[1:]
        return step @ transform

    offsets = np.arange(-cfg.texture_search_m, cfg.texture_search_m + 1e-9, cfg.texture_search_step_m)
    agreements = np.array([score.colour(slid(float(s)))[0] for s in offsets])
    best = int(np.nanargmax(np.where(np.isfinite(agreements), agreements, -np.inf)))
    candidate = slid(float(offsets[best]))
    before, after = score("before", transform).support, score("after", candidate).support
    accepted = bool(agreements[best] >= cfg.min_colour_agreement and after >= before - 0.02)
    info.update({"agreement_after": float(agreements[best]), "moved_m": float(abs(offsets[best])),
                 "direction": [float(v) for v in direction], "support_before": before, "support_after": after,
                 "accepted": accepted})
    return (candidate if accepted else transform), info


def _spatial_blocks(points: np.ndarray, blocks: int) -> np.ndarray:
    """``[N]`` block label of each of ``points [N, 3]``: k-means (10 rounds, fixed seed)."""
    rng = np.random.default_rng(0)
    centres = points[rng.choice(len(points), blocks, replace=False)]
    label = np.zeros(len(points), np.int64)
    for _ in range(10):
        label = cKDTree(centres).query(points, workers=-1)[1]
        centres = np.stack([points[label == k].mean(0) if np.any(label == k) else centres[k] for k in range(blocks)])
    return label


def _photometric(static: Capture, dynamic: Capture, frames, points: np.ndarray, target: PlaneTarget,
                 transform: np.ndarray, score: _Scorer, up: np.ndarray, voxel: float, cfg: RegistrationConfig) -> tuple[np.ndarray, dict]:
    """The photometric and point-to-plane refinement (:mod:`._photometric`) from ``transform``.

    Where the recordings overlap only in part, the geometry in common often pins everything but
    a slide along the furniture's front, and only the texture pins that. The result is kept if
    it moved less than ``photometric_max_step_m`` (a refinement, not a jump to another basin)
    and its geometric support did not drop by more than 0.02."""
    r = photometric_refine(
        static, dynamic, frames, target, points, transform, up, blur_rad=tuple(cfg.photometric_blur_rad),
        num_views=cfg.photometric_views, max_points=cfg.photometric_points, visibility_m=cfg.photometric_visibility_m,
        max_distance_m=2.5 * voxel, kernel_m=1.5 * voxel, grey_noise=cfg.photometric_noise, stride=cfg.pixel_stride,
        max_depth_m=cfg.max_depth_m, min_confidence=cfg.min_confidence,
    )
    step = np.linalg.inv(transform) @ r.transform
    before, after = score("before", transform).support, score("after", r.transform).support
    accepted = bool(np.linalg.norm(step[:3, 3]) < cfg.photometric_max_step_m and after >= before - 0.02)
    info = {"levels": list(r.levels), "accepted": accepted, "step_m": float(np.linalg.norm(step[:3, 3])),
            "step_deg": float(np.rad2deg(_angle(step[:3, :3]))), "support_before": before, "support_after": after}
    return (r.transform if accepted else transform), info


def _angle(rotation: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1)))


def _yaw_deg(transform: np.ndarray, up: np.ndarray) -> float:
    """Yaw (degrees) of ``transform`` about ``up``: how it turns a horizontal direction."""
    e1, _, e2 = gravity_basis(-up)  # e2 = e1 x up, so a yaw of +90 deg takes e1 to -e2
    v = transform[:3, :3] @ e1
    return float(np.rad2deg(np.arctan2(-(v @ e2), v @ e1)))


def _distinct(scored: list[HypothesisScore], points: np.ndarray, min_m: float) -> list[HypothesisScore]:
    """``scored`` (best first) without those within ``min_m`` RMS of a better one."""
    out: list[HypothesisScore] = []
    placed: list[np.ndarray] = []
    for h in scored:
        m = h.canonical_from_session
        moved = points @ m[:3, :3].T + m[:3, 3]
        if all(np.sqrt(np.mean(np.sum((moved - other) ** 2, axis=1))) > min_m for other in placed):
            out.append(h)
            placed.append(moved)
    return out


def _rival(distinct: list[HypothesisScore], points: np.ndarray, cfg: RegistrationConfig) -> HypothesisScore | None:
    """The best of ``distinct`` (best first) that places ``points`` more than ``rival_distance_m``
    RMS from where the best one does (a different reading of the scene, not the same one slid a
    little) and lays the static surfaces' own texture on them: in a box-shaped room the placement
    turned by 180 deg about gravity fits walls and floor nearly as well (generalization seeds 11,
    16, 22: 71-87 % of the best's support) but lays other texture on them (colour agreement -0.26
    to 0.11 against 0.62-0.81), and is no rival."""
    def placed(h: HypothesisScore) -> np.ndarray:
        return points @ h.canonical_from_session[:3, :3].T + h.canonical_from_session[:3, 3]

    first = placed(distinct[0])
    for h in distinct[1:]:
        if np.sqrt(np.mean(np.sum((placed(h) - first) ** 2, axis=1))) > cfg.rival_distance_m and not _other_texture(h, cfg):
            return h
    return None


def _other_texture(h: HypothesisScore, cfg: RegistrationConfig) -> bool:
    """Whether ``h`` lays other texture on textured static surfaces than theirs."""
    return h.colour_contrast >= cfg.min_colour_contrast and not h.colour_agreement >= cfg.min_colour_agreement


def _texture_pins(h: HypothesisScore, cfg: RegistrationConfig) -> bool:
    """Whether the photometric refinement runs and ``h``'s static surfaces carry texture for it."""
    return bool(cfg.photometric_blur_rad) and h.colour_contrast >= cfg.min_colour_contrast


def _ratio(best: HypothesisScore, rival: HypothesisScore | None) -> float:
    """The rival's support as a fraction of the best's (0 without a rival, 1 if the best has none)."""
    if rival is None:
        return 0.0
    return max(rival.support, 0.0) / best.support if best.support > 0 else 1.0


def _refusals(best: HypothesisScore, rival: HypothesisScore | None, cfg: RegistrationConfig) -> list[str]:
    """The refusal tests the best hypothesis fails, each a sentence with its numbers."""
    failed = []
    confirmed = best.colour_contrast >= cfg.min_colour_contrast and best.colour_agreement >= cfg.confirming_colour_agreement
    if best.overlap < (cfg.min_textured_overlap if confirmed else cfg.min_overlap):
        failed.append(f"only {100 * best.overlap:.0f}% of the dynamic points fall where the static recording looked "
                      f"(min_overlap {100 * cfg.min_overlap:.0f}%, or {100 * cfg.min_textured_overlap:.0f}% where the "
                      f"texture confirms the placement)")
    if best.inlier_ratio < cfg.min_inlier_ratio:
        failed.append(f"of those, only {100 * best.inlier_ratio:.0f}% lie on its surfaces and the rest in space it saw "
                      f"empty (min_inlier_ratio {100 * cfg.min_inlier_ratio:.0f}%)")
    ratio = _ratio(best, rival)
    if rival is not None and ratio >= cfg.max_rival_ratio:
        failed.append(f"a placement more than {cfg.rival_distance_m:g} m away, '{rival.name}' (support "
                      f"{rival.support:.3f}), explains the data {100 * ratio:.0f}% as well "
                      f"(max_rival_ratio {100 * cfg.max_rival_ratio:.0f}%)")
    if best.constraint < cfg.min_constraint and not _texture_pins(best, cfg):
        # A textured plane is pinned by the photometric refinement, and the texture test checks
        # the result (a close-up of a cabinet front: generalization seed 26, 0.0011).
        failed.append(f"its matched points pin the weakest direction to {best.constraint:.4f} "
                      f"(min_constraint {cfg.min_constraint}): the overlap is one or two planes and could slide")
    return failed


def _texture_refusal(final: HypothesisScore, cfg: RegistrationConfig) -> list[str]:
    """The texture test of the refined placement, as a sentence with its numbers (or none)."""
    if final.colour_contrast < cfg.min_colour_contrast or final.colour_agreement >= cfg.min_colour_agreement:
        return []  # agrees, or too little texture to tell (the geometric tests then decide alone)
    return [f"refined, its matched points' colours correlate with the static surfaces' at only "
            f"{final.colour_agreement:.2f} (min_colour_agreement {cfg.min_colour_agreement:g}; about 0 for unrelated "
            f"textures) although those surfaces carry texture (RMS {final.colour_contrast:.3f} about each surface's "
            f"mean): the shapes match (a corner onto another corner, a wall onto another wall) but the surfaces "
            f"are not the same ones"]


def _refusal_message(best: HypothesisScore, rival: HypothesisScore | None, failed: list[str],
                     cfg: RegistrationConfig) -> str:
    other = (f"; the best placement more than {cfg.rival_distance_m:g} m away, '{rival.name}': support {rival.support:.3f}, overlap "
             f"{100 * rival.overlap:.0f}%, inliers {100 * rival.inlier_ratio:.0f}%") if rival is not None else ""
    return (
        "register: no placement of the dynamic recording in the static one is convincing, so registration stops "
        "here rather than pass a wrong one on (every surface it misplaces would become a moving part). "
        f"Best hypothesis '{best.name}': support {best.support:.3f} (points on static surfaces minus points in "
        f"space the static recording saw empty, per dynamic point), overlap {100 * best.overlap:.0f}%, inliers "
        f"{100 * best.inlier_ratio:.0f}% of the overlap, weakest constraint {best.constraint:.4f}, colour agreement "
        f"{best.colour_agreement:.2f} on texture of RMS {best.colour_contrast:.3f}{other}. "
        f"Failed: {'; '.join(failed)}. "
        "What to do: check that both recordings show the same room and the same furniture; record the dynamic "
        "recording so that at least a third of what it sees was also covered by the static sweep (start it from "
        "where the static one looked at the furniture, with some of the surroundings in view: a wall corner, the "
        "floor, other furniture), or re-record the static sweep to cover the dynamic recording's view."
    )


def _block_jackknife(dynamic_cloud, static_cloud, transform: np.ndarray, voxel: float, blocks: int) -> np.ndarray | None:
    """``[6, 6]`` covariance of the registration error ``(w, v)`` (see ``RegistrationResult``):
    the dynamic cloud is cut into ``blocks`` spatial clusters (k-means on the registered points),
    each left out in turn and the finest point-to-plane ICP rerun from ``transform``; the
    jackknife variance of the leave-one-out corrections, within a factor of a few of the true
    error (docs/accuracy.md). None when a block is too small to leave out."""
    pts = np.asarray(dynamic_cloud.points) @ transform[:3, :3].T + transform[:3, 3]
    if len(pts) < 50 * blocks:
        return None
    label = _spatial_blocks(pts, blocks)
    inv = np.linalg.inv(transform)
    params = []
    for k in range(blocks):
        keep = np.nonzero(label != k)[0]
        if len(keep) == len(pts):
            continue
        step = _icp(dynamic_cloud.select_by_index(keep.tolist()), static_cloud, transform, voxel).transformation @ inv
        rot = step[:3, :3]
        angle = np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1))
        axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
        w = axis * (angle / (2 * np.sin(angle))) if angle > 1e-12 else 0.5 * axis
        params.append(np.concatenate([w, step[:3, 3]]))
    if len(params) < 3:
        return None
    x = np.stack(params)
    dev = x - x.mean(0)
    return (len(x) - 1) / len(x) * dev.T @ dev
