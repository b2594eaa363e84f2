"""Generate a synthetic scene: two recordings (static, dynamic) and their exact ground truth.

The static recording's world frame is the canonical frame (y up, gravity along -y). The dynamic
recording's poses are written in its own session frame, ``dynamic_session_from_canonical``
applied to the canonical poses. Timestamps follow a 30 fps stream of which every stride-th frame
is kept.
"""

from __future__ import annotations

import copy
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.capture import Capture, depth_intrinsics_from_rgb
from artitwin_core.geometry import invert_se3
from artitwin_core.joints import Joint
from artitwin_core.synth._effects import effects_in
from artitwin_core.synth._motion import (
    FPS,
    Interaction,
    SmoothNoise,
    camera_path,
    drift_and_jitter,
    session_transform,
)
from artitwin_core.synth._overlap import overlap_fraction
from artitwin_core.synth._render import WorldState, render_supersampled, render_view
from artitwin_core.synth._scene import HAND_LABEL, SceneModel, build_scene, part_motion, sub_rng
from artitwin_core.synth._sensor import (
    default_intrinsics,
    depth_sensor,
    expose_rgb,
    vignette,
)
from artitwin_core.synth._spec import SceneSpec
from artitwin_core.synth._types import SceneGroundTruth


@dataclass(frozen=True)
class SyntheticScene:
    """Two recordings and the answers. ``static.world_from_camera`` is in the canonical frame,
    ``dynamic.world_from_camera`` in the dynamic session frame (see ``truth``)."""

    static: Capture
    dynamic: Capture
    truth: SceneGroundTruth
    spec: SceneSpec


_MODELS: OrderedDict[str, SceneModel] = OrderedDict()


def scene_model(spec: SceneSpec) -> SceneModel:
    """The (cached) geometry of ``spec``; specs hold dicts, so the cache keys on ``repr``."""
    key = repr(spec)
    if key not in _MODELS:
        _MODELS[key] = build_scene(spec)
        while len(_MODELS) > 8:
            _MODELS.popitem(last=False)
    return _MODELS[key]


