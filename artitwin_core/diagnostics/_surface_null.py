"""The twin's own geometry as a null hypothesis for camera-motion effects.

An unconverged twin has surfaces in slightly the wrong place. Its depth residual is then fixed in
the world: every frame that sees a surface sees the same error there. A camera-motion effect (pose
drift) moves the measured point cloud by a different rigid motion per frame; its residual at one
place in the world changes with time. A drift model is flexible enough to pass for a world-fixed
error when the camera sees different surfaces at different times (a wall 2 cm too far is a
translation while the camera faces it, a floor 2 cm too high another one later), so the share of
the depth residual it explains is no evidence by itself.

The test is a panel regression with one fixed effect per surface patch. The depth residual is
taken as a point-to-plane distance ``e = n . (q - p)`` (predicted point ``p``, its normal ``n``,
measured point ``q``), whitened by the assumed depth noise sigma(z), and grouped by world voxel and
surface orientation. The patch means (the static per-surface correction: anything fixed in the
world, a constant rigid misplacement of the twin included) are the null. The effect's time-varying
part (for pose drift, the rates: ``s (q x n)``, ``s n`` with ``s`` the time) is fitted only to what
varies within a patch across frames (the within estimator). Both are fitted on training frames and
scored on held-out frames (every ``every``-th, as ``evaluate_heldout``) on patches seen in training
from at least two frames: the null predicts the patch mean, the effect the patch mean plus its
time-varying part. A camera motion is accepted only when it cuts the null's held-out error by a
clear share: a twin's own error leaves nothing that varies with time for it to explain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artitwin_core.diagnostics._camera import _backproject, _normals
from artitwin_core.diagnostics._heldout import heldout_frames
from artitwin_core.diagnostics._patch import PatchGeometry, drift_columns
from artitwin_core.diagnostics._residuals import ResidualData

# Pixels seen more grazing than this (|cos| of the ray against the normal) are left out.
_MIN_COS = 0.3


@dataclass(frozen=True)
class SurfaceNullCheck:
    """A camera-motion effect against the twin-geometry null, on held-out frames.

    Energies are mean squared point-to-plane residuals whitened by sigma(z) (1 = the assumed
    depth noise along the ray), over held-out pixels whose patch was seen in training.

    Attributes:
        name: the effect.
        n_pixels: held-out pixels scored.
        energy_before: with no correction.
        energy_null: with the static per-surface correction (patch means from training frames).
        energy_effect: with the patch means plus the effect's time-varying part.
        floor: the whitened noise energy of those pixels (mean cos^2 of the incidence).
        accepted: the effect cuts ``energy_null`` by ``min_gain`` of it and ``min_floors`` floors.
        rates: the effect's parameters fitted within patches, free of the twin's world-fixed error
            (pose drift: ``(w1 [3] rad/s, v1 [3] m/s)``, ``PoseDrift``'s ``rot_rad_per_s`` and
            ``trans_m_per_s``; depth affine: ``(scale - 1, offset_m)``).
    """

    name: str
    n_pixels: int
    energy_before: float
    energy_null: float
    energy_effect: float
    floor: float
    accepted: bool
    rates: tuple[float, ...] = ()

    @property
    def null_fraction(self) -> float:
        """Share of the held-out depth residual the static twin-geometry correction explains."""
        return 1.0 - self.energy_null / self.energy_before if self.energy_before > 0 else 0.0

    @property
    def gain_over_null(self) -> float:
        """Share of what the null leaves that the effect removes as well."""
        return 1.0 - self.energy_effect / self.energy_null if self.energy_null > 0 else 0.0


def default_voxel_m(data: ResidualData) -> float:
    """Patch size: three depth pixels' footprint at the median depth, at least 4 cm."""
    z = float(np.nanmedian(data.depth_pred)) if np.isfinite(data.depth_pred).any() else 1.0
    return float(max(0.04, 3.0 * z / np.median(data.depth_intrinsics[:, 0])))


