"""A stand-in for gsplat's ``rasterization`` that runs on CPU (see test_raster_cuda_mapping).

It implements gsplat's documented contract (activated scales and opacities, ``viewmats [C, 4, 4]``,
``Ks [C, 3, 3]``, SH colours with ``sh_degree``, ``render_mode="RGB+D"`` appending accumulated
depth as a last channel, ``backgrounds [C, 3]``, ``packed=False`` meta with ``means2d [C, N, 2]``
and per-axis ``radii [C, N, 2]``) by undoing the activations and calling our dense reference, so
the code above the rasterizer can run its CUDA path on a machine without a GPU.
"""

from __future__ import annotations

import torch

from artitwin_core.gaussians._raster_reference import rasterize_reference

CALLS: list[dict] = []


def _fake_rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, **kw):
    CALLS.append(kw)
    assert kw["render_mode"] == "RGB+D" and kw["packed"] is False and kw["eps2d"] == 0.3
    k = Ks[0]
    intr = (float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]))
    logits = torch.log(opacities / (1 - opacities))
    rgb, depth, alpha, means2d, depths, valid = rasterize_reference(
        means, quats, torch.log(scales), logits, colors, viewmats[0], intr, width, height,
        kw["sh_degree"], kw["backgrounds"][0], kw["near_plane"],
    )  # fmt: skip
    # Like gsplat, the image is composited from the very means2d tensor handed back in meta.
    m2d = means2d[None]
    shift = (m2d - m2d.detach()).sum() * 0.0
    render = torch.cat([rgb, depth[..., None]], -1)[None] + shift
    radii = torch.where(valid, 3, 0)[None, :, None].expand(1, -1, 2).to(torch.int32)
    meta = {"means2d": m2d, "radii": radii, "depths": depths[None]}
    return render, alpha[None, ..., None], meta


