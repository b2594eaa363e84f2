"""A chosen slide's direction from the part's face: a drawer slides along its face's normal,
plus the tilt its rigid motions show when that explains them (``_slide_along_face``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artitwin_core.joints._config import JointFitConfig
from artitwin_core.joints._depth_fit import robust_plane
from artitwin_core.joints._fit import _tangent_basis
from artitwin_core.joints._types import Joint


def _slide_along_face(
    joint: Joint, points: np.ndarray, points_ref: np.ndarray, rigid: np.ndarray, cfg: JointFitConfig
) -> Joint:
    """``joint`` (prismatic, direction ``a``) with its direction fused with its part's face
    normal ``n`` where the tracks cannot tell the two apart; else ``joint`` itself.

    A drawer slides along its front's normal. The tracks measure the slide's direction from the
    part's displacement across ``a`` per unit of travel, and a tracker's error is common to a
    frame's points (a drawer's tracks shift a frame by millimetres across the slide while
    moving): over 0.25 m of travel that is up to a degree, frames, not points, being the
    independent samples. The front's normal is a plane fit over hundreds of points, each with
    its own noise (a tenth of a degree or less from the truth). Per axis ``e``
    across ``a``: the tracks' slope is the regression of the frames' displacements (``rigid
    [T, 4, 4]`` applied to the points' centroid) along ``e`` on ``q``, with its standard error
    from the frames' scatter; the face's slope is ``(n.e) / (n.a)``, with the plane fit's
    standard error. If the two agree (chi-square over both axes at most ``face_chi2``, the
    tracks' variance widened by ``slide_floor_rad`` of systematic error), the direction takes
    their inverse-variance weighted mean (the scatter's variances: a flat front's normal
    outweighs the tracks, clean tracks outweigh a thick slab's scattered face). Needs a face:
    ``face_min_fraction`` of ``points [N, 3]`` (the closed part's inliers) on one plane whose
    normal is within ``face_max_angle_rad`` of ``a``.

    A drawer that also turns as it slides (its front dips over the travel) is tested first
    (``_tilt_rate``). Its tracks' direction is their centroid's, degrees off the rail, and the
    rail's direction is that of the turn's pivot, which no track sees; the prismatic model's
    latent ``points`` are smeared by the turn. So a tilting slide takes its face from
    ``points_ref [M, 3]``, the reference
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
        face_points, a, np.random.default_rng(cfg.seed), min_points=cfg.face_fit_min_points,
        normal_tol_deg=float(np.degrees(cfg.face_max_angle_rad + stray)), iterations=cfg.face_fit_iterations,
        band_m=cfg.face_fit_band_m,
    )
    if plane is None or plane.fraction < cfg.face_min_fraction:
        return joint
    n = plane.normal
    on_face = face_points[np.abs((face_points - plane.centroid) @ n) < 2.5 * plane.sigma] - plane.centroid
    if tilt is not None:
        gap = np.asarray(sum((slope - float(n @ e) / float(n @ a)) * e for e, slope in zip(_tangent_basis(a), slopes, strict=True)))
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
    centroid. True when the gap's part along ``w`` is within ``tilt_explain_sigmas`` of the tracks' standard errors
    ``se_tracks`` (widened by ``slide_floor_rad``) and the rest within ``|w| reach``."""
    turn = float(np.linalg.norm(rate))
    w = rate / turn
    along = abs(float(gap @ w))
    across = float(np.linalg.norm(gap - (gap @ w) * w))
    return along <= cfg.tilt_explain_sigmas * float(np.hypot(se_tracks, cfg.slide_floor_rad)) and across <= turn * reach