def _panel(data: ResidualData, voxel_m: float, columns):
    """Per usable depth pixel: frame, patch key, whitened residual ``y``, whitened effect columns
    ``x [n, k]`` (``columns(PatchGeometry)``), and ``cos^2`` of the incidence."""
    k, poses = data.depth_intrinsics, data.world_from_camera
    p = _backproject(data.depth_pred, k, poses)
    q = _backproject(data.depth_meas, k, poses)
    n = _normals(p)
    ray = p - poses[:, None, None, :3, 3]
    cos = np.sum(n * ray, -1) / np.maximum(np.linalg.norm(ray, axis=-1), 1e-9)
    ok = np.isfinite(data.depth_residual()) & np.all(np.isfinite(n), -1) & (np.abs(cos) >= _MIN_COS)
    frame = np.broadcast_to(np.arange(ok.shape[0])[:, None, None], ok.shape)[ok]
    p, q, n = p[ok], q[ok], n[ok]
    a, b = data.depth_sigma
    z = data.depth_pred[ok].astype(np.float64)
    w = 1.0 / (a + b * z**2)
    geo = PatchGeometry(p, q, n, z, np.linalg.norm(ray[ok], axis=-1), cos[ok],
                        data.timestamps[frame] - data.timestamps[0])
    x = columns(geo) * w[:, None]
    y = np.sum(n * (q - p), -1) * w
    # Patch: world voxel and the normal's dominant axis and sign (two walls meeting stay apart).
    axis = np.argmax(np.abs(n), -1)
    sign = (np.take_along_axis(n, axis[:, None], -1)[:, 0] > 0).astype(np.int64)
    cell = np.floor(p / voxel_m).astype(np.int64) + (1 << 15)
    key = (((cell[:, 0] << 32) | (cell[:, 1] << 16) | cell[:, 2]) << 3) | (axis * 2 + sign)
    return frame, key, y, x, cos[ok] ** 2


def _group_means(key: np.ndarray, values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Mean of ``values [n, ...]`` per entry of the sorted ``groups`` (rows of ``key`` outside: 0)."""
    idx = np.searchsorted(groups, key)
    count = np.bincount(idx, minlength=groups.size).astype(np.float64)
    flat = values.reshape(values.shape[0], -1)
    sums = np.stack([np.bincount(idx, weights=flat[:, j], minlength=groups.size) for j in range(flat.shape[1])], 1)
    return (sums / np.maximum(count, 1)[:, None]).reshape((groups.size,) + values.shape[1:])


def surface_null_check(data: ResidualData, name: str = "pose_drift", every: int = 4, min_gain: float = 0.2,
                       min_floors: float = 0.5, voxel_m: float | None = None,
                       columns=drift_columns) -> SurfaceNullCheck:
    """Does an effect explain clearly more of the depth residual than the twin's own world-fixed
    geometry error? See the module docstring. ``columns(PatchGeometry) -> [n, k]`` is the effect's
    linearised change of the point-to-plane residual (default: a pose drift's rates); ``every``
    picks the held-out frames."""
    voxel_m = default_voxel_m(data) if voxel_m is None else voxel_m
    frame, key, y, x, cos2 = _panel(data, voxel_m, columns)
    held = heldout_frames(data.depth_pred.shape[0], every)[frame]
    train = ~held
    # Patches seen in training from at least two frames carry a within-patch (over time) signal.
    tk, tf = key[train], frame[train]
    pairs = np.unique(np.stack([tk, tf], 1), axis=0) if tk.size else np.zeros((0, 2), np.int64)
    groups, n_frames = np.unique(pairs[:, 0], return_counts=True)
    groups = groups[n_frames >= 2]
    in_train = train & np.isin(key, groups)
    scored = held & np.isin(key, groups)
    nan = float("nan")
    if in_train.sum() < 50 or scored.sum() < 20:
        return SurfaceNullCheck(name, int(scored.sum()), nan, nan, nan, nan, False)
    y_mean = _group_means(key[in_train], y[in_train], groups)
    x_mean = _group_means(key[in_train], x[in_train], groups)
    gi_t = np.searchsorted(groups, key[in_train])
    xw, yw = x[in_train] - x_mean[gi_t], y[in_train] - y_mean[gi_t]
    scale = np.maximum(np.linalg.norm(xw, axis=0), 1e-12)
    rates = np.linalg.lstsq(xw / scale, yw, rcond=None)[0] / scale
    gi = np.searchsorted(groups, key[scored])
    ys = y[scored]
    null = ys - y_mean[gi]
    effect = null - (x[scored] - x_mean[gi]) @ rates
    e_before, e_null, e_effect = (float(np.mean(v**2)) for v in (ys, null, effect))
    floor = float(np.mean(cos2[scored]))
    gain = e_null - e_effect
    ok = bool(gain >= min_gain * e_null and gain >= min_floors * floor)
    # y is +n.(q - p) where PoseDrift solves for -n.(q - p): its rates are the negatives.
    return SurfaceNullCheck(name, int(scored.sum()), e_before, e_null, e_effect, floor, ok,
                            tuple(-float(r) for r in rates))
