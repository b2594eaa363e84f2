"""Refine the capture's camera poses with COLMAP features and a depth-aware bundle adjustment.

Not a from-scratch SfM: COLMAP extracts SIFT features on the RGB frames, matches them (every pair
for short recordings, sequentially otherwise) and triangulates points from the KNOWN capture poses
and intrinsics (its point_triangulator). Poses and points are then adjusted jointly with the
sensor depth at each keypoint as an extra observation (:func:`adjust_with_depth`): COLMAP's own
bundle adjuster, tried first, left a flat valley between small rotations and sideways
translations at phone-video resolution (it moved exact poses by ~1.5 cm / 0.7 deg) and leaves the
scale free; the depth term removes both. Intrinsics stay fixed, and the lens distortion (OpenCV
``k1 k2 p1 p2``) is applied as the capture records it. (Calibrating the distortion here was
tried: at 256 x 192 SIFT keypoints, about 1 px RMS, gave k1 -0.03 for a true -0.08.) Two rounds of triangulate-adjust
are run, then one rigid transform maps the adjusted trajectory back onto the capture's (rotation
from the chordal mean of per-frame rotation differences, translation by least squares on the
centres), so the world frame stays the capture's and the metric scale the depth sensor's.

Anything that goes wrong (too few features or matches on a low-texture scene, a degenerate
triangulation) falls back to the capture poses with a note; this never raises for bad data.
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from artitwin_core import progress
from artitwin_core.capture import Capture
from artitwin_core.geometry import invert_se3
from artitwin_core.reconstruction._config import PoseRefineConfig

log = logging.getLogger(__name__)

RefineStatus = Literal["refined", "partial", "fallback"]


@dataclass(frozen=True)
class PoseRefinement:
    """Refined poses and what happened.

    Attributes:
        world_from_camera: ``[T, 4, 4]`` refined poses in the capture's world frame (OpenCV axes,
            metres); equal to the capture poses for frames that were not refined.
        refined: ``[T]`` bool, frames whose pose COLMAP refined and that passed the checks.
        correction_translation_m: ``[T]`` distance between refined and capture camera centres, metres.
        correction_rotation_deg: ``[T]`` angle of the rotation between refined and capture poses, degrees.
        observations: ``[T]`` triangulated points each frame observes after bundle adjustment.
        num_points: triangulated 3D points.
        reprojection_error_px: mean reprojection error after bundle adjustment, pixels (NaN if none).
        scale: the similarity's scale that mapped COLMAP's result back onto the capture (1 = no drift).
        status: ``"refined"``, ``"partial"`` (some frames kept) or ``"fallback"`` (all kept).
        notes: human-readable remarks (why frames were kept, why refinement was abandoned).
        distortion: ``[4]`` OpenCV ``k1 k2 p1 p2`` of the RGB lens as the capture records it
            (None for a pinhole camera), which the adjustment projected through.
    """

    world_from_camera: np.ndarray
    refined: np.ndarray
    correction_translation_m: np.ndarray
    correction_rotation_deg: np.ndarray
    observations: np.ndarray
    num_points: int
    reprojection_error_px: float
    scale: float
    status: RefineStatus
    notes: list[str] = field(default_factory=list)
    distortion: np.ndarray | None = None


def pose_difference(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame translation (metres) and rotation angle (degrees) between ``[T, 4, 4]`` poses."""
    dt = np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)
    rel = np.einsum("tji,tjk->tik", a[:, :3, :3], b[:, :3, :3])
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    return dt, np.degrees(np.arccos(cos))


def _fallback(capture: Capture, note: str, observations: np.ndarray | None = None) -> PoseRefinement:
    t = capture.num_frames
    return PoseRefinement(
        world_from_camera=capture.world_from_camera.copy(),
        refined=np.zeros(t, bool),
        correction_translation_m=np.zeros(t),
        correction_rotation_deg=np.zeros(t),
        observations=np.zeros(t, np.int64) if observations is None else observations,
        num_points=0,
        reprojection_error_px=float("nan"),
        scale=1.0,
        status="fallback",
        notes=[note + " Kept the capture poses."],
        distortion=recorded_distortion(capture),
    )


def recorded_distortion(capture: Capture) -> np.ndarray | None:
    """The capture's ``k1 k2 p1 p2`` (``[4]``), None when it records a pinhole camera."""
    if capture.distortion is None or not np.any(np.asarray(capture.distortion)[:4] != 0):
        return None
    dist = np.zeros(4)
    d = np.asarray(capture.distortion, np.float64).ravel()[:4]
    dist[: len(d)] = d
    return dist


