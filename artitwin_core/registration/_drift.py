"""The dynamic recording's pose drift, against the canonical model (the effect ``pose_drift``).

A single rigid registration cannot follow a recording whose odometry creeps: frames late in the
sweep are then centimetres off the canonical frame, and so are the part's tracks and the joint
fitted to them. Here the recording's poses get a constant correction (what the registration left)
and a linear drift (:class:`artitwin_core.capture.PoseDrift`), fitted with

- each frame's depth against the canonical mesh, associated projectively (the mesh ray-cast
  through the pixel; a point more than ``max_association_m`` from what the mesh shows there, as
  the inside of a cabinet a door reveals, is left out), parts and hand masked out;
- SIFT matches to the nearest static frames, whose keypoints the static depth places in the
  canonical frame (their distance from the dynamic pixel's ray);
- SIFT matches between the recording's own frames (fixing the rate along surfaces).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.capture._drift import (
    DriftSignificance,
    FeatureCache,
    PoseDrift,
    block_jackknife_cov,
    depth_at_pixels,
    drift_significance,
    pixel_rays,
    ray_normals,
    sift_matches,
)
from artitwin_core.registration._config import SessionDriftConfig


class RayCastMesh(Protocol):
    """What the drift fit needs of the canonical mesh (``artitwin_core.change.CanonicalMesh``, not
    imported here: change detection builds on registration, not the other way round)."""

    vertices: np.ndarray  # [V, 3] metres, canonical frame
    triangles: np.ndarray  # [F, 3] vertex indices

    def render(
        self, world_from_camera: np.ndarray, intrinsics, width: int, height: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """rgb ``[H, W, 3]``, z-depth ``[H, W]`` metres (NaN: no surface), hit triangle ``[H, W]``."""
        ...


@dataclass(frozen=True)
class SessionDrift:
    """A recording's fitted pose correction.

    Attributes:
        drift: corrects the recording's own poses (session frame): ``canonical_from_session @
            drift.apply(world_from_camera, timestamps)`` are its poses in the canonical frame.
        drift_canonical: the same correction in the canonical frame.
        significance: how far the drift's rate moves a point ahead of the first camera by the
            last frame (canonical frame), with standard errors.
        residual_m: robust spread (1.4826 MAD) of the depth terms after the fit.
        points: depth points in the last solve; feature_rows: keypoint terms in it.
    """

    drift: PoseDrift
    drift_canonical: PoseDrift
    significance: DriftSignificance
    residual_m: float
    points: int
    feature_rows: int


def _excluded(part: np.ndarray, hand: np.ndarray, px: int) -> np.ndarray:
    mask = ((np.asarray(part) > 0) | np.asarray(hand, bool)).astype(np.uint8)
    if px > 0:
        mask = cv2.dilate(mask, np.ones((2 * px + 1, 2 * px + 1), np.uint8))
    return mask.astype(bool)


def _at(mask: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    return mask[np.clip(np.round(pixels[:, 1]).astype(int), 0, h - 1), np.clip(np.round(pixels[:, 0]).astype(int), 0, w - 1)]


def _robust_weights(r: np.ndarray) -> tuple[np.ndarray, float]:
    spread = float(1.4826 * np.median(np.abs(r))) + 1e-9
    return np.clip(1.0 - (r / (4.685 * spread)) ** 2, 0.0, 1.0) ** 2 / spread**2, spread


def estimate_session_drift(
    dynamic: Capture,
    canonical_from_session: np.ndarray,
    mesh: RayCastMesh,
    part: np.ndarray,
    hand: np.ndarray,
    static: Capture,
    config: SessionDriftConfig = SessionDriftConfig(),
) -> SessionDrift:
    """Fit a constant correction and a linear drift to ``dynamic``'s poses against the canonical
    model (module docstring), and the drift of each half of the recording alone (in
    ``significance.half_rates_m_per_s``: a linear drift is the same in both).

    Args:
        dynamic: the recording, depth metric (already calibrated).
        canonical_from_session: ``[4, 4]`` its registration.
        mesh: the canonical mesh (``build_canonical_tsdf`` of ``static``).
        part, hand: ``[T, H, W]`` part labels and hand masks at RGB resolution (left out).
        static: the static recording, poses in the canonical frame.

    Raises:
        InputError: masks that do not match the recording, or too little unmasked evidence.
    """
    fit = _estimate(dynamic, canonical_from_session, mesh, part, hand, static, config)
    t_count = dynamic.num_frames
    if t_count < 2 * max(config.frame_gaps, default=2) + 2:
        return fit
    half = t_count // 2
    rates = []
    for sub in (slice(0, half), slice(half, None)):
        try:
            part_fit = _estimate(dynamic.select_frames(sub), canonical_from_session, mesh, part[sub], hand[sub], static, config)
        except InputError:
            return fit  # a half with too little evidence: the check is skipped
        rates.append(part_fit.drift_canonical.rate_at(fit.significance.point))
    return dataclasses.replace(
        fit, significance=dataclasses.replace(fit.significance, half_rates_m_per_s=np.stack(rates))
    )


def _estimate(
    dynamic: Capture,
    canonical_from_session: np.ndarray,
    mesh: RayCastMesh,
    part: np.ndarray,
    hand: np.ndarray,
    static: Capture,
    config: SessionDriftConfig,
) -> SessionDrift:
    t_count = dynamic.num_frames
    ts = _check_inputs(dynamic, part, hand)
    gravity = np.asarray(config.gravity, np.float64)
    gravity = gravity / np.linalg.norm(gravity)
    recorded = np.einsum("ij,tjk->tik", np.asarray(canonical_from_session, np.float64), np.asarray(dynamic.world_from_camera, np.float64))
    pivot = recorded[0, :3, 3].copy()
    excluded = [_excluded(part[t], hand[t], config.mask_dilation_px) for t in range(t_count)]
    tri_normals = _triangle_normals(mesh)
    own, anchored = _keypoints(dynamic, static, recorded, excluded, config)

    drift = PoseDrift(pivot=pivot, t0_s=float(ts[0]))
    for _ in range(config.iterations):
        poses = drift.apply(recorded, ts)
        basis = (pivot, gravity, ts)
        sources = [_depth_rows(dynamic, mesh, tri_normals, poses, excluded, basis, config)]
        keypoint_rows = _keypoint_rows(dynamic, poses, own, anchored, basis, config)
        if keypoint_rows is not None:
            sources.append(keypoint_rows)
        step, weighted, residual, points = _weighted_step(sources, config.jackknife_blocks, t_count)
        drift = PoseDrift(
            pivot=pivot, t0_s=drift.t0_s,
            rot0_rad=drift.rot0_rad + step[0:3], trans0_m=drift.trans0_m + step[3:6],
            rot_rate_rad_per_s=drift.rot_rate_rad_per_s + step[6] * gravity,
            trans_rate_m_per_s=drift.trans_rate_m_per_s + step[7:10],
        )
        if np.max(np.abs(step[:6])) < 1e-5 and np.max(np.abs(step[6:])) < 1e-6:
            break
    # Jackknife over blocks of frames at the last association.
    cov = block_jackknife_cov(
        *(np.concatenate([x[k] for x in weighted]) for k in (0, 2, 1, 3)), ridge=1e-9
    )  # design, weights, rhs, block
    rate_cov = None if cov is None else cov[6:, 6:]
    z_ref = float(np.nanmedian(np.asarray(dynamic.depth[0], np.float64)))
    ahead = pivot + (z_ref if np.isfinite(z_ref) else 2.0) * recorded[0, :3, 2]
    significance = drift_significance(drift, ahead, float(ts[-1]), rate_cov, yaw_axis=gravity)
    session_from_canonical = np.linalg.inv(np.asarray(canonical_from_session, np.float64))
    return SessionDrift(
        drift=drift.in_frame(session_from_canonical), drift_canonical=drift, significance=significance,
        residual_m=residual, points=points, feature_rows=int(sum(len(x[1]) for x in weighted[1:])),
    )


def _check_inputs(dynamic: Capture, part: np.ndarray, hand: np.ndarray) -> np.ndarray:
    """``[T]`` the recording's timestamps (seconds), once its masks and clock are usable."""
    t_count = dynamic.num_frames
    h, w = dynamic.rgb.shape[1:3]
    if np.shape(part) != (t_count, h, w) or np.shape(hand) != (t_count, h, w):
        raise InputError(
            f"estimate_session_drift: masks have shapes {np.shape(part)} / {np.shape(hand)}; the recording's frames "
            f"need ({t_count}, {h}, {w})."
        )
    ts = np.asarray(dynamic.timestamps, np.float64)
    if t_count < 3 or ts[-1] <= ts[0]:
        raise InputError("estimate_session_drift: the drift needs at least 3 frames with increasing timestamps.")
    return ts


