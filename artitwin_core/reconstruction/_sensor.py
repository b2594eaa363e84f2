"""The camera's own effects on what it records, learned alongside the Gaussians when enabled.

The Gaussians model the scene; the sensor model maps what they render to what this camera
recorded. Three effects of the diagnosis catalog (``artitwin_core.diagnostics``) can be modelled
here, each a switch in ``TrainConfig.sensor_effects``:

- ``exposure_white_balance``: per-frame, per-channel gain ``g`` on linear RGB,
  ``measured = g * rendered`` (auto exposure, auto white balance: both scale the radiance). The
  first training view is the reference (``g = 1``): without it a global gain and the Gaussians'
  colours trade off freely. A frame not trained on (held out) gets its gains interpolated in time
  between its neighbours (log gain, by frame index): auto exposure is smooth in time, and the
  held-out frame's own pixels are never used to fit them. No per-frame offset is learned here
  (``SensorModel.offset`` stays 0; the dynamic camera's closed-form fit has a ridged one): fitted
  by gradient on the sRGB L1 loss, whose slope is steepest in the dark pixels, the offsets took up
  the Gaussians' own residual on a clean recording (up to 0.05 linear) and cost held-out frames
  0.3 dB; without them the clean recording keeps its PSNR (+0.05 dB) and an injected exposure
  drift of 0.35 stops is recovered as well (held-out 26.1 -> 29.5 dB against 29.6 with offsets;
  the tiny scene at 128x96, 300 steps).
- ``vignetting``: a radial gain ``1 + c1 r^2 + c2 r^4`` on linear RGB, shared by every frame,
  ``r`` the distance from the principal point over the distance to the farthest image corner.
  Measured from the training frames themselves when they can show it
  (``artitwin_core.capture.estimate_vignetting``: the same surfaces recorded darker at larger
  radii), and then kept fixed: the photometric gradient against the Gaussians is biased, as their
  view-dependent colour trades off against the radius (on the tiny scene, 300 steps: a 0.35
  corner fall-off learned as 0.20-0.24 whether started at 0 or at the truth, and a clean camera
  learned as 0.08 brighter corners), while the frames agree on it to within 0.004.
- ``depth_scale_offset``: an affine depth error of the sensor, ``measured = s * true + o``
  (metres); the Gaussians stay metric (the capture's poses fix the scale through the images).

And the RGB lens: the rasterizer renders a pinhole image, so when the images are distorted
(OpenCV ``k1 k2 p1 p2``, as the capture records them or as pose refinement calibrated them, the
``lens_distortion`` effect), each recorded pixel samples the render where its ray goes (the pixel
undistorted by fixed-point iteration, as OpenCV does). The coefficients are given, not learned
here: a photometric gradient on them is too weak at phone-video resolution (on the tiny scene a
-0.08 k1 stayed at 0 after 300 steps), while the bundle adjustment's keypoints pin them down.
Depth stays pinhole, as ARKit's is.

Order, as light goes: the lens moves where rays land (distortion), then the sensor weighs them
(vignetting, then exposure and white balance).

Both torch (training) and numpy (rendering a trained model) forms are here, with the same
formulas, so what was trained is what is predicted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from artitwin_core.gaussians import adam_step
from artitwin_core.geometry import corner_radius_sq, pixel_grid, pixel_rays

_UNDISTORT_ITERATIONS = 10

SENSOR_EFFECTS = ("exposure_white_balance", "vignetting", "depth_scale_offset")


def check_sensor_effects(effects) -> tuple[str, ...]:
    """The effects as a sorted tuple; ``ValueError`` naming an unknown one and the known ones."""
    out = tuple(sorted(set(effects)))
    unknown = [e for e in out if e not in SENSOR_EFFECTS]
    if unknown:
        raise ValueError(
            f"sensor_effects: {unknown} cannot be modelled by the reconstruction; it models {list(SENSOR_EFFECTS)}."
        )
    return out


# -- colour spaces (the IEC 61966-2-1 sRGB curve, extended linearly below 0) -------------------


def srgb_to_linear_t(x: torch.Tensor) -> torch.Tensor:
    hi = ((x.clamp(min=0.04045) + 0.055) / 1.055) ** 2.4
    return torch.where(x <= 0.04045, x / 12.92, hi)


def linear_to_srgb_t(x: torch.Tensor) -> torch.Tensor:
    hi = 1.055 * x.clamp(min=0.0031308) ** (1 / 2.4) - 0.055
    return torch.where(x <= 0.0031308, 12.92 * x, hi)


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055)


def radius_sq(intrinsics, width: int, height: int) -> np.ndarray:
    """``[H, W]`` squared radius from the principal point over the farthest corner's (as the catalog's)."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return corner_radius_sq(intrinsics, u, v, width, height)


