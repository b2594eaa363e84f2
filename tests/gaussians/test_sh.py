"""The numba SH colour kernels against the torch SH evaluation (values and both gradients)."""

from __future__ import annotations

import pytest
import torch

from artitwin_core.gaussians import eval_sh_colors
from artitwin_core.gaussians._sh_cpu import eval_sh_colors_cpu


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_numba_sh_matches_torch(degree: int) -> None:
    g = torch.Generator().manual_seed(degree)
    sh = torch.randn(400, 16, 3, generator=g, dtype=torch.float64).requires_grad_()
    dirs = (3 * torch.randn(400, 3, generator=g, dtype=torch.float64)).requires_grad_()
    w = torch.randn(400, 3, generator=g, dtype=torch.float64)
    ref = eval_sh_colors(sh, dirs, degree)
    got = eval_sh_colors_cpu(sh, dirs, degree)
    assert 0.01 < float((ref == 0).double().mean()) < 0.6  # the clamp at 0 is exercised
    # float64: identical maths up to rounding (measured <= 2e-15).
    assert torch.allclose(got, ref, atol=1e-12, rtol=0)
    g_ref = torch.autograd.grad((ref * w).sum(), [sh, dirs], allow_unused=True)
    g_got = torch.autograd.grad((got * w).sum(), [sh, dirs])
    assert torch.allclose(g_got[0], g_ref[0], atol=1e-12, rtol=0)
    if degree == 0:  # the DC term does not depend on the view direction
        assert g_ref[1] is None and torch.all(g_got[1] == 0)
    else:
        assert float(g_ref[1].abs().max()) > 0.1
        assert torch.allclose(g_got[1], g_ref[1], atol=1e-12, rtol=0)