def _triangle_normals(mesh: RayCastMesh) -> np.ndarray:
    """``[F, 3]`` unit normals of the mesh's triangles."""
    tri_normals = np.cross(
        mesh.vertices[mesh.triangles[:, 1]] - mesh.vertices[mesh.triangles[:, 0]],
        mesh.vertices[mesh.triangles[:, 2]] - mesh.vertices[mesh.triangles[:, 0]],
    )
    tri_normals /= np.maximum(np.linalg.norm(tri_normals, axis=1, keepdims=True), 1e-12)
    return tri_normals


def _keypoints(
    dynamic: Capture, static: Capture, recorded: np.ndarray, excluded: list[np.ndarray], config: SessionDriftConfig
) -> tuple[dict, dict]:
    """Keypoints: the recording's own pairs ``{(i, j): (pixels_i, pixels_j)}``, and each frame against
    its nearest static frames ``{t: (points [M, 3] canonical metres, pixels [M, 2])}`` (static
    keypoints lifted once into the canonical frame by the static depth and poses)."""
    t_count = dynamic.num_frames
    dyn_features, static_features = FeatureCache(dynamic.rgb), FeatureCache(static.rgb)
    own = {}
    for g in config.frame_gaps:
        for i in range(t_count - g):
            pi, pj = sift_matches(dyn_features(i), dyn_features(i + g))
            keep = ~_at(excluded[i], pi) & ~_at(excluded[i + g], pj)
            if np.count_nonzero(keep):
                own[(i, i + g)] = (pi[keep], pj[keep])
    static_centres = np.asarray(static.world_from_camera, np.float64)[:, :3, 3]
    anchored = {}
    for t in range(t_count):
        near = np.argsort(np.linalg.norm(static_centres - recorded[t, :3, 3], axis=1))[: config.static_neighbours]
        lifted, pixels = [], []
        for k in near:
            ps, pd = sift_matches(static_features(int(k)), dyn_features(t))
            keep = ~_at(excluded[t], pd)
            ps, pd = ps[keep], pd[keep]
            d = depth_at_pixels(static, int(k), ps, min_confidence=config.min_confidence)
            ok = np.isfinite(d) & (d > 0) & (d < config.max_depth_m)
            if np.any(ok):
                pose = static.world_from_camera[k]
                lifted.append(pose[:3, 3] + d[ok, None] * pixel_rays(static.rgb_intrinsics[k], ps[ok], pose))
                pixels.append(pd[ok])
        if lifted:
            anchored[t] = (np.concatenate(lifted), np.concatenate(pixels))
    return own, anchored


