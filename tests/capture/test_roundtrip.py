"""Writer -> reader round trips for every format on a small synthetic capture.

Tolerances (measured on these fixtures, seeds 0-2, then given headroom):
- JPEG quality 95 on 64x48 smooth images: mean abs error 0.66 grey levels measured; bound 2.0.
- mp4v video (Stray, lossy): 2.6 measured; bound 6.0. FFV1 (lossless): exactly equal.
- Poses: quaternion <-> matrix conversions measured 3e-16; bound 1e-9.
- Depth: r3d float32 exact; EXR float16 relative 2^-11 (half the float16 ulp); PNG mm 0.5 mm.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import make_capture

from artitwin_core.capture import (
    Capture,
    ReadOptions,
    depth_intrinsics_from_rgb,
    detect_format,
    read_capture,
    recording_files,
    scale_intrinsics,
    write_nerfstudio,
    write_r3d,
    write_record3d_exr,
    write_stray,
)

JPEG_MAE = 2.0
MP4V_MAE = 6.0
POSE_TOL = 1e-9


def constant_intrinsics(c: Capture) -> Capture:
    k = np.tile(c.rgb_intrinsics[:1], (c.num_frames, 1))
    return dataclasses.replace(c, rgb_intrinsics=k,
                               depth_intrinsics=depth_intrinsics_from_rgb(k, c.rgb_size, c.depth_size))


def write(fmt: str, c: Capture, tmp_path, **kw):
    if fmt == "record3d-r3d":
        return write_r3d(c, tmp_path / "rec.r3d")
    if fmt == "record3d-exr":
        return write_record3d_exr(c, tmp_path / "EXR_RGBD")
    if fmt == "nerfstudio":
        return write_nerfstudio(c, tmp_path / "ns").parent
    return write_stray(c, tmp_path / "stray", **kw)


def depth_bound(fmt: str, depth: np.ndarray) -> np.ndarray:
    if fmt == "record3d-r3d":
        return np.zeros_like(depth)
    if fmt == "record3d-exr":
        return np.abs(depth) * 2.0**-11 + 1e-7
    return np.full_like(depth, 0.0005 + 1e-6)


FORMATS = ["record3d-r3d", "record3d-exr", "nerfstudio", "stray"]
HAS_CONF = {"record3d-r3d": True, "record3d-exr": False, "nerfstudio": False, "stray": True}


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("seed", [0, 1])
def test_round_trip(fmt, seed, tmp_path):
    c = make_capture(seed=seed, frame_ids=[0, 1, 3, 4, 7, 8])  # gaps: frames 2, 5, 6 removed
    if fmt == "stray":
        c = constant_intrinsics(c)  # Stray has one K
    path = write(fmt, c, tmp_path)
    assert detect_format(path) == fmt
    r = read_capture(path)
    assert r.source_format == fmt
    np.testing.assert_array_equal(r.frame_ids, c.frame_ids)
    assert r.rgb.shape == c.rgb.shape and r.depth.shape == c.depth.shape
    mae = np.abs(r.rgb.astype(np.int16) - c.rgb).mean()
    assert mae < (MP4V_MAE if fmt == "stray" else JPEG_MAE), mae
    np.testing.assert_array_equal(np.isnan(r.depth), np.isnan(c.depth))
    ok = np.isfinite(c.depth)
    assert np.all(np.abs(r.depth[ok] - c.depth[ok]) <= depth_bound(fmt, c.depth[ok]))
    np.testing.assert_allclose(r.world_from_camera, c.world_from_camera, atol=POSE_TOL)
    np.testing.assert_allclose(r.rgb_intrinsics, c.rgb_intrinsics, atol=1e-9)
    np.testing.assert_allclose(r.depth_intrinsics, c.depth_intrinsics, atol=1e-9)
    np.testing.assert_allclose(r.timestamps, c.timestamps, atol=1e-9)
    if HAS_CONF[fmt]:
        np.testing.assert_array_equal(r.confidence, c.confidence)
    else:
        assert r.confidence is None
    assert r.distortion is None
    files = recording_files(path)
    assert all(f.is_file() for f in files)
    assert len(files) == {"record3d-r3d": 1, "record3d-exr": 13, "nerfstudio": 13, "stray": 15}[fmt]


def test_stray_lossless_video_is_exact(tmp_path):
    c = constant_intrinsics(make_capture(seed=2))
    r = read_capture(write_stray(c, tmp_path / "s", lossless=True))
    np.testing.assert_array_equal(r.rgb, c.rgb)


def test_nerfstudio_distortion_round_trip(tmp_path):
    c = dataclasses.replace(make_capture(), distortion=np.array([0.1, -0.02, 0.001, 0.002, 0.003]))
    r = read_capture(write_nerfstudio(c, tmp_path / "ns"))
    np.testing.assert_array_equal(r.distortion, c.distortion)


@pytest.mark.parametrize("fmt", FORMATS)
def test_stride_and_max_frames(fmt, tmp_path):
    c = constant_intrinsics(make_capture(t=8, frame_ids=[0, 2, 3, 4, 5, 6, 9, 10]))
    path = write(fmt, c, tmp_path, lossless=True)
    r = read_capture(path, ReadOptions(stride=2, max_frames=3))
    np.testing.assert_array_equal(r.frame_ids, [0, 3, 5])
    np.testing.assert_allclose(r.world_from_camera, c.world_from_camera[[0, 2, 4]], atol=POSE_TOL)
    np.testing.assert_allclose(r.timestamps, c.timestamps[[0, 2, 4]], atol=1e-9)


@pytest.mark.parametrize("fmt", FORMATS)
def test_rgb_max_width_scales_image_and_intrinsics(fmt, tmp_path):
    import cv2

    c = constant_intrinsics(make_capture())
    r = read_capture(write(fmt, c, tmp_path, lossless=True), ReadOptions(rgb_max_width=32))
    assert r.rgb_size == (32, 24)
    want = np.stack([cv2.resize(f, (32, 24), interpolation=cv2.INTER_AREA) for f in c.rgb])
    assert np.abs(r.rgb.astype(np.int16) - want).mean() < (MP4V_MAE if fmt == "stray" else JPEG_MAE)
    fx, fy, cx, cy = c.rgb_intrinsics[0]
    np.testing.assert_allclose(r.rgb_intrinsics[0], [fx / 2, fy / 2, (cx + 0.5) / 2 - 0.5, (cy + 0.5) / 2 - 0.5])
    # Depth is untouched by the RGB option.
    np.testing.assert_allclose(r.depth_intrinsics, c.depth_intrinsics, atol=1e-9)


def test_scaled_intrinsics_follow_pixel_areas():
    """Pixel-centre convention: a point's projection at full resolution, mapped to the
    downscaled grid (u' = (u + 0.5) s - 0.5), equals its projection with the scaled intrinsics."""
    rng = np.random.default_rng(3)
    k = np.array([500.0, 510.0, 330.2, 241.7])
    s = np.array([0.25, 0.4])
    k2 = scale_intrinsics(k, *s)
    pts = rng.uniform([-1, -1, 1], [1, 1, 5], (50, 3))
    uv = k[:2] * pts[:, :2] / pts[:, 2:] + k[2:]
    uv2 = k2[:2] * pts[:, :2] / pts[:, 2:] + k2[2:]
    np.testing.assert_allclose(uv2, (uv + 0.5) * s - 0.5, atol=1e-9)
    # The image's outer edges (-0.5 and w - 0.5) map onto the scaled image's outer edges.
    np.testing.assert_allclose((np.array([-0.5, 639.5]) + 0.5) * 0.25 - 0.5, [-0.5, 159.5])


def test_faceid_sized_depth_round_trip(tmp_path):
    """FaceID captures have larger depth (here at RGB size); nothing assumes LiDAR's 256x192."""
    c = make_capture(rgb_wh=(48, 64), depth_wh=(48, 64))
    r = read_capture(write_r3d(c, tmp_path / "face.r3d"))
    assert r.depth_size == (48, 64)
    np.testing.assert_array_equal(r.depth, c.depth)


def test_writer_refuses_depth_intrinsics_it_cannot_store(tmp_path):
    c = make_capture()
    bad = dataclasses.replace(c, depth_intrinsics=c.depth_intrinsics + [0, 0, 0.3, 0])
    with pytest.raises(ValueError, match="depth_intrinsics_from_rgb"):
        write_r3d(bad, tmp_path / "x.r3d")


@pytest.mark.parametrize("fmt", FORMATS)
def test_writing_a_capture_again_gives_the_same_bytes(fmt, tmp_path, monkeypatch):
    """A recording's content key (the store's raw input) is its files' bytes: a scene written
    again later must keep it, or a rerun recomputes every stage. Zip entries were dated when
    written."""
    import hashlib
    import time

    c = constant_intrinsics(make_capture(3, confidence=HAS_CONF[fmt]))

    def digest(root):
        files = recording_files(root)
        return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}

    first = digest(write(fmt, c, tmp_path / "a"))
    later = time.time() + 86400.0
    monkeypatch.setattr(time, "time", lambda: later)
    assert digest(write(fmt, c, tmp_path / "b")) == first
