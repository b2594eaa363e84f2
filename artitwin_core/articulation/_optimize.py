"""Articulation-conditioned optimisation of the Gaussians: seeding, phase I, phase II, evaluation.

Everything that changes lives in :class:`ArticulationState` (parameters, labels, Adam moments,
step counter); every hyperparameter in the frozen :class:`ArticulationConfig`. Each training
step renders one view with the part Gaussians moved by their joints to that view's states, so
gradients reach the canonical (closed-state) parameters through the rigid motion.

Phase I trains only interior and part Gaussians, on the dynamic views, inside the part region
(the dilated part mask plus what the closed part covered). Phase II trains everything on both
recordings, the dynamic views with a weaker weight. Hand pixels never enter a loss.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from scipy.ndimage import binary_dilation
from scipy.spatial import cKDTree

from artitwin_core import progress
from artitwin_core.articulation._appearance import PartAppearance, apply_part_gains, part_log_gains
from artitwin_core.articulation._config import ArticulationConfig
from artitwin_core.articulation._kinematics import (
    articulate_tensors,
    motion_tables,
    move_by_label,
    part_motions,
)
from artitwin_core.gaussians import (
    LABEL_BACKGROUND,
    LABEL_INTERIOR,
    LABEL_PART,
    GaussianParams,
    adam_step,
    edit_rows,
    rasterize,
)
from artitwin_core.gaussians._sh import SH_C0
from artitwin_core.geometry import pixel_rays, unique_rows
from artitwin_core.joints import Joint
from artitwin_core.reconstruction import TrainViews
from artitwin_core.reconstruction._losses import depth_l1, photometric_loss, psnr
from artitwin_core.reconstruction._train import background_tensor, view_index

PARAM_NAMES = ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


@dataclass
class ArticulatedViews:
    """Training or evaluation views with what articulation needs besides the images.

    Attributes:
        views: images, sensor depth on the RGB grid, canonical ``cam_from_world``, intrinsics.
        q: ``[V, K]`` float64 joint states at each view (zeros for the static recording).
        part: ``[V, H, W]`` uint8 part labels (0 = none, k + 1 = part k); zeros when static.
        hand: ``[V, H, W]`` bool pixels excluded from every loss and metric.
        tables: each view's per-label part motions (:func:`motion_tables` of the joints at ``q``:
            rotations ``[V, L, 3, 3]``, translations ``[V, L, 3]``, wxyz quaternions ``[V, L, 4]``)
            on the views' device, made once by :meth:`with_tables`; None computes them per render.
            Derived from ``q``: a copy with other states must drop them.
    """

    views: TrainViews
    q: np.ndarray
    part: np.ndarray
    hand: np.ndarray
    tables: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None

    def __len__(self) -> int:
        return len(self.views.frames)

    def with_tables(self, joints: Sequence[Joint]) -> ArticulatedViews:
        """These views with every view's part motions (``joints`` at ``q``) built on the views'
        device once, so a training step copies nothing to the device."""
        if not len(joints) or not len(self):
            return self
        return self.with_motions(np.stack([part_motions(joints, self.q[v]) for v in range(len(self))]))

    def with_motions(self, motions: np.ndarray) -> ArticulatedViews:
        """These views with ``motions [V, K, 4, 4]`` (each view's ``world_from_part`` per joint) as
        :attr:`tables` on the views' device (the static recording's: the identity, parts closed)."""
        motions = np.asarray(motions, np.float64)
        if motions.shape[1] == 0 or not len(self):
            return self
        dev = self.views.device
        tables = tuple(torch.from_numpy(a.astype(np.float32)).to(dev) for a in motion_tables(motions))
        return replace(self, tables=tables)


@dataclass
class ArticulationState:
    """Everything that evolves during articulation (checkpointable).

    Attributes:
        params: name -> leaf tensor (see ``PARAM_NAMES``; ``sh_dc [N, 1, 3]``, ``sh_rest [N, K-1, 3]``).
        labels: ``[N]`` int32 part labels.
        exp_avg, exp_avg_sq: Adam moments, shaped as ``params``.
        step: steps taken over both phases.
        extent: scene scale, metres (the position learning rate scales with it).
        losses: loss of every step.
        knots: ``[K, M]`` joint states of the part gain curves (see :class:`PartAppearance`).
        log_gain: ``[K, M]`` leaf tensor, the curves' log gains; ``gain_avg``, ``gain_avg_sq``
            its Adam moments.
    """

    params: dict[str, torch.Tensor]
    labels: torch.Tensor
    exp_avg: dict[str, torch.Tensor]
    exp_avg_sq: dict[str, torch.Tensor]
    step: int
    extent: float
    losses: list[float] = field(default_factory=list)
    knots: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    log_gain: torch.Tensor = field(default_factory=lambda: torch.zeros((0, 0), dtype=torch.float64))
    gain_avg: torch.Tensor = field(default_factory=lambda: torch.zeros((0, 0), dtype=torch.float64))
    gain_avg_sq: torch.Tensor = field(default_factory=lambda: torch.zeros((0, 0), dtype=torch.float64))

    def set_appearance(self, appearance: PartAppearance | None) -> None:
        """Start the part gain curves from ``appearance`` (None: no curves, gain 1)."""
        if appearance is None:
            appearance = PartAppearance(np.zeros((0, 0)), np.zeros((0, 0)))
        self.knots = np.asarray(appearance.knots, np.float64)
        self.log_gain = torch.tensor(appearance.log_gain, dtype=torch.float64, device=self.device, requires_grad=True)
        self.gain_avg = torch.zeros_like(self.log_gain)
        self.gain_avg_sq = torch.zeros_like(self.log_gain)

    def appearance(self) -> PartAppearance | None:
        if self.knots.size == 0:
            return None
        return PartAppearance(self.knots.copy(), self.log_gain.detach().cpu().numpy().copy())

    @classmethod
    def from_params(
        cls,
        params: GaussianParams,
        extent: float,
        appearance: PartAppearance | None = None,
        device: torch.device | str | None = None,
    ) -> ArticulationState:
        """A fresh state (step 0, zero moments) with every tensor on ``device`` (default CPU)."""
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
        state = cls(
            params=p,
            labels=torch.from_numpy(np.asarray(params.labels, np.int32).copy()).to(dev),
            exp_avg={k: torch.zeros_like(v) for k, v in p.items()},
            exp_avg_sq={k: torch.zeros_like(v) for k, v in p.items()},
            step=0,
            extent=float(extent),
        )
        state.set_appearance(appearance)
        return state

    @property
    def num_gaussians(self) -> int:
        return int(self.labels.shape[0])

    @property
    def device(self) -> torch.device:
        return self.labels.device

    def to_params(self) -> GaussianParams:
        p = {k: v.detach().cpu() for k, v in self.params.items()}
        return GaussianParams(
            means=p["means"].numpy().copy(),
            quats_wxyz=p["quats_wxyz"].numpy().copy(),
            log_scales=p["log_scales"].numpy().copy(),
            opacity_logits=p["opacity_logits"].numpy().copy(),
            sh=torch.cat([p["sh_dc"], p["sh_rest"]], 1).numpy().copy(),
            labels=self.labels.cpu().numpy().copy(),
        )

    def edit(self, keep: torch.Tensor, new: GaussianParams | None = None) -> None:
        """Keep rows ``keep``, then append ``new`` Gaussians (with zero Adam moments)."""
        add = None
        if new is not None and new.num_gaussians:
            add = ArticulationState.from_params(new, self.extent, device=self.device)
        rows = None
        if add is not None:
            rows = {}
            for name, extra in add.params.items():
                extra = extra.detach()
                shape = self.params[name].shape[1:]
                if extra.shape[1:] != shape:  # fewer SH bands in the seeds: pad with zeros
                    pad = torch.zeros((extra.shape[0], *shape), dtype=extra.dtype, device=extra.device)
                    pad[:, : extra.shape[1]] = extra
                    extra = pad
                rows[name] = extra
        edit_rows(self.params, (self.exp_avg, self.exp_avg_sq), keep, rows)
        labels = self.labels[keep]
        if add is not None:
            labels = torch.cat([labels, add.labels])
        self.labels = labels.contiguous()


def render_state(
    state: ArticulationState,
    av: ArticulatedViews,
    v: int,
    joints: Sequence[Joint],
    config: ArticulationConfig,
    subset: torch.Tensor | None = None,
):
    """Render view ``v`` with the part Gaussians at that view's joint states (``RenderOutput``)."""
    p = state.params
    labels = state.labels
    idx = slice(None) if subset is None else subset
    if av.tables is not None:
        rot, trans, quat = (t[v] for t in av.tables)
        means, quats = move_by_label(p["means"][idx], p["quats_wxyz"][idx], labels[idx], rot, trans, quat)
    else:
        means, quats = articulate_tensors(
            p["means"][idx], p["quats_wxyz"][idx], labels[idx], part_motions(joints, av.q[v])
        )
    sh = torch.cat([p["sh_dc"][idx], p["sh_rest"][idx]], 1)
    if state.knots.size:
        sh = apply_part_gains(sh, labels[idx], part_log_gains(state.log_gain, state.knots, av.q[v]))
    w, h = av.views.size
    return rasterize(
        means, quats, p["log_scales"][idx], p["opacity_logits"][idx], sh,
        av.views.cam_from_world[v], tuple(float(x) for x in av.views.intrinsics[v]), w, h,
        background=background_tensor(config.background, p["means"].device), backend=config.backend,
    )  # fmt: skip


