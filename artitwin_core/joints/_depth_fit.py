"""Fitting a hinged slab's line (axis and pivot) to the planes its faces show in depth.

Point tracks on a weakly textured door slide along its surface, and the joint fitted to them
inherits their bias: on a white door the pivot line sat centimetres off, along the door's
normal, where a door's tracks say least. A door is a slab, and depth measures its faces
well: each frame's visible face is a plane fitted to a thousand points, which averages the
depth noise down to a fraction of a millimetre without matching any point to any other.

For a rotation ``R`` about the line ``(a, p)``, a face plane ``n0 . x = d0`` at rest becomes
``n_t . x = d_t`` with ``n_t = R n0`` and

    d_t - d0 = (n_t - n0) . p                                        (front face)
    d_t - d0 = (n_t - n0) . p - tau                                  (inside face)

(``tau`` the slab's thickness, the same in every frame). The axis is the direction every
``n_t - n0`` is perpendicular to, the pivot is linear least squares given the normals, and
``q_t`` is the angle from ``n0`` to ``n_t`` about the axis. The inside face, seen once the door
has turned past the camera, fixes the pivot's depth far better than the front face alone, whose
offsets move with it only by ``1 - cos q``.

The rest plane comes from the frames in which the part is at rest (``q ~ 0``), not from undoing
the current joint's motion, so it does not inherit that joint's error. Parts whose rest points
are not one plane (a carved front, a drawer's box) are left to the tracks.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from artitwin_core.joints._config import StateRefineConfig
from artitwin_core.joints._model import rotations_about
from artitwin_core.joints._types import Joint

# Neighbouring depth pixels are not independent (bilinear upsampling, a smoothed sensor): one in
# this many counts as an independent measurement in the standard errors.
_CORRELATED_PIXELS = 16.0


@dataclass(frozen=True)
class PlaneLineFit:
    """A joint line and states fitted to the face planes of a slab.

    Attributes:
        axis: ``[3]`` unit axis, canonical frame (the input's sign).
        pivot: ``[3]`` metres, a point of the line.
        q: ``[T]`` radians from the rest plane's normal to each frame's; NaN where not ``fitted``.
        fitted: ``[T]`` frames whose face plane was measured.
        rest: ``[T]`` frames that made the rest plane.
        inside: ``[T]`` fitted frames that saw the slab's inside face.
        confidence: ``[T]`` in [0, 1] from the standard error of each ``q`` (0 where not fitted).
        residual_m: ``[T]`` robust RMS distance of the frame's points to its plane, metres.
        axis_se_rad: standard error of the axis direction (largest of its two), radians.
        pivot_se_m: standard error of the line's position (largest of its two), metres.
        thickness_m: slab thickness from the inside face, metres; NaN if no frame saw it.
    """

    axis: np.ndarray
    pivot: np.ndarray
    q: np.ndarray
    fitted: np.ndarray
    rest: np.ndarray
    inside: np.ndarray
    confidence: np.ndarray
    residual_m: np.ndarray
    axis_se_rad: float
    pivot_se_m: float
    thickness_m: float


@dataclass(frozen=True)
class _Plane:
    normal: np.ndarray  # [3] unit
    centroid: np.ndarray  # [3] metres
    sigma: float  # robust scatter of inliers about the plane, metres
    inliers: int
    fraction: float  # inliers / points


def _plane_variances(points: np.ndarray, plane: _Plane) -> tuple[float, float]:
    """Variances of a plane fitted to ``points``: of its normal (radians^2) and of its offset
    (metres^2). The offset's is sigma^2 / N_eff; the normal's is that divided by the squared
    spread of the points across the plane (its "lever arm")."""
    n_eff = max(plane.inliers / _CORRELATED_PIXELS, 1.0)
    spread = float(np.sqrt(np.mean(np.sum((points - plane.centroid) ** 2, 1))))
    return (plane.sigma / spread) ** 2 / n_eff, plane.sigma**2 / n_eff


def _weighted_plane(points: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = (w[:, None] * points).sum(0) / w.sum()
    e = points - c
    return np.linalg.eigh((w[:, None] * e).T @ e)[1][:, 0], c


def _robust_plane(
    points: np.ndarray, guess: np.ndarray, cfg: StateRefineConfig, rng: np.random.Generator
) -> _Plane | None:
    """:func:`robust_plane` with ``StateRefineConfig``'s ``min_points`` and ``plane_*`` fields."""
    return robust_plane(
        points, guess, rng, min_points=cfg.min_points, normal_tol_deg=cfg.plane_normal_tol_deg,
        iterations=cfg.plane_ransac_iterations, band_m=cfg.plane_ransac_band_m,
    )


def robust_plane(
    points: np.ndarray, guess: np.ndarray, rng: np.random.Generator, *, min_points: int,
    normal_tol_deg: float, iterations: int, band_m: float,
) -> _Plane | None:
    """The dominant plane of ``points [N, 3]`` whose normal is within ``normal_tol_deg`` of
    ``guess [3]`` (unit), returned with the guess's sign: RANSAC (``iterations`` 3-point samples
    scored in a band of ``band_m`` metres), then Tukey-weighted PCA; None with fewer than
    ``min_points`` points or no such plane.

    The inlier band scales with the points' own scatter about the plane, so it admits the depth
    noise of far or noisy frames and refuses a door's edge face or the carcass beside it."""
    n = points.shape[0]
    if n < min_points:
        return None
    cos_tol = np.cos(np.radians(normal_tol_deg))
    best, best_score = None, -1.0
    tri = rng.integers(0, n, size=(iterations, 3))
    for i, j, k in tri:
        nrm = np.cross(points[j] - points[i], points[k] - points[i])
        norm = np.linalg.norm(nrm)
        if norm < 1e-9:
            continue
        nrm /= norm
        if abs(nrm @ guess) < cos_tol:
            continue
        dist = np.abs((points - points[i]) @ nrm)
        score = float(np.sum(np.maximum(0.0, 1.0 - (dist / band_m) ** 2)))
        if score > best_score:
            best, best_score = (nrm, points[i]), score
    if best is None:
        return None
    nrm, c = best
    scale = band_m
    for _ in range(10):
        r = (points - c) @ nrm
        sigma = max(1.4826 * float(np.median(np.abs(r[np.abs(r) < 3.0 * scale]))), 1e-4)
        scale = 4.685 * sigma
        z = r / scale
        w = np.where(np.abs(z) < 1.0, (1.0 - z**2) ** 2, 0.0)
        if w.sum() < 3:
            return None
        nrm, c = _weighted_plane(points, w)
    nrm = nrm if nrm @ guess >= 0 else -nrm
    if abs(nrm @ guess) < cos_tol:
        return None
    r = (points - c) @ nrm
    inl = np.abs(r) < 2.5 * sigma
    return _Plane(nrm, c, sigma, int(inl.sum()), float(inl.mean()))


def _basis(a: np.ndarray) -> np.ndarray:
    """``[3, 2]`` orthonormal directions perpendicular to unit ``a``."""
    helper = np.eye(3)[np.argmin(np.abs(a))]
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(a, e1)], 1)