def align_similarity(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[np.ndarray, float, np.ndarray]:
    """Similarity ``(R, s, t)`` that maps poses ``src`` ``[M, 4, 4]`` onto ``dst`` (world-from-camera).

    ``R`` is the chordal mean of ``R_dst R_src^T`` (well defined even for a straight camera path),
    then ``s, t`` minimise ``sum |s R c_src + t - c_dst|^2`` over the camera centres.
    """
    m = np.einsum("tij,tkj->ik", dst[:, :3, :3], src[:, :3, :3])
    u, _, vt = np.linalg.svd(m)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    a = src[:, :3, 3] @ r.T
    b = dst[:, :3, 3]
    a0, b0 = a - a.mean(0), b - b.mean(0)
    denom = float((a0 * a0).sum())
    s = float((a0 * b0).sum()) / denom if denom > 1e-12 and with_scale else 1.0
    if not np.isfinite(s) or s <= 0:
        s = 1.0
    t = b.mean(0) - s * a.mean(0)
    return r, s, t


def refine_poses(capture: Capture, config: PoseRefineConfig = PoseRefineConfig()) -> PoseRefinement:
    """Refine ``capture.world_from_camera`` with COLMAP; see the module docstring.

    Args:
        capture: the recording (RGB frames ``[T, H, W, 3]``, intrinsics, poses).
        config: feature, matching and acceptance settings.

    Returns:
        :class:`PoseRefinement`; ``status == "fallback"`` (capture poses kept) when COLMAP is
        missing, finds too little structure, or its result fails the checks.
    """
    if not config.enabled:
        return _fallback(capture, "Pose refinement disabled by config.")
    if capture.num_frames < 3:
        return _fallback(capture, f"Only {capture.num_frames} frames; pose refinement needs at least 3.")
    try:
        import pycolmap
    except ImportError:
        return _fallback(capture, "pycolmap is not installed (pip install pycolmap).")
    try:
        with tempfile.TemporaryDirectory(prefix="artitwin-colmap-") as tmp, progress(
            "pose refinement (features, matches, triangulate and adjust)", total=2 + config.iterations
        ) as report:
            return _refine(capture, config, pycolmap, Path(tmp), report)
    except Exception as exc:  # noqa: BLE001 -- COLMAP failures must never stop the pipeline
        log.warning("pose refinement failed: %s", exc)
        return _fallback(capture, f"COLMAP failed ({type(exc).__name__}: {exc}).")


def _camera_model(capture: Capture, distortion: np.ndarray | None) -> tuple[str, np.ndarray]:
    """COLMAP model name and ``[T, P]`` params per frame."""
    k = np.asarray(capture.rgb_intrinsics, np.float64).copy()
    k[:, 2:4] += 0.5  # COLMAP puts pixel centres at +0.5, the capture's intrinsics at integers
    if distortion is not None:
        return "OPENCV", np.concatenate([k, np.tile(distortion, (len(k), 1))], axis=1)
    return "PINHOLE", k


def distort_normalized(x: np.ndarray, y: np.ndarray, k) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV radial-tangential model (``k1 k2 p1 p2``) on normalised image coordinates."""
    k1, k2, p1, p2 = k[0], k[1], k[2], k[3]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    return x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y


def undistort_pixels(uv: np.ndarray, intrinsics: np.ndarray, k, iterations: int = 20) -> np.ndarray:
    """``[N, 2]`` distorted pixels to where a pinhole camera with the same ``[N, 4]`` intrinsics
    would see them (fixed-point iteration, as OpenCV's ``undistortPoints``)."""
    xd = (uv[:, 0] - intrinsics[:, 2]) / intrinsics[:, 0]
    yd = (uv[:, 1] - intrinsics[:, 3]) / intrinsics[:, 1]
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        dx, dy = distort_normalized(x, y, k)
        x, y = x + (xd - dx), y + (yd - dy)
    return np.stack([intrinsics[:, 0] * x + intrinsics[:, 2], intrinsics[:, 1] * y + intrinsics[:, 3]], 1)


def _refine(capture: Capture, config: PoseRefineConfig, pycolmap, tmp: Path, report) -> PoseRefinement:
    from PIL import Image

    prev_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2  # errors only: COLMAP logs every image otherwise
    try:
        t_frames = capture.num_frames
        image_dir = tmp / "images"
        image_dir.mkdir()
        names = [f"{t:06d}.png" for t in range(t_frames)]
        for t, name in enumerate(names):
            Image.fromarray(np.ascontiguousarray(capture.rgb[t])).save(image_dir / name)
        db_path = tmp / "database.db"
        distortion = recorded_distortion(capture)
        model, params = _camera_model(capture, distortion)
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = model
        reader.camera_params = ",".join(f"{x:.10g}" for x in params[0])
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = config.extraction_threads or (os.cpu_count() or 1)
        extraction.use_gpu = False
        extraction.sift.max_num_features = config.features_for(*capture.rgb_size)
        extraction.sift.peak_threshold = config.sift_peak_threshold
        pycolmap.extract_features(
            db_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.PER_IMAGE,
            reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
        )  # fmt: skip
        report.advance(info=f"{t_frames} frames")
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = config.num_threads
        matching.use_gpu = False
        verification = pycolmap.TwoViewGeometryOptions()
        verification.ransac.random_seed = config.seed
        if t_frames <= config.exhaustive_max_frames:
            pycolmap.match_exhaustive(db_path, matching_options=matching, verification_options=verification,
                                      device=pycolmap.Device.cpu)
        elif config.loop_closure_pairs > 0:
            pairs = match_pairs(capture, config.sequential_overlap, config.loop_closure_pairs)
            listing = tmp / "pairs.txt"
            listing.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
            pairing = pycolmap.ImportedPairingOptions()
            pairing.match_list_path = str(listing)
            pycolmap.match_image_pairs(
                db_path, matching_options=matching, pairing_options=pairing, verification_options=verification,
                device=pycolmap.Device.cpu,
            )
        else:
            pairing = pycolmap.SequentialPairingOptions()
            pairing.overlap = config.sequential_overlap
            pycolmap.match_sequential(
                db_path, matching_options=matching, pairing_options=pairing, verification_options=verification,
                device=pycolmap.Device.cpu,
            )

        report.advance()
        db = pycolmap.Database.open(db_path)
        try:
            verified = db.num_verified_image_pairs()
        finally:
            db.close()
        if verified == 0:
            return _fallback(capture, "COLMAP found no geometrically verified image pair (low texture?).")
        poses = capture.world_from_camera.copy()
        for it in range(config.iterations):  # re-triangulate from the improved poses, adjust again
            rec = _triangulate(pycolmap, db_path, image_dir, names, params, poses, tmp / f"tri{it}", config)
            tracks = _tracks(rec, names)
            if len(tracks.points) < 3 * config.min_track_points:
                return _fallback(capture, f"COLMAP triangulated only {len(tracks.points)} points (low texture?).")
            poses, observations, rms_px = adjust_with_depth(capture, poses, tracks, config, distortion)
            report.advance(info=f"{len(tracks.points)} points")
        refined_raw = poses
        usable = observations >= config.min_track_points
        if usable.sum() < max(3, config.min_refined_frac * t_frames):
            return _fallback(
                capture,
                f"only {int(usable.sum())} of {t_frames} frames observe {config.min_track_points}+ points.",
                observations,
            )
        r, s, tr = align_similarity(refined_raw[usable], capture.world_from_camera[usable], with_scale=False)
        aligned = capture.world_from_camera.copy()
        for t in np.flatnonzero(usable):
            aligned[t, :3, :3] = r @ refined_raw[t, :3, :3]
            aligned[t, :3, 3] = s * (r @ refined_raw[t, :3, 3]) + tr
        dt, dr = pose_difference(aligned, capture.world_from_camera)
        notes: list[str] = []
        suspicious = usable & ((dt > config.max_correction_m) | (dr > config.max_correction_deg))
        if suspicious.any():
            notes.append(
                f"{int(suspicious.sum())} frame(s) moved more than {config.max_correction_m} m or "
                f"{config.max_correction_deg} deg (first: frame {int(capture.frame_ids[np.flatnonzero(suspicious)[0]])}); "
                "kept their capture poses."
            )
        accepted = usable & ~suspicious
        if accepted.sum() < max(3, config.min_refined_frac * t_frames):
            return _fallback(capture, "too many refined poses failed the correction-size check.", observations)
        if (~usable).any():
            notes.append(f"{int((~usable).sum())} frame(s) observe too few points; kept their capture poses.")
        final = capture.world_from_camera.copy()
        final[accepted] = aligned[accepted]
        dt, dr = pose_difference(final, capture.world_from_camera)
        return PoseRefinement(
            world_from_camera=final,
            refined=accepted,
            correction_translation_m=dt,
            correction_rotation_deg=dr,
            observations=observations,
            num_points=len(tracks.points),
            reprojection_error_px=rms_px,
            scale=float(s),
            status="refined" if accepted.all() else "partial",
            notes=notes,
            distortion=distortion,
        )
    finally:
        pycolmap.logging.minloglevel = prev_level


def match_pairs(capture: Capture, overlap: int, loop_pairs: int, max_angle_deg: float = 30.0) -> list[tuple[int, int]]:
    """Frame pairs ``(i, j)``, ``i < j``, to match in a long recording: each frame with the next
    ``overlap`` frames, and with up to ``loop_pairs`` frames outside that window whose views
    overlap most by the capture poses (optical axes within ``max_angle_deg``, centres closer than
    the median depth): the loop closures of a sweep that comes back, found without a vocabulary tree.
    """
    t = capture.num_frames
    pairs = {(i, j) for i in range(t) for j in range(i + 1, min(t, i + overlap + 1))}
    if loop_pairs <= 0 or t <= overlap + 1:
        return sorted(pairs)
    depth = capture.depth[:, ::4, ::4]
    with np.errstate(all="ignore"):
        median = float(np.nanmedian(np.where(depth > 0, depth, np.nan))) if np.isfinite(depth).any() else 1.0
    median = max(median if np.isfinite(median) else 1.0, 0.3)
    centres = capture.world_from_camera[:, :3, 3]
    axes = capture.world_from_camera[:, :3, 2]
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1) / median
    cos = np.clip(axes @ axes.T, -1.0, 1.0)
    score = dist + (1.0 - cos) * 10.0
    far = np.abs(np.arange(t)[:, None] - np.arange(t)[None]) > overlap
    ok = far & (cos >= np.cos(np.radians(max_angle_deg))) & (dist < 1.0)
    for i in range(t):
        cand = np.flatnonzero(ok[i])
        for j in cand[np.argsort(score[i, cand])][:loop_pairs]:
            pairs.add((min(i, int(j)), max(i, int(j))))
    return sorted(pairs)


@dataclass(frozen=True)
class Tracks:
    """COLMAP's triangulated points and their observations.

    Attributes:
        points: ``[M, 3]`` world positions triangulated from the capture poses, metres.
        obs_frame: ``[K]`` frame index of each observation.
        obs_point: ``[K]`` point index of each observation.
        obs_uv: ``[K, 2]`` keypoint position, pixels, with pixel centres at integers as the
            capture's intrinsics (COLMAP's keypoints, which put them at +0.5, less 0.5).
    """

    points: np.ndarray
    obs_frame: np.ndarray
    obs_point: np.ndarray
    obs_uv: np.ndarray


def _tracks(rec, names: list[str]) -> Tracks:
    frame_of = {}
    for image_id, im in rec.images.items():
        if im.name in names:
            frame_of[image_id] = names.index(im.name)
    pts, of, op, uv = [], [], [], []
    for j, (_, p) in enumerate(rec.points3D.items()):
        pts.append(p.xyz)
        for el in p.track.elements:
            if el.image_id not in frame_of:
                continue
            of.append(frame_of[el.image_id])
            op.append(j)
            uv.append(rec.images[el.image_id].points2D[el.point2D_idx].xy - 0.5)
    return Tracks(
        points=np.asarray(pts, np.float64).reshape(-1, 3),
        obs_frame=np.asarray(of, np.int64),
        obs_point=np.asarray(op, np.int64),
        obs_uv=np.asarray(uv, np.float64).reshape(-1, 2),
    )


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """``[N, 3]`` axis-angle vectors to ``[N, 3, 3]`` rotation matrices."""
    theta = np.linalg.norm(w, axis=1)[:, None, None]
    k = np.zeros((len(w), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    k = k - k.transpose(0, 2, 1)
    small = theta < 1e-8
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(t) / t)
    b = np.where(small, 0.5, (1 - np.cos(t)) / t**2)
    return np.eye(3)[None] + a * k + b * (k @ k)


def _sensor_depth_at(capture: Capture, frames: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sensor depth (metres) at RGB pixel positions ``uv`` of ``frames``, bilinear between depth
    pixel centres; NaN where invalid, low confidence, or at a depth edge (the 3x3 neighbourhood
    spans more than 3 cm + 2 %)."""
    _, h, w = capture.depth.shape
    rk = capture.rgb_intrinsics[frames]
    dk = capture.depth_intrinsics[frames]
    # Continuous depth-pixel coordinates with pixel centres at integers, as ``uv``'s.
    ud = (uv[:, 0] - rk[:, 2]) / rk[:, 0] * dk[:, 0] + dk[:, 2]
    vd = (uv[:, 1] - rk[:, 3]) / rk[:, 1] * dk[:, 1] + dk[:, 3]
    ui, vi = np.floor(ud).astype(np.int64), np.floor(vd).astype(np.int64)
    out = np.full(len(uv), np.nan)
    ok = (ui >= 1) & (ui < w - 2) & (vi >= 1) & (vi < h - 2)
    if not ok.any():
        return out
    f, ui, vi, au, av = frames[ok], ui[ok], vi[ok], (ud - np.floor(ud))[ok], (vd - np.floor(vd))[ok]
    patch = np.stack([capture.depth[f, vi + dy, ui + dx] for dy in (-1, 0, 1, 2) for dx in (-1, 0, 1, 2)], 1)
    d00, d01 = capture.depth[f, vi, ui], capture.depth[f, vi, ui + 1]
    d10, d11 = capture.depth[f, vi + 1, ui], capture.depth[f, vi + 1, ui + 1]
    centre = ((1 - av) * ((1 - au) * d00 + au * d01) + av * ((1 - au) * d10 + au * d11)).astype(np.float64)
    with np.errstate(invalid="ignore"):
        flat = np.nanmax(patch, 1) - np.nanmin(patch, 1) < 0.03 + 0.02 * centre
    good = np.isfinite(centre) & flat & np.all(np.isfinite(patch), 1)
    if capture.confidence is not None:
        c = np.minimum.reduce([capture.confidence[f, vi + dy, ui + dx] for dy in (0, 1) for dx in (0, 1)])
        good &= c >= 1
    out[np.flatnonzero(ok)] = np.where(good, centre, np.nan)
    return out


def _triangulate(pycolmap, db_path: Path, image_dir: Path, names: list[str], params: np.ndarray,
                 world_from_camera: np.ndarray, out_dir: Path, config: PoseRefineConfig):
    """A COLMAP reconstruction with the given poses and intrinsics, points triangulated from the
    database's verified matches (COLMAP's point_triangulator)."""
    db = pycolmap.Database.open(db_path)
    try:
        rec = pycolmap.Reconstruction()
        images = {im.name: im for im in db.read_all_images()}
        cameras = {cam.camera_id: cam for cam in db.read_all_cameras()}
        frames = {f.frame_id: f for f in db.read_all_frames()}
        for t, name in enumerate(names):  # the capture's own per-frame intrinsics
            cameras[images[name].camera_id].params = params[t]
        for cam in cameras.values():
            rec.add_camera(cam)
        for rig in db.read_all_rigs():
            rec.add_rig(rig)
        for t, name in enumerate(names):
            frame = frames[images[name].frame_id]
            frame.rig_from_world = pycolmap.Rigid3d(invert_se3(world_from_camera[t])[:3, :4])
            rec.add_frame(frame)
        for name in names:
            rec.add_image(images[name])
    finally:
        db.close()
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = config.num_threads
    options.mapper.num_threads = config.num_threads
    options.random_seed = options.mapper.random_seed = options.triangulation.random_seed = config.seed
    out_dir.mkdir()
    return pycolmap.triangulate_points(rec, db_path, image_dir, out_dir, options=options)


def adjust_with_depth(
    capture: Capture, world_from_camera: np.ndarray, tracks: Tracks, config: PoseRefineConfig,
    distortion: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Bundle adjustment of poses and points with the sensor depth as an extra observation.

    Unknowns: a small rigid correction per frame (``world_from_camera @ D``, starting from the
    given ``[T, 4, 4]`` poses, which also centre the priors) and every point. Residuals
    (robust soft-L1): reprojection error in pixels (through the lens, ``distortion``); the point's camera depth
    minus the sensor depth at the keypoint (looked up where a pinhole camera sees it: the depth map
    is pinhole), divided by the depth noise ``3 mm + 0.2 % z^2`` (about the LiDAR's);
    and weak priors on each correction (``prior_position_std_m``, 2 degrees). Reprojection alone
    cannot tell a small rotation from a sideways translation at low resolution; the depth can,
    and it also fixes the metric scale.

    Returns:
        ``[T, 4, 4]`` adjusted poses (the capture's for frames without observations), ``[T]``
        observations per frame that survived (inlier reprojection < 3 px), RMS reprojection error
        of the inliers in pixels.
    """
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    t_frames, m = capture.num_frames, len(tracks.points)
    fr, pt, uv = tracks.obs_frame, tracks.obs_point, tracks.obs_uv
    k = capture.rgb_intrinsics[fr]
    z_obs = _sensor_depth_at(capture, fr, uv if distortion is None else undistort_pixels(uv, k, distortion))
    has_d = np.isfinite(z_obs)
    sigma_d = 0.003 + 0.002 * np.where(has_d, z_obs, 1.0) ** 2
    cam_from_world0 = np.stack([invert_se3(p) for p in world_from_camera])
    rot_prior = np.radians(2.0)
    n_obs, n_d = len(fr), int(has_d.sum())
    d_idx = np.flatnonzero(has_d)

    def residuals(x: np.ndarray) -> np.ndarray:
        w, v = x[: 3 * t_frames].reshape(-1, 3), x[3 * t_frames : 6 * t_frames].reshape(-1, 3)
        pts = x[6 * t_frames :].reshape(-1, 3)
        r = _rodrigues(w)
        y = np.einsum("kij,kj->ki", cam_from_world0[fr, :3, :3], pts[pt]) + cam_from_world0[fr, :3, 3]
        xc = np.einsum("kji,kj->ki", r[fr], y - v[fr])  # D^-1 applied: R^T (y - v)
        z = np.maximum(xc[:, 2], 1e-3)
        xn, yn = xc[:, 0] / z, xc[:, 1] / z
        if distortion is not None:
            xn, yn = distort_normalized(xn, yn, distortion)
        ru = k[:, 0] * xn + k[:, 2] - uv[:, 0]
        rv = k[:, 1] * yn + k[:, 3] - uv[:, 1]
        rd = (xc[d_idx, 2] - z_obs[d_idx]) / sigma_d[d_idx]
        return np.concatenate([ru, rv, rd, (w / rot_prior).ravel(), (v / config.prior_position_std_m).ravel()])

    n_res = 2 * n_obs + n_d + 6 * t_frames
    n_par = 6 * t_frames + 3 * m
    sparsity = lil_matrix((n_res, n_par), dtype=np.int8)
    rows = np.arange(n_obs)
    for base in (0, n_obs):
        for c in range(3):
            sparsity[base + rows, 3 * fr + c] = 1
            sparsity[base + rows, 3 * t_frames + 3 * fr + c] = 1
            sparsity[base + rows, 6 * t_frames + 3 * pt + c] = 1
    rows_d = 2 * n_obs + np.arange(n_d)
    for c in range(3):
        sparsity[rows_d, 3 * fr[d_idx] + c] = 1
        sparsity[rows_d, 3 * t_frames + 3 * fr[d_idx] + c] = 1
        sparsity[rows_d, 6 * t_frames + 3 * pt[d_idx] + c] = 1
    prior_rows = 2 * n_obs + n_d + np.arange(6 * t_frames)
    sparsity[prior_rows, np.arange(6 * t_frames)] = 1
    x0 = np.concatenate([np.zeros(6 * t_frames), tracks.points.ravel()])
    sol = least_squares(
        residuals, x0, jac_sparsity=sparsity.tocsr(), method="trf", loss="soft_l1", f_scale=1.5,
        x_scale="jac", max_nfev=300, xtol=1e-10, ftol=1e-8,
    )  # fmt: skip
    res = residuals(sol.x)
    err = np.hypot(res[:n_obs], res[n_obs : 2 * n_obs])
    inlier = err < 3.0
    observations = np.bincount(fr[inlier], minlength=t_frames)
    w = sol.x[: 3 * t_frames].reshape(-1, 3)
    v = sol.x[3 * t_frames : 6 * t_frames].reshape(-1, 3)
    r = _rodrigues(w)
    out = np.asarray(world_from_camera, np.float64).copy()
    for t in range(t_frames):
        d = np.eye(4)
        d[:3, :3], d[:3, 3] = r[t], v[t]
        out[t] = out[t] @ d
    rms = float(np.sqrt(np.mean(err[inlier] ** 2))) if inlier.any() else float("nan")
    return out, observations, rms
