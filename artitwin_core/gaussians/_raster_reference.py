"""Dense reference rasterizer: every Gaussian at every pixel, in plain torch. Tests only.

Written independently of the fast path (explicit 3x3 matrices instead of column arithmetic,
cumulative products instead of a compositing loop) so that comparing the two checks both.
Memory is ``O(H W N)``: keep it to a few hundred Gaussians and small images.
"""

from __future__ import annotations

import torch

from artitwin_core.gaussians._project import ALPHA_MAX, ALPHA_MIN, EPS2D, FAR, T_MIN
from artitwin_core.gaussians._sh import eval_sh_colors
from artitwin_core.geometry import quat_wxyz_to_matrix


def rasterize_reference(
    means, quats_wxyz, log_scales, opacity_logits, sh, cam_from_world, intrinsics, width, height,
    sh_degree, background, near,
):  # fmt: skip
    """Returns ``(rgb [H, W, 3], depth [H, W], alpha [H, W], means2d [N, 2], depths [N], valid [N])``."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    rot = cam_from_world[:3, :3]
    p_cam = means @ rot.T + cam_from_world[:3, 3]
    z_raw = p_cam[:, 2]
    valid = ((z_raw >= near) & (z_raw <= FAR)).detach()
    p_cam = torch.where(valid[:, None], p_cam, torch.tensor([0.0, 0.0, 1.0], dtype=means.dtype))
    x, y, z = p_cam.unbind(-1)

    cov_world = quat_wxyz_to_matrix(quats_wxyz) @ torch.diag_embed(torch.exp(2 * log_scales))
    cov_world = cov_world @ quat_wxyz_to_matrix(quats_wxyz).transpose(-1, -2)
    cov_cam = rot @ cov_world @ rot.T

    # Jacobian of the pinhole projection at the mean, with x/z, y/z clamped to 1.3x the FOV.
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    xz = torch.clamp(x / z, -(cx / fx + 0.3 * tan_fovx), (width - cx) / fx + 0.3 * tan_fovx)
    yz = torch.clamp(y / z, -(cy / fy + 0.3 * tan_fovy), (height - cy) / fy + 0.3 * tan_fovy)
    zero = torch.zeros_like(z)
    jac = torch.stack(
        [
            torch.stack([fx / z, zero, -fx * xz / z], -1),
            torch.stack([zero, fy / z, -fy * yz / z], -1),
        ],
        -2,
    )
    cov2d = jac @ cov_cam @ jac.transpose(-1, -2) + EPS2D * torch.eye(2, dtype=means.dtype)
    conic = torch.linalg.inv(cov2d)
    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], -1)

    cam_center = -(rot.T @ cam_from_world[:3, 3])
    colors = eval_sh_colors(sh, means - cam_center, sh_degree)
    opac = torch.sigmoid(opacity_logits)

    jj, ii = torch.meshgrid(
        torch.arange(width, dtype=means.dtype), torch.arange(height, dtype=means.dtype), indexing="xy"
    )
    pix = torch.stack([jj + 0.5, ii + 0.5], -1).reshape(-1, 2)  # [P, 2], row-major
    d = means2d[None, :, :] - pix[:, None, :]  # [P, N, 2]
    power = -0.5 * torch.einsum("pni,nij,pnj->pn", d, conic, d)
    power = torch.where(valid[None, :] & (power <= 0), power, torch.full_like(power, -torch.inf))
    alpha = torch.clamp_max(opac[None, :] * torch.exp(power), ALPHA_MAX)
    alpha = torch.where(alpha >= ALPHA_MIN, alpha, torch.zeros_like(alpha))

    order = torch.argsort(z_raw.detach(), stable=True)
    alpha = alpha[:, order]
    t_incl = torch.cumprod(1.0 - alpha, dim=1)  # transmittance after each Gaussian
    t_before = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], dim=1)
    # A pixel stops before the Gaussian that would bring it to <= T_MIN; t_incl is monotone,
    # so the composited Gaussians are exactly those with t_incl > T_MIN.
    used = (t_incl > T_MIN).detach()
    w = alpha * t_before * used
    t_final = torch.prod(torch.where(used, 1.0 - alpha, torch.ones_like(alpha)), dim=1)
    rgb = w @ colors[order] + t_final[:, None] * background[None, :]
    depth = w @ z[order]
    return (
        rgb.reshape(height, width, 3),
        depth.reshape(height, width),
        (1.0 - t_final).reshape(height, width),
        means2d,
        z_raw,
        valid,
    )
