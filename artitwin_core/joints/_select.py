"""Model selection among the joint hypotheses (step 3 of ``estimate_joint``).

Hypotheses are scored on the common inlier set by BIC with the noise level known (``_score``). The
screw must beat the revolute by ``screw_bic_margin``, show ``min_screw_travel_m`` of axial travel
and a pitch significant against the frames' scatter (``_pitch_significance``); a rotational fit
competes only if it is a rotation (``_rotation_plausible``); "fixed" wins when its BIC is lowest or
the best model moves the part by less than ``min_motion_m``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artitwin_core.joints._config import JointFitConfig
from artitwin_core.joints._finalize import _finalize
from artitwin_core.joints._fit import _Fit, _motions, _predict, _residuals, _update_points
from artitwin_core.joints._frame_level import _refine_frame_level
from artitwin_core.joints._frame_motions import FrameMotions
from artitwin_core.joints._model import joint_motion
from artitwin_core.joints._result import HypothesisScore, JointFit
from artitwin_core.joints._slide import _slide_along_face
from artitwin_core.joints._types import Joint, JointType


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
    growing with ``q``) reads as a pitch: on a weakly textured door, whose per-frame rotations
    carry tens of mrad of tracker error, the screw's own fit read a confident pitch where the
    revolute's axis saw none (docs/accuracy.md). A real pitch
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


def select_joint(
    pts: np.ndarray,
    valid: np.ndarray,
    ref: int,
    m: FrameMotions,
    hyps: dict[JointType, HypothesisScore],
    finals: dict[JointType, tuple[_Fit, Joint, np.ndarray]],
    cfg: JointFitConfig,
) -> JointFit:
    """The joint the hypotheses ``hyps`` (fits ``finals``) select, refined as its type needs: a
    revolute frame by frame, a slide along the part's face. Updates ``hyps`` and ``finals``."""
    y = np.where(valid[..., None], pts, 0.0)
    best = _best_moving(hyps, finals, m, cfg)
    if best == "revolute" and cfg.frame_gls_iterations > 0:
        # Scored and tested at the point level; the chosen hinge is refitted frame by frame.
        fit_r = replace(finals["revolute"][0])
        fit_r.points, fit_r.q = fit_r.points.copy(), fit_r.q.copy()
        if _refine_frame_level(fit_r, y, valid, ref, cfg):
            joint_r, points_r = _finalize(fit_r, ref, y, m.sigma, cfg)
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
            joint_c, points_c[fit_c.track_ok], pts[ref, fit_c.track_ok & valid[ref]], m.rigid, cfg
        )
        hyps["prismatic"] = replace(hyps["prismatic"], joint=joint_c)
    closed = np.where(fit_c.track_ok[:, None], points_c, np.nan)
    return JointFit(
        joint=joint_c,
        hypotheses=tuple(hyps[k] for k in ("revolute", "prismatic", "screw", "fixed")),
        inlier_mask=fit_c.track_ok.copy(),
        rigid_motions=m.rigid,
        points_closed=closed,
        noise_sigma_m=m.sigma,
        reference_frame=ref,
    )


def _best_moving(
    hyps: dict[JointType, HypothesisScore],
    finals: dict[JointType, tuple[_Fit, Joint, np.ndarray]],
    m: FrameMotions,
    cfg: JointFitConfig,
) -> JointType:
    """The moving joint type with the best BIC among the plausible ones; the screw only when it
    beats the revolute by ``screw_bic_margin`` with enough travel and a significant pitch."""
    plausible = {
        k: _rotation_plausible(finals[k][1], finals[k][2], finals[k][0].track_ok, cfg)
        for k in ("revolute", "screw")
    }
    moving: list[JointType] = [k for k in ("prismatic", "revolute") if k == "prismatic" or plausible[k]]
    best = min(moving, key=lambda k: hyps[k].bic)
    screw = finals["screw"][1]
    travel = abs(screw.pitch) * float(screw.q_range[1] - screw.q_range[0])
    support = m.ransac_in.sum(1)
    strong = m.has & (support >= max(cfg.pitch_min_support, cfg.pitch_support_fraction * float(np.median(support[m.has]))))
    # Tested at the revolute's fit (see _pitch_significance); the screw's own axis when the
    # revolute ran away (no hinge near the part to test against).
    null = finals["revolute"][1] if plausible["revolute"] else screw
    pitch_t = _pitch_significance(null, m.rots, m.trans, strong, m.centroid)
    if (
        hyps["screw"].bic + cfg.screw_bic_margin < hyps["revolute"].bic
        and hyps["screw"].bic < hyps["prismatic"].bic
        and travel >= cfg.min_screw_travel_m
        and pitch_t >= cfg.screw_min_pitch_t
        and plausible["screw"]
    ):
        best = "screw"
    return best
