"""Record3D metadata: parsing the JSON both Record3D formats share, and writing it back.

Keys (checked on real captures, see CAPTURE_FORMATS.md): ``w, h`` RGB size, ``dw, dh`` depth size,
``fps``, ``K`` (9 floats, column-major, at RGB resolution), ``poses`` (N x [qx, qy, qz, qw, tx, ty,
tz], camera-to-world in OpenGL camera axes), optional ``perFrameIntrinsicCoeffs`` (N x [fx, fy, cx,
cy]), ``frameTimestamps`` (s), ``initPose``, ``cameraType`` (1 = LiDAR).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.capture._common import PoseStream, check_side, input_error, pose_stream
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import OPENGL_FROM_OPENCV, make_se3, matrix_to_quat_wxyz, quat_wxyz_to_matrix

_FIX_META = "Re-export the recording from Record3D; the metadata is damaged or from an unknown version."


@dataclass(frozen=True)
class Record3dMeta:
    """Parsed Record3D metadata (arrays float64).

    Attributes:
        rgb_wh: RGB ``(width, height)`` in pixels.
        depth_wh: depth ``(width, height)`` in pixels, or ``None`` when the file predates ``dw, dh``.
        fps: frame rate in Hz.
        intrinsics: ``[4]`` ``(fx, fy, cx, cy)`` at RGB resolution from ``K``.
        poses: ``[N, 7]`` raw ``[qx, qy, qz, qw, tx, ty, tz]`` rows (OpenGL camera-to-world).
        per_frame_intrinsics: ``[N, 4]`` or ``None``.
        timestamps: ``[N]`` seconds or ``None``.
        camera_type: ``cameraType`` (1 = LiDAR, 0 = FaceID) or ``None``.
    """

    rgb_wh: tuple[int, int]
    depth_wh: tuple[int, int] | None
    fps: float
    intrinsics: np.ndarray
    poses: np.ndarray
    per_frame_intrinsics: np.ndarray | None
    timestamps: np.ndarray | None
    camera_type: int | None

    @property
    def num_poses(self) -> int:
        return int(self.poses.shape[0])

    def world_from_camera(self, index: int, source: str | Path) -> np.ndarray:
        """OpenCV camera-to-world ``[4, 4]`` for pose row ``index`` (= file frame number)."""
        row = self.poses[index]
        if not np.all(np.isfinite(row)):
            raise input_error(source, f"poses[{index}] contains NaN or infinity",
                              "The tracking was lost for this frame; remove it or re-record.", index)
        qx, qy, qz, qw = row[:4]
        norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        # Stored as float32 by the app: unit to ~1e-6. Far from 1 means a damaged pose, not rounding.
        if abs(norm - 1.0) > 1e-2:
            raise input_error(source, f"poses[{index}] has a quaternion of norm {norm:.4g}, not a rigid rotation",
                              "The tracking data is damaged; re-export the recording or remove the frame.", index)
        world_from_gl = make_se3(quat_wxyz_to_matrix(np.array([qw, qx, qy, qz])), row[4:7])
        return world_from_gl @ OPENGL_FROM_OPENCV

    def frame_intrinsics(self, index: int) -> np.ndarray:
        """``[4]`` RGB intrinsics of file frame ``index`` (per-frame when the file has them)."""
        if self.per_frame_intrinsics is not None:
            return self.per_frame_intrinsics[index].copy()
        return self.intrinsics.copy()

    def frame_time(self, index: int) -> float:
        """Seconds since the recording's first frame for file frame ``index``."""
        if self.timestamps is not None:
            return float(self.timestamps[index] - self.timestamps[0])
        return index / self.fps


    def pose_stream(self, with_frames: set[int], source: str | Path) -> PoseStream:
        """Every pose row as a :class:`PoseStream` (rows that are not a rigid pose, and an
        exporter's repeats in place of removed frames, left out); ``with_frames``: the frame
        numbers whose files exist."""
        poses = []
        for i in range(self.num_poses):
            try:
                poses.append(self.world_from_camera(i, source))
            except InputError:
                poses.append(None)
        ids = range(self.num_poses)
        return pose_stream(ids, [self.frame_time(i) for i in ids], poses, [i in with_frames for i in ids])


