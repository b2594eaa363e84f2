"""A camera's vignetting found from its own frames: the same surface seen near the image centre in
one frame and near a corner in another is recorded darker there, by the lens's fall-off.

A twin trained on vignetted frames hides the effect: its view-dependent colour takes up what the
radius did, and its residual against those frames shows little. The frames themselves do not agree:
:func:`estimate_vignetting` places each frame's depth pixels in the world by its pose, finds them in
a later frame, and fits the ratio of the two recorded intensities (linear RGB) to the ratio of one
radial gain at their two image radii, with a free gain per frame pair and channel (auto exposure and
white balance change between frames). No twin, no training: the recording against itself, as
``estimate_depth_calibration`` does for depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.capture._common import scale_intrinsics
from artitwin_core.capture._config import VignettingConfig
from artitwin_core.capture._drift import block_jackknife_cov
from artitwin_core.capture._types import Capture
from artitwin_core.geometry import corner_radius_sq, pixel_rays, project


@dataclass(frozen=True)
class VignettingEstimate:
    """A camera's radial gain ``V(r) = 1 + a r^2 + b r^4`` (``r`` the distance from the principal
    point over the farthest image corner's), as its frames disagree about it.

    Attributes:
        gain: ``(a, b)``, the polynomial the sensor models use (least squares over ``r^2`` in
            ``[0, 1]`` to the fitted ``exp(c1 r^2 + c2 r^4)``).
        log_coeffs: ``(c1, c2)`` of ``log V(r) = c1 r^2 + c2 r^4``, the fitted form.
        falloff: ``1 - V(1)``, the share of light lost at the farthest corner (0 for none, > 0 for
            a darker corner).
        falloff_se: its standard error (frame-block jackknife); NaN with fewer than 3 blocks.
        residual: robust spread (1.4826 MAD) of the log-intensity ratios after the fit.
        initial_residual: the same with no vignetting (each pair's gains fitted alone).
        points: pixel pairs with a positive weight in the final fit.
    """

    gain: tuple[float, float]
    log_coeffs: tuple[float, float]
    falloff: float
    falloff_se: float
    residual: float
    initial_residual: float
    points: int


def _log_to_poly(c1: float, c2: float) -> tuple[float, float]:
    t = np.linspace(0.0, 1.0, 101)
    ab, *_ = np.linalg.lstsq(np.stack([t, t * t], 1), np.exp(c1 * t + c2 * t * t) - 1.0, rcond=None)
    return float(ab[0]), float(ab[1])


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``img [H, W, C]`` at float pixels ``u, v [N]`` (all at least one pixel inside)."""
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    return (img[v0, u0] * (1 - fu) * (1 - fv) + img[v0, u0 + 1] * fu * (1 - fv)
            + img[v0 + 1, u0] * (1 - fu) * fv + img[v0 + 1, u0 + 1] * fu * fv)  # fmt: skip


class _Frames:
    """The recording at the working size: log linear RGB, where each pixel may be used (not
    clipped, not too dark, not on a strong edge), and the scaled RGB intrinsics."""

    def __init__(self, capture: Capture, cfg: VignettingConfig):
        w, h = capture.rgb_size
        s = min(1.0, cfg.max_side / max(w, h))
        self.w, self.h = max(8, round(w * s)), max(8, round(h * s))
        self.k = scale_intrinsics(capture.rgb_intrinsics, self.w / w, self.h / h)
        self.capture, self.cfg = capture, cfg
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        if t not in self._cache:
            rgb = cv2.resize(self.capture.rgb[t], (self.w, self.h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
            lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
            log = np.log(np.maximum(lin, 1e-4))
            luma = log.mean(-1)
            grad = np.hypot(cv2.Sobel(luma, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(luma, cv2.CV_32F, 0, 1, ksize=3)) / 8
            usable = (rgb.max(-1) < self.cfg.max_srgb) & (lin.min(-1) > self.cfg.min_linear) & (grad < self.cfg.max_log_gradient)
            self._cache[t] = (log, usable)
        return self._cache[t]


def _pair_samples(frames: _Frames, poses: np.ndarray, i: int, j: int, modelled: tuple[float, float] | None):
    """Frame ``i``'s depth pixels seen again in frame ``j``: ``(y [N, 3], x [N, 2])``, the log
    ratio of the two recorded intensities per channel and ``(r_i^2 - r_j^2, r_i^4 - r_j^4)``;
    None when fewer than ``min_pair_points`` agree. ``modelled``: a vignetting already modelled,
    divided out of both intensities first."""
    cap, cfg = frames.capture, frames.cfg
    st = cfg.pixel_stride
    dh, dw = cap.depth.shape[1:]
    vv, uu = np.mgrid[0:dh:st, 0:dw:st]
    d = np.asarray(cap.depth[i], np.float64)[::st, ::st]
    ok = np.isfinite(d) & (d > 0) & (d < cfg.max_depth_m)
    if cap.confidence is not None:
        ok &= np.asarray(cap.confidence[i])[::st, ::st] >= cfg.min_confidence
    d = d[ok]
    rays = pixel_rays(np.asarray(cap.depth_intrinsics[i], np.float64), uu[ok].astype(np.float64), vv[ok].astype(np.float64))
    x_i = rays * d[:, None]  # camera i
    world = x_i @ poses[i][:3, :3].T + poses[i][:3, 3]
    x_j = (world - poses[j][:3, 3]) @ poses[j][:3, :3]
    ki, kj = frames.k[i], frames.k[j]
    ui, vi = project(x_i, ki)[0].T
    uj, vj = project(x_j, kj)[0].T
    # frame j's own depth where the point lands: a point it does not see (occluded) is not used
    ud, vd = project(x_j, np.asarray(cap.depth_intrinsics[j], np.float64))[0].T
    w, h = frames.w, frames.h
    inside = (x_j[:, 2] > 0.05) & (uj >= 1) & (uj < w - 2) & (vj >= 1) & (vj < h - 2)
    inside &= (ui >= 1) & (ui < w - 2) & (vi >= 1) & (vi < h - 2) & (ud >= 0) & (ud < dw - 0.5) & (vd >= 0) & (vd < dh - 0.5)
    idx = np.nonzero(inside)[0]
    dj = np.asarray(cap.depth[j], np.float64)[np.round(vd[idx]).astype(int), np.round(ud[idx]).astype(int)]
    with np.errstate(invalid="ignore"):
        seen = np.abs(dj - x_j[idx, 2]) < cfg.occlusion_rel * x_j[idx, 2]
    idx = idx[seen]
    if len(idx) < cfg.min_pair_points:
        return None
    log_i, use_i = frames(i)
    log_j, use_j = frames(j)
    pi_u, pi_v, pj_u, pj_v = ui[idx], vi[idx], uj[idx], vj[idx]
    use = use_i[np.round(pi_v).astype(int), np.round(pi_u).astype(int)] & use_j[np.round(pj_v).astype(int), np.round(pj_u).astype(int)]
    if np.count_nonzero(use) < cfg.min_pair_points:
        return None
    pi_u, pi_v, pj_u, pj_v = pi_u[use], pi_v[use], pj_u[use], pj_v[use]
    y = _bilinear(log_i, pi_u, pi_v) - _bilinear(log_j, pj_u, pj_v)
    r2i, r2j = corner_radius_sq(ki, pi_u, pi_v, w, h), corner_radius_sq(kj, pj_u, pj_v, w, h)
    if modelled is not None:
        a, b = modelled
        y = y - (np.log(np.maximum(1 + a * r2i + b * r2i**2, 1e-3)) - np.log(np.maximum(1 + a * r2j + b * r2j**2, 1e-3)))[:, None]
    return y, np.stack([r2i - r2j, r2i**2 - r2j**2], 1)


def _demeaned(values: np.ndarray, group: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``values [N, ...]`` minus their weighted mean within each ``group`` label (the fixed effect
    of a pair's and channel's gain)."""
    n_groups = int(group.max()) + 1
    wsum = np.bincount(group, weights, n_groups)
    flat = values.reshape(len(values), -1)
    means = np.stack([np.bincount(group, weights * flat[:, k], n_groups) for k in range(flat.shape[1])], 1)
    means /= np.maximum(wsum, 1e-12)[:, None]
    return (flat - means[group]).reshape(values.shape)


def estimate_vignetting(
    capture: Capture, world_from_camera: np.ndarray | None = None, config: VignettingConfig = VignettingConfig(),
    modelled: tuple[float, float] | None = None,
) -> VignettingEstimate:
    """The camera's vignetting, from how its frames' intensities of the same surfaces disagree.

    For frame pairs ``(i, i + gap)``, each of frame ``i``'s depth pixels (every
    ``pixel_stride``-th, confident, in range) is placed in the world by its pose and projected into
    both frames' RGB (at most ``max_side`` pixels on the long side). Where frame ``j``'s own depth
    agrees (not occluded), the log ratio of the two linear intensities is, for a surface that looks
    the same from both places, ``log V(r_i) - log V(r_j)`` plus the pair's gain ratio per channel:
    least squares in ``(c1, c2)`` of ``log V = c1 r^2 + c2 r^4`` after each pair's and channel's
    mean is removed (its free gain), with Tukey weights against what does not fit (a glossy
    highlight, a misplaced edge, a moved object). Pixels on strong image edges, clipped or very dark
    ones are not used: a pose or depth error there moves the intensity more than a lens does.

    ``modelled``: ``(a, b)`` of a vignetting already modelled; it is divided out first, so the
    estimate is what it left (0 when it was right).

    The poses must be metric and consistent with the depth (a recording's own ARKit poses).

    Raises:
        InputError: poses of the wrong shape, or too few frame pairs that see the same surfaces.
    """
    poses = np.asarray(capture.world_from_camera if world_from_camera is None else world_from_camera, np.float64)
    t_count = capture.num_frames
    if poses.shape != (t_count, 4, 4):
        raise InputError(f"estimate_vignetting: poses have shape {poses.shape}; expected ({t_count}, 4, 4).")
    frames = _Frames(capture, config)
    ys, xs, groups, blocks = [], [], [], []
    for g in config.frame_gaps:
        for i in range(t_count - g):
            s = _pair_samples(frames, poses, i, i + g, modelled)
            if s is None:
                continue
            y, x = s
            groups.append(3 * len(ys) + np.repeat(np.arange(3), len(y)))  # each (pair, channel) its own group
            ys.append(y.T.reshape(-1))  # channel-major, as the groups
            xs.append(np.tile(x, (3, 1)))
            blocks.append(np.full(3 * len(y), (i * config.jackknife_blocks) // t_count))
    if len(ys) < 2:
        raise InputError(
            f"estimate_vignetting: only {len(ys)} frame pair(s) of {t_count} frames see the same surfaces at gaps "
            f"{config.frame_gaps}; the vignetting test needs a sweep whose frames overlap."
        )
    y, x = np.concatenate(ys), np.concatenate(xs)
    group, block = np.concatenate(groups), np.concatenate(blocks)
    wts = np.ones(len(y))
    coeffs = np.zeros(2)
    initial = float("nan")
    for _ in range(config.iterations):
        yd, xd = _demeaned(y, group, wts), _demeaned(x, group, wts)
        r = yd - xd @ coeffs
        spread = float(1.4826 * np.median(np.abs(r))) + 1e-9
        if np.isnan(initial):
            initial = float(1.4826 * np.median(np.abs(yd))) + 1e-9
        wts = np.clip(1.0 - (r / (4.685 * spread)) ** 2, 0.0, 1.0) ** 2
        yd, xd = _demeaned(y, group, wts), _demeaned(x, group, wts)
        hess = (xd * wts[:, None]).T @ xd
        if np.linalg.cond(hess) > 1e12:
            raise InputError(
                "estimate_vignetting: the frames see each surface at one image radius only; record a sweep that moves "
                "surfaces across the image."
            )
        coeffs = np.linalg.solve(hess, (xd * wts[:, None]).T @ yd)
    r = yd - xd @ coeffs
    residual = float(1.4826 * np.median(np.abs(r[wts > 0]))) if np.any(wts > 0) else float("nan")
    cov = block_jackknife_cov(xd, wts, -yd, block)
    falloff = float(1.0 - np.exp(coeffs.sum()))
    falloff_se = float("nan")
    if cov is not None:
        grad = np.full(2, -np.exp(coeffs.sum()))  # d falloff / d (c1, c2)
        falloff_se = float(np.sqrt(max(grad @ cov @ grad, 0.0)))
    return VignettingEstimate(
        gain=_log_to_poly(float(coeffs[0]), float(coeffs[1])), log_coeffs=(float(coeffs[0]), float(coeffs[1])),
        falloff=falloff, falloff_se=falloff_se, residual=residual, initial_residual=initial,
        points=int(np.count_nonzero(wts > 0)),
    )
