"""Synthetic captures the capture tests write to disk and read back."""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core.capture import Capture, depth_intrinsics_from_rgb
from artitwin_core.geometry import axis_angle_to_matrix, make_se3


def smooth_rgb(rng: np.random.Generator, t: int, h: int, w: int) -> np.ndarray:
    """``[t, h, w, 3]`` uint8 images of smooth gradients plus blobs: JPEG/video friendly, not flat."""
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    out = np.empty((t, h, w, 3), np.float64)
    for k in range(t):
        for c in range(3):
            a, b, p = rng.uniform(-1, 1, 3)
            out[k, :, :, c] = 128 + 70 * np.sin(3 * (a * xx + b * yy) + 6 * p) + 40 * np.cos(7 * xx * a - 5 * yy * b)
    return np.clip(out, 0, 255).astype(np.uint8)


def make_capture(t: int = 6, rgb_wh=(64, 48), depth_wh=(32, 24), seed: int = 0,
                 frame_ids=None, confidence: bool = True) -> Capture:
    """A ``t``-frame capture with random but deterministic poses, per-frame intrinsics and depth."""
    rng = np.random.default_rng(seed)
    w, h = rgb_wh
    dw, dh = depth_wh
    rgb = smooth_rgb(rng, t, h, w)
    # Depth 0.5..4.5 m with holes (NaN), kept to values a float16 EXR stores to < 2 mm.
    depth = rng.uniform(0.5, 4.5, (t, dh, dw)).astype(np.float32)
    depth[rng.random((t, dh, dw)) < 0.1] = np.nan
    conf = rng.integers(0, 3, (t, dh, dw), dtype=np.uint8) if confidence else None
    fx = 55 + rng.uniform(-0.5, 0.5, t)
    intr = np.stack([fx, fx * 1.01, np.full(t, w / 2 + 3.3), np.full(t, h / 2 - 2.1)], 1)
    rots = [axis_angle_to_matrix(rng.normal(size=3), rng.uniform(0, np.pi)) for _ in range(t)]
    poses = np.stack([make_se3(r, rng.normal(size=3)) for r in rots])
    ids = np.arange(t) if frame_ids is None else np.asarray(frame_ids)
    return Capture(
        rgb=rgb, depth=depth, confidence=conf, rgb_intrinsics=intr,
        depth_intrinsics=depth_intrinsics_from_rgb(intr, rgb_wh, depth_wh),
        world_from_camera=poses, timestamps=ids / 30.0, frame_ids=ids.astype(np.int64),
    )


@pytest.fixture
def capture() -> Capture:
    return make_capture()