def part_regions(
    state: ArticulationState, av: ArticulatedViews, joints: Sequence[Joint], config: ArticulationConfig
) -> np.ndarray:
    """``[V, H, W]`` bool phase-I loss region: dilated part masks plus the closed parts' footprint."""
    w, h = av.views.size
    region = np.zeros((len(av), h, w), bool)
    parts = state.labels >= LABEL_PART
    closed = ArticulatedViews(av.views, np.zeros_like(av.q), av.part, av.hand)
    for v in range(len(av)):
        m = av.part[v] > 0
        if config.region_dilate_px > 0:
            m = binary_dilation(m, iterations=config.region_dilate_px)
        if bool(parts.any()):
            with torch.no_grad():
                out = render_state(state, closed, v, joints, config, subset=parts)
            m |= out.alpha.cpu().numpy() > 0.3
        region[v] = m
    return region


def auto_seed_voxel(av: ArticulatedViews) -> float:
    d = av.views.depth[av.views.depth_weight > 0]
    med = float(d.median()) if d.numel() else 2.0
    fx = float(np.median(av.views.intrinsics[:, 0]))
    return float(np.clip(1.5 * med / fx, 0.005, 0.03))


def uncovered_background(
    state: ArticulationState,
    av: ArticulatedViews,
    region: np.ndarray,
    joints: Sequence[Joint],
    config: ArticulationConfig,
) -> np.ndarray:
    """``[V, H, W]`` bool pixels outside the part ``region`` (and clear of the hand) where the
    model is transparent (alpha < 0.5): static surface the dynamic views see and the static
    recording never did. On the door benchmark the camera turns towards the opened handle and
    shows floor the static sweep missed; left empty it rendered black there (13 dB background
    PSNR on the last held-out frame)."""
    out = np.zeros(region.shape, bool)
    for v in range(len(av)):
        with torch.no_grad():
            alpha = render_state(state, av, v, joints, config).alpha.cpu().numpy()
        hand = (
            binary_dilation(av.hand[v], iterations=config.region_dilate_px)
            if av.hand[v].any()
            else av.hand[v]
        )
        out[v] = (alpha < 0.5) & ~region[v] & ~hand
    return out


