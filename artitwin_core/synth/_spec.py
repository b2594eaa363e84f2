"""What a synthetic scene is made of: the frozen ``SceneSpec`` and the named benchmark scenes."""

from __future__ import annotations

from dataclasses import dataclass

from artitwin_core._errors import InputError
from artitwin_core.synth._effects import resolve_effects

FURNITURE_KINDS = ("door", "drawer", "door+drawer")
TEXTURE_KINDS = ("textured", "low-texture")
HAND_MODELS = ("palm", "sphere", "thin", "glove", "none")
ARM_SIDES = ("auto", "left", "right", "above")
HANDLE_SHAPES = ("bar", "knob", "long-bar", "none")
CAMERA_PATHS = ("orbit", "walk", "closeup")
DOOR_MAX_RAD = 1.92  # 110 degrees
MAX_SHELVES = 4


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
        door_open_rad: how far the door opens in the dynamic recording (radians, up to 1.92 =
            110 degrees).
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
        hand_model: the hand that opens the parts: ``"palm"`` (a box palm with capsule fingers
            on a two-segment arm), ``"sphere"`` (a ball on a straight forearm cylinder), ``"thin"``
            (a small hand on a thin arm), ``"glove"`` (a box mitten on a box sleeve) or ``"none"``
            (the parts move by themselves, as ``hand_occlusion=0``).
        arm_from: where the arm comes from: ``"auto"`` (the handle's side of the view; the other
            side at ``hand_occlusion`` 2), ``"left"``, ``"right"`` (the lower left or right of
            the view, whatever the handle's side) or ``"above"`` (the top of the view).
        hinge_gap_m: gap (metres) between a door's hinge edge and the carcass's outer edge; the
            door turns about its own back hinge-side edge, set in by this much.
        front_thickness_m: thickness (metres) of doors and drawer fronts.
        shelves: shelf boards in the door's compartment, evenly spaced (none in a drawer chest).
        interior_items: whether objects stand inside the cabinet and its drawer.
        handle: ``"bar"`` (a short bar: vertical on doors, horizontal on drawers), ``"knob"``,
            ``"long-bar"`` (most of the door's height, most of the drawer's width) or ``"none"``
            (a plain front; the hand pulls at its edge).
        static_path, dynamic_path: each recording's camera path: ``"orbit"`` (an arc around the
            furniture), ``"walk"`` (walking past it: mostly translation, with step bob) or
            ``"closeup"`` (an arc 0.6-0.9 m from the cabinet's front).
        static_shift_m: moves the static sweep this far (metres) along the cabinet's front, away
            from the side the dynamic recording watches from, so the two recordings overlap
            only partly (``SceneGroundTruth.overlap_fraction`` says how much).
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
    hand_model: str = "palm"
    arm_from: str = "auto"
    hinge_gap_m: float = 0.0
    front_thickness_m: float = 0.02
    shelves: int = 0
    interior_items: bool = True
    handle: str = "bar"
    static_path: str = "orbit"
    dynamic_path: str = "orbit"
    static_shift_m: float = 0.0
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
        if not 0.0 < self.door_open_rad <= DOOR_MAX_RAD:
            raise InputError(
                f"SceneSpec.door_open_rad is {self.door_open_rad}; use (0, {DOOR_MAX_RAD}] radians (110 degrees)."
            )
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
        for name, allowed in (("hand_model", HAND_MODELS), ("arm_from", ARM_SIDES), ("handle", HANDLE_SHAPES),
                              ("static_path", CAMERA_PATHS), ("dynamic_path", CAMERA_PATHS)):
            if getattr(self, name) not in allowed:
                raise InputError(f"SceneSpec.{name} is {getattr(self, name)!r}; use one of {allowed}.")
        if not 0.0 <= self.hinge_gap_m <= 0.015:
            raise InputError(
                f"SceneSpec.hinge_gap_m is {self.hinge_gap_m}; use 0-0.015 m (a wider gap than the 18 mm "
                "side board would open onto the cabinet's inside)."
            )
        if not 0.008 <= self.front_thickness_m <= 0.05:
            raise InputError(f"SceneSpec.front_thickness_m is {self.front_thickness_m}; use 0.008-0.05 m.")
        if isinstance(self.shelves, bool) or not isinstance(self.shelves, int) or not 0 <= self.shelves <= MAX_SHELVES:
            raise InputError(f"SceneSpec.shelves is {self.shelves!r}; use a whole number 0-{MAX_SHELVES}.")
        if self.shelves and self.furniture == "drawer":
            raise InputError(
                "SceneSpec.shelves go in a door's compartment, and furniture='drawer' has none; set shelves=0 "
                "or use furniture='door' or 'door+drawer'."
            )
        if not isinstance(self.interior_items, bool):
            raise InputError(f"SceneSpec.interior_items is {self.interior_items!r}; use True or False.")
        if not 0.0 <= self.static_shift_m <= 1.5:
            raise InputError(f"SceneSpec.static_shift_m is {self.static_shift_m}; use 0-1.5 m (0: full overlap).")
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
