"""The built-in effects: sensor (exposure and white balance, vignetting, depth bias, depth noise)
and joint (screw pitch, an axis that tilts with the joint state, a drawer that tilts as it slides).

Every fit is closed form or a small linear least-squares problem on the residuals. Photometric
effects work on linear RGB (the camera applies gains before its tone curve). Joint effects work on
track residuals expressed in the part's closed frame, ``s_ti = R_t^T (y_ti - M_t x_i)``, with each
track's mean removed (a per-track offset is a latent-point error, not an effect): what is left and
grows with the joint state ``q`` is a motion the joint does not model.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artitwin_core.diagnostics._patch import depth_affine_columns
from artitwin_core.diagnostics._plugin import Effect, Evidence, register_effect
from artitwin_core.diagnostics._residuals import (
    NOT_READ_BY_IMAGE_EFFECTS,
    RGB_PREDICTION_FIELDS,
    TRACK_FIELDS,
    ResidualData,
    depth_noise_bins,
    solve_points,
)
from artitwin_core.geometry import axis_angle_to_matrix


def _bins(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    edges = np.quantile(x, np.linspace(0, 1, n + 1))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, n - 1)
    return idx, 0.5 * (edges[1:] + edges[:-1])


def _binned_mean(x: np.ndarray, y: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    idx, centre = _bins(x, n)
    counts = np.bincount(idx, minlength=n)
    sums = np.bincount(idx, weights=y, minlength=n)
    return centre, np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


class ExposureWhiteBalance(Effect):
    """Per-frame, per-channel gain and offset of the camera (auto exposure, auto white balance)."""

    name = "exposure_white_balance"
    target = "photometric"
    unaffected_by = NOT_READ_BY_IMAGE_EFFECTS  # reads RGB only
    description = "Per-frame per-channel gain g and offset o on linear RGB: measured = g * predicted + o."

    def applies(self, data: ResidualData) -> bool:
        return data.has_rgb

    def fit(self, data: ResidualData):
        t_count = data.rgb_pred.shape[0]
        gain, offset = np.ones((t_count, 3)), np.zeros((t_count, 3))
        ratio = np.full((t_count, 3), np.nan)
        for t in range(t_count):
            v = data.rgb_valid[t]
            if v.sum() < 20:
                continue
            p, m = data.rgb_pred[t][v].astype(np.float64), data.rgb_meas[t][v].astype(np.float64)
            for c in range(3):
                a = np.stack([p[:, c], np.ones(len(p))], 1)
                gain[t, c], offset[t, c] = np.linalg.lstsq(a, m[:, c], rcond=None)[0]
                ratio[t, c] = m[:, c].sum() / max(p[:, c].sum(), 1e-9)
        model = gain + offset / np.maximum(
            np.array([[data.rgb_pred[t][data.rgb_valid[t]][:, c].mean() if data.rgb_valid[t].any() else 1.0
                       for c in range(3)] for t in range(t_count)]), 1e-9)
        ev = Evidence("measured / predicted brightness per frame", "frame", "ratio (linear)",
                      list(range(t_count)), ratio.T.tolist(), model.T.tolist(), ("R", "G", "B"))
        log2 = np.log2(np.clip(gain.mean(1), 1e-6, None))
        params = {"gain": gain.tolist(), "offset": offset.tolist(), "exposure_stops_std": float(np.std(log2)),
                  "white_balance_rb_std": float(np.std(gain[:, [0, 2]] / gain[:, 1:2]))}
        return params, ev

    def transfer(self, params: dict, train: ResidualData, heldout: ResidualData) -> dict:
        """White balance (gain ratios to green) and offsets are the camera's, fixed from training;
        the exposure of a held-out frame is one scalar per frame, refitted on that frame."""
        gain, offset = np.array(params["gain"], np.float64), np.array(params["offset"], np.float64)
        fitted = train.rgb_valid.sum((1, 2)) >= 20
        if not fitted.any():
            return params
        wb = np.median(gain[fitted] / np.maximum(gain[fitted][:, 1:2], 1e-9), 0)  # [3], green = 1
        o = np.median(offset[fitted], 0)
        for t in np.flatnonzero(heldout.rgb_valid.sum((1, 2)) >= 20):
            v = heldout.rgb_valid[t]
            p = heldout.rgb_pred[t][v].astype(np.float64) * wb
            m = heldout.rgb_meas[t][v].astype(np.float64) - o
            exposure = float(np.sum(p * m) / max(np.sum(p * p), 1e-12))
            gain[t], offset[t] = exposure * wb, o
        return {**params, "gain": gain.tolist(), "offset": offset.tolist()}

    def apply(self, data: ResidualData, params: dict) -> ResidualData:
        g = np.asarray(params["gain"], np.float32)[:, None, None, :]
        o = np.asarray(params["offset"], np.float32)[:, None, None, :]
        return replace(data, rgb_pred=(data.rgb_pred * g + o).astype(np.float32))


class Vignetting(Effect):
    """Radial fall-off of the lens: gain 1 + c1 r^2 + c2 r^4, r normalised to 1 at the farthest corner."""

    name = "vignetting"
    target = "photometric"
    unaffected_by = NOT_READ_BY_IMAGE_EFFECTS  # reads RGB only
    description = "Radial gain 1 + c1 r^2 + c2 r^4 on linear RGB, shared by every frame."

    def applies(self, data: ResidualData) -> bool:
        return data.has_rgb

    def fit(self, data: ResidualData):
        rho = data.radius()
        v = data.rgb_valid
        r2 = np.repeat(rho[v][:, None] ** 2, 3, 1).ravel()
        p = data.rgb_pred[v].astype(np.float64).ravel()
        m = data.rgb_meas[v].astype(np.float64).ravel()
        a = np.stack([p * r2, p * r2**2], 1)
        c1, c2 = np.linalg.lstsq(a, m - p, rcond=None)[0]
        x, ratio_m = _binned_mean(np.sqrt(r2), m, 12)
        _, ratio_p = _binned_mean(np.sqrt(r2), p, 12)
        ratio = ratio_m / np.maximum(ratio_p, 1e-9)
        ev = Evidence("measured / predicted brightness vs image radius", "radius / corner radius", "ratio",
                      x.tolist(), ratio.tolist(), (1 + c1 * x**2 + c2 * x**4).tolist())
        return {"c1": float(c1), "c2": float(c2), "corner_falloff": float(-(c1 + c2))}, ev

    def apply(self, data: ResidualData, params: dict) -> ResidualData:
        r2 = data.radius() ** 2
        gain = (1.0 + params["c1"] * r2 + params["c2"] * r2**2).astype(np.float32)
        return replace(data, rgb_pred=(data.rgb_pred * gain[..., None]).astype(np.float32))


class DepthScaleOffset(Effect):
    """An affine depth error of the sensor: measured = scale * true + offset."""

    name = "depth_scale_offset"
    target = "depth"
    unaffected_by = TRACK_FIELDS | RGB_PREDICTION_FIELDS | {"depth_sigma"}  # the depth residual only
    description = "Per-recording affine depth error: measured = scale * predicted + offset_m."

    def applies(self, data: ResidualData) -> bool:
        return data.has_depth

    def fit(self, data: ResidualData):
        r = data.depth_residual()
        ok = np.isfinite(r)
        z, m = data.depth_pred[ok].astype(np.float64), data.depth_meas[ok].astype(np.float64)
        keep = np.ones(z.size, bool)
        for _ in range(3):  # trimmed least squares: edge pixels and missing geometry are not a bias
            s, o = np.linalg.lstsq(np.stack([z[keep], np.ones(keep.sum())], 1), m[keep], rcond=None)[0]
            e = m - (s * z + o)
            keep = np.abs(e) < 4.0 * 1.4826 * np.median(np.abs(e[keep])) + 1e-6
        x, y = _binned_mean(z, m - z, 10)
        ev = Evidence("depth residual vs depth", "predicted depth (m)", "measured - predicted (m)",
                      x.tolist(), y.tolist(), ((s - 1) * x + o).tolist())
        return {"scale": float(s), "offset_m": float(o)}, ev

    def null_columns(self, geometry):
        return depth_affine_columns(geometry)

    def apply(self, data: ResidualData, params: dict) -> ResidualData:
        # The sensor's error is removed from the measurement (the twin's geometry stays metric).
        m = (data.depth_meas - params["offset_m"]) / params["scale"]
        return replace(data, depth_meas=m.astype(np.float32))


class DepthNoise(Effect):
    """Depth noise that grows with distance, sigma(z) = a + b z^2 (stereo/ToF-like)."""

    name = "depth_noise"
    target = "depth-noise"
    unaffected_by = TRACK_FIELDS | RGB_PREDICTION_FIELDS  # the depth residual and sigma(z)
    description = "Depth noise model sigma(z) = a_m + b_per_m * z^2, fitted to the depth-binned residual spread."

    def applies(self, data: ResidualData) -> bool:
        return data.has_depth

    def fit(self, data: ResidualData):
        z, spread, count = depth_noise_bins(data)
        if z.size < 2:
            return {"a_m": data.depth_sigma[0], "b_per_m": data.depth_sigma[1]}, None
        w = np.sqrt(count) / spread  # relative errors: the target is a log ratio
        a_mat = np.stack([np.ones_like(z), z**2], 1) * w[:, None]
        a, b = np.linalg.lstsq(a_mat, spread * w, rcond=None)[0]
        if a < 0 or b < 0:  # fall back to the single term that fits
            only_b = np.sum(w**2 * spread * z**2) / np.sum(w**2 * z**4)
            only_a = np.sum(w**2 * spread) / np.sum(w**2)
            err_b = np.sum((w * (spread - only_b * z**2)) ** 2)
            err_a = np.sum((w * (spread - only_a)) ** 2)
            a, b = (0.0, only_b) if err_b < err_a else (only_a, 0.0)
        a0, b0 = data.depth_sigma
        ev = Evidence("depth residual spread vs depth", "depth (m)", "robust std (m)", z.tolist(), spread.tolist(),
                      (a + b * z**2).tolist())
        return {"a_m": float(a), "b_per_m": float(b), "assumed_a_m": float(a0), "assumed_b_per_m": float(b0)}, ev

    def apply(self, data: ResidualData, params: dict) -> ResidualData:
        return replace(data, depth_sigma=(float(params["a_m"]), float(params["b_per_m"])))


def _perp_basis(a: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a)
    helper = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(a, e1)])


class _LinearTwist(Effect):
    """A motion the joint misses that grows linearly with q: M'_t = M_t exp(q_t xi), xi a body twist
    about ``origin`` restricted to a subspace (rotation directions, translation directions)."""

    joint_types: tuple[str, ...] = ()

    def applies(self, data: ResidualData) -> bool:
        return data.has_tracks and data.tracks.joint_type in self.joint_types and data.tracks_valid.sum() > 10

    def _basis(self, data: ResidualData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rotation directions ``[kw, 3]``, translation directions ``[kv, 3]`` and the origin ``[3]``."""
        raise NotImplementedError

    def _design(self, data: ResidualData):
        tm = data.tracks
        bw, bv, origin = self._basis(data)
        valid = data.tracks_valid
        rot = tm.motions[:, :3, :3]
        s = np.einsum("tji,tnj->tni", rot, np.nan_to_num(data.track_residual()))
        n = np.maximum(valid.sum(0), 1)
        q = np.broadcast_to(tm.q[:, None], valid.shape)
        q_c = np.where(valid, q - (np.where(valid, q, 0).sum(0) / n)[None], 0.0)
        s_c = np.where(valid[..., None], s - (np.where(valid[..., None], s, 0).sum(0) / n[:, None])[None], 0.0)
        x = tm.points_closed - origin
        cols = [np.cross(w, x)[None] * q_c[..., None] for w in bw] + [q_c[..., None] * v[None, None] for v in bv]
        g = np.stack(cols, -1)  # [T, N, 3, k]
        return g[valid].reshape(-1, g.shape[-1]), s_c[valid].reshape(-1), bw, bv, origin, q_c, s_c

    def fit(self, data: ResidualData):
        a, b, bw, bv, origin, q_c, s_c = self._design(data)
        theta = np.linalg.lstsq(a, b, rcond=None)[0]
        w = theta[: len(bw)] @ bw if len(bw) else np.zeros(3)
        v = theta[len(bw):] @ bv if len(bv) else np.zeros(3)
        # Evidence: per frame, the amount of the fitted pattern in the residual, against q.
        pattern = np.cross(w, data.tracks.points_closed - origin) + v  # [N, 3] per unit q
        valid = data.tracks_valid
        num = np.einsum("tni,ni->t", np.where(valid[..., None], s_c, 0.0), pattern)
        den = np.einsum("tn,n->t", valid.astype(float), np.sum(pattern**2, -1))
        amount = np.where(den > 0, num / np.maximum(den, 1e-12), np.nan)
        q_cm = np.where(valid.any(1), q_c.sum(1) / np.maximum(valid.sum(1), 1), np.nan)
        ev = Evidence(f"{self.name}: fitted pattern in the track residual vs joint state", "q",
                      "pattern amount (q units)", data.tracks.q.tolist(), amount.tolist(), q_cm.tolist())
        return self._params(w, v, origin, data), ev

    def _params(self, w, v, origin, data) -> dict:
        return {"rotation_per_q": w.tolist(), "translation_per_q": v.tolist(), "origin": origin.tolist()}

    def apply(self, data: ResidualData, params: dict) -> ResidualData:
        tm = data.tracks
        w = np.asarray(params["rotation_per_q"], np.float64)
        v = np.asarray(params["translation_per_q"], np.float64)
        c = np.asarray(params["origin"], np.float64)
        angle = np.linalg.norm(w)
        t_count = tm.q.shape[0]
        corr = np.tile(np.eye(4), (t_count, 1, 1))
        if angle > 0:
            corr[:, :3, :3] = axis_angle_to_matrix(w / angle, tm.q * angle)
        corr[:, :3, 3] = c - np.einsum("tij,j->ti", corr[:, :3, :3], c) + tm.q[:, None] * v
        motions = tm.motions @ corr
        points = solve_points(motions, data.tracks_obs, data.tracks_valid, tm.points_closed)
        return replace(data, tracks=replace(tm, motions=motions, points_closed=points))


