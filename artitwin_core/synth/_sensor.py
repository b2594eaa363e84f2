"""An iPhone-like sensor: what turns clean renders into recorded RGB, depth and confidence.

Depth: Gaussian noise with sigma = noise_level * (a + b z^2), NaN at depth discontinuities and
beyond the maximum range, ARKit-like confidence (2 high, 1 medium near edges / far / at grazing
angles, 0 where invalid). RGB: exposure and white-balance gains, vignetting, shot-like noise,
then the sRGB curve and 8-bit quantisation (JPEG compression is left to the file writers).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from artitwin_core.geometry import corner_radius_sq

DEPTH_A_M = 0.001
DEPTH_B_PER_M = 0.002
MAX_RANGE_M = 5.0
# Inverse depth is affine in pixel coordinates on a plane, so its second difference is ~0 on
# every surface, however slanted; occlusion boundaries give tens of percent. 8 % also leaves
# convex creases (cabinet corners, a few percent at 128x96) valid.
EDGE_SECOND_DIFF = 0.08
MEDIUM_BEYOND_M = 2.5
LOW_BEYOND_M = 4.0


def default_intrinsics(width: int, height: int) -> np.ndarray:
    """``(fx, fy, cx, cy)`` of an iPhone-like wide camera: ~64 degrees across, off-centre."""
    f = 0.80 * width
    return np.array([f, f, 0.512 * width, 0.484 * height])


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


def vignette(width: int, height: int, intrinsics, strength: float) -> np.ndarray:
    """``[H, W]`` gain 1 - strength * r^2, r normalised to 1 at the farthest image corner."""
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    return 1.0 - strength * corner_radius_sq(intrinsics, u, v, width, height)


def expose_rgb(
    radiance: np.ndarray, gain: np.ndarray, noise_level: float, rng: np.random.Generator | None
) -> np.ndarray:
    """Linear radiance ``[H, W, 3]`` times ``gain`` (``[3]`` or ``[H, W, 1 or 3]``) -> uint8 sRGB."""
    x = radiance * gain
    if rng is not None and noise_level > 0:
        sigma = noise_level * (0.002 + 0.01 * np.sqrt(np.clip(x, 0, None)))
        x = x + sigma * rng.standard_normal(x.shape)
    return np.round(linear_to_srgb(x) * 255.0).astype(np.uint8)


def depth_sensor(
    z: np.ndarray,
    cos_incidence: np.ndarray,
    rng: np.random.Generator,
    noise_level: float,
    a_m: float = DEPTH_A_M,
    b_per_m: float = DEPTH_B_PER_M,
    max_range_m: float = MAX_RANGE_M,
    scale: float = 1.0,
    offset_m: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Clean z-depth ``[h, w]`` (inf on a miss) -> recorded depth ``[h, w]`` float32 (NaN invalid)
    and confidence ``[h, w]`` uint8.

    ``scale``/``offset_m`` are the ``depth_bias`` effect, applied after the noise.
    """
    finite = np.isfinite(z)
    zf = np.where(finite, z, 1e6)
    w = np.pad(1.0 / zf, 1, mode="edge")
    d2x = np.abs(w[1:-1, :-2] - 2 * w[1:-1, 1:-1] + w[1:-1, 2:])
    d2y = np.abs(w[:-2, 1:-1] - 2 * w[1:-1, 1:-1] + w[2:, 1:-1])
    edge = np.maximum(d2x, d2y) > EDGE_SECOND_DIFF * w[1:-1, 1:-1]
    invalid = edge | ~finite | (zf > max_range_m)
    near_edge = ndimage.binary_dilation(edge, iterations=1)
    sigma = noise_level * (a_m + b_per_m * zf**2)
    noisy = zf + sigma * rng.standard_normal(z.shape)
    depth = np.where(invalid, np.nan, scale * noisy + offset_m).astype(np.float32)
    conf = np.full(z.shape, 2, dtype=np.uint8)
    conf[near_edge | (zf > MEDIUM_BEYOND_M) | (cos_incidence < 0.35)] = 1
    conf[invalid | (zf > LOW_BEYOND_M) | (cos_incidence < 0.12)] = 0
    return depth, conf
