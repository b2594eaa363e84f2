"""Synthetic articulated scenes with exact ground truth.

``generate_scene(SceneSpec(...))`` renders a room with a cabinet (revolute door, prismatic
drawer, or both) into two iPhone-like RGB-D recordings: a static sweep with the parts closed,
and a dynamic one in which a hand opens them, in its own session frame. The canonical frame is
the static recording's world frame: y up (gravity along -y), floor at y = 0, cabinet front at
z = 0 facing +z. ``render_state`` renders the true scene at any joint state and viewpoint.

Example::

    scene = generate_scene(BENCHMARK_SCENES["tiny"])        # ~1 s on one core
    other = generate_scene(random_scene_spec(seed=3))        # any scene of the family
    write_scene(scene, "out/tiny")                           # static.r3d, dynamic.r3d, ground_truth/
    truth = load_ground_truth("out/tiny")
    rgb, depth, part_mask = render_state(scene, truth.static_world_from_camera[0],
                                         scene.static.rgb_intrinsics[0], 128, 96, q=[0.5])
"""

from artitwin_core.synth._effects import EFFECTS, Effect
from artitwin_core.synth._generate import (
    SyntheticScene,
    generate_scene,
    render_state,
    static_shift_for_overlap,
)
from artitwin_core.synth._io import load_ground_truth, load_scene_spec, write_scene
from artitwin_core.synth._motion import look_at
from artitwin_core.synth._random import random_scene_spec
from artitwin_core.synth._render import WorldState, render_view
from artitwin_core.synth._sensor import srgb_to_linear
from artitwin_core.synth._spec import BENCHMARK_SCENES, SceneSpec
from artitwin_core.synth._types import SceneGroundTruth

__all__ = [
    "srgb_to_linear",
    "render_view",
    "WorldState",
    "look_at",
    "BENCHMARK_SCENES",
    "EFFECTS",
    "Effect",
    "SceneGroundTruth",
    "SceneSpec",
    "SyntheticScene",
    "generate_scene",
    "load_ground_truth",
    "load_scene_spec",
    "random_scene_spec",
    "render_state",
    "static_shift_for_overlap",
    "write_scene",
]
