"""What the effects look at: the twin's predictions beside the measurement, in the forward model's units.

``ResidualData`` holds, for one recording, the predicted and measured linear RGB, the predicted and
measured depth with the depth-noise model the twin assumes, and (dynamic recording) the joint's
track model against the observed 3D tracks. Effects fit their parameters on it and return a
modified copy (``dataclasses.replace``): a prediction with the effect added, or a measurement with
it corrected. ``target_energy`` measures each kind of residual the same way for every effect, so
"explained fraction" means one thing: ``1 - energy(after) / energy(before)`` on the effect's target.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.geometry import corner_radius_sq
from artitwin_core.joints import JointType, joint_transforms

TARGETS = ("photometric", "depth", "depth-noise", "joint-tracks")

# Field groups of ResidualData, for ``Effect.unaffected_by``: an image effect never reads the
# tracks, and one that reads no depth model never reads the assumed sigma(z).
TRACK_FIELDS = frozenset({"tracks", "tracks_obs", "tracks_valid", "track_noise_m"})
RGB_PREDICTION_FIELDS = frozenset({"rgb_pred", "rgb_pred_hi"})
NOT_READ_BY_IMAGE_EFFECTS = TRACK_FIELDS | {"depth_sigma"}

# Depth residuals beyond this are mismatched surfaces (edges, missing geometry), not sensor effects.
DEPTH_OUTLIER_M = 0.15
DEPTH_NOISE_BINS = 8


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB in [0, 1] (or uint8) -> linear radiance in [0, 1], float32."""
    x = np.asarray(x)
    x = x.astype(np.float32) / 255.0 if x.dtype == np.uint8 else x.astype(np.float32)
    return np.where(x <= 0.04045, x / 12.92, np.power((np.clip(x, 0, 1) + 0.055) / 1.055, 2.4)).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear radiance -> sRGB in [0, 1], float32 (clipped)."""
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


@dataclass(frozen=True)
class TrackModel:
    """The joint's prediction of 3D point tracks.

    A track's closed-state point ``points_closed[i]`` moves to ``motions[t] @ [x, 1]`` at frame t.

    Attributes:
        motions: ``[T, 4, 4]`` world_from_closed part motions the joint predicts (canonical frame).
        points_closed: ``[N, 3]`` metres, latent closed-state positions of the tracks.
        q: ``[T]`` joint state per frame (radians or metres).
        joint_type: ``revolute``, ``prismatic``, ``screw`` or ``fixed``.
        axis: ``[3]`` unit axis, canonical frame.
        pivot: ``[3]`` metres, a point on the axis line.
    """

    motions: np.ndarray
    points_closed: np.ndarray
    q: np.ndarray
    joint_type: JointType
    axis: np.ndarray
    pivot: np.ndarray

    def predict(self) -> np.ndarray:
        """``[T, N, 3]`` predicted track positions, metres."""
        rot, trans = self.motions[:, :3, :3], self.motions[:, :3, 3]
        return np.einsum("tij,nj->tni", rot, self.points_closed) + trans[:, None, :]


def solve_points(motions: np.ndarray, observed: np.ndarray, valid: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Least-squares closed-state points for fixed rigid ``motions [T, 4, 4]``: the mean of the
    back-projected observations ``[T, N, 3]`` over each track's valid frames ``[T, N]``."""
    rot, trans = motions[:, :3, :3], motions[:, :3, 3]
    back = np.einsum("tji,tnj->tni", rot, observed - trans[:, None, :])
    w = valid.astype(np.float64)[..., None]
    n = w.sum(0)
    return np.where(n > 0, (back * w).sum(0) / np.maximum(n, 1), fallback)