def seed_unexplained(
    state: ArticulationState,
    av: ArticulatedViews,
    region: np.ndarray,
    joints: Sequence[Joint],
    config: ArticulationConfig,
    other_label: int = LABEL_INTERIOR,
    max_points: int | None = None,
) -> GaussianParams:
    """New Gaussians where the dynamic views see surface the current model does not explain.

    A region pixel with valid sensor depth (not hand) is unexplained when the model's alpha is
    below 0.5 there or its depth lies more than ``seed_depth_tol_m`` behind the sensor. It is
    lifted into the canonical frame; on a part (mask k + 1) it is moved back to the closed state
    by the inverse joint motion and labelled part k, elsewhere it is labelled ``other_label``
    (interior behind the parts, background for :func:`uncovered_background`). At most
    ``max_points`` (default ``config.seed_max_points``) Gaussians.
    """
    pts, cols, labs = [], [], []
    w, h = av.views.size
    vv, uu = np.mgrid[0:h, 0:w]
    for v in range(len(av)):
        with torch.no_grad():
            out = render_state(state, av, v, joints, config)
        alpha = out.alpha.cpu().numpy()
        rdepth = out.expected_depth(1e-3).cpu().numpy()
        d = av.views.depth[v].cpu().numpy()
        ok = (av.views.depth_weight[v].cpu().numpy() > 0) & region[v] & ~av.hand[v]
        bad = ok & ((alpha < 0.5) | (rdepth > d + config.seed_depth_tol_m))
        if not bad.any():
            continue
        z = d[bad].astype(np.float64)
        # Pixel centres at +0.5, as the rasterizer draws with the data's K (geometry._camera).
        ray = pixel_rays(av.views.intrinsics[v], uu[bad] + 0.5, vv[bad] + 0.5)
        cam = np.concatenate([ray * z[:, None], np.ones_like(z)[:, None]], 1)
        world_from_cam = np.linalg.inv(av.views.cam_from_world[v].cpu().numpy().astype(np.float64))
        x = cam @ world_from_cam.T
        lab = np.full(len(z), other_label, np.int32)
        part = av.part[v][bad].astype(np.int64)
        motions = part_motions(joints, av.q[v])
        for k in range(len(joints)):
            on = part == k + 1
            if on.any():
                x[on] = x[on] @ np.linalg.inv(motions[k]).T
                lab[on] = LABEL_PART + k
        pts.append(x[:, :3])
        cols.append(av.views.target(v).cpu().numpy()[bad])
        labs.append(lab)
    if not pts:
        return _empty_params()
    points, colours, labels = np.concatenate(pts), np.concatenate(cols), np.concatenate(labs)
    voxel = config.seed_voxel_m or auto_seed_voxel(av)
    while True:
        means, rgb, lab = _voxel_merge(points, colours, labels, voxel)
        if len(means) <= (config.seed_max_points if max_points is None else max_points):
            break
        voxel *= 1.25
    n = len(means)
    if n == 0:
        return _empty_params()
    if n >= 4:
        dist, _ = cKDTree(means).query(means, k=4)
        nn = np.clip(dist[:, 1:].mean(1), 0.3 * voxel, 2.0 * voxel)
    else:
        nn = np.full(n, voxel)
    sh = np.zeros((n, 1, 3), np.float32)
    sh[:, 0] = (np.clip(rgb, 0, 1) - 0.5) / SH_C0
    o = config.seed_opacity
    return GaussianParams(
        means=means.astype(np.float32),
        quats_wxyz=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
        log_scales=np.repeat(np.log(nn)[:, None], 3, 1).astype(np.float32),
        opacity_logits=np.full(n, math.log(o / (1 - o)), np.float32),
        sh=sh,
        labels=lab.astype(np.int32),
    )


