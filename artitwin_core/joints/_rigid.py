"""Rigid motion between two point sets: weighted Kabsch and a vectorised 3-point RANSAC.

The RANSAC here only has to find the majority motion of one frame against the reference frame
(the moving part holds most tracks; background, hand and jumping tracks are the minority), so it
scores minimal samples by MSAC (truncated quadratic) and refines on the consensus set.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Median of the chi distribution with 3 degrees of freedom: the median 3D norm of an isotropic
# Gaussian vector with unit per-coordinate standard deviation.
CHI3_MEDIAN = 1.5381722
_BATCH = 32


def kabsch(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid motion with ``dst ~ R @ src + t``, batched.

    Args:
        src: ``[..., M, 3]`` metres.
        dst: ``[..., M, 3]`` metres.
        weights: ``[..., M]`` non-negative, or None for uniform.

    Returns:
        ``R [..., 3, 3]`` (proper rotation, det +1) and ``t [..., 3]`` metres.
    """
    if weights is None:
        weights = np.ones(src.shape[:-1])
    w = weights[..., None]
    wsum = np.maximum(w.sum(-2), 1e-300)
    cs = (w * src).sum(-2) / wsum
    cd = (w * dst).sum(-2) / wsum
    h = np.swapaxes(w * (src - cs[..., None, :]), -1, -2) @ (dst - cd[..., None, :])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)))
    d = np.where(d == 0, 1.0, d)
    fix = np.ones(h.shape[:-2] + (3,))
    fix[..., 2] = d
    rot = np.swapaxes(vt, -1, -2) @ (fix[..., :, None] * np.swapaxes(u, -1, -2))
    trans = cd - (rot @ cs[..., None])[..., 0]
    return rot, trans


@dataclass(frozen=True)
class RigidRansacResult:
    """One frame's motion against the reference frame.

    Attributes:
        rotation: ``[3, 3]``.
        translation: ``[3]`` metres; ``dst ~ rotation @ src + translation``.
        inliers: ``[M]`` bool over the input correspondences.
        residuals: ``[M]`` metres, ``|R src + t - dst|`` for every correspondence.
        threshold_m: the final (noise-adapted) inlier threshold.
    """

    rotation: np.ndarray
    translation: np.ndarray
    inliers: np.ndarray
    residuals: np.ndarray
    threshold_m: float


def ransac_rigid(
    src: np.ndarray,
    dst: np.ndarray,
    rng: np.random.Generator,
    *,
    iterations: int,
    threshold_m: float,
    min_threshold_m: float,
    inlier_sigmas: float,
    confidence: float = 0.999,
) -> RigidRansacResult | None:
    """Robust rigid motion ``dst ~ R src + t`` from ``src, dst [M, 3]`` metres; None if ``M < 3``.

    Minimal 3-point samples (at most ``iterations``, fewer once the consensus makes missing an
    all-inlier sample less likely than ``1 - confidence``) are scored by MSAC at ``threshold_m``;
    the best one is refined by
    Kabsch on its inliers. The threshold then adapts to the noise: the per-coordinate noise of the
    difference is estimated from the median inlier residual (chi-3 median) and the threshold set
    to ``max(min_threshold_m, inlier_sigmas * that)``; Kabsch and the consensus are redone twice.
    """
    m = src.shape[0]
    if m < 3:
        return None
    # Samples are drawn in batches; RANSAC stops once the best consensus so far makes missing an
    # all-inlier sample unlikely (probability 1 - confidence), the standard adaptive criterion.
    best_cost, best_rt, best_r2 = np.inf, None, None
    drawn, needed = 0, iterations
    while drawn < min(needed, iterations):
        k = min(_BATCH, iterations - drawn)
        if m == 3:
            idx = np.arange(3)[None]
        else:
            idx = np.stack([rng.choice(m, 3, replace=False) for _ in range(k)])
        drawn += k
        s = src[idx]
        d = dst[idx]
        # Reject near-collinear samples: their rotation about the line through them is undetermined.
        area = np.linalg.norm(np.cross(s[:, 1] - s[:, 0], s[:, 2] - s[:, 0]), axis=-1)
        keep = area > 1e-8
        if not np.any(keep):
            continue
        rot, trans = kabsch(s[keep], d[keep])
        pred = np.matmul(src[None], np.swapaxes(rot, 1, 2)) + trans[:, None, :]
        r2 = np.sum((pred - dst[None]) ** 2, axis=-1)
        cost = np.minimum(r2, threshold_m**2).sum(-1)
        j = int(np.argmin(cost))
        if cost[j] < best_cost:
            best_cost, best_rt, best_r2 = cost[j], (rot[j], trans[j]), r2[j]
            ratio = float(np.mean(best_r2 <= threshold_m**2))
            miss = 1.0 - ratio**3
            if miss <= 0:
                needed = 0
            elif miss >= 1.0:  # no inlier at all (or ratio**3 below float resolution): draw them all
                needed = iterations
            else:
                needed = int(np.ceil(np.log(1 - confidence) / np.log(max(miss, 1e-12))))
        if m == 3:
            break
    if best_rt is None or best_r2 is None:
        return None
    r2 = best_r2
    inl = r2 <= threshold_m**2
    thr = threshold_m
    r_best, t_best = best_rt
    for _ in range(3):
        if inl.sum() < 3:
            break
        r_best, t_best = kabsch(src[inl], dst[inl])
        res = np.linalg.norm(src @ r_best.T + t_best - dst, axis=-1)
        sigma = np.median(res[inl]) / CHI3_MEDIAN
        thr = max(min_threshold_m, inlier_sigmas * sigma)
        inl = res <= thr
    res = np.linalg.norm(src @ r_best.T + t_best - dst, axis=-1)
    return RigidRansacResult(r_best, t_best, res <= thr, res, float(thr))