@dataclass(frozen=True)
class ResidualData:
    """Predictions and measurements of one recording, in the units the effects model.

    Every block is optional (None when that part of the twin or the capture is missing).

    Attributes:
        rgb_pred: ``[T, H, W, 3]`` float32 predicted linear RGB.
        rgb_meas: ``[T, H, W, 3]`` float32 measured linear RGB.
        rgb_valid: ``[T, H, W]`` bool, pixels to compare (not saturated, rendered).
        rgb_intrinsics: ``[T, 4]`` (fx, fy, cx, cy) pixels of the RGB camera.
        depth_pred: ``[T, h, w]`` float32 predicted z-depth, metres (NaN where none).
        depth_meas: ``[T, h, w]`` float32 measured z-depth, metres (NaN where invalid).
        depth_valid: ``[T, h, w]`` bool, pixels to compare.
        depth_sigma: ``(a_m, b_per_m)`` the depth-noise model sigma(z) = a + b z^2 the twin assumes.
        tracks: the joint's track model (dynamic recording).
        tracks_obs: ``[T2, N, 3]`` observed track positions, metres.
        tracks_valid: ``[T2, N]`` bool.
        track_noise_m: per-coordinate noise of one track observation, metres (the floor).
        timestamps: ``[T]`` seconds of the image frames.
        depth_intrinsics: ``[T, 4]`` (fx, fy, cx, cy) pixels of the depth map.
        world_from_camera: ``[T, 4, 4]`` the recorded camera poses (OpenCV axes) the prediction was
            rendered at; the RGB and depth cameras share them (as ARKit's do).
        rgb_pred_hi: optional ``[T, sH, sW, 3]`` float32 predicted linear RGB sampled ``s`` times
            denser (``s = rgb_pred_scale``): sample (i, j) at RGB pixel ((j + 0.5) / s - 0.5,
            (i + 0.5) / s - 0.5). The displacement effects (lens, timing) resample it instead of
            ``rgb_pred`` (bilinear resampling of a 1x render leaves edges wrong by more than the
            lens moves them) and reduce it to the RGB pixels with ``rgb_pred_sampling``; None:
            they resample ``rgb_pred``.
        rgb_pred_scale: ``s``, 1 when there is no ``rgb_pred_hi``.
        rgb_pred_sampling: how the capture records a pixel from its sub-pixels: ``"box"`` (their
            mean: a sensor integrating over the pixel, or s x s anti-aliasing) or ``"point"`` (the
            centre sub-pixel, odd ``s``: a point-sampled render).
        track_timestamps, track_world_from_camera: optional ``[S]`` seconds (the clock of
            ``timestamps``) and ``[S, 4, 4]`` poses of the recording's pose stream, denser than the
            frames (``Capture.pose_track``), in its own world frame: only the camera's motion
            between times is read off it (the timing effects' image velocity), applied to
            ``world_from_camera``. None: that motion is read off the frames' own poses.
    """

    rgb_pred: np.ndarray | None = None
    rgb_meas: np.ndarray | None = None
    rgb_valid: np.ndarray | None = None
    rgb_intrinsics: np.ndarray | None = None
    depth_pred: np.ndarray | None = None
    depth_meas: np.ndarray | None = None
    depth_valid: np.ndarray | None = None
    depth_sigma: tuple[float, float] = (0.001, 0.002)
    tracks: TrackModel | None = None
    tracks_obs: np.ndarray | None = None
    tracks_valid: np.ndarray | None = None
    track_noise_m: float = 0.002
    timestamps: np.ndarray | None = None
    depth_intrinsics: np.ndarray | None = None
    world_from_camera: np.ndarray | None = None
    rgb_pred_hi: np.ndarray | None = None
    rgb_pred_scale: int = 1
    rgb_pred_sampling: str = "box"
    track_timestamps: np.ndarray | None = None
    track_world_from_camera: np.ndarray | None = None

    @property
    def has_rgb(self) -> bool:
        return self.rgb_pred is not None and self.rgb_meas is not None

    @property
    def has_depth(self) -> bool:
        return self.depth_pred is not None and self.depth_meas is not None

    @property
    def has_tracks(self) -> bool:
        return self.tracks is not None and self.tracks_obs is not None

    @property
    def has_poses(self) -> bool:
        """Recorded poses and timestamps for every image frame (the camera-motion effects need them)."""
        return self.world_from_camera is not None and self.timestamps is not None

    def rgb_residual(self) -> np.ndarray:
        """``[T, H, W, 3]`` measured minus predicted linear RGB (0 outside ``rgb_valid``)."""
        return np.where(self.rgb_valid[..., None], self.rgb_meas - self.rgb_pred, 0.0)

    def changed_from(self, other: ResidualData) -> frozenset[str]:
        """The fields of this data that are not ``other``'s (a field is changed unless it is the
        same object or, for tuples and numbers, an equal value): what an effect's ``apply`` changed."""
        out = []
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if a is b or (isinstance(a, tuple | int | float | str) and a == b):
                continue
            out.append(f.name)
        return frozenset(out)

    def depth_residual(self) -> np.ndarray:
        """``[T, h, w]`` measured minus predicted depth, metres (NaN outside ``depth_valid``)."""
        r = self.depth_meas - self.depth_pred
        return np.where(self.depth_valid & (np.abs(r) < DEPTH_OUTLIER_M), r, np.nan)

    def track_residual(self) -> np.ndarray:
        """``[T, N, 3]`` observed minus predicted track positions, metres (NaN where invalid)."""
        return np.where(self.tracks_valid[..., None], self.tracks_obs - self.tracks.predict(), np.nan)

    def radius(self) -> np.ndarray:
        """``[T, H, W]`` distance from the principal point over the distance to the farthest corner."""
        t_count, h, w = self.rgb_valid.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        out = np.empty((t_count, h, w))
        for t in range(t_count):
            out[t] = np.sqrt(corner_radius_sq(self.rgb_intrinsics[t], u, v, w, h))
        return out