def _signed_angle(a: np.ndarray, n0: np.ndarray, n1: np.ndarray) -> float:
    """Angle (radians) turning ``n0`` onto ``n1`` about unit ``a`` (right hand), in the plane ⟂ ``a``."""
    u = n0 - (n0 @ a) * a
    v = n1 - (n1 @ a) * a
    return float(np.arctan2(a @ np.cross(u, v), u @ v))


def _solve_line(normals, offsets, inside, var_n, var_off, lever, n0, d0, axis_in, pivot_in):
    """Axis, pivot and thickness from face planes (normals ``[F, 3]``, offsets ``[F]``, inside
    ``[F]`` bool, variances ``[F]`` of the normals and offsets, distances ``[F]`` of the planes'
    centroids from the line) against the rest plane ``(n0, d0)``; with standard errors and each
    frame's normalised residuals (normal across the axis, offset). None when singular."""
    # Axis: the unit direction most perpendicular to every n_t - n0 (weighted by the normals'
    # precision), sign kept from the input; its standard error from the next curvature.
    dn = normals - n0
    m = (dn / var_n[:, None]).T @ dn
    vals, vecs = np.linalg.eigh(m)
    axis = vecs[:, 0] * (1.0 if vecs[:, 0] @ axis_in >= 0 else -1.0)
    axis_se = float(1.0 / np.sqrt(max(vals[1], 1e-300)))
    z_n = (dn @ axis) / np.sqrt(var_n)
    # Pivot (2 unknowns across the axis) and thickness (if an inside face was seen), weighted by
    # the offsets' precision plus the normals' error carried over the plane's distance to the line.
    b = _basis(axis)
    rhs = offsets - d0 - dn @ pivot_in
    cols = [dn @ b[:, 0], dn @ b[:, 1]]
    if inside.any():
        cols.append(-inside.astype(float))
    design = np.stack(cols, 1)
    var_d = var_off + var_n * lever**2
    wts = 1.0 / var_d
    try:
        cov = np.linalg.inv(design.T @ (wts[:, None] * design))
    except np.linalg.LinAlgError:
        return None
    sol = cov @ (design.T @ (wts * rhs))
    res = rhs - design @ sol
    z_d = res * np.sqrt(wts)
    # The covariance grows with the fit's own scatter when that exceeds the planes' precision.
    dof = max(normals.shape[0] - design.shape[1], 1)
    chi2 = max(float(np.sum(z_d**2) / dof), 1.0)
    pivot = pivot_in + b @ sol[:2]
    pivot_se = float(np.sqrt(max(np.linalg.eigvalsh(cov[:2, :2] * chi2).max(), 0.0)))
    thickness = float(sol[2]) if inside.any() else float("nan")
    axis_se *= np.sqrt(max(float(np.sum(z_n**2) / max(normals.shape[0] - 2, 1)), 1.0))
    return axis, pivot, thickness, axis_se, pivot_se, z_n / np.sqrt(chi2), z_d / np.sqrt(chi2)


