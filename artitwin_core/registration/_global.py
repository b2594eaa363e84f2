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
    """One global hypothesis: ``canonical_from_session``, its correlation score (higher better)
    and which of its yaw's translation peaks it is (0 = the highest)."""

    canonical_from_session: np.ndarray
    yaw_deg: float
    score: float
    peak: int = 0


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
    peaks_per_yaw: int = 1,
) -> list[YawCandidate]:
    """(yaw, translation) hypotheses: the ``peaks_per_yaw`` best translations (at least 0.5 m
    apart) of each of the best ``num_candidates`` yaws (distinct in yaw); the yaws' best peaks
    first, best yaw first.

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
    scores = np.empty((len(yaws), peaks_per_yaw))
    shifts = np.empty((len(yaws), peaks_per_yaw, 2))
    # Peaks closer than this (cells) are one peak; 0.5 m apart is a different placement.
    radius = max(1, int(round(0.5 / cell_m)))
    for i, yaw in enumerate(yaws):
        c, sn = np.cos(yaw), np.sin(yaw)
        # Rotation about up in the (e1, e2) plane, right-handed about up: e2 -> e1 for +yaw.
        rot = np.array([[c, sn], [-sn, c]])
        g_d = _grids(d_ab @ rot.T, d_slab, origin_d, shape, cell_m, num_slabs)
        f_d = np.fft.rfft2(g_d, axes=(1, 2))
        corr = np.fft.irfft2((f_s * np.conj(f_d)).sum(0), s=shape)
        norm = norm_s * np.sqrt((g_d**2).sum()) + 1e-12
        # Several peaks per yaw: where the recordings overlap only in part, the highest peak can
        # be a wall and the floor slid along each other, the right placement the next one.
        for j in range(peaks_per_yaw):
            k = np.unravel_index(int(np.argmax(corr)), shape)
            scores[i, j] = corr[k] / norm
            # Cyclic shift k: static cell j matches dynamic cell j - k.
            shift = np.array(k, dtype=np.float64)
            shifts[i, j] = np.where(shift > np.array(shape) / 2, shift - np.array(shape), shift)
            rows = np.arange(k[0] - radius, k[0] + radius + 1) % shape[0]
            cols = np.arange(k[1] - radius, k[1] + radius + 1) % shape[1]
            corr[np.ix_(rows, cols)] = -np.inf

    order = np.argsort(-scores[:, 0])
    chosen: list[int] = []
    min_sep = np.deg2rad(max(4.0, 3 * yaw_step_deg))
    for i in order:
        if all(abs(np.angle(np.exp(1j * (yaws[i] - yaws[j])))) > min_sep for j in chosen):
            chosen.append(int(i))
        if len(chosen) == num_candidates:
            break

    out = []
    for i, j in [(i, j) for j in range(peaks_per_yaw) for i in chosen]:
        yaw = yaws[i]
        c, sn = np.cos(yaw), np.sin(yaw)
        rot2 = np.array([[c, sn], [-sn, c]])
        # Point p_d (gravity coords) -> rot2 @ (p_d_ab - d_centre) in the dynamic grid, whose
        # cell j maps onto static cell j + shift: world ab = that + origin_d - s_lo + s_lo...
        # Static grid position of the dynamic grid origin: s_lo + shift * cell; dynamic grid
        # position of a point: rot2 @ (ab - d_centre) - origin_d.
        t_ab = s_lo + shifts[i, j] * cell_m - origin_d - rot2 @ d_centre
        rot3 = np.eye(3)
        rot3[np.ix_([0, 2], [0, 2])] = rot2
        trans = np.array([t_ab[0], dz, t_ab[1]])
        # In gravity coordinates: x_s = rot3 @ x_d + trans. Back to world coordinates.
        rot_w = basis.T @ rot3 @ basis
        trans_w = basis.T @ trans
        m = np.eye(4)
        m[:3, :3] = rot_w
        m[:3, 3] = trans_w
        out.append(YawCandidate(m, float(np.rad2deg(yaw)), float(scores[i, j]), j))
    return out


def _heading(rotation: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Unit horizontal direction a camera (``rotation [3, 3]``, OpenCV axes) looks towards; the
    image's up direction where it looks straight up or down."""
    for axis in (rotation[:, 2], -rotation[:, 1]):
        h = axis - (axis @ up) * up
        if np.linalg.norm(h) > 0.2:
            return h / np.linalg.norm(h)
    return np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])


def camera_anchor(static_camera: np.ndarray, dynamic_camera: np.ndarray, gravity) -> np.ndarray:
    """``[4, 4]`` canonical_from_session that puts ``dynamic_camera`` (``[4, 4]`` session
    world_from_camera) where ``static_camera`` (canonical) is, facing the same horizontal way,
    keeping gravity: what it means for a new AR session to begin where another one began or ended."""
    up = gravity_basis(gravity)[1]
    hs, hd = _heading(static_camera[:3, :3], up), _heading(dynamic_camera[:3, :3], up)
    angle = float(np.arctan2(up @ np.cross(hd, hs), hd @ hs))
    c, s = np.cos(angle), np.sin(angle)
    k = np.array([[0, -up[2], up[1]], [up[2], 0, -up[0]], [-up[1], up[0], 0]])
    rot = np.eye(3) + s * k + (1 - c) * (k @ k)
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = static_camera[:3, 3] - rot @ dynamic_camera[:3, 3]
    return m


def pose_hypotheses(static_poses: np.ndarray, dynamic_poses: np.ndarray, gravity) -> list[tuple[str, np.ndarray]]:
    """The session offsets the recorded poses suggest, beside the yaw sweep's: the identity (both
    recordings in one AR session, or sessions that share a world anchor) and the dynamic
    recording's first camera at the static recording's first or last camera (a new session
    started where the user stood). ``[T, 4, 4]`` world_from_camera each."""
    return [
        ("identity", np.eye(4)),
        ("first dynamic camera at the first static camera", camera_anchor(static_poses[0], dynamic_poses[0], gravity)),
        ("first dynamic camera at the last static camera", camera_anchor(static_poses[-1], dynamic_poses[0], gravity)),
    ]
