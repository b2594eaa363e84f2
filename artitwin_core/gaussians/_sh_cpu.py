"""SH colour evaluation as one numba kernel pair (forward, backward) behind an autograd Function.

The torch version in ``_sh`` builds a ``[N, 16]`` basis from ~40 column ops and contracts it with
a batched matmul; with autograd that was ~10 ms per view for 20k Gaussians on one core, more than
the rest of the projection. Here each Gaussian is one loop iteration with the basis, its
derivative w.r.t. the unit view direction, and the normalisation's Jacobian written out. The torch
version stays the reference (the dense backend uses it), so the backend comparison tests check
this kernel, gradients included. The kernels are serial on purpose: at ~0.1 us per Gaussian a
thread-pool round trip costs more than it saves.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit

from artitwin_core.gaussians._sh import SH_C0, SH_C1, SH_C2, SH_C3

_FM = {"nsz", "arcp", "contract", "afn", "reassoc"}


@njit(inline="always", fastmath=_FM)
def _basis(x, y, z, degree, b):
    b[0] = SH_C0
    if degree >= 1:
        b[1] = -SH_C1 * y
        b[2] = SH_C1 * z
        b[3] = -SH_C1 * x
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        b[4] = SH_C2[0] * x * y
        b[5] = SH_C2[1] * y * z
        b[6] = SH_C2[2] * (2.0 * zz - xx - yy)
        b[7] = SH_C2[3] * x * z
        b[8] = SH_C2[4] * (xx - yy)
    if degree >= 3:
        b[9] = SH_C3[0] * y * (3.0 * xx - yy)
        b[10] = SH_C3[1] * x * y * z
        b[11] = SH_C3[2] * y * (4.0 * zz - xx - yy)
        b[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
        b[13] = SH_C3[4] * x * (4.0 * zz - xx - yy)
        b[14] = SH_C3[5] * z * (xx - yy)
        b[15] = SH_C3[6] * x * (xx - 3.0 * yy)


@njit(cache=True, fastmath=_FM)
def sh_forward(sh: np.ndarray, dirs: np.ndarray, degree: int, out: np.ndarray) -> None:
    """``out [N, 3] = clamp(sum_k basis_k(dir / |dir|) sh[:, k] + 0.5, min=0)``."""
    n = sh.shape[0]
    nb = (degree + 1) * (degree + 1)
    for i in range(n):
        b = np.empty(16, np.float64)
        dx, dy, dz = float(dirs[i, 0]), float(dirs[i, 1]), float(dirs[i, 2])
        inv = 1.0 / max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
        _basis(dx * inv, dy * inv, dz * inv, degree, b)
        for c in range(3):
            acc = 0.0
            for k in range(nb):
                acc += b[k] * sh[i, k, c]
            out[i, c] = max(acc + 0.5, 0.0)


@njit(cache=True, fastmath=_FM)
def sh_backward(
    sh: np.ndarray, dirs: np.ndarray, degree: int, colors: np.ndarray, g_colors: np.ndarray,
    g_sh: np.ndarray, g_dirs: np.ndarray,
) -> None:  # fmt: skip
    """Gradients w.r.t. ``sh [N, K, 3]`` and the un-normalised ``dirs [N, 3]``.

    ``colors`` are the forward outputs: a channel clamped to 0 passes no gradient (as torch's
    ``clamp_min``, except for pre-clamp values of exactly 0).
    """
    n = sh.shape[0]
    nb = (degree + 1) * (degree + 1)
    for i in range(n):
        b = np.empty(16, np.float64)
        dx, dy, dz = float(dirs[i, 0]), float(dirs[i, 1]), float(dirs[i, 2])
        norm = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
        inv = 1.0 / norm
        x, y, z = dx * inv, dy * inv, dz * inv
        _basis(x, y, z, degree, b)
        g0 = float(g_colors[i, 0]) if colors[i, 0] > 0 else 0.0
        g1 = float(g_colors[i, 1]) if colors[i, 1] > 0 else 0.0
        g2 = float(g_colors[i, 2]) if colors[i, 2] > 0 else 0.0
        for k in range(nb):
            g_sh[i, k, 0] = b[k] * g0
            g_sh[i, k, 1] = b[k] * g1
            g_sh[i, k, 2] = b[k] * g2
        for k in range(nb, sh.shape[1]):
            g_sh[i, k, 0] = 0.0
            g_sh[i, k, 1] = 0.0
            g_sh[i, k, 2] = 0.0
        if degree == 0:
            g_dirs[i, 0] = 0.0
            g_dirs[i, 1] = 0.0
            g_dirs[i, 2] = 0.0
            continue
        # gb[k] = dL/d basis_k
        gb = np.empty(16, np.float64)
        for k in range(nb):
            gb[k] = sh[i, k, 0] * g0 + sh[i, k, 1] * g1 + sh[i, k, 2] * g2
        # dL/d(unit direction), basis derivatives written out per band.
        ux = -SH_C1 * gb[3]
        uy = -SH_C1 * gb[1]
        uz = SH_C1 * gb[2]
        if degree >= 2:
            ux += SH_C2[0] * y * gb[4] + SH_C2[2] * (-2.0 * x) * gb[6] + SH_C2[3] * z * gb[7]
            ux += SH_C2[4] * 2.0 * x * gb[8]
            uy += SH_C2[0] * x * gb[4] + SH_C2[1] * z * gb[5] + SH_C2[2] * (-2.0 * y) * gb[6]
            uy += SH_C2[4] * (-2.0 * y) * gb[8]
            uz += SH_C2[1] * y * gb[5] + SH_C2[2] * 4.0 * z * gb[6] + SH_C2[3] * x * gb[7]
        if degree >= 3:
            xx, yy, zz = x * x, y * y, z * z
            ux += (
                SH_C3[0] * 6.0 * x * y * gb[9]
                + SH_C3[1] * y * z * gb[10]
                + SH_C3[2] * (-2.0 * x * y) * gb[11]
                + SH_C3[3] * (-6.0 * x * z) * gb[12]
                + SH_C3[4] * (4.0 * zz - 3.0 * xx - yy) * gb[13]
                + SH_C3[5] * 2.0 * x * z * gb[14]
                + SH_C3[6] * (3.0 * xx - 3.0 * yy) * gb[15]
            )
            uy += (
                SH_C3[0] * (3.0 * xx - 3.0 * yy) * gb[9]
                + SH_C3[1] * x * z * gb[10]
                + SH_C3[2] * (4.0 * zz - xx - 3.0 * yy) * gb[11]
                + SH_C3[3] * (-6.0 * y * z) * gb[12]
                + SH_C3[4] * (-2.0 * x * y) * gb[13]
                + SH_C3[5] * (-2.0 * y * z) * gb[14]
                + SH_C3[6] * (-6.0 * x * y) * gb[15]
            )
            uz += (
                SH_C3[1] * x * y * gb[10]
                + SH_C3[2] * 8.0 * y * z * gb[11]
                + SH_C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy) * gb[12]
                + SH_C3[4] * 8.0 * x * z * gb[13]
                + SH_C3[5] * (xx - yy) * gb[14]
            )
        # Through u = d / |d|: du/dd = (I - u u^T) / |d|.
        dot = ux * x + uy * y + uz * z
        g_dirs[i, 0] = (ux - x * dot) * inv
        g_dirs[i, 1] = (uy - y * dot) * inv
        g_dirs[i, 2] = (uz - z * dot) * inv


class ShColors(torch.autograd.Function):
    """``colors [N, 3]`` from ``sh [N, K, 3]`` and view directions ``dirs [N, 3]`` (CPU tensors)."""

    @staticmethod
    def forward(ctx, sh, dirs, degree):
        sh_np = np.ascontiguousarray(sh.detach().numpy())
        dirs_np = np.ascontiguousarray(dirs.detach().numpy())
        out = np.empty((sh_np.shape[0], 3), sh_np.dtype)
        sh_forward(sh_np, dirs_np, degree, out)
        ctx.saved = (sh_np, dirs_np, degree, out)
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, g_colors):
        sh_np, dirs_np, degree, out = ctx.saved
        g_sh = np.empty_like(sh_np)
        g_dirs = np.empty_like(dirs_np)
        g = np.ascontiguousarray(g_colors.detach().numpy().astype(sh_np.dtype, copy=False))
        sh_backward(sh_np, dirs_np, degree, out, g, g_sh, g_dirs)
        return torch.from_numpy(g_sh), torch.from_numpy(g_dirs), None


def eval_sh_colors_cpu(sh: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Same as :func:`artitwin_core.gaussians.eval_sh_colors` (``[N, 3]``), numba forward/backward."""
    return ShColors.apply(sh, dirs, degree)