def fit_line_from_planes(joint: Joint, lifted, cams: np.ndarray, cfg: StateRefineConfig) -> PlaneLineFit | None:
    """Fit a revolute joint's line and states to the face planes of its part (module docstring).

    Args:
        joint: the joint with states ``q [T]`` refined per frame; its line and ``q`` only say
            which way each frame's face should point.
        lifted: per frame, the part's canonical points ``[N, 3]`` (and normals, unused).
        cams: ``[T, 3]`` camera centres, canonical frame.
        cfg: ``StateRefineConfig`` (the ``plane_*``, ``axis_*`` and ``rest_rad`` fields).

    Returns:
        The fit, or None where it cannot be trusted: not a revolute joint, no frames at rest,
        a rest part that is not one plane (fewer than ``plane_min_fraction`` of its points on
        it), too few turned frames or too little angle among them, standard errors above
        ``axis_max_se_rad`` / ``axis_max_pivot_se_m``, or a line turned or moved farther than
        ``axis_max_change_rad`` / ``axis_max_shift_m`` from the input's.
    """
    if joint.joint_type != "revolute":
        return None
    t_count = cams.shape[0]
    q0 = np.asarray(joint.q, dtype=np.float64)
    conf0 = np.nan_to_num(np.asarray(joint.confidence, dtype=np.float64))
    n_pts = np.array([p.shape[0] for p, _ in lifted])
    usable = (n_pts >= cfg.min_points) & np.isfinite(q0)
    rest = usable & (np.abs(q0) <= cfg.rest_rad) & (conf0 >= cfg.seed_confidence)
    if not rest.any():
        return None
    rng = np.random.default_rng(0)
    axis_in = np.asarray(joint.axis, dtype=np.float64)
    axis_in = axis_in / np.linalg.norm(axis_in)
    pivot_in = np.asarray(joint.pivot, dtype=np.float64)

    # The rest plane, with its normal towards the cameras that saw it. Its guess: the direction
    # of least spread of the rest points (any plane normal is perpendicular to a hinge axis).
    rest_pts = np.concatenate([lifted[t][0] for t in np.nonzero(rest)[0]])
    e = rest_pts - rest_pts.mean(0)
    guess = np.linalg.eigh(e.T @ e)[1][:, 0]
    if guess @ (cams[rest].mean(0) - rest_pts.mean(0)) < 0:
        guess = -guess
    p0 = _robust_plane(rest_pts, guess, cfg, rng)
    if p0 is None or p0.fraction < cfg.plane_min_fraction:
        return None
    n0, d0 = p0.normal, float(p0.normal @ p0.centroid)

    # Each turned frame's face: the front (camera on the side the rest normal turned to) or the
    # inside face (camera behind it), predicted from the per-frame states.
    planes: dict[int, tuple[_Plane, bool]] = {}
    rots = rotations_about(axis_in, np.nan_to_num(q0))
    for t in np.nonzero(usable & ~rest)[0]:
        n_pred = rots[t] @ n0
        plane = _robust_plane(lifted[t][0], n_pred, cfg, rng)
        if plane is None or plane.inliers < cfg.min_points or plane.fraction < cfg.plane_min_fraction:
            continue
        planes[int(t)] = (plane, bool((cams[t] - plane.centroid) @ plane.normal < 0))
    frames = np.array(sorted(planes), dtype=np.int64)
    if frames.size < cfg.axis_min_frames or np.ptp(q0[frames]) < cfg.axis_min_span_rad:
        return None
    normals = np.stack([planes[t][0].normal for t in frames])
    offsets = np.array([planes[t][0].normal @ planes[t][0].centroid for t in frames])
    inside = np.array([planes[t][1] for t in frames])
    sig = np.array([planes[t][0].sigma for t in frames])
    var_n, var_off = np.array([_plane_variances(lifted[t][0], planes[t][0]) for t in frames]).T
    lever = np.array([np.linalg.norm(planes[t][0].centroid - pivot_in) for t in frames])

    # A frame whose plane disagrees with the others' line (an edge face taken for the face, a
    # door mostly out of view) is dropped and the line refitted, the worst first.
    keep = np.ones(frames.size, bool)
    dropped = 0
    while True:
        line = _solve_line(
            normals[keep], offsets[keep], inside[keep], var_n[keep], var_off[keep], lever[keep],
            n0, d0, axis_in, pivot_in,
        )  # fmt: skip
        if line is None:
            return None
        axis, pivot, thickness, axis_se, pivot_se, z_n, z_d = line
        z = np.full(frames.size, -1.0)
        z[keep] = np.maximum(np.abs(z_n), np.abs(z_d))
        worst = int(np.argmax(z))
        if z[worst] <= cfg.plane_outlier_z or dropped >= frames.size // 3 or keep.sum() <= cfg.axis_min_frames:
            break
        keep[worst] = False
        dropped += 1
    if keep.sum() < cfg.axis_min_frames or np.ptp(q0[frames[keep]]) < cfg.axis_min_span_rad:
        return None

    turned = float(np.arctan2(np.linalg.norm(np.cross(axis, axis_in)), abs(axis @ axis_in)))
    d = pivot - pivot_in
    shift = float(np.linalg.norm(d - (d @ axis) * axis))
    if (
        axis_se > cfg.axis_max_se_rad
        or pivot_se > cfg.axis_max_pivot_se_m
        or turned > cfg.axis_max_change_rad
        or shift > cfg.axis_max_shift_m
    ):
        return None

    q = np.full(t_count, np.nan)
    confidence = np.zeros(t_count)
    residual = np.full(t_count, np.nan)
    fitted = np.zeros(t_count, bool)
    inside_t = np.zeros(t_count, bool)
    for i, t in enumerate(frames):
        if not keep[i]:
            continue
        q[t] = _signed_angle(axis, n0, normals[i])
        q_se = np.sqrt(var_n[i])
        confidence[t] = 1.0 / (1.0 + (q_se / cfg.q_tolerance_rad) ** 2)
        residual[t] = sig[i]
        fitted[t] = True
        inside_t[t] = inside[i]
    return PlaneLineFit(
        axis=axis,
        pivot=pivot,
        q=q,
        fitted=fitted,
        rest=rest,
        inside=inside_t,
        confidence=confidence,
        residual_m=residual,
        axis_se_rad=axis_se,
        pivot_se_m=pivot_se,
        thickness_m=thickness,
    )


