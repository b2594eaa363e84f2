"""CUDA backend: a thin mapping of ``rasterize``'s arguments onto gsplat's ``rasterization``.

gsplat is optional (it needs a CUDA toolchain); it is imported lazily so the CPU paths never
require it. We ask gsplat for ``"RGB+D"`` (accumulated depth ``sum w_i z_i``) rather than
``"RGB+ED"`` so every backend returns the same un-normalised depth, and ``packed=False`` so the
2D means come back as one ``[N, 2]`` tensor whose gradient can be retained for densification.
"""

from __future__ import annotations

import torch


def gsplat_available() -> bool:
    """True when a CUDA device is visible and gsplat imports."""
    if not torch.cuda.is_available():
        return False
    try:
        import gsplat  # noqa: F401
    except ImportError:
        return False
    return True


def rasterize_cuda(
    means, quats_wxyz, log_scales, opacity_logits, sh, cam_from_world, intrinsics, width, height,
    sh_degree, background, near,
):  # fmt: skip
    """Returns ``(rgb [H, W, 3], depth [H, W], alpha [H, W], means2d [1, N, 2], radii [N], depths [N])``.

    ``means2d`` is gsplat's own tensor (the one its rasterizer consumes), so a retained gradient
    on it is the screen-space gradient used by densification.
    """
    from gsplat import rasterization

    fx, fy, cx, cy = (float(v) for v in intrinsics)
    dev, dt = means.device, means.dtype
    ks = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=dt, device=dev)[None]
    colors, alphas, meta = rasterization(
        means=means,
        quats=quats_wxyz,
        scales=torch.exp(log_scales),
        opacities=torch.sigmoid(opacity_logits),
        colors=sh,
        viewmats=cam_from_world[None],
        Ks=ks,
        width=width,
        height=height,
        near_plane=near,
        eps2d=0.3,
        sh_degree=sh_degree,
        packed=False,
        tile_size=16,
        backgrounds=background[None],
        render_mode="RGB+D",
        rasterize_mode="classic",
    )
    rgb = colors[0, ..., :3]
    depth = colors[0, ..., 3]
    alpha = alphas[0, ..., 0]
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 reports per-axis (x, y) radii; culled = any zero
        radii = torch.where((radii > 0).all(dim=-1), radii.max(dim=-1).values, 0)
    return rgb, depth, alpha, meta["means2d"], radii.to(dt), meta["depths"][0]
