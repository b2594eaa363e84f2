"""3DGS's adaptive density control as a strategy beside the optimiser (gsplat's ``DefaultStrategy``).

A trainer renders, back-propagates and takes its Adam step; the strategy then, on its schedule,
clones small and splits large Gaussians whose projected centres kept getting large gradients,
prunes faint, huge and (after an opacity reset) screen-filling ones, and periodically caps every
opacity. Its settings are a frozen :class:`DensifyStrategy` (the trainer's config converts its own
fields into one); what evolves lives in the trainer's state, which must offer the
:class:`DensifiableState` attributes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch

from artitwin_core.gaussians._ops import edit_rows
from artitwin_core.geometry import quat_wxyz_to_matrix


class DensifiableState(Protocol):
    """What the strategy reads and edits in a trainer's state."""

    params: dict[str, torch.Tensor]  # means, quats_wxyz, log_scales, opacity_logits, sh_dc, sh_rest
    exp_avg: dict[str, torch.Tensor]
    exp_avg_sq: dict[str, torch.Tensor]
    step: int  # steps taken
    extent: float  # scene scale, metres
    grad_accum: torch.Tensor  # [N] summed NDC gradient norms of the 2D centres since the last densification
    grad_count: torch.Tensor  # [N] views each Gaussian was visible in since then
    max_radii: torch.Tensor  # [N] largest screen radius since then, pixels


@dataclass(frozen=True)
class DensifyStrategy:
    """When and how to densify, prune and reset opacity (see ``TrainConfig`` for each field's meaning).

    No defaults here: a trainer's config declares them once and converts.
    """

    densify_from: int
    densify_until: int
    densify_every: int
    grad_threshold: float
    percent_dense: float
    max_gaussians: int
    min_opacity: float
    max_screen_radius_px: float
    max_world_scale: float
    opacity_reset_every: int
    opacity_reset_value: float
    seed: int

    @torch.no_grad()
    def accumulate(self, state: DensifiableState, means2d_grad: torch.Tensor | None, radii: torch.Tensor,
                   width: int, height: int) -> None:
        """Add one view's statistics: ``means2d_grad [N, 2]`` (pixels) and ``radii [N]`` of the render."""
        if means2d_grad is None:
            return
        # Masked arithmetic rather than indexing by the visible set: no host sync per step on a GPU.
        vis = radii > 0
        # 3DGS measures the gradient w.r.t. NDC coordinates: d(px)/d(ndc) = (W/2, H/2).
        g = means2d_grad.detach().float()
        gn = torch.linalg.norm(torch.stack([g[:, 0] * (width / 2.0), g[:, 1] * (height / 2.0)], dim=-1), dim=-1)
        state.grad_accum += torch.where(vis, gn, 0.0)
        state.grad_count += vis.to(state.grad_count.dtype)
        state.max_radii.copy_(torch.where(vis, torch.maximum(state.max_radii, radii.detach().float()), state.max_radii))

    def after_step(self, state: DensifiableState) -> None:
        """Densify and reset opacity where the schedule says, after step ``state.step`` was taken."""
        s = state.step
        if self.densify_from <= s <= self.densify_until and s % self.densify_every == 0:
            self.densify_and_prune(state)
        if self.opacity_reset_every > 0 and s % self.opacity_reset_every == 0 and s <= self.densify_until:
            self.reset_opacity(state)

    @torch.no_grad()
    def densify_and_prune(self, state: DensifiableState) -> dict[str, int]:
        """Clone small and split large Gaussians with high view-space gradients; prune faint and
        huge ones (3DGS ``densify_and_prune``). Returns how many were cloned, split and pruned;
        the statistics restart."""
        p = {k: v.detach() for k, v in state.params.items()}
        n = p["means"].shape[0]
        grads = torch.where(state.grad_count > 0, state.grad_accum / state.grad_count.clamp_min(1), 0.0)
        max_scale = p["log_scales"].exp().max(dim=1).values
        cand = grads >= self.grad_threshold
        room = max(0, self.max_gaussians - n)
        if int(cand.sum()) > room:  # over budget: keep the strongest gradients only
            order = torch.argsort(torch.where(cand, grads, -1.0), descending=True)
            cand = torch.zeros_like(cand)
            cand[order[:room]] = True
        large = max_scale > self.percent_dense * state.extent
        clone, split = cand & ~large, cand & large
        new = {k: v[clone] for k, v in p.items()}
        # Split: two samples from each large Gaussian, 1.6x smaller (3DGS).
        idx = torch.nonzero(split).squeeze(1)
        dev = p["means"].device
        gen = torch.Generator(device=dev).manual_seed(int(self.seed) * 1_000_003 + state.step)
        if len(idx):
            s = p["log_scales"][idx].exp()
            rot = quat_wxyz_to_matrix(p["quats_wxyz"][idx])
            for _ in range(2):
                offs = torch.randn(s.shape, generator=gen, device=dev) * s
                new["means"] = torch.cat([new["means"], p["means"][idx] + (rot @ offs[:, :, None])[:, :, 0]])
                new["log_scales"] = torch.cat([new["log_scales"], torch.log(s / 1.6)])
                for k in ("quats_wxyz", "opacity_logits", "sh_dc", "sh_rest"):
                    new[k] = torch.cat([new[k], p[k][idx]])
        opacity = torch.sigmoid(p["opacity_logits"])
        prune = split | (opacity < self.min_opacity)
        if self.opacity_reset_every > 0 and state.step > self.opacity_reset_every:
            prune |= state.max_radii > self.max_screen_radius_px
        prune |= max_scale > self.max_world_scale * state.extent
        # Never empty the model.
        if bool(prune.all()) and not len(new["means"]):
            prune[:] = False
        stats = {"cloned": int(clone.sum()), "split": int(split.sum()), "pruned": int((prune & ~split).sum())}
        edit_rows(state.params, (state.exp_avg, state.exp_avg_sq), ~prune, new)
        n = state.params["means"].shape[0]
        state.grad_accum = torch.zeros(n, device=dev)
        state.grad_count = torch.zeros(n, device=dev)
        state.max_radii = torch.zeros(n, device=dev)
        return stats

    @torch.no_grad()
    def reset_opacity(self, state: DensifiableState) -> None:
        """Cap every opacity at ``opacity_reset_value`` (3DGS), zeroing its Adam moments."""
        cap = math.log(self.opacity_reset_value / (1 - self.opacity_reset_value))
        logits = state.params["opacity_logits"].detach().clamp(max=cap)
        state.params["opacity_logits"] = logits.contiguous().requires_grad_(True)
        state.exp_avg["opacity_logits"].zero_()
        state.exp_avg_sq["opacity_logits"].zero_()