@dataclass(frozen=True)
class FrontAxisFit:
    """A drawer's front normal, from the planes its frames show (:func:`fit_slide_axis_from_front`).

    Attributes:
        axis: ``[3]`` unit normal, signed like the input joint's axis.
        se_rad: its standard error (radians): the larger of the planes' formal error and their
            scatter about it.
        frames: how many frames' planes it combines.
    """

    axis: np.ndarray
    se_rad: float
    frames: int


def fit_slide_axis_from_front(joint: Joint, lifted, cams: np.ndarray, cfg: StateRefineConfig) -> FrontAxisFit | None:
    """The normal of a sliding part's front, combined over the frames that show it.

    A drawer's front turns with none of its states, so every frame's points hold a plane of the
    same normal (its front, or the box's back and inside faces, parallel to it); each frame's
    plane within ``slide_front_max_deg`` of ``joint``'s axis holding ``plane_min_fraction`` of
    its points is weighted by its precision (:func:`_plane_variances`). None with
    fewer than ``axis_min_frames`` such frames: a sliding door's front is parallel to its slide,
    and no plane is looked for there.

    Args:
        joint: the prismatic joint (its axis is the guess).
        lifted: per frame, the part's canonical points ``[N, 3]``, normals (unused) and whether
            its mask was eroded (``lift_frame``).
        cams: ``[T, 3]`` camera centres, canonical frame.
        cfg: ``StateRefineConfig`` (``min_points``, ``plane_*``, ``axis_min_frames``,
            ``slide_front_max_deg``).
    """
    axis = np.asarray(joint.axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    within = replace(cfg, plane_normal_tol_deg=cfg.slide_front_max_deg)
    rng = np.random.default_rng(0)
    normals, weights = [], []
    for t, (pts, _, eroded) in enumerate(lifted):
        if not eroded or pts.shape[0] < cfg.min_points:  # an uneroded sliver is mostly its mixed outline
            continue
        guess = axis if axis @ (cams[t] - pts.mean(0)) >= 0 else -axis  # the face the camera sees
        plane = _robust_plane(pts, guess, within, rng)
        if plane is None or plane.fraction < cfg.plane_min_fraction:
            continue
        normals.append(plane.normal if plane.normal @ axis >= 0 else -plane.normal)
        weights.append(1.0 / _plane_variances(pts, plane)[0])
    if len(normals) < cfg.axis_min_frames:
        return None
    n, w = np.asarray(normals), np.asarray(weights)
    mean = (w[:, None] * n).sum(0)
    mean /= np.linalg.norm(mean)
    off = np.arccos(np.clip(n @ mean, -1.0, 1.0))
    formal = 1.0 / np.sqrt(w.sum())
    scatter = float(np.sqrt((w * off**2).sum() / w.sum() / (len(n) - 1)))
    return FrontAxisFit(axis=mean, se_rad=float(max(formal, scatter)), frames=len(n))
