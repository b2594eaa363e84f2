"""``rasterize``: one entry point for the differentiable 3DGS rasterizer and its backends.

Semantics are those of 3DGS / gsplat ("classic" mode): EWA projection with a 0.3 px^2 low-pass
dilation, front-to-back compositing with ``alpha = min(0.999, o exp(-d^T Sigma^-1 d / 2))``,
contributions with alpha < 1/255 skipped, a pixel stopped before its transmittance would reach
1e-4, and colours ``clamp(SH(view dir) + 0.5, min=0)``. Backends:

- ``"cpu"``: torch projection + numba tile rasterizer with a hand-written backward (2 cores OK).
- ``"reference"``: dense torch, every Gaussian at every pixel; tests only (small N and images).
- ``"cuda"``: gsplat's ``rasterization`` (needs a CUDA device and the optional gsplat package).
- ``"auto"``: ``"cuda"`` when ``means`` is on a CUDA device, else ``"cpu"``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from artitwin_core.gaussians._sh import sh_degree_from_bases

BACKENDS = ("auto", "cpu", "reference", "cuda")


@dataclass
class RenderOutput:
    """One rendered view.

    Attributes:
        rgb: ``[H, W, 3]`` composited colour, including ``(1 - alpha) * background``.
        depth: ``[H, W]`` accumulated depth ``sum_i w_i z_i`` in metres, NOT normalised: divide
            by ``alpha`` for the expected depth of the covered part (:meth:`expected_depth`).
            Using the un-normalised sum keeps every backend identical and its gradient simple.
        alpha: ``[H, W]`` accumulated opacity ``1 - T_final``.
        means2d: ``[N, 2]`` projected centres, pixels (pixel (i, j) has its centre at
            ``(j + 0.5, i + 0.5)``); meaningful where ``radii > 0``.
        radii: ``[N]`` float pixel radius of the footprint's bounding circle (opacity-aware,
            at most 3.33 sigma); 0 for Gaussians culled in this view (behind the near plane,
            off-screen, or too faint to ever reach alpha 1/255).
        depths: ``[N]`` camera-space z of the centres, metres.
        backend: the backend that produced it (``"cpu"``, ``"reference"`` or ``"cuda"``).
    """

    rgb: torch.Tensor
    depth: torch.Tensor
    alpha: torch.Tensor
    means2d: torch.Tensor
    radii: torch.Tensor
    depths: torch.Tensor
    backend: str
    # The tensor that the compositor consumes (``[N, 2]``, or gsplat's ``[1, N, 2]``).
    _means2d_graph: torch.Tensor = field(repr=False, default=None)

    @property
    def visible(self) -> torch.Tensor:
        """``[N]`` bool, Gaussians that reached the compositor in this view."""
        return self.radii > 0

    def retain_means2d_grad(self) -> None:
        """Keep dL/d``means2d`` after ``backward()`` (call before it), for densification."""
        if self._means2d_graph is not None and self._means2d_graph.requires_grad:
            self._means2d_graph.retain_grad()

    @property
    def means2d_grad(self) -> torch.Tensor | None:
        """``[N, 2]`` dL/d``means2d`` in 1/pixel units after ``backward()`` (zero rows for culled
        Gaussians), or None if :meth:`retain_means2d_grad` was not called or nothing required grad.
        The 3DGS densification statistic is the norm of this, averaged over the views a Gaussian
        was visible in (3DGS measures it in NDC: multiply x by W/2 and y by H/2 to match).
        """
        g = None if self._means2d_graph is None else self._means2d_graph.grad
        if g is None:
            return None
        return g[0] if g.dim() == 3 else g

    def expected_depth(self, min_alpha: float = 1e-6) -> torch.Tensor:
        """``[H, W]`` depth / alpha in metres (0 where alpha < ``min_alpha``)."""
        return torch.where(self.alpha >= min_alpha, self.depth / self.alpha.clamp_min(min_alpha), 0.0)


def _check(name: str, t: torch.Tensor, shape: tuple, n: int | None = None) -> None:
    if not isinstance(t, torch.Tensor):
        raise TypeError(f"rasterize: {name} must be a torch.Tensor, got {type(t).__name__}")
    ok = t.dim() == len(shape) and all(s is None or s == d for s, d in zip(shape, t.shape, strict=True))
    if not ok:
        want = "[" + ", ".join("N" if s is None else str(s) for s in shape) + "]"
        raise ValueError(f"rasterize: {name} has shape {list(t.shape)}, expected {want}")
    if n is not None and t.shape[0] != n:
        raise ValueError(f"rasterize: {name} has {t.shape[0]} rows, means has {n}")


def rasterize(
    means: torch.Tensor,
    quats_wxyz: torch.Tensor,
    log_scales: torch.Tensor,
    opacity_logits: torch.Tensor,
    sh: torch.Tensor,
    cam_from_world: torch.Tensor | np.ndarray,
    intrinsics: tuple[float, float, float, float],
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    background: torch.Tensor | None = None,
    backend: str = "auto",
    near: float = 0.01,
) -> RenderOutput:
    """Render N 3D Gaussians into one pinhole camera, differentiably.

    Args:
        means: ``[N, 3]`` world centres, metres.
        quats_wxyz: ``[N, 4]`` rotations, scalar first, any norm.
        log_scales: ``[N, 3]`` natural log of per-axis standard deviations, log metres.
        opacity_logits: ``[N]`` logits of opacity.
        sh: ``[N, K, 3]`` SH coefficients, K = (d + 1)^2 for d in 0..3 (3DGS layout).
        cam_from_world: ``[4, 4]`` rigid transform, OpenCV camera axes (x right, y down,
            z forward). A tensor that requires grad receives a gradient on the cpu and
            reference backends.
        intrinsics: ``(fx, fy, cx, cy)`` pixels; pixel (i, j)'s centre is ``(j + 0.5, i + 0.5)``.
        width, height: image size, pixels.
        sh_degree: degree to evaluate (default: the one K holds); may be lower than K's.
        background: ``[3]`` colour behind everything (default black).
        backend: ``"auto"``, ``"cpu"``, ``"reference"`` or ``"cuda"`` (module docstring).
        near: near plane in metres; Gaussians with centre z < near are culled.

    Returns:
        :class:`RenderOutput`. Gradients flow from ``rgb``, ``depth`` and ``alpha`` to means,
        quats, log_scales, opacity_logits and sh (float32 or float64; cpu and reference).
    """
    if backend not in BACKENDS:
        raise ValueError(f"rasterize: backend {backend!r} is not one of {BACKENDS}")
    _check("means", means, (None, 3))
    n = means.shape[0]
    _check("quats_wxyz", quats_wxyz, (None, 4), n)
    _check("log_scales", log_scales, (None, 3), n)
    _check("opacity_logits", opacity_logits, (None,), n)
    _check("sh", sh, (None, None, 3), n)
    k_degree = sh_degree_from_bases(sh.shape[1])
    if sh_degree is None:
        sh_degree = k_degree
    if not 0 <= sh_degree <= k_degree:
        raise ValueError(f"rasterize: sh_degree={sh_degree} but sh holds degree {k_degree}")
    if len(intrinsics) != 4:
        raise ValueError("rasterize: intrinsics must be (fx, fy, cx, cy)")
    if width <= 0 or height <= 0:
        raise ValueError(f"rasterize: image size {width}x{height} must be positive")
    dtype, device = means.dtype, means.device
    if not isinstance(cam_from_world, torch.Tensor):
        cam_from_world = torch.as_tensor(np.asarray(cam_from_world))
    _check("cam_from_world", cam_from_world, (4, 4))
    cam_from_world = cam_from_world.to(dtype=dtype, device=device)
    if background is None:
        background = torch.zeros(3, dtype=dtype, device=device)
    else:
        background = torch.as_tensor(background).to(dtype=dtype, device=device).reshape(3)

    if backend == "auto":
        backend = "cuda" if means.is_cuda else "cpu"
    args = (
        means, quats_wxyz, log_scales, opacity_logits, sh, cam_from_world, intrinsics,
        int(width), int(height), sh_degree, background, float(near),
    )  # fmt: skip
    if backend == "cpu":
        from artitwin_core.gaussians._raster_cpu import rasterize_cpu

        if means.is_cuda:
            raise ValueError("rasterize: backend 'cpu' needs CPU tensors; use backend='cuda'")
        r = rasterize_cpu(*args)
        return RenderOutput(
            rgb=r.rgb, depth=r.depth, alpha=r.alpha, means2d=r.proj.means2d, radii=r.radii,
            depths=r.proj.depths, backend="cpu", _means2d_graph=r.proj.means2d,
        )  # fmt: skip
    if backend == "reference":
        from artitwin_core.gaussians._project import project_gaussians
        from artitwin_core.gaussians._raster_cpu import visible_radii
        from artitwin_core.gaussians._raster_reference import rasterize_reference

        rgb, depth, alpha, means2d, depths, _ = rasterize_reference(*args)
        with torch.no_grad():  # radii for API parity, by the CPU backend's culling rule
            p = project_gaussians(*args[:10], float(near), numba_sh=False)
            radii = visible_radii(p, int(width), int(height))
        return RenderOutput(
            rgb=rgb, depth=depth, alpha=alpha, means2d=means2d, radii=radii, depths=depths,
            backend="reference", _means2d_graph=means2d,
        )  # fmt: skip
    from artitwin_core.gaussians._raster_cuda import gsplat_available, rasterize_cuda

    if not gsplat_available():
        raise RuntimeError(
            "rasterize: backend 'cuda' needs a CUDA device and the gsplat package "
            "(pip install gsplat); use backend='cpu' otherwise"
        )
    rgb, depth, alpha, means2d_graph, radii, depths = rasterize_cuda(*args)
    return RenderOutput(
        rgb=rgb, depth=depth, alpha=alpha, means2d=means2d_graph[0], radii=radii, depths=depths,
        backend="cuda", _means2d_graph=means2d_graph,
    )  # fmt: skip
