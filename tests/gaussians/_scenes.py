"""Random and hand-made Gaussian scenes shared by the rasterizer tests."""

from __future__ import annotations

import math

import torch

from artitwin_core.geometry import axis_angle_to_matrix, make_se3

WIDTH, HEIGHT = 64, 48
INTRINSICS = (52.0, 50.0, 31.3, 23.7)  # off-centre principal point on purpose


def random_camera(seed: int, dtype=torch.float32) -> torch.Tensor:
    """``[4, 4]`` cam_from_world: a small random rotation and translation."""
    g = torch.Generator().manual_seed(1000 + seed)
    axis = torch.randn(3, generator=g).double().numpy()
    angle = 0.2 * float(torch.rand(1, generator=g))
    rot = axis_angle_to_matrix(axis / (axis**2).sum() ** 0.5, angle)
    trans = (0.1 * torch.randn(3, generator=g)).double().numpy()
    return torch.as_tensor(make_se3(rot, trans)).to(dtype)


def random_scene(
    n: int, seed: int, dtype=torch.float32, sh_degree: int = 3, opacity_shift: float = 0.0
) -> list[torch.Tensor]:
    """``[means, quats, log_scales, opacity_logits, sh]`` requiring grad.

    Most centres are 0.5-3 m in front of a camera near the origin and spread wider than the
    field of view (so some project outside the image), 10 % are behind the camera and 5 % sit
    just beyond the 0.01 m near plane (huge screen footprints). ``opacity_shift`` is added to
    the logits (e.g. +5 for a nearly opaque scene whose pixels stop compositing early).
    """
    g = torch.Generator().manual_seed(seed)
    z = 0.5 + 2.5 * torch.rand(n, generator=g)
    x = (torch.rand(n, generator=g) * 2 - 1) * 0.9 * z
    y = (torch.rand(n, generator=g) * 2 - 1) * 0.7 * z
    means = torch.stack([x, y, z], -1)
    n_behind, n_near = n // 10, n // 20
    means[:n_behind, 2] = -0.5 - torch.rand(n_behind, generator=g)
    means[n_behind : n_behind + n_near, 2] = 0.015 + 0.03 * torch.rand(n_near, generator=g)
    means[n_behind : n_behind + n_near, :2] *= 0.02
    quats = torch.randn(n, 4, generator=g)
    log_scales = math.log(0.05) + 0.5 * torch.randn(n, 3, generator=g)
    logits = 2.0 * torch.randn(n, generator=g) + opacity_shift
    k = (sh_degree + 1) ** 2
    sh = 0.3 * torch.randn(n, k, 3, generator=g)
    return [t.to(dtype).requires_grad_() for t in (means, quats, log_scales, logits, sh)]


def random_loss_weights(seed: int, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Weights of a random linear loss on ``(rgb, depth, alpha)``."""
    g = torch.Generator().manual_seed(2000 + seed)
    return (
        torch.randn(HEIGHT, WIDTH, 3, generator=g).to(dtype),
        torch.randn(HEIGHT, WIDTH, generator=g).to(dtype),
        torch.randn(HEIGHT, WIDTH, generator=g).to(dtype),
    )


def linear_loss(out, weights) -> torch.Tensor:
    w_rgb, w_depth, w_alpha = weights
    return (out.rgb * w_rgb).sum() + (out.depth * w_depth).sum() + (out.alpha * w_alpha).sum()
