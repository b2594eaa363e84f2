"""The dynamic recording's own camera: per-frame exposure and white balance (and vignetting) of
the camera that filmed the part moving, fitted against the articulated twin.

The static recording's camera effects are learned with the Gaussians (``reconstruction._sensor``);
the twin's colours are then that recording's. The dynamic recording is a second recording, often
with its own auto exposure, so stage IV models it separately: per frame and channel,
``measured = (g * rendered + o) * (1 + c1 r^2 + c2 r^4)`` on linear RGB (the same form as
``SensorModel.apply_rgb``, which renders it).

Three things keep a model of an absent effect from costing anything:

- the reference is the twin itself (the static recording's exposure): a frame that matches it
  fits ``g = 1``, ``o = 0`` up to noise, and the fit is a ridge toward exactly that;
- the fit uses background pixels the twin covers (not the hand, not the moving part, not pixels
  clipped at either end), twice, dropping pixels beyond ``outlier_mads`` robust deviations
  (silhouettes, the twin's own misses);
- frames held out of training are not fitted: the model stores the training frames only, and
  ``SensorModel.frame_gain`` interpolates the held-out ones in time.

Closed form, one 2x2 solve per frame and channel: no gradient step, so nothing here shares state
with the Gaussians' optimiser.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.reconstruction import SensorModel
from artitwin_core.reconstruction._sensor import _linear_to_srgb, _srgb_to_linear, radius_sq

# The camera effects of a recording that stage IV can model (a depth error is the depth
# calibration's, applied to both recordings before either is used).
RECORDING_EFFECTS = ("exposure_white_balance", "vignetting")


@dataclass(frozen=True)
class CameraFitConfig:
    """How the dynamic recording's camera is fitted.

    Attributes:
        effects: which of ``RECORDING_EFFECTS`` to fit.
        gain_ridge: ridge weight pulling each frame's gain toward 1, per pixel (relative to the
            mean squared linear radiance, about 0.1).
        offset_ridge: ridge weight pulling each frame's offset toward 0, per pixel: larger than
            the gain's because an offset trades off with the gain on a narrow range of radiance.
        outlier_mads: pixels whose residual is beyond this many robust deviations are refitted without.
        min_pixels: a frame with fewer usable pixels keeps ``g = 1``, ``o = 0`` (its neighbours'
            values are not borrowed: the ridge's answer with no data).
        rounds: alternations between the per-frame gains and the shared vignetting.
    """

    effects: tuple[str, ...] = ("exposure_white_balance",)
    gain_ridge: float = 1e-3
    offset_ridge: float = 1.0
    outlier_mads: float = 3.0
    min_pixels: int = 200
    rounds: int = 3

    def __post_init__(self) -> None:
        unknown = sorted(set(self.effects) - set(RECORDING_EFFECTS))
        if unknown:
            raise InputError(
                f"CameraFitConfig.effects: {unknown} cannot be modelled for the dynamic recording; "
                f"it models {list(RECORDING_EFFECTS)}."
            )
        if self.gain_ridge < 0 or self.offset_ridge < 0:
            raise InputError("CameraFitConfig.gain_ridge and offset_ridge must be >= 0.")


def _solve_frame(p: np.ndarray, m: np.ndarray, cfg: CameraFitConfig) -> tuple[float, float]:
    """Ridge least squares of ``m ~ g p + o`` (``p``, ``m`` ``[n]``), toward ``g = 1``, ``o = 0``."""
    n = len(p)
    a = np.array([[p @ p + cfg.gain_ridge * n, p.sum()], [p.sum(), n * (1.0 + cfg.offset_ridge)]])
    b = np.array([p @ m + cfg.gain_ridge * n, m.sum()])
    g, o = np.linalg.solve(a, b)
    return float(g), float(o)


def fit_recording_camera(
    pred: np.ndarray,
    meas: np.ndarray,
    valid: np.ndarray,
    frames: Sequence[int],
    intrinsics: np.ndarray,
    config: CameraFitConfig = CameraFitConfig(),
) -> SensorModel:
    """The camera that turns the twin's renders into what the recording measured.

    Args:
        pred: ``[N, H, W, 3]`` the twin's renders, sRGB in [0, 1] (float) or uint8.
        meas: ``[N, H, W, 3]`` the recording's frames, same form and size.
        valid: ``[N, H, W]`` pixels to fit on (covered by the twin, not the hand, not the part).
        frames: ``[N]`` the frames' positions in the recording (the model's ``frames``), ascending.
        intrinsics: ``[N, 4]`` ``(fx, fy, cx, cy)`` at this size (for the vignetting radius).
        config: which effects, and the regularisation.

    Returns:
        A ``SensorModel`` with ``effects``, ``frames`` (the fitted frames), ``log_gain`` and
        ``offset`` ``[N, 3]`` (identity when exposure is not modelled) and ``vignetting``.
    """
    frames = np.asarray(frames, np.int64)
    if pred.shape != meas.shape or pred.shape[:3] != valid.shape or len(frames) != len(pred):
        raise InputError(
            f"fit_recording_camera: renders {pred.shape}, frames {meas.shape}, masks {valid.shape} and "
            f"{len(frames)} frame indices must agree."
        )
    if np.any(np.diff(frames) <= 0):
        raise InputError("fit_recording_camera: frames must be ascending and distinct.")

    def linear(x):
        x = np.asarray(x)
        return _srgb_to_linear(x.astype(np.float64) / 255.0 if x.dtype == np.uint8 else x.astype(np.float64))

    n_frames, h, w, _ = pred.shape
    gain, offset = np.ones((n_frames, 3)), np.zeros((n_frames, 3))
    vig = np.zeros(2)
    exposure = "exposure_white_balance" in config.effects
    vignetting = "vignetting" in config.effects
    p_all, m_all = linear(pred), linear(meas)
    # Clipped pixels do not follow a gain: leave out the measured and rendered near-black and near-white.
    usable = np.asarray(valid, bool) & np.all((m_all > 1e-3) & (m_all < 0.95) & (p_all > 1e-3) & (p_all < 0.95), axis=-1)
    r2 = np.stack([radius_sq(k, w, h) for k in np.asarray(intrinsics, np.float64)]) if vignetting else None
    def fit(keep: np.ndarray) -> np.ndarray:
        """Fit on ``keep``; ``[N, H, W, 3]`` the model's prediction of the measurement."""
        nonlocal vig
        for _ in range(config.rounds if vignetting else 1):
            v = 1.0 + vig[0] * r2 + vig[1] * r2**2 if vignetting else np.ones((n_frames, h, w))
            if exposure:
                for i in range(n_frames):
                    sel = keep[i]
                    if sel.sum() < config.min_pixels:
                        gain[i], offset[i] = 1.0, 0.0
                        continue
                    for c in range(3):
                        gain[i, c], offset[i, c] = _solve_frame(p_all[i, ..., c][sel], m_all[i, ..., c][sel] / v[i][sel], config)
            q = p_all * gain[:, None, None, :] + offset[:, None, None, :]
            if vignetting and keep.sum() >= config.min_pixels:
                # measured - q = q r^2 c1 + q r^4 c2 over every kept pixel and channel.
                qq, mm = q[keep], m_all[keep]
                rr = np.repeat(r2[keep][:, None], 3, axis=1)
                a = np.stack([(qq * rr).ravel(), (qq * rr**2).ravel()], 1)
                vig = np.linalg.lstsq(a, (mm - qq).ravel(), rcond=None)[0]
        v = 1.0 + vig[0] * r2 + vig[1] * r2**2 if vignetting else np.ones((n_frames, h, w))
        return (p_all * gain[:, None, None, :] + offset[:, None, None, :]) * v[..., None]

    if vignetting:
        # A start for the alternation, which alone converges slowly (a gain absorbs the mean
        # falloff): per frame and channel, m ~ p (g + a r^2 + b r^4), then (c1, c2) = median (a, b) / g.
        ratios = []
        for i in range(n_frames):
            sel = usable[i]
            if sel.sum() < config.min_pixels:
                continue
            rr = r2[i][sel]
            for c in range(3):
                pc = p_all[i, ..., c][sel]
                a = np.stack([pc, pc * rr, pc * rr**2], 1)
                g, a1, b1 = np.linalg.lstsq(a, m_all[i, ..., c][sel], rcond=None)[0]
                if g > 1e-3:
                    ratios.append((a1 / g, b1 / g))
        if ratios:
            vig = np.median(np.asarray(ratios), axis=0)

    # Twice: the second time without the first fit's outliers (silhouettes, the twin's own misses).
    resid = np.abs(m_all - fit(usable)).max(-1)
    keep = usable.copy()
    for i in range(n_frames):
        r = resid[i][usable[i]]
        if len(r) >= config.min_pixels:
            med = np.median(r)
            keep[i] = usable[i] & (resid[i] <= med + config.outlier_mads * 1.4826 * np.median(np.abs(r - med)) + 1e-6)
    fit(keep)
    return SensorModel(
        effects=tuple(sorted(config.effects)),
        frames=frames,
        log_gain=np.log(np.maximum(gain, 1e-6)) if exposure else None,
        offset=offset if exposure else None,
        vignetting=(float(vig[0]), float(vig[1])) if vignetting else None,
    )


def remove_camera(rgb: np.ndarray, model: SensorModel, frames: Sequence[int], intrinsics: np.ndarray) -> np.ndarray:
    """``rgb [N, H, W, 3]`` uint8 frames (positions ``frames``) as the twin's camera would have
    recorded them: the inverse of ``model.apply_rgb``, for training the twin on them."""
    out = np.empty_like(rgb)
    n, h, w, _ = rgb.shape
    for i, t in enumerate(frames):
        lin = _srgb_to_linear(rgb[i].astype(np.float64) / 255.0)
        if model.vignetting is not None:
            r2 = radius_sq(intrinsics[i], w, h)
            lin = lin / (1.0 + model.vignetting[0] * r2 + model.vignetting[1] * r2**2)[..., None]
        g, o = model.frame_gain(int(t))
        lin = (lin - o) / g
        out[i] = np.round(np.clip(_linear_to_srgb(np.clip(lin, 0.0, 1.0)), 0.0, 1.0) * 255).astype(rgb.dtype)
    return out
