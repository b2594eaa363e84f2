"""Reading long recordings: the working resolution, a poses-and-depth-only read, keyframes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import make_capture
from test_roundtrip import FORMATS, constant_intrinsics, write

from artitwin_core import InputError
from artitwin_core.capture import KeyframeConfig, ReadOptions, read_capture, select_keyframes, write_r3d
from artitwin_core.geometry import axis_angle_to_matrix, make_se3


def test_rgb_size_caps_the_long_side():
    assert ReadOptions(rgb_max_side=640).rgb_size(1920, 1440) == (640, 480)
    assert ReadOptions(rgb_max_side=640).rgb_size(1440, 1920) == (480, 640)  # portrait
    assert ReadOptions(rgb_max_side=640).rgb_size(320, 240) == (320, 240)  # never upscaled
    assert ReadOptions(rgb_max_width=512, rgb_max_side=640).rgb_size(1920, 1440) == (512, 384)
    assert ReadOptions(rgb_max_width=32).rgb_size(64, 48) == (32, 24)


@pytest.mark.parametrize("fmt", FORMATS)
def test_max_side_frames_and_skip_rgb(fmt, tmp_path):
    c = constant_intrinsics(make_capture(t=8, rgb_wh=(48, 64), depth_wh=(24, 32)))  # portrait
    path = write(fmt, c, tmp_path, lossless=True)
    r = read_capture(path, ReadOptions(rgb_max_side=32, frames=(1, 4, 6)))
    assert r.rgb_size == (24, 32) and r.rgb.dtype == np.uint8
    np.testing.assert_array_equal(r.frame_ids, c.frame_ids[[1, 4, 6]])
    fx, fy, cx, cy = c.rgb_intrinsics[0]
    np.testing.assert_allclose(r.rgb_intrinsics[0], [fx / 2, fy / 2, (cx + 0.5) / 2 - 0.5, (cy + 0.5) / 2 - 0.5])
    # A poses-and-depth read: the same geometry, RGB a zero view of the size a full read gives.
    g = read_capture(path, ReadOptions(rgb_max_side=32, skip_rgb=True))
    assert g.rgb.shape == (8, 32, 24, 3) and g.rgb.strides[0] == 0 and not g.rgb.any()
    np.testing.assert_array_equal(g.depth[[1, 4, 6]], r.depth)
    np.testing.assert_allclose(g.rgb_intrinsics[[1, 4, 6]], r.rgb_intrinsics)
    with pytest.raises(InputError, match="position 9"):
        read_capture(path, ReadOptions(frames=(9,)))


def _sweep(t: int, moving: slice | None = None, fps: float = 60.0):
    """A ``t``-frame capture panning slowly over a wall 2 m away; within ``moving`` a block of the
    wall (a 'part') comes 1 m closer, a little more each frame."""
    c = make_capture(t=t, rgb_wh=(64, 48), depth_wh=(64, 48), confidence=False)
    poses = np.stack([make_se3(axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), 0.4 * k / t), [0.002 * k, 0, 0])
                      for k in range(t)])
    depth = np.full((t, 48, 64), 2.0, np.float32)
    if moving is not None:
        frames = np.arange(t)[moving]
        for i, k in enumerate(frames):
            depth[k:, 10:30, 20:40] = 2.0 - 1.0 * (i + 1) / len(frames)
    return dataclasses.replace(c, world_from_camera=poses, depth=depth, timestamps=np.arange(t) / fps)


def test_short_recordings_keep_every_frame():
    sel = select_keyframes(_sweep(40), KeyframeConfig(max_frames=40))
    np.testing.assert_array_equal(sel.frames, np.arange(40))


def test_keyframes_meet_the_budget_and_follow_the_motion():
    cap = _sweep(600, moving=slice(300, 400))
    sel = select_keyframes(cap, KeyframeConfig(max_frames=60))
    assert 30 <= len(sel.frames) <= 60
    assert sel.frames[0] == 0 and sel.frames[-1] == 599
    assert np.all(np.diff(sel.frames) > 0)
    # Where the part moves (frames 300-399, a sixth of the recording) the frames are kept densely.
    during = np.count_nonzero((sel.frames >= 300) & (sel.frames < 400))
    assert during >= 2 * len(sel.frames) / 6, (during, len(sel.frames))
    assert sel.scene_change[300:400].max() > 0.05 and sel.scene_change[:300].max() < 0.01


def test_ingest_keeps_keyframes_at_the_working_resolution(tmp_path):
    from schemas import IngestConfig
    from tasks.ingest import ingest_recording

    cap = _sweep(90, moving=slice(40, 60))
    cap = dataclasses.replace(cap, rgb=np.repeat(np.repeat(cap.rgb, 2, axis=1), 2, axis=2),
                              rgb_intrinsics=cap.rgb_intrinsics * [2, 2, 2, 2] + [0, 0, 0.5, 0.5])
    path = write_r3d(cap, tmp_path / "long.r3d")
    art = ingest_recording(path, IngestConfig(rgb_max_side=64, keyframes_max=30))
    assert art.rgb.shape[0] <= 30 and art.rgb.shape[1:] == (48, 64, 3)
    assert art.frame_ids[0] == 0 and art.frame_ids[-1] == 89
    whole = ingest_recording(path, IngestConfig(rgb_max_side=64))
    assert whole.rgb.shape[0] == 90
    keep = np.searchsorted(whole.frame_ids, art.frame_ids)
    np.testing.assert_array_equal(whole.rgb[keep], art.rgb)
    np.testing.assert_allclose(whole.rgb_intrinsics[keep], art.rgb_intrinsics)
    # the frames left out keep their poses in the pose stream (the lag correction reads them)
    assert whole.stream_world_from_camera is None
    np.testing.assert_array_equal(art.stream_frame_ids, whole.frame_ids)
    np.testing.assert_allclose(art.stream_world_from_camera, whole.world_from_camera)