class _Recorder:
    """Renders one recording frame by frame with the sensor model and the effects."""

    def __init__(self, spec: SceneSpec, name: str):
        self.spec = spec
        self.effects = effects_in(spec.resolved_effects, name)
        self.rng = sub_rng(spec.seed, f"sensor_{name}")
        (self.w, self.h), (self.dw, self.dh) = spec.rgb_size, spec.depth_size
        self.k_rgb = default_intrinsics(self.w, self.h)
        # Pixel-centre convention (c' = (c + 0.5) s - 0.5), as the capture readers and writers use;
        # the depth map is rendered with exactly these intrinsics.
        self.k_depth = depth_intrinsics_from_rgb(self.k_rgb, (self.w, self.h), (self.dw, self.dh))
        lens = self.effects.get("lens_distortion")
        self.distortion = None if lens is None else np.array([lens["k1"], lens["k2"], lens["p1"], lens["p2"]])
        self.gain_map = np.ones((self.h, self.w, 1))
        if "vignetting" in self.effects:
            self.gain_map = vignette(self.w, self.h, self.k_rgb, self.effects["vignetting"]["strength"])[..., None]
        self.exposure = SmoothNoise(self.rng, 1, self.effects.get("exposure", {}).get("freq_hz", 0.4))
        self.wb = SmoothNoise(self.rng, 2, self.effects.get("white_balance", {}).get("freq_hz", 0.3))
        self.dt = float(self.effects.get("time_offset", {}).get("seconds", 0.0))
        self.readout = float(self.effects.get("rolling_shutter", {}).get("readout_s", 0.0))
        self.pose_lag = float(self.effects.get("pose_lag", {}).get("seconds", 0.0))

    def recorded_pose_times(self, t: np.ndarray) -> np.ndarray:
        """When each frame's recorded pose was really taken: with the depth map (``time_offset``),
        less the pose stream's lag (``pose_lag``)."""
        return t + self.dt - self.pose_lag

    def gain(self, t: float) -> np.ndarray:
        g = np.ones(3)
        if "exposure" in self.effects:
            g *= 2.0 ** (self.effects["exposure"]["stops_std"] * self.exposure(t)[0, 0])
        if "white_balance" in self.effects:
            rb = 1.0 + self.effects["white_balance"]["gain_std"] * self.wb(t)[0]
            g *= np.array([rb[0], 1.0, rb[1]])
        return g

    def rgb_poses(self, pose_at, t: float) -> np.ndarray:
        if not self.readout:
            return pose_at(t)[0]
        rows = t + (np.arange(self.h) / (self.h - 1) - 0.5) * self.readout
        return pose_at(rows)

    def frame(self, state_at, pose_at, t: float):
        """RGB (uint8), depth, confidence, RGB labels for the frame at time ``t``."""
        state_rgb = state_at(t)
        view = render_supersampled(state_rgb, self.rgb_poses(pose_at, t), self.k_rgb, self.w, self.h,
                                   self.distortion, self.spec.rgb_supersample)
        rgb = expose_rgb(view.radiance, self.gain(t) * self.gain_map, self.spec.noise_level, self.rng)
        state_d = state_rgb if self.dt == 0 else state_at(t + self.dt)
        dview = render_view(state_d, pose_at(t + self.dt)[0], self.k_depth, self.dw, self.dh, shade=False)
        noise = self.effects.get("depth_noise", {})
        bias = self.effects.get("depth_bias", {})
        depth, conf = depth_sensor(
            dview.depth, dview.cos_incidence, self.rng, self.spec.noise_level,
            a_m=noise.get("a_m", 0.001), b_per_m=noise.get("b_per_m", 0.002),
            max_range_m=noise.get("max_range_m", 5.0),
            scale=bias.get("scale", 1.0), offset_m=bias.get("offset_m", 0.0),
        )
        return rgb, depth, conf, view.label, dview.depth, dview.label

    def pose_stream(self, pose_at, frame_ids: np.ndarray, recorded: np.ndarray, drift_rng: np.random.Generator,
                    jitter_rng: np.random.Generator) -> dict:
        """``Capture``'s ``stream_*`` fields: the recorded pose of every frame of the 30 fps stream
        up to the last frame kept, as a phone records one per frame whether the frame is kept or
        not. The kept frames' poses are ``recorded``; the others are read off the camera path
        the same way (``pose_at``: true pose, in the recording's world, at given times), with the
        same drift (``drift_rng``: the generator ``recorded`` was drawn from, as it was before)
        and their own jitter (``jitter_rng``)."""
        ids = np.arange(int(frame_ids[-1]) + 1)
        t = ids / FPS
        no_jitter = {k: v for k, v in self.effects.items() if k != "pose_jitter"}
        stream = drift_and_jitter(pose_at(self.recorded_pose_times(t)), t, no_jitter, drift_rng)
        if "pose_jitter" in self.effects:
            stream = drift_and_jitter(stream, t, {"pose_jitter": self.effects["pose_jitter"]}, jitter_rng)
        stream[frame_ids] = recorded
        return {"stream_world_from_camera": stream, "stream_timestamps": t, "stream_frame_ids": ids.astype(np.int64)}

    def capture(self, frame_ids, rgb, depth, conf, recorded_poses, stream: dict | None = None) -> Capture:
        n = len(frame_ids)
        lens = self.effects.get("lens_distortion")
        honest = lens is not None and bool(lens["record"])
        return Capture(
            rgb=np.stack(rgb),
            depth=np.stack(depth),
            confidence=np.stack(conf),
            rgb_intrinsics=np.tile(self.k_rgb, (n, 1)),
            depth_intrinsics=np.tile(self.k_depth, (n, 1)),
            world_from_camera=recorded_poses,
            timestamps=np.asarray(frame_ids, dtype=np.float64) / FPS,
            frame_ids=np.asarray(frame_ids, dtype=np.int64),
            distortion=self.distortion.copy() if honest else None,
            source_format="synthetic",
            **(stream or {}),
        )


