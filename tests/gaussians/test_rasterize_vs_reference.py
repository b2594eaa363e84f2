"""The numba CPU rasterizer against the dense torch reference on random scenes.

Tolerances were measured on these cases (float32, 64x48, N = 50-300; `PYTHONPATH=. python`
printing the max differences): forward max |diff| <= 2.4e-6 (rgb, alpha) and <= 6.7e-6 m (depth);
gradient max |diff| relative to the largest reference gradient entry of each input <= 8.7e-6.
The bounds below leave ~10x margin for summation-order noise across machines while still
catching any wrong term (a missing factor, sign or skipped pixel gives O(1e-2..1)). Two nearly
opaque cases make hundreds of pixels stop compositing at T < 1e-4, exercising early termination.
"""

from __future__ import annotations

import pytest
import torch

from artitwin_core.gaussians import rasterize

from ._scenes import HEIGHT, INTRINSICS, WIDTH, linear_loss, random_camera, random_loss_weights, random_scene

# (seed, N, opacity logit shift): shift 4-6 makes pixels reach the T < 1e-4 stop.
CASES = [
    (0, 50, 0.0),
    (1, 120, 0.0),
    (2, 200, 0.0),
    (3, 300, 0.0),
    (5, 80, 0.0),
    (7, 300, 6.0),
    (11, 300, 4.0),
]
NAMES = ["means", "quats_wxyz", "log_scales", "opacity_logits", "sh", "cam_from_world"]


def _render_and_grads(backend: str, seed: int, n: int, shift: float):
    params = random_scene(n, seed, opacity_shift=shift)
    cam = random_camera(seed).requires_grad_()
    bg = torch.tensor([0.1, 0.3, 0.2])
    out = rasterize(*params, cam, INTRINSICS, WIDTH, HEIGHT, background=bg, backend=backend)
    grads = torch.autograd.grad(linear_loss(out, random_loss_weights(seed)), [*params, cam])
    return out, grads


@pytest.mark.parametrize(("seed", "n", "shift"), CASES)
def test_cpu_matches_reference(seed: int, n: int, shift: float) -> None:
    fast, g_fast = _render_and_grads("cpu", seed, n, shift)
    ref, g_ref = _render_and_grads("reference", seed, n, shift)

    # The scene must actually exercise the renderer: some coverage, some culling.
    assert 0.05 < float(ref.alpha.detach().mean()) < 0.999
    if shift > 0:  # nearly opaque: many pixels must hit the T < 1e-4 stop (measured 200+)
        assert int((1.0 - ref.alpha.detach() < 1.2e-4).sum()) > 100
    assert 0 < int((fast.radii > 0).sum()) < n

    # Forward: measured max |diff| <= 2.4e-6 (rgb, alpha), <= 6.7e-6 m (depth).
    assert torch.allclose(fast.rgb, ref.rgb, atol=2e-5, rtol=0)
    assert torch.allclose(fast.alpha, ref.alpha, atol=2e-5, rtol=0)
    assert torch.allclose(fast.depth, ref.depth, atol=6e-5, rtol=0)
    vis = fast.radii > 0
    assert torch.allclose(fast.means2d[vis], ref.means2d[vis], atol=1e-3, rtol=0)

    for name, a, b in zip(NAMES, g_fast, g_ref, strict=True):
        scale = float(b.abs().max())
        assert scale > 0, f"{name}: reference gradient is identically zero"
        err = float((a - b).abs().max())
        # Measured err / scale <= 8.7e-6 over these cases.
        assert err <= 1e-4 * scale, f"{name}: max |grad diff| {err:.3g} vs scale {scale:.3g}"


def test_means2d_gradient_for_densification() -> None:
    seed, n = 2, 150
    outs = []
    for backend in ("cpu", "reference"):
        params = random_scene(n, seed)
        out = rasterize(*params, random_camera(seed), INTRINSICS, WIDTH, HEIGHT, backend=backend)
        out.retain_means2d_grad()
        linear_loss(out, random_loss_weights(seed)).backward()
        outs.append(out)
    fast, ref = outs
    vis = fast.visible
    g_fast, g_ref = fast.means2d_grad, ref.means2d_grad
    assert g_fast.shape == (n, 2)
    # Culled Gaussians (behind the camera, off-screen) get exactly zero screen-space gradient.
    assert torch.all(g_fast[~vis] == 0)
    assert torch.all(g_ref[~vis].abs() < 1e-6)  # the reference composites everything; all ~0 there
    scale = float(g_ref.abs().max())
    assert float((g_fast - g_ref).abs().max()) <= 1e-4 * scale  # measured ~1e-6 * scale
    # Behind-camera Gaussians (first 10 %) are never visible.
    assert not bool(vis[: n // 10].any())


def test_odd_image_size_and_degenerate_scenes() -> None:
    # 50x37 leaves partial tiles on the right and bottom edges.
    width, height = 50, 37
    outs = []
    for backend in ("cpu", "reference"):
        params = random_scene(150, seed=2)
        out = rasterize(*params, random_camera(2), INTRINSICS, width, height, backend=backend)
        w = torch.randn(height, width, 3, generator=torch.Generator().manual_seed(1))
        outs.append((out, torch.autograd.grad((out.rgb * w).sum() + out.depth.sum(), params)))
    (fast, g_fast), (ref, g_ref) = outs
    assert torch.equal(fast.radii > 0, ref.radii > 0)  # same culling rule reported
    assert torch.allclose(fast.rgb, ref.rgb, atol=2e-5, rtol=0)  # measured 6e-7
    assert torch.allclose(fast.depth, ref.depth, atol=6e-5, rtol=0)
    for a, b in zip(g_fast, g_ref, strict=True):
        assert float((a - b).abs().max()) <= 1e-4 * float(b.abs().max())  # measured <= 1.4e-5

    # No Gaussians at all, and only Gaussians behind the camera: background, zero gradients.
    bg = torch.tensor([0.1, 0.2, 0.3])
    empty = [torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 16, 3)]
    out = rasterize(*empty, torch.eye(4), INTRINSICS, width, height, background=bg)
    assert torch.equal(out.rgb, bg.expand(height, width, 3)) and float(out.alpha.abs().max()) == 0
    behind = random_scene(20, seed=0)
    with torch.no_grad():
        behind[0][:, 2] = -1.0
    out = rasterize(*behind, torch.eye(4), INTRINSICS, width, height, background=bg)
    out.rgb.sum().backward()
    assert torch.equal(out.rgb.detach(), bg.expand(height, width, 3))
    assert all(float(p.grad.abs().max()) == 0 for p in behind)
