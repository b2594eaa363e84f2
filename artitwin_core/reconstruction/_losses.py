"""Image losses and metrics of 3DGS training: L1, SSIM (11x11 Gaussian window), PSNR, depth L1."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

_SSIM_C1 = 0.01**2
_SSIM_C2 = 0.03**2


def _gauss_window(size: int, sigma: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    x = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def ssim(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean structural similarity of two images, as in the 3DGS code (zero padding, same size).

    Args:
        a, b: ``[H, W, C]`` images with values in [0, 1].

    Returns:
        scalar tensor, 1 for identical images; differentiable in both.
    """
    c = a.shape[-1]
    x = a.permute(2, 0, 1)[None]
    y = b.permute(2, 0, 1)[None]
    g = _gauss_window(window, sigma, a.dtype, a.device)
    # Separable blur: a row pass then a column pass, one group per channel.
    kr = g.view(1, 1, 1, -1).expand(c, 1, 1, window)
    kc = g.view(1, 1, -1, 1).expand(c, 1, window, 1)
    pad = window // 2

    def blur(t: torch.Tensor) -> torch.Tensor:
        t = F.conv2d(t, kr, padding=(0, pad), groups=c)
        return F.conv2d(t, kc, padding=(pad, 0), groups=c)

    mu_x, mu_y = blur(x), blur(y)
    sxx = blur(x * x) - mu_x**2
    syy = blur(y * y) - mu_y**2
    sxy = blur(x * y) - mu_x * mu_y
    num = (2 * mu_x * mu_y + _SSIM_C1) * (2 * sxy + _SSIM_C2)
    den = (mu_x**2 + mu_y**2 + _SSIM_C1) * (sxx + syy + _SSIM_C2)
    return (num / den).mean()


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """Peak signal-to-noise ratio in dB of two images with values in [0, 1] (any equal shapes)."""
    mse = float(torch.mean((a.clamp(0, 1) - b.clamp(0, 1)) ** 2))
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def photometric_loss(render: torch.Tensor, target: torch.Tensor, lambda_dssim: float) -> torch.Tensor:
    """``(1 - lambda) L1 + lambda (1 - SSIM)`` of ``[H, W, 3]`` images in [0, 1]."""
    l1 = (render - target).abs().mean()
    if lambda_dssim == 0:
        return l1
    return (1 - lambda_dssim) * l1 + lambda_dssim * (1 - ssim(render, target))


def depth_l1(expected_depth: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Confidence-weighted mean |rendered - sensor| depth in metres over valid pixels.

    Args:
        expected_depth: ``[H, W]`` rendered depth normalised by alpha, metres.
        target: ``[H, W]`` sensor depth resampled to the render grid, metres (any value where
            ``weight`` is 0).
        weight: ``[H, W]`` per-pixel confidence weight, 0 where there is no valid measurement.
    """
    wsum = weight.sum()
    if float(wsum) <= 0:
        return expected_depth.sum() * 0.0
    return (weight * (expected_depth - target).abs()).sum() / wsum
