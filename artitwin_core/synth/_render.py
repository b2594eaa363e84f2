"""Ray casting (open3d ``RaycastingScene``) and shading of the scene at one instant.

Rays are built per pixel with the camera-frame direction ``((u - cx) / fx, (v - cy) / fy, 1)``
(pixel centres at integer coordinates, column u, row v), so the ray parameter of a hit IS its
z-depth. Shading is Lambertian under one point light with a shadow ray, plus ambient light.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from artitwin_core.geometry import invert_se3, pixel_grid
from artitwin_core.geometry import pixel_rays as camera_rays
from artitwin_core.synth._scene import SceneModel, SceneObject, part_motion
from artitwin_core.synth._textures import evaluate_texture

MISS_LABEL = -3
AMBIENT = 0.32
DIFFUSE = 0.85


class WorldState:
    """The scene frozen at one instant: every object placed in the world, ready to ray cast."""

    def __init__(self, model: SceneModel, q, hand: SceneObject | None = None):
        if len(q) != len(model.parts):
            raise ValueError(f"need {len(model.parts)} joint states, got {len(q)}")
        self.model = model
        self.objects: list[SceneObject] = list(model.objects) + ([hand] if hand is not None else [])
        self.world_from_local: list[np.ndarray] = []
        self.scene = o3d.t.geometry.RaycastingScene()
        motions = [part_motion(p, float(qk)) for p, qk in zip(model.parts, q, strict=True)]
        for obj in self.objects:
            pose = obj.world_from_local if obj.label < 0 else motions[obj.label] @ obj.world_from_local
            self.world_from_local.append(pose)
            verts = obj.vertices @ pose[:3, :3].T + pose[:3, 3]
            self.scene.add_triangles(
                o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(obj.triangles.astype(np.uint32))
            )
        self.labels = np.array([o.label for o in self.objects], dtype=np.int64)

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rays ``[N, 3]`` -> ray parameter ``[N]`` (inf on a miss), object index ``[N]`` (-1 on a
        miss) and unit normals ``[N, 3]`` facing against the ray."""
        rays = np.concatenate([origins, dirs], 1).astype(np.float32)
        hit = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy().astype(np.float64)
        gid = hit["geometry_ids"].numpy().astype(np.int64)
        gid[~np.isfinite(t)] = -1
        normals = hit["primitive_normals"].numpy().astype(np.float64)
        flip = np.sum(normals * dirs, 1) > 0
        normals[flip] *= -1
        return t, gid, normals

    def shade(self, origins, dirs, t, gid, normals) -> np.ndarray:
        """Linear radiance ``[N, 3]`` of the hits (black on a miss)."""
        out = np.zeros((t.shape[0], 3))
        ok = gid >= 0
        if not np.any(ok):
            return out
        pts = origins[ok] + t[ok, None] * dirs[ok]
        albedo = np.zeros((pts.shape[0], 3))
        g = gid[ok]
        for k in np.unique(g):
            sel = g == k
            obj = self.objects[k]
            local_from_world = invert_se3(self.world_from_local[k])
            local = pts[sel] @ local_from_world[:3, :3].T + local_from_world[:3, 3]
            albedo[sel] = evaluate_texture(obj.texture, local, obj.params)
        n = normals[ok]
        to_light = self.model.light - pts
        cos = np.clip(np.sum(n * to_light, 1) / np.linalg.norm(to_light, axis=1), 0.0, 1.0)
        shadow_rays = np.concatenate([pts + 2e-3 * n, to_light], 1).astype(np.float32)
        lit = ~self.scene.test_occlusions(o3d.core.Tensor(shadow_rays), tnear=1e-4, tfar=1.0).numpy()
        out[ok] = albedo * (AMBIENT + DIFFUSE * cos * lit)[:, None]
        return out


