"""Point-to-plane ICP that keeps gravity: yaw about it and a translation, plus a bounded tilt.

Both recordings come from AR sessions that measure gravity with the IMU to a few tenths of a
degree, so the rotation between them is a yaw about gravity. A free 6-DOF ICP started in a wrong
basin tilts away from gravity to fit whatever it can (a real desk recording came back tilted by
40 degrees); one that estimates yaw and translation only cannot. ``max_tilt_rad > 0`` adds the
two tilt angles for a final refinement, clamped to that bound (the sensors' disagreement).

Each Gauss-Newton step linearises the rotation about the centroid of the matched points (so the
translation and the rotation are nearly decoupled) and weights residuals with a Tukey kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from artitwin_core.geometry import axis_angle_to_matrix


@dataclass(frozen=True)
class PlaneTarget:
    """A target surface for point-to-plane ICP: ``points [N, 3]``, unit ``normals [N, 3]``, a tree."""

    points: np.ndarray
    normals: np.ndarray
    tree: cKDTree

    @classmethod
    def of(cls, points: np.ndarray, normals: np.ndarray) -> PlaneTarget:
        points = np.asarray(points, dtype=np.float64)
        return cls(points, np.asarray(normals, dtype=np.float64), cKDTree(points))


@dataclass(frozen=True)
class IcpResult:
    """``transform [4, 4]`` (target_from_source), the fraction of source points with a match
    within the correspondence distance (``fitness``), the RMS point-to-plane distance of those
    matches (``inlier_rmse``, metres) and the iterations run."""

    transform: np.ndarray
    fitness: float
    inlier_rmse: float
    iterations: int


def tilt_of(transform: np.ndarray, up: np.ndarray) -> float:
    """Angle (radians) between ``up`` and the rotated ``up``: how far ``transform`` tilts gravity."""
    u = np.asarray(up, dtype=np.float64)
    return float(np.arccos(np.clip(u @ (transform[:3, :3] @ u), -1.0, 1.0)))


def clamp_tilt(transform: np.ndarray, up: np.ndarray, max_tilt_rad: float, centre: np.ndarray) -> np.ndarray:
    """``transform`` with its tilt reduced to at most ``max_tilt_rad``, rotating about ``centre [3]``
    (target frame) so that the points there do not move."""
    u = np.asarray(up, dtype=np.float64)
    ru = transform[:3, :3] @ u
    tilt = float(np.arccos(np.clip(u @ ru, -1.0, 1.0)))
    if tilt <= max_tilt_rad:
        return transform
    axis = np.cross(ru, u)
    fix = axis_angle_to_matrix(axis / np.linalg.norm(axis), tilt - max_tilt_rad)
    step = np.eye(4)
    step[:3, :3] = fix
    step[:3, 3] = centre - fix @ centre
    return step @ transform


def tilt_vector(transform: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``[3]`` ``up x (R up)``: the axis of the tilt scaled by its sine (zero without tilt)."""
    u = np.asarray(up, dtype=np.float64)
    return np.cross(u, transform[:3, :3] @ u)


@dataclass(frozen=True)
class PlaneSystem:
    """One Gauss-Newton linearisation of the robust point-to-plane cost about the current pose.

    ``hessian [D, D]`` and ``gradient [D]`` (Tukey-weighted ``J^T W J`` and ``J^T W r``) in the
    parameters ``(yaw, tx, ty, tz)`` (``D = 4``; with the tilt, ``(wx, wy, wz, tx, ty, tz)``),
    the rotation about ``centre [3]`` (the weighted centroid of the matches, which nearly
    decouples it from the translation); ``residuals [K]`` the matched point-to-plane distances
    (metres)."""

    hessian: np.ndarray
    gradient: np.ndarray
    centre: np.ndarray
    residuals: np.ndarray