def _float_array(meta: dict, key: str, source: str | Path, shape_tail: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(meta[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise input_error(source, f"field {key!r} is not a list of numbers", _FIX_META) from exc
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        want = "N x " + " x ".join(map(str, shape_tail)) if shape_tail else "a list"
        raise input_error(source, f"field {key!r} has shape {list(arr.shape)}, expected {want}", _FIX_META)
    return arr


def parse_metadata(meta: object, source: str | Path) -> Record3dMeta:
    """Validate Record3D metadata (already JSON-decoded) from file ``source``."""
    if not isinstance(meta, dict):
        raise input_error(source, "the metadata is not a JSON object", _FIX_META)
    for key in ("w", "h", "K", "poses"):
        if key not in meta:
            raise input_error(source, f"the metadata has no {key!r} field", _FIX_META)
    rgb_wh = (check_side(source, "w", meta["w"]), check_side(source, "h", meta["h"]))
    depth_wh = None
    if "dw" in meta or "dh" in meta:
        depth_wh = (check_side(source, "dw", meta.get("dw")), check_side(source, "dh", meta.get("dh")))

    k = _float_array(meta, "K", source, ())
    if k.shape != (9,) or not np.all(np.isfinite(k)):
        raise input_error(source, f"field 'K' must hold 9 finite numbers, got {k.tolist()}", _FIX_META)
    if abs(k[2]) > 1e-6 or abs(k[5]) > 1e-6 or abs(k[8] - 1) > 1e-6:
        raise input_error(source, f"field 'K' = {k.tolist()} is not a column-major pinhole matrix "
                          "(expected K[2] = K[5] = 0 and K[8] = 1)", _FIX_META)
    intr = np.array([k[0], k[4], k[6], k[7]])
    if intr[0] <= 0 or intr[1] <= 0:
        raise input_error(source, f"field 'K' has focal lengths {intr[:2].tolist()}; they must be positive",
                          _FIX_META)

    poses = _float_array(meta, "poses", source, (7,))
    if poses.shape[0] == 0:
        raise input_error(source, "the metadata holds no poses", "The recording is empty; record again.")
    n = poses.shape[0]

    per_frame = None
    if meta.get("perFrameIntrinsicCoeffs") is not None:
        per_frame = _float_array(meta, "perFrameIntrinsicCoeffs", source, (4,))
        if per_frame.shape[0] < n:
            raise input_error(source, f"'perFrameIntrinsicCoeffs' has {per_frame.shape[0]} rows for {n} poses",
                              _FIX_META)
        bad = np.flatnonzero(~np.all(np.isfinite(per_frame), 1) | np.any(per_frame[:, :2] <= 0, 1))
        if bad.size:
            raise input_error(source, f"'perFrameIntrinsicCoeffs' row {int(bad[0])} is "
                              f"{per_frame[bad[0]].tolist()} (non-finite or non-positive focal length)",
                              _FIX_META, int(bad[0]))

    stamps = None
    if meta.get("frameTimestamps") is not None:
        stamps = _float_array(meta, "frameTimestamps", source, ())
        if stamps.shape[0] < n:
            raise input_error(source, f"'frameTimestamps' has {stamps.shape[0]} entries for {n} poses", _FIX_META)
        if not np.all(np.isfinite(stamps[:n])):
            raise input_error(source, "'frameTimestamps' contains NaN or infinity", _FIX_META)

    fps = meta.get("fps")
    if fps is None:
        if stamps is None:
            raise input_error(source, "the metadata has neither 'fps' nor 'frameTimestamps'", _FIX_META)
        fps = 30.0
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not 0 < fps < 10000:
        raise input_error(source, f"field 'fps' is {fps!r}, expected a positive frame rate", _FIX_META)

    cam = meta.get("cameraType")
    return Record3dMeta(
        rgb_wh=rgb_wh, depth_wh=depth_wh, fps=float(fps), intrinsics=intr, poses=poses,
        per_frame_intrinsics=per_frame, timestamps=stamps,
        camera_type=int(cam) if isinstance(cam, int | float) and not isinstance(cam, bool) else None,
    )


def default_depth_wh(rgb_wh: tuple[int, int]) -> tuple[int, int]:
    """LiDAR depth size for files that predate ``dw, dh``: 192x256, oriented like the RGB."""
    return (192, 256) if rgb_wh[1] >= rgb_wh[0] else (256, 192)


def _nearest(ids: np.ndarray, n_total: int) -> np.ndarray:
    """For every index 0..n_total-1, the position in sorted ``ids`` of the nearest id."""
    pos = np.clip(np.searchsorted(ids, np.arange(n_total)), 1, len(ids) - 1) if len(ids) > 1 else None
    if pos is None:
        return np.zeros(n_total, dtype=int)
    left = ids[pos - 1]
    right = ids[pos]
    take_left = np.abs(np.arange(n_total) - left) <= np.abs(right - np.arange(n_total))
    return np.where(take_left, pos - 1, pos)


def build_metadata(capture: Capture) -> dict:
    """Record3D metadata for ``capture``. Frame numbers without a frame take the capture's pose
    stream's pose and time where it has one (``Capture.stream_*``: a phone records a pose for every
    frame, and the app's export keeps them when frames are removed); the rest repeat the nearest
    known pose, with times interpolated (a reader leaves such repeats out of the stream)."""
    ids = np.asarray(capture.frame_ids, dtype=np.int64)
    known_ids, known_ts, known_poses = ids, capture.timestamps, capture.world_from_camera
    if capture.stream_frame_ids is not None and capture.stream_world_from_camera is not None:
        extra = ~np.isin(capture.stream_frame_ids, ids)
        known_ids = np.concatenate([ids, capture.stream_frame_ids[extra]])
        known_ts = np.concatenate([capture.timestamps, capture.stream_timestamps[extra]])
        known_poses = np.concatenate([capture.world_from_camera, capture.stream_world_from_camera[extra]])
        order = np.argsort(known_ids)
        known_ids, known_ts, known_poses = known_ids[order], known_ts[order], known_poses[order]
    n_total = int(known_ids[-1]) + 1
    near = _nearest(known_ids, n_total)
    world_from_gl = known_poses @ OPENGL_FROM_OPENCV
    q = matrix_to_quat_wxyz(world_from_gl[:, :3, :3])
    rows = np.concatenate([q[:, 1:], q[:, :1], world_from_gl[:, :3, 3]], axis=1)[near]
    intr = capture.rgb_intrinsics[_nearest(ids, n_total)]
    stamps = np.interp(np.arange(n_total), known_ids, known_ts)
    fx, fy, cx, cy = capture.rgb_intrinsics[0]
    dt = np.diff(capture.timestamps) / np.maximum(np.diff(ids), 1)
    fps = float(1.0 / np.median(dt)) if dt.size and np.median(dt) > 0 else 30.0
    w, h = capture.rgb_size
    dw, dh = capture.depth_size
    return {
        "w": w, "h": h, "dw": dw, "dh": dh, "fps": round(fps, 6),
        "K": [float(fx), 0.0, 0.0, 0.0, float(fy), 0.0, float(cx), float(cy), 1.0],
        "poses": rows.tolist(),
        "initPose": rows[0].tolist(),
        "perFrameIntrinsicCoeffs": intr.tolist(),
        "frameTimestamps": stamps.tolist(),
        "cameraType": 1,
    }