def make_residual_data(
    *,
    rgb_pred=None,
    rgb_meas=None,
    rgb_intrinsics=None,
    rgb_mask=None,
    depth_pred=None,
    depth_meas=None,
    depth_confidence=None,
    depth_sigma: tuple[float, float] = (0.001, 0.002),
    min_confidence: int = 1,
    tracks: TrackModel | None = None,
    tracks_obs=None,
    tracks_valid=None,
    track_noise_m: float = 0.002,
    timestamps=None,
    depth_intrinsics=None,
    world_from_camera=None,
    rgb_pred_hi=None,
    rgb_pred_sampling: str = "box",
    pose_track=None,
) -> ResidualData:
    """Check shapes and build ``ResidualData`` from sRGB images and depth maps.

    Args:
        rgb_pred, rgb_meas: ``[T, H, W, 3]`` sRGB, uint8 or float in [0, 1].
        rgb_intrinsics: ``[T, 4]`` or ``[4]`` (fx, fy, cx, cy) pixels.
        rgb_mask: optional ``[T, H, W]`` bool, pixels the prediction covers (e.g. render alpha > 0.5).
        depth_pred, depth_meas: ``[T, h, w]`` metres; 0 or NaN means no value.
        depth_confidence: optional ``[T, h, w]`` uint8 ARKit confidence; below ``min_confidence`` is ignored.
        depth_sigma: the depth-noise model ``(a_m, b_per_m)`` the twin assumes.
        tracks, tracks_obs ``[T2, N, 3]``, tracks_valid ``[T2, N]``: the joint's track model and observations.
        track_noise_m: per-coordinate noise of a track observation, metres.
        timestamps: ``[T]`` seconds.
        depth_intrinsics: ``[T, 4]`` or ``[4]`` (fx, fy, cx, cy) pixels of the depth map.
        world_from_camera: ``[T, 4, 4]`` the recorded poses the prediction was rendered at.
        rgb_pred_hi: optional ``[T, sH, sW, 3]`` sRGB, the prediction rendered ``s`` times denser
            (integer ``s >= 2``; see ``ResidualData.rgb_pred_hi`` for where its samples lie).
        rgb_pred_sampling: ``"box"`` or ``"point"`` (odd ``s``), see ``ResidualData``.
        pose_track: optional ``(timestamps [S], world_from_camera [S, 4, 4])``, the recording's
            pose stream (``Capture.pose_track``), see ``ResidualData.track_timestamps``.
    """
    kw: dict = {"depth_sigma": (float(depth_sigma[0]), float(depth_sigma[1])), "track_noise_m": float(track_noise_m)}
    if rgb_pred is not None or rgb_meas is not None:
        if rgb_pred is None or rgb_meas is None:
            raise InputError("make_residual_data: give both rgb_pred and rgb_meas, or neither.")
        p, m = srgb_to_linear(rgb_pred), srgb_to_linear(rgb_meas)
        if p.shape != m.shape or p.ndim != 4 or p.shape[-1] != 3:
            raise InputError(
                f"make_residual_data: rgb_pred {p.shape} and rgb_meas {m.shape} must both be [T, H, W, 3]; "
                "render the prediction at the capture's RGB resolution."
            )
        valid = (m.max(-1) < 0.98) & (p.max(-1) < 0.98) & (p.max(-1) > 1e-3)
        if rgb_mask is not None:
            valid &= np.asarray(rgb_mask, dtype=bool)
        if rgb_intrinsics is None:
            raise InputError("make_residual_data: rgb_intrinsics [T, 4] are needed with RGB.")
        k = np.asarray(rgb_intrinsics, dtype=np.float64)
        k = np.broadcast_to(k, (p.shape[0], 4)).copy() if k.ndim == 1 else k
        if k.shape != (p.shape[0], 4):
            raise InputError(f"make_residual_data: rgb_intrinsics has shape {k.shape}; expected [{p.shape[0]}, 4].")
        kw.update(rgb_pred=p, rgb_meas=m, rgb_valid=valid, rgb_intrinsics=k)
        if rgb_pred_hi is not None:
            hi = srgb_to_linear(rgb_pred_hi)
            scale = hi.shape[1] // p.shape[1] if hi.ndim == 4 else 0
            if scale < 2 or hi.shape != (p.shape[0], scale * p.shape[1], scale * p.shape[2], 3):
                raise InputError(
                    f"make_residual_data: rgb_pred_hi has shape {hi.shape}; expected [T, sH, sW, 3] with an "
                    f"integer s >= 2 for rgb_pred {p.shape}: render the prediction at s times the RGB resolution."
                )
            if rgb_pred_sampling not in ("box", "point") or (rgb_pred_sampling == "point" and scale % 2 == 0):
                raise InputError(
                    f"make_residual_data: rgb_pred_sampling is {rgb_pred_sampling!r} with rgb_pred_hi at {scale}x; "
                    "use 'box', or 'point' with an odd scale (its centre sub-pixel is the pixel centre)."
                )
            kw.update(rgb_pred_hi=hi, rgb_pred_scale=int(scale), rgb_pred_sampling=rgb_pred_sampling)
    elif rgb_pred_hi is not None:
        raise InputError("make_residual_data: rgb_pred_hi needs rgb_pred and rgb_meas.")
    if depth_pred is not None or depth_meas is not None:
        if depth_pred is None or depth_meas is None:
            raise InputError("make_residual_data: give both depth_pred and depth_meas, or neither.")
        dp = np.asarray(depth_pred, dtype=np.float32)
        dm = np.asarray(depth_meas, dtype=np.float32)
        if dp.shape != dm.shape or dp.ndim != 3:
            raise InputError(
                f"make_residual_data: depth_pred {dp.shape} and depth_meas {dm.shape} must both be [T, h, w]; "
                "render the predicted depth with the capture's depth intrinsics and size."
            )
        dp = np.where(np.isfinite(dp) & (dp > 0), dp, np.nan).astype(np.float32)
        dm = np.where(np.isfinite(dm) & (dm > 0), dm, np.nan).astype(np.float32)
        dvalid = np.isfinite(dp) & np.isfinite(dm)
        if depth_confidence is not None:
            dvalid &= np.asarray(depth_confidence) >= min_confidence
        kw.update(depth_pred=dp, depth_meas=dm, depth_valid=dvalid)
    if tracks is not None:
        obs = np.asarray(tracks_obs, dtype=np.float64)
        val = np.asarray(tracks_valid, dtype=bool) & np.all(np.isfinite(obs), -1)
        if obs.shape != (tracks.motions.shape[0], tracks.points_closed.shape[0], 3):
            raise InputError(
                f"make_residual_data: tracks_obs has shape {obs.shape}; the track model predicts "
                f"[{tracks.motions.shape[0]}, {tracks.points_closed.shape[0]}, 3]."
            )
        kw.update(tracks=tracks, tracks_obs=np.where(val[..., None], obs, 0.0), tracks_valid=val)
    if timestamps is not None:
        kw["timestamps"] = np.asarray(timestamps, dtype=np.float64)
    n_img = kw["rgb_pred"].shape[0] if "rgb_pred" in kw else kw["depth_pred"].shape[0] if "depth_pred" in kw else None
    if depth_intrinsics is not None:
        k = np.asarray(depth_intrinsics, dtype=np.float64)
        k = np.broadcast_to(k, (n_img or 1, 4)).copy() if k.ndim == 1 else k
        if "depth_pred" not in kw or k.shape != (n_img, 4):
            raise InputError(f"make_residual_data: depth_intrinsics has shape {k.shape}; give it as [T, 4] "
                             "together with depth_pred and depth_meas.")
        kw["depth_intrinsics"] = k
    if world_from_camera is not None:
        poses = np.asarray(world_from_camera, dtype=np.float64)
        if n_img is None or poses.shape != (n_img, 4, 4) or not np.all(np.isfinite(poses)):
            raise InputError(f"make_residual_data: world_from_camera has shape {poses.shape}; give one finite "
                             f"[4, 4] recorded pose per image frame ([{n_img}, 4, 4]).")
        kw["world_from_camera"] = poses
    if "timestamps" in kw and n_img is not None and kw["timestamps"].shape != (n_img,):
        raise InputError(f"make_residual_data: timestamps has shape {kw['timestamps'].shape}; expected [{n_img}].")
    if pose_track is not None:
        ts, poses = (np.asarray(v, dtype=np.float64) for v in pose_track)
        if (ts.ndim != 1 or ts.size < 2 or poses.shape != (ts.size, 4, 4) or np.any(np.diff(ts) <= 0)
                or not np.all(np.isfinite(poses)) or "timestamps" not in kw):
            raise InputError(f"make_residual_data: pose_track holds {ts.shape} times and {poses.shape} poses; give "
                             "increasing [S] seconds and finite [S, 4, 4] poses, with the frames' timestamps.")
        kw.update(track_timestamps=ts, track_world_from_camera=poses)
    return ResidualData(**kw)


