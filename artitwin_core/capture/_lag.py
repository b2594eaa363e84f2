"""The lag between a recording's pose stream and its images, from how well its frames' depth agrees.

A phone's AR poses can reach the export late (or early) against the RGB-D frames they are stored
with: frame ``i``'s images are taken at ``timestamps[i]`` but its recorded pose is the camera's at
``timestamps[i] - lag_s``. Every frame's pose is then off by the camera's motion over ``lag_s``,
and the static background, seen through those poses, appears to move with the camera's velocity.
:func:`estimate_pose_lag` finds ``lag_s`` by a 1-D search: the poses are read off the recorded
trajectory (the recording's pose stream, ``Capture.pose_track``, when it holds poses between the
frames) at ``timestamps + lag`` (``interpolate_poses``) and each frame's depth is projected
into nearby frames, where it must meet their depth; the lag at which the most depth agrees wins.

Only depth and poses are compared, never grey levels: when the RGB alone is exposed at another
time than the depth and pose (the effect ``time_offset``) depth and pose still agree, and that is
not a pose lag. The frames are compared with each other, not with a model, so the estimate needs
nothing but the recording: it can run before the registration and the reconstruction that the
lagging poses would spoil. A lag that is a rigid shift of the whole trajectory (a constant
velocity) is invisible to the frames and harmless to everything built on them alike; what they
see, and what matters, is the camera's change of velocity. The moving part and the hand are not
masked (nothing has found them yet): a robust (Geman-McClure) score bounds what each point can
contribute to the coarse search, and the fine search counts only the points that agree with the
other frame's depth near its minimum, which they do not.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.capture._config import PoseLagConfig
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import backproject, interpolate_poses, invert_se3


@dataclass(frozen=True)
class PoseLag:
    """What :func:`estimate_pose_lag` found. The poses are late by ``lag_s`` (negative: early):
    the camera's pose at ``timestamps[i]`` is the recorded trajectory's at ``timestamps[i] + lag_s``
    (:func:`correct_pose_lag`).

    Attributes:
        lag_s: the lag, seconds.
        lag_se_s: its standard error (frame-block jackknife), seconds.
        frame_interval_s: the median spacing of the timestamps, seconds (a "frame").
        pose_interval_s: the median spacing of the poses the trajectory is read off between
            (the pose stream's when the capture has one, else ``frame_interval_s``), seconds.
        lags_frames: ``[G]`` the lags of the coarse search, frame intervals, increasing.
        disagreement: ``[G]`` the score at each: the mean over projected points of the robust
            depth misfit, 0 (every point lands on the depth it predicts) to 1 (none does).
        disagreement_zero: the score at lag 0 (the poses as recorded), over the points that land
            inside the other frame's image both at 0 and at ``lag_s``.
        disagreement_lag: the score at ``lag_s``, over the same points.
        agreement_z: how much better the depth agrees at ``lag_s`` than at 0, in standard errors
            of that difference (frame-block jackknife); 0 when ``lag_s`` is 0.
        residual_zero_m: median absolute depth misfit of the points that land within
            ``robust_scale_m`` of their depth, at lag 0, metres.
        residual_lag_m: the same at ``lag_s``, metres.
        searched_frames: the search range actually used, ``[-searched, +searched]`` frames.
        at_range_end: the best score lies at an end of the search range (the lag may be larger).
        frames_used: frames compared (the ones whose poses stay inside the recorded span).
        pairs: frame pairs compared.
    """

    lag_s: float
    lag_se_s: float
    frame_interval_s: float
    pose_interval_s: float
    lags_frames: np.ndarray
    disagreement: np.ndarray
    disagreement_zero: float
    disagreement_lag: float
    agreement_z: float
    residual_zero_m: float
    residual_lag_m: float
    searched_frames: float
    at_range_end: bool
    frames_used: int
    pairs: int

    @property
    def lag_frames(self) -> float:
        """The lag in frame intervals."""
        return self.lag_s / self.frame_interval_s

    @property
    def z_score(self) -> float:
        """The lag over its standard error (inf when the standard error is 0)."""
        if self.lag_se_s > 0:
            return abs(self.lag_s) / self.lag_se_s
        return math.inf if self.lag_s != 0 else 0.0

    def why_not(self, min_lag_frames: float, min_z: float, min_agreement_z: float) -> str:
        """Why the lag should not be corrected, in words; empty when every test passes: it is at
        least ``min_lag_frames``, ``min_z`` standard errors, and the depth agrees better at it by
        at least ``min_agreement_z``, and it lies inside the search range."""
        if not math.isfinite(self.lag_s):
            return "no lag could be estimated"
        if self.at_range_end:
            return (
                f"the best agreement is at the end of the lags searched ({self.lag_frames:+.2f} frames of "
                f"+-{self.searched_frames:g}); the lag may be larger (raise max_lag_frames) or the depth does not "
                "constrain it"
            )
        if abs(self.lag_frames) < min_lag_frames:
            return f"it is {self.lag_frames:+.2f} frames, less than {min_lag_frames:g}"
        if self.z_score < min_z:
            return f"it is {self.z_score:.1f} standard errors from 0, fewer than {min_z:g}"
        if self.agreement_z < min_agreement_z:
            return (
                f"the frames' depth agrees better at it than at 0 by only {self.agreement_z:.1f} standard errors "
                f"(fewer than {min_agreement_z:g})"
            )
        return ""


def beyond_recorded(timestamps: np.ndarray, lag_s: float, track_timestamps: np.ndarray | None = None) -> np.ndarray:
    """``[T]`` the frames whose time plus ``lag_s`` falls outside the recorded span
    (``track_timestamps``, the pose stream's; default the frames' own ``timestamps [T]``):
    :func:`correct_pose_lag` gives them the end pose (no lag: none)."""
    ts = np.asarray(timestamps, dtype=np.float64)
    span = ts if track_timestamps is None else np.asarray(track_timestamps, dtype=np.float64)
    at = ts + float(lag_s)
    return (at < span[0]) | (at > span[-1])


def correct_pose_lag(world_from_camera: np.ndarray, timestamps: np.ndarray, lag_s: float,
                     track: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``[T, 4, 4]`` poses at the frames' ``timestamps [T]`` from ``world_from_camera [T, 4, 4]``
    recorded ``lag_s`` seconds late (negative: early): the recorded trajectory read at
    ``timestamps + lag_s`` (``interpolate_poses``). The trajectory is ``track`` (``(timestamps
    [S], world_from_camera [S, 4, 4])``, the recording's pose stream, ``Capture.pose_track``) when
    given, else the frames' own poses, whose chords between frames far apart are the
    interpolation's error. The frames whose time falls outside the recorded span (the last
    ``lag_s`` of a late recording) take the end pose: no better than what was recorded, and no
    worse. ``lag_s = 0`` returns a copy."""
    poses = np.asarray(world_from_camera, dtype=np.float64)
    ts = np.asarray(timestamps, dtype=np.float64)
    track_ts, track_poses = (ts, poses) if track is None else (np.asarray(track[0], np.float64), np.asarray(track[1], np.float64))
    if lag_s == 0.0 or track_ts.size < 2:
        return poses.copy()
    return interpolate_poses(track_poses, track_ts, ts + lag_s)


def lag_corrected(capture: Capture, lag_s: float) -> Capture:
    """``capture`` with its frames' poses and its pose stream (when it has one) read ``lag_s``
    later off its pose track (:func:`correct_pose_lag`); everything else as it was."""
    track = capture.pose_track()
    out = dataclasses.replace(capture, world_from_camera=correct_pose_lag(
        capture.world_from_camera, capture.timestamps, lag_s, track))
    if capture.stream_world_from_camera is not None:
        out = dataclasses.replace(out, stream_world_from_camera=correct_pose_lag(track[1], track[0], lag_s))
    return out


@dataclass(frozen=True)
class _Pairs:
    """The points projected between frame pairs: each point in its source camera and its pair,
    and each pair's source and destination frames."""

    points: np.ndarray  # [N, 3] metres, source camera frame
    pair: np.ndarray  # [N] pair index
    src: np.ndarray  # [P] source frame of each pair
    dst: np.ndarray  # [P] destination frame of each pair


def estimate_pose_lag(capture: Capture, config: PoseLagConfig | None = None) -> PoseLag:
    """The lag of ``capture``'s recorded poses behind its RGB-D frames.

    For a lag ``tau`` (frame intervals) every frame's pose is read off the recorded trajectory at
    ``timestamps + tau * frame_interval``. Depth pixels of each frame ``i`` are lifted into 3D and
    projected into frames ``j = i +- gap`` at those poses; where the point lands, ``j``'s depth
    (bilinear, not across a depth edge) should read the point's depth. Each point scores
    ``r^2 / (r^2 + s^2)`` for a misfit ``r`` (``s = robust_scale_m``) and 1 when it lands
    off ``j``'s image or on no depth, so the score is the fraction of depth that disagrees. The lag
    minimises the mean score: a coarse search over ``[-max_lag_frames, +max_lag_frames]``, a finer
    one about its minimum over the points that stay in view across the finer window (a point
    leaving the other frame's view as the lag changes would otherwise tilt the score one way in
    time), and the vertex of a parabola through the best scores. Only frames
    whose poses stay inside the recorded span at every lag searched are compared (no
    extrapolation in the evidence). The standard errors come from redoing the search with blocks
    of consecutive frames left out.

    Args:
        capture: the recording, poses as recorded (``world_from_camera [T, 4, 4]``, ``depth
            [T, h, w]`` metres, ``timestamps [T]`` seconds).
        config: hyperparameters (defaults: ``PoseLagConfig()``).

    Returns:
        A :class:`PoseLag` (seconds, its standard error, and the scores).

    Raises:
        InputError: timestamps that do not increase, or too few frames or too little depth to
            compare (fewer than ``min_frames`` frames once the search range is kept clear of the
            ends, or no usable depth pixels).
    """
    cfg = config or PoseLagConfig()
    ts = np.asarray(capture.timestamps, dtype=np.float64)
    t_count = capture.num_frames
    if t_count < cfg.min_frames or np.any(np.diff(ts) <= 0):
        raise InputError(
            f"pose lag: the recording has {t_count} frames (at least {cfg.min_frames} with increasing timestamps are "
            "needed); record longer, or turn the lag estimate off (pose_lag.correct = false)."
        )
    interval = float(np.median(np.diff(ts)))
    # The range, kept clear of the ends: frame i is compared only if t_i + tau stays in the span.
    margin = min(cfg.max_lag_frames, (t_count - cfg.min_frames) / 2.0)
    margin = math.floor(margin / cfg.coarse_step_frames) * cfg.coarse_step_frames
    if margin < 1.0:
        raise InputError(
            f"pose lag: {t_count} frames leave no room to search a lag of at least one frame while comparing "
            f"{cfg.min_frames} frames; record longer, or turn the lag estimate off (pose_lag.correct = false)."
        )
    reach = margin * interval * (1 - 1e-9)
    track_ts, track_poses = (np.asarray(v, np.float64) for v in capture.pose_track())
    used = np.flatnonzero((ts - track_ts[0] >= reach) & (track_ts[-1] - ts >= reach))
    depth = _usable_depth(capture, cfg)
    pairs = _draw_pairs(depth, capture.depth_intrinsics, used, cfg)
    if pairs.src.size == 0:
        raise InputError(
            f"pose lag: no frame pair of the {used.size} frames compared has usable depth (within {cfg.max_depth_m:g} m, "
            f"confidence >= {cfg.min_confidence}); turn the lag estimate off (pose_lag.correct = false)."
        )
    poses = np.asarray(capture.world_from_camera, dtype=np.float64)
    k = capture.depth_intrinsics

    def at(taus: np.ndarray) -> np.ndarray:
        """``[len(taus), T, 4, 4]`` the poses read at ``timestamps + tau`` frames, every tau at once."""
        times = (ts[None, :] + np.asarray(taus, np.float64)[:, None] * interval).ravel()
        return interpolate_poses(track_poses, track_ts, times).reshape(len(taus), t_count, 4, 4)

    def table(taus: np.ndarray, use: np.ndarray | None = None) -> np.ndarray:
        """``[len(taus), P]`` each pair's summed score at each lag, over the points ``use``."""
        return np.stack([_per_pair(_score_points(p, k, depth, pairs, cfg)[0], pairs, use) for p in at(taus)])

    # Coarse: the whole range, every point (one that leaves the other frame's view scores 1).
    coarse = np.round(np.arange(-margin, margin + 1e-9, cfg.coarse_step_frames), 9)
    coarse_sums = table(coarse)
    best = float(coarse[int(np.argmin(coarse_sums.sum(1)))])
    at_end = abs(best) >= margin - 1e-9
    # Fine: about the coarse minimum, over the points that stay in view across the whole window
    # (no point entering or leaving a frame's view tilts the score one way in time) and that
    # agree with the other frame's depth there to within robust_scale_m: the moving part, the
    # hand and depth edges, whose misfit changes with the lag as the part moves, are left out.
    fine = best + np.arange(-cfg.fine_half_width_frames, cfg.fine_half_width_frames + 1e-9, cfg.fine_step_frames)
    fine = np.round(fine[np.abs(fine) <= margin + 1e-9], 9)
    ends = [_score_points(p, k, depth, pairs, cfg) for p in at([fine[0], best, fine[-1]])]
    with np.errstate(invalid="ignore"):
        use = ends[0][1] & ends[1][1] & ends[2][1] & (np.abs(ends[1][2]) <= cfg.robust_scale_m)
    fine_sums = table(fine, use)
    lag = _vertex(fine, fine_sums.sum(1), cfg.fit_half_width_frames)

    # The agreement at the lag against the poses as recorded, over the points seen at both that
    # agree with the other frame's depth at either (what disagrees at both, the moving part and
    # the hand, says nothing about the lag and only adds noise).
    score_zero, seen_zero, r_zero = _score_points(poses, k, depth, pairs, cfg)
    score_lag, seen_lag, r_lag = _score_points(at([lag])[0], k, depth, pairs, cfg)
    with np.errstate(invalid="ignore"):
        agrees = (np.abs(r_zero) <= cfg.robust_scale_m) | (np.abs(r_lag) <= cfg.robust_scale_m)
    both = seen_zero & seen_lag & agrees
    zero_sums, lag_sums = _per_pair(score_zero, pairs, both), _per_pair(score_lag, pairs, both)
    both_counts = np.bincount(pairs.pair, weights=both, minlength=pairs.src.size)

    # Leave-one-block-out: a block's frames take every pair they are in with them.
    drops, gains = [], []
    for block in np.array_split(used, min(cfg.jackknife_blocks, used.size)):
        keep = ~(np.isin(pairs.src, block) | np.isin(pairs.dst, block))
        if not keep.any() or both_counts[keep].sum() == 0:
            continue
        drops.append(_vertex(fine, fine_sums[:, keep].sum(1), cfg.fit_half_width_frames))
        gains.append((zero_sums[keep].sum() - lag_sums[keep].sum()) / both_counts[keep].sum())
    se, gain_se = _jackknife_se(drops), _jackknife_se(gains)
    gain = float((zero_sums.sum() - lag_sums.sum()) / max(both_counts.sum(), 1.0))
    if gain == 0.0:
        agreement_z = 0.0
    else:
        agreement_z = gain / gain_se if gain_se > 0 else math.copysign(math.inf, gain)
    total = max(both_counts.sum(), 1.0)
    return PoseLag(
        lag_s=float(lag * interval),
        lag_se_s=se * interval,
        frame_interval_s=interval,
        pose_interval_s=float(np.median(np.diff(track_ts))),
        lags_frames=coarse.astype(np.float64),
        disagreement=coarse_sums.sum(1) / pairs.points.shape[0],
        disagreement_zero=float(zero_sums.sum() / total),
        disagreement_lag=float(lag_sums.sum() / total),
        agreement_z=float(agreement_z),
        residual_zero_m=_median_misfit(r_zero, cfg.robust_scale_m),
        residual_lag_m=_median_misfit(r_lag, cfg.robust_scale_m),
        searched_frames=float(margin),
        at_range_end=bool(at_end),
        frames_used=int(used.size),
        pairs=int(pairs.src.size),
    )


def _jackknife_se(estimates: list[float]) -> float:
    """Standard error from leave-one-block-out ``estimates``; inf with fewer than 3."""
    n = len(estimates)
    if n < 3:
        return math.inf
    d = np.asarray(estimates, np.float64)
    return float(np.sqrt((n - 1) / n * np.sum((d - d.mean()) ** 2)))


def _per_pair(score: np.ndarray, pairs: _Pairs, use: np.ndarray | None) -> np.ndarray:
    """``[P]`` the points' ``score [N]`` summed per pair (only the points ``use [N]``, when given)."""
    weights = score if use is None else np.where(use, score, 0.0)
    return np.bincount(pairs.pair, weights=weights, minlength=pairs.src.size)


def _median_misfit(r: np.ndarray, scale: float) -> float:
    near = np.abs(r[np.isfinite(r)])
    near = near[near <= scale]
    return float(np.median(near)) if near.size else math.nan


def _vertex(grid: np.ndarray, score: np.ndarray, half_width: float) -> float:
    """The minimiser of ``score [G]`` over ``grid [G]``: the vertex of a least-squares parabola
    through the scores within ``half_width`` of the best grid point (that point when the fit is
    not convex or its vertex leaves the window)."""
    k = int(np.argmin(score))
    near = np.abs(grid - grid[k]) <= half_width + 1e-9
    if np.count_nonzero(near) < 3:
        return float(grid[k])
    x = grid[near] - grid[k]
    a, b, _ = np.polyfit(x, score[near], 2)
    if a <= 0:
        return float(grid[k])
    v = -b / (2 * a)
    return float(grid[k] + v) if abs(v) <= half_width else float(grid[k])


def _usable_depth(capture: Capture, cfg: PoseLagConfig) -> np.ndarray:
    """``[T, h, w]`` float32 depth, NaN where it is not to be used (too far, low confidence)."""
    d = np.array(capture.depth, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        d[~((d > 0) & (d < cfg.max_depth_m))] = np.nan
    if capture.confidence is not None and cfg.min_confidence > 0:
        d[np.asarray(capture.confidence) < cfg.min_confidence] = np.nan
    return d


def _draw_pairs(depth: np.ndarray, intrinsics: np.ndarray, used: np.ndarray, cfg: PoseLagConfig) -> _Pairs:
    """Every ``(i, i +- gap)`` pair among the ``used`` frames, with pixels of ``i``'s usable
    ``depth [T, h, w]`` drawn for it, lifted into ``i``'s camera frame."""
    rng = np.random.default_rng(cfg.seed)
    members = set(used.tolist())
    src, dst = [], []
    for i in used:
        for gap in cfg.frame_gaps:
            for j in (i - gap, i + gap):
                if j in members:
                    src.append(int(i))
                    dst.append(int(j))
    per_pair = max(10, min(cfg.points_per_frame, cfg.max_points // max(len(src), 1)))
    pixels: dict[int, np.ndarray] = {}
    points, pair_of, keep = [], [], []
    for p, (i, _) in enumerate(zip(src, dst, strict=True)):
        if i not in pixels:
            v, u = np.nonzero(np.isfinite(depth[i]))
            pixels[i] = np.stack([u, v], 1)
        uv = pixels[i]
        if len(uv) == 0:
            continue
        pick = uv[rng.choice(len(uv), min(per_pair, len(uv)), replace=False)]
        z = depth[i][pick[:, 1], pick[:, 0]]
        points.append(backproject(z, intrinsics[i], pick[:, 0], pick[:, 1]))
        pair_of.append(np.full(len(pick), len(keep)))
        keep.append(p)
    if not keep:
        empty = np.zeros(0, np.int64)
        return _Pairs(np.zeros((0, 3)), empty, empty, empty)
    return _Pairs(
        points=np.concatenate(points),
        pair=np.concatenate(pair_of),
        src=np.asarray(src)[keep],
        dst=np.asarray(dst)[keep],
    )


def _score_points(
    world_from_camera: np.ndarray, intrinsics: np.ndarray, depth: np.ndarray, pairs: _Pairs, cfg: PoseLagConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point of ``pairs`` projected into its pair's other frame at the poses ``world_from_camera
    [T, 4, 4]``: its robust score ``[N]`` (0 to 1; 1 where it does not land on that frame's
    depth), whether it lands inside that frame's image ``[N]``, and its depth misfit ``[N]``
    (measured minus predicted, metres; NaN where it does not land on depth)."""
    dst_from_src = invert_se3(world_from_camera[pairs.dst]) @ world_from_camera[pairs.src]  # [P, 4, 4]
    rel = dst_from_src[pairs.pair]
    x = np.einsum("nij,nj->ni", rel[:, :3, :3], pairs.points) + rel[:, :3, 3]
    frame = pairs.dst[pairs.pair]
    k = np.asarray(intrinsics, dtype=np.float64)[frame]
    z = x[:, 2]
    front = z > 1e-3
    zs = np.where(front, z, 1.0)
    u = x[:, 0] / zs * k[:, 0] + k[:, 2]
    v = x[:, 1] / zs * k[:, 1] + k[:, 3]
    _, h, w = depth.shape
    inside = front & (u >= 0) & (u < w - 1) & (v >= 0) & (v < h - 1)
    u0 = np.clip(np.floor(u).astype(np.int64), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(np.int64), 0, h - 2)
    fu, fv = u - u0, v - v0
    q00, q01 = depth[frame, v0, u0], depth[frame, v0, u0 + 1]
    q10, q11 = depth[frame, v0 + 1, u0], depth[frame, v0 + 1, u0 + 1]
    measured = q00 * (1 - fu) * (1 - fv) + q01 * fu * (1 - fv) + q10 * (1 - fu) * fv + q11 * fu * fv
    spread = np.maximum(np.maximum(q00, q01), np.maximum(q10, q11)) - np.minimum(np.minimum(q00, q01), np.minimum(q10, q11))
    with np.errstate(invalid="ignore"):
        landed = inside & np.isfinite(measured) & (spread <= cfg.edge_m)
    r = np.where(landed, measured - z, np.nan)
    r2 = np.where(landed, r, 0.0) ** 2
    score = np.where(landed, r2 / (r2 + cfg.robust_scale_m**2), 1.0)
    return score, inside, r
