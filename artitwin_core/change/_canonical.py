"""A geometric stand-in for the canonical model: a TSDF mesh of the static recording, ray-cast.

The change detector only needs rendered canonical RGB and depth per dynamic frame, from any
renderer (the Gaussian splatting twin once trained). This TSDF mesh is the robust geometric
baseline: it needs no training, and its triangle ids tell which canonical surface a pixel sees.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture
from artitwin_core.geometry import invert_se3, pixel_grid, pixel_rays


@dataclass
class CanonicalMesh:
    """A triangle mesh of the static scene (canonical frame) and a ray-casting scene over it.

    Attributes:
        vertices: ``[V, 3]`` float64 metres, canonical frame.
        triangles: ``[F, 3]`` int32 vertex indices.
        colors: ``[V, 3]`` float64 RGB in [0, 1].
    """

    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray

    def __post_init__(self) -> None:
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(self.vertices.astype(np.float32)), o3d.core.Tensor(self.triangles.astype(np.uint32))
        )

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """``[N]`` metres from ``points [N, 3]`` to the nearest surface, positive on the side the
        static cameras saw (free space), negative behind the surface."""
        res = self._scene.compute_closest_points(o3d.core.Tensor(np.asarray(points, dtype=np.float32)))
        near = res["points"].numpy().astype(np.float64)
        normal = res["primitive_normals"].numpy().astype(np.float64)
        return np.sum((points - near) * normal, axis=1)

    def render(
        self, world_from_camera: np.ndarray, intrinsics, width: int, height: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ray-cast the mesh from one pinhole camera (OpenCV axes, canonical frame).

        Args:
            world_from_camera: ``[4, 4]`` camera pose in the canonical frame.
            intrinsics: ``(fx, fy, cx, cy)`` pixels at the requested resolution.
            width, height: image size in pixels.

        Returns:
            rgb ``[H, W, 3]`` uint8 (vertex colours, barycentric), depth ``[H, W]`` float32 z-depth
            metres (NaN = no surface), triangle ``[H, W]`` int64 hit triangle id (-1 = none).
        """
        dirs_cam = pixel_rays(intrinsics, *pixel_grid(width, height))
        rot, origin = world_from_camera[:3, :3], world_from_camera[:3, 3]
        dirs = dirs_cam @ rot.T
        rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], -1).astype(np.float32)
        hit = self._scene.cast_rays(o3d.core.Tensor(rays))
        t_hit = hit["t_hit"].numpy()  # along dirs whose camera z is 1: t is z-depth
        tri = hit["primitive_ids"].numpy().astype(np.int64)
        ok = np.isfinite(t_hit)
        tri[~ok] = -1
        depth = np.where(ok, t_hit, np.nan).astype(np.float32)
        uvw = hit["primitive_uvs"].numpy()
        rgb = np.zeros((height, width, 3), dtype=np.float64)
        if ok.any():
            corners = self.triangles[tri[ok]]  # [N, 3]
            b1, b2 = uvw[ok, 0], uvw[ok, 1]
            b0 = 1.0 - b1 - b2
            rgb[ok] = (b0[:, None] * self.colors[corners[:, 0]] + b1[:, None] * self.colors[corners[:, 1]]
                       + b2[:, None] * self.colors[corners[:, 2]])
        return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8), depth, tri


def build_canonical_tsdf(
    static: Capture,
    *,
    voxel_m: float = 0.02,
    max_depth_m: float = 4.5,
    min_confidence: int = 1,
    max_frames: int = 20,
    world_from_camera: np.ndarray | None = None,
) -> CanonicalMesh:
    """Fuse the static recording into a TSDF and extract its mesh (canonical frame).

    Args:
        static: the static recording; its poses are the canonical frame unless
            ``world_from_camera`` ``[T, 4, 4]`` overrides them (e.g. refined poses).
        voxel_m: TSDF voxel size (metres); truncation is 4 voxels.
        max_depth_m: depth beyond this is not fused.
        min_confidence: ARKit confidence below this is not fused.
        max_frames: fuse at most this many frames, evenly spaced (fusion cost grows with them).
    """
    poses = static.world_from_camera if world_from_camera is None else np.asarray(world_from_camera)
    if poses.shape != (static.num_frames, 4, 4):
        raise InputError(f"build_canonical_tsdf: poses have shape {poses.shape}; expected ({static.num_frames}, 4, 4).")
    vol = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=voxel_m, sdf_trunc=4 * voxel_m,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8,
    )
    dh, dw = static.depth.shape[1:]
    frames = np.unique(np.linspace(0, static.num_frames - 1, min(max_frames, static.num_frames)).round().astype(int))
    for t in frames:
        depth = np.nan_to_num(static.depth[t].astype(np.float32), nan=0.0)
        if static.confidence is not None and min_confidence > 0:
            depth[static.confidence[t] < min_confidence] = 0.0
        rgb = cv2.resize(static.rgb[t], (dw, dh), interpolation=cv2.INTER_AREA)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(rgb)), o3d.geometry.Image(depth),
            depth_scale=1.0, depth_trunc=max_depth_m, convert_rgb_to_intensity=False,
        )
        fx, fy, cx, cy = static.depth_intrinsics[t]
        intr = o3d.camera.PinholeCameraIntrinsic(dw, dh, fx, fy, cx, cy)
        vol.integrate(rgbd, intr, invert_se3(poses[t]))
    mesh = vol.extract_triangle_mesh()
    if len(mesh.triangles) == 0:
        raise InputError("build_canonical_tsdf: the static recording fused into an empty mesh; check its depth.")
    return CanonicalMesh(
        vertices=np.asarray(mesh.vertices, dtype=np.float64),
        triangles=np.asarray(mesh.triangles, dtype=np.int32),
        colors=np.asarray(mesh.vertex_colors, dtype=np.float64),
    )
