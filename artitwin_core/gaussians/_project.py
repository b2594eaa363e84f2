"""EWA projection of 3D Gaussians to screen-space conics, in torch (autograd = backward).

This is the per-Gaussian half of the CPU rasterizer, written with elementwise ops on ``[N]``
columns (torch's batched matmuls are slow for tiny matrices on CPU); for 20k Gaussians the
~60 column ops cost ~8 ms forward + backward on one core. SH colours go through the numba
kernels of ``_sh_cpu`` (the torch version took ~10 ms more).

Conventions (shared with gsplat): OpenCV camera axes, pinhole ``u = fx x / z + cx``, pixel
``(row i, col j)`` has its centre at ``(j + 0.5, i + 0.5)``; the Jacobian of the projection is
evaluated at the mean with ``x/z, y/z`` clamped to 1.3x the field of view (3DGS), and 0.3 px^2 is
added to the 2D covariance diagonal (the low-pass dilation).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

EPS2D = 0.3  # px^2 added to the projected covariance diagonal (3DGS low-pass filter)
ALPHA_MIN = 1.0 / 255.0  # contributions below this alpha are skipped
ALPHA_MAX = 0.999  # alpha is clamped here so 1 - alpha stays invertible in the backward pass
T_MIN = 1e-4  # compositing of a pixel stops before transmittance would drop to this
FAR = 1e10  # metres; Gaussians further than this are culled


@dataclass
class Projected:
    """Per-Gaussian screen-space quantities (all ``[N, ...]``, float, differentiable).

    Attributes:
        means2d: ``[N, 2]`` pixel coordinates of the projected centres.
        conics: ``[N, 3]`` inverse 2D covariance ``(a, b, c)`` of ``[[a, b], [b, c]]``, 1/px^2.
        cov2d: ``[N, 3]`` 2D covariance ``(xx, xy, yy)`` in px^2 (dilated).
        depths: ``[N]`` camera-space z, metres.
        colors: ``[N, 3]`` SH colours for this view.
        opacities: ``[N]`` sigmoid of the logits.
        valid: ``[N]`` bool, inside the near/far range (not differentiable).
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    cov2d: torch.Tensor
    depths: torch.Tensor
    colors: torch.Tensor
    opacities: torch.Tensor
    valid: torch.Tensor


def quat_to_rotmat_columns(quats_wxyz: torch.Tensor) -> list[torch.Tensor]:
    """Rotation matrix entries ``[r00, r01, ..., r22]`` (each ``[N]``) of quaternions ``[N, 4]``.

    ``geometry.quat_wxyz_to_matrix`` as separate columns (stacking them into ``[N, 3, 3]`` costs
    more than the formula on CPU); the same normalisation, zero giving the identity, and tested
    equal to it (tests/geometry/test_quaternion.py)."""
    q = quats_wxyz / quats_wxyz.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip


