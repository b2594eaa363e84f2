"""Stage IV end to end: partition the canonical model, seed, phase I, phase II, held-out PSNR."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from artitwin_core._errors import InputError
from artitwin_core.articulation._appearance import PartAppearance
from artitwin_core.articulation._camera import CameraFitConfig, fit_recording_camera, remove_camera
from artitwin_core.articulation._config import ArticulationConfig
from artitwin_core.articulation._kinematics import TwinRenderer
from artitwin_core.articulation._optimize import (
    ArticulatedViews,
    ArticulationState,
    evaluate_psnr,
    non_background,
    part_regions,
    prune_faint,
    run_phase,
    seed_unexplained,
    uncovered_background,
)
from artitwin_core.articulation._partition import partition_gaussians, surface_hits
from artitwin_core.capture import Capture, downscale_rgb
from artitwin_core.gaussians import (
    LABEL_BACKGROUND,
    LABEL_INTERIOR,
    LABEL_PART,
    GaussianParams,
    resolve_backend,
)
from artitwin_core.joints import Joint
from artitwin_core.masks import MaskSequence, downscale_masks
from artitwin_core.reconstruction import SensorModel, make_views, scene_extent, split_frames


def _concat(a: GaussianParams | None, b: GaussianParams) -> GaussianParams:
    if a is None or a.num_gaussians == 0:
        return b
    return GaussianParams(**{k: np.concatenate([getattr(a, k), getattr(b, k)]) for k in a.__dict__})


@dataclass(frozen=True)
class ArticulationResult:
    """The result of :func:`articulate`.

    Attributes:
        params: the labelled, optimised Gaussians in the canonical (closed) state.
        appearance: each part's brightness curve over its joint state (None when
            ``appearance_knots`` is 0 or there are no joints); render with it.
        train_frames, test_frames: dynamic frame indices used for training and held out.
        psnr_canonical_db: held-out PSNR of the canonical model, nothing moved (hand excluded).
        psnr_partitioned_db: held-out PSNR right after partitioning, parts moved, no training.
        psnr_phase1_db: held-out PSNR after phase I.
        psnr_holdout_db: held-out PSNR after phase II (the final model).
        counts: Gaussians per label name (``background``, ``interior``, ``part_0``, ...),
            ``seeded`` (new part and interior ones), ``seeded_background`` (new background
            ones where the static recording saw nothing), ``pruned``.
        losses: ``[steps]`` loss per step over both phases.
        seconds: wall time of ``partition``, ``seed``, ``phase1``, ``phase2``, ``evaluate``
            (and ``camera`` when the dynamic recording's camera is modelled).
        camera: the dynamic recording's own camera (``config.camera_effects``), fitted on its
            training frames against the final twin; None when not modelled. Render the twin
            through it (``SensorModel.apply_rgb`` at the frame's position) to predict that
            recording's frames; held-out frames get interpolated gains.
    """

    params: GaussianParams
    appearance: PartAppearance | None
    train_frames: list[int]
    test_frames: list[int]
    psnr_canonical_db: float
    psnr_partitioned_db: float
    psnr_phase1_db: float
    psnr_holdout_db: float
    counts: dict[str, int]
    losses: np.ndarray
    seconds: dict[str, float]
    camera: SensorModel | None = None


CAMERA_FIT_MAX_SIDE = 256


def fit_dynamic_camera(
    params: GaussianParams,
    joints: Sequence[Joint],
    dynamic: Capture,
    world_from_camera: np.ndarray,
    masks: MaskSequence,
    frames: Sequence[int],
    config: ArticulationConfig,
    appearance: PartAppearance | None = None,
) -> SensorModel:
    """The dynamic recording's camera (``config.camera_effects``) against the twin ``params``
    rendered at ``frames`` with the parts at their states: fitted on the background pixels the
    twin covers (the hand and the part, grown by ``region_dilate_px``, left out)."""
    frames = sorted(int(f) for f in frames)
    # A few gains per frame need few pixels: render and fit at most CAMERA_FIT_MAX_SIDE on the long
    # side (the model is resolution-free: gains per frame, vignetting over the normalised radius).
    if max(dynamic.rgb_size) > CAMERA_FIT_MAX_SIDE:
        dynamic = downscale_rgb(dynamic, CAMERA_FIT_MAX_SIDE)
        masks = downscale_masks(masks, dynamic.rgb_size)
    twin = TwinRenderer(params, joints, backend=config.backend, appearance=appearance)
    w, h = dynamic.rgb_size
    pred, valid = [], []
    for t in frames:
        colour, _, alpha = twin.render([float(j.q[t]) for j in joints], world_from_camera[t], dynamic.rgb_intrinsics[t], w, h)
        moving = (np.asarray(masks.part[t]) > 0) | np.asarray(masks.hand[t], bool)
        if config.region_dilate_px > 0 and moving.any():
            moving = binary_dilation(moving, iterations=config.region_dilate_px)
        pred.append(np.clip(colour, 0.0, 1.0))
        valid.append((alpha >= 0.95) & ~moving)
    return fit_recording_camera(
        np.stack(pred), dynamic.rgb[frames], np.stack(valid), frames, dynamic.rgb_intrinsics[frames],
        CameraFitConfig(effects=tuple(config.camera_effects)),
    )


def dynamic_views(
    dynamic: Capture,
    world_from_camera: np.ndarray,
    masks: MaskSequence,
    joints: Sequence[Joint],
    frames: Sequence[int],
    device: torch.device | str | None = None,
) -> ArticulatedViews:
    """Views of dynamic ``frames`` with canonical poses ``world_from_camera [T, 4, 4]``, their
    tensors (and each view's part motions) on ``device`` (default CPU)."""
    frames = [int(f) for f in frames]
    q = (
        np.stack([np.asarray(j.q, np.float64)[frames] for j in joints], 1)
        if joints
        else np.zeros((len(frames), 0))
    )
    return ArticulatedViews(
        views=make_views(dynamic, world_from_camera, frames, device=device),
        q=q,
        part=np.asarray(masks.part[frames]),
        hand=np.asarray(masks.hand[frames], bool),
    ).with_tables(joints)


def static_views(
    static: Capture, world_from_camera: np.ndarray, num_joints: int, device: torch.device | str | None = None
) -> ArticulatedViews:
    """Views of every static frame (parts closed, nothing masked), on ``device`` (default CPU)."""
    frames = list(range(static.num_frames))
    views = make_views(static, world_from_camera, frames, device=device)
    _, h, w, _ = static.rgb.shape
    return ArticulatedViews(
        views=views,
        q=np.zeros((len(frames), num_joints)),
        part=np.zeros((len(frames), h, w), np.uint8),
        hand=np.zeros((len(frames), h, w), bool),
    ).with_motions(np.broadcast_to(np.eye(4), (len(frames), num_joints, 4, 4)))


def label_counts(labels: np.ndarray, num_joints: int) -> dict[str, int]:
    out = {
        "background": int(np.sum(labels == LABEL_BACKGROUND)),
        "interior": int(np.sum(labels == LABEL_INTERIOR)),
    }
    for k in range(num_joints):
        out[f"part_{k}"] = int(np.sum(labels == LABEL_PART + k))
    return out


def _check_inputs(
    dynamic: Capture, world_from_camera: np.ndarray, masks: MaskSequence, joints: Sequence[Joint]
) -> None:
    t = dynamic.num_frames
    if world_from_camera.shape != (t, 4, 4):
        raise InputError(
            f"articulate: {world_from_camera.shape[0]} dynamic poses for a recording of {t} frames; "
            "give one canonical pose per dynamic frame."
        )
    if masks.part.shape[0] != t or masks.part.shape[1:] != dynamic.rgb.shape[1:3]:
        raise InputError(
            f"articulate: masks have shape {masks.part.shape} but the dynamic recording has {t} frames of "
            f"{dynamic.rgb.shape[2]}x{dynamic.rgb.shape[1]} pixels; recompute the masks of this recording."
        )
    for k, j in enumerate(joints):
        if len(j.q) != t:
            raise InputError(
                f"articulate: joint {k} has {len(j.q)} states for {t} dynamic frames; re-estimate the joints."
            )
    if int(masks.part.max(initial=0)) > len(joints):
        raise InputError(
            f"articulate: masks label part {int(masks.part.max()) - 1} but only {len(joints)} joints were given; "
            "give one joint per masked part."
        )


def articulate(
    canonical: GaussianParams,
    static: Capture,
    static_world_from_camera: np.ndarray,
    dynamic: Capture,
    dynamic_world_from_camera: np.ndarray,
    masks: MaskSequence,
    joints: Sequence[Joint],
    config: ArticulationConfig = ArticulationConfig(),
    *,
    callback: Callable[[ArticulationState], None] | None = None,
) -> ArticulationResult:
    """Partition and optimise the canonical model against the dynamic recording.

    Args:
        canonical: the static reconstruction (canonical frame, parts closed); labels ignored.
        static: the static recording; ``static_world_from_camera [Ts, 4, 4]`` its (refined) poses.
        dynamic: the dynamic recording; ``dynamic_world_from_camera [Td, 4, 4]`` its poses in the
            canonical frame (``canonical_from_session @ world_from_camera``).
        masks: part (label k + 1 = joint k) and hand masks of the dynamic recording.
        joints: one joint per part, canonical frame, ``q`` per dynamic frame.
        config: every hyperparameter.
        callback: called after every training step with the state.
    """
    joints = list(joints)
    dyn_poses = np.asarray(dynamic_world_from_camera, np.float64)
    _check_inputs(dynamic, dyn_poses, masks, joints)
    if config.max_side is not None:  # the training resolution: captures and masks downscaled together
        static, dynamic = downscale_rgb(static, config.max_side), downscale_rgb(dynamic, config.max_side)
        masks = downscale_masks(masks, dynamic.rgb_size)
    backend = resolve_backend(config.backend)  # every tensor below lives on its device
    config, dev = replace(config, backend=backend.name), backend.device
    seconds: dict[str, float] = {}
    train_frames, test_frames = split_frames(dynamic.num_frames, config.holdout_every)
    train_av = dynamic_views(dynamic, dyn_poses, masks, joints, train_frames, dev)
    test_av = dynamic_views(dynamic, dyn_poses, masks, joints, test_frames, dev) if test_frames else None

    def heldout(
        params: GaussianParams, js: Sequence[Joint], appearance: PartAppearance | None = None
    ) -> float:
        if test_av is None:
            return float("nan")
        return float(np.mean(evaluate_psnr(params, test_av, js, config, appearance)))

    t0 = time.perf_counter()
    st_av = static_views(static, np.asarray(static_world_from_camera, np.float64), len(joints), dev)
    seen_static = surface_hits(
        canonical.means, st_av.views.cam_from_world.cpu().numpy(), st_av.views.intrinsics,
        st_av.views.depth.cpu().numpy(), st_av.views.depth_weight.cpu().numpy(), config.partition.depth_tol_m,
    )  # fmt: skip
    votes = partition_gaussians(
        canonical.means, joints, masks, train_frames, train_av.views.cam_from_world.cpu().numpy().astype(np.float64),
        train_av.views.intrinsics, train_av.views.depth.cpu().numpy(), train_av.views.depth_weight.cpu().numpy(),
        config.partition, seen_closed=seen_static,
    )  # fmt: skip
    labelled = replace(canonical, labels=votes.labels)
    seconds["partition"] = time.perf_counter() - t0

    measured = dynamic
    if config.camera_effects and train_frames:
        # Train on the dynamic frames as the twin's (the static recording's) camera would have
        # recorded them: the camera fitted against the partitioned twin taken out.
        t0 = time.perf_counter()
        first = fit_dynamic_camera(labelled, joints, dynamic, dyn_poses, masks, train_frames, config)
        rgb = dynamic.rgb.copy()
        rgb[train_frames] = remove_camera(dynamic.rgb[train_frames], first, train_frames, dynamic.rgb_intrinsics[train_frames])
        dynamic = replace(dynamic, rgb=rgb)
        train_av = dynamic_views(dynamic, dyn_poses, masks, joints, train_frames, dev)
        seconds["camera"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    psnr_canonical = heldout(replace(canonical, labels=np.zeros_like(votes.labels)), joints)
    psnr_partitioned = heldout(labelled, joints)
    seconds["evaluate"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    extent = scene_extent(np.concatenate([np.asarray(static_world_from_camera), dyn_poses]))
    appearance = None
    if joints and config.appearance_knots:
        appearance = PartAppearance.neutral(train_av.q, config.appearance_knots)
    state = ArticulationState.from_params(labelled, extent, appearance, device=dev)
    region = part_regions(state, train_av, joints, config)
    uncovered = np.zeros_like(region)
    bg_seeds = None
    if config.seed_background:
        uncovered = uncovered_background(state, train_av, region, joints, config)
        bg_seeds = seed_unexplained(
            state, train_av, uncovered, joints, config, LABEL_BACKGROUND, config.seed_background_max_points
        )
    seeds = seed_unexplained(state, train_av, region, joints, config)
    n_before = state.num_gaussians
    state.edit(torch.ones(n_before, dtype=torch.bool, device=dev), _concat(bg_seeds, seeds))
    seconds["seed"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    trainable = non_background(state)
    trainable[n_before:] = True
    if config.region_dilate_px > 0 and uncovered.any():
        uncovered = np.stack([binary_dilation(u, iterations=config.region_dilate_px) for u in uncovered])
    mask1 = (region | uncovered) & ~train_av.hand
    run_phase(state, [(train_av, mask1, 1.0)], joints, config, config.phase1_steps, trainable, callback)
    pruned = prune_faint(state, config, trainable)
    seconds["phase1"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    psnr_phase1 = heldout(state.to_params(), joints, state.appearance())
    seconds["evaluate"] += time.perf_counter() - t0

    t0 = time.perf_counter()
    if config.phase2_steps > 0:
        sources = [
            (st_av, np.ones((len(st_av), *st_av.hand.shape[1:]), bool), 1.0),
            (train_av, ~train_av.hand, config.dynamic_weight),
        ]
        run_phase(state, sources, joints, config, config.phase2_steps, None, callback, config.phase2_lr_scale)
        pruned += prune_faint(state, config, None)
    seconds["phase2"] = time.perf_counter() - t0
    params = state.to_params()
    t0 = time.perf_counter()
    psnr_final = heldout(params, joints, state.appearance()) if config.phase2_steps > 0 else psnr_phase1
    seconds["evaluate"] += time.perf_counter() - t0
    camera = None
    if config.camera_effects and train_frames:
        # The camera of the final twin, against the frames as measured.
        t0 = time.perf_counter()
        camera = fit_dynamic_camera(params, joints, measured, dyn_poses, masks, train_frames, config, state.appearance())
        seconds["camera"] += time.perf_counter() - t0
    counts = label_counts(params.labels, len(joints))
    counts["seeded"] = seeds.num_gaussians
    counts["seeded_background"] = 0 if bg_seeds is None else bg_seeds.num_gaussians
    counts["pruned"] = pruned
    return ArticulationResult(
        params=params,
        appearance=state.appearance(),
        train_frames=train_frames,
        test_frames=test_frames,
        psnr_canonical_db=psnr_canonical,
        psnr_partitioned_db=psnr_partitioned,
        psnr_phase1_db=psnr_phase1,
        psnr_holdout_db=psnr_final,
        counts=counts,
        losses=np.asarray(state.losses),
        seconds=seconds,
        camera=camera,
    )
