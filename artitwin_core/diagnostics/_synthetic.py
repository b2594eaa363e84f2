"""Residual data of a synthetic scene, with the twin replaced by the ground truth.

The prediction side is the exact scene (``synth.render_state`` at the recorded poses, where the
pipeline renders its twin: the true ones unless a pose or timing effect is injected), and for the
tracks the part's nominal joint (``joint="nominal"``: the designed hinge or slide, a revolute for
a screw) or a free revolute / prismatic fit of the tracks (``joint="fit"``, ``joints.estimate_joint``).
Tracks follow the true part motion plus noise. Whatever residual remains is the injected sensor or
joint effect plus noise, which is what the effect catalog is tested and benchmarked on; the
diagnosis is never told which effect was injected.

A free fit absorbs some joint effects into its own parameters: a sagging hinge is, to the track
noise, a revolute about a tilted axis, and a drawer that tilts linearly as it slides is exactly a
revolute about a far axis. The effects then show only against a joint whose axis is held (nominal).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.diagnostics._residuals import ResidualData, make_residual_data, track_model_from_joint
from artitwin_core.geometry import backproject
from artitwin_core.joints import JointFitConfig, estimate_joint
from artitwin_core.synth import SyntheticScene, render_state
from artitwin_core.tracking import Trajectories


def _closed_part_points(scene: SyntheticScene, part: int, n_points: int, rng: np.random.Generator) -> np.ndarray:
    """``[n, 3]`` points on part ``part``'s visible surface in the closed state (canonical frame)."""
    cap, truth = scene.static, scene.truth
    w, h = cap.rgb.shape[2], cap.rgb.shape[1]
    best = None
    for t in range(0, cap.num_frames, max(1, cap.num_frames // 6)):
        k = cap.rgb_intrinsics[t]
        _, depth, mask = render_state(scene, truth.static_world_from_camera[t], k, w, h, q=[0.0] * len(truth.joints))
        sel = (mask == part + 1) & np.isfinite(depth)
        if best is None or sel.sum() > best[0].sum():
            best = (sel, depth, k, truth.static_world_from_camera[t])
    sel, depth, k, pose = best
    v, u = np.nonzero(sel)
    pick = rng.choice(len(u), size=min(n_points, len(u)), replace=False)
    u, v = u[pick], v[pick]
    cam = backproject(depth[v, u], k, u, v)
    return cam @ pose[:3, :3].T + pose[:3, 3]


def synthetic_tracks(
    scene: SyntheticScene, part: int = 0, n_points: int = 150, track_noise_m: float = 0.002, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Part ``part``'s 3D tracks in the dynamic recording: points on its visible closed surface moved
    by the true part motion, plus noise. Returns ``obs [T, N, 3]`` metres (canonical frame), ``valid [T, N]``."""
    rng = np.random.default_rng(seed)
    x = _closed_part_points(scene, part, n_points, rng)
    motion = scene.truth.part_world_from_closed[part]
    obs = np.einsum("tij,nj->tni", motion[:, :3, :3], x) + motion[:, None, :3, 3]
    obs = obs + track_noise_m * rng.standard_normal(obs.shape)
    return obs, np.ones(obs.shape[:2], bool)


def synthetic_residual_data(
    scene: SyntheticScene,
    *,
    part: int | None = 0,
    joint: str = "nominal",
    n_points: int = 150,
    track_noise_m: float = 0.002,
    depth_sigma: tuple[float, float] = (0.001, 0.002),
    seed: int = 0,
    dense_prediction: bool = False,
) -> ResidualData:
    """Static-recording RGB and depth against ground-truth renders, and (when ``part`` is given and
    the scene has parts) part ``part``'s tracks in the dynamic recording against a simple-joint fit.

    Args:
        scene: a ``generate_scene`` result.
        part: which articulated part's tracks to simulate (None: no tracks).
        joint: ``"nominal"`` (the designed joint: type, axis, pivot and q of the ground truth, a
            screw read as a revolute) or ``"fit"`` (the revolute or prismatic hypothesis of
            ``estimate_joint``, whichever the nominal type is).
        n_points: tracks on the part.
        track_noise_m: per-coordinate noise added to the true track positions, metres.
        depth_sigma: the depth-noise model the twin assumes (the sensor's nominal one).
        seed: seeds the track sampling and noise.
        dense_prediction: also render the prediction denser (``rgb_pred_hi``, which the
            displacement effects resample), one ray per sub-pixel centre, so that reducing it
            reproduces how the recording samples a pixel: ``s = rgb_supersample`` and the mean
            (``"box"``) for an anti-aliased recording, ``s = 3`` and the centre sub-pixel
            (``"point"``) for a point-sampled one.
    """
    cap, truth = scene.static, scene.truth
    h, w = cap.rgb.shape[1:3]
    dh, dw = cap.depth.shape[1:3]
    q0 = [0.0] * len(truth.joints)
    rgb, depth = [], []
    for t in range(cap.num_frames):
        # At the recorded pose, as the pipeline renders its twin: pose and timing effects then show.
        pose = cap.world_from_camera[t]
        rgb.append(render_state(scene, pose, cap.rgb_intrinsics[t], w, h, q=q0)[0])
        depth.append(render_state(scene, pose, cap.depth_intrinsics[t], dw, dh, q=q0)[1])
    hi, sampling = None, "box"
    if dense_prediction:
        s = scene.spec.rgb_supersample if scene.spec.rgb_supersample > 1 else 3
        sampling = "box" if scene.spec.rgb_supersample > 1 else "point"
        spec_hi = replace(scene.spec, rgb_supersample=1)
        hi = []
        for t in range(cap.num_frames):
            fx, fy, cx, cy = cap.rgb_intrinsics[t]
            # Sub-pixel i of an axis lies at pixel (i + 0.5) / s - 0.5.
            k_hi = (s * fx, s * fy, s * cx + (s - 1) / 2, s * cy + (s - 1) / 2)
            hi.append(render_state(spec_hi, cap.world_from_camera[t], k_hi, s * w, s * h, q=q0)[0])
        hi = np.stack(hi)
    kw = {}
    if part is not None and truth.joints:
        obs, valid = synthetic_tracks(scene, part, n_points, track_noise_m, seed)
        traj = Trajectories(obs, np.zeros(obs.shape[:2] + (2,), np.float32), valid, 0)
        nominal = truth.joints[part]
        nominal = replace(nominal, joint_type="revolute" if nominal.joint_type == "screw" else nominal.joint_type,
                          pitch=0.0)
        if joint == "fit":
            fit = estimate_joint(traj, JointFitConfig(seed=seed), reference_frame=0)
            nominal = fit.score(nominal.joint_type).joint
        elif joint != "nominal":
            raise InputError(f"synthetic_residual_data: joint is {joint!r}; use 'nominal' or 'fit'.")
        kw = {"tracks": track_model_from_joint(nominal, obs, valid), "tracks_obs": obs,
              "tracks_valid": valid, "track_noise_m": track_noise_m}
    return make_residual_data(
        rgb_pred=np.stack(rgb), rgb_meas=cap.rgb, rgb_intrinsics=cap.rgb_intrinsics,
        depth_pred=np.stack(depth), depth_meas=cap.depth, depth_confidence=cap.confidence,
        depth_sigma=depth_sigma, timestamps=cap.timestamps, depth_intrinsics=cap.depth_intrinsics,
        world_from_camera=cap.world_from_camera, rgb_pred_hi=hi, rgb_pred_sampling=sampling, **kw,
    )


def perturb_twin_depth(data: ResidualData, amplitude_m: float = 0.02, wavelength_m: float = 2.0,
                       offset_m: float = 0.0) -> ResidualData:
    """``data`` whose predicted depth comes from a twin with its own, world-fixed geometry error.

    Every predicted surface point moves along its normal by ``offset_m + amplitude_m cos(2 pi x / L)
    cos(2 pi z / L)`` (world x, z; ``L = wavelength_m``): the same error in every frame that sees
    that place, as an unconverged twin has. The RGB prediction is left as it is.
    """
    from artitwin_core.diagnostics._camera import _backproject, _normals

    k, poses = data.depth_intrinsics, data.world_from_camera
    p = _backproject(data.depth_pred, k, poses)
    n = _normals(p)
    ray = p - poses[:, None, None, :3, 3]
    dist = np.linalg.norm(ray, axis=-1)
    cos = np.abs(np.sum(n * ray, -1)) / np.maximum(dist, 1e-9)
    two_pi = 2 * np.pi / wavelength_m
    delta = offset_m + amplitude_m * np.cos(two_pi * p[..., 0]) * np.cos(two_pi * p[..., 2])
    # A surface moved back by delta along its normal is hit delta / cos further along the ray.
    change = delta / np.maximum(cos, 0.3) * data.depth_pred / np.maximum(dist, 1e-9)
    pred = np.where(np.isfinite(change), data.depth_pred + change, data.depth_pred).astype(np.float32)
    return replace(data, depth_pred=pred)