def generate_scene(spec: SceneSpec) -> SyntheticScene:
    """Render both recordings of ``spec`` and their ground truth. Deterministic in ``spec.seed``.

    Cost: about two ray casts per frame (RGB with shadow rays, depth), e.g. ~0.1 s per frame at
    256x192 RGB on one core.
    """
    if not isinstance(spec, SceneSpec):
        raise InputError(f"generate_scene needs a SceneSpec, got {type(spec).__name__}.")
    model = scene_model(spec)
    effects = spec.resolved_effects
    n_parts = len(model.parts)

    # Static: parts closed, no hand, a wide sweep. Its world frame is the canonical frame.
    ids_s = np.arange(spec.static_frames) * spec.static_stride
    t_s = ids_s / FPS
    path_s = camera_path(model, spec.seed, "static", float(t_s[-1]), spec.static_path, spec.static_shift_m)
    closed = WorldState(model, [0.0] * n_parts)
    rec = _Recorder(spec, "static")
    frames = [rec.frame(lambda _t: closed, path_s.world_from_camera, t) for t in t_s]
    true_s = path_s.world_from_camera(t_s)
    pose_rng = sub_rng(spec.seed, "pose_s")
    drift_rng = copy.deepcopy(pose_rng)
    recorded_s = drift_and_jitter(path_s.world_from_camera(rec.recorded_pose_times(t_s)), t_s, rec.effects, pose_rng)
    stream_s = rec.pose_stream(path_s.world_from_camera, ids_s, recorded_s, drift_rng, sub_rng(spec.seed, "stream_s"))
    static = rec.capture(ids_s, *zip(*[f[:3] for f in frames], strict=True), recorded_s, stream_s)
    static_seen = (np.stack([f[4] for f in frames]), path_s.world_from_camera(t_s + rec.dt), rec.k_depth)

    # Dynamic: a short sweep while the hand opens each part in turn.
    ids_d = np.arange(spec.dynamic_frames) * spec.dynamic_stride
    t_d = ids_d / FPS
    duration = float(t_d[-1])
    path_d = camera_path(model, spec.seed, "dynamic", duration, spec.dynamic_path)
    story = Interaction(model, duration, path_d, float(spec.hand_occlusion), spec.hand_model, spec.arm_from)

    def state_at(t: float) -> WorldState:
        return WorldState(model, story.q(t), story.hand(t))

    rec = _Recorder(spec, "dynamic")
    frames = [rec.frame(state_at, path_d.world_from_camera, t) for t in t_d]
    true_d = path_d.world_from_camera(t_d)
    canonical_from_session = session_transform(spec.seed, spec.session_offset_m)
    session_from_canonical = invert_se3(canonical_from_session)

    def in_session(times: np.ndarray) -> np.ndarray:
        return session_from_canonical @ path_d.world_from_camera(times)

    pose_rng = sub_rng(spec.seed, "pose_d")
    drift_rng = copy.deepcopy(pose_rng)
    recorded_d = drift_and_jitter(in_session(rec.recorded_pose_times(t_d)), t_d, rec.effects, pose_rng)
    stream_d = rec.pose_stream(in_session, ids_d, recorded_d, drift_rng, sub_rng(spec.seed, "stream_d"))
    dynamic = rec.capture(ids_d, *zip(*[f[:3] for f in frames], strict=True), recorded_d, stream_d)

    labels = np.stack([f[3] for f in frames])
    closed_from_world = np.stack([
        [invert_se3(part_motion(part, story.q(float(t + rec.dt))[k])) for t in t_d]
        for k, part in enumerate(model.parts)
    ]) if n_parts else np.zeros((0, len(t_d), 4, 4))
    overlap = overlap_fraction(
        static_seen[0], static_seen[1], np.stack([f[4] for f in frames]), np.stack([f[5] for f in frames]),
        path_d.world_from_camera(t_d + rec.dt), closed_from_world, static_seen[2], hand_label=HAND_LABEL,
    )
    part_masks = np.where(labels >= 0, labels + 1, 0).astype(np.uint8)
    q = np.array([story.q(t) for t in t_d]).reshape(len(t_d), n_parts)
    joints, motions = [], []
    for k, part in enumerate(model.parts):
        motions.append(np.stack([part_motion(part, qk) for qk in q[:, k]]))
        joints.append(Joint(
            joint_type="screw" if part.pitch else part.joint_type,
            axis=part.axis.copy(),
            pivot=part.pivot.copy(),
            q=q[:, k].copy(),
            q_range=np.array([q[:, k].min(), q[:, k].max()]),
            residual=np.zeros(len(t_d)),
            confidence=np.ones(len(t_d)),
            pitch=float(part.pitch),
        ))
    truth = SceneGroundTruth(
        joints=joints,
        part_masks=part_masks,
        hand_masks=labels == HAND_LABEL,
        static_world_from_camera=true_s,
        dynamic_world_from_camera=true_d,
        canonical_from_dynamic_session=canonical_from_session,
        effects=effects,
        part_world_from_closed=np.stack(motions) if motions else np.zeros((0, len(t_d), 4, 4)),
        overlap_fraction=overlap,
    )
    return SyntheticScene(static=static, dynamic=dynamic, truth=truth, spec=spec)


