"""A recording's pose drift: odometry error that grows linearly in time (the effect ``pose_drift``).

ARKit-style visual-inertial odometry sees gravity, so its world frame can only creep by a turn
about gravity (yaw) and a translation, both accumulating from the first frame. Over a sweep of a
few tens of seconds that is well described by rates: the recorded pose of frame ``t`` is off the
true one by the rigid motion ``exp(yaw_rate * (t - t0) * g) , trans_rate * (t - t0)`` about the
first camera. :class:`PoseDrift` holds such a correction (and a constant rigid offset, which a
second recording's registration leaves), :func:`sift_matches` and :func:`feature_terms` give the
image evidence that fixes the drift along surfaces depth alone cannot see (sliding along a wall).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from artitwin_core.capture._types import Capture
from artitwin_core.geometry import axis_angle_to_matrix, invert_se3, make_se3
from artitwin_core.geometry import pixel_rays as camera_rays


def _rigid_about(pivot: np.ndarray, rotvec: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """``[4, 4]``: rotate by ``rotvec`` (radians) about ``pivot``, then translate by ``trans``."""
    angle = float(np.linalg.norm(rotvec))
    rot = axis_angle_to_matrix(rotvec / angle, angle) if angle > 1e-15 else np.eye(3)
    about = make_se3(np.eye(3), pivot)
    return about @ make_se3(rot, trans) @ invert_se3(about)


@dataclass(frozen=True)
class PoseDrift:
    """A correction of recorded poses: ``corrected(t) = G(t) @ recorded(t)`` with
    ``G(t) = G_rate(t - t0_s) @ G_offset``, both rigid motions about ``pivot``.

    Attributes:
        pivot: ``[3]`` metres, the point the motions turn about (the first camera's position).
        t0_s: time (seconds, the recording's clock) at which the rate part is zero.
        rot0_rad, trans0_m: ``[3]`` the constant part (rotation vector, translation).
        rot_rate_rad_per_s, trans_rate_m_per_s: ``[3]`` the rate part.
    """

    pivot: np.ndarray
    t0_s: float = 0.0
    rot0_rad: np.ndarray = field(default_factory=lambda: np.zeros(3))
    trans0_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rot_rate_rad_per_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    trans_rate_m_per_s: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def correction(self, timestamps: np.ndarray) -> np.ndarray:
        """``[T, 4, 4]`` the correction ``G(t)`` at each time (seconds)."""
        g0 = _rigid_about(self.pivot, np.asarray(self.rot0_rad, float), np.asarray(self.trans0_m, float))
        out = []
        for t in np.asarray(timestamps, float) - self.t0_s:
            rate = _rigid_about(self.pivot, t * np.asarray(self.rot_rate_rad_per_s, float),
                                t * np.asarray(self.trans_rate_m_per_s, float))
            out.append(rate @ g0)
        return np.stack(out) if out else np.zeros((0, 4, 4))

    def apply(self, world_from_camera: np.ndarray, timestamps: np.ndarray) -> np.ndarray:
        """``[T, 4, 4]`` corrected poses from recorded ``world_from_camera [T, 4, 4]``."""
        return np.einsum("tij,tjk->tik", self.correction(timestamps), np.asarray(world_from_camera, float))

    def in_frame(self, new_from_old: np.ndarray) -> PoseDrift:
        """The same correction for poses expressed in another frame: if this corrects
        ``old_from_camera``, the result corrects ``new_from_old @ old_from_camera``."""
        rot, trans = new_from_old[:3, :3], new_from_old[:3, 3]
        return PoseDrift(
            pivot=rot @ self.pivot + trans, t0_s=self.t0_s,
            rot0_rad=rot @ self.rot0_rad, trans0_m=rot @ self.trans0_m,
            rot_rate_rad_per_s=rot @ self.rot_rate_rad_per_s, trans_rate_m_per_s=rot @ self.trans_rate_m_per_s,
        )

    def rate_at(self, point: np.ndarray) -> np.ndarray:
        """``[3]`` how fast the rate part moves ``point`` (m/s)."""
        return np.cross(np.asarray(self.rot_rate_rad_per_s, float), point - self.pivot) + np.asarray(
            self.trans_rate_m_per_s, float
        )

    def rate_displacement_m(self, point: np.ndarray, t_s: float) -> np.ndarray:
        """``[3]`` how far the rate part alone moves ``point`` (metres) by time ``t_s``."""
        g = _rigid_about(self.pivot, (t_s - self.t0_s) * np.asarray(self.rot_rate_rad_per_s, float),
                         (t_s - self.t0_s) * np.asarray(self.trans_rate_m_per_s, float))
        return g[:3, :3] @ point + g[:3, 3] - point


@dataclass(frozen=True)
class DriftSignificance:
    """How far a fitted drift's rate moves a reference point by the recording's end, how sure that
    is, and whether each half of the recording sees the same drift.

    Attributes:
        point: ``[3]`` the reference point (metres): ahead of the first camera at the median depth.
        displacement_m: ``[3]`` the rate part's displacement of ``point`` at the last frame.
        displacement_se_m: ``[3]`` its standard errors (frame-block jackknife); NaN if unknown.
        z_score: ``|displacement|`` over its standard error along its own direction.
        rate_m_per_s: ``[3]`` how fast the drift moves ``point``.
        half_rates_m_per_s: ``[2, 3]`` the same, fitted on the first and on the second half of the
            recording alone (None if a half is too short to fit). A drift is linear only if both
            halves see it.
    """

    point: np.ndarray
    displacement_m: np.ndarray
    displacement_se_m: np.ndarray
    z_score: float
    rate_m_per_s: np.ndarray
    half_rates_m_per_s: np.ndarray | None = None

    @property
    def size_m(self) -> float:
        return float(np.linalg.norm(self.displacement_m))

    @property
    def half_disagreement(self) -> float:
        """``|rate(first half) - rate(second half)| / |rate|`` (NaN without halves)."""
        if self.half_rates_m_per_s is None:
            return float("nan")
        diff = float(np.linalg.norm(self.half_rates_m_per_s[0] - self.half_rates_m_per_s[1]))
        return diff / max(float(np.linalg.norm(self.rate_m_per_s)), 1e-12)

    def why_not(self, min_displacement_m: float, min_z: float, max_half_disagreement: float) -> str:
        """Why this drift should not be applied, in words; empty if it should. It must move the
        reference point by at least ``min_displacement_m``, by at least ``min_z`` standard
        errors, and both halves of the recording must see it, their rates differing by at most
        ``max_half_disagreement`` of its rate (a spurious trend fitted to per-frame jitter or to
        the canonical model's own errors changes with the frames; a real drift does not)."""
        size = self.size_m
        if size < min_displacement_m:
            return (f"the drift moves a point {1e3 * size:.1f} mm by the last frame, under the "
                    f"{1e3 * min_displacement_m:.0f} mm that would matter")
        if not (self.z_score >= min_z):
            return (f"the drift ({1e3 * size:.1f} mm by the last frame) is {self.z_score:.1f} standard errors, "
                    f"under {min_z:g}")
        if self.half_rates_m_per_s is None:
            return (f"the recording is too short to fit the drift ({1e3 * size:.1f} mm by the last frame) on each half "
                    "alone, so it cannot be told from a trend that per-frame errors fake")
        if not (self.half_disagreement <= max_half_disagreement):
            r0, r1 = (1e3 * np.asarray(r) for r in self.half_rates_m_per_s)
            return (f"the two halves of the recording disagree on the drift (rates {np.round(r0, 1).tolist()} and "
                    f"{np.round(r1, 1).tolist()} mm/s, {self.half_disagreement:.1f} times the fitted "
                    f"{1e3 * float(np.linalg.norm(self.rate_m_per_s)):.1f} mm/s): it is not a linear drift")
        return ""


def drift_significance(
    drift: PoseDrift, point: np.ndarray, t_end: float, rate_cov: np.ndarray | None, yaw_axis: np.ndarray
) -> DriftSignificance:
    """The rate part's displacement of ``point`` by ``t_end`` and its uncertainty, from the
    ``[4, 4]`` covariance ``rate_cov`` of (yaw rate about the unit ``yaw_axis`` in rad/s,
    translation rate in m/s); None leaves the standard errors NaN."""
    disp = drift.rate_displacement_m(point, t_end)
    se = np.full(3, np.nan)
    z = float("nan")
    if rate_cov is not None:
        dt = t_end - drift.t0_s
        jac = np.concatenate([dt * np.cross(yaw_axis, point - drift.pivot)[:, None], dt * np.eye(3)], 1)
        cov = jac @ rate_cov @ jac.T
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        size = float(np.linalg.norm(disp))
        if size > 0:
            u = disp / size
            z = size / max(float(np.sqrt(max(u @ cov @ u, 0.0))), 1e-12)
    return DriftSignificance(
        point=np.asarray(point, float), displacement_m=disp, displacement_se_m=se, z_score=z,
        rate_m_per_s=drift.rate_at(point),
    )


def block_jackknife_cov(
    design: np.ndarray, weights: np.ndarray, rhs: np.ndarray, block: np.ndarray, ridge: float = 0.0
) -> np.ndarray | None:
    """``[P, P]`` jackknife covariance of the weighted least-squares solution of ``design [N, P]
    x = -rhs [N]`` (weights ``[N]``), leaving out each ``block [N]`` label in turn: rows that share
    a block (a frame's points share its pose and depth-map errors) are not independent, so their
    scatter is what the covariance must show. None with fewer than 3 solvable blocks."""
    drops = []
    for k in np.unique(block):
        keep = block != k
        x, w = design[keep], weights[keep]
        hess = (x * w[:, None]).T @ x + ridge * np.eye(design.shape[1])
        if np.linalg.cond(hess) < 1e12:
            drops.append(np.linalg.solve(hess, -(x * w[:, None]).T @ rhs[keep]))
    if len(drops) < 3:
        return None
    d = np.asarray(drops)
    n = len(d)
    return (n - 1) / n * (d - d.mean(0)).T @ (d - d.mean(0))


# ----------------------------------------------------------------------------------------------
# Image evidence: SIFT matches and their reprojection terms
# ----------------------------------------------------------------------------------------------


class FeatureCache:
    """SIFT keypoints ``[N, 2]`` (RGB pixels) and descriptors of a recording's frames, computed
    once per frame."""

    def __init__(self, rgb: np.ndarray, max_features: int = 1500):
        self._rgb = rgb
        self._sift = cv2.SIFT_create(nfeatures=max_features)
        self._cache: dict[int, tuple[np.ndarray, np.ndarray | None]] = {}

    def __call__(self, frame: int) -> tuple[np.ndarray, np.ndarray | None]:
        if frame not in self._cache:
            grey = cv2.cvtColor(np.ascontiguousarray(self._rgb[frame]), cv2.COLOR_RGB2GRAY)
            kps, desc = self._sift.detectAndCompute(grey, None)
            self._cache[frame] = (np.float64([k.pt for k in kps]).reshape(-1, 2), desc)
        return self._cache[frame]


def sift_matches(
    a: tuple[np.ndarray, np.ndarray | None], b: tuple[np.ndarray, np.ndarray | None], ratio: float = 0.75,
    ransac_px: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Matched pixels ``([M, 2], [M, 2])`` between two frames' features: Lowe's ratio test, then
    a fundamental-matrix RANSAC (``ransac_px``). Empty arrays when fewer than 8 survive."""
    (pa, da), (pb, db) = a, b
    empty = (np.zeros((0, 2)), np.zeros((0, 2)))
    if da is None or db is None or len(pa) < 8 or len(pb) < 8:
        return empty
    knn = cv2.BFMatcher().knnMatch(da, db, k=2)
    good = [m for m, n in (x for x in knn if len(x) == 2) if m.distance < ratio * n.distance]
    if len(good) < 8:
        return empty
    pi = pa[[g.queryIdx for g in good]]
    pj = pb[[g.trainIdx for g in good]]
    _, inl = cv2.findFundamentalMat(pi, pj, cv2.FM_RANSAC, ransac_px, 0.999)
    if inl is None:
        return empty
    inl = inl.ravel().astype(bool)
    return pi[inl], pj[inl]


def depth_at_pixels(
    capture: Capture, frame: int, pixels: np.ndarray, edge_m: float = 0.02, min_confidence: int = 0
) -> np.ndarray:
    """``[N]`` measured depth (bilinear on the depth map) at RGB ``pixels [N, 2]`` of ``frame``;
    NaN off the map, across a depth edge (the four neighbours span more than ``edge_m``), or
    below ``min_confidence``."""
    kr = np.asarray(capture.rgb_intrinsics[frame], float)
    kd = np.asarray(capture.depth_intrinsics[frame], float)
    dm = np.asarray(capture.depth[frame], float)
    if capture.confidence is not None and min_confidence > 0:
        dm = np.where(np.asarray(capture.confidence[frame]) >= min_confidence, dm, np.nan)
    h, w = dm.shape
    ud = (pixels[:, 0] - kr[2]) / kr[0] * kd[0] + kd[2]
    vd = (pixels[:, 1] - kr[3]) / kr[1] * kd[1] + kd[3]
    inside = (ud >= 0) & (ud < w - 1) & (vd >= 0) & (vd < h - 1)
    u0 = np.clip(np.floor(ud).astype(int), 0, w - 2)
    v0 = np.clip(np.floor(vd).astype(int), 0, h - 2)
    fu, fv = ud - u0, vd - v0
    q = np.stack([dm[v0, u0], dm[v0, u0 + 1], dm[v0 + 1, u0], dm[v0 + 1, u0 + 1]], 1)
    d = q[:, 0] * (1 - fu) * (1 - fv) + q[:, 1] * fu * (1 - fv) + q[:, 2] * (1 - fu) * fv + q[:, 3] * fu * fv
    with np.errstate(invalid="ignore"):
        ok = inside & np.isfinite(d) & ((np.max(q, 1) - np.min(q, 1)) <= edge_m)
    return np.where(ok, d, np.nan)


def ray_normals(rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``[N, 3]`` each perpendicular to ``rays [N, 3]`` and to each other: the
    directions in which a point's distance from the ray is measured."""
    r = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    up = np.where(np.abs(r[:, 1:2]) < 0.9, np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))
    m1 = np.cross(r, up)
    m1 /= np.linalg.norm(m1, axis=1, keepdims=True)
    return m1, np.cross(r, m1)


def pixel_rays(intrinsics, pixels: np.ndarray, world_from_camera: np.ndarray) -> np.ndarray:
    """``[N, 3]`` world directions (camera z = 1) of ``pixels [N, 2]``."""
    cam = camera_rays(intrinsics, pixels[:, 0], pixels[:, 1])
    return cam @ np.asarray(world_from_camera, float)[:3, :3].T
