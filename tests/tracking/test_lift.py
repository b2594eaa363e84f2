"""Lifting RGB pixels to 3D with a lower-resolution depth map: exact on planes, edges rejected."""

from __future__ import annotations

import numpy as np

from artitwin_core.capture import depth_intrinsics_from_rgb
from artitwin_core.geometry import axis_angle_to_matrix, make_se3
from artitwin_core.tracking import lift_pixels

RGB_SIZE, DEPTH_SIZE = (256, 192), (64, 48)
K_RGB = np.array([205.0, 205.0, 131.1, 94.3])
K_DEPTH = depth_intrinsics_from_rgb(K_RGB, RGB_SIZE, DEPTH_SIZE)


def plane_depth(k, size, normal, offset):
    """z-depth ``[h, w]`` of the plane ``normal . X = offset`` (camera frame), pixel centres at
    integer coordinates."""
    u, v = np.meshgrid(np.arange(size[0], dtype=float), np.arange(size[1], dtype=float))
    rays = np.stack([(u - k[2]) / k[0], (v - k[3]) / k[1], np.ones_like(u)], -1)
    return (offset / (rays @ normal)).astype(np.float64)


def test_lift_is_exact_on_a_slanted_plane_at_quarter_resolution():
    rng = np.random.default_rng(0)
    normal = np.array([0.35, -0.2, 1.0])
    normal /= np.linalg.norm(normal)
    depth = plane_depth(K_DEPTH, DEPTH_SIZE, normal, 1.4)
    pose = make_se3(axis_angle_to_matrix(np.array([0.2, 1.0, 0.1]), 0.7), np.array([0.3, 1.2, -2.0]))
    pixels = rng.uniform([8, 8], [RGB_SIZE[0] - 8, RGB_SIZE[1] - 8], size=(500, 2))
    points, ok = lift_pixels(pixels, depth, None, K_RGB, K_DEPTH, pose, edge_rel=0.2)
    assert ok.all()
    rays = np.stack([(pixels[:, 0] - K_RGB[2]) / K_RGB[0], (pixels[:, 1] - K_RGB[3]) / K_RGB[1], np.ones(500)], -1)
    truth_cam = rays * (1.4 / (rays @ normal))[:, None]
    truth = truth_cam @ pose[:3, :3].T + pose[:3, 3]
    # Inverse depth is affine on a plane, so bilinear interpolation of it is exact (measured
    # 1e-15 m; interpolating z itself bends the plane between depth pixels). Mapping RGB to depth pixels by plain scaling (ignoring the
    # pixel-centre offset) would sample 0.375 depth pixels off: ~4 mm here.
    assert np.max(np.linalg.norm(points - truth, axis=1)) < 1e-5


def test_lift_rejects_depth_edges_low_confidence_nan_and_outside():
    depth = np.full((DEPTH_SIZE[1], DEPTH_SIZE[0]), 2.0, np.float32)
    depth[:, 32:] = 1.0  # a step edge between depth columns 31 and 32
    conf = np.full(depth.shape, 2, np.uint8)
    conf[10, 10] = 0
    pose = np.eye(4)

    def rgb_of(ud, vd):  # the RGB pixel whose ray hits depth pixel (ud, vd)
        x, y = (ud - K_DEPTH[2]) / K_DEPTH[0], (vd - K_DEPTH[3]) / K_DEPTH[1]
        return [x * K_RGB[0] + K_RGB[2], y * K_RGB[1] + K_RGB[3]]

    pixels = np.array([rgb_of(20.0, 20.0), rgb_of(31.5, 20.0), rgb_of(10.2, 10.2), [np.nan, 3.0], [-5.0, 4.0],
                       rgb_of(40.0, 20.0)])
    points, ok = lift_pixels(pixels, depth, conf, K_RGB, K_DEPTH, pose, edge_rel=0.05, min_confidence=1)
    assert ok.tolist() == [True, False, False, False, False, True]
    assert np.all(np.isnan(points[~ok]))
    np.testing.assert_allclose(points[0, 2], 2.0, atol=1e-6)
    np.testing.assert_allclose(points[5, 2], 1.0, atol=1e-6)
