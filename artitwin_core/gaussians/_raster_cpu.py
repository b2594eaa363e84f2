"""The CPU rasterizer: torch projection + numba tile compositing behind one autograd Function.

The split follows gsplat: :func:`project_gaussians` (torch with autograd, plus a numba SH
kernel pair) turns 3D parameters into screen-space means, conics, colours, opacities and depths;
the custom :class:`_RasterizeToPixels` composites them with hand-written numba kernels forward
and backward. Culling, depth ordering and binning are computed once per call outside autograd.

Where the time goes (20k room-like Gaussians, 256x192, one thread, CPU time): compositing
forward ~27 ms and backward ~35 ms (about half of each is per-row set-up: chord bounds and two
exps per row; the rest is ~3M pixel updates), projection + SH forward and backward ~11 ms,
culling/sorting/binning ~3 ms. Two threads split the compositing over tiles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from artitwin_core.gaussians import _kernels
from artitwin_core.gaussians._project import (
    ALPHA_MAX,
    ALPHA_MIN,
    T_MIN,
    Projected,
    project_gaussians,
    screen_extent,
)


@dataclass
class _Layout:
    """Visibility, depth order and tile lists of one render (numpy, no gradient).

    Attributes:
        order: ``[M]`` int64 indices into the N Gaussians of the visible ones, front to back.
        boxes: ``[M, 4]`` int32 pixel ranges ``x0, x1, y0, y1`` (half-open).
        cutoff2: ``[M]`` squared Mahalanobis radius beyond which alpha < 1/255 (working dtype).
        offsets: ``[n_tiles + 1]`` int64 tile list offsets into ``ids``.
        ids: ``[n_isect]`` int32 entries into ``order`` per tile, depth-sorted.
    """

    order: np.ndarray
    boxes: np.ndarray
    cutoff2: np.ndarray
    offsets: np.ndarray
    ids: np.ndarray


def _make_layout(
    means2d: torch.Tensor,
    depths: torch.Tensor,
    half_w: torch.Tensor,
    half_h: torch.Tensor,
    radius: torch.Tensor,
    cutoff: torch.Tensor,
    width: int,
    height: int,
) -> _Layout:
    with torch.no_grad():
        mx = means2d[:, 0].double()
        my = means2d[:, 1].double()
        hw = half_w.double()
        hh = half_h.double()
        # Pixel j's centre is j + 0.5; keep j with |centre - mean| <= half extent.
        x0 = torch.ceil(mx - hw - 0.5).clamp(0, width)
        x1 = (torch.floor(mx + hw - 0.5) + 1).clamp(0, width)
        y0 = torch.ceil(my - hh - 0.5).clamp(0, height)
        y1 = (torch.floor(my + hh - 0.5) + 1).clamp(0, height)
        keep = (radius > 0) & (x1 > x0) & (y1 > y0) & torch.isfinite(mx) & torch.isfinite(my)
        idx = torch.nonzero(keep).squeeze(1)
        idx = idx[torch.argsort(depths.detach()[idx], stable=True)]
        boxes = torch.stack([x0[idx], x1[idx], y0[idx], y1[idx]], dim=1).to(torch.int32)
        cutoff2 = np.ascontiguousarray(torch.square(cutoff[idx]).numpy())
    boxes_np = np.ascontiguousarray(boxes.numpy())
    tiles_x = (width + _kernels.TILE - 1) // _kernels.TILE
    tiles_y = (height + _kernels.TILE - 1) // _kernels.TILE
    offsets, ids = _kernels.bin_gaussians(boxes_np, tiles_x, tiles_y)
    return _Layout(order=idx.numpy(), boxes=boxes_np, cutoff2=cutoff2, offsets=offsets, ids=ids)


def _consts(dtype: np.dtype) -> np.ndarray:
    return np.array([ALPHA_MAX, ALPHA_MIN, T_MIN, 1.0, 0.5], dtype=dtype)


class _RasterizeToPixels(torch.autograd.Function):
    """Composite screen-space Gaussians; inputs ``[N, ...]``, outputs rgb/depth/alpha images."""

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, layout, background, width, height):
        order = torch.from_numpy(layout.order)
        params = torch.cat(
            [
                means2d[order],
                conics[order],
                colors[order],
                opacities[order, None],
                depths[order, None],
            ],
            dim=1,
        )
        params_np = np.ascontiguousarray(params.detach().numpy())
        dtype = params_np.dtype
        bg = np.ascontiguousarray(background.detach().numpy().astype(dtype))
        rgbd = np.empty((height, width, 4), dtype)
        tfinal = np.empty((height, width), dtype)
        last = np.empty((height, width), np.int32)
        _kernels.rasterize_forward(
            params_np, layout.boxes, layout.cutoff2, layout.offsets, layout.ids, width, height, bg, _consts(dtype),
            rgbd, tfinal, last,
        )  # fmt: skip
        ctx.layout = layout
        ctx.params_np = params_np
        ctx.bg = bg
        ctx.tfinal = tfinal
        ctx.last = last
        ctx.size = (width, height)
        ctx.n = means2d.shape[0]
        rgbd_t = torch.from_numpy(rgbd)
        rgb = rgbd_t[..., :3].contiguous()
        depth = rgbd_t[..., 3].contiguous()
        alpha = 1.0 - torch.from_numpy(tfinal)
        return rgb, depth, alpha

    @staticmethod
    def backward(ctx, g_rgb, g_depth, g_alpha):
        width, height = ctx.size
        dtype = ctx.params_np.dtype
        tdtype = torch.from_numpy(ctx.params_np[:0]).dtype
        grad_rgbd = torch.zeros((height, width, 4), dtype=tdtype)
        if g_rgb is not None:
            grad_rgbd[..., :3] = g_rgb
        if g_depth is not None:
            grad_rgbd[..., 3] = g_depth
        grad_alpha = torch.zeros((height, width), dtype=tdtype) if g_alpha is None else g_alpha.to(tdtype)
        layout = ctx.layout
        isect = np.empty((layout.ids.shape[0], 10), dtype)
        _kernels.rasterize_backward(
            ctx.params_np, layout.boxes, layout.cutoff2, layout.offsets, layout.ids, width, height, ctx.bg,
            _consts(dtype), ctx.tfinal, ctx.last, grad_rgbd.numpy(),
            np.ascontiguousarray(grad_alpha.numpy()), isect,
        )  # fmt: skip
        per_g = _kernels.sum_isect_grads(layout.ids, isect, layout.order.shape[0])
        full = torch.zeros((ctx.n, 10), dtype=tdtype)
        full[torch.from_numpy(layout.order)] = torch.from_numpy(per_g).to(tdtype)
        return (
            full[:, 0:2],
            full[:, 2:5],
            full[:, 5:8],
            full[:, 8],
            full[:, 9],
            None,
            None,
            None,
            None,
        )


def visible_radii(proj: Projected, width: int, height: int) -> torch.Tensor:
    """``[N]`` bounding-circle radii in pixels of the Gaussians the compositor would use, else 0."""
    half_w, half_h, radius, cutoff = screen_extent(proj.cov2d, proj.opacities, proj.valid)
    layout = _make_layout(proj.means2d, proj.depths, half_w, half_h, radius, cutoff, width, height)
    visible = torch.zeros_like(radius, dtype=torch.bool)
    visible[torch.from_numpy(layout.order)] = True
    return torch.where(visible, radius, torch.zeros_like(radius))


@dataclass
class CpuRender:
    """Raw outputs of :func:`rasterize_cpu` (wrapped into ``RenderOutput`` by the caller)."""

    rgb: torch.Tensor
    depth: torch.Tensor
    alpha: torch.Tensor
    proj: Projected
    radii: torch.Tensor
    n_isect: int


def rasterize_cpu(
    means, quats_wxyz, log_scales, opacity_logits, sh, cam_from_world, intrinsics, width, height,
    sh_degree, background, near,
) -> CpuRender:  # fmt: skip
    """CPU backend of ``rasterize`` (arguments as there, already validated)."""
    proj = project_gaussians(
        means, quats_wxyz, log_scales, opacity_logits, sh, cam_from_world, intrinsics,
        width, height, sh_degree, near,
    )  # fmt: skip
    half_w, half_h, radius, cutoff = screen_extent(proj.cov2d, proj.opacities, proj.valid)
    layout = _make_layout(proj.means2d, proj.depths, half_w, half_h, radius, cutoff, width, height)
    visible = torch.zeros_like(radius, dtype=torch.bool)
    visible[torch.from_numpy(layout.order)] = True
    rgb, depth, alpha = _RasterizeToPixels.apply(
        proj.means2d, proj.conics, proj.colors, proj.opacities, proj.depths, layout, background,
        width, height,
    )  # fmt: skip
    return CpuRender(
        rgb=rgb,
        depth=depth,
        alpha=alpha,
        proj=proj,
        radii=torch.where(visible, radius, torch.zeros_like(radius)),
        n_isect=int(layout.ids.shape[0]),
    )