def _depth_rows(
    dynamic: Capture,
    mesh: RayCastMesh,
    tri_normals: np.ndarray,
    poses: np.ndarray,
    excluded: list[np.ndarray],
    basis: tuple[np.ndarray, np.ndarray, np.ndarray],
    config: SessionDriftConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Design rows ``[n, 10]``, right-hand sides ``[n]`` and frames ``[n]`` of the depth against the
    mesh, projectively associated, at the current ``poses [T, 4, 4]``; ``basis`` is the drift's
    pivot, gravity and the timestamps."""
    pivot, gravity, ts = basis
    dh, dw = dynamic.depth.shape[1:]
    st = config.pixel_stride
    vv, uu = np.mgrid[0:dh:st, 0:dw:st]
    rows, rhs, frames = [], [], []
    for t in range(dynamic.num_frames):
        k = np.asarray(dynamic.depth_intrinsics[t], np.float64)
        z = np.asarray(dynamic.depth[t], np.float64)[::st, ::st]
        ok = np.isfinite(z) & (z > 0) & (z < config.max_depth_m)
        if dynamic.confidence is not None and config.min_confidence > 0:
            ok &= np.asarray(dynamic.confidence[t])[::st, ::st] >= config.min_confidence
        ex = cv2.resize(excluded[t].astype(np.uint8), (dw, dh), interpolation=cv2.INTER_NEAREST)[::st, ::st].astype(bool)
        ok &= ~ex
        _, rendered, tri = mesh.render(poses[t], k, dw, dh)
        rendered, tri = np.asarray(rendered, np.float64)[::st, ::st][ok], tri[::st, ::st][ok]
        zc = z[ok]
        good = np.isfinite(rendered) & (np.abs(rendered - zc) < config.max_association_m)
        if not np.any(good):
            continue
        cam = np.stack([(uu[ok][good] - k[2]) / k[0], (vv[ok][good] - k[3]) / k[1], np.ones(np.count_nonzero(good))], -1)
        rays = cam @ poses[t][:3, :3].T
        x = poses[t][:3, 3] + zc[good, None] * rays
        q = poses[t][:3, 3] + rendered[good, None] * rays
        n = tri_normals[tri[good]]
        dt = ts[t] - ts[0]
        arm = np.cross(x - pivot, n)
        rows.append(np.concatenate([arm, n, dt * (arm @ gravity)[:, None], dt * n], 1))
        rhs.append(np.sum((x - q) * n, 1))
        frames.append(np.full(len(n), t))
    if not rows or sum(len(r) for r in rhs) < 100:
        raise InputError(
            "estimate_session_drift: fewer than 100 unmasked depth points of the recording lie on the canonical "
            "surface; check the registration, or leave pose_drift off."
        )
    return np.concatenate(rows), np.concatenate(rhs), np.concatenate(frames)


def _keypoint_rows(
    dynamic: Capture,
    poses: np.ndarray,
    own: dict,
    anchored: dict,
    basis: tuple[np.ndarray, np.ndarray, np.ndarray],
    config: SessionDriftConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """As :func:`_depth_rows`, for the keypoints: static-anchored (all unknowns) and the recording's
    own pairs (the rate only); None when there are none."""
    pivot, gravity, ts = basis
    rows, rhs, frames = [], [], []
    for t, (lifted, pixels) in anchored.items():
        centre = poses[t][:3, 3]
        rays = pixel_rays(dynamic.rgb_intrinsics[t], pixels, poses[t])
        dt = ts[t] - ts[0]
        for m in ray_normals(rays):
            arm = -np.cross(lifted - pivot, m)
            rows.append(np.concatenate([arm, -m, dt * (arm @ gravity)[:, None], -dt * m], 1))
            rhs.append(np.sum(m * (lifted - centre), 1))
            frames.append(np.full(len(m), t))
    for (i, j), (pi, pj) in own.items():
        d = depth_at_pixels(dynamic, i, pi, min_confidence=config.min_confidence)
        ok = np.isfinite(d) & (d > 0) & (d < config.max_depth_m)
        if not np.any(ok):
            continue
        ray_i = pixel_rays(dynamic.rgb_intrinsics[i], pi[ok], poses[i])
        x = poses[i][:3, 3] + d[ok, None] * ray_i
        dt = ts[i] - ts[j]
        for m in ray_normals(pixel_rays(dynamic.rgb_intrinsics[j], pj[ok], poses[j])):
            arm = np.cross(x - pivot, m)
            rows.append(np.concatenate([np.zeros((len(m), 6)), dt * (arm @ gravity)[:, None], dt * m], 1))
            rhs.append(np.sum(m * (x - poses[j][:3, 3]), 1))
            frames.append(np.full(len(m), i))
    if not rows:
        return None
    return np.concatenate(rows), np.concatenate(rhs), np.concatenate(frames)


def _weighted_step(sources: list, blocks: int, t_count: int) -> tuple[np.ndarray, list, float, int]:
    """One robustly weighted least-squares step ``[10]`` over every source's rows, the weighted rows
    ``(design, rhs, weights, block)`` per source, and the depth source's (the first) robust spread
    (metres) and count of points with weight."""
    hess, grad, weighted = np.zeros((10, 10)), np.zeros(10), []
    for s_idx, (a_mat, r, fr) in enumerate(sources):
        wts, spread = _robust_weights(r)
        if s_idx == 0:
            residual, points = spread, int(np.count_nonzero(wts))
        hess += (a_mat * wts[:, None]).T @ a_mat
        grad += (a_mat * wts[:, None]).T @ r
        weighted.append((a_mat, r, wts, (fr * blocks) // t_count))
    step = np.linalg.solve(hess + 1e-9 * np.eye(10), -grad)
    return step, weighted, residual, points
