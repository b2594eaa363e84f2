"""What a synthetic scene is made of: the frozen ``SceneSpec`` and the named benchmark scenes."""

from __future__ import annotations

from dataclasses import dataclass

from artitwin_core._errors import InputError
from artitwin_core.synth._effects import resolve_effects

FURNITURE_KINDS = ("door", "drawer", "door+drawer")
TEXTURE_KINDS = ("textured", "low-texture")


@dataclass(frozen=True)
class SceneSpec:
    """Everything that defines one synthetic scene; the same spec always gives the same scene.

    The canonical frame (= the static recording's world frame) has gravity along -y (y up, as
    ARKit's world frame), the floor at y = 0 and the cabinet's front face at z = 0 facing +z.

    Attributes:
        furniture: ``"door"`` (a cabinet with one revolute door), ``"drawer"`` (a chest whose
            top drawer slides; the bottom one stays shut) or ``"door+drawer"`` (a drawer below a
            door; the hand opens the door, then the drawer).
        texture: ``"textured"`` (wood grain) or ``"low-texture"`` (white painted furniture).
        size_m: cabinet ``(width, height, depth)`` in metres.
        door_open_rad: how far the door opens in the dynamic recording (radians).
        drawer_open_m: how far the drawer slides out (metres, less than the depth).
        static_frames, dynamic_frames: frames in each recording.
        static_stride, dynamic_stride: the recordings are 30 fps streams of which every
            ``stride``-th frame is kept (frame_ids have gaps; timestamps are frame_id / 30).
        rgb_size, depth_size: ``(width, height)`` in pixels; the aspect ratios must match.
        rgb_supersample: RGB anti-aliasing, ``n x n`` rays per pixel averaged (1 = point
            sampling, the default; 2 costs ~4x the time for smoother edges and texture).
            Masks and depth always use pixel-centre rays.
        noise_level: multiplies the RGB sensor noise and the depth noise (0 = noise-free).
        hand_occlusion: 0 = no hand (the part moves by itself), 1 = a hand and arm reaching in
            from the lower right, 2 = a bigger arm crossing the view.
        session_offset_m: distance (metres) between the two recordings' session origins; the yaw
            between them is drawn uniformly from [-pi, pi).
        effects: ``((name, {param: value}), ...)`` from ``EFFECTS``.
        seed: drives every random choice (hinge side, layout, textures, paths, noise).

    Specs compare by value; their effect parameters are dicts, so they are not hashable (key
    caches on ``repr(spec)``).
    """

    furniture: str = "door"
    texture: str = "textured"
    size_m: tuple[float, float, float] = (0.8, 0.9, 0.45)
    door_open_rad: float = 1.2
    drawer_open_m: float = 0.25
    static_frames: int = 40
    dynamic_frames: int = 30
    static_stride: int = 3
    dynamic_stride: int = 2
    rgb_size: tuple[int, int] = (256, 192)
    depth_size: tuple[int, int] = (128, 96)
    rgb_supersample: int = 1
    noise_level: float = 1.0
    hand_occlusion: float = 1.0
    session_offset_m: float = 1.0
    effects: tuple = ()
    seed: int = 0

    def __post_init__(self) -> None:
        if self.furniture not in FURNITURE_KINDS:
            raise InputError(f"SceneSpec.furniture is {self.furniture!r}; use one of {FURNITURE_KINDS}.")
        if self.texture not in TEXTURE_KINDS:
            raise InputError(f"SceneSpec.texture is {self.texture!r}; use one of {TEXTURE_KINDS}.")
        w, h, d = self.size_m
        if not (0.3 <= w <= 2.0 and 0.3 <= h <= 2.2 and 0.25 <= d <= 1.0):
            raise InputError(
                f"SceneSpec.size_m is {self.size_m}; width 0.3-2 m, height 0.3-2.2 m, depth 0.25-1 m."
            )
        if not 0.0 < self.drawer_open_m < d - 0.06:
            raise InputError(f"SceneSpec.drawer_open_m must be in (0, depth - 0.06) = (0, {d - 0.06:.2f}) m.")
        if not 0.0 < self.door_open_rad <= 1.9:
            raise InputError("SceneSpec.door_open_rad must be in (0, 1.9] radians.")
        for name in ("static_frames", "dynamic_frames"):
            if getattr(self, name) < 2:
                raise InputError(f"SceneSpec.{name} must be at least 2.")
        for name in ("static_stride", "dynamic_stride", "rgb_supersample"):
            if getattr(self, name) < 1:
                raise InputError(f"SceneSpec.{name} must be at least 1.")
        (rw, rh), (dw, dh) = self.rgb_size, self.depth_size
        if min(rw, rh, dw, dh) < 8:
            raise InputError("SceneSpec.rgb_size and depth_size must be at least 8 pixels each way.")
        if rw * dh != rh * dw:
            raise InputError(
                f"SceneSpec.rgb_size {self.rgb_size} and depth_size {self.depth_size} have different "
                "aspect ratios; keep them equal (the depth intrinsics are the RGB ones scaled)."
            )
        if self.noise_level < 0 or self.hand_occlusion < 0 or self.session_offset_m < 0:
            raise InputError("SceneSpec.noise_level, hand_occlusion and session_offset_m must be >= 0.")
        resolve_effects(self.effects)

    @property
    def resolved_effects(self) -> dict[str, dict]:
        """``{name: params}`` with every default filled in."""
        return resolve_effects(self.effects)


BENCHMARK_SCENES: dict[str, SceneSpec] = {
    # Used by the demo and the tests: renders in a few seconds.
    "tiny": SceneSpec(
        static_frames=12, dynamic_frames=12, static_stride=8, dynamic_stride=5,
        rgb_size=(128, 96), depth_size=(64, 48), seed=7,
    ),
    "door": SceneSpec(furniture="door", seed=1),
    "drawer": SceneSpec(furniture="drawer", seed=2),
    "door+drawer": SceneSpec(furniture="door+drawer", dynamic_frames=40, seed=3),
    "low-texture-door": SceneSpec(furniture="door", texture="low-texture", seed=4),
    "strong-hand-occlusion": SceneSpec(furniture="door", hand_occlusion=2.0, seed=5),
    "low-noise": SceneSpec(furniture="drawer", noise_level=0.2, seed=6),
    "high-noise": SceneSpec(
        furniture="door", noise_level=3.0, seed=8,
        effects=(("pose_jitter", {}), ("exposure", {}), ("white_balance", {})),
    ),
    "large-session-offset": SceneSpec(furniture="door+drawer", session_offset_m=4.0, dynamic_frames=40, seed=9),
    # Unmodelled sensor defects. The distortion is not declared in the files (Record3D cannot
    # store it); the ground truth holds its coefficients.
    "sensor-effects": SceneSpec(
        furniture="door", seed=10,
        effects=(
            ("exposure", {}), ("vignetting", {}), ("depth_bias", {}), ("time_offset", {"seconds": 0.033}),
            ("lens_distortion", {"record": False}), ("rolling_shutter", {}), ("pose_drift", {}),
        ),
    ),
    "non-ideal-joints": SceneSpec(
        furniture="door+drawer", dynamic_frames=40, seed=11,
        effects=(("axis_sag", {}), ("drawer_tilt", {})),
    ),
}
