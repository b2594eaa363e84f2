"""Whether the texture on the surfaces a registration matches is the same texture.

Geometry alone cannot tell two corners of a box-shaped room apart: a recording of a corner the
static sweep never saw lays its two walls and floor onto another corner's, with every point on a
static surface and none in space seen empty. The texture on those surfaces (posters, floor
boards, furniture grain) is what differs. Comparing raw colours does not show it, because which
surface a point lands on already predicts most of its colour (a light wall above a dark floor
correlates wherever the corner goes); so each matched point's colour is taken relative to the
mean of the matched points on its surface (points whose static normals point the same way and
whose planes lie at the same offset), in both recordings, and the two are correlated. Pearson
correlation per frame ignores each frame's exposure and offset.
"""

from __future__ import annotations

import numpy as np

from artitwin_core.registration._global import gravity_basis


def luminance(colours: np.ndarray) -> np.ndarray:
    """``[N]`` mean of the three channels of ``colours [N, 3]`` (any linear or sRGB scale)."""
    return np.asarray(colours, dtype=np.float64).mean(axis=1)


def surface_groups(points: np.ndarray, normals: np.ndarray, up: np.ndarray, *, azimuth_bins: int = 4,
                   offset_m: float = 0.1, level_cos: float = 0.9) -> np.ndarray:
    """``[N]`` int label of the planar surface each of ``points [N, 3]`` roughly lies on.

    Points whose ``normals [N, 3]`` are within ``acos(level_cos)`` of vertical form one class
    (floors, table tops, ceilings); the others are binned by the normal's azimuth about ``up``
    into ``azimuth_bins`` sectors of 180 degrees (a normal's sign is arbitrary, so opposite
    directions share a sector). Within a class, the plane's distance from the origin
    ``|n . p|`` is binned by ``offset_m``, which separates a cabinet front from the wall
    behind it and a floor from a table top.
    """
    e1, u, e2 = gravity_basis(-np.asarray(up, dtype=np.float64))
    n = np.asarray(normals, dtype=np.float64)
    azimuth = np.mod(np.arctan2(n @ e2, n @ e1), np.pi)
    sector = np.minimum((azimuth / np.pi * azimuth_bins).astype(np.int64), azimuth_bins - 1)
    direction = np.where(np.abs(n @ u) > level_cos, azimuth_bins, sector)
    offset = np.floor(np.abs(np.einsum("ij,ij->i", n, points)) / offset_m).astype(np.int64)
    return direction * (1 << 20) + offset


def within_surface_correlation(dynamic: np.ndarray, static: np.ndarray, groups: np.ndarray,
                               min_points: int = 30) -> tuple[float, float] | None:
    """Correlation of the within-surface variations of two intensities at matched points.

    Args:
        dynamic: ``[N]`` the dynamic recording's intensity at its matched points (one frame).
        static: ``[N]`` the static recording's intensity at the points they matched.
        groups: ``[N]`` the surface each match lies on (``surface_groups`` of the static points).
        min_points: fewer matches than this tell nothing.

    Returns:
        ``(r, contrast)``: Pearson's r of the two after each surface's mean is removed from
        both, and the RMS of the static intensity about its surfaces' means (how much texture
        there is to agree on); None when there are too few matches or either side is flat.
    """
    if len(dynamic) < min_points:
        return None
    _, label = np.unique(groups, return_inverse=True)
    count = np.bincount(label).astype(np.float64)
    a = dynamic - (np.bincount(label, dynamic) / count)[label]
    b = static - (np.bincount(label, static) / count)[label]
    sa, sb = float(np.sqrt(np.mean(a**2))), float(np.sqrt(np.mean(b**2)))
    if sa < 1e-6 or sb < 1e-6:
        return None
    return float(np.mean(a * b) / (sa * sb)), sb