def project_gaussians(
    means: torch.Tensor,
    quats_wxyz: torch.Tensor,
    log_scales: torch.Tensor,
    opacity_logits: torch.Tensor,
    sh: torch.Tensor,
    cam_from_world: torch.Tensor,
    intrinsics: tuple[float, float, float, float],
    width: int,
    height: int,
    sh_degree: int,
    near: float,
    numba_sh: bool = True,
) -> Projected:
    """Project N Gaussians into one pinhole camera.

    Args:
        means: ``[N, 3]`` world centres, metres.
        quats_wxyz: ``[N, 4]`` rotations (any norm).
        log_scales: ``[N, 3]`` log standard deviations, log metres.
        opacity_logits: ``[N]``.
        sh: ``[N, K, 3]`` SH coefficients.
        cam_from_world: ``[4, 4]`` rigid transform, same dtype as ``means``.
        intrinsics: ``(fx, fy, cx, cy)`` pixels.
        width, height: image size, pixels.
        sh_degree: degree evaluated, 0..3.
        near: near plane, metres.
        numba_sh: evaluate SH colours with the numba kernels of ``_sh_cpu`` (CPU tensors; ~10x
            faster than the torch version, which is used when False).
    """
    from artitwin_core.gaussians._sh import eval_sh_colors
    from artitwin_core.gaussians._sh_cpu import eval_sh_colors_cpu

    fx, fy, cx, cy = (float(v) for v in intrinsics)
    rot = cam_from_world[:3, :3]
    trans = cam_from_world[:3, 3]
    p_cam = means @ rot.T + trans
    tx, ty, tz = p_cam.unbind(-1)
    valid = ((tz >= near) & (tz <= FAR)).detach()
    # Invalid Gaussians get a harmless depth so no inf/nan enters the graph (their outputs are
    # masked out downstream, and a 0 * inf in the backward pass would poison the gradients).
    z = torch.where(valid, tz, torch.ones_like(tz))
    inv_z = 1.0 / z

    # Covariance factor in camera axes: M = R_cam * R_gauss * diag(s), cov3d = M M^T.
    rg = quat_to_rotmat_columns(quats_wxyz)
    s = torch.exp(log_scales)
    sx, sy, sz = s.unbind(-1)
    rc = [rot[i, j] for i in range(3) for j in range(3)]
    m = [[None] * 3 for _ in range(3)]
    for i in range(3):
        for j in range(3):
            m[i][j] = rc[3 * i] * rg[j] + rc[3 * i + 1] * rg[3 + j] + rc[3 * i + 2] * rg[6 + j]
    for i in range(3):
        m[i][0] = m[i][0] * sx
        m[i][1] = m[i][1] * sy
        m[i][2] = m[i][2] * sz

    # Jacobian at the (frustum-clamped) mean.
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    xc = z * torch.clamp(tx * inv_z, -lim_x_neg, lim_x_pos)
    yc = z * torch.clamp(ty * inv_z, -lim_y_neg, lim_y_pos)
    j00 = fx * inv_z
    j02 = -fx * xc * inv_z * inv_z
    j11 = fy * inv_z
    j12 = -fy * yc * inv_z * inv_z
    # T = J M (2x3): rows u and v.
    u = [j00 * m[0][k] + j02 * m[2][k] for k in range(3)]
    v = [j11 * m[1][k] + j12 * m[2][k] for k in range(3)]
    cxx = u[0] * u[0] + u[1] * u[1] + u[2] * u[2] + EPS2D
    cxy = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    cyy = v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + EPS2D
    det = cxx * cyy - cxy * cxy
    inv_det = 1.0 / det
    conics = torch.stack([cyy * inv_det, -cxy * inv_det, cxx * inv_det], dim=-1)
    cov2d = torch.stack([cxx, cxy, cyy], dim=-1)
    means2d = torch.stack([fx * tx * inv_z + cx, fy * ty * inv_z + cy], dim=-1)

    # View direction from the camera centre; the centre is -R^T t.
    cam_center = -(rot.T @ trans)
    sh_eval = eval_sh_colors_cpu if numba_sh and not means.is_cuda else eval_sh_colors
    colors = sh_eval(sh, means - cam_center, sh_degree)
    opacities = torch.sigmoid(opacity_logits)
    return Projected(
        means2d=means2d,
        conics=conics,
        cov2d=cov2d,
        depths=tz,
        colors=colors,
        opacities=opacities,
        valid=valid,
    )


def screen_extent(
    cov2d: torch.Tensor, opacities: torch.Tensor, valid: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Opacity-aware footprint of each Gaussian (no gradient).

    Outside Mahalanobis distance ``r = sqrt(2 ln(255 o))`` the alpha ``o exp(-r^2/2)`` is below
    1/255 and is skipped by the compositor anyway, so clipping there is exact (never more than
    3.33 sigma, at o = 0.999). This is tighter than the fixed 3-sigma cut of 3DGS for faint
    Gaussians, and unlike it changes no pixel.

    Returns:
        half_w, half_h: ``[N]`` half-extents of the axis-aligned box around the ellipse, pixels
            (``r sqrt(cov_xx)``, ``r sqrt(cov_yy)``); 0 for culled Gaussians.
        radius: ``[N]`` radius of the bounding circle ``r sqrt(lambda_max)``, pixels; 0 = culled.
        cutoff: ``[N]`` the Mahalanobis radius ``r`` itself (with a hair of margin); 0 = culled.
    """
    with torch.no_grad():
        o = opacities
        keep = valid & (o >= ALPHA_MIN)
        r = torch.sqrt(2.0 * torch.log(torch.clamp_min(o * 255.0, 1.0)))
        # A hair of margin so float rounding at the box edge can never drop a pixel whose alpha
        # the compositor would round up to exactly 1/255.
        r = (r * 1.001 + 1e-3) * keep
        cxx, cxy, cyy = cov2d.unbind(-1)
        mid = 0.5 * (cxx + cyy)
        lam_max = mid + torch.sqrt(torch.clamp_min(mid * mid - (cxx * cyy - cxy * cxy), 0.0))
        return r * torch.sqrt(cxx), r * torch.sqrt(cyy), r * torch.sqrt(lam_max), r
