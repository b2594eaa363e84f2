"""One joint hypothesis fitted to the tracks by alternation (step 2 of ``estimate_joint``).

The fit alternates (a) ``scipy.optimize.least_squares`` over the joint parameters (axis on the
sphere, pivot in the plane normal to the axis, pitch, one ``q`` per frame), (b) the closed-form
latent closed-state points ``X_i`` (mean of back-projected observations) and (c) robust Cauchy
weights with a hard gate at ``inlier_sigmas`` noise levels. Step (a) is exact and cheap because,
for fixed ``X`` and weights, a frame's weighted sum of squared point residuals under a rigid motion
equals the squared norm of 21 numbers (``_compress``). Each hypothesis starts in closed form from
the per-frame rigid motions (``_init_rotational``, ``_init_prismatic``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from artitwin_core.joints._config import JointFitConfig
from artitwin_core.joints._model import joint_motion, rotations_about, skew
from artitwin_core.joints._rigid import CHI3_MEDIAN
from artitwin_core.joints._types import JointType


@dataclass
class _Fit:
    """Internal state of one hypothesis fit (q free at every frame: gauge fixed afterwards)."""

    kind: JointType
    axis: np.ndarray
    pivot: np.ndarray
    pitch: float
    q: np.ndarray  # [T], NaN where the frame had too few inliers
    points: np.ndarray  # [N, 3] latent positions in the gauge of this fit
    weights: np.ndarray  # [T, N]
    track_ok: np.ndarray  # [N]
    sigma_t: np.ndarray  # [T]
    axis_se: float | None = None  # radians, from the frame-level fit (revolute)
    pivot_se: float | None = None  # metres, across the axis


def _tangent_basis(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.eye(3)[np.argmin(np.abs(a))]
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


def _motions(fit_kind: JointType, axis, pivot, q, pitch) -> tuple[np.ndarray, np.ndarray]:
    qq = np.nan_to_num(q)
    return joint_motion(fit_kind, axis, pivot, qq, pitch)


def _predict(rot: np.ndarray, trans: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.matmul(points[None], np.swapaxes(rot, 1, 2)) + trans[:, None, :]


def _residuals(rot, trans, points, y, valid) -> np.ndarray:
    r = np.linalg.norm(_predict(rot, trans, points) - y, axis=-1)
    return np.where(valid, r, np.inf)


def _update_points(rot, trans, y, valid, weights, fallback: np.ndarray) -> np.ndarray:
    """Closed-form latent points: weighted mean of the back-projected observations."""
    back = np.matmul(y - trans[:, None, :], rot)
    w = weights
    wsum = w.sum(0)
    out = (w[..., None] * back).sum(0) / np.maximum(wsum, 1e-300)[:, None]
    # Tracks with no weight keep a plain mean over their valid frames so they can be re-tested.
    vw = valid.astype(float)
    vsum = vw.sum(0)
    plain = (vw[..., None] * back).sum(0) / np.maximum(vsum, 1)[:, None]
    out = np.where((wsum > 0)[:, None], out, np.where((vsum > 0)[:, None], plain, fallback))
    return out


def _robust_weights(r, valid, track_ok_prev, sigma_glob, cfg: JointFitConfig):
    """Per-frame noise scale, hard gate and Cauchy weights from residuals ``r [T, N]``."""
    t_count = r.shape[0]
    use = valid & track_ok_prev[None, :]
    enough = use.sum(1) >= cfg.min_frame_tracks
    med = np.full(t_count, sigma_glob * CHI3_MEDIAN)
    if enough.any():
        med[enough] = np.nanmedian(np.where(use[enough], r[enough], np.nan), axis=1)
    sigma_t = med / CHI3_MEDIAN
    sigma_t = np.maximum(sigma_t, cfg.noise_floor_m)
    thr = np.maximum(cfg.min_inlier_threshold_m, cfg.inlier_sigmas * sigma_t)
    inl = valid & (r <= thr[:, None])
    nv = valid.sum(0)
    frac = inl.sum(0) / np.maximum(nv, 1)
    track_ok = (nv >= 2) & (frac >= cfg.min_track_inlier_fraction)
    scale = cfg.robust_scale_sigmas * sigma_t[:, None]
    rr = np.where(inl, r, 0.0)
    w = np.where(inl & track_ok[None, :], 1.0 / (1.0 + (rr / scale) ** 2), 0.0)
    return w, track_ok, sigma_t


def _compress(points, y, weights, frames):
    """Per frame: sqrt(W), weighted centroids and a 6x6 square root of the centred Gram matrix.

    For ``z_i = [x_i - xb, y_i - yb]`` and ``G = sum_i w_i z_i z_i^T = F^T F`` (``F`` from the
    eigendecomposition, so rank-deficient frames are fine), ``sum_i w_i |R (x_i - xb) - (y_i - yb)|^2
    = |F[:, :3] R^T - F[:, 3:]|_F^2``: 18 numbers carry every point's rotational residual.
    """
    w = weights[frames]
    yy = y[frames]
    ws = w.sum(1)
    xb = (w @ points) / ws[:, None]
    yb = np.einsum("fn,fni->fi", w, yy) / ws[:, None]
    z = np.concatenate([np.broadcast_to(points, yy.shape) - xb[:, None], yy - yb[:, None]], axis=-1)
    gram = np.matmul(np.swapaxes(z * w[..., None], 1, 2), z)
    lam, vec = np.linalg.eigh(gram)
    root = np.sqrt(np.clip(lam, 0.0, None))[:, :, None] * np.swapaxes(vec, 1, 2)
    return np.sqrt(ws), xb, yb, root[:, :, :3], root[:, :, 3:]


def _theta_problem(fit: _Fit, y: np.ndarray, frames: np.ndarray):
    """The compressed least-squares problem of the joint parameters for fixed points and weights.

    Returns ``(fun, jac, x0, unpack)``: residuals ``[F * rows]``, their analytic Jacobian
    ``[F * rows, n_glob + F]``, the start (zero tangent steps, current pitch and ``q``) and a map
    from parameters to ``(axis, pivot, pitch, q [F])``.
    """
    kind = fit.kind
    sw, xb, yb, a_mat, b_mat = _compress(fit.points, y, fit.weights, frames)
    a0 = fit.axis / np.linalg.norm(fit.axis)
    e1, e2 = _tangent_basis(a0)
    p0 = fit.pivot
    n_glob = {"prismatic": 2, "revolute": 4, "screw": 5}[kind]
    f = len(frames)
    q0 = np.nan_to_num(fit.q[frames])
    rows = 3 if kind == "prismatic" else 21

    def unpack(x):
        ax = a0 + x[0] * e1 + x[1] * e2
        ax = ax / np.linalg.norm(ax)
        if kind == "prismatic":
            return ax, p0, 0.0, x[2:]
        piv = p0 + x[2] * e1 + x[3] * e2
        pitch = x[4] if kind == "screw" else 0.0
        return ax, piv, pitch, x[n_glob:]

    def fun(x):
        ax, piv, pitch, q = unpack(x)
        if kind == "prismatic":
            return (sw[:, None] * (xb + q[:, None] * ax - yb)).ravel()
        rot = rotations_about(ax, q)
        trans = piv - rot @ piv + (pitch * q)[:, None] * ax
        r1 = sw[:, None] * (np.einsum("fij,fj->fi", rot, xb) + trans - yb)
        r2 = a_mat @ np.swapaxes(rot, -1, -2) - b_mat
        return np.concatenate([r1, r2.reshape(f, 18)], axis=1).ravel()

    def dir_derivs(x):
        # d axis / d (u1, u2) at x: the normalisation's projection applied to e1, e2.
        raw = a0 + x[0] * e1 + x[1] * e2
        nr = np.linalg.norm(raw)
        ax = raw / nr
        proj = (np.eye(3) - np.outer(ax, ax)) / nr
        return ax, (proj @ e1, proj @ e2)

    def jac(x):
        ax, piv, pitch, q = unpack(x)
        _, dax = dir_derivs(x)
        jm = np.zeros((f, rows, n_glob + f))
        fi = np.arange(f)
        if kind == "prismatic":
            for j in range(2):
                jm[:, :, j] = sw[:, None] * q[:, None] * dax[j]
            jm[fi, :, n_glob + fi] = sw[:, None] * ax
            return jm.reshape(f * rows, n_glob + f)
        k = skew(ax)
        rot = rotations_about(ax, q)
        lever = np.einsum("fij,fj->fi", rot, xb - piv)
        rt = np.swapaxes(rot, -1, -2)
        art = a_mat @ rt
        for j in range(2):
            # Rotation derivative wrt the axis through the left Jacobian of SO(3) at q * axis.
            omega = (
                q[:, None] * dax[j]
                + (1 - np.cos(q))[:, None] * (k @ dax[j])
                + (q - np.sin(q))[:, None] * (k @ k @ dax[j])
            )
            om = skew(omega)
            jm[:, :3, j] = sw[:, None] * (np.cross(omega, lever) + (pitch * q)[:, None] * dax[j])
            jm[:, 3:, j] = (-(art @ om)).reshape(f, 18)
        for j, e in enumerate((e1, e2)):
            jm[:, :3, 2 + j] = sw[:, None] * (e - rot @ e)
        if kind == "screw":
            jm[:, :3, 4] = sw[:, None] * q[:, None] * ax
        jm[fi, :3, n_glob + fi] = sw[:, None] * (lever @ k.T + pitch * ax)
        jm[fi, 3:, n_glob + fi] = (-(art @ k)).reshape(f, 18)
        return jm.reshape(f * rows, n_glob + f)

    x0 = np.zeros(n_glob + f)
    if kind == "screw":
        x0[4] = fit.pitch
    x0[n_glob:] = q0
    return fun, jac, x0, unpack


def _theta_step(fit: _Fit, y: np.ndarray, frames: np.ndarray) -> None:
    """One least-squares solve of the joint parameters for fixed latent points and weights."""
    fun, jac, x0, unpack = _theta_problem(fit, y, frames)
    sol = least_squares(
        fun, x0, jac=jac, method="lm", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=50
    )
    ax, piv, pitch, q = unpack(sol.x)
    fit.axis, fit.pivot, fit.pitch = ax, piv, float(pitch)
    qn = np.full(fit.q.shape, np.nan)
    qn[frames] = q
    fit.q = qn


def _frames_with_support(weights: np.ndarray) -> np.ndarray:
    return np.nonzero((weights > 0).sum(1) >= 3)[0]


def _start_fit(kind, init, y, w0, x0, sigma_glob) -> _Fit:
    axis, pivot, pitch, q = init
    return _Fit(
        kind,
        axis,
        pivot,
        pitch,
        q.copy(),
        x0.copy(),
        w0.copy(),
        w0.sum(0) > 0,
        np.full(y.shape[0], sigma_glob),
    )


def _iterate(fit: _Fit, y, valid, sigma_glob, cfg: JointFitConfig, max_iterations: int) -> bool:
    """Alternate joint parameters / latent points / robust weights; True once the cost settled."""
    kind = fit.kind
    prev = np.inf
    for _ in range(max_iterations):
        frames = _frames_with_support(fit.weights)
        if kind != "fixed" and len(frames) >= 2:
            _theta_step(fit, y, frames)
        if kind in ("revolute", "screw") and _pivot_runaway(fit, cfg):
            return False
        rot, trans = _motions(kind, fit.axis, fit.pivot, fit.q, fit.pitch)
        fit.points = _update_points(rot, trans, y, valid, fit.weights, fit.points)
        r = _residuals(rot, trans, fit.points, y, valid)
        fit.weights, fit.track_ok, fit.sigma_t = _robust_weights(r, valid, fit.track_ok, sigma_glob, cfg)
        fit.points = _update_points(rot, trans, y, valid, fit.weights, fit.points)
        r = _residuals(rot, trans, fit.points, y, valid)
        cost = float(np.sum(fit.weights * np.where(fit.weights > 0, r, 0.0) ** 2))
        if abs(prev - cost) <= cfg.tolerance * max(cost, 1e-300) or cost == 0.0:
            return True
        prev = cost
    return False


def _pivot_runaway(fit: _Fit, cfg: JointFitConfig) -> bool:
    """A rotation about an axis this far from the part is a translation in disguise: stop."""
    part = fit.track_ok if fit.track_ok.any() else np.ones(fit.points.shape[0], bool)
    off = fit.points[part].mean(0) - fit.pivot
    off -= (off @ fit.axis) * fit.axis
    return bool(np.linalg.norm(off) > cfg.max_pivot_distance_m)


def _fit_q(fit: _Fit) -> np.ndarray:
    """``q [T]`` with NaN where the frame kept fewer than 3 inliers."""
    frames = _frames_with_support(fit.weights)
    q = np.full(fit.q.shape, np.nan)
    q[frames] = fit.q[frames] if fit.kind != "fixed" else 0.0
    return q


def _init_rotational(rots, trans, has, centroid, with_pitch):
    """Axis from the stacked rotation vectors, pivot (and pitch) from ``t = (I - R) p + h q a``."""
    rotvec = Rotation.from_matrix(rots[has]).as_rotvec()
    _, _, vt = np.linalg.svd(rotvec, full_matrices=False)
    axis = vt[0]
    if np.sum(rotvec @ axis) < 0:
        axis = -axis
    q = np.zeros(rots.shape[0])
    q[has] = rotvec @ axis
    rows, rhs = [], []
    for t in np.nonzero(has)[0]:
        block = np.eye(3) - rots[t]
        col = (q[t] * axis)[:, None] if with_pitch else np.zeros((3, 0))
        rows.append(np.hstack([block, col]))
        rhs.append(trans[t])
    extra = 1 if with_pitch else 0
    # The axis component of the pivot is free: pin it to the centroid's; a weak pull towards the
    # centroid keeps the solve well posed when the rotation is tiny (prismatic data).
    rows.append(np.hstack([axis, np.zeros(extra)])[None])
    rhs.append(np.array([axis @ centroid]))
    lam = 1e-4
    rows.append(np.hstack([lam * np.eye(3), np.zeros((3, extra))]))
    rhs.append(lam * centroid)
    sol = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    pitch = float(sol[3]) if with_pitch else 0.0
    return axis, sol[:3], pitch, q


def _init_prismatic(rots, trans, has, centroid):
    disp = np.einsum("tij,j->ti", rots[has], centroid) + trans[has] - centroid
    _, _, vt = np.linalg.svd(disp, full_matrices=False)
    axis = vt[0]
    if np.sum(disp @ axis) < 0:
        axis = -axis
    q = np.zeros(rots.shape[0])
    q[has] = disp @ axis
    return axis, centroid.copy(), 0.0, q
