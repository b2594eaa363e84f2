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

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.joints._config import JointFitConfig
from artitwin_core.joints._finalize import _finalize
from artitwin_core.joints._fit import (
    _Fit,
    _fit_q,
    _init_prismatic,
    _init_rotational,
    _iterate,
    _motions,
    _predict,
    _start_fit,
    _update_points,
)
from artitwin_core.joints._frame_motions import FrameMotions, frame_motions
from artitwin_core.joints._result import HypothesisScore, JointFit
from artitwin_core.joints._select import _score, select_joint
from artitwin_core.joints._types import Joint, JointType
from artitwin_core.tracking import Trajectories


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
    motions = frame_motions(pts, valid, reference_frame, cfg)
    hyps, finals = fit_hypotheses(pts, valid, reference_frame, motions, cfg)
    return select_joint(pts, valid, reference_frame, motions, hyps, finals, cfg)


def fit_hypotheses(
    pts: np.ndarray, valid: np.ndarray, ref: int, m: FrameMotions, cfg: JointFitConfig
) -> tuple[dict[JointType, HypothesisScore], dict[JointType, tuple[_Fit, Joint, np.ndarray]]]:
    """Every joint type fitted to the tracks ``pts [T, N, 3]`` and scored: per type, its score and
    ``(fit, finalised joint, latent closed-state points [N, 3])``."""
    t_count = pts.shape[0]
    y = np.where(valid[..., None], pts, 0.0)
    x0 = _latent_start(pts, valid, ref, y, m)
    w0 = m.s_mask.astype(float)
    inits: dict[JointType, tuple] = {
        "fixed": (np.array([0.0, 0.0, 1.0]), m.centroid, 0.0, np.zeros(t_count)),
        "prismatic": _init_prismatic(m.rots, m.trans, m.has, m.centroid),
        "revolute": _init_rotational(m.rots, m.trans, m.has, m.centroid, with_pitch=False),
        "screw": _init_rotational(m.rots, m.trans, m.has, m.centroid, with_pitch=True),
    }
    sigma, s_mask = m.sigma, m.s_mask
    # Screen every hypothesis with a few alternations, then run the plausible ones (BIC within
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
        bic, n_par, n_in = _score(fit, q_fit, y, valid, s_mask, sigma, cfg)
        fit.q = q_fit
        joint, points = _finalize(fit, ref, y, sigma, cfg)
        finals[kind] = (fit, joint, points)
        used = (fit.weights > 0) & np.isfinite(q_fit)[:, None]
        d2 = np.sum(
            (_predict(*_motions(kind, fit.axis, fit.pivot, q_fit, fit.pitch), fit.points) - y) ** 2, -1
        )
        rms_all = float(np.sqrt(np.mean(d2[used]))) if used.any() else float("nan")
        hyps[kind] = HypothesisScore(
            kind, bic, n_par, int(fit.track_ok.sum()), n_in, rms_all, bool(converged[kind]), joint
        )
    return hyps, finals


def _latent_start(pts: np.ndarray, valid: np.ndarray, ref: int, y: np.ndarray, m: FrameMotions) -> np.ndarray:
    """``[N, 3]`` latent points to start from: the reference observation, back-projected through
    the frames' motions where the track is not valid there."""
    x0 = np.where(valid[ref][:, None], pts[ref], 0.0)
    rh = np.where(m.has[:, None, None], m.rots, np.eye(3))
    th = np.where(m.has[:, None], m.trans, 0.0)
    vh = valid & m.has[:, None]
    x0 = _update_points(rh, th, y, vh, vh.astype(float) * 0.0, x0)
    x0[valid[ref]] = pts[ref, valid[ref]]
    return x0
