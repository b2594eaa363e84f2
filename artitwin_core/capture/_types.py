"""The in-memory form of one RGB-D recording, whatever format it was read from."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Capture:
    """One RGB-D recording in ArtiTwin's conventions.

    Cameras follow OpenCV axes (x right, y down, z forwards); poses are camera-to-world
    (``world_from_camera``) in metres, in the recording's own world frame (its AR session).
    RGB and depth may differ in resolution; each has its own pinhole intrinsics.

    Attributes:
        rgb: ``[T, H, W, 3]`` uint8 sRGB frames.
        depth: ``[T, h, w]`` float32 metres along the optical axis (z-depth); NaN = no measurement.
        confidence: ``[T, h, w]`` uint8 ARKit confidence (0 low, 1 medium, 2 high), or ``None``.
        rgb_intrinsics: ``[T, 4]`` float64 ``(fx, fy, cx, cy)`` in pixels at RGB resolution.
        depth_intrinsics: ``[T, 4]`` float64 ``(fx, fy, cx, cy)`` in pixels at depth resolution.
        world_from_camera: ``[T, 4, 4]`` float64 camera-to-world rigid transforms (OpenCV axes).
        timestamps: ``[T]`` float64 seconds since the first frame of the recording.
        frame_ids: ``[T]`` int64 frame numbers in the source files (may have gaps).
        distortion: ``[K]`` float64 OpenCV coefficients ``k1 k2 p1 p2 [k3 ...]`` or ``None``
            (images are pinhole).
        source_format: which reader produced this (``record3d-r3d``, ``nerfstudio``, ...).
        stream_world_from_camera: ``[S, 4, 4]`` every pose the recording holds, as recorded, the
            frames' and those of the frames not read (a Record3D export with frames removed, a
            strided or keyframed read: a phone records poses at 30-60 Hz); ``None`` when it holds
            no pose beyond the frames'. The pose-lag correction reads the trajectory off it
            rather than off the frames' poses alone, which can be far apart. Stages that correct
            the frames' poses later (drift, refinement) leave it as it was.
        stream_timestamps: ``[S]`` increasing seconds, on the clock of ``timestamps``, of
            ``stream_world_from_camera``; it holds every frame's time, at the frame's pose.
        stream_frame_ids: ``[S]`` frame numbers of the stream's poses in the source files.
    """

    rgb: np.ndarray
    depth: np.ndarray
    confidence: np.ndarray | None
    rgb_intrinsics: np.ndarray
    depth_intrinsics: np.ndarray
    world_from_camera: np.ndarray
    timestamps: np.ndarray
    frame_ids: np.ndarray
    distortion: np.ndarray | None = None
    source_format: str = "unknown"
    stream_world_from_camera: np.ndarray | None = None
    stream_timestamps: np.ndarray | None = None
    stream_frame_ids: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return int(self.rgb.shape[0])

    @property
    def rgb_size(self) -> tuple[int, int]:
        """``(width, height)`` of the RGB frames in pixels."""
        return int(self.rgb.shape[2]), int(self.rgb.shape[1])

    @property
    def depth_size(self) -> tuple[int, int]:
        """``(width, height)`` of the depth maps in pixels."""
        return int(self.depth.shape[2]), int(self.depth.shape[1])

    def pose_track(self) -> tuple[np.ndarray, np.ndarray]:
        """``(timestamps [S], world_from_camera [S, 4, 4])``: the densest recorded trajectory the
        capture holds, its pose stream when it has one, else its frames' poses."""
        return self.stream_track() or (self.timestamps, self.world_from_camera)

    def stream_track(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(stream_timestamps [S], stream_world_from_camera [S, 4, 4])``, or ``None`` when the
        capture holds no poses beyond its frames'."""
        if self.stream_world_from_camera is None or self.stream_timestamps is None:
            return None
        return self.stream_timestamps, self.stream_world_from_camera

    def select_frames(self, index) -> Capture:
        """The recording restricted to the frames ``index`` (a slice or indices), in that order
        (the pose stream is kept whole: it is the recording's, not the frames')."""
        idx = np.arange(self.num_frames)[index]
        return dataclasses.replace(
            self, rgb=self.rgb[idx], depth=self.depth[idx],
            confidence=None if self.confidence is None else self.confidence[idx],
            rgb_intrinsics=self.rgb_intrinsics[idx], depth_intrinsics=self.depth_intrinsics[idx],
            world_from_camera=self.world_from_camera[idx], timestamps=self.timestamps[idx], frame_ids=self.frame_ids[idx],
        )


def intrinsics_matrix(fx_fy_cx_cy: np.ndarray) -> np.ndarray:
    """``[..., 4]`` ``(fx, fy, cx, cy)`` to ``[..., 3, 3]`` pinhole matrices K."""
    p = np.asarray(fx_fy_cx_cy, dtype=np.float64)
    k = np.zeros(p.shape[:-1] + (3, 3))
    k[..., 0, 0], k[..., 1, 1], k[..., 0, 2], k[..., 1, 2] = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    k[..., 2, 2] = 1.0
    return k
