"""Joint estimation from 3D point trajectories: RANSAC motions, hypotheses, BIC, joint refinement.

Pipeline (``estimate_joint``):

1. Per frame, the part's rigid motion against the reference frame by 3-point RANSAC over the tracks
   valid in both (``_rigid.ransac_rigid``). Its consensus gives a model-agnostic set ``S`` of
   inlier observations (tracks that stay rigid with the majority in most frames) and a robust
   noise level ``sigma`` (median residual, chi-3 corrected).
2. Every hypothesis (fixed, prismatic, revolute, screw) is initialised in closed form from those
   motions and refined by a joint least-squares over all frames of the point residuals
   ``|M(q_t) X_i - y_ti|``, where ``X_i`` are the latent closed-state positions of the tracks
   (estimated, not copied from the noisy reference frame: otherwise the reference frame's noise is
   shared by every frame and the axis error stops shrinking with the number of frames). The fit
   alternates (a) ``scipy.optimize.least_squares`` over the joint parameters (axis on the sphere,
   pivot in the plane normal to the axis, pitch, one ``q`` per frame), (b) the closed-form
   ``X_i`` (mean of back-projected observations) and (c) robust Cauchy weights with a hard gate
   at ``inlier_sigmas`` noise levels: iteratively reweighted least squares, i.e. the M-estimator
   of the Cauchy loss. Step (a) is exact and cheap because, for fixed ``X`` and weights, a
   frame's weighted sum of squared point residuals under a rigid motion equals the squared norm
   of 21 numbers (weighted centroids plus the 6x6 R factor of the centred coordinates), so the
   solver sees ``21 T`` residuals whatever the number of tracks.
3. Hypotheses are scored on the common set ``S`` by BIC with the noise level known (robust
   estimate from step 1): ``sum min(r^2 / sigma^2, c^2) + k ln(3 |S|)`` with ``k`` the joint's
   parameter count (the latent points are shared by all models and cancel). The screw must beat
   the revolute by ``screw_bic_margin``, show at least ``min_screw_travel_m`` of axial travel
   and a pitch significant against the frames' scatter along the revolute's axis;
   "fixed" wins when its BIC is lowest (the motion is within what noise explains) or when the
   best model moves the part by less than ``min_motion_m``. A rotational fit competes only if it
   is a rotation (``_rotation_plausible``): it turns the part by ``min_rotation_rad`` or more,
   and it is no slide with a tilt (an axis many part radii away with a small turn).
4. A chosen revolute is refitted frame by frame (``_refine_frame_level``): the tracker's errors
   are shared by the tracks of a frame (a door's tracks sliding along its grain, a weakly
   textured face turned in its plane), so each frame's rigid motion is one sample, compared with
   the joint's in six components whose spreads are estimated from the frames (feasible GLS).
   The same fit gives the line's standard errors (``Joint.axis_se_rad``, ``pivot_se_m``), with
   the frames as the samples; what all frames share (the registration) is not in them.
5. The chosen fit is re-gauged so that ``q = 0`` at the reference frame, its pivot is moved to the
   point of the axis line closest to the part's centroid, and the axis is flipped so that the
   largest ``|q|`` is positive. Per-frame confidence comes from the standard error of ``q_t``
   (noise over the lever arm of the inliers) and the frame's residual; only frames below
   ``smooth_below_confidence`` are replaced by a zero-phase local quadratic fit of their
   neighbours (no lag, and confident frames keep their unbiased least-squares value: smoothing
   them would only flatten turning points).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from artitwin_core._errors import InputError
from artitwin_core.joints._depth_fit import robust_plane
from artitwin_core.joints._model import joint_motion, rotations_about, skew
from artitwin_core.joints._rigid import CHI3_MEDIAN, ransac_rigid
from artitwin_core.joints._types import Joint
from artitwin_core.tracking import Trajectories

_MOVING = ("prismatic", "revolute", "screw")


@dataclass(frozen=True)
class JointFitConfig:
    """Hyperparameters of ``estimate_joint`` (lengths in metres, angles in radians).

    Attributes:
        ransac_iterations: minimal 3-point samples per frame.
        ransac_threshold_m: first inlier threshold on the 3D residual; adapted to the noise after.
        min_inlier_threshold_m: the adapted threshold never goes below this (noise-free data).
        inlier_sigmas: inlier gate on the 3D residual norm in noise standard deviations (4.0
            keeps 99.9% of Gaussian inliers: the chi-3 quantile).
        min_track_inlier_fraction: a track is part of the part if it is an inlier in at least this
            fraction of its valid frames (rejects tracks that slid onto the background or hand).
        robust_scale_sigmas: scale of the Cauchy loss on the 3D residual, in noise sigmas.
        screening_iterations: alternations every hypothesis gets before the BIC screening.
        refine_bic_margin: hypotheses within this BIC of the best screened one are run to
            convergence (the others keep their screening fit and score).
        max_iterations: further alternations of joint parameters / latent points / weights.
        max_pivot_distance_m: a rotational fit whose axis runs farther than this from the part
            is stopped (a tiny rotation about a far axis is a translation; prismatic explains it
            with fewer parameters).
        tolerance: stop when the relative change of the weighted cost is below this.
        screw_bic_margin: BIC units by which the screw must beat the revolute (10 = "very
            strong" evidence in Kass and Raftery's scale).
        min_screw_travel_m: the screw's axial travel over the observed range must exceed this
            (the pipeline's tracks of the non-screw "door" scene drift 7 mm along the hinge,
            linearly with q, over 1 rad: a trend no frame-level test can tell from a pitch).
        screw_min_pitch_t: the screw's pitch must stand this many standard errors above zero
            when the frames' displacements along the revolute fit's axis are regressed on its
            states (frames, not points, are the independent samples, and the null model's axis
            cannot tilt to fake a pitch: see ``_pitch_significance``).
        min_rotation_rad: a revolute or screw fit must turn the part by at least this much over
            the recording, else it is not considered (a near-zero rotation about a far axis is a
            translation).
        max_pivot_part_ratio: a revolute or screw fit whose axis runs farther from the part's
            centroid than this many part radii (90th percentile of the inlier points' distances
            to their centroid across the axis) ...
        max_tilt_rad: ... and that turns the part by less than this over the recording is a
            slide with a tilt, not a hinge, and is not considered. Over a small angle a rotation
            about an axis at distance ``R`` moves the part along an arc of sagitta
            ``R dq^2 / 8`` (1.3 mm for a drawer tilting 0.04 rad over 0.25 m, i.e. ``R`` = 6 m),
            which no tracker tells from a straight slide with the same tilt; a hinge sits at the
            part (a door's axis is about one part radius from its centroid) and a slide's tilt is
            small, so only the combination of both is read as a tilt.
        min_motion_m: below this RMS displacement of the part's points, the joint is "fixed".
        noise_floor_m: lower bound on the noise estimate (keeps the BIC finite on clean data).
        q_tolerance_rad: standard error of a revolute ``q`` at which confidence is 0.5.
        q_tolerance_m: standard error of a prismatic ``q`` at which confidence is 0.5.
        smooth_below_confidence: frames under this confidence get a smoothed ``q``.
        smoothing_half_window: frames on each side used by the smoother.
        frame_gls_iterations: reweightings of the revolute's frame-level refit
            (``_refine_frame_level``); 0 keeps the point-level fit.
        frame_floor_rad: lower bound on the frames' rotation error spread (a component the
            joint absorbs, the turn about the axis, measures zero spread).
        frame_floor_m: lower bound on the frames' translation error spread.
        slide_along_face: a prismatic joint slides along its part's face normal (the dominant
            plane of its closed points) where the frames' displacements across the fitted
            direction cannot tell the two apart (``_slide_along_face``).
        face_min_fraction: the share of the part's inlier points the face plane must hold.
        face_max_angle_rad: the face normal must be within this of the fitted direction.
        face_chi2: the test's threshold (chi-square, 2 degrees of freedom; 9.21 is its 99%
            quantile): above it the tracks' direction stands.
        slide_floor_rad: systematic error of the tracks' slide direction, added in quadrature to
            the standard error their frames' scatter gives in that test: the pipeline's tracks of the ideal
            benchmark drawers run 0.3-1.0 deg off the truth while their frames regress tightly
            on ``q`` (tracker errors correlated over frames, which the scatter does not show).
        tilt_chi2, tilt_min_rad: a slide whose frames turn significantly (chi-square over 3 axes
            at least ``tilt_chi2``, 11.34 its 99% quantile) and by at least ``tilt_min_rad``
            over the travel is a tilting slide: its direction is its closed face's normal if the
            turn explains the tracks' disagreement with it (``_slide_along_face``).
        seed: RANSAC random seed.
    """

    ransac_iterations: int = 200
    ransac_threshold_m: float = 0.03
    min_inlier_threshold_m: float = 1e-4
    inlier_sigmas: float = 4.0
    min_track_inlier_fraction: float = 0.7
    robust_scale_sigmas: float = 4.0
    screening_iterations: int = 6
    refine_bic_margin: float = 100.0
    max_iterations: int = 30
    max_pivot_distance_m: float = 10.0
    tolerance: float = 1e-8
    screw_bic_margin: float = 10.0
    min_screw_travel_m: float = 0.015
    screw_min_pitch_t: float = 5.0
    min_rotation_rad: float = 0.05
    max_pivot_part_ratio: float = 4.0
    max_tilt_rad: float = 0.25
    min_motion_m: float = 0.002
    noise_floor_m: float = 1e-5
    q_tolerance_rad: float = float(np.deg2rad(0.5))
    q_tolerance_m: float = 0.002
    smooth_below_confidence: float = 0.5
    smoothing_half_window: int = 3
    frame_gls_iterations: int = 6
    frame_floor_rad: float = 1e-4
    frame_floor_m: float = 1e-5
    slide_along_face: bool = True
    face_min_fraction: float = 0.6
    face_max_angle_rad: float = float(np.deg2rad(10.0))
    face_chi2: float = 9.21
    slide_floor_rad: float = float(np.deg2rad(0.7))
    tilt_chi2: float = 11.34
    tilt_min_rad: float = float(np.deg2rad(0.5))
    seed: int = 0

    def __post_init__(self) -> None:
        for name in (
            "ransac_threshold_m",
            "min_inlier_threshold_m",
            "inlier_sigmas",
            "robust_scale_sigmas",
            "noise_floor_m",
            "q_tolerance_rad",
            "q_tolerance_m",
            "max_pivot_part_ratio",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"JointFitConfig.{name} must be > 0, got {getattr(self, name)}")
        if self.ransac_iterations < 1 or self.max_iterations < 1:
            raise ValueError("JointFitConfig.ransac_iterations and max_iterations must be >= 1")
        if not 0 < self.min_track_inlier_fraction <= 1:
            raise ValueError("JointFitConfig.min_track_inlier_fraction must be in (0, 1]")


@dataclass(frozen=True)
class HypothesisScore:
    """How well one joint type explains the trajectories.

    Attributes:
        joint_type: one of ``JOINT_TYPES``.
        bic: robust BIC on the common inlier set (lower is better).
        n_parameters: joint parameters counted by the BIC (per-frame ``q`` included).
        n_inlier_tracks: tracks this hypothesis's fit kept.
        n_inlier_points: observations (track x frame) of the common set within the inlier gate.
        rms_residual_m: RMS 3D residual over this fit's inlier observations, metres.
        converged: the alternation settled (False for hypotheses screened out early, whose BIC
            was already worse than the best by more than ``refine_bic_margin``).
        joint: this hypothesis's fitted joint (same post-processing as the chosen one).
    """

    joint_type: str
    bic: float
    n_parameters: int
    n_inlier_tracks: int
    n_inlier_points: int
    rms_residual_m: float
    converged: bool
    joint: Joint


@dataclass(frozen=True)
class JointFit:
    """The result of ``estimate_joint``.

    Attributes:
        joint: the chosen joint.
        hypotheses: one ``HypothesisScore`` per joint type, in ``JOINT_TYPES`` order.
        inlier_mask: ``[N]`` bool, tracks the chosen fit treats as the moving part.
        rigid_motions: ``[T, 4, 4]`` float64, per frame the RANSAC-refined rigid motion mapping a
            part point's reference-frame position to its frame-t position (identity at the
            reference frame, NaN where fewer than 3 tracks were shared with it).
        points_closed: ``[N, 3]`` metres, latent closed-state (q = 0) positions of the inlier
            tracks, NaN for the others.
        noise_sigma_m: robust per-coordinate noise estimate of one observation, metres.
        reference_frame: the frame defined as ``q = 0``.
    """

    joint: Joint
    hypotheses: tuple[HypothesisScore, ...]
    inlier_mask: np.ndarray
    rigid_motions: np.ndarray
    points_closed: np.ndarray
    noise_sigma_m: float
    reference_frame: int

    def score(self, joint_type: str) -> HypothesisScore:
        """The ``HypothesisScore`` of ``joint_type``."""
        for h in self.hypotheses:
            if h.joint_type == joint_type:
                return h
        raise KeyError(joint_type)


@dataclass
class _Fit:
    """Internal state of one hypothesis fit (q free at every frame: gauge fixed afterwards)."""

    kind: str
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


def _motions(fit_kind: str, axis, pivot, q, pitch) -> tuple[np.ndarray, np.ndarray]:
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
    enough = use.sum(1) >= 10
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
    tracks slide together along its grain, which runs along the hinge (6-7 mm at 30-43 deg on
    "door"), and a weakly textured face turns whole frames by 10-30 mrad about its own normal
    ("low-texture-door"). The point-level fit counts each frame's error once per track and
    tilts the axis to explain it. Here each frame ``t`` is one sample: its rigid motion ``M_t``
    (weighted Kabsch of the fit's latent points onto the frame's inlier observations) is
    compared with the joint's, ``J(q_t) G`` (``G``: the closed pose of the latent points, free,
    so that no single frame's error is everyone's), as 6 numbers: the rotation and the
    centroid's displacement error, each along the axis, the part's radial direction and its
    normal (the basis turns with the part, as the tracker's error modes do). Their spreads are
    estimated from the residuals and the fit is reweighted by them, alternating: a component
    the frames scatter in (the slide on "door", the in-plane turn on "low-texture-door") stops
    steering the axis. Measured on the pipeline's tracks (axis error, deg): door 0.84 -> 0.07,
    low-texture-door 1.50 -> 0.31, door+drawer 0.73 -> 0.22, tiny 1.69 -> 1.25.
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
    error, or a tracker error that grows with the opening and so looks like a tilted axis (on
    the high-noise scene's tracks lifted at the true poses, 0.45 deg of axis error against a
    0.06 deg standard error). The first four parameters are the axis' and the pivot's tangent
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


def _slide_along_face(
    joint: Joint, points: np.ndarray, points_ref: np.ndarray, rigid: np.ndarray, cfg: JointFitConfig
) -> Joint:
    """``joint`` (prismatic, direction ``a``) with its direction fused with its part's face
    normal ``n`` where the tracks cannot tell the two apart; else ``joint`` itself.

    A drawer slides along its front's normal. The tracks measure the slide's direction from the
    part's displacement across ``a`` per unit of travel, and a tracker's error is common to a
    frame's points (the benchmark drawers' tracks shift a frame by 2-7 mm across the slide
    while moving): over 0.25 m of travel that is 0.4-1 deg, frames, not points, being the
    independent samples. The front's normal is a plane fit over hundreds of points, each with
    its own noise (0.02-0.09 deg from the truth on the benchmark drawers). Per axis ``e``
    across ``a``: the tracks' slope is the regression of the frames' displacements (``rigid
    [T, 4, 4]`` applied to the points' centroid) along ``e`` on ``q``, with its standard error
    from the frames' scatter; the face's slope is ``(n.e) / (n.a)``, with the plane fit's
    standard error. If the two agree (chi-square over both axes at most ``face_chi2``, the
    tracks' variance widened by ``slide_floor_rad`` of systematic error), the direction takes
    their inverse-variance weighted mean (the scatter's variances: a flat front's normal
    outweighs the tracks, clean tracks outweigh a thick slab's scattered face). Needs a face:
    ``face_min_fraction`` of ``points [N, 3]`` (the closed part's inliers) on one plane whose
    normal is within ``face_max_angle_rad`` of ``a``.

    A drawer that also turns as it slides (non-ideal-joints: its front dips 2.3 deg over the
    travel) is tested first (``_tilt_rate``). Its tracks' direction is their centroid's, 2.7 deg
    off the rail there, and the rail's direction is that of the turn's pivot, which no track
    sees; the prismatic model's latent ``points`` are smeared by the turn (their face came out
    0.6 deg off). So a tilting slide takes its face from ``points_ref [M, 3]``, the reference
    frame's own observations, and slides along that normal if the turn explains the tracks'
    disagreement with it (``_tilt_explains``); else it keeps the tracks' direction.

    ``q`` is rescaled to the travel along the new direction; ``residual`` and ``confidence``
    stay those of the tracks' fit. ``axis_se_rad`` is set either way: the
    tracks' slope standard error (the frames' scatter), or the fused one; with
    ``slide_along_face`` off only the former."""
    a = np.asarray(joint.axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    q = np.asarray(joint.q, dtype=np.float64)
    has = np.isfinite(rigid[:, 0, 0]) & np.isfinite(q)
    if has.sum() < 4 or np.ptp(q[has]) <= 0:
        return joint
    centroid = points.mean(0)
    disp = np.einsum("tij,j->ti", rigid[has, :3, :3], centroid) + rigid[has, :3, 3] - centroid
    design = np.stack([np.ones(has.sum()), q[has]], 1)
    inv = np.linalg.inv(design.T @ design)
    slopes, var_tracks = [], []
    for e in _tangent_basis(a):
        across = disp @ e
        coef = inv @ design.T @ across
        res = across - design @ coef
        slopes.append(float(coef[1]))
        var_tracks.append(max(float(res @ res) / max(has.sum() - 2, 1), 1e-12) * inv[1, 1])
    # The direction's standard error from the frames' scatter across it (the worse axis).
    joint = replace(joint, axis_se_rad=float(np.sqrt(max(var_tracks))))
    if not cfg.slide_along_face:
        return joint
    tilt = _tilt_rate(rigid[has], q[has], cfg)
    face_points = points_ref if tilt is not None else points
    reach = 2.0 * float(np.max(np.linalg.norm(points - centroid, axis=1)))
    # A tilting slide's tracks may stray from the face normal by up to the turn's lever.
    stray = float(np.arctan(np.linalg.norm(tilt) * reach)) if tilt is not None else 0.0
    plane = robust_plane(
        face_points, a, np.random.default_rng(cfg.seed), min_points=20,
        normal_tol_deg=float(np.degrees(cfg.face_max_angle_rad + stray)), iterations=200, band_m=0.01,
    )
    if plane is None or plane.fraction < cfg.face_min_fraction:
        return joint
    n = plane.normal
    on_face = face_points[np.abs((face_points - plane.centroid) @ n) < 2.5 * plane.sigma] - plane.centroid
    if tilt is not None:
        gap = sum((slope - float(n @ e) / float(n @ a)) * e for e, slope in zip(_tangent_basis(a), slopes, strict=True))
        if not _tilt_explains(gap, tilt, reach, float(np.sqrt(max(var_tracks))), cfg):
            return joint
        fused = [float(n @ e) / float(n @ a) for e in _tangent_basis(a)]
        var_fused = [
            plane.sigma**2 / max(float(np.sum((on_face @ e) ** 2)), 1e-12) / float(n @ a) ** 2
            for e in _tangent_basis(a)
        ]
        return _along(joint, a, q, fused, var_fused)
    chi2, fused, var_fused = 0.0, [], []
    for e, slope, var_t in zip(_tangent_basis(a), slopes, var_tracks, strict=True):
        # A plane's normal tilts towards e by sigma / sqrt(sum of squared extents along e).
        var_face = plane.sigma**2 / max(float(np.sum((on_face @ e) ** 2)), 1e-12) / float(n @ a) ** 2
        slope_face = float(n @ e) / float(n @ a)
        chi2 += (slope_face - slope) ** 2 / (var_t + cfg.slide_floor_rad**2 + var_face)
        fused.append((slope / var_t + slope_face / var_face) / (1.0 / var_t + 1.0 / var_face))
        var_fused.append(1.0 / (1.0 / var_t + 1.0 / var_face))
    if chi2 > cfg.face_chi2:
        return joint
    return _along(joint, a, q, fused, var_fused)


def _along(joint: Joint, a: np.ndarray, q: np.ndarray, slopes: list[float], variances: list[float]) -> Joint:
    """``joint`` sliding along ``a`` plus ``slopes`` across it (per ``_tangent_basis(a)``),
    with the direction's standard error the worse of ``variances``."""
    direction = a + sum(s * e for s, e in zip(slopes, _tangent_basis(a), strict=True))
    # Displacement q * direction per unit of q along a: the travel along the new unit axis.
    scale = float(np.linalg.norm(direction))
    return replace(
        joint, axis=direction / scale, q=q * scale, q_range=np.asarray(joint.q_range) * scale,
        axis_se_rad=float(np.sqrt(max(variances))),
    )


def _tilt_rate(rigid: np.ndarray, q: np.ndarray, cfg: JointFitConfig) -> np.ndarray | None:
    """The rate ``[3]`` (rad per unit of ``q``) at which a slide's part turns as it moves, or
    None if it does not turn measurably.

    The frames' rotations ``rigid [T, 4, 4]`` (reference to frame, frames with a motion) are
    regressed on their travel ``q [T]`` through the reference, with the rate's covariance from
    the frames' scatter. A turn counts when it is significant (chi-square over 3 axes at least
    ``tilt_chi2``) and at least ``tilt_min_rad`` over the travel."""
    if q.size < 4 or np.ptp(q) <= 0:
        return None
    rot = rigid[:, :3, :3]
    vec = 0.5 * np.stack(
        [rot[:, 2, 1] - rot[:, 1, 2], rot[:, 0, 2] - rot[:, 2, 0], rot[:, 1, 0] - rot[:, 0, 1]], 1
    )
    qq = float(q @ q)
    rate = (q @ vec) / qq
    res = vec - q[:, None] * rate[None]
    cov = (res.T @ res) / max(q.size - 1, 1) / qq
    try:
        chi2 = float(rate @ np.linalg.solve(cov + 1e-18 * np.eye(3), rate))
    except np.linalg.LinAlgError:
        return None
    if chi2 < cfg.tilt_chi2 or float(np.linalg.norm(rate)) * float(np.ptp(q)) < cfg.tilt_min_rad:
        return None
    return rate


def _tilt_explains(gap: np.ndarray, rate: np.ndarray, reach: float, se_tracks: float, cfg: JointFitConfig) -> bool:
    """Whether a slide turning at ``rate [3]`` (``_tilt_rate``) explains the tracks' direction
    being ``gap [3]`` (per unit of travel, across the slide) off the face normal.

    A turn about ``w`` moves a point ``x`` by ``w x (x - p)`` per unit of travel on top of the
    slide at its pivot ``p``, so the tracks' centroid ``c`` strays from the rail by ``w x (c -
    p)``: a gap across ``w``, of at most ``|w| reach`` for a pivot within ``reach`` of the
    centroid. True when the gap's part along ``w`` is within 3 of the tracks' standard errors
    ``se_tracks`` (widened by ``slide_floor_rad``) and the rest within ``|w| reach``."""
    turn = float(np.linalg.norm(rate))
    w = rate / turn
    along = abs(float(gap @ w))
    across = float(np.linalg.norm(gap - (gap @ w) * w))
    return along <= 3.0 * float(np.hypot(se_tracks, cfg.slide_floor_rad)) and across <= turn * reach


def _n_params(kind: str, n_frames: int) -> int:
    return {"fixed": 0, "prismatic": 2, "revolute": 4, "screw": 5}[kind] + (
        max(n_frames - 1, 0) if kind != "fixed" else 0
    )


def _score(fit: _Fit, q, y, valid, s_mask, sigma, cfg: JointFitConfig) -> tuple[float, int, int]:
    """Robust BIC on the common set ``s_mask [T, N]`` with the noise level ``sigma`` known.

    Frames where this fit has no ``q`` (NaN) are scored as unexplained (truncated cost).
    """
    rot, trans = _motions(fit.kind, fit.axis, fit.pivot, q, fit.pitch)
    w = s_mask.astype(float)
    pts = _update_points(rot, trans, y, valid, w, fit.points)
    r = _residuals(rot, trans, pts, y, valid)
    r = np.where(np.isfinite(q)[:, None], r, np.inf)
    z2 = np.where(s_mask, (r / sigma) ** 2, 0.0)
    rho = np.minimum(z2, cfg.inlier_sigmas**2).sum()
    n_frames = int(np.sum(s_mask.sum(1) >= 3))
    k = _n_params(fit.kind, n_frames)
    n_obs = 3 * int(s_mask.sum())
    bic = float(rho + k * np.log(max(n_obs, 2)))
    n_in = int(np.sum(s_mask & (z2 <= cfg.inlier_sigmas**2)))
    return bic, k, n_in


def _confidence(fit: _Fit, kind: str, sigma_glob: float, cfg: JointFitConfig, rms: np.ndarray):
    t_count = fit.q.shape[0]
    conf = np.zeros(t_count)
    if kind == "fixed":
        return np.where(np.isfinite(rms), 1.0, 0.0)
    if kind == "prismatic":
        lever2 = np.ones(fit.points.shape[0])
        tol = cfg.q_tolerance_m
    else:
        arm = np.cross(fit.axis, fit.points - fit.pivot) + fit.pitch * fit.axis
        lever2 = np.sum(arm**2, axis=-1)
        tol = cfg.q_tolerance_rad
    info = fit.weights @ np.nan_to_num(lever2)
    for t in range(t_count):
        if not np.isfinite(fit.q[t]) or info[t] <= 0 or not np.isfinite(rms[t]):
            continue
        se = fit.sigma_t[t] / np.sqrt(info[t])
        # RMS of a 3D residual is sqrt(3) sigma under the noise model; allow up to sqrt(6) sigma.
        gof = min(1.0, 6.0 * max(sigma_glob, cfg.noise_floor_m) ** 2 / max(rms[t] ** 2, 1e-300))
        conf[t] = gof / (1.0 + (se / tol) ** 2)
    return conf


def _smooth_low_confidence(q: np.ndarray, conf: np.ndarray, ref: int, cfg: JointFitConfig) -> np.ndarray:
    """Zero-phase local quadratic fit, confidence-weighted, applied only to low-confidence frames.

    A centred window has no lag (unlike a causal filter); confident frames keep their unbiased
    least-squares value; the reference frame is ``q = 0`` by definition and is never changed.
    """
    out = q.copy()
    h = cfg.smoothing_half_window
    t_count = q.shape[0]
    ok = np.isfinite(q) & (conf > 0)
    for t in range(t_count):
        if t == ref or (ok[t] and conf[t] >= cfg.smooth_below_confidence):
            continue
        lo, hi = max(0, t - h), min(t_count, t + h + 1)
        s = np.arange(lo, hi)
        sel = ok[s]
        if sel.sum() < 2:
            continue
        s = s[sel]
        kernel = (1 - (np.abs(s - t) / (h + 1)) ** 3) ** 3
        w = conf[s] * kernel
        deg = 2 if len(s) >= 4 else 1
        if len(np.unique(s)) <= deg:
            deg = len(np.unique(s)) - 1
        coef = np.polyfit(s - t, q[s], deg, w=np.sqrt(w))
        out[t] = coef[-1]
    return out


def _finalize(fit: _Fit, ref: int, y, sigma_glob, cfg: JointFitConfig) -> tuple[Joint, np.ndarray]:
    """Gauge q(ref) = 0, pivot nearest the centroid, positive opening, confidence, smoothing."""
    kind = fit.kind
    t_count = fit.q.shape[0]
    axis = fit.axis / np.linalg.norm(fit.axis)
    pivot = fit.pivot
    q = fit.q.copy()
    points = fit.points.copy()
    if kind != "fixed":
        q_ref = q[ref] if np.isfinite(q[ref]) else 0.0
        rot_ref, trans_ref = joint_motion(kind, axis, pivot, np.array([q_ref]), fit.pitch)
        points = points @ rot_ref[0].T + trans_ref[0]
        q = q - q_ref
        if kind == "revolute":
            # An angle and the same angle +- 2 pi are one pose: a per-frame angle near -pi against a
            # reference near +pi must read as a small turn, not as ~2 pi (a door's range of 356 deg).
            q = np.where(np.isfinite(q), np.mod(q + np.pi, 2.0 * np.pi) - np.pi, q)
    part = fit.track_ok
    centroid = points[part].mean(0) if part.any() else np.nanmean(points, 0)
    pivot = pivot + ((centroid - pivot) @ axis) * axis
    if kind == "fixed":
        axis = np.array([0.0, 0.0, 1.0])
        pivot = centroid
        q = np.where(np.isfinite(q), 0.0, np.nan)
    elif np.any(np.isfinite(q)):
        k = int(np.nanargmax(np.abs(q)))
        if q[k] < 0:
            axis, q = -axis, -q
    fit2 = _Fit(kind, axis, pivot, fit.pitch, q, points, fit.weights, fit.track_ok, fit.sigma_t,
                fit.axis_se, fit.pivot_se)
    rms = _frame_rms(fit2, y)
    conf = _confidence(fit2, kind, sigma_glob, cfg, rms)
    conf[ref] = 1.0  # q(ref) = 0 by definition
    q_s = _smooth_low_confidence(q, conf, ref, cfg) if kind != "fixed" else np.where(np.isfinite(q), 0.0, q)
    if kind == "fixed":
        q_s = np.zeros(t_count)
    elif np.any(~np.isfinite(q_s)):
        good = np.isfinite(q_s)
        q_s = (
            np.interp(np.arange(t_count), np.nonzero(good)[0], q_s[good]) if good.any() else np.zeros(t_count)
        )
    fit2.q = q_s
    rms = _frame_rms(fit2, y)
    finite = q_s[np.isfinite(q_s)]
    q_range = np.array([finite.min(), finite.max()]) if finite.size else np.zeros(2)
    joint = Joint(
        joint_type=kind,
        axis=axis,
        pivot=pivot,
        q=q_s,
        q_range=q_range,
        residual=rms,
        confidence=conf,
        pitch=float(fit.pitch) if kind == "screw" else 0.0,
        axis_se_rad=fit.axis_se,
        pivot_se_m=fit.pivot_se,
    )
    return joint, points


def _frame_rms(fit: _Fit, y) -> np.ndarray:
    rot, trans = _motions(fit.kind, fit.axis, fit.pivot, fit.q, fit.pitch)
    d2 = np.sum((_predict(rot, trans, fit.points) - y) ** 2, axis=-1)
    use = (fit.weights > 0) & np.isfinite(fit.q)[:, None]
    n = use.sum(1)
    s = np.where(use, d2, 0.0).sum(1)
    return np.where(n > 0, np.sqrt(s / np.maximum(n, 1)), np.nan)


def _validate(traj: Trajectories, reference_frame: int) -> tuple[np.ndarray, np.ndarray]:
    pts = np.asarray(traj.points_in_world, dtype=np.float64)
    valid = np.asarray(traj.valid, dtype=bool)
    if pts.ndim != 3 or pts.shape[2] != 3:
        raise InputError(f"Trajectories.points_in_world has shape {pts.shape}, expected [T, N, 3]")
    if valid.shape != pts.shape[:2]:
        raise InputError(
            f"Trajectories.valid has shape {valid.shape}, expected {pts.shape[:2]} to match points_in_world"
        )
    t_count = pts.shape[0]
    if not 0 <= reference_frame < t_count:
        raise InputError(
            f"reference_frame {reference_frame} is outside the {t_count} frames of the trajectories"
        )
    valid = valid & np.all(np.isfinite(pts), axis=-1)
    if valid[reference_frame].sum() < 3:
        raise InputError(
            f"reference frame {reference_frame} has {int(valid[reference_frame].sum())} valid tracks; "
            "at least 3 are needed: pass a reference_frame where the part is tracked"
        )
    return pts, valid


def _rotation_plausible(joint: Joint, points: np.ndarray, part: np.ndarray, cfg: JointFitConfig) -> bool:
    """A rotational fit is a rotation, not a translation in disguise.

    It turns the part by at least ``min_rotation_rad`` over the recording (a drawer's tracking
    errors that grow as it slides out are fitted best by a rotation of a few milliradians about an
    axis tens of metres away, which wins the BIC against the translation by the two parameters it
    adds), and it is not a slide with a tilt: an axis farther than ``max_pivot_part_ratio`` part
    radii from the part together with a turn below ``max_tilt_rad`` (a drawer that dips 0.04 rad
    as it slides 0.25 m is a rotation about an axis 6 m away, and wins the BIC by far because the
    prismatic model has no tilt; it is still a drawer).

    Args:
        joint: the finalised rotational fit (pivot at the axis point closest to the centroid).
        points: ``[N, 3]`` its latent closed-state points, metres.
        part: ``[N]`` bool, the tracks the fit kept.
    """
    span = float(joint.q_range[1] - joint.q_range[0])
    if span < cfg.min_rotation_rad:
        return False
    if span >= cfg.max_tilt_rad:
        return True
    x = points[part] if part.sum() >= 3 else points[np.all(np.isfinite(points), axis=1)]
    if x.shape[0] < 3:
        return True
    axis = joint.axis / np.linalg.norm(joint.axis)
    centroid = x.mean(0)
    across = (x - centroid) - np.outer((x - centroid) @ axis, axis)
    radius = float(np.percentile(np.linalg.norm(across, axis=1), 90))
    off = centroid - joint.pivot
    distance = float(np.linalg.norm(off - (off @ axis) * axis))
    return distance <= cfg.max_pivot_part_ratio * max(radius, 1e-6)


def _pitch_significance(
    null: Joint, rots: np.ndarray, trans: np.ndarray, has: np.ndarray, centroid: np.ndarray
) -> float:
    """t statistic of a pitch, tested at the revolute (null) fit, against the frames' own scatter.

    A single rigid motion is always a screw (Chasles), and per-point BIC counts every track of
    a frame as independent evidence, while tracking errors are shared by the tracks of a frame
    (a slid homography, a depth bias). The frames are the independent samples: each frame's
    rigid motion moves the part by ``d_t`` along the axis, and a screw needs ``d_t`` to grow
    linearly with ``q_t``. ``d_t`` is taken at the part's centroid, where an error of the axis
    direction leaks least of the rotation into it; frames whose motion rests on few tracks
    (``has`` False) are left out. Regressing ``d_t = c + pitch q_t`` over the frames, the slope's
    standard error comes from the scatter of the frames about the line, so drift that does not
    follow ``q`` (frames at the same ``q`` with different ``d``) weakens the evidence.

    The axis and ``q_t`` are the null model's (a score test): the screw's own fit is free to tilt
    its axis so that the tilt's leak of the swing into the axial direction (``|chord| sin(tilt)``,
    growing with ``q``) reads as a pitch. On low-texture-door, whose per-frame rotations carry
    10-30 mrad of tracker error, the screw tilted its axis 4.4 deg and read 31 mm of travel at
    t = 11; along the revolute's axis (1.5 deg off) the same frames give t = 2.7. A real pitch
    moves every point of the part along the axis by the same amount, which no tilt of a hinge
    reproduces, so it shows along the revolute's axis too (``test_screw_*``). Fewer than 4
    frames, or fewer than 3 distinct states, give 0 (not identifiable).
    """
    q = null.q
    use = has & np.isfinite(q)
    if use.sum() < 4:
        return 0.0
    qs = q[use]
    d = (np.einsum("tij,j->ti", rots[use], centroid) + trans[use] - centroid) @ null.axis
    # Distinct states: at least 3 clusters apart by 5% of the observed range.
    span = float(qs.max() - qs.min())
    levels = np.unique(np.round(qs / max(0.05 * span, 1e-9)))
    if span <= 0 or levels.size < 3:
        return 0.0
    a = np.stack([np.ones_like(qs), qs], -1)
    coef, *_ = np.linalg.lstsq(a, d, rcond=None)
    res = d - a @ coef
    dof = qs.size - 2
    s2 = float(res @ res) / dof
    cov = s2 * np.linalg.inv(a.T @ a)
    se = float(np.sqrt(max(cov[1, 1], 1e-30)))
    return float(abs(coef[1]) / se)


def estimate_joint(
    traj: Trajectories, config: JointFitConfig | None = None, *, reference_frame: int = 0
) -> JointFit:
    """Estimate the joint that moves the tracked part (see the module docstring for the method).

    Args:
        traj: ``points_in_world [T, N, 3]`` metres in the canonical frame with ``valid [T, N]``;
            most valid tracks should lie on the moving part (outliers are rejected).
        config: hyperparameters; ``JointFitConfig()`` when None.
        reference_frame: the frame that defines the closed state ``q = 0``.

    Returns:
        ``JointFit`` with the chosen ``Joint`` (``q [T]`` radians or metres, ``q >= 0`` opening),
        the per-hypothesis scores, the inlier tracks and the per-frame rigid motions.

    Raises:
        InputError: shapes disagree, the reference frame is out of range or has < 3 valid tracks.
    """
    cfg = config if config is not None else JointFitConfig()
    pts, valid = _validate(traj, reference_frame)
    ref = reference_frame
    t_count, n = pts.shape[:2]
    y = np.where(valid[..., None], pts, 0.0)
    rng = np.random.default_rng(cfg.seed)

    # 1. Per-frame rigid motions against the reference frame.
    rots = np.full((t_count, 3, 3), np.nan)
    trans = np.full((t_count, 3), np.nan)
    rots[ref], trans[ref] = np.eye(3), np.zeros(3)
    ransac_in = np.zeros((t_count, n), bool)
    checked = np.zeros((t_count, n), bool)
    diff_res = []
    for t in range(t_count):
        if t == ref:
            continue
        common = np.nonzero(valid[ref] & valid[t])[0]
        res = ransac_rigid(
            pts[ref, common],
            pts[t, common],
            rng,
            iterations=cfg.ransac_iterations,
            threshold_m=cfg.ransac_threshold_m,
            min_threshold_m=cfg.min_inlier_threshold_m,
            inlier_sigmas=cfg.inlier_sigmas * np.sqrt(2.0),
        )
        if res is None or res.inliers.sum() < 3:
            continue
        rots[t], trans[t] = res.rotation, res.translation
        ransac_in[t, common] = res.inliers
        checked[t, common] = True
        diff_res.append(res.residuals[res.inliers])
    has = np.isfinite(rots[:, 0, 0])
    # A difference of two observations has twice the per-coordinate variance of one.
    if diff_res:
        sigma = float(np.median(np.concatenate(diff_res)) / CHI3_MEDIAN / np.sqrt(2.0))
    else:
        sigma = cfg.noise_floor_m
    sigma = max(sigma, cfg.noise_floor_m)
    n_checked = checked.sum(0)
    frac = ransac_in.sum(0) / np.maximum(n_checked, 1)
    track_ok = valid[ref] & (n_checked >= 1) & (frac >= cfg.min_track_inlier_fraction)
    if track_ok.sum() < 3:
        track_ok = valid[ref].copy()
    s_mask = (ransac_in & track_ok[None, :]) & valid
    s_mask[ref] = track_ok & valid[ref]
    rigid = np.full((t_count, 4, 4), np.nan)
    rigid[has, :3, :3] = rots[has]
    rigid[has, :3, 3] = trans[has]
    rigid[has, 3] = [0, 0, 0, 1]

    # Latent points start at the reference observation (back-projected where not valid there).
    x0 = np.where(valid[ref][:, None], pts[ref], 0.0)
    rh = np.where(has[:, None, None], rots, np.eye(3))
    th = np.where(has[:, None], trans, 0.0)
    vh = valid & has[:, None]
    x0 = _update_points(rh, th, y, vh, vh.astype(float) * 0.0, x0)
    x0[valid[ref]] = pts[ref, valid[ref]]
    centroid = pts[ref, track_ok].mean(0)

    w0 = s_mask.astype(float)
    inits = {
        "fixed": (np.array([0.0, 0.0, 1.0]), centroid, 0.0, np.zeros(t_count)),
        "prismatic": _init_prismatic(rots, trans, has, centroid),
        "revolute": _init_rotational(rots, trans, has, centroid, with_pitch=False),
        "screw": _init_rotational(rots, trans, has, centroid, with_pitch=True),
    }
    # 2. Screen every hypothesis with a few alternations, then run the plausible ones (BIC within
    # refine_bic_margin of the best) to convergence: a wrong model's BIC is far off long before
    # it converges, and converging it would cost most of the run time.
    fits = {k: _start_fit(k, inits[k], y, w0, x0, sigma) for k in inits}
    converged = {k: _iterate(f, y, valid, sigma, cfg, cfg.screening_iterations) for k, f in fits.items()}
    screen = {k: _score(f, _fit_q(f), y, valid, s_mask, sigma, cfg)[0] for k, f in fits.items()}
    best_screen = min(screen.values())
    for k, f in fits.items():
        if not converged[k] and screen[k] <= best_screen + cfg.refine_bic_margin:
            converged[k] = _iterate(f, y, valid, sigma, cfg, cfg.max_iterations)
    hyps = {}
    finals = {}
    for kind, fit in fits.items():
        q_fit = _fit_q(fit)
        bic, k, n_in = _score(fit, q_fit, y, valid, s_mask, sigma, cfg)
        fit.q = q_fit
        joint, points = _finalize(fit, ref, y, sigma, cfg)
        finals[kind] = (fit, joint, points)
        used = (fit.weights > 0) & np.isfinite(q_fit)[:, None]
        d2 = np.sum(
            (_predict(*_motions(kind, fit.axis, fit.pivot, q_fit, fit.pitch), fit.points) - y) ** 2, -1
        )
        rms_all = float(np.sqrt(np.mean(d2[used]))) if used.any() else float("nan")
        hyps[kind] = HypothesisScore(
            kind, bic, k, int(fit.track_ok.sum()), n_in, rms_all, bool(converged[kind]), joint
        )

    # 3. Model selection.
    plausible = {
        k: _rotation_plausible(finals[k][1], finals[k][2], finals[k][0].track_ok, cfg)
        for k in ("revolute", "screw")
    }
    moving = [k for k in ("prismatic", "revolute") if k == "prismatic" or plausible[k]]
    best = min(moving, key=lambda k: hyps[k].bic)
    screw = finals["screw"][1]
    travel = abs(screw.pitch) * float(screw.q_range[1] - screw.q_range[0])
    support = ransac_in.sum(1)
    strong = has & (support >= max(10.0, 0.2 * float(np.median(support[has]))))
    # Tested at the revolute's fit (see _pitch_significance); the screw's own axis when the
    # revolute ran away (no hinge near the part to test against).
    null = finals["revolute"][1] if plausible["revolute"] else screw
    pitch_t = _pitch_significance(null, rots, trans, strong, centroid)
    if (
        hyps["screw"].bic + cfg.screw_bic_margin < hyps["revolute"].bic
        and hyps["screw"].bic < hyps["prismatic"].bic
        and travel >= cfg.min_screw_travel_m
        and pitch_t >= cfg.screw_min_pitch_t
        and plausible["screw"]
    ):
        best = "screw"
    if best == "revolute" and cfg.frame_gls_iterations > 0:
        # Scored and tested at the point level; the chosen hinge is refitted frame by frame.
        fit_r = replace(finals["revolute"][0])
        fit_r.points, fit_r.q = fit_r.points.copy(), fit_r.q.copy()
        if _refine_frame_level(fit_r, y, valid, ref, cfg):
            joint_r, points_r = _finalize(fit_r, ref, y, sigma, cfg)
            finals["revolute"] = (fit_r, joint_r, points_r)
            hyps["revolute"] = replace(hyps["revolute"], joint=joint_r)
    fit_b, joint_b, points_b = finals[best]
    rot, tr = joint_motion(best, joint_b.axis, joint_b.pivot, joint_b.q, joint_b.pitch)
    disp = np.linalg.norm(_predict(rot, tr, points_b) - points_b[None], axis=-1)
    part = fit_b.track_ok
    motion = float(np.max(np.sqrt(np.mean(disp[:, part] ** 2, axis=1)))) if part.any() else 0.0
    if hyps["fixed"].bic <= hyps[best].bic or motion < cfg.min_motion_m:
        best = "fixed"
    fit_c, joint_c, points_c = finals[best]
    if best == "prismatic":
        joint_c = _slide_along_face(
            joint_c, points_c[fit_c.track_ok], pts[ref, fit_c.track_ok & valid[ref]], rigid, cfg
        )
        hyps["prismatic"] = replace(hyps["prismatic"], joint=joint_c)
    closed = np.where(fit_c.track_ok[:, None], points_c, np.nan)
    return JointFit(
        joint=joint_c,
        hypotheses=tuple(hyps[k] for k in ("revolute", "prismatic", "screw", "fixed")),
        inlier_mask=fit_c.track_ok.copy(),
        rigid_motions=rigid,
        points_closed=closed,
        noise_sigma_m=sigma,
        reference_frame=ref,
    )
