"""A joint's states on the RGB clock when the depth map and pose are recorded later than the RGB.

Some capture apps stamp a frame with its RGB exposure but record its depth map and pose a little
later (the diagnosis's ``time_offset`` effect fits that lag, ``seconds``). Every state the joint
stages measure is read from a frame's depth and pose: the depth refit fits the part's surface in
the depth map, and the tracks are lifted along their rays by it. So the state of frame ``i`` is
the part's at ``timestamps[i] + seconds``, while the twin renders and compares frame ``i`` at its
RGB exposure, ``timestamps[i]``. ``to_rgb_clock`` moves the states to that clock by
interpolating between the frames (a lag of half a frame shifts the state by half its change).

What it gains through the whole pipeline is measured in docs/accuracy.md.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.geometry import relative_motion
from artitwin_core.joints._types import Joint


def _check_clock(ts: np.ndarray, depth_late_s: float) -> None:
    if not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
        raise InputError("timestamps must be finite and strictly increasing (seconds of each frame's RGB exposure)")
    span = float(ts[-1] - ts[0]) if ts.size > 1 else 0.0
    if not np.isfinite(depth_late_s) or abs(depth_late_s) > span:
        raise InputError(
            f"time offset {depth_late_s!r} s must be finite and within the recording's {span:.3f} s; it is the "
            "lag of the depth map and pose behind the RGB, as the diagnosis's time_offset reports it"
        )


def to_rgb_clock(joint: Joint, timestamps: np.ndarray, depth_late_s: float) -> Joint:
    """``joint`` with ``q``, ``confidence`` and ``residual`` moved from the depth clock to the RGB one.

    Args:
        joint: states ``q [T]`` measured from frames whose depth map and pose were recorded at
            ``timestamps + depth_late_s``.
        timestamps: ``[T]`` seconds of the frames' RGB exposures, strictly increasing.
        depth_late_s: how much later than the RGB the depth map and pose are recorded, seconds
            (the diagnosis's ``time_offset`` ``seconds``; negative when the RGB is the later one).

    Returns:
        The joint with each frame's values interpolated (linearly, between the frames that have
        a ``q``) at its RGB time; frames before the first or after the last such frame hold its
        values, and frames without a ``q`` stay without one. ``q_range`` is recomputed; the
        line, type and standard errors are unchanged.

    Raises:
        InputError: timestamps of another length than ``q``, not finite or not increasing, or a
            lag that is not finite or exceeds the recording's duration.
    """
    ts = np.asarray(timestamps, dtype=np.float64)
    q = np.asarray(joint.q, dtype=np.float64)
    if ts.shape != q.shape:
        raise InputError(f"timestamps has shape {ts.shape} but the joint has {q.shape[0]} states; pass the recording's frame timestamps")
    _check_clock(ts, depth_late_s)
    has = np.isfinite(q)
    if depth_late_s == 0.0 or has.sum() < 2:
        return joint
    measured_at = ts[has] + depth_late_s

    def at_rgb(values: np.ndarray) -> np.ndarray:
        v = np.asarray(values, dtype=np.float64)[has]
        ok = np.isfinite(v)
        if ok.sum() < 2:
            return np.asarray(values, dtype=np.float64).copy()
        return np.interp(ts, measured_at[ok], v[ok])

    q_new = np.where(has, at_rgb(q), np.nan)
    conf = np.where(has, at_rgb(joint.confidence), np.asarray(joint.confidence, dtype=np.float64))
    res = np.where(has, at_rgb(joint.residual), np.asarray(joint.residual, dtype=np.float64))
    return replace(
        joint, q=q_new, confidence=conf, residual=res,
        q_range=np.array([float(np.nanmin(q_new)), float(np.nanmax(q_new))]),
    )  # fmt: skip


def poses_on_rgb_clock(world_from_camera: np.ndarray, timestamps: np.ndarray, depth_late_s: float,
                       track: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``[T, 4, 4]`` camera poses at the frames' RGB exposures, from poses recorded
    ``depth_late_s`` later (with the depth maps). With ``track`` (``(timestamps [S],
    world_from_camera [S, 4, 4])``, the recording's pose stream on the frames' clock, in any world
    frame) each pose is moved by the stream's motion over ``-depth_late_s``
    (``geometry.relative_motion``); without, rotations by spherical interpolation, centres
    linearly, between the recorded poses. Frames outside their span hold the nearest one.

    Raises:
        InputError: ``world_from_camera`` not ``[T, 4, 4]`` for the ``[T]`` timestamps, or a
            clock as ``to_rgb_clock`` refuses it.
    """
    from scipy.spatial.transform import Rotation, Slerp

    poses = np.asarray(world_from_camera, dtype=np.float64)
    ts = np.asarray(timestamps, dtype=np.float64)
    if poses.shape != (ts.shape[0], 4, 4):
        raise InputError(f"world_from_camera has shape {poses.shape}; expected ({ts.shape[0]}, 4, 4) for the timestamps")
    _check_clock(ts, depth_late_s)
    if depth_late_s == 0.0 or ts.size < 2:
        return poses.copy()
    if track is not None:
        track_ts, track_poses = (np.asarray(v, dtype=np.float64) for v in track)
        return poses @ relative_motion(track_poses, track_ts, ts, ts - depth_late_s)
    recorded_at = ts + depth_late_s
    at = np.clip(ts, recorded_at[0], recorded_at[-1])
    out = poses.copy()
    out[:, :3, :3] = Slerp(recorded_at, Rotation.from_matrix(poses[:, :3, :3]))(at).as_matrix()
    out[:, :3, 3] = np.stack([np.interp(at, recorded_at, poses[:, i, 3]) for i in range(3)], 1)
    return out
