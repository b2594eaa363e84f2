"""Global alignment of two gravity-aligned clouds: an exhaustive yaw sweep plus correlation.

Both recordings come from AR sessions that share the gravity direction, so the unknown rotation
is one angle (yaw about gravity). We sweep it exhaustively instead of matching local descriptors
(FPFH + RANSAC): the sweep cannot miss the right basin, whatever the yaw (170 degrees included),
and it does not need distinctive local geometry, which flat, low-texture rooms lack. For each yaw
the horizontal translation is the peak of the FFT cross-correlation of top-down occupancy grids
of vertical structures (walls, furniture sides), in a few height slabs; the vertical offset comes
first, from the correlation of height histograms, which does not depend on yaw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class YawCandidate:
    """One global hypothesis: ``canonical_from_session`` and its correlation score (higher better)."""

    canonical_from_session: np.ndarray
    yaw_deg: float
    score: float


def gravity_basis(gravity) -> np.ndarray:
    """``[3, 3]`` rows ``(e1, up, e2)``: an orthonormal right-handed frame with ``up = -gravity``."""
    up = -np.asarray(gravity, dtype=np.float64)
    up /= np.linalg.norm(up)
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = helper - up * (helper @ up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e1, up)
    return np.stack([e1, up, e2])


def _height_offset(h_static: np.ndarray, h_dyn: np.ndarray, bin_m: float) -> float:
    """Vertical shift (metres) that best overlays the dynamic height histogram on the static one."""
    lo = min(h_static.min(), h_dyn.min()) - 1.0
    hi = max(h_static.max(), h_dyn.max()) + 1.0
    bins = np.arange(lo, hi + bin_m, bin_m)
    a = np.log1p(np.histogram(h_static, bins)[0].astype(np.float64))
    b = np.log1p(np.histogram(h_dyn, bins)[0].astype(np.float64))
    a -= a.mean()
    b -= b.mean()
    corr = np.correlate(a, b, mode="full")  # corr[k] pairs a[i] with b[i - (k - (n - 1))]
    k = int(np.argmax(corr))
    # Sub-bin peak by a parabola through the neighbours.
    frac = 0.0
    if 0 < k < len(corr) - 1:
        den = corr[k - 1] - 2 * corr[k] + corr[k + 1]
        frac = 0.5 * (corr[k - 1] - corr[k + 1]) / den if den < 0 else 0.0
    return (k - (len(b) - 1) + frac) * bin_m


def _grids(ab: np.ndarray, slab: np.ndarray, origin: np.ndarray, shape, cell: float, num_slabs: int) -> np.ndarray:
    """Binary top-down occupancy ``[S, A, B]`` of points ``ab [N, 2]`` in slabs ``slab [N]``."""
    idx = np.floor((ab - origin) / cell).astype(np.int64)
    ok = (idx[:, 0] >= 0) & (idx[:, 0] < shape[0]) & (idx[:, 1] >= 0) & (idx[:, 1] < shape[1])
    g = np.zeros((num_slabs, *shape), dtype=np.float64)
    g[slab[ok], idx[ok, 0], idx[ok, 1]] = 1.0
    # A little blur tolerates the cell quantisation and small rotation errors.
    return ndimage.gaussian_filter(g, sigma=(0, 0.7, 0.7))


def yaw_candidates(
    static_points: np.ndarray,
    static_normals: np.ndarray,
    dynamic_points: np.ndarray,
    dynamic_normals: np.ndarray,
    gravity,
    *,
    yaw_step_deg: float = 1.0,
    cell_m: float = 0.05,
    height_bin_m: float = 0.02,
    num_slabs: int = 4,
    num_candidates: int = 6,
) -> list[YawCandidate]:
    """The best ``num_candidates`` (yaw, translation) hypotheses, distinct in yaw, best first.

    Args:
        static_points, static_normals: ``[N, 3]`` static cloud (canonical frame) and unit normals.
        dynamic_points, dynamic_normals: ``[M, 3]`` dynamic cloud (its session frame) and normals.
        gravity: ``[3]`` direction of gravity, shared by both frames.
    """
    basis = gravity_basis(gravity)  # rows e1, up, e2
    s = static_points @ basis.T
    d = dynamic_points @ basis.T
    dz = _height_offset(s[:, 1], d[:, 1], height_bin_m)

    # Vertical structures only: horizontal planes (floor, ceiling, shelves) carry no yaw or
    # horizontal information and would dominate the occupancy.
    up = basis[1]
    s_v = np.abs(static_normals @ up) < 0.5
    d_v = np.abs(dynamic_normals @ up) < 0.5
    if s_v.sum() < 50 or d_v.sum() < 50:
        s_v = np.ones(len(s), bool)
        d_v = np.ones(len(d), bool)
    s, d = s[s_v], d[d_v]
    d = d + np.array([0.0, dz, 0.0])

    h_lo, h_hi = np.quantile(s[:, 1], [0.02, 0.98])
    edges = np.linspace(h_lo, h_hi, num_slabs + 1)
    s_slab = np.clip(np.searchsorted(edges, s[:, 1]) - 1, 0, num_slabs - 1)
    d_slab = np.clip(np.searchsorted(edges, d[:, 1]) - 1, 0, num_slabs - 1)

    # A common grid large enough for any rotated dynamic cloud plus the static one (no wrap).
    s_ab = s[:, [0, 2]]
    d_ab = d[:, [0, 2]]
    d_centre = d_ab.mean(0)
    d_ab = d_ab - d_centre
    d_radius = float(np.max(np.linalg.norm(d_ab, axis=1))) + 2 * cell_m
    s_lo, s_hi = s_ab.min(0) - d_radius, s_ab.max(0) + d_radius
    n = np.ceil((s_hi - s_lo) / cell_m).astype(int) + 1
    shape = tuple(int(x) for x in n)
    g_s = _grids(s_ab, s_slab, s_lo, shape, cell_m, num_slabs)
    f_s = np.fft.rfft2(g_s, axes=(1, 2))
    norm_s = np.sqrt((g_s**2).sum())
    centre_cell = np.array(shape) // 2
    origin_d = -centre_cell * cell_m  # the dynamic cloud is centred on the grid's middle cell

    yaws = np.deg2rad(np.arange(0.0, 360.0, yaw_step_deg))
    scores = np.empty(len(yaws))
    shifts = np.empty((len(yaws), 2))
    for i, yaw in enumerate(yaws):
        c, sn = np.cos(yaw), np.sin(yaw)
        # Rotation about up in the (e1, e2) plane, right-handed about up: e2 -> e1 for +yaw.
        rot = np.array([[c, sn], [-sn, c]])
        g_d = _grids(d_ab @ rot.T, d_slab, origin_d, shape, cell_m, num_slabs)
        f_d = np.fft.rfft2(g_d, axes=(1, 2))
        corr = np.fft.irfft2((f_s * np.conj(f_d)).sum(0), s=shape)
        k = np.unravel_index(int(np.argmax(corr)), shape)
        scores[i] = corr[k] / (norm_s * np.sqrt((g_d**2).sum()) + 1e-12)
        # Cyclic shift k: static cell j matches dynamic cell j - k.
        shift = np.array(k, dtype=np.float64)
        shift = np.where(shift > np.array(shape) / 2, shift - np.array(shape), shift)
        shifts[i] = shift

    order = np.argsort(-scores)
    chosen: list[int] = []
    min_sep = np.deg2rad(max(4.0, 3 * yaw_step_deg))
    for i in order:
        if all(abs(np.angle(np.exp(1j * (yaws[i] - yaws[j])))) > min_sep for j in chosen):
            chosen.append(int(i))
        if len(chosen) == num_candidates:
            break

    out = []
    for i in chosen:
        yaw = yaws[i]
        c, sn = np.cos(yaw), np.sin(yaw)
        rot2 = np.array([[c, sn], [-sn, c]])
        # Point p_d (gravity coords) -> rot2 @ (p_d_ab - d_centre) in the dynamic grid, whose
        # cell j maps onto static cell j + shift: world ab = that + origin_d - s_lo + s_lo...
        # Static grid position of the dynamic grid origin: s_lo + shift * cell; dynamic grid
        # position of a point: rot2 @ (ab - d_centre) - origin_d.
        t_ab = s_lo + shifts[i] * cell_m - origin_d - rot2 @ d_centre
        rot3 = np.eye(3)
        rot3[np.ix_([0, 2], [0, 2])] = rot2
        trans = np.array([t_ab[0], dz, t_ab[1]])
        # In gravity coordinates: x_s = rot3 @ x_d + trans. Back to world coordinates.
        rot_w = basis.T @ rot3 @ basis
        trans_w = basis.T @ trans
        m = np.eye(4)
        m[:3, :3] = rot_w
        m[:3, 3] = trans_w
        out.append(YawCandidate(m, float(np.rad2deg(yaw)), float(scores[i])))
    return out
