"""One scene drawn at random from everything the generator can vary: ``random_scene_spec(seed)``.

The family spans furniture kind, texture, size, opening range (doors 20-110 degrees, drawers
10-40 cm, the cabinet deep enough), hand model and the side the arm comes from, hinge-side gap
and front thickness, shelves and contents, handle shape, both camera paths, noise level and the
session offset, and, each with some probability, a pose lag and an exposure drift in the dynamic
recording and a static sweep that covers one side only (partial overlap). Scenes are small
(RGB 192x144, depth 96x72, 24 + 24 frames): the ``quick`` preset runs one end to end in about
10 CPU-minutes (docs/generalization.md has the measurements).
"""

from __future__ import annotations

import dataclasses
import zlib

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.synth._generate import static_shift_for_overlap
from artitwin_core.synth._motion import FPS
from artitwin_core.synth._spec import (
    ARM_SIDES,
    CAMERA_PATHS,
    FURNITURE_KINDS,
    HAND_MODELS,
    HANDLE_SHAPES,
    TEXTURE_KINDS,
    SceneSpec,
)

# Probabilities of the drawn options, in the order of the tuples they index.
_FURNITURE_P = (0.4, 0.3, 0.3)
_TEXTURE_P = (0.75, 0.25)
_HAND_P = (0.25, 0.25, 0.15, 0.2, 0.15)  # palm, sphere, thin, glove, none
_ARM_P = (0.25, 0.3, 0.3, 0.15)  # auto, left, right, above
_STATIC_PATH_P = (0.55, 0.3, 0.15)  # orbit, walk, closeup (a static close-up overlaps less)
_DYNAMIC_PATH_P = (0.4, 0.3, 0.3)
P_POSE_LAG = 0.25
P_EXPOSURE = 0.25
P_PARTIAL_OVERLAP = 0.25
_FIELDS = frozenset(f.name for f in dataclasses.fields(SceneSpec))
# A partial overlap aims at an overlap fraction drawn from this range.
PARTIAL_OVERLAP = (0.3, 0.6)


def random_scene_spec(seed: int, **overrides) -> SceneSpec:
    """A scene drawn from the generator's family, the same for the same ``seed``.

    Args:
        seed: drives the draw and becomes ``SceneSpec.seed`` (layout, textures, paths, noise).
        **overrides: ``SceneSpec`` fields to fix instead of drawing them; the other fields are
            drawn as without them (each draw is made whether or not it is overridden), and draws
            that depend on a fixed field follow it (a fixed ``furniture="drawer"`` gets no
            shelves; a fixed ``size_m`` bounds the drawer's travel).

    Returns:
        The ``SceneSpec``; every draw is in its fields (and so in the scene's ground truth).
    """
    unknown = sorted(set(overrides) - _FIELDS)
    if unknown:
        raise InputError(f"random_scene_spec: unknown SceneSpec fields {unknown}; known: {sorted(_FIELDS)}.")
    rng = np.random.default_rng([int(seed), zlib.crc32(b"random_scene_spec")])
    draw: dict = {}

    def pick(name: str, value):
        draw[name] = overrides.get(name, value)
        return draw[name]

    def choice(options: tuple, p: tuple):
        return options[int(rng.choice(len(options), p=p))]

    furniture = pick("furniture", choice(FURNITURE_KINDS, _FURNITURE_P))
    pick("texture", choice(TEXTURE_KINDS, _TEXTURE_P))
    pick("door_open_rad", float(np.deg2rad(rng.uniform(20.0, 110.0))))
    drawer_open = float(rng.uniform(0.10, 0.40))
    width = float(rng.uniform(0.5, 1.0))
    height = float(rng.uniform(*{"door": (0.6, 1.2), "drawer": (0.5, 1.0), "door+drawer": (0.8, 1.3)}[furniture]))
    depth = float(rng.uniform(0.35, 0.6))
    if "drawer" in furniture:  # deep enough for the drawer's travel and its box behind the front
        depth = max(depth, drawer_open + 0.1)
    size = pick("size_m", (round(width, 3), round(height, 3), round(depth, 3)))
    pick("drawer_open_m", min(drawer_open, size[2] - 0.08))
    pick("hand_model", choice(HAND_MODELS, _HAND_P))
    pick("arm_from", choice(ARM_SIDES, _ARM_P))
    pick("hand_occlusion", 1.5 if rng.random() < 0.2 else 1.0)
    pick("hinge_gap_m", float(rng.uniform(0.0, 0.01)))
    pick("front_thickness_m", float(rng.uniform(0.012, 0.03)))
    shelves = int(rng.integers(0, 4))
    pick("shelves", 0 if draw["furniture"] == "drawer" else shelves)
    pick("interior_items", bool(rng.random() < 0.8))
    pick("handle", choice(HANDLE_SHAPES, (0.25, 0.25, 0.25, 0.25)))
    pick("static_path", choice(CAMERA_PATHS, _STATIC_PATH_P))
    pick("dynamic_path", choice(CAMERA_PATHS, _DYNAMIC_PATH_P))
    pick("noise_level", float(np.exp(rng.uniform(np.log(0.3), np.log(2.0)))))
    pick("session_offset_m", float(rng.uniform(0.0, 3.0)))
    pick("static_frames", 24)
    pick("dynamic_frames", 24)
    pick("static_stride", 4)  # a 3 s sweep
    dynamic_stride = pick("dynamic_stride", 3)  # a 2.3 s recording
    effects = []
    lag_frames = float(rng.uniform(0.5, 3.0))
    if rng.random() < P_POSE_LAG:
        effects.append(("pose_lag", {"seconds": round(lag_frames * dynamic_stride / FPS, 4), "recordings": "dynamic"}))
    stops = float(rng.uniform(0.2, 0.5))
    if rng.random() < P_EXPOSURE:
        effects.append(("exposure", {"stops_std": round(stops, 3), "recordings": "dynamic"}))
    pick("effects", tuple(effects))
    target_overlap = float(rng.uniform(*PARTIAL_OVERLAP))
    partial = bool(rng.random() < P_PARTIAL_OVERLAP)
    for name, value in (("rgb_size", (192, 144)), ("depth_size", (96, 72)), ("seed", int(seed))):
        pick(name, value)
    draw.update({k: v for k, v in overrides.items() if k not in draw})
    draw.setdefault("static_shift_m", 0.0)
    if partial and "static_shift_m" not in overrides:
        # Aim at the fraction: the shift that gives it depends on both camera paths and the room.
        draw["static_shift_m"] = static_shift_for_overlap(SceneSpec(**draw), target_overlap)
    return SceneSpec(**draw)
