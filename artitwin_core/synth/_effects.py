"""The registry of effects the generator can inject, each documented with its parameters.

An effect is named in ``SceneSpec.effects`` as ``(name, {param: value})``; missing parameters
take the defaults below. Sensor, timing and pose effects apply to both recordings unless their
parameter ``recordings`` says ``"static"`` or ``"dynamic"`` (a phone's exposure may wander in one
recording only); joint effects change how the parts really move (the ground truth then holds the nominal joint plus the true
per-frame motion in ``SceneGroundTruth.part_world_from_closed``). The ground truth records every
effect with its resolved parameters, whether or not the capture files admit to it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from artitwin_core._errors import InputError


@dataclass(frozen=True)
class Effect:
    """One injectable effect.

    Attributes:
        name: the key in ``EFFECTS``.
        target: what it changes: ``rgb``, ``depth``, ``pose``, ``timing``, ``lens`` or ``joint``.
        defaults: every parameter with its default value (unknown parameters are refused).
        doc: what it does and what each parameter means, with units.
    """

    name: str
    target: str
    defaults: dict = field(default_factory=dict)
    doc: str = ""


_ALL = (
    Effect(
        "exposure",
        "rgb",
        {"stops_std": 0.35, "freq_hz": 0.4},
        "Auto-exposure wander: RGB linear radiance is multiplied per frame by 2**e(t), e a smooth "
        "random signal with std `stops_std` (photographic stops) and frequencies up to `freq_hz`.",
    ),
    Effect(
        "white_balance",
        "rgb",
        {"gain_std": 0.06, "freq_hz": 0.3},
        "Auto white balance wander: red and blue channels are multiplied per frame by 1 + g(t), "
        "g smooth with std `gain_std` (green fixed).",
    ),
    Effect(
        "vignetting",
        "rgb",
        {"strength": 0.35},
        "Radial fall-off: linear RGB times 1 - strength * r**2, r the distance from the principal "
        "point divided by the distance to the farthest image corner.",
    ),
    Effect(
        "depth_bias",
        "depth",
        {"scale": 1.03, "offset_m": 0.01},
        "Systematic depth error: recorded depth = scale * depth + offset_m (metres), after noise.",
    ),
    Effect(
        "depth_noise",
        "depth",
        {"a_m": 0.001, "b_per_m": 0.002, "max_range_m": 5.0},
        "Overrides the depth noise model: sigma(z) = noise_level * (a_m + b_per_m * z**2) metres; "
        "depth beyond max_range_m (metres) is NaN.",
    ),
    Effect(
        "time_offset",
        "timing",
        {"seconds": 0.05},
        "RGB lags depth and pose: frame i's RGB is exposed at timestamps[i], its depth map and "
        "recorded pose are sampled at timestamps[i] + seconds. The true poses are those of the RGB.",
    ),
    Effect(
        "pose_lag",
        "timing",
        {"seconds": 0.067},
        "The recorded poses are late relative to both images: frame i's RGB and depth are taken at "
        "timestamps[i] with the camera where it truly was then, but its recorded pose is the camera's "
        "pose at timestamps[i] - seconds (negative: early). A pose stream buffered behind the "
        "images, as phone exports can be; 2 frames of a 30 fps stream is 0.067 s.",
    ),
    Effect(
        "pose_drift",
        "pose",
        {"trans_m_per_s": 0.02, "yaw_rad_per_s": 0.01},
        "Odometry drift in the recorded poses (not the true ones): a translation growing linearly "
        "in a random horizontal direction and a yaw about gravity growing linearly, left-multiplied "
        "onto world_from_camera (the session frame drifts away from the world).",
    ),
    Effect(
        "pose_jitter",
        "pose",
        {"trans_std_m": 0.003, "rot_std_rad": 0.003},
        "White noise per frame in the recorded poses: translation (metres) and rotation (radians, "
        "random axis) applied on the camera side.",
    ),
    Effect(
        "lens_distortion",
        "lens",
        {"k1": -0.08, "k2": 0.02, "p1": 0.0005, "p2": -0.0005, "record": True},
        "Renders RGB (and its part and hand masks) through OpenCV radial-tangential distortion "
        "(k1 k2 p1 p2). record=True writes the coefficients into Capture.distortion; record=False "
        "hides them (the file claims a pinhole camera). Depth stays pinhole, as ARKit's is.",
    ),
    Effect(
        "rolling_shutter",
        "timing",
        {"readout_s": 0.03},
        "RGB row v is exposed at t + (v / (H - 1) - 0.5) * readout_s with the camera pose of that "
        "instant (the joint and hand are held at the frame's mid-exposure state). The true pose is "
        "the mid-row pose.",
    ),
    Effect(
        "screw_joint",
        "joint",
        {"rise_m_per_rad": 0.01},
        "Rising hinge: every revolute door also rises by rise_m_per_rad * q metres along gravity-up "
        "while it opens. The ground truth joint becomes a screw joint with that pitch (signed "
        "along its axis), which describes the motion exactly.",
    ),
    Effect(
        "axis_sag",
        "joint",
        {"angle_rad": 0.04},
        "A sagging hinge: on top of the nominal rotation, each revolute door droops by "
        "angle_rad * q / q_max about the horizontal axis through the pivot perpendicular to the "
        "door plane (its free edge drops). The ground truth keeps the nominal revolute joint.",
    ),
    Effect(
        "drawer_tilt",
        "joint",
        {"angle_rad": 0.04},
        "A drawer that tilts as it slides: on top of the nominal translation, its front dips by "
        "angle_rad * q / q_max about the horizontal axis through its back-bottom edge. The ground "
        "truth keeps the nominal prismatic joint.",
    ),
)

EFFECTS: dict[str, Effect] = {e.name: e for e in _ALL}
RECORDINGS = ("both", "static", "dynamic")


def _scope_default(effect: Effect) -> dict:
    """Every effect but a joint effect takes ``recordings``: which recording(s) it is injected in."""
    return {} if effect.target == "joint" else {"recordings": "both"}


def resolve_effects(effects: tuple) -> dict[str, dict]:
    """``((name, params), ...)`` -> ``{name: params with defaults filled}``; refuses bad entries."""
    out: dict[str, dict] = {}
    for entry in effects:
        if not (isinstance(entry, tuple | list) and len(entry) == 2 and isinstance(entry[1], dict)):
            raise InputError(
                f"SceneSpec.effects entry {entry!r} is not a (name, {{param: value}}) pair; write e.g. "
                "('depth_bias', {'scale': 1.02})."
            )
        name, params = entry
        if name not in EFFECTS:
            raise InputError(f"SceneSpec.effects: unknown effect {name!r}; known: {sorted(EFFECTS)}.")
        if name in out:
            raise InputError(f"SceneSpec.effects names {name!r} twice; give it once.")
        defaults = {**EFFECTS[name].defaults, **_scope_default(EFFECTS[name])}
        unknown = set(params) - set(defaults)
        if unknown:
            raise InputError(
                f"SceneSpec.effects[{name!r}]: unknown parameters {sorted(unknown)}; "
                f"known: {sorted(defaults)}."
            )
        resolved = {**defaults, **params}
        if resolved.get("recordings", "both") not in RECORDINGS:
            raise InputError(
                f"SceneSpec.effects[{name!r}]: recordings is {resolved['recordings']!r}; use one of {RECORDINGS}."
            )
        out[name] = resolved
    return out


def effects_in(effects: dict[str, dict], recording: str) -> dict[str, dict]:
    """The resolved ``effects`` injected in ``recording`` (``"static"`` or ``"dynamic"``)."""
    return {n: p for n, p in effects.items() if p.get("recordings", "both") in ("both", recording)}
