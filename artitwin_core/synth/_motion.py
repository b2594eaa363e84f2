"""Everything that moves with time: handheld camera paths, the joint states q(t), the hand and arm.

Every trajectory is a smooth function of continuous time (seconds), so effects that sample a
frame at a shifted instant (time offset, rolling shutter) get the true state at that instant.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from artitwin_core.geometry import axis_angle_to_matrix, invert_se3, make_se3
from artitwin_core.synth._scene import (
    BOX_TRIANGLES,
    HAND_LABEL,
    UP,
    SceneModel,
    SceneObject,
    boxes,
    cylinder,
    part_motion,
    sphere,
    sub_rng,
)

FPS = 30.0


class SmoothNoise:
    """A smooth random signal ``t [N] -> [N, dim]``: a sum of sines, unit variance per dimension."""

    def __init__(self, rng: np.random.Generator, dim: int, max_freq_hz: float, terms: int = 4):
        self.freq = rng.uniform(0.25, 1.0, (terms, dim)) * max_freq_hz
        self.phase = rng.uniform(0.0, 2 * np.pi, (terms, dim))
        self.amp = np.sqrt(2.0 / terms)

    def __call__(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        return self.amp * np.sin(2 * np.pi * self.freq[None] * t[:, None, None] + self.phase[None]).sum(1)


def ease(x) -> np.ndarray:
    """Smooth 0 -> 1 on [0, 1] (zero velocity at both ends), clamped outside."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def look_at(eye: np.ndarray, target: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """``[N, 3]`` eyes and targets, ``[N]`` roll (radians) -> ``[N, 4, 4]`` world_from_camera (OpenCV)."""
    z = target - eye
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross(z, UP)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    rot = np.stack([x, y, z], -1)  # columns: camera axes in the world
    rot = rot @ axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), roll)
    return make_se3(rot, eye)


@dataclass
class CameraPath:
    """A handheld sweep: an arc around ``centre`` at ``radius`` and ``height``, plus wobble."""

    centre: np.ndarray
    radius: float
    height: float
    angle0: float
    angle1: float
    duration: float
    drift: SmoothNoise  # slow hand wander of the eye, ~drift_m
    shake: SmoothNoise  # fast small jitter, ~2 mm
    wobble: SmoothNoise  # look-at target wander, ~5 cm
    roll: SmoothNoise  # ~2 degrees
    # Optional ``t [N] -> [N, 3]`` shift of the look-at target (the dynamic recording follows
    # the handle, as a person watches what they pull).
    target_shift: Callable[[np.ndarray], np.ndarray] | None = None
    drift_m: float = 0.04  # less for a close-up: the hand wanders less relative to the subject

    def world_from_camera(self, t) -> np.ndarray:
        """``t [N]`` seconds -> ``[N, 4, 4]`` true poses (OpenCV axes)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        ang = self.angle0 + (self.angle1 - self.angle0) * (0.15 * t / self.duration + 0.85 * ease(t / self.duration))
        eye = self.centre + np.stack([self.radius * np.sin(ang), np.full_like(ang, self.height - self.centre[1]),
                                      self.radius * np.cos(ang)], -1)
        eye = eye + self.drift_m * self.drift(t) + 0.002 * self.shake(t)
        target = self.centre + 0.05 * self.wobble(t)
        if self.target_shift is not None:
            target = target + self.target_shift(t)
        return look_at(eye, target, 0.035 * self.roll(t)[:, 0])