def distort_normalized(x: np.ndarray, y: np.ndarray, coeffs) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV radial-tangential model (``k1 k2 p1 p2``) on normalised coordinates."""
    k1, k2, p1, p2 = (float(c) for c in coeffs[:4])
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def undistort_normalized(xd: np.ndarray, yd: np.ndarray, coeffs, iterations: int = 30):
    """Inverse of :func:`distort_normalized` by Newton-free fixed-point iteration (as OpenCV),
    which converges for the mild distortion of phone lenses (|k1| < ~0.3)."""
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        dx, dy = distort_normalized(x, y, coeffs)
        x, y = x + (xd - dx), y + (yd - dy)
    return x, y


def pixel_rays(
    world_from_camera: np.ndarray,
    intrinsics,
    width: int,
    height: int,
    distortion: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Rays through every pixel, row-major.

    Args:
        world_from_camera: ``[4, 4]``, or ``[H, 4, 4]`` with one pose per image row (rolling
            shutter).
        intrinsics: ``(fx, fy, cx, cy)`` pixels.
        distortion: OpenCV ``k1 k2 p1 p2`` if the image is distorted (rays go through the
            undistorted direction of each distorted pixel), else None.

    Returns:
        origins ``[H*W, 3]`` and directions ``[H*W, 3]`` in the world; a direction's
        camera-frame z is 1, so a hit's ray parameter is its z-depth in metres.
    """
    d_cam = camera_rays(intrinsics, *pixel_grid(width, height))  # [H, W, 3]
    if distortion is not None:
        x, y = undistort_normalized(d_cam[..., 0], d_cam[..., 1], distortion)
        d_cam = np.stack([x, y, np.ones_like(x)], -1)
    pose = np.asarray(world_from_camera, dtype=np.float64)
    if pose.ndim == 2:
        dirs = d_cam.reshape(-1, 3) @ pose[:3, :3].T
        origins = np.broadcast_to(pose[:3, 3], dirs.shape)
    else:
        dirs = np.einsum("hij,hwj->hwi", pose[:, :3, :3], d_cam).reshape(-1, 3)
        origins = np.repeat(pose[:, :3, 3], width, axis=0)
    return np.ascontiguousarray(origins), np.ascontiguousarray(dirs)


@dataclass
class View:
    """What one camera saw: ``[H, W]`` maps."""

    radiance: np.ndarray | None  # [H, W, 3] linear, None when not shaded
    depth: np.ndarray  # [H, W] z-depth metres, inf on a miss
    label: np.ndarray  # [H, W] int64: -1 static, k part k, -2 hand, -3 miss
    cos_incidence: np.ndarray  # [H, W] |cos| between ray and surface normal


def render_view(
    state: WorldState,
    world_from_camera: np.ndarray,
    intrinsics,
    width: int,
    height: int,
    distortion: np.ndarray | None = None,
    shade: bool = True,
) -> View:
    """Ray cast ``state`` from one camera (see :func:`pixel_rays` for the arguments)."""
    origins, dirs = pixel_rays(world_from_camera, intrinsics, width, height, distortion)
    t, gid, normals = state.cast(origins, dirs)
    label = np.where(gid >= 0, state.labels[np.maximum(gid, 0)], MISS_LABEL)
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    cos = np.abs(np.sum(unit * normals, 1))
    radiance = state.shade(origins, dirs, t, gid, normals).reshape(height, width, 3) if shade else None
    return View(radiance, t.reshape(height, width), label.reshape(height, width), cos.reshape(height, width))


def render_supersampled(
    state: WorldState,
    world_from_camera: np.ndarray,
    intrinsics,
    width: int,
    height: int,
    distortion: np.ndarray | None = None,
    samples: int = 1,
) -> View:
    """:func:`render_view` with anti-aliased radiance: the mean of ``samples x samples`` sub-pixel
    rays per pixel (a box filter, as a sensor pixel integrates light over its area). Depth,
    labels and incidence come from the pixel-centre ray, so masks stay exact per pixel."""
    if samples <= 1:
        return render_view(state, world_from_camera, intrinsics, width, height, distortion)
    view = render_view(state, world_from_camera, intrinsics, width, height, distortion, shade=False)
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    acc = np.zeros((height, width, 3))
    for dy in offsets:
        for dx in offsets:
            # Sampling pixel u at u + dx is the pinhole with its principal point moved by -dx.
            sub = render_view(state, world_from_camera, (fx, fy, cx - dx, cy - dy), width, height, distortion)
            acc += sub.radiance
    view.radiance = acc / samples**2
    return view
