"""Argument mapping of the gsplat backend, checked on CPU against a stand-in ``gsplat`` module.

No GPU or gsplat is needed: the stand-in implements gsplat's documented ``rasterization``
contract (activated scales and opacities, ``viewmats [C, 4, 4]``, ``Ks [C, 3, 3]``, SH colours
with ``sh_degree``, ``render_mode="RGB+D"`` appending accumulated depth as a last channel,
``backgrounds [C, 3]``, ``packed=False`` meta with ``means2d [C, N, 2]`` and per-axis
``radii [C, N, 2]``) by undoing the activations and calling our dense reference. So this test
fails if ``rasterize_cuda`` passes a parameter in the wrong form, slices the outputs wrongly or
loses the screen-space gradient, but says nothing about gsplat itself (test_rasterize_cuda does).
"""

from __future__ import annotations

import sys
import types

import torch

from artitwin_core.gaussians._raster_cuda import rasterize_cuda
from artitwin_core.gaussians._raster_reference import rasterize_reference

from ._fake_gsplat import CALLS, _fake_rasterization
from ._scenes import HEIGHT, INTRINSICS, WIDTH, random_camera, random_scene


def test_gsplat_arguments_are_mapped(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "gsplat", types.SimpleNamespace(rasterization=_fake_rasterization))
    params = random_scene(80, seed=1)
    cam = random_camera(1)
    bg = torch.tensor([0.2, 0.4, 0.1])
    rgb, depth, alpha, m2d_graph, radii, depths = rasterize_cuda(
        *params, cam, INTRINSICS, WIDTH, HEIGHT, 3, bg, 0.01
    )
    ref = rasterize_reference(*params, cam, INTRINSICS, WIDTH, HEIGHT, 3, bg, 0.01)
    assert CALLS and CALLS[-1]["sh_degree"] == 3 and CALLS[-1]["near_plane"] == 0.01
    assert rgb.shape == (HEIGHT, WIDTH, 3) and depth.shape == (HEIGHT, WIDTH)
    assert alpha.shape == (HEIGHT, WIDTH) and radii.shape == (80,)
    # exp / sigmoid round trips in float32: measured ~1e-6.
    assert torch.allclose(rgb, ref[0], atol=1e-4)
    assert torch.allclose(depth, ref[1], atol=1e-4)
    assert torch.allclose(alpha, ref[2], atol=1e-4)
    assert torch.equal(radii > 0, ref[5])
    assert m2d_graph.shape == (1, 80, 2)
    m2d_graph.retain_grad()
    (rgb.sum() + depth.sum()).backward()
    assert m2d_graph.grad is not None and m2d_graph.grad.shape == (1, 80, 2)
    assert all(p.grad is not None and float(p.grad.abs().max()) > 0 for p in params)