@dataclass
class WalkPath:
    """Walking past the furniture with the phone held out: the eye moves along the cabinet's front
    at ``distance`` (metres) from it, at roughly constant speed, bobbing up and down once per step
    and swaying sideways once per stride; the aim follows the eye ``follow`` of the way, so the
    view turns far less than on an orbit (mostly translation)."""

    centre: np.ndarray  # what the walker looks at, on average
    distance: float  # eye's z (the cabinet's front is z = 0)
    height: float
    x0: float  # eye's x at the start and at the end (metres)
    x1: float
    follow: float  # 0: aim fixed on the centre (pure turning), 1: aim straight ahead (no turning)
    duration: float
    bob_m: float  # vertical step bob amplitude
    step_hz: float
    phase: float
    drift: SmoothNoise
    shake: SmoothNoise
    wobble: SmoothNoise
    roll: SmoothNoise
    target_shift: Callable[[np.ndarray], np.ndarray] | None = None

    def world_from_camera(self, t) -> np.ndarray:
        """``t [N]`` seconds -> ``[N, 4, 4]`` true poses (OpenCV axes)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        u = t / self.duration
        x = self.x0 + (self.x1 - self.x0) * (0.5 * u + 0.5 * ease(u))
        step = 2 * np.pi * self.step_hz * t + self.phase
        eye = np.stack([
            x + 0.4 * self.bob_m * np.sin(0.5 * step),  # sideways sway, once per stride
            self.height + self.bob_m * np.cos(step),
            np.full_like(x, self.distance),
        ], -1)
        eye = eye + 0.015 * self.drift(t) + 0.002 * self.shake(t)
        target = self.centre + np.stack([self.follow * (x - self.centre[0]), np.zeros_like(x), np.zeros_like(x)], -1)
        target = target + 0.03 * self.wobble(t)
        if self.target_shift is not None:
            target = target + self.target_shift(t)
        return look_at(eye, target, 0.03 * self.roll(t)[:, 0])


def dynamic_side(model: SceneModel, seed: int) -> float:
    """The side of the cabinet (+1: +x, -1: -x) the dynamic recording watches from: a door's
    free-edge side, else drawn (the first draw of the dynamic camera's generator, as the orbit does)."""
    part = model.parts[0]
    if part.d_free is not None:
        return float(np.sign(part.d_free[0]))
    return float(sub_rng(seed, "camera_dynamic").choice([-1.0, 1.0]))


def _clearance(model: SceneModel, eyes: np.ndarray) -> float:
    """Smallest gap (metres) between eye positions ``[N, 3]`` and the space the parts sweep when
    fully open: a door's quarter disc about its hinge, a drawer's box pulled out (and its handle)."""
    gaps = [np.inf]
    for p in model.parts:
        if p.joint_type == "revolute":
            width = abs(p.grip[0] - p.pivot[0]) + 0.1
            gaps.append(float(np.min(np.linalg.norm(eyes[:, [0, 2]] - p.pivot[[0, 2]], axis=1) - width)))
        else:
            gaps.append(float(np.min(eyes[:, 2] - (p.grip[2] + 0.01 + p.q_max))))
    return min(gaps)


def camera_path(model: SceneModel, seed: int, which: str, duration: float, kind: str = "orbit",
                shift_m: float = 0.0) -> CameraPath | WalkPath:
    """The static sweep or the dynamic one, as an orbit (a wide arc for the static recording, a
    short arc on the free-edge side for the dynamic one), a walk past the cabinet, or a close-up
    arc 0.6-0.9 m from its front. ``shift_m`` moves the static sweep along the front, away from
    the side the dynamic recording watches from (partial overlap)."""
    if kind in ("walk", "closeup"):
        make = _walk_path if kind == "walk" else _closeup_path
        return _aim_beyond(make(model, seed, which, duration, shift_m), model, seed, which, shift_m)
    rng = sub_rng(seed, f"camera_{which}")
    if which == "static":
        # A person sweeps at ~15 degrees/s around the furniture (peak ~0.7 m/s at 1.6 m).
        span = np.deg2rad(np.clip(rng.uniform(13, 17) * duration, 30, 110))
        direction = rng.choice([-1.0, 1.0])
        a0, a1 = -direction * span / 2, direction * span / 2
        radius, height = rng.uniform(1.45, 1.75), rng.uniform(1.25, 1.45)
    else:
        part = model.parts[0]
        side = float(np.sign(part.d_free[0])) if part.d_free is not None else float(rng.choice([-1.0, 1.0]))
        mid = side * np.deg2rad(rng.uniform(10, 20))
        a0, a1 = mid - np.deg2rad(8), mid + np.deg2rad(8)
        radius, height = rng.uniform(1.15, 1.35), rng.uniform(1.2, 1.35)
    centre = model.look_at.copy()
    if which == "static" and shift_m:
        centre[0] -= dynamic_side(model, seed) * shift_m
    path = CameraPath(
        centre=centre, radius=float(radius), height=float(height),
        angle0=float(a0), angle1=float(a1), duration=max(duration, 1e-3),
        drift=SmoothNoise(rng, 3, 0.5), shake=SmoothNoise(rng, 3, 6.0),
        wobble=SmoothNoise(rng, 3, 0.6), roll=SmoothNoise(rng, 1, 0.4),
    )
    return _aim_beyond(path, model, seed, which, shift_m)


AIM_BEYOND = 0.5


def _aim_beyond(path, model: SceneModel, seed: int, which: str, shift_m: float):
    """A shifted static sweep also aims ``AIM_BEYOND`` of the shift further out, turning its view
    away from the cabinet's other side (the eye alone moving sideways keeps it in view)."""
    if which == "static" and shift_m:
        offset = np.array([-dynamic_side(model, seed) * AIM_BEYOND * shift_m, 0.0, 0.0])
        path.target_shift = lambda t: np.broadcast_to(offset, (np.atleast_1d(t).shape[0], 3))
    return path


def _walk_path(model: SceneModel, seed: int, which: str, duration: float, shift_m: float) -> WalkPath:
    rng = sub_rng(seed, f"camera_{which}_walk")
    side = dynamic_side(model, seed)
    duration = max(duration, 1e-3)
    speed = rng.uniform(0.25, 0.45)  # a slow walk, m/s
    length = float(np.clip(speed * duration, 0.3, 1.2))
    direction = float(rng.choice([-1.0, 1.0]))
    centre = np.array([model.look_at[0], model.look_at[1], 0.0])
    if which == "static":
        distance, height = rng.uniform(1.4, 1.8), rng.uniform(1.25, 1.45)
        mid = centre[0] - side * shift_m
        centre[0] = mid
    else:  # on the free-edge side, clear of an opening door's sweep
        distance, height = rng.uniform(1.25, 1.45), rng.uniform(1.2, 1.35)
        mid = centre[0] + side * distance * np.tan(np.deg2rad(rng.uniform(8, 16)))
    return WalkPath(
        centre=centre, distance=float(distance), height=float(height),
        x0=float(mid - direction * length / 2), x1=float(mid + direction * length / 2),
        follow=float(rng.uniform(0.6, 0.8)), duration=duration,
        bob_m=float(rng.uniform(0.012, 0.025)), step_hz=float(rng.uniform(1.6, 2.0)),
        phase=float(rng.uniform(0, 2 * np.pi)),
        drift=SmoothNoise(rng, 3, 0.5), shake=SmoothNoise(rng, 3, 6.0),
        wobble=SmoothNoise(rng, 3, 0.6), roll=SmoothNoise(rng, 1, 0.4),
    )


def _closeup_path(model: SceneModel, seed: int, which: str, duration: float, shift_m: float) -> CameraPath:
    """An arc whose eye stays ``distance`` (0.6-0.9 m, drawn) from a point on the cabinet's front."""
    rng = sub_rng(seed, f"camera_{which}_closeup")
    side = dynamic_side(model, seed)
    duration = max(duration, 1e-3)
    distance = float(rng.uniform(0.6, 0.9))
    rise = float(rng.uniform(0.1, 0.3))  # eye above the centre
    w = model.size_m[0]
    centre = np.array([model.look_at[0], model.look_at[1], 0.0])
    drift = dict(drift=SmoothNoise(rng, 3, 0.5), shake=SmoothNoise(rng, 3, 6.0),
                 wobble=SmoothNoise(rng, 3, 0.6), roll=SmoothNoise(rng, 1, 0.4))
    if which == "static":
        span = np.deg2rad(np.clip(rng.uniform(13, 17) * duration, 30, 90))
        direction = rng.choice([-1.0, 1.0])
        a0, a1 = -direction * span / 2, direction * span / 2
        centre[0] -= side * shift_m
    else:
        # Look at the free half of the front (a drawer's front where it ends up), from the
        # free-edge side, outside what the parts sweep (a door's edge must not pass through the
        # camera): the nearest, least oblique such view, else the one with the most room.
        centre[0] += side * w / 4
        centre[2] = max([p.grip[2] + p.q_max for p in model.parts if p.joint_type == "prismatic"], default=0.0)
        half = np.deg2rad(8)
        best = None
        for d in np.linspace(distance, 0.9, 7):
            r_h = np.sqrt(d * d - rise * rise)
            for mid_deg in np.arange(10.0, 61.0, 2.0):
                angles = side * np.deg2rad(mid_deg) + np.linspace(-half, half, 9)
                eyes = centre + np.stack([r_h * np.sin(angles), np.full_like(angles, rise), r_h * np.cos(angles)], -1)
                gap = _clearance(model, eyes)
                if best is None or gap > best[0]:
                    best = (gap, d, mid_deg)
                if gap >= 0.15:
                    best = (gap, d, mid_deg)
                    break
            if best[0] >= 0.15:
                break
        _, distance, mid_deg = best
        mid = side * np.deg2rad(mid_deg)
        a0, a1 = mid - half, mid + half
    r_h = float(np.sqrt(distance**2 - rise**2))
    return CameraPath(
        centre=centre, radius=r_h, height=float(centre[1] + rise), angle0=float(a0), angle1=float(a1),
        duration=duration, drift_m=0.015, **drift,
    )


@dataclass
class Interaction:
    """The dynamic recording's story: the hand opens each part in turn.

    Part k owns the time window ``[k, k + 1] * duration / K``: the hand approaches its handle
    (first 30 %), pulls it open with an eased q (next 55 %), then holds.
    """

    model: SceneModel
    duration: float
    path: CameraPath | WalkPath
    strength: float
    hand_model: str = "palm"  # SceneSpec.hand_model
    arm_from: str = "auto"  # SceneSpec.arm_from

    def __post_init__(self) -> None:
        # The camera drifts its aim towards the handles (their mean), 60 % of the way.
        def shift(t: np.ndarray) -> np.ndarray:
            out = np.zeros((len(t), 3))
            for i, ti in enumerate(t):
                qs = self.q(float(ti))
                grips = [self._grip(k, qk)[0] for k, qk in enumerate(qs)]
                out[i] = 0.6 * (np.mean(grips, axis=0) - self.path.centre)
            return out

        if self.model.parts:
            self.path.target_shift = shift

    def window(self, k: int, t) -> np.ndarray:
        n = len(self.model.parts)
        return np.asarray(t, dtype=np.float64) / self.duration * n - k

    def q(self, t: float) -> list[float]:
        """Joint states ``[K]`` at time ``t`` (radians / metres); 0 closed, q_max fully open."""
        return [float(p.q_max * ease((self.window(k, t) - 0.3) / 0.55)) for k, p in enumerate(self.model.parts)]

    def _side(self, k: int) -> float:
        """+1 if part k's handle is right of the view centre (mid-recording camera), else -1."""
        cam = self.path.world_from_camera(self.duration / 2)[0]
        in_cam = cam[:3, :3].T @ (self.model.parts[k].grip - cam[:3, 3])
        return 1.0 if in_cam[0] >= 0 else -1.0

    def _shoulder(self, t: float, side: float) -> np.ndarray:
        """The arm's root beside and below the camera. At strength 1 it sits on the handle's side
        of the view (the arm stays at the edge); at 2 on the other side, so the arm crosses the
        view in front of the part."""
        cam = self.path.world_from_camera(t)[0]
        s = self.strength
        if self.arm_from == "auto":
            lateral = side * 0.3 * (1.5 - min(s, 2.0))
            offset = np.array([lateral, 0.30 - 0.06 * s, -0.05])  # camera frame: right, down, back
        elif self.arm_from == "above":  # over the camera, a little towards the handle's side
            offset = np.array([0.12 * side, -0.29 - 0.06 * s, 0.0])
        else:
            lateral = (1.0 if self.arm_from == "right" else -1.0) * 0.22
            offset = np.array([lateral, 0.30 - 0.06 * s, -0.05])
        return cam[:3, :3] @ offset + cam[:3, 3]

    def _grip(self, k: int, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        part = self.model.parts[k]
        m = part_motion(part, q)
        return m[:3, :3] @ part.grip + m[:3, 3], m[:3, :3] @ part.front, m[:3, :3] @ part.handle_dir

    def hand(self, t: float) -> SceneObject | None:
        """The hand and arm at time ``t`` as one mesh (world coordinates), or None without a hand."""
        if self.strength <= 0 or not self.model.parts or self.hand_model == "none":
            return None
        n = len(self.model.parts)
        k = int(np.clip(np.floor(t / self.duration * n), 0, n - 1))
        s = float(self.window(k, t))
        qs = self.q(t)
        grip, front, hdir = self._grip(k, qs[k])
        side = self._side(k)
        if s < 0.3:  # reaching: from rest (or the previous handle) to this handle
            a = float(ease(s / 0.3))
            if k == 0:
                # Rest: halfway between the handle and a point in front of the shoulder, so the
                # reach stays at walking-hand speed (~1-2 m/s) however short the recording.
                cam = self.path.world_from_camera(t)[0]
                rest = self._shoulder(t, side) + cam[:3, :3] @ np.array([0.0, 0.05, 0.3])
                start, start_front, start_dir, start_side = 0.5 * (rest + grip), front, hdir, side
            else:
                start, start_front, start_dir = self._grip(k - 1, self.model.parts[k - 1].q_max)
                start_side = self._side(k - 1)
            grip = (1 - a) * start + a * grip
            front = (1 - a) * start_front + a * front
            hdir = (1 - a) * start_dir + a * hdir
            front /= np.linalg.norm(front)
            side = (1 - a) * start_side + a * side
        return self._hand_mesh(grip, front, hdir, self._shoulder(t, side))

    def _hand_mesh(self, grip, front, hdir, shoulder) -> SceneObject:
        size = 0.7 + 0.4 * min(self.strength, 2.0)  # 2: a thick sleeve close to the camera
        z = -front / np.linalg.norm(front)  # palm faces the part
        y = hdir - np.dot(hdir, z) * z
        y /= np.linalg.norm(y)
        x = np.cross(y, z)
        palm = make_se3(np.stack([x, y, z], -1), grip - z * 0.03 * size)
        build = {"palm": _palm_hand, "sphere": _sphere_hand, "thin": _thin_hand, "glove": _glove_hand}
        pieces = build[self.hand_model](palm, grip, shoulder, size)
        verts, tris, base_idx = [], [], 0
        for v, tr in pieces:
            verts.append(v)
            tris.append(tr + base_idx)
            base_idx += v.shape[0]
        world = np.concatenate(verts)
        local = (world - palm[:3, 3]) @ palm[:3, :3]
        skin = {"color": [0.72, 0.50, 0.40], "color_b": [0.60, 0.40, 0.32], "seed": 11, "freq": 30.0}
        if self.hand_model == "glove":
            skin = {"color": [0.20, 0.28, 0.45], "color_b": [0.12, 0.16, 0.28], "seed": 12, "freq": 18.0}
        return SceneObject("hand", local, np.concatenate(tris), "noise", skin, HAND_LABEL, palm)


Pieces = list[tuple[np.ndarray, np.ndarray]]


def _palm_hand(palm: np.ndarray, grip: np.ndarray, shoulder: np.ndarray, size: float) -> Pieces:
    """A box palm, four capsule fingers round the handle and a thumb; forearm and upper arm
    capsules with the elbow below the line to the shoulder."""
    x, y, z = palm[:3, 0], palm[:3, 1], palm[:3, 2]
    pieces = []
    bx, by, bz = 0.045 * size, 0.05 * size, 0.015 * size
    corners = np.array([[sx, sy, sz] for sz in (-bz, bz) for sy in (-by, by) for sx in (-bx, bx)])
    # Box corner order of _scene.boxes: (x0y0z0, x1y0z0, x1y1z0, x0y1z0, ...): reorder.
    order = [0, 1, 3, 2, 4, 5, 7, 6]
    pieces.append((corners[order] @ palm[:3, :3].T + palm[:3, 3], BOX_TRIANGLES))
    centre = palm[:3, 3]
    r_f = 0.009 * size
    for off in (-0.033, -0.011, 0.011, 0.033):
        base = centre + x * bx * 0.9 + y * off * size
        tip = grip + z * 0.012 + y * off * size + x * 0.005
        pieces += _capsule(base, tip, r_f)
    pieces += _capsule(centre - x * bx * 0.9, grip - x * 0.02 + z * 0.004, r_f * 1.15)
    wrist = centre - z * 0.02 * size - y * by * 0.6
    elbow = wrist + 0.55 * (shoulder - wrist) - UP * 0.12
    pieces += _capsule(wrist, elbow, 0.03 * size)
    pieces += _capsule(elbow, shoulder, 0.04 * size)
    return pieces


def _sphere_hand(palm: np.ndarray, grip: np.ndarray, shoulder: np.ndarray, size: float) -> Pieces:
    """A ball (4.5 cm radius at strength 1) touching the handle, on a straight forearm cylinder
    to the shoulder: the toy hand of simple renderers."""
    r = 0.045 * size
    centre = grip - palm[:3, 2] * r
    ball = (_BALL[0] * r + centre, _BALL[1])
    return [ball, _capsule(centre, shoulder, 0.032 * size)[0]]


def _thin_hand(palm: np.ndarray, grip: np.ndarray, shoulder: np.ndarray, size: float) -> Pieces:
    """A small palm with two thin fingers on a thin, nearly straight arm (a child's, or a
    sleeve-less reach): few pixels to mask."""
    x, y, z = palm[:3, 0], palm[:3, 1], palm[:3, 2]
    corners = np.array([[sx, sy, sz] for sz in (-0.008, 0.008) for sy in (-0.03, 0.03) for sx in (-0.028, 0.028)])
    order = [0, 1, 3, 2, 4, 5, 7, 6]
    centre = grip - z * 0.02
    pieces = [(corners[order] @ palm[:3, :3].T + centre, BOX_TRIANGLES)]
    for off in (-0.012, 0.012):
        pieces += _capsule(centre + x * 0.025 + y * off, grip + z * 0.01 + y * off + x * 0.005, 0.005)
    wrist = centre - y * 0.02
    elbow = wrist + 0.55 * (shoulder - wrist) - UP * 0.04
    pieces += _capsule(wrist, elbow, 0.013)
    pieces += _capsule(elbow, shoulder, 0.017)
    return pieces


def _glove_hand(palm: np.ndarray, grip: np.ndarray, shoulder: np.ndarray, size: float) -> Pieces:
    """A box mitten over the handle on a square sleeve (forearm and upper arm boxes)."""
    y, z = palm[:3, 1], palm[:3, 2]
    bx, by, bz = 0.06 * size, 0.065 * size, 0.03 * size
    corners = np.array([[sx, sy, sz] for sz in (-bz, bz) for sy in (-by, by) for sx in (-bx, bx)])
    order = [0, 1, 3, 2, 4, 5, 7, 6]
    centre = grip - z * (bz + 0.005)
    pieces = [(corners[order] @ palm[:3, :3].T + centre, BOX_TRIANGLES)]
    wrist = centre - z * bz - y * by * 0.5
    elbow = wrist + 0.55 * (shoulder - wrist) - UP * 0.1
    pieces.append(_box_between(wrist, elbow, 0.04 * size))
    pieces.append(_box_between(elbow, shoulder, 0.05 * size))
    return pieces


_CYL = cylinder(1.0, 1.0, segments=12)
_SPH = sphere(1.0, rings=6, segments=10)
_BALL = sphere(1.0, rings=10, segments=16)


def _segment_frame(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """``[3, 3]`` rotation whose y column points from ``a`` to ``b``, and the length."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    y = axis / max(length, 1e-9)
    helper = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(y, helper)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    return np.stack([x, y, z], -1), length


def _box_between(a: np.ndarray, b: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """A square-section box from ``a`` to ``b`` (world, metres), ``half`` its half width."""
    rot, length = _segment_frame(a, b)
    v, t = boxes([((-half, 0.0, -half), (half, length, half))])
    return v @ rot.T + a, t


def _capsule(a: np.ndarray, b: np.ndarray, radius: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """A capsule from ``a`` to ``b`` (world, metres) as (vertices, triangles) pieces."""
    rot, length = _segment_frame(a, b)
    cyl = (_CYL[0] * [radius, length, radius]) @ rot.T + a
    return [(cyl, _CYL[1]), (_SPH[0] * radius + a, _SPH[1]), (_SPH[0] * radius + b, _SPH[1])]


def session_transform(seed: int, offset_m: float) -> np.ndarray:
    """``[4, 4]`` canonical_from_dynamic_session: a yaw about gravity (any angle) and an offset."""
    rng = sub_rng(seed, "session")
    yaw = rng.uniform(-np.pi, np.pi)
    heading = rng.uniform(-np.pi, np.pi)
    trans = offset_m * np.array([np.cos(heading), 0.0, np.sin(heading)])
    trans[1] = rng.uniform(-0.1, 0.1) * min(offset_m, 1.0)
    return make_se3(axis_angle_to_matrix(UP, yaw), trans)


def drift_and_jitter(
    world_from_camera: np.ndarray, t: np.ndarray, effects: dict, rng: np.random.Generator
) -> np.ndarray:
    """Recorded poses ``[N, 4, 4]`` from true ones with the ``pose_drift``/``pose_jitter`` effects."""
    out = world_from_camera.copy()
    if "pose_drift" in effects:
        prm = effects["pose_drift"]
        heading = rng.uniform(0, 2 * np.pi)
        direction = np.array([np.cos(heading), 0.0, np.sin(heading)])
        for i, ti in enumerate(t):
            drift = make_se3(axis_angle_to_matrix(UP, prm["yaw_rad_per_s"] * ti),
                             direction * prm["trans_m_per_s"] * ti)
            # Drift about the first camera's position, as odometry error accumulates from there.
            pivot = make_se3(np.eye(3), world_from_camera[0, :3, 3])
            out[i] = pivot @ drift @ invert_se3(pivot) @ out[i]
    if "pose_jitter" in effects:
        prm = effects["pose_jitter"]
        for i in range(out.shape[0]):
            axis = rng.normal(size=3)
            rot = axis_angle_to_matrix(axis, rng.normal() * prm["rot_std_rad"])
            out[i] = out[i] @ make_se3(rot, rng.normal(size=3) * prm["trans_std_m"])
    return out
