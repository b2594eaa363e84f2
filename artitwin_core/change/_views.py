"""The part finder's view of the data: each dynamic frame in the canonical frame
(:class:`FrameView`, its observed depth beside the canonical model rendered there), and one moving
part with its 1-DOF motion (:class:`PartModel`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from artitwin_core.capture import Capture
from artitwin_core.change._canonical import CanonicalMesh
from artitwin_core.geometry import axis_angle_to_matrix, make_se3, nearest_pixel, project
from artitwin_core.joints import JointType
from artitwin_core.registration import backproject


@dataclass(frozen=True)
class PartModel:
    """One moving part: its closed surface samples and its 1-DOF motion.

    Attributes:
        closed_points: ``[N, 3]`` metres, samples of the part's surface when closed (canonical).
        joint_type: ``"revolute"`` or ``"prismatic"``.
        axis: ``[3]`` unit joint axis (canonical frame).
        pivot: ``[3]`` a point on the axis (revolute), metres.
        reference_frame: the frame whose motion defined the joint.
        reference_q: the joint state there (radians or metres, signed along ``axis``).
        onset_frame: first frame in which the part was seen to have moved.
        front_normal: ``[3]`` unit outward normal of the closed front face (canonical frame).
        hidden: its samples are surface hidden by something nearer, not surface seen vanished
            (``find_moved_parts(..., hidden=True)``): larger than the part by the perspective,
            their rim floats in front of the scene once moved out, which contradicts nothing.
    """

    closed_points: np.ndarray
    joint_type: JointType
    axis: np.ndarray
    pivot: np.ndarray
    reference_frame: int
    reference_q: float
    onset_frame: int
    front_normal: np.ndarray
    hidden: bool = False

    def motion(self, q: float) -> np.ndarray:
        """``[4, 4]`` canonical-from-closed transform at joint state ``q``."""
        if self.joint_type == "prismatic":
            return make_se3(np.eye(3), self.axis * q)
        rot = axis_angle_to_matrix(self.axis, q)
        return make_se3(rot, self.pivot - rot @ self.pivot)


@dataclass
class FrameView:
    """One dynamic frame in the canonical frame: observed depth and the canonical rendering.

    Attributes:
        world_from_camera: ``[4, 4]`` camera pose in the canonical frame.
        depth_intrinsics: ``(fx, fy, cx, cy)`` at depth resolution.
        observed_depth, rendered_depth: ``[h, w]`` float32 metres, NaN invalid.
        timestamp_s: seconds since the recording's first frame (NaN: unknown, frames are then
            taken as 1/15 s apart).
    """

    world_from_camera: np.ndarray
    depth_intrinsics: np.ndarray
    observed_depth: np.ndarray
    rendered_depth: np.ndarray
    timestamp_s: float = float("nan")
    cache: dict = field(default_factory=dict, repr=False)


def frame_views(dynamic: Capture, canonical_from_session: np.ndarray, mesh: CanonicalMesh) -> list[FrameView]:
    """Render the canonical mesh at every dynamic pose (depth resolution)."""
    h, w = dynamic.depth.shape[1:]
    out = []
    for t in range(dynamic.num_frames):
        pose = canonical_from_session @ dynamic.world_from_camera[t]
        _, depth, _ = mesh.render(pose, dynamic.depth_intrinsics[t], w, h)
        obs = np.where(dynamic.depth[t] > 0, dynamic.depth[t], np.nan).astype(np.float32)
        out.append(FrameView(pose, dynamic.depth_intrinsics[t], obs, depth, float(dynamic.timestamps[t])))
    return out


def _to_world(view: FrameView, depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    d = np.where(mask, depth, np.nan)
    pts, _ = backproject(d, view.depth_intrinsics)
    return pts @ view.world_from_camera[:3, :3].T + view.world_from_camera[:3, 3]


def _depth_pixels(view: FrameView, cam: np.ndarray, min_z: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The depth pixel of each camera point ``cam [..., 3]`` (metres): column ``u``, row ``v``
    (int64, nearest pixel centre), its z (metres) and ``ok``: in front of the camera by more than
    ``min_z`` and inside the depth image."""
    uv, z = project(cam, view.depth_intrinsics, min_z=min_z)
    u, v = nearest_pixel(uv)
    h, w = view.observed_depth.shape
    ok = (z > min_z) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return u, v, z, ok
