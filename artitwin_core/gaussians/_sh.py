"""Real spherical harmonics up to degree 3 in the 3DGS convention, evaluated in torch.

The constants and sign pattern are those of the reference 3DGS code (and gsplat), so a model
trained with either evaluates to the same colours here. Autograd provides the backward pass to
both the coefficients and the view directions.
"""

from __future__ import annotations

import torch

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def num_sh_bases(degree: int) -> int:
    """Number of coefficients K = (degree + 1)^2 of a degree-``degree`` expansion."""
    return (degree + 1) ** 2


def sh_degree_from_bases(k: int) -> int:
    """Inverse of :func:`num_sh_bases`; raises ValueError if ``k`` is not a square in 1..16."""
    for d in range(4):
        if num_sh_bases(d) == k:
            return d
    raise ValueError(f"{k} SH coefficients per channel is not (degree+1)^2 for a degree in 0..3")


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Real SH basis functions at unit directions.

    Args:
        dirs: ``[N, 3]`` unit view directions (from the camera centre to the Gaussian).
        degree: 0..3.

    Returns:
        ``[N, (degree+1)^2]`` basis values, ordered as the 3DGS coefficient layout.
    """
    n = dirs.shape[0]
    cols = [torch.full((n,), SH_C0, dtype=dirs.dtype, device=dirs.device)]
    if degree >= 1:
        x, y, z = dirs.unbind(-1)
        cols += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
        if degree >= 2:
            xx, yy, zz = x * x, y * y, z * z
            xy, yz, xz = x * y, y * z, x * z
            cols += [
                SH_C2[0] * xy,
                SH_C2[1] * yz,
                SH_C2[2] * (2.0 * zz - xx - yy),
                SH_C2[3] * xz,
                SH_C2[4] * (xx - yy),
            ]
            if degree >= 3:
                cols += [
                    SH_C3[0] * y * (3.0 * xx - yy),
                    SH_C3[1] * xy * z,
                    SH_C3[2] * y * (4.0 * zz - xx - yy),
                    SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                    SH_C3[4] * x * (4.0 * zz - xx - yy),
                    SH_C3[5] * z * (xx - yy),
                    SH_C3[6] * x * (xx - 3.0 * yy),
                ]
    return torch.stack(cols, dim=-1)


def eval_sh_colors(sh: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Colours from SH coefficients: ``clamp(sum_k basis_k(dir) * sh_k + 0.5, min=0)``.

    Args:
        sh: ``[N, K, 3]`` coefficients with K >= (degree+1)^2 (extra bands are ignored).
        dirs: ``[N, 3]`` view directions, need not be normalised (normalised here; a zero
            direction gives the DC colour only).
        degree: SH degree to evaluate, 0..3.

    Returns:
        ``[N, 3]`` non-negative colours (not clamped above: 3DGS leaves that to the loss).
    """
    k = num_sh_bases(degree)
    if degree == 0:
        rgb = SH_C0 * sh[:, 0, :]
    else:
        unit = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        basis = sh_basis(unit, degree)
        rgb = torch.einsum("nk,nkc->nc", basis, sh[:, :k, :])
    return torch.clamp_min(rgb + 0.5, 0.0)