def _empty_params() -> GaussianParams:
    return GaussianParams(
        means=np.zeros((0, 3), np.float32), quats_wxyz=np.zeros((0, 4), np.float32),
        log_scales=np.zeros((0, 3), np.float32), opacity_logits=np.zeros(0, np.float32),
        sh=np.zeros((0, 1, 3), np.float32), labels=np.zeros(0, np.int32),
    )  # fmt: skip


def _voxel_merge(points: np.ndarray, colours: np.ndarray, labels: np.ndarray, voxel: float):
    """Mean point and colour per (label, voxel)."""
    keys = np.concatenate([labels[:, None].astype(np.int64), np.floor(points / voxel).astype(np.int64)], 1)
    uniq, inv, _ = unique_rows(keys)
    cnt = np.bincount(inv, minlength=len(uniq)).astype(np.float64)
    p = np.stack([np.bincount(inv, points[:, i], len(uniq)) for i in range(3)], 1) / cnt[:, None]
    c = np.stack([np.bincount(inv, colours[:, i], len(uniq)) for i in range(3)], 1) / cnt[:, None]
    return p, c, uniq[:, 0].astype(np.int32)


def _adam(
    state: ArticulationState,
    config: ArticulationConfig,
    frac: float,
    trainable: torch.Tensor | None,
    lr_scale: float = 1.0,
) -> None:
    lr_means = state.extent * config.lr_means * math.exp(frac * math.log(0.01))
    lrs = {
        "means": lr_means, "quats_wxyz": config.lr_quats, "log_scales": config.lr_scales,
        "opacity_logits": config.lr_opacity, "sh_dc": config.lr_sh_dc, "sh_rest": config.lr_sh_rest,
    }  # fmt: skip
    lrs = {k: lr_scale * v for k, v in lrs.items()}
    t = state.step + 1
    for name, p in state.params.items():
        adam_step(p, state.exp_avg[name], state.exp_avg_sq[name], lrs[name], t, trainable)
    if state.log_gain.numel():
        adam_step(state.log_gain, state.gain_avg, state.gain_avg_sq, lr_scale * config.lr_part_gain, t)


