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
    drift: SmoothNoise  # slow hand wander of the eye, ~4 cm
    shake: SmoothNoise  # fast small jitter, ~2 mm
    wobble: SmoothNoise  # look-at target wander, ~5 cm
    roll: SmoothNoise  # ~2 degrees
    # Optional ``t [N] -> [N, 3]`` shift of the look-at target (the dynamic recording follows
    # the handle, as a person watches what they pull).
    target_shift: Callable[[np.ndarray], np.ndarray] | None = None

    def world_from_camera(self, t) -> np.ndarray:
        """``t [N]`` seconds -> ``[N, 4, 4]`` true poses (OpenCV axes)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        ang = self.angle0 + (self.angle1 - self.angle0) * (0.15 * t / self.duration + 0.85 * ease(t / self.duration))
        eye = self.centre + np.stack([self.radius * np.sin(ang), np.full_like(ang, self.height - self.centre[1]),
                                      self.radius * np.cos(ang)], -1)
        eye = eye + 0.04 * self.drift(t) + 0.002 * self.shake(t)
        target = self.centre + 0.05 * self.wobble(t)
        if self.target_shift is not None:
            target = target + self.target_shift(t)
        return look_at(eye, target, 0.035 * self.roll(t)[:, 0])


def camera_path(model: SceneModel, seed: int, which: str, duration: float) -> CameraPath:
    """The static sweep (a wide arc) or the dynamic one (a short arc on the free-edge side)."""
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
    return CameraPath(
        centre=model.look_at.copy(), radius=float(radius), height=float(height),
        angle0=float(a0), angle1=float(a1), duration=max(duration, 1e-3),
        drift=SmoothNoise(rng, 3, 0.5), shake=SmoothNoise(rng, 3, 6.0),
        wobble=SmoothNoise(rng, 3, 0.6), roll=SmoothNoise(rng, 1, 0.4),
    )


@dataclass
class Interaction:
    """The dynamic recording's story: the hand opens each part in turn.

    Part k owns the time window ``[k, k + 1] * duration / K``: the hand approaches its handle
    (first 30 %), pulls it open with an eased q (next 55 %), then holds.
    """

    model: SceneModel
    duration: float
    path: CameraPath
    strength: float

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
        lateral = side * 0.3 * (1.5 - min(s, 2.0))
        offset = np.array([lateral, 0.30 - 0.06 * s, -0.05])  # camera frame: right, down, back
        return cam[:3, :3] @ offset + cam[:3, 3]

    def _grip(self, k: int, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        part = self.model.parts[k]
        m = part_motion(part, q)
        return m[:3, :3] @ part.grip + m[:3, 3], m[:3, :3] @ part.front, m[:3, :3] @ part.handle_dir

    def hand(self, t: float) -> SceneObject | None:
        """The hand and arm at time ``t`` as one mesh (world coordinates), or None without a hand."""
        if self.strength <= 0 or not self.model.parts:
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
        verts, tris, base_idx = [], [], 0
        for v, tr in pieces:
            verts.append(v)
            tris.append(tr + base_idx)
            base_idx += v.shape[0]
        world = np.concatenate(verts)
        local = (world - palm[:3, 3]) @ palm[:3, :3]
        skin = {"color": [0.72, 0.50, 0.40], "color_b": [0.60, 0.40, 0.32], "seed": 11, "freq": 30.0}
        return SceneObject("hand", local, np.concatenate(tris), "noise", skin, HAND_LABEL, palm)


_CYL = cylinder(1.0, 1.0, segments=12)
_SPH = sphere(1.0, rings=6, segments=10)


def _capsule(a: np.ndarray, b: np.ndarray, radius: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """A capsule from ``a`` to ``b`` (world, metres) as (vertices, triangles) pieces."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    y = axis / max(length, 1e-9)
    helper = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(y, helper)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    rot = np.stack([x, y, z], -1)
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
