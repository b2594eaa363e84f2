"""What the twin-geometry null test (``_surface_null``) hands a depth effect: the geometry of each
usable depth pixel (:class:`PatchGeometry`), and the columns by which the built-in depth effects
move its point-to-plane residual (``Effect.null_columns``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PatchGeometry:
    """Per usable depth pixel (``[n]`` or ``[n, 3]``), what an effect needs to say how it moves the
    point-to-plane residual ``e = n . (q - p)``.

    Attributes:
        p, q: predicted and measured world points, metres.
        normal: unit normal of the predicted surface.
        z: predicted z-depth, metres.
        ray_length: distance from the camera centre to ``p``, metres.
        cos: cosine between the normal and the viewing ray.
        seconds: time since the first frame.
    """

    p: np.ndarray
    q: np.ndarray
    normal: np.ndarray
    z: np.ndarray
    ray_length: np.ndarray
    cos: np.ndarray
    seconds: np.ndarray


def drift_columns(g: PatchGeometry) -> np.ndarray:
    """``[n, 6]`` d(e)/d(rates) of a pose drift (``PoseDrift``'s rotation and translation rates)."""
    s = g.seconds[:, None]
    return np.concatenate([s * np.cross(g.q, g.normal), s * g.normal], 1)


def depth_affine_columns(g: PatchGeometry) -> np.ndarray:
    """``[n, 2]`` d(e)/d(scale - 1, offset) of an affine depth error: a z change dz moves the point
    along its ray by dz |p - c| / z, i.e. ``e`` by that times cos."""
    along = g.ray_length / g.z * g.cos
    return np.stack([g.z * along, along], 1)