def view_loss(
    state: ArticulationState,
    av: ArticulatedViews,
    v: int,
    loss_mask: np.ndarray | torch.Tensor,
    joints: Sequence[Joint],
    config: ArticulationConfig,
) -> torch.Tensor:
    """Photometric (L1 + D-SSIM) plus depth loss of view ``v`` restricted to ``loss_mask [H, W]``
    (bool; a tensor on the state's device, or numpy, which is copied there).

    Outside the mask the render is replaced by the target, so those pixels add neither error
    nor gradient (SSIM windows straddling the border still see both sides).
    """
    out = render_state(state, av, v, joints, config)
    target = av.views.target(v)
    m = loss_mask if isinstance(loss_mask, torch.Tensor) else torch.from_numpy(loss_mask).to(state.device)
    comp = torch.where(m[..., None], out.rgb, target)
    loss = photometric_loss(comp, target, config.lambda_dssim)
    if config.depth_weight > 0:
        wgt = av.views.depth_weight[v] * m.to(torch.float32)
        loss = loss + config.depth_weight * depth_l1(out.expected_depth(), av.views.depth[v], wgt)
    return loss


def run_phase(
    state: ArticulationState,
    sources: Sequence[tuple[ArticulatedViews, np.ndarray, float]],
    joints: Sequence[Joint],
    config: ArticulationConfig,
    steps: int,
    trainable: torch.Tensor | None,
    callback: Callable[[ArticulationState], None] | None = None,
    lr_scale: float = 1.0,
) -> None:
    """``steps`` Adam steps over the views of ``sources`` in seeded random order.

    Args:
        sources: ``(views, loss_masks [V, H, W] bool, weight)`` per recording.
        trainable: ``[N]`` bool rows that may change (None = all).
    """
    index = [(s, v) for s, (av, _, _) in enumerate(sources) for v in range(len(av))]
    if not index or steps <= 0:
        return
    # The loss masks go to the device once, as the views did.
    sources = [(av, torch.from_numpy(np.ascontiguousarray(m, bool)).to(state.device), w) for av, m, w in sources]
    with progress("articulation", total=steps) as report:
        for i in range(steps):
            _phase_step(state, sources, index, i, steps, joints, config, trainable, lr_scale)
            report.advance()
            if callback is not None:
                callback(state)


def _phase_step(
    state: ArticulationState,
    sources: Sequence[tuple[ArticulatedViews, torch.Tensor, float]],
    index: list[tuple[int, int]],
    i: int,
    steps: int,
    joints: Sequence[Joint],
    config: ArticulationConfig,
    trainable: torch.Tensor | None,
    lr_scale: float,
) -> None:
    """Step ``i`` of ``steps`` of a phase: one view's loss, its gradient, one Adam update."""
    s, v = index[view_index(i, len(index), config.seed)]
    av, masks, weight = sources[s]
    loss = weight * view_loss(state, av, v, masks[v], joints, config)
    for p in state.params.values():
        p.grad = None
    state.log_gain.grad = None
    loss.backward()
    with torch.no_grad():
        _adam(state, config, i / max(steps, 1), trainable, lr_scale)
    state.step += 1
    state.losses.append(float(loss.detach()))


def prune_faint(state: ArticulationState, config: ArticulationConfig, trainable: torch.Tensor | None) -> int:
    """Drop trainable Gaussians with opacity below ``min_opacity``; returns how many."""
    with torch.no_grad():
        faint = torch.sigmoid(state.params["opacity_logits"].detach()) < config.min_opacity
        if trainable is not None:
            faint &= trainable
        if bool(faint.any()):
            state.edit(~faint)
        return int(faint.sum())


def evaluate_psnr(
    params: GaussianParams,
    av: ArticulatedViews,
    joints: Sequence[Joint],
    config: ArticulationConfig,
    appearance: PartAppearance | None = None,
) -> np.ndarray:
    """``[V]`` PSNR (dB) of the twin at each view's joint states, hand pixels excluded."""
    state = ArticulationState.from_params(params, 1.0, appearance, device=av.views.device)
    out = []
    for v in range(len(av)):
        with torch.no_grad():
            r = render_state(state, av, v, joints, config)
        keep = torch.from_numpy(~av.hand[v]).to(state.device)
        out.append(psnr(r.rgb[keep], av.views.target(v)[keep]))
    return np.asarray(out)


def non_background(state: ArticulationState) -> torch.Tensor:
    return state.labels != LABEL_BACKGROUND
