"""Held-out evaluation of a trained model: PSNR, SSIM and depth error per view."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from artitwin_core.capture import Capture
from artitwin_core.gaussians import GaussianParams, rasterize, resolve_backend
from artitwin_core.geometry import invert_se3
from artitwin_core.reconstruction._losses import psnr, ssim
from artitwin_core.reconstruction._sensor import SensorModel
from artitwin_core.reconstruction._train import depth_on_rgb_grid


@dataclass(frozen=True)
class EvalResult:
    """Metrics of one model on some views (means over views; per-view arrays alongside).

    Attributes:
        frames: ``[V]`` evaluated frame indices.
        psnr_db, ssim: ``[V]`` RGB PSNR (dB) and SSIM against the captured frames.
        depth_mae_m: ``[V]`` mean |rendered - sensor| depth over valid sensor pixels
            (confidence >= 1), metres.
        depth_mae_gt_m: ``[V]`` the same against ground-truth depth, or ``None`` when not given.
    """

    frames: np.ndarray
    psnr_db: np.ndarray
    ssim: np.ndarray
    depth_mae_m: np.ndarray
    depth_mae_gt_m: np.ndarray | None = None

    def summary(self) -> dict[str, float]:
        """Mean metrics, named with unit suffixes (``_db``, ``_m``)."""
        out = {
            "psnr_db": float(np.mean(self.psnr_db)) if len(self.frames) else float("nan"),
            "ssim": float(np.mean(self.ssim)) if len(self.frames) else float("nan"),
            "depth_mae_m": float(np.nanmean(self.depth_mae_m)) if len(self.frames) else float("nan"),
        }
        if self.depth_mae_gt_m is not None and len(self.frames):
            out["depth_mae_gt_m"] = float(np.nanmean(self.depth_mae_gt_m))
        return out


class ModelRenderer:
    """A model's tensors on the device ``backend`` resolves to (``resolve_backend``), copied there
    once, then rendered into any number of pinhole cameras (predictions, evaluation, reports).

    Args:
        params: the Gaussians.
        background: RGB in [0, 1] behind everything.
        backend: ``"auto"`` (CUDA with gsplat when present, else CPU), ``"cpu"``, ``"reference"`` or ``"cuda"``.
    """

    def __init__(self, params: GaussianParams, *, background: Sequence[float] = (0.0, 0.0, 0.0), backend: str = "auto"):
        resolved = resolve_backend(backend)
        dev = self.device = resolved.device
        self.backend = resolved.name

        def up(a: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(a, np.float32)).to(dev)

        self.means, self.quats_wxyz = up(params.means), up(params.quats_wxyz)
        self.log_scales, self.opacity_logits, self.sh = up(params.log_scales), up(params.opacity_logits), up(params.sh)
        self.background = torch.tensor([float(c) for c in background], dtype=torch.float32, device=dev)

    def render(
        self,
        world_from_camera: np.ndarray,
        intrinsics: Sequence[float],
        width: int,
        height: int,
        *,
        means: torch.Tensor | None = None,
        quats_wxyz: torch.Tensor | None = None,
        sh: torch.Tensor | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render into one camera (see :func:`render_view`); ``means``, ``quats_wxyz`` and ``sh``
        replace the model's own (same device and shapes: an articulated twin moves its parts)."""
        with torch.no_grad():
            out = rasterize(
                self.means if means is None else means, self.quats_wxyz if quats_wxyz is None else quats_wxyz,
                self.log_scales, self.opacity_logits, self.sh if sh is None else sh,
                invert_se3(np.asarray(world_from_camera, np.float64)),
                tuple(float(x) for x in intrinsics), int(width), int(height),
                background=self.background, backend=self.backend,
            )  # fmt: skip
            return (
                out.rgb.clamp(0, 1).cpu().numpy(),
                out.expected_depth(1e-3).cpu().numpy(),
                out.alpha.cpu().numpy(),
            )


def render_view(
    params: GaussianParams,
    world_from_camera: np.ndarray,
    intrinsics: Sequence[float],
    width: int,
    height: int,
    *,
    background: Sequence[float] = (0.0, 0.0, 0.0),
    backend: str = "auto",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render a model into one pinhole camera (many cameras: :class:`ModelRenderer` copies the
    model to the device once).

    Args:
        params: the Gaussians.
        world_from_camera: ``[4, 4]`` camera pose, OpenCV axes, metres.
        intrinsics: ``(fx, fy, cx, cy)`` pixels.
        width, height: image size, pixels.
        backend: ``"auto"`` (CUDA with gsplat when present, else CPU), ``"cpu"``, ``"reference"``, ``"cuda"``.

    Returns:
        rgb ``[H, W, 3]`` float32 in [0, 1], expected depth ``[H, W]`` float32 metres (0 where
        nothing is rendered), alpha ``[H, W]`` float32.
    """
    return ModelRenderer(params, background=background, backend=backend).render(world_from_camera, intrinsics, width, height)


def evaluate_views(
    params: GaussianParams,
    capture: Capture,
    world_from_camera: np.ndarray,
    frames: Sequence[int],
    *,
    gt_depth: np.ndarray | None = None,
    background: Sequence[float] = (0.0, 0.0, 0.0),
    backend: str = "auto",
    sensor: SensorModel | None = None,
) -> EvalResult:
    """PSNR, SSIM and depth errors of ``params`` rendered at ``frames``.

    Args:
        params: the model.
        capture: the recording (targets: its RGB frames and sensor depth).
        world_from_camera: ``[T, 4, 4]`` poses to render from (the refined ones).
        frames: frame indices to evaluate (the held-out ones).
        gt_depth: optional ``[T, H, W]`` ground-truth z-depth at RGB resolution (NaN = no surface),
            for the ``depth_mae_gt_m`` metric.
        sensor: the learned sensor model, applied to the renders before they are compared with
            the recording (a frame it was not trained on gets gains interpolated in time); the
            ground-truth depth is compared with the rendered (true) depth.
    """
    frames = [int(f) for f in frames]
    _, h, w, _ = capture.rgb.shape
    ps, ss, dm, dg = [], [], [], []
    renderer = ModelRenderer(params, background=background, backend=backend) if frames else None
    for t in frames:
        rgb, depth, alpha = renderer.render(world_from_camera[t], capture.rgb_intrinsics[t], w, h)
        sensor_depth = depth
        if sensor is not None:
            rgb = sensor.apply_rgb(rgb, t, capture.rgb_intrinsics[t])
            sensor_depth = sensor.apply_depth(depth)
        target = torch.from_numpy(capture.rgb[t].astype(np.float32) / 255.0)
        r = torch.from_numpy(rgb)
        ps.append(psnr(r, target))
        ss.append(float(ssim(r, target)))
        sd, sw = depth_on_rgb_grid(capture, t)
        m = sw > 0
        dm.append(float(np.abs(sensor_depth[m] - sd[m]).mean()) if m.any() else float("nan"))
        if gt_depth is not None:
            g = gt_depth[t]
            m = np.isfinite(g) & (g > 0)
            dg.append(float(np.abs(depth[m] - g[m]).mean()) if m.any() else float("nan"))
    return EvalResult(
        frames=np.asarray(frames, np.int64),
        psnr_db=np.asarray(ps),
        ssim=np.asarray(ss),
        depth_mae_m=np.asarray(dm),
        depth_mae_gt_m=None if gt_depth is None else np.asarray(dg),
    )