def render_state(
    scene: SceneSpec | SyntheticScene,
    world_from_camera: np.ndarray,
    intrinsics,
    width: int,
    height: int,
    q,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A clean ground-truth render of the scene at joint states ``q`` from any pinhole camera.

    No hand, no sensor noise, no exposure or lens effects; the parts move as they really do
    (joint effects such as ``axis_sag`` included). RGB is anti-aliased like the recordings
    (``spec.rgb_supersample``); depth and mask come from pixel-centre rays.

    Args:
        scene: a ``SceneSpec`` or a ``SyntheticScene``.
        world_from_camera: ``[4, 4]`` camera pose in the canonical frame (OpenCV axes).
        intrinsics: ``(fx, fy, cx, cy)`` pixels.
        width, height: image size in pixels.
        q: one state per part (radians for doors, metres for drawers), in ``truth.joints`` order.

    Returns:
        rgb ``[H, W, 3]`` uint8 sRGB, depth ``[H, W]`` float32 z-depth metres (NaN where no
        surface), part_mask ``[H, W]`` uint8 (0 = no part, k + 1 = part k).
    """
    spec = scene.spec if isinstance(scene, SyntheticScene) else scene
    if not isinstance(spec, SceneSpec):
        raise InputError(f"render_state needs a SceneSpec or SyntheticScene, got {type(scene).__name__}.")
    model = scene_model(spec)
    q = [float(v) for v in np.atleast_1d(np.asarray(q, dtype=np.float64))] if len(model.parts) else []
    if len(q) != len(model.parts):
        raise InputError(f"render_state: q has {len(q)} states; this scene has {len(model.parts)} parts.")
    pose = np.asarray(world_from_camera, dtype=np.float64)
    if pose.shape != (4, 4):
        raise InputError(f"render_state: world_from_camera has shape {pose.shape}; expected (4, 4).")
    view = render_supersampled(WorldState(model, q), pose, intrinsics, int(width), int(height),
                               samples=spec.rgb_supersample)
    rgb = expose_rgb(view.radiance, np.ones(3), 0.0, None)
    depth = np.where(np.isfinite(view.depth), view.depth, np.nan).astype(np.float32)
    part_mask = np.where(view.label >= 0, view.label + 1, 0).astype(np.uint8)
    return rgb, depth, part_mask


def static_shift_for_overlap(spec: SceneSpec, target: float, size: tuple[int, int] = (40, 30)) -> float:
    """The ``static_shift_m`` (0-1.5 m, in 5 cm steps) whose overlap fraction comes nearest to
    ``target``: the scene's depth rendered small (``size`` pixels, no shading, no sensor) at
    shift up to a little past the target, measured as ``SceneGroundTruth.overlap_fraction`` is
    (within ~0.03 of it at full size). 0 if the unshifted scene already overlaps less. Cost: one
    small depth render per frame and shift, a few seconds on one core.
    """
    import dataclasses

    from artitwin_core.synth._render import render_view

    if not 0.0 < target < 1.0:
        raise InputError(f"static_shift_for_overlap: target is {target}; use a fraction in (0, 1).")
    base = dataclasses.replace(spec, static_shift_m=0.0)
    model = scene_model(base)
    w, h = size
    k = default_intrinsics(w, h)
    n_parts = len(model.parts)
    t_d = np.arange(spec.dynamic_frames) * spec.dynamic_stride / FPS
    path_d = camera_path(model, spec.seed, "dynamic", float(t_d[-1]), spec.dynamic_path)
    story = Interaction(model, float(t_d[-1]), path_d, float(spec.hand_occlusion), spec.hand_model, spec.arm_from)
    poses_d = path_d.world_from_camera(t_d)
    views = [render_view(WorldState(model, story.q(t), story.hand(t)), poses_d[i], k, w, h, shade=False)
             for i, t in enumerate(t_d)]
    depth_d, labels_d = np.stack([v.depth for v in views]), np.stack([v.label for v in views])
    closed_from_world = np.stack([
        [invert_se3(part_motion(part, story.q(float(t))[j])) for t in t_d] for j, part in enumerate(model.parts)
    ]) if n_parts else np.zeros((0, len(t_d), 4, 4))
    t_s = np.arange(spec.static_frames) * spec.static_stride / FPS
    closed = WorldState(model, [0.0] * n_parts)
    best = (np.inf, 0.0)
    for shift in np.round(np.arange(0.0, 1.5001, 0.05), 2):
        path_s = camera_path(model, spec.seed, "static", float(t_s[-1]), spec.static_path, float(shift))
        poses_s = path_s.world_from_camera(t_s)
        depth_s = np.stack([render_view(closed, p, k, w, h, shade=False).depth for p in poses_s])
        frac = overlap_fraction(depth_s, poses_s, depth_d, labels_d, poses_d, closed_from_world, k,
                                stride=1, hand_label=HAND_LABEL)
        if shift == 0.0 and frac <= target:
            return 0.0
        if abs(frac - target) < best[0]:
            best = (abs(frac - target), float(shift))
        if frac < target - 0.1:  # the overlap falls (not strictly) with the shift: past it
            break
    return best[1]
