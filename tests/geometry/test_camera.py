"""The one camera model against ground truth: the synthetic renderer's rays, the rasterizer's
projection of a known point, and round trips (hypothesis, as jaxlie tests its Lie groups)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from artitwin_core.gaussians import rasterize
from artitwin_core.geometry import (
    backproject,
    depth_normals,
    invert_se3,
    nearest_pixel,
    pixel_grid,
    project,
    raster_intrinsics,
)
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, render_state

finite = st.floats(-1e3, 1e3, allow_nan=False, width=64)
intrinsics = st.tuples(st.floats(50, 2000), st.floats(50, 2000), st.floats(-100, 600), st.floats(-100, 600))


@settings(max_examples=200, deadline=None)
@given(
    k=intrinsics,
    uv=arrays(np.float64, (7, 2), elements=st.floats(-200, 800)),
    z=arrays(np.float64, 7, elements=st.floats(0.05, 50)),
)
def test_project_inverts_backproject(k, uv, z):
    pts = backproject(z, k, uv[:, 0], uv[:, 1])
    back, zz = project(pts, k)
    np.testing.assert_allclose(zz, z, rtol=0, atol=0)
    np.testing.assert_allclose(back, uv, rtol=0, atol=1e-9)  # float64 round-off at 1e3 px


@settings(max_examples=200, deadline=None)
@given(k=intrinsics, p=arrays(np.float64, (5, 3), elements=finite))
def test_backproject_inverts_project(k, p):
    p[:, 2] = np.abs(p[:, 2]) + 0.1
    uv, z = project(p, k)
    np.testing.assert_allclose(backproject(z, k, uv[:, 0], uv[:, 1]), p, rtol=1e-9, atol=1e-9)


def test_whole_depth_map_pixel_centres_are_integers():
    k = (100.0, 120.0, 3.0, 2.0)
    depth = np.full((5, 7), 2.0)
    pts = backproject(depth, k)
    assert pts.shape == (5, 7, 3)
    # Pixel (row 2, col 3) is the principal point: straight ahead.
    np.testing.assert_array_equal(pts[2, 3], [0.0, 0.0, 2.0])
    u, v = pixel_grid(7, 5, stride=2)
    np.testing.assert_array_equal(backproject(depth[::2, ::2], k, u, v), pts[::2, ::2])
    with pytest.raises(ValueError):
        backproject(depth[0], k)


def test_depth_normals_of_a_tilted_plane():
    # The plane n . p = 1.5 with n 30 deg off the optical axis, seen by a 40 x 30 camera.
    n = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])
    k = (40.0, 40.0, 19.5, 14.5)
    u, v = pixel_grid(40, 30)
    rays = np.stack([(u - k[2]) / k[0], (v - k[3]) / k[1], np.ones_like(u, dtype=float)], -1)
    depth = 1.5 / (rays @ n)
    depth[10, 10] = np.nan  # an invalid pixel spoils its four neighbours' differences
    normals = depth_normals(depth, k)
    ok = np.isfinite(normals).all(-1)
    assert ok.sum() == 38 * 28 - 4 and not ok[0].any() and not ok[:, -1].any()
    np.testing.assert_allclose(normals[ok], np.broadcast_to(n, (ok.sum(), 3)), atol=1e-9)


@pytest.fixture(scope="module")
def tiny_view():
    scene = generate_scene(BENCHMARK_SCENES["tiny"])
    pose = scene.truth.static_world_from_camera[0]
    k = scene.static.rgb_intrinsics[0]
    w, h = scene.static.rgb_size
    _, depth, _ = render_state(scene, pose, k, w, h, [0.0])
    return pose, k, depth


def test_synthetic_depth_lifts_onto_the_floor_it_was_rendered_from(tiny_view):
    """The synthetic renderer's ray of pixel (u, v) passes through (u, v): the floor (world
    y = 0) back-projects onto y = 0 to float32 depth precision; a +0.5 px slip tilts it off."""
    pose, k, depth = tiny_view
    ok = np.isfinite(depth) & (depth > 0)
    u, v = pixel_grid(depth.shape[1], depth.shape[0])

    def world_y(shift):
        cam = backproject(depth[ok], k, u[ok] + shift, v[ok] + shift)
        return (cam @ pose[:3, :3].T + pose[:3, 3])[:, 1]

    floor = np.abs(world_y(0.0)) < 0.01
    assert floor.sum() > 200
    exact, slipped = np.abs(world_y(0.0)[floor]), np.abs(world_y(0.5)[floor])
    # Measured on frame 0 (128x96, f = 102 px, floor ~1.8 m away): median 5e-8 m, and 7.7 mm
    # with pixel centres at +0.5.
    assert np.median(exact) < 1e-5
    assert np.median(slipped) > 20 * np.median(exact) + 1e-4


def test_rasterizer_lines_up_with_the_data_through_raster_intrinsics():
    """A small Gaussian at a known camera point renders centred on ``project`` of that point when
    the rasterizer gets ``raster_intrinsics(K)``; with K itself it lands half a pixel up-left."""
    w, h = 64, 48
    k = np.array([60.0, 60.0, 31.3, 22.6])
    point = np.array([0.05, -0.03, 1.0])
    uv, _ = project(point, k)

    def centroid(kk):
        out = rasterize(
            torch.tensor(point[None], dtype=torch.float64), torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64),
            torch.full((1, 3), np.log(0.004), dtype=torch.float64), torch.tensor([4.0], dtype=torch.float64),
            torch.zeros((1, 1, 3), dtype=torch.float64), torch.eye(4, dtype=torch.float64),
            tuple(float(c) for c in kk), w, h, backend="reference",
        )  # fmt: skip
        a = out.alpha.detach().numpy()
        gu, gv = pixel_grid(w, h)
        return np.array([(a * gu).sum() / a.sum(), (a * gv).sum() / a.sum()])

    np.testing.assert_allclose(centroid(raster_intrinsics(k)), uv, atol=0.02)  # measured 0.001 px
    np.testing.assert_allclose(centroid(k), uv - 0.5, atol=0.02)
    assert nearest_pixel(uv) == (round(uv[0]), round(uv[1]))


def test_project_through_a_pose_matches_the_world_point():
    rng = np.random.default_rng(0)
    world_from_camera = np.eye(4)
    world_from_camera[:3, 3] = [0.2, -0.1, 0.3]
    k = (500.0, 500.0, 320.0, 240.0)
    p_world = rng.uniform(-1, 1, (10, 3)) + [0, 0, 3]
    cam = invert_se3(world_from_camera)
    uv, z = project(p_world @ cam[:3, :3].T + cam[:3, 3], k)
    back = backproject(z, k, uv[:, 0], uv[:, 1]) @ world_from_camera[:3, :3].T + world_from_camera[:3, 3]
    np.testing.assert_allclose(back, p_world, atol=1e-12)


def test_one_camera_per_leading_index():
    k = np.array([[100.0, 110.0, 3.0, 2.0], [200.0, 190.0, 4.0, 1.0]])
    depth = np.random.default_rng(2).uniform(0.5, 3.0, (2, 5, 7))
    u, v = pixel_grid(7, 5)
    pts = backproject(depth, k, u[None], v[None])
    assert pts.shape == (2, 5, 7, 3)
    for t in range(2):
        np.testing.assert_array_equal(pts[t], backproject(depth[t], k[t]))
    uv, z = project(pts, k)
    np.testing.assert_allclose(uv[..., 0], np.broadcast_to(u, (2, 5, 7)), atol=1e-12)
    np.testing.assert_allclose(z, depth)
