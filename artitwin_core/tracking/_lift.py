"""Lifting RGB pixels to 3D: depth sampled at the pixel's ray, unprojected, moved to the world.

The depth map usually has a lower resolution than the RGB image. An RGB pixel is mapped to the
depth image through its ray, not by scaling its coordinates: the pixel is undistorted (if the
capture has lens distortion), turned into the normalised ray ``((u - cx) / fx, (v - cy) / fy)``
with the RGB intrinsics and projected with the depth intrinsics. That is exact whatever pixel
convention the two intrinsics share. Depth arrays are indexed with pixel centres at integer
coordinates (OpenCV), so bilinear interpolation uses the four pixels around ``(ud, vd)``.
"""

from __future__ import annotations

import cv2
import numpy as np

from artitwin_core.geometry import pixel_rays as camera_rays


def pixel_rays(pixels: np.ndarray, rgb_intrinsics: np.ndarray, distortion: np.ndarray | None) -> np.ndarray:
    """Normalised camera rays ``[N, 2]`` ``(x / z, y / z)`` of RGB pixels ``[N, 2]`` ``(u, v)``.

    Args:
        pixels: ``[N, 2]`` (u, v) at RGB resolution, pixel centres at integer coordinates.
        rgb_intrinsics: ``[4]`` ``(fx, fy, cx, cy)`` pixels.
        distortion: OpenCV coefficients of the RGB image, or None (pinhole).
    """
    fx, fy, cx, cy = (float(v) for v in rgb_intrinsics)
    pix = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if distortion is None or pix.shape[0] == 0:
        return camera_rays(rgb_intrinsics, pix[:, 0], pix[:, 1])[:, :2]
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
    und = cv2.undistortPointsIter(pix[:, None, :], k, np.asarray(distortion, np.float64), None, None, crit)
    return und[:, 0, :].astype(np.float64)


def sample_depth(
    depth: np.ndarray,
    confidence: np.ndarray | None,
    uv_depth: np.ndarray,
    edge_rel: float,
    min_confidence: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear z-depth at depth-image positions, rejecting edges and low confidence.

    Args:
        depth: ``[h, w]`` float metres, NaN invalid.
        confidence: ``[h, w]`` uint8 (0/1/2) or None.
        uv_depth: ``[N, 2]`` (u, v) at depth resolution, pixel centres at integer coordinates.
        edge_rel: the four neighbours may spread by at most ``edge_rel * depth``.
        min_confidence: each of the four neighbours needs at least this confidence.

    Returns:
        ``z [N]`` metres (NaN where rejected) and ``ok [N]`` bool.
    """
    h, w = depth.shape
    uv = np.asarray(uv_depth, dtype=np.float64).reshape(-1, 2)
    n = uv.shape[0]
    z = np.full(n, np.nan)
    finite = np.all(np.isfinite(uv), axis=1)
    u0 = np.floor(np.where(finite, uv[:, 0], -10)).astype(np.int64)
    v0 = np.floor(np.where(finite, uv[:, 1], -10)).astype(np.int64)
    inside = finite & (u0 >= 0) & (v0 >= 0) & (u0 + 1 < w) & (v0 + 1 < h)
    if not inside.any():
        return z, np.zeros(n, bool)
    idx = np.nonzero(inside)[0]
    a, b = u0[idx], v0[idx]
    fu = uv[idx, 0] - a
    fv = uv[idx, 1] - b
    d = np.stack([depth[b, a], depth[b, a + 1], depth[b + 1, a], depth[b + 1, a + 1]], -1).astype(np.float64)
    wts = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], -1)
    ok = np.all(np.isfinite(d) & (d > 0), axis=1)
    if confidence is not None:
        c = np.stack([confidence[b, a], confidence[b, a + 1], confidence[b + 1, a], confidence[b + 1, a + 1]], -1)
        ok &= np.all(c >= min_confidence, axis=1)
    # Inverse depth is affine in pixel coordinates on a plane, so interpolating it is exact on
    # planar faces (interpolating z itself bends slanted planes between depth pixels).
    inv = np.sum(np.where(ok[:, None], 1.0 / np.where(ok[:, None], d, 1.0), 0.0) * wts, axis=1)
    zi = np.where(ok, 1.0 / np.where(ok, inv, 1.0), np.nan)
    spread = np.nanmax(np.where(np.isfinite(d), d, np.nan), axis=1, initial=-np.inf) - np.nanmin(
        np.where(np.isfinite(d), d, np.nan), axis=1, initial=np.inf
    )
    ok &= spread <= edge_rel * zi
    z[idx[ok]] = zi[ok]
    out = np.zeros(n, bool)
    out[idx[ok]] = True
    return z, out


def lift_pixels(
    pixels: np.ndarray,
    depth: np.ndarray,
    confidence: np.ndarray | None,
    rgb_intrinsics: np.ndarray,
    depth_intrinsics: np.ndarray,
    world_from_camera: np.ndarray,
    distortion: np.ndarray | None = None,
    edge_rel: float = 0.05,
    min_confidence: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """3D world points of RGB pixels in one frame.

    Args:
        pixels: ``[N, 2]`` (u, v) at RGB resolution (NaN rows are returned invalid).
        depth: ``[h, w]`` z-depth metres of the frame, NaN invalid.
        confidence: ``[h, w]`` uint8 or None.
        rgb_intrinsics, depth_intrinsics: ``[4]`` ``(fx, fy, cx, cy)`` at each resolution.
        world_from_camera: ``[4, 4]`` camera-to-world (OpenCV axes); pass
            ``canonical_from_session @ world_from_camera[t]`` for canonical points.
        distortion: OpenCV coefficients of the RGB image, or None.
        edge_rel, min_confidence: see :func:`sample_depth`.

    Returns:
        ``points [N, 3]`` float64 metres in the world (NaN where invalid) and ``ok [N]`` bool.
    """
    pix = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    n = pix.shape[0]
    finite = np.all(np.isfinite(pix), axis=1)
    rays = np.full((n, 2), np.nan)
    if finite.any():
        rays[finite] = pixel_rays(pix[finite], rgb_intrinsics, distortion)
    fxd, fyd, cxd, cyd = (float(v) for v in depth_intrinsics)
    uv_d = np.stack([rays[:, 0] * fxd + cxd, rays[:, 1] * fyd + cyd], -1)
    z, ok = sample_depth(depth, confidence, uv_d, edge_rel, min_confidence)
    cam = np.stack([rays[:, 0] * z, rays[:, 1] * z, z], -1)
    pose = np.asarray(world_from_camera, dtype=np.float64)
    world = cam @ pose[:3, :3].T + pose[:3, 3]
    world[~ok] = np.nan
    return world, ok
