"""3DGS optimisation with explicit state: one view per step, Adam, then the densification strategy.

Everything that changes during training lives in :class:`TrainState` (parameters, Adam moments,
densification statistics, the step counter), and every hyperparameter in the frozen
:class:`TrainConfig`; so a run can be stopped after any step, stored, and resumed to the same
result. The view order is a function of ``(seed, epoch)`` and split samples of ``(seed, step)``,
never of hidden generator state.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from artitwin_core import progress
from artitwin_core.capture import Capture
from artitwin_core.gaussians import LABEL_BACKGROUND, GaussianParams, adam_step, rasterize
from artitwin_core.geometry import invert_se3
from artitwin_core.reconstruction._config import TrainConfig
from artitwin_core.reconstruction._losses import depth_l1, photometric_loss
from artitwin_core.reconstruction._sensor import SensorModel, SensorParams

PARAM_NAMES = ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


@dataclass
class TrainViews:
    """The training views as tensors on one device, with sensor depth resampled onto the RGB grid.

    Attributes:
        frames: ``[V]`` capture frame indices of the views.
        rgb: ``[V, H, W, 3]`` uint8 targets as recorded (sRGB); :meth:`target` gives one view in
            [0, 1]. Held as bytes: a quarter of the memory of float32, converted on the device per step.
        depth: ``[V, H, W]`` float32 sensor depth at each RGB pixel (nearest depth pixel), metres;
            0 where invalid.
        depth_weight: ``[V, H, W]`` float32 confidence weight (0 = no valid measurement).
        cam_from_world: ``[V, 4, 4]`` float32 world-to-camera transforms (OpenCV axes).
        intrinsics: ``[V, 4]`` float64 RGB ``(fx, fy, cx, cy)`` pixels.
        distortion: the RGB lens's OpenCV coefficients as the capture records them (None: pinhole).
    """

    frames: list[int]
    rgb: torch.Tensor
    depth: torch.Tensor
    depth_weight: torch.Tensor
    cam_from_world: torch.Tensor
    intrinsics: np.ndarray
    distortion: np.ndarray | None = None

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` pixels."""
        return int(self.rgb.shape[2]), int(self.rgb.shape[1])

    @property
    def device(self) -> torch.device:
        return self.rgb.device

    def target(self, v: int) -> torch.Tensor:
        """``[H, W, 3]`` float32 RGB of view ``v`` in [0, 1], on the views' device."""
        return self.rgb[v].to(torch.float32) / 255.0