def depth_noise_bins(data: ResidualData, n_bins: int = DEPTH_NOISE_BINS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust spread of the depth residual per depth bin, free of any smooth bias in z.

    Within each bin (quantiles of predicted depth) a line in z is removed first, so a depth
    scale error does not pass for noise. Returns ``z [B]`` bin centres (metres), ``spread [B]``
    (1.4826 MAD, metres) and ``count [B]``.
    """
    r = data.depth_residual()
    ok = np.isfinite(r)
    z, r = data.depth_pred[ok].astype(np.float64), r[ok].astype(np.float64)
    if z.size < 50 * n_bins:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    edges = np.quantile(z, np.linspace(0, 1, n_bins + 1))
    idx = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, n_bins - 1)
    zc, spread, count = [], [], []
    for b in range(n_bins):
        sel = idx == b
        zb, rb = z[sel], r[sel]
        if zb.size < 20:
            continue
        coef = np.polyfit(zb - zb.mean(), rb, 1)
        e = rb - np.polyval(coef, zb - zb.mean())
        zc.append(np.median(zb))
        spread.append(1.4826 * np.median(np.abs(e - np.median(e))))
        count.append(zb.size)
    return np.array(zc), np.array(spread), np.array(count, dtype=np.float64)


def target_energy(data: ResidualData, target: str) -> float:
    """The size of one kind of residual (lower is better; the units depend on the target).

    photometric: mean squared linear-RGB residual; depth: mean squared depth residual (m^2);
    depth-noise: mean squared log ratio of the measured depth-residual spread to the assumed
    sigma(z), over depth bins; joint-tracks: mean squared 3D track residual (m^2).
    """
    if target == "photometric":
        if not data.has_rgb or not data.rgb_valid.any():
            return float("nan")
        return float(np.mean((data.rgb_meas - data.rgb_pred)[data.rgb_valid] ** 2))
    if target == "depth":
        if not data.has_depth:
            return float("nan")
        r = data.depth_residual()
        return float(np.nanmean(r**2)) if np.isfinite(r).any() else float("nan")
    if target == "depth-noise":
        if not data.has_depth:
            return float("nan")
        z, spread, count = depth_noise_bins(data)
        if z.size == 0:
            return float("nan")
        a, b = data.depth_sigma
        model = np.maximum(a + b * z**2, 1e-6)
        return float(np.sum(count * np.log(np.maximum(spread, 1e-7) / model) ** 2) / count.sum())
    if target == "joint-tracks":
        if not data.has_tracks:
            return float("nan")
        r = data.track_residual()
        return float(np.nanmean(np.sum(r**2, -1))) if data.tracks_valid.any() else float("nan")
    raise ValueError(f"unknown residual target {target!r}; known: {TARGETS}")


def noise_floor(data: ResidualData, target: str) -> float:
    """The energy ``target_energy`` would have if only sensor noise were left.

    photometric: twice-differenced residual between horizontal neighbours (smooth effects cancel,
    noise does not), as a variance; depth: mean sigma(z)^2 of the assumed noise model;
    depth-noise: the sampling error of the per-bin spreads (MAD of n samples: ~1.36 / (2 n));
    joint-tracks: 3 track_noise_m^2.
    """
    if target == "photometric":
        if not data.has_rgb:
            return float("nan")
        r = data.rgb_residual()
        both = data.rgb_valid[:, :, 1:] & data.rgb_valid[:, :, :-1]
        d = (r[:, :, 1:] - r[:, :, :-1])[both]
        if d.size == 0:
            return float("nan")
        sigma = 1.4826 * np.median(np.abs(d)) / np.sqrt(2.0)
        return float(sigma**2)
    if target == "depth":
        if not data.has_depth:
            return float("nan")
        ok = np.isfinite(data.depth_residual())
        z = data.depth_pred[ok].astype(np.float64)
        a, b = data.depth_sigma
        return float(np.mean((a + b * z**2) ** 2)) if z.size else float("nan")
    if target == "depth-noise":
        if not data.has_depth:
            return float("nan")
        _, _, count = depth_noise_bins(data)
        return float(1.36 / (2 * np.mean(count))) if count.size else float("nan")
    if target == "joint-tracks":
        return 3.0 * data.track_noise_m**2 if data.has_tracks else float("nan")
    raise ValueError(f"unknown residual target {target!r}; known: {TARGETS}")


def per_frame_errors(data: ResidualData) -> dict[str, np.ndarray]:
    """Per-frame RMS residual of each block the data holds, for error curves over time.

    Returns ``{"rgb_rms": [T] linear RGB, "depth_rms_m": [T] metres, "track_rms_m": [T2] metres}``
    (only the blocks present); NaN for frames with nothing to compare.
    """
    out: dict[str, np.ndarray] = {}
    if data.has_rgb:
        sq = np.where(data.rgb_valid[..., None], (data.rgb_meas - data.rgb_pred) ** 2, 0.0).sum((1, 2, 3))
        n = 3 * data.rgb_valid.sum((1, 2))
        out["rgb_rms"] = np.where(n > 0, np.sqrt(sq / np.maximum(n, 1)), np.nan)
    if data.has_depth:
        r = data.depth_residual()
        n = np.isfinite(r).sum((1, 2))
        out["depth_rms_m"] = np.where(n > 0, np.sqrt(np.nansum(r**2, (1, 2)) / np.maximum(n, 1)), np.nan)
    if data.has_tracks:
        d2 = np.where(data.tracks_valid, np.sum(np.nan_to_num(data.track_residual()) ** 2, -1), 0.0)
        n = data.tracks_valid.sum(1)
        out["track_rms_m"] = np.where(n > 0, np.sqrt(d2.sum(1) / np.maximum(n, 1)), np.nan)
    return out


def track_model_from_joint(joint, tracks_obs: np.ndarray, tracks_valid: np.ndarray) -> TrackModel:
    """The track model of a fitted ``artitwin_core.joints.Joint``: its motions at the per-frame ``q``
    and the least-squares closed-state points of the observed tracks ``[T, N, 3]`` (valid ``[T, N]``).

    A screw is kept a screw (pitch included); frames whose ``q`` is NaN predict nothing.
    """
    obs = np.asarray(tracks_obs, dtype=np.float64)
    valid = np.asarray(tracks_valid, dtype=bool) & np.all(np.isfinite(obs), -1)
    q = np.asarray(joint.q, dtype=np.float64)
    if q.shape[0] != obs.shape[0]:
        raise InputError(f"track_model_from_joint: the joint has {q.shape[0]} states; the tracks have {obs.shape[0]} frames.")
    valid &= np.isfinite(q)[:, None]
    qf = np.nan_to_num(q)
    motions = joint_transforms(joint.joint_type, joint.axis, joint.pivot, qf, joint.pitch)
    obs0 = np.where(valid[..., None], obs, 0.0)
    fallback = np.nanmean(np.where(valid[..., None], obs, np.nan), 0)
    points = solve_points(motions, obs0, valid, np.nan_to_num(fallback))
    return TrackModel(motions, points, qf, joint.joint_type, np.asarray(joint.axis, np.float64),
                      np.asarray(joint.pivot, np.float64))