def _distort(x, y, k):
    """OpenCV radial-tangential model on normalised coordinates (numpy or torch, ``k`` = k1 k2 p1 p2)."""
    k1, k2, p1, p2 = k[0], k[1], k[2], k[3]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)  # fmt: skip


def _undistort(xd, yd, k, iterations: int = _UNDISTORT_ITERATIONS):
    """The pinhole point whose distorted image is ``(xd, yd)``: fixed-point iteration, as OpenCV's
    ``undistortPoints`` (converges for phone lenses, ``|k1| r^2`` well below 1)."""
    x, y = xd, yd
    for _ in range(iterations):
        dx, dy = _distort(x, y, k)
        x, y = x + (xd - dx), y + (yd - dy)
    return x, y


def _normalised_grid(intrinsics, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    u, v = pixel_grid(width, height)
    ray = pixel_rays([float(c) for c in intrinsics[:4]], u, v)
    return ray[..., 0], ray[..., 1]


def distortion_sample_points(intrinsics, width: int, height: int, k) -> tuple[np.ndarray, np.ndarray]:
    """``(u, v)`` ``[H, W]`` pixel positions in the pinhole image that each recorded pixel shows."""
    fx, fy, cx, cy = (float(c) for c in intrinsics[:4])
    xd, yd = _normalised_grid(intrinsics, width, height)
    x, y = _undistort(xd, yd, np.asarray(k, np.float64))
    return fx * x + cx, fy * y + cy


def _sample_bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``img [H, W, C]`` at float pixel positions, edge pixels repeated outside (as torch's
    ``grid_sample(padding_mode="border", align_corners=True)``)."""
    h, w = img.shape[:2]
    u, v = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
    u0, v0 = np.minimum(np.floor(u).astype(np.int64), w - 2), np.minimum(np.floor(v).astype(np.int64), h - 2)
    a, b = (u - u0)[..., None], (v - v0)[..., None]
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
            + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])  # fmt: skip


@dataclass(frozen=True)
class SensorModel:
    """A learned sensor model (see the module docstring). Effects not enabled are ``None``.

    Attributes:
        effects: the enabled effect names.
        frames: ``[V]`` frame indices (0-based positions in the capture, not its frame ids) the
            per-frame gains were learned on, ascending.
        log_gain: ``[V, 3]`` natural log of the linear RGB gain per frame (None: no exposure model).
        offset: ``[V, 3]`` linear RGB offset per frame (0 as learned here; the dynamic recording's
            camera, ``articulation._camera``, fits one).
        vignetting: ``(c1, c2)`` radial gain coefficients (None: no vignetting model).
        depth_scale, depth_offset_m: the sensor's affine depth error.
        distortion: ``(k1, k2, p1, p2)`` of the RGB lens (as recorded or calibrated), None for
            a pinhole lens.
    """

    effects: tuple[str, ...]
    frames: np.ndarray
    log_gain: np.ndarray | None = None
    offset: np.ndarray | None = None
    vignetting: tuple[float, float] | None = None
    depth_scale: float = 1.0
    depth_offset_m: float = 0.0
    distortion: tuple[float, float, float, float] | None = None

    def frame_gain(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """``(gain [3], offset [3])`` of frame index ``frame``: learned, or interpolated in time."""
        if self.log_gain is None or len(self.frames) == 0:
            return np.ones(3), np.zeros(3)
        f = self.frames.astype(np.float64)
        lg = np.array([np.interp(frame, f, self.log_gain[:, c]) for c in range(3)])
        off = np.array([np.interp(frame, f, self.offset[:, c]) for c in range(3)])
        return np.exp(lg), off

    def apply_rgb(self, rgb: np.ndarray, frame: int, intrinsics) -> np.ndarray:
        """What the camera records of a rendered sRGB image ``[H, W, 3]`` in [0, 1] at ``frame``."""
        if self.distortion is not None:
            u, v = distortion_sample_points(intrinsics, rgb.shape[1], rgb.shape[0], self.distortion)
            rgb = _sample_bilinear(rgb.astype(np.float64), u, v).astype(np.float32)
        if self.log_gain is None and self.vignetting is None:
            return rgb
        lin = _srgb_to_linear(rgb.astype(np.float64))
        gain, off = self.frame_gain(frame)
        lin = lin * gain + off
        if self.vignetting is not None:
            r2 = radius_sq(intrinsics, rgb.shape[1], rgb.shape[0])
            lin = lin * (1.0 + self.vignetting[0] * r2 + self.vignetting[1] * r2**2)[..., None]
        return np.clip(_linear_to_srgb(lin), 0.0, 1.0).astype(np.float32)

    def apply_depth(self, depth: np.ndarray) -> np.ndarray:
        """What the depth sensor records of rendered z-depth (0 and NaN stay as they are)."""
        if "depth_scale_offset" not in self.effects:
            return depth
        ok = np.isfinite(depth) & (depth > 0)
        return np.where(ok, self.depth_scale * depth + self.depth_offset_m, depth).astype(depth.dtype)


class SensorParams:
    """The trainable form: leaf tensors with their own Adam moments, one row per training view."""

    def __init__(
        self, effects, frames, intrinsics: np.ndarray, width: int, height: int, distortion=None,
        device: torch.device | str | None = None, vignetting: tuple[float, float] | None = None,
    ) -> None:
        """``distortion``: the RGB lens's ``k1 k2 p1 p2 [...]`` (None: pinhole), applied to every render.
        ``vignetting``: the vignetting's ``(c1, c2)`` as the frames themselves measured it, then
        kept fixed (None: learned, from no fall-off).
        Every tensor lives on ``device`` (default CPU), the device of the renders it is applied to."""
        self.effects = check_sensor_effects(effects)
        self.frames = [int(f) for f in frames]
        self.intrinsics = np.asarray(intrinsics, np.float64)
        self.size = (int(width), int(height))
        self.device = dev = torch.device(device or "cpu")
        k0 = np.zeros(4)
        if distortion is not None:
            d = np.asarray(distortion, np.float64).ravel()[:4]
            k0[: len(d)] = d
        self.distortion = torch.tensor(k0, dtype=torch.float64, device=dev) if np.any(k0 != 0) else None
        v = len(self.frames)
        self.params: dict[str, torch.Tensor] = {}
        if "exposure_white_balance" in self.effects:
            self.params["log_gain"] = torch.zeros(v, 3, device=dev)
        if "vignetting" in self.effects:
            if vignetting is None:
                self.params["vignetting"] = torch.zeros(2, device=dev)
            self._r2 = [torch.from_numpy(radius_sq(k, width, height).astype(np.float32)).to(dev) for k in intrinsics]
        self.fixed_vignetting = None if vignetting is None else torch.tensor(vignetting, dtype=torch.float32, device=dev)
        if "depth_scale_offset" in self.effects:
            self.params["depth_affine"] = torch.tensor([1.0, 0.0], device=dev)
        self._grids: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        for p in self.params.values():
            p.requires_grad_(True)
        self.exp_avg = {k: torch.zeros_like(p) for k, p in self.params.items()}
        self.exp_avg_sq = {k: torch.zeros_like(p) for k, p in self.params.items()}

    def __bool__(self) -> bool:
        return bool(self.params) or self.distortion is not None or self.fixed_vignetting is not None

    def distort(self, render: torch.Tensor, view: int) -> torch.Tensor:
        """The pinhole render ``[H, W, C]`` as the lens images it (unchanged for a pinhole lens)."""
        k = self.distortion
        if k is None:
            return render
        if view not in self._grids:
            xd, yd = _normalised_grid(self.intrinsics[view], *self.size)
            self._grids[view] = (torch.from_numpy(xd).to(self.device), torch.from_numpy(yd).to(self.device))
        xd, yd = self._grids[view]
        x, y = _undistort(xd, yd, k)
        fx, fy, cx, cy = (float(c) for c in self.intrinsics[view][:4])
        w, h = self.size
        # align_corners=True: -1 and 1 are the centres of the first and last pixels.
        gx = (fx * x + cx) * (2.0 / (w - 1)) - 1.0
        gy = (fy * y + cy) * (2.0 / (h - 1)) - 1.0
        grid = torch.stack([gx, gy], dim=-1).to(render.dtype)[None]
        out = F.grid_sample(render.permute(2, 0, 1)[None], grid, mode="bilinear", padding_mode="border", align_corners=True)
        return out[0].permute(1, 2, 0)

    def rgb(self, render: torch.Tensor, view: int) -> torch.Tensor:
        """The recorded sRGB ``[H, W, 3]`` of a rendered one at training view ``view``."""
        render = self.distort(render, view)
        c = self.params.get("vignetting", self.fixed_vignetting)
        if "log_gain" not in self.params and c is None:
            return render
        lin = srgb_to_linear_t(render)
        if "log_gain" in self.params and view != 0:  # view 0 is the reference
            lin = lin * torch.exp(self.params["log_gain"][view])
        if c is not None:
            r2 = self._r2[view]
            lin = lin * (1.0 + c[0] * r2 + c[1] * r2 * r2)[..., None]
        return linear_to_srgb_t(lin)

    def depth(self, depth: torch.Tensor) -> torch.Tensor:
        if "depth_affine" not in self.params:
            return depth
        s, o = self.params["depth_affine"]
        return torch.where(depth > 0, s * depth + o, depth)

    def zero_grad(self) -> None:
        for p in self.params.values():
            p.grad = None

    def adam_step(self, step: int, lr: float) -> None:
        """Adam on the parameters that got a gradient. Every row steps, also the other views' rows of
        ``log_gain`` (zero gradient, but momentum): as before the shared Adam step."""
        for name, p in self.params.items():
            # The depth scale is shared by every view and multiplies metres: a smaller step keeps it
            # from chasing one view's noise.
            scale = 0.1 if name == "depth_affine" else 1.0
            adam_step(p, self.exp_avg[name], self.exp_avg_sq[name], scale * lr, step + 1)

    def to_model(self) -> SensorModel:
        p = {k: v.detach().cpu().numpy().astype(np.float64) for k, v in self.params.items()}
        order = np.argsort(self.frames)
        log_gain = offset = None
        if "log_gain" in p:
            lg = p["log_gain"].copy()
            lg[0] = 0.0  # the reference view
            log_gain, offset = lg[order], np.zeros_like(lg)
        da = p.get("depth_affine", np.array([1.0, 0.0]))
        vig = p.get("vignetting", None if self.fixed_vignetting is None else self.fixed_vignetting.cpu().numpy())
        k = None if self.distortion is None else self.distortion.cpu().numpy()
        return SensorModel(
            effects=self.effects,
            frames=np.asarray(self.frames, np.int64)[order],
            log_gain=log_gain,
            offset=offset,
            vignetting=None if vig is None else (float(vig[0]), float(vig[1])),
            depth_scale=float(da[0]),
            depth_offset_m=float(da[1]),
            distortion=None if k is None else tuple(float(c) for c in k[:4]),
        )
