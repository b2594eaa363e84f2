"""Closed-form checks of the rasterizer semantics, on both the fast and the reference backend."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from artitwin_core.gaussians import eval_sh_colors, rasterize
from artitwin_core.gaussians._sh import SH_C0, SH_C1, sh_basis

from ._scenes import HEIGHT, INTRINSICS, WIDTH, random_camera, random_scene

BACKENDS = ["cpu", "reference"]


def _gaussian(mean, scale, opacity, rgb, dtype=torch.float64):
    """One isotropic Gaussian with a degree-0 colour ``rgb`` (before the +0.5 / clamp)."""
    sh = (torch.tensor(rgb, dtype=dtype) - 0.5) / SH_C0
    return [
        torch.tensor([mean], dtype=dtype),
        torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=dtype),
        torch.full((1, 3), math.log(scale), dtype=dtype),
        torch.tensor([math.log(opacity / (1 - opacity))], dtype=dtype),
        sh[None, None, :],
    ]


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_gaussian_matches_closed_form(backend: str) -> None:
    fx, fy, cx, cy = 50.0, 55.0, 32.0, 24.0
    z, s, o, rgb = 2.0, 0.04, 0.8, (0.9, 0.2, 0.4)
    # Centre the projection exactly on the centre (31.5, 23.5) of pixel (row 23, col 31).
    u0, v0 = 31.5, 23.5
    x, y = (u0 - cx) * z / fx, (v0 - cy) * z / fy
    params = _gaussian((x, y, z), s, o, rgb)
    out = rasterize(*params, torch.eye(4), (fx, fy, cx, cy), 64, 48, backend=backend)

    # EWA: Sigma2D = J (s^2 I) J^T + 0.3 I with J the pinhole Jacobian at the mean.
    jac = np.array([[fx / z, 0.0, -fx * x / z**2], [0.0, fy / z, -fy * y / z**2]])
    cov = s**2 * jac @ jac.T + 0.3 * np.eye(2)
    conic = np.linalg.inv(cov)
    jj, ii = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5)
    d = np.stack([jj - u0, ii - v0], -1)
    alpha = o * np.exp(-0.5 * np.einsum("hwi,ij,hwj->hw", d, conic, d))
    alpha[alpha < 1 / 255] = 0.0

    # Peak: exactly opacity * colour at the centre pixel, depth opacity * z.
    assert out.rgb[23, 31].detach().numpy() == pytest.approx(o * np.array(rgb), abs=1e-9)
    assert float(out.depth[23, 31]) == pytest.approx(o * z, abs=1e-9)
    # Whole image (float64 kernels: differences are rounding only, measured ~1e-16).
    np.testing.assert_allclose(out.alpha.detach().numpy(), alpha, atol=1e-9)
    np.testing.assert_allclose(out.rgb.detach().numpy(), alpha[..., None] * np.array(rgb), atol=1e-9)
    np.testing.assert_allclose(out.depth.detach().numpy(), alpha * z, atol=1e-9)
    # Footprint: the lit pixels are exactly those inside the 1/255 ellipse (sigma ~1.1-1.2 px
    # here, so the opacity-aware radius sqrt(2 ln(255 o)) ~3.27 sigma covers a few dozen pixels).
    lit = out.alpha.detach().numpy() > 0
    assert lit.sum() == (alpha > 0).sum()
    assert 20 < lit.sum() < 80
    assert out.radii[0] > 0
    assert torch.allclose(out.means2d[0], torch.tensor([u0, v0], dtype=torch.float64))


@pytest.mark.parametrize("backend", BACKENDS)
def test_opaque_front_gaussian_hides_the_one_behind(backend: str) -> None:
    def render(front_opacity: float):
        a = _gaussian((0.0, 0.0, 1.0), 0.2, front_opacity, (1.0, 0.0, 0.0))
        b = _gaussian((0.0, 0.0, 2.0), 0.2, 0.999, (0.0, 1.0, 0.0))
        params = [torch.cat([p, q]).requires_grad_() for p, q in zip(a, b, strict=True)]
        bg = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        intr = (50.0, 50.0, 16.5, 12.5)  # optical axis through the centre of pixel (12, 16)
        return params, rasterize(*params, torch.eye(4), intr, 32, 24, background=bg, backend=backend)

    params, out = render(1.0 - 1e-9)
    centre = out.rgb[12, 16]
    # Front alpha is clamped to 0.999; the back one would take T to 1e-6 < 1e-4, so the pixel
    # stops before it: colour = 0.999 * red + T_final * blue background, with T_final = 0.001.
    assert centre.detach().numpy() == pytest.approx([0.999, 0.0, 0.001], abs=1e-12)
    assert float(out.alpha.detach()[12, 16]) == pytest.approx(0.999, abs=1e-12)
    # And the hidden Gaussian gets no gradient from that pixel.
    centre.sum().backward()
    assert float(params[4].grad[1].abs().max()) == 0.0
    assert float(params[4].grad[0].abs().max()) > 0.1
    # Around the centre the front alpha drops a little, letting < 2 % of green through.
    assert float(out.rgb.detach()[11:14, 15:18, 1].max()) < 0.02

    # Not vacuous: with a faint front Gaussian the green one shows.
    _, out = render(0.05)
    assert float(out.rgb.detach()[12, 16, 1]) > 0.8


@pytest.mark.parametrize("backend", BACKENDS)
def test_sh_degree_0_and_3_agree_when_higher_bands_vanish(backend: str) -> None:
    params = random_scene(100, seed=3)
    with torch.no_grad():
        params[4][:, 1:] = 0.0
    cam = random_camera(3)
    out3 = rasterize(*params, cam, INTRINSICS, WIDTH, HEIGHT, backend=backend)
    out0 = rasterize(*params, cam, INTRINSICS, WIDTH, HEIGHT, sh_degree=0, backend=backend)
    dc_only = params[:4] + [params[4][:, :1]]
    out1 = rasterize(*dc_only, cam, INTRINSICS, WIDTH, HEIGHT, backend=backend)
    assert float(out3.alpha.detach().mean()) > 0.1
    # Identical maths up to float32 summation order (measured 0).
    assert torch.allclose(out3.rgb, out0.rgb, atol=1e-6)
    assert torch.allclose(out0.rgb, out1.rgb, atol=1e-6)

    # With non-zero higher bands, degree 3 differs from degree 0 (the bands are used) ...
    params = random_scene(100, seed=3)
    out3 = rasterize(*params, cam, INTRINSICS, WIDTH, HEIGHT, backend=backend)
    out0 = rasterize(*params, cam, INTRINSICS, WIDTH, HEIGHT, sh_degree=0, backend=backend)
    assert float((out3.rgb - out0.rgb).abs().max()) > 0.05
    # ... and sh_degree=0 ignores them exactly.
    out1 = rasterize(*params[:4], params[4][:, :1], cam, INTRINSICS, WIDTH, HEIGHT, backend=backend)
    assert torch.allclose(out0.rgb, out1.rgb, atol=1e-6)


def test_sh_basis_is_orthonormal() -> None:
    # Fibonacci-sphere quadrature: sum over 20k near-uniform directions of Y_i Y_j * 4 pi / n
    # integrates degree <= 6 products to ~1e-5; a wrong constant or sign pattern breaks it.
    n = 20000
    k = torch.arange(n, dtype=torch.float64) + 0.5
    zc = 1 - 2 * k / n
    phi = math.pi * (1 + 5**0.5) * k
    r = torch.sqrt(1 - zc**2)
    dirs = torch.stack([r * torch.cos(phi), r * torch.sin(phi), zc], -1)
    basis = sh_basis(dirs, 3)
    gram = basis.T @ basis * (4 * math.pi / n)
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=1e-3)


def test_sh_degree_1_closed_form() -> None:
    sh = torch.zeros(3, 4, 3, dtype=torch.float64)
    sh[:, 0] = 0.2
    sh[:, 1:4] = torch.tensor([0.3, -0.1, 0.7], dtype=torch.float64)[:, None]
    dirs = torch.tensor([[1.0, 0, 0], [0, 2.0, 0], [0, 0, 0.5]], dtype=torch.float64)
    got = eval_sh_colors(sh, dirs, 1)[:, 0]
    # 3DGS: C0 sh0 - C1 y sh1 + C1 z sh2 - C1 x sh3 + 0.5 at unit directions.
    want = [
        SH_C0 * 0.2 - SH_C1 * 0.7 + 0.5,
        SH_C0 * 0.2 - SH_C1 * 0.3 + 0.5,
        SH_C0 * 0.2 + SH_C1 * -0.1 + 0.5,
    ]
    assert got.numpy() == pytest.approx(want, abs=1e-12)


def test_background_shows_where_nothing_is_drawn() -> None:
    params = random_scene(60, seed=4)
    bg = torch.tensor([0.25, 0.5, 0.75])
    out = rasterize(*params, random_camera(4), INTRINSICS, WIDTH, HEIGHT, background=bg, backend="cpu")
    empty = out.alpha.detach() == 0
    assert 0 < int(empty.sum()) < HEIGHT * WIDTH
    assert torch.equal(out.rgb.detach()[empty], bg.expand(int(empty.sum()), 3))
    assert torch.all(out.depth.detach()[empty] == 0)
    assert out.backend == "cpu"
    # auto picks the CPU backend for CPU tensors and renders the same image.
    out_auto = rasterize(*params, random_camera(4), INTRINSICS, WIDTH, HEIGHT, background=bg)
    assert out_auto.backend == "cpu"
    assert torch.equal(out_auto.rgb, out.rgb)


def test_bad_inputs_are_rejected_with_a_message() -> None:
    params = random_scene(10, seed=0)
    cam = random_camera(0)
    with pytest.raises(ValueError, match="log_scales"):
        rasterize(params[0], params[1], params[2][:, :2], *params[3:], cam, INTRINSICS, 8, 8)
    with pytest.raises(ValueError, match="sh_degree"):
        rasterize(*params[:4], params[4][:, :4], cam, INTRINSICS, 8, 8, sh_degree=2)
    with pytest.raises(ValueError, match="backend"):
        rasterize(*params, cam, INTRINSICS, 8, 8, backend="opengl")
    with pytest.raises(ValueError, match="SH coefficients"):
        rasterize(*params[:4], params[4][:, :5], cam, INTRINSICS, 8, 8)