class ScrewJoint(_LinearTwist):
    """A hinge that also travels along its axis as it turns (a rising hinge, a lid on a thread)."""

    name = "screw_joint"
    target = "joint-tracks"
    description = "Revolute joint plus translation pitch * q along its axis (a screw joint)."
    joint_types = ("revolute",)

    def _basis(self, data):
        a = data.tracks.axis / np.linalg.norm(data.tracks.axis)
        return np.zeros((0, 3)), a[None], data.tracks.pivot

    def _params(self, w, v, origin, data):
        a = data.tracks.axis / np.linalg.norm(data.tracks.axis)
        return {**super()._params(w, v, origin, data), "pitch_m_per_rad": float(v @ a)}


class AxisTilt(_LinearTwist):
    """A hinge axis whose direction changes with the joint state (a sagging door)."""

    name = "axis_tilt"
    target = "joint-tracks"
    description = "Revolute joint whose axis tilts by tilt_rad_per_rad * q about a direction normal to it."
    joint_types = ("revolute",)

    def _basis(self, data):
        b = _perp_basis(data.tracks.axis)
        return b, b, data.tracks.pivot

    def _params(self, w, v, origin, data):
        return {**super()._params(w, v, origin, data), "tilt_rad_per_rad": float(np.linalg.norm(w))}


class DrawerTilt(_LinearTwist):
    """A drawer that pitches or rolls as it slides out (worn runners, a heavy front)."""

    name = "drawer_tilt"
    target = "joint-tracks"
    description = "Prismatic joint whose part rotates by tilt_rad_per_m * q about a direction normal to the slide."
    joint_types = ("prismatic",)

    def _basis(self, data):
        # The tilt's centre is anywhere on the part (a runner's end, the back edge): a rotation
        # about it is one about the centroid plus a translation in any direction.
        return _perp_basis(data.tracks.axis), np.eye(3), np.nanmean(data.tracks.points_closed, 0)

    def _params(self, w, v, origin, data):
        return {**super()._params(w, v, origin, data), "tilt_rad_per_m": float(np.linalg.norm(w))}


BUILTIN_EFFECTS = (ExposureWhiteBalance, Vignetting, DepthScaleOffset, DepthNoise, ScrewJoint, AxisTilt, DrawerTilt)
for _cls in BUILTIN_EFFECTS:
    register_effect(_cls)
