"""Procedural 3D textures evaluated in an object's own local frame.

A texture is a function of the surface point in the object's local frame (metres), so it moves
with the object: a door's wood grain turns with the door. Every texture returns linear-light
albedo in [0, 1]; the sensor model applies exposure and the sRGB curve afterwards.
"""

from __future__ import annotations

import numpy as np


def _hash01(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Integer lattice coordinates ``[N]`` -> pseudo-random values in [0, 1) ``[N]``.

    uint32 arithmetic wraps modulo 2^32, which is what the mixing constants expect.
    """
    u32 = np.uint32
    h = ix.astype(u32) * u32(73856093) ^ iy.astype(u32) * u32(19349663) ^ iz.astype(u32) * u32(83492791)
    h ^= u32((seed * 2654435761) & 0xFFFFFFFF)
    h = (h ^ (h >> u32(15))) * u32(2246822519)
    h = (h ^ (h >> u32(13))) * u32(3266489917)
    h ^= h >> u32(16)
    return (h >> u32(8)).astype(np.float64) * (1.0 / float(1 << 24))


def value_noise(points: np.ndarray, seed: int) -> np.ndarray:
    """Smooth 3D value noise at ``points [N, 3]`` (lattice spacing 1) -> ``[N]`` in [0, 1]."""
    p0 = np.floor(points)
    f = points - p0
    f = f * f * (3.0 - 2.0 * f)  # smoothstep: C1 across lattice cells
    i = p0.astype(np.int64)
    out = np.zeros(points.shape[0])
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1.0 - f[:, 0]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1.0 - f[:, 1]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1.0 - f[:, 2]
                out += wx * wy * wz * _hash01(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def fbm(points: np.ndarray, seed: int, octaves: int = 3) -> np.ndarray:
    """Fractal sum of ``octaves`` value-noise layers at ``points [N, 3]`` -> ``[N]`` about [0, 1]."""
    out = np.zeros(points.shape[0])
    amp, total = 1.0, 0.0
    for o in range(octaves):
        out += amp * value_noise(points * (2.0**o), seed + 101 * o)
        total += amp
        amp *= 0.5
    return out / total


def _wood(p: np.ndarray, prm: dict) -> np.ndarray:
    # Rings about the local y axis (grain runs along y), warped by noise so they are not circles.
    scale = prm.get("scale", 1.0)
    q = p * scale
    warp = fbm(q * np.array([4.0, 0.6, 4.0]), prm["seed"]) - 0.5
    r = np.sqrt(q[:, 0] ** 2 + (q[:, 2] + 0.7) ** 2) + 0.08 * warp
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * prm.get("ring_freq", 18.0) * r)
    fine = fbm(q * np.array([60.0, 4.0, 60.0]), prm["seed"] + 7, octaves=2)
    a, b = np.asarray(prm["color_a"]), np.asarray(prm["color_b"])
    t = (rings**2)[:, None]
    return ((1 - t) * a + t * b) * (0.85 + 0.3 * fine)[:, None]


def _noise(p: np.ndarray, prm: dict) -> np.ndarray:
    n = fbm(p * prm.get("freq", 12.0), prm["seed"], octaves=4)
    base = np.asarray(prm["color"])
    tint = np.asarray(prm.get("color_b", prm["color"]))
    t = n[:, None]
    return ((1 - t) * base + t * tint) * (0.55 + 0.9 * n)[:, None]


def _paint(p: np.ndarray, prm: dict) -> np.ndarray:
    # Nearly uniform: what feature trackers find hard (white furniture, painted walls).
    n = value_noise(p * prm.get("freq", 6.0), prm["seed"])
    return np.asarray(prm["color"])[None, :] * (1.0 + prm.get("amp", 0.02) * (n - 0.5))[:, None]


def _floor(p: np.ndarray, prm: dict) -> np.ndarray:
    # Planks along local x, each with its own tint, plus fine grain.
    plank = np.floor(p[:, 2] / 0.14).astype(np.int64)
    tint = _hash01(plank, np.zeros_like(plank), np.zeros_like(plank), prm["seed"])
    grain = fbm(p * np.array([3.0, 40.0, 40.0]), prm["seed"] + 3)
    a, b = np.asarray(prm["color_a"]), np.asarray(prm["color_b"])
    t = (0.6 * tint + 0.4 * grain)[:, None]
    seam = (np.abs(p[:, 2] / 0.14 - np.round(p[:, 2] / 0.14)) < 0.03)[:, None]
    return np.where(seam, a * 0.4, (1 - t) * a + t * b)


def _wall(p: np.ndarray, prm: dict) -> np.ndarray:
    # Painted wall with rectangular posters (local x, y on the wall plane) in high-contrast patterns.
    out = _paint(p, {"color": prm["color"], "seed": prm["seed"], "amp": 0.04})
    for k, (x0, y0, x1, y1) in enumerate(prm.get("posters", ())):
        inside = (p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1)
        if not np.any(inside):
            continue
        q = p[inside]
        s = prm["seed"] + 31 * (k + 1)
        n = fbm(q * 9.0, s, octaves=4)
        stripes = 0.5 + 0.5 * np.sin(40.0 * (q[:, 0] + 0.5 * q[:, 1]) + 6.0 * n)
        hue = 2 * np.pi * (n[:, None] + np.array([0.0, 0.33, 0.67]) + 0.1 * k)
        col = 0.15 + 0.75 * (0.5 + 0.5 * np.cos(hue)) * (0.4 + 0.6 * stripes[:, None])
        border = (
            np.minimum.reduce([q[:, 0] - x0, x1 - q[:, 0], q[:, 1] - y0, y1 - q[:, 1]]) < 0.015
        )[:, None]
        out[inside] = np.where(border, 0.9, col)
    return out


def _solid(p: np.ndarray, prm: dict) -> np.ndarray:
    return np.broadcast_to(np.asarray(prm["color"], dtype=np.float64), (p.shape[0], 3)).copy()


TEXTURES = {
    "wood": _wood,
    "noise": _noise,
    "paint": _paint,
    "floor": _floor,
    "wall": _wall,
    "solid": _solid,
}


def evaluate_texture(name: str, points_local: np.ndarray, params: dict) -> np.ndarray:
    """Albedo ``[N, 3]`` (linear, [0, 1]) of texture ``name`` at ``points_local [N, 3]`` metres."""
    return np.clip(TEXTURES[name](np.asarray(points_local, dtype=np.float64), params), 0.0, 1.0)
