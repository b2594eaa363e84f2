"""A chosen revolute refitted frame by frame (step 4 of ``estimate_joint``).

The tracker's errors are shared by the tracks of a frame (a door's tracks sliding along its grain,
a weakly textured face turned in its plane), so each frame's rigid motion is one sample, compared
with the joint's in six components whose spreads are estimated from the frames (feasible GLS). The
same fit gives the line's standard errors (``Joint.axis_se_rad``, ``pivot_se_m``), with the frames
as the samples; what all frames share (the registration) is not in them.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from artitwin_core.joints._config import JointFitConfig
from artitwin_core.joints._fit import _Fit, _frames_with_support, _tangent_basis
from artitwin_core.joints._model import rotations_about


def _kabsch(src: np.ndarray, dst: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted rigid fit ``dst ~ R src + t`` of ``[M, 3]`` point sets: ``(R [3, 3], t [3])``."""
    cs = (w[:, None] * src).sum(0) / w.sum()
    cd = (w[:, None] * dst).sum(0) / w.sum()
    u, _, vt = np.linalg.svd(((src - cs) * w[:, None]).T @ (dst - cd))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cd - r @ cs


def _refine_frame_level(fit: _Fit, y: np.ndarray, valid: np.ndarray, ref: int, cfg: JointFitConfig) -> bool:
    """Refit a revolute joint to the frames' rigid motions by feasible generalised least squares
    (in place; False where there are too few frames).

    The tracker's errors are shared by the tracks of a frame, and they have directions: a door's
    tracks slide together along its grain, which runs along the hinge, and a weakly textured
    face turns whole frames by tens of mrad about its own normal. The point-level fit counts
    each frame's error once per track and
    tilts the axis to explain it. Here each frame ``t`` is one sample: its rigid motion ``M_t``
    (weighted Kabsch of the fit's latent points onto the frame's inlier observations) is
    compared with the joint's, ``J(q_t) G`` (``G``: the closed pose of the latent points, free,
    so that no single frame's error is everyone's), as 6 numbers: the rotation and the
    centroid's displacement error, each along the axis, the part's radial direction and its
    normal (the basis turns with the part, as the tracker's error modes do). Their spreads are
    estimated from the residuals and the fit is reweighted by them, alternating: a component
    the frames scatter in (the slide along the grain, the in-plane turn) stops steering the
    axis, which lowers the axis error on every measured door (docs/accuracy.md).
    The latent points are moved to their fitted closed pose ``G``; per-frame ``q`` follows.
    """
    frames = _frames_with_support(fit.weights)
    frames = frames[[fit.weights[t].sum() > 0 and np.count_nonzero(fit.weights[t]) >= 3 for t in frames]]
    f = len(frames)
    if f < 4:
        return False
    rots = np.zeros((f, 3, 3))
    trans = np.zeros((f, 3))
    for i, t in enumerate(frames):
        use = fit.weights[t] > 0
        rots[i], trans[i] = _kabsch(fit.points[use], y[t, use], fit.weights[t, use])
    part = fit.track_ok if fit.track_ok.any() else np.ones(fit.points.shape[0], bool)
    c = fit.points[part].mean(0)
    iref = int(np.nonzero(frames == ref)[0][0]) if np.any(frames == ref) else int(np.argmin(np.abs(fit.q[frames])))
    free = np.ones(f, bool)
    free[iref] = False
    q0 = np.nan_to_num(fit.q[frames]) - np.nan_to_num(fit.q[frames][iref])
    a0 = fit.axis / np.linalg.norm(fit.axis)
    e1, e2 = _tangent_basis(a0)
    p0 = fit.pivot.copy()
    n_q = f - 1

    def unpack(x):
        ax = a0 + x[0] * e1 + x[1] * e2
        ax = ax / np.linalg.norm(ax)
        q = np.zeros(f)
        q[free] = x[4 : 4 + n_q]
        g = Rotation.from_rotvec(x[4 + n_q : 7 + n_q]).as_matrix()
        return ax, p0 + x[2] * e1 + x[3] * e2, q, g, x[7 + n_q : 10 + n_q]

    def residuals(x):
        ax, piv, q, g, h = unpack(x)
        rq = rotations_about(ax, q)
        rv = Rotation.from_matrix(rots @ np.swapaxes(rq @ g, 1, 2)).as_rotvec()
        arm = g @ c + h - piv
        u0 = arm - (arm @ ax) * ax
        u0 = u0 / max(np.linalg.norm(u0), 1e-12)
        u = rq @ u0
        v = np.cross(ax, u)
        d = (rots @ c + trans) - (rq @ arm + piv)
        return np.stack([rv @ ax, np.sum(rv * u, 1), np.sum(rv * v, 1), d @ ax, np.sum(d * u, 1), np.sum(d * v, 1)], 1)

    x = np.concatenate([np.zeros(4), q0[free], np.zeros(6)])
    sig = np.full(6, 1.0)
    dof = max(f - (x.size / 6.0), 1.0)
    floor = np.array([cfg.frame_floor_rad] * 3 + [cfg.frame_floor_m] * 3)
    for _ in range(cfg.frame_gls_iterations):
        sol = least_squares(lambda z, sig=sig: (residuals(z) / sig).ravel(), x, method="lm", x_scale="jac")
        x = sol.x
        sig_used = sig
        sig = np.maximum(np.sqrt(np.sum(residuals(x) ** 2, 0) / dof), floor)
    ax, piv, q, g, h = unpack(x)
    fit.axis, fit.pivot = ax, piv
    fit.axis_se, fit.pivot_se = _frame_level_errors(sol.jac, sig_used / sig)
    qn = np.full(fit.q.shape, np.nan)
    qn[frames] = q
    fit.q = qn
    fit.points = fit.points @ g.T + h
    return True


def _frame_level_errors(jac: np.ndarray, rescale: np.ndarray) -> tuple[float | None, float | None]:
    """Standard errors of the axis (radians) and of the pivot across it (metres, the larger of
    its two directions) of the frame-level fit.

    ``jac [F * 6, P]`` is the Jacobian of its residuals divided by the spreads it used, and
    ``rescale [6]`` those spreads over the ones its residuals finally show. The frames are the
    samples, so an error common to a frame's tracks (a pose error of the recording, the tracker
    sliding a whole face) counts once per frame, as it should; a point-level covariance would
    shrink it by the number of tracks. What every frame shares is not seen: the registration's
    error, or a tracker error that grows with the opening and so looks like a tilted axis
    (several times the standard error on noisy tracks). The first four parameters are the axis' and the pivot's tangent
    steps. None where the fit is singular."""
    n_par = jac.shape[1]
    j = np.asarray(jac, dtype=np.float64).reshape(-1, 6, n_par) * rescale[None, :, None]
    info = np.einsum("fkp,fkq->pq", j, j)
    if not np.all(np.isfinite(info)):
        return None, None
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None, None
    a, p = np.linalg.eigvalsh(cov[:2, :2]), np.linalg.eigvalsh(cov[2:4, 2:4])
    if a[0] < 0 or p[0] < 0:
        return None, None
    return float(np.sqrt(a[-1])), float(np.sqrt(p[-1]))