def plane_system(
    points: np.ndarray, target: PlaneTarget, up: np.ndarray, *, max_distance_m: float, kernel_m: float,
    tilt: bool = False,
) -> PlaneSystem | None:
    """The point-to-plane normal equations of ``points [N, 3]`` (already moved into the target
    frame) against ``target``: nearest neighbours within ``max_distance_m``, a Tukey kernel of
    width ``kernel_m`` on the residual. None when fewer than 10 points match or none is weighted."""
    up = np.asarray(up, dtype=np.float64)
    dist, idx = target.tree.query(points, distance_upper_bound=max_distance_m, workers=-1)
    ok = np.isfinite(dist)
    if ok.sum() < 10:
        return None
    p, q, n = points[ok], target.points[idx[ok]], target.normals[idx[ok]]
    r = np.einsum("ij,ij->i", p - q, n)
    w = np.where(np.abs(r) < kernel_m, (1.0 - (r / kernel_m) ** 2) ** 2, 0.0)
    if w.sum() <= 0:
        return None
    centre = (w[:, None] * p).sum(0) / w.sum()
    j_rot = np.cross(p - centre, n)  # d r / d omega for x -> x + omega x (x - centre)
    jac = np.hstack([j_rot if tilt else (j_rot @ up)[:, None], n])
    return PlaneSystem(jac.T @ (w[:, None] * jac), jac.T @ (w * r), centre, r)


def gravity_icp(
    source: np.ndarray,
    target: PlaneTarget,
    init: np.ndarray,
    up: np.ndarray,
    *,
    max_distance_m: float,
    kernel_m: float,
    iterations: int = 30,
    max_tilt_rad: float = 0.0,
    tolerance: float = 1e-5,
) -> IcpResult:
    """Robust point-to-plane ICP with the rotation restricted to yaw about ``up``.

    Args:
        source: ``[M, 3]`` points to move (dynamic session frame).
        target: the surface to align them to (canonical frame).
        init: ``[4, 4]`` starting ``target_from_source``.
        up: ``[3]`` unit vector against gravity, in both frames.
        max_distance_m: nearest neighbours further than this are not matched (metres).
        kernel_m: Tukey kernel width on the point-to-plane residual (metres).
        iterations: at most this many Gauss-Newton steps.
        max_tilt_rad: 0 keeps gravity exactly (4 DOF); otherwise the two tilt angles are also
            estimated and the total tilt of the result is clamped to this bound (radians).
        tolerance: stop when a step rotates less than this (radians) and moves less than this (m).
    """
    up = np.asarray(up, dtype=np.float64)
    src = np.asarray(source, dtype=np.float64)
    transform = np.asarray(init, dtype=np.float64).copy()
    six = max_tilt_rad > 0
    done = 0
    for _ in range(iterations):
        done += 1
        system = plane_system(src @ transform[:3, :3].T + transform[:3, 3], target, up,
                              max_distance_m=max_distance_m, kernel_m=kernel_m, tilt=six)
        if system is None:
            break
        h = system.hessian
        # A direction the points do not constrain (a plane slides along itself) gets no step.
        h = h + np.eye(len(h)) * (1e-6 * np.trace(h) / len(h) + 1e-12)
        x = -np.linalg.solve(h, system.gradient)
        omega = x[:3] if six else x[0] * up
        angle = float(np.linalg.norm(omega))
        rot = axis_angle_to_matrix(omega / angle, angle) if angle > 0 else np.eye(3)
        centre = system.centre
        step = np.eye(4)
        step[:3, :3] = rot
        step[:3, 3] = centre - rot @ centre + x[-3:]
        transform = step @ transform
        if six:
            transform = clamp_tilt(transform, up, max_tilt_rad, centre)
        if angle < tolerance and np.linalg.norm(x[-3:]) < tolerance:
            break
    p = src @ transform[:3, :3].T + transform[:3, 3]
    dist, idx = target.tree.query(p, distance_upper_bound=max_distance_m, workers=-1)
    ok = np.isfinite(dist)
    r = np.einsum("ij,ij->i", p[ok] - target.points[idx[ok]], target.normals[idx[ok]])
    return IcpResult(
        transform=transform,
        fitness=float(ok.mean()) if len(ok) else 0.0,
        inlier_rmse=float(np.sqrt(np.mean(r**2))) if len(r) else float("inf"),
        iterations=done,
    )
