"""Surface meshes of the base and of each part at the canonical (closed) state, by TSDF fusion.

A part is fused from the *dynamic* recording: at frame t the part has moved by
``world_from_closed[t]`` (the joint's motion at ``q[t]``), so a camera at ``world_from_camera[t]``
sees the closed part as if it stood at ``inv(world_from_closed[t]) @ world_from_camera[t]``.
Integrating each frame's part pixels with that virtual camera pose brings every observation back to
``q = 0`` without touching the depth maps. We fuse the dynamic frames rather than the static ones
because only they see the part from more than one side (the back of an opened door, the sides and
inside of a pulled-out drawer); the static recording sees a closed door as one flat face. The base is
fused from the static recording (its world frame is the canonical frame), minus every pixel whose
3D point lies near a part mesh.
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
import trimesh
from scipy.spatial import cKDTree

from artitwin_core._errors import InputError
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import backproject, invert_se3


def _backproject(depth: np.ndarray, intr: np.ndarray) -> np.ndarray:
    """``[h, w, 3]`` camera-frame points (metres, OpenCV axes) of a z-depth map ``[h, w]``."""
    return backproject(depth, intr)


def _mask_at_depth_res(mask: np.ndarray, size_wh: tuple[int, int], erode_px: int) -> np.ndarray:
    m = np.asarray(mask).astype(np.uint8)
    if m.shape[::-1] != size_wh:
        m = cv2.resize(m, size_wh, interpolation=cv2.INTER_NEAREST)
    if erode_px > 0:
        # Depth at a part's silhouette mixes part and background (flying pixels): drop a rim.
        m = cv2.erode(m, np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8))
    return m.astype(bool)


def clean_mesh(mesh: trimesh.Trimesh, max_faces: int = 20000, min_component_fraction: float = 0.05) -> trimesh.Trimesh:
    """Drop small islands and decimate.

    Keeps the connected components with at least ``min_component_fraction`` of the largest one's
    face count (fusion leaves speckles from noisy depth), then quadric-decimates to at most
    ``max_faces`` faces. Vertex colours survive.
    """
    if len(mesh.faces) == 0:
        return mesh
    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
        o3d.utility.Vector3iVector(np.asarray(mesh.faces, np.int32)),
    )
    colors = getattr(mesh.visual, "vertex_colors", None)
    if colors is not None and len(colors) == len(mesh.vertices):
        m.vertex_colors = o3d.utility.Vector3dVector(np.asarray(colors)[:, :3] / 255.0)
    m.remove_duplicated_vertices()
    m.remove_degenerate_triangles()
    m.remove_unreferenced_vertices()
    cluster, counts, _ = m.cluster_connected_triangles()
    cluster, counts = np.asarray(cluster), np.asarray(counts)
    if counts.size:
        small = counts < min_component_fraction * counts.max()
        m.remove_triangles_by_mask(small[cluster])
        m.remove_unreferenced_vertices()
    if len(m.triangles) > max_faces:
        m = m.simplify_quadric_decimation(target_number_of_triangles=int(max_faces))
        m.remove_unreferenced_vertices()
    vc = None
    if m.has_vertex_colors():
        vc = (np.clip(np.asarray(m.vertex_colors), 0, 1) * 255).astype(np.uint8)
    return trimesh.Trimesh(np.asarray(m.vertices), np.asarray(m.triangles), vertex_colors=vc, process=False)


def fuse_part_mesh(
    capture: Capture,
    masks: np.ndarray | None,
    *,
    world_from_capture: np.ndarray | None = None,
    world_from_closed: np.ndarray | None = None,
    crop_box: np.ndarray | None = None,
    voxel_m: float = 0.01,
    sdf_trunc_m: float | None = None,
    depth_max_m: float = 4.0,
    erode_px: int = 1,
    max_faces: int = 20000,
    min_component_fraction: float = 0.05,
) -> trimesh.Trimesh:
    """TSDF-fuse one rigid piece of a recording into a mesh in its closed-state (canonical) frame.

    Args:
        capture: the recording (depth NaN = invalid; ``depth_intrinsics [T, 4]``;
            ``world_from_camera [T, 4, 4]`` OpenCV axes in the recording's own world frame).
        masks: ``[T, H, W]`` bool (or 0/1) pixels of the piece per frame, at RGB or depth resolution;
            ``None`` keeps every pixel.
        world_from_capture: ``[4, 4]`` canonical-from-recording-world (the registration result for the
            dynamic recording); identity if ``None``.
        world_from_closed: ``[T, 4, 4]`` the piece's rigid motion at each frame in the canonical frame
            (``joint_transforms(...)`` at ``joint.q``); ``None`` = the piece does not move.
        crop_box: ``[2, 3]`` metres ``(lo, hi)`` axis-aligned box in the closed-state frame; points
            outside are not integrated. ``None`` = no crop.
        voxel_m: TSDF voxel size, metres. ``sdf_trunc_m`` defaults to ``3 * voxel_m``.
        depth_max_m: depth beyond this is ignored, metres.
        erode_px: masks are eroded by this many depth pixels (drops mixed silhouette pixels).
        max_faces, min_component_fraction: see ``clean_mesh``.

    Returns:
        The cleaned mesh (metres, closed-state canonical frame), vertex colours from the RGB frames.
        Empty (no faces) if nothing was observed.
    """
    t_count = capture.num_frames
    if masks is not None and len(masks) != t_count:
        raise InputError(f"fuse_part_mesh: {len(masks)} masks for a capture of {t_count} frames.")
    if world_from_closed is not None and len(world_from_closed) != t_count:
        raise InputError(
            f"fuse_part_mesh: world_from_closed has {len(world_from_closed)} poses for {t_count} frames."
        )
    if voxel_m <= 0:
        raise InputError(f"fuse_part_mesh: voxel_m must be > 0 metres, got {voxel_m}.")
    w_from_c = np.eye(4) if world_from_capture is None else np.asarray(world_from_capture, np.float64)
    volume = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=float(voxel_m),
        sdf_trunc=float(sdf_trunc_m if sdf_trunc_m is not None else 3.0 * voxel_m),
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8,
    )
    dw, dh = capture.depth_size
    integrated = 0
    for t in range(t_count):
        depth = np.nan_to_num(capture.depth[t].astype(np.float32), nan=0.0)
        depth[(depth < 0) | (depth > depth_max_m)] = 0.0
        if masks is not None:
            depth[~_mask_at_depth_res(masks[t], (dw, dh), erode_px)] = 0.0
        closed_from_camera = w_from_c @ capture.world_from_camera[t]
        if world_from_closed is not None:
            closed_from_camera = invert_se3(np.asarray(world_from_closed[t], np.float64)) @ closed_from_camera
        intr = np.asarray(capture.depth_intrinsics[t], np.float64)
        if crop_box is not None:
            pts = _backproject(depth, intr) @ closed_from_camera[:3, :3].T + closed_from_camera[:3, 3]
            lo, hi = np.asarray(crop_box, np.float64)
            depth[~np.all((pts >= lo) & (pts <= hi), axis=-1)] = 0.0
        if not np.any(depth > 0):
            continue
        rgb = cv2.resize(capture.rgb[t], (dw, dh), interpolation=cv2.INTER_AREA)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(rgb)),
            o3d.geometry.Image(np.ascontiguousarray(depth)),
            depth_scale=1.0,
            depth_trunc=float(depth_max_m),
            convert_rgb_to_intensity=False,
        )
        cam = o3d.camera.PinholeCameraIntrinsic(dw, dh, *[float(v) for v in intr])
        volume.integrate(rgbd, cam, invert_se3(closed_from_camera))
        integrated += 1
    if integrated == 0:
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    mesh = volume.extract_triangle_mesh()
    tm = trimesh.Trimesh(
        np.asarray(mesh.vertices),
        np.asarray(mesh.triangles),
        vertex_colors=(np.clip(np.asarray(mesh.vertex_colors), 0, 1) * 255).astype(np.uint8)
        if mesh.has_vertex_colors() else None,
        process=False,
    )
    return clean_mesh(tm, max_faces=max_faces, min_component_fraction=min_component_fraction)


def fuse_base_mesh(
    capture: Capture,
    part_meshes: list[trimesh.Trimesh],
    *,
    margin_m: float = 0.03,
    crop_box: np.ndarray | None = None,
    voxel_m: float = 0.02,
    max_faces: int = 30000,
    **fuse_kwargs,
) -> trimesh.Trimesh:
    """The static scene without its parts: the static recording fused with part pixels removed.

    A pixel is dropped when its 3D point (canonical frame) lies within ``margin_m`` metres of any
    part mesh (closed state, as the static recording sees the parts). ``crop_box [2, 3]`` metres
    keeps the base to a region (a whole room makes a large, slow-to-simulate mesh); other keyword
    arguments go to ``fuse_part_mesh``.
    """
    samples = [np.asarray(m.sample(max(2000, int(m.area / (0.5 * margin_m) ** 2)))) for m in part_meshes
               if len(m.faces)]
    tree = cKDTree(np.concatenate(samples)) if samples else None
    masks = np.ones(capture.depth.shape, bool)
    if tree is not None:
        for t in range(capture.num_frames):
            depth = np.nan_to_num(capture.depth[t].astype(np.float64), nan=0.0)
            pts = _backproject(depth, capture.depth_intrinsics[t]).reshape(-1, 3)
            pose = capture.world_from_camera[t]
            pts = pts @ pose[:3, :3].T + pose[:3, 3]
            dist, _ = tree.query(pts, distance_upper_bound=margin_m)
            masks[t] = ~np.isfinite(dist).reshape(depth.shape) | (depth <= 0)
    return fuse_part_mesh(
        capture, masks, crop_box=crop_box, voxel_m=voxel_m, max_faces=max_faces, erode_px=0, **fuse_kwargs
    )