def depth_on_rgb_grid(capture: Capture, t: int, min_confidence: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Sensor depth of frame ``t`` sampled at every RGB pixel centre (nearest depth pixel).

    Uses each image's own intrinsics, so any resolution ratio works.

    Returns:
        depth ``[H, W]`` float32 metres (0 where invalid), weight ``[H, W]`` float32 (confidence,
        1 without a confidence map, 0 where invalid or below ``min_confidence``).
    """
    _, hr, wr, _ = capture.rgb.shape
    _, h, w = capture.depth.shape
    rfx, rfy, rcx, rcy = capture.rgb_intrinsics[t]
    dfx, dfy, dcx, dcy = capture.depth_intrinsics[t]
    u = (np.arange(wr) + 0.5 - rcx) / rfx * dfx + dcx
    v = (np.arange(hr) + 0.5 - rcy) / rfy * dfy + dcy
    ui = np.floor(u).astype(np.int64)
    vi = np.floor(v).astype(np.int64)
    inside = (ui[None, :] >= 0) & (ui[None, :] < w) & (vi[:, None] >= 0) & (vi[:, None] < h)
    d = capture.depth[t][np.clip(vi, 0, h - 1)][:, np.clip(ui, 0, w - 1)]
    weight = np.where(inside & np.isfinite(d) & (d > 0), 1.0, 0.0)
    if capture.confidence is not None:
        c = capture.confidence[t][np.clip(vi, 0, h - 1)][:, np.clip(ui, 0, w - 1)].astype(np.float64)
        weight = np.where(c >= max(min_confidence, 1), weight * c, 0.0)
    return np.where(weight > 0, d, 0.0).astype(np.float32), weight.astype(np.float32)


def make_views(
    capture: Capture,
    world_from_camera: np.ndarray,
    frames: Sequence[int],
    min_confidence: int = 1,
    device: torch.device | str | None = None,
) -> TrainViews:
    """Tensors of ``frames`` on ``device`` (default CPU) for training or evaluation, with the given
    ``[T, 4, 4]`` poses. Each array is copied to the device once, here."""
    frames = [int(f) for f in frames]
    dev = torch.device(device or "cpu")
    h, w = capture.rgb.shape[1:3]
    depth = torch.empty((len(frames), h, w), dtype=torch.float32, device=dev)
    weight = torch.empty((len(frames), h, w), dtype=torch.float32, device=dev)
    for i, t in enumerate(frames):  # one frame at a time: the full-resolution float maps never pile up on the host
        d, c = depth_on_rgb_grid(capture, t, min_confidence)
        depth[i], weight[i] = torch.from_numpy(d), torch.from_numpy(c)
    cams = np.stack([invert_se3(world_from_camera[t]) for t in frames]) if frames else np.zeros((0, 4, 4))
    return TrainViews(
        frames=frames,
        rgb=torch.from_numpy(np.ascontiguousarray(capture.rgb[frames], np.uint8)).to(dev),
        depth=depth,
        depth_weight=weight,
        cam_from_world=torch.from_numpy(cams.astype(np.float32)).to(dev),
        intrinsics=np.asarray(capture.rgb_intrinsics[frames], np.float64),
        distortion=None if capture.distortion is None else np.asarray(capture.distortion, np.float64),
    )


def scene_extent(world_from_camera: np.ndarray) -> float:
    """3DGS's scene scale: 1.1 x the largest distance of a camera centre from their mean, metres
    (at least 0.5 m, so a tripod-like capture still gets sensible learning rates)."""
    centres = world_from_camera[:, :3, 3]
    return max(0.5, 1.1 * float(np.linalg.norm(centres - centres.mean(0), axis=1).max()))


@dataclass
class TrainState:
    """Everything that evolves during training (checkpointable).

    Attributes:
        params: name -> ``[N, ...]`` float32 leaf tensors: means ``[N, 3]`` metres, quats_wxyz
            ``[N, 4]``, log_scales ``[N, 3]``, opacity_logits ``[N]``, sh_dc ``[N, 1, 3]``,
            sh_rest ``[N, K - 1, 3]``.
        exp_avg, exp_avg_sq: Adam first and second moments, same shapes as ``params``.
        step: optimisation steps taken.
        extent: scene scale in metres (learning rates and size thresholds scale with it).
        grad_accum: ``[N]`` sum of NDC gradient norms of the 2D centres since the last densification.
        grad_count: ``[N]`` views each Gaussian was visible in since then.
        max_radii: ``[N]`` largest screen radius (pixels) since then.
        losses: the total loss of every step taken.
        sensor: the learned sensor model's parameters (``TrainConfig.sensor_effects``), created
            at the first step; None for an ideal camera.
    """

    params: dict[str, torch.Tensor]
    exp_avg: dict[str, torch.Tensor]
    exp_avg_sq: dict[str, torch.Tensor]
    step: int
    extent: float
    grad_accum: torch.Tensor
    grad_count: torch.Tensor
    max_radii: torch.Tensor
    losses: list[float] = field(default_factory=list)
    sensor: SensorParams | None = None

    @classmethod
    def from_params(cls, params: GaussianParams, extent: float, device: torch.device | str | None = None) -> TrainState:
        """A fresh state (step 0, zero moments) of ``params`` with every tensor on ``device`` (default CPU)."""
        dev = torch.device(device or "cpu")
        sh = torch.from_numpy(np.ascontiguousarray(params.sh, np.float32))
        p = {
            "means": torch.from_numpy(np.ascontiguousarray(params.means, np.float32)),
            "quats_wxyz": torch.from_numpy(np.ascontiguousarray(params.quats_wxyz, np.float32)),
            "log_scales": torch.from_numpy(np.ascontiguousarray(params.log_scales, np.float32)),
            "opacity_logits": torch.from_numpy(np.ascontiguousarray(params.opacity_logits, np.float32)),
            "sh_dc": sh[:, :1],
            "sh_rest": sh[:, 1:],
        }
        p = {k: v.to(dev, copy=True).contiguous().requires_grad_(True) for k, v in p.items()}
        n = params.num_gaussians
        return cls(
            params=p,
            exp_avg={k: torch.zeros_like(v) for k, v in p.items()},
            exp_avg_sq={k: torch.zeros_like(v) for k, v in p.items()},
            step=0,
            extent=float(extent),
            grad_accum=torch.zeros(n, device=dev),
            grad_count=torch.zeros(n, device=dev),
            max_radii=torch.zeros(n, device=dev),
        )

    @property
    def num_gaussians(self) -> int:
        return int(self.params["means"].shape[0])

    @property
    def device(self) -> torch.device:
        return self.params["means"].device

    def sensor_model(self) -> SensorModel | None:
        """The learned sensor model (None when no sensor effect was trained)."""
        return self.sensor.to_model() if self.sensor else None

    def to_params(self) -> GaussianParams:
        """The current model as ``GaussianParams`` (numpy copies; labels all background)."""
        p = {k: v.detach().cpu() for k, v in self.params.items()}
        sh = torch.cat([p["sh_dc"], p["sh_rest"]], dim=1)
        return GaussianParams(
            means=p["means"].numpy().copy(),
            quats_wxyz=p["quats_wxyz"].numpy().copy(),
            log_scales=p["log_scales"].numpy().copy(),
            opacity_logits=p["opacity_logits"].numpy().copy(),
            sh=sh.numpy().copy(),
            labels=np.full(self.num_gaussians, LABEL_BACKGROUND, np.int32),
        )


def current_sh_degree(step: int, config: TrainConfig) -> int:
    """3DGS grows the SH degree by one every ``sh_degree_every`` steps, up to ``sh_degree``."""
    if config.sh_degree_every <= 0:
        return config.sh_degree
    return min(config.sh_degree, step // config.sh_degree_every)


def means_lr(step: int, config: TrainConfig, extent: float) -> float:
    """Exponential decay from ``lr_means`` to ``lr_means_final`` over ``steps``, times extent."""
    r = min(max(step / max(config.steps, 1), 0.0), 1.0)
    return extent * math.exp((1 - r) * math.log(config.lr_means) + r * math.log(config.lr_means_final))


def render_params(
    params: dict[str, torch.Tensor],
    cam_from_world: torch.Tensor,
    intrinsics: Sequence[float],
    width: int,
    height: int,
    sh_degree: int,
    config: TrainConfig,
):
    """Render the state's parameters into one view (``RenderOutput``)."""
    sh = torch.cat([params["sh_dc"], params["sh_rest"]], dim=1)
    return rasterize(
        params["means"], params["quats_wxyz"], params["log_scales"], params["opacity_logits"], sh,
        cam_from_world, tuple(float(x) for x in intrinsics), width, height,
        sh_degree=sh_degree, background=background_tensor(config.background, params["means"].device),
        backend=config.backend,
    )  # fmt: skip


@functools.lru_cache(maxsize=16)
def _background(rgb: tuple[float, float, float], device: torch.device) -> torch.Tensor:
    return torch.tensor(rgb, dtype=torch.float32, device=device)


def background_tensor(rgb, device: torch.device) -> torch.Tensor:
    """``[3]`` float32 background colour on ``device``, made once per colour and device (not per step)."""
    return _background(tuple(float(c) for c in rgb), torch.device(device))


def view_index(step: int, num_views: int, seed: int) -> int:
    """Which training view step ``step`` uses: a fresh permutation per epoch, seeded."""
    epoch, pos = divmod(step, num_views)
    return int(np.random.default_rng((seed, epoch)).permutation(num_views)[pos])


def _records_distortion(views: TrainViews) -> bool:
    return views.distortion is not None and bool(np.any(np.asarray(views.distortion)[:4] != 0))


def train_step(state: TrainState, views: TrainViews, config: TrainConfig) -> float:
    """One optimisation step on one training view (plus densification when scheduled).

    Returns:
        the step's total loss.
    """
    v = view_index(state.step, len(views.frames), config.seed)
    w, h = views.size
    out = render_params(
        state.params, views.cam_from_world[v], views.intrinsics[v], w, h,
        current_sh_degree(state.step, config), config,
    )  # fmt: skip
    out.retain_means2d_grad()
    if state.sensor is None and (config.sensor_effects or _records_distortion(views)):
        state.sensor = SensorParams(config.sensor_effects, views.frames, views.intrinsics, w, h, views.distortion,
                                    device=state.device)
    sensor = state.sensor
    rgb = sensor.rgb(out.rgb, v) if sensor else out.rgb
    loss = photometric_loss(rgb, views.target(v), config.lambda_dssim)
    if config.depth_weight > 0:
        depth = out.expected_depth()
        depth = sensor.depth(depth) if sensor else depth
        loss = loss + config.depth_weight * depth_l1(depth, views.depth[v], views.depth_weight[v])
    for p in state.params.values():
        p.grad = None
    if sensor:
        sensor.zero_grad()
    loss.backward()
    strategy = config.densify_strategy()
    with torch.no_grad():
        strategy.accumulate(state, out.means2d_grad, out.radii, w, h)
        _adam_update(state, config)
        if sensor:
            sensor.adam_step(state.step, config.lr_sensor)
    state.step += 1
    state.losses.append(float(loss.detach()))
    strategy.after_step(state)
    return state.losses[-1]


def _adam_update(state: TrainState, config: TrainConfig) -> None:
    lrs = {
        "means": means_lr(state.step, config, state.extent),
        "quats_wxyz": config.lr_quats,
        "log_scales": config.lr_scales,
        "opacity_logits": config.lr_opacity,
        "sh_dc": config.lr_sh_dc,
        "sh_rest": config.lr_sh_rest,
    }
    t = state.step + 1
    for name, p in state.params.items():
        adam_step(p, state.exp_avg[name], state.exp_avg_sq[name], lrs[name], t)


def densify_and_prune(state: TrainState, config: TrainConfig) -> dict[str, int]:
    """Clone, split and prune now, as :class:`DensifyStrategy` does on its schedule."""
    return config.densify_strategy().densify_and_prune(state)


def reset_opacity(state: TrainState, config: TrainConfig) -> None:
    """Cap every opacity now, as :class:`DensifyStrategy` does on its schedule."""
    config.densify_strategy().reset_opacity(state)


def train(
    state: TrainState,
    views: TrainViews,
    config: TrainConfig,
    *,
    until: int | None = None,
    callback: Callable[[TrainState], None] | None = None,
    time_budget_s: float | None = None,
) -> TrainState:
    """Run :func:`train_step` until ``until`` steps (default ``config.steps``) are done.

    Args:
        state: modified in place and returned (resume by passing a stored state).
        views: the training views.
        config: hyperparameters.
        until: stop after this many total steps (for checkpointing in slices).
        callback: called after every step with the state.
        time_budget_s: stop early once this many seconds have passed (the state stays valid).
    """
    end = config.steps if until is None else min(until, config.steps)
    start = time.perf_counter()
    with progress("3DGS training", total=end) as report:
        report.set(state.step)
        while state.step < end:
            train_step(state, views, config)
            report.advance(info=f"{state.num_gaussians} Gaussians")
            if callback is not None:
                callback(state)
            if time_budget_s is not None and time.perf_counter() - start > time_budget_s:
                break
    return state
