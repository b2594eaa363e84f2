"""detect_changes on ray-cast box scenes with exact ground truth: a moved box is found, an
exposure change and depth noise are not."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from artitwin_core import InputError
from artitwin_core.change import CanonicalMesh, ChangeConfig, detect_changes
from artitwin_core.geometry import make_se3

W, H = 160, 120
INTR = np.array([130.0, 130.0, 80.0, 60.0])
# Camera 2.5 m in front of the wall (z = 0), looking along -z; OpenCV axes: x right, y down.
POSE = make_se3(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 2.5]))


def _scene(box_offset: np.ndarray) -> CanonicalMesh:
    """A wall, a floor and a 40 cm box (at ``box_offset``), with colourful vertex colours."""
    parts = [
        o3d.geometry.TriangleMesh.create_box(4.0, 3.0, 0.02).translate((-2.0, -1.0, -0.02)),
        o3d.geometry.TriangleMesh.create_box(4.0, 0.02, 3.0).translate((-2.0, -1.02, 0.0)),
        o3d.geometry.TriangleMesh.create_box(0.4, 0.4, 0.4).translate((-0.2, -1.0, 0.3) + box_offset),
    ]
    verts, tris, cols = [], [], []
    rng = np.random.default_rng(3)
    n = 0
    for p in parts:
        p = p.subdivide_midpoint(3)
        v = np.asarray(p.vertices)
        verts.append(v)
        tris.append(np.asarray(p.triangles) + n)
        cols.append(rng.uniform(0.2, 0.8, (len(v), 3)))
        n += len(v)
    return CanonicalMesh(np.concatenate(verts), np.concatenate(tris).astype(np.int32), np.concatenate(cols))


@pytest.fixture(scope="module")
def renders():
    before = _scene(np.zeros(3))
    after = _scene(np.array([0.6, 0.0, 0.2]))
    rgb0, d0, tri0 = before.render(POSE, INTR, W, H)
    rgb1, d1, tri1 = after.render(POSE, INTR, W, H)
    box_first = len(before.triangles) - 12 * 4**3  # the box is the last mesh: 12 * 4^3 triangles
    return dict(rgb0=rgb0, d0=d0, rgb1=rgb1, d1=d1, box0=tri0 >= box_first, box1=tri1 >= box_first)


def test_moved_box_is_closer_where_it_is_and_farther_where_it_was(renders):
    r = renders
    c = detect_changes(r["rgb1"], r["d1"], r["rgb0"], r["d0"])
    new_only = r["box1"] & ~r["box0"]
    gone_only = r["box0"] & ~r["box1"]
    unchanged = ~r["box0"] & ~r["box1"]
    assert new_only.sum() > 500 and gone_only.sum() > 500
    assert c.closer[new_only].mean() > 0.97  # measured 1.0
    assert c.farther[gone_only].mean() > 0.97  # measured 1.0
    assert c.changed[unchanged].mean() < 0.005  # measured 0
    assert c.closer.shape == (H, W) and c.depth_difference.dtype == np.float32


def test_exposure_change_is_not_a_change(renders):
    r = renders
    brighter = np.clip(r["rgb0"].astype(np.float64) * 1.5 + 12.0, 0, 255).astype(np.uint8)
    c = detect_changes(brighter, r["d0"], r["rgb0"], r["d0"])
    assert not c.changed.any()
    # The fitted colour transform recovers the exposure (saturated pixels are left out of the
    # fit; uint8 rounding remains).
    assert np.allclose(c.colour_gain, 1.5, atol=0.01)
    assert np.allclose(c.colour_offset, 12.0, atol=1.0)
    assert np.mean(c.appearance > ChangeConfig().appearance_threshold) < 0.01  # measured 0
    # Without the colour fit the same frames differ everywhere: the test can fail.
    raw = np.abs(brighter.astype(float) - r["rgb0"]).mean(-1) / 255.0
    assert np.mean(raw > 0.1) > 0.5


def test_depth_noise_growing_with_range_is_tolerated(renders):
    r = renders
    rng = np.random.default_rng(0)
    d = r["d0"]
    noisy = (d + rng.normal(0.0, 1.0, d.shape) * (0.002 + 0.003 * d**2)).astype(np.float32)
    c = detect_changes(r["rgb0"], noisy, r["rgb0"], d)
    assert c.changed.mean() < 0.002  # 3-sigma tolerance at 2.5 m is ~0.09 m; measured 0


def test_depth_at_lower_resolution_is_resampled(renders):
    r = renders
    half = r["d1"][::2, ::2]
    c = detect_changes(r["rgb1"], half, r["rgb0"], r["d0"])
    new_only = r["box1"] & ~r["box0"]
    assert c.closer[new_only].mean() > 0.9  # nearest resampling loses a pixel at edges; measured 0.98


def test_mismatched_rgb_sizes_raise(renders):
    r = renders
    with pytest.raises(InputError, match="same size"):
        detect_changes(r["rgb1"][:-1], r["d1"], r["rgb0"], r["d0"])
