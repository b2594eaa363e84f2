"""The pinhole camera every stage shares: pixel convention, back-projection, projection.

Convention (the one the data follow): OpenCV camera axes (x right, y down, z forwards, metres),
intrinsics ``(fx, fy, cx, cy)`` in pixels, and **the centre of pixel (row v, column u) at the
continuous image coordinate (u, v)**, integers, so that a camera point ``(x, y, z)`` lies at
``u = fx x / z + cx, v = fy y / z + cy`` and depth pixel ``depth[v, u]`` lifts to
``((u - cx) / fx z, (v - cy) / fy z, z)``. ARKit's intrinsics (Record3D, Stray), OpenCV and the
synthetic renderer's rays (``artitwin_core.synth``: one ray through ``(u, v)`` per pixel) all put
pixel centres there; resampling keeps it (``capture.scale_intrinsics``: ``c' = (c + 0.5) s - 0.5``).
The nearest pixel of a continuous ``(u, v)`` is ``rint``, not ``floor``.

The Gaussian rasterizer (``artitwin_core.gaussians``, as gsplat and COLMAP) puts the centre of
pixel (i, j) at ``(j + 0.5, i + 0.5)`` instead, so given the data's K it draws every point on pixel
``u - 0.5``: half a pixel up and left of where the recording shows it. :func:`raster_intrinsics`
converts the data's intrinsics into the ones that make a render line up with the recording. The
trainers do not convert yet: reconstruction and articulation hand the rasterizer the data's K and
lift their seeds at ``u + 0.5`` (pick pixels with ``floor``) to match it, so their models sit half
a pixel off the recording. Switching them changes results and is measured separately.
"""

from __future__ import annotations

import numpy as np


def pixel_grid(width: int, height: int, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates of an image: ``u, v`` each ``[H', W']`` float64 pixels.

    ``u[i, j]`` is the column and ``v[i, j]`` the row of pixel ``(i * stride, j * stride)``,
    which is also its centre under the convention above, so ``depth[::s, ::s]`` pairs with
    ``pixel_grid(w, h, s)``.
    """
    v, u = np.mgrid[0:height:stride, 0:width:stride]
    return u.astype(np.float64), v.astype(np.float64)


def _split(intrinsics, ndim: int) -> tuple[np.ndarray, ...]:
    """``fx, fy, cx, cy`` of ``intrinsics [..., 4]``, each shaped to broadcast against ``ndim``-d
    point arrays whose leading axes are the intrinsics' leading axes."""
    k = np.asarray(intrinsics, np.float64)
    lead = k.shape[:-1]
    if len(lead) > ndim:
        raise ValueError(f"intrinsics {k.shape} have more leading axes than the {ndim}-d points")
    return tuple(k[..., i].reshape(lead + (1,) * (ndim - len(lead))) for i in range(4))


def pixel_rays(intrinsics, u, v) -> np.ndarray:
    """Camera-frame rays ``[..., 3]`` with ``z = 1`` through image points ``u, v`` (``[...]``, pixels).

    ``intrinsics``: ``(fx, fy, cx, cy)`` pixels, ``[4]`` for one camera or ``[..., 4]`` with one
    camera per leading index of ``u, v`` (e.g. ``[T, 4]`` with ``u, v`` ``[T, H, W]`` or
    ``[1, H, W]``). A ray times a z-depth is the camera point.
    """
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    shape = np.broadcast_shapes(u.shape, v.shape)
    fx, fy, cx, cy = _split(intrinsics, len(shape))
    x, y = (u - cx) / fx, (v - cy) / fy
    shape = np.broadcast_shapes(x.shape, y.shape)
    return np.stack([np.broadcast_to(x, shape), np.broadcast_to(y, shape), np.ones(shape)], -1)


def backproject(depth, intrinsics, u=None, v=None) -> np.ndarray:
    """Camera points ``[..., 3]`` (float64 metres) of z-depths at image points.

    Args:
        depth: z-depth in metres (not ray length): ``[H, W]`` for a whole image, or ``[...]``
            values at the points ``u, v``.
        intrinsics: ``(fx, fy, cx, cy)`` pixels, of the image ``depth`` was measured in (or
            ``[..., 4]``, one camera per leading index, as :func:`pixel_rays`).
        u, v: ``[...]`` image points, pixels, pixel centres at integers; both or neither.
            Neither: every pixel of the ``[H, W]`` depth map, in row-major order (``[H, W, 3]`` out).

    Invalid depths (0, NaN) give invalid points; mask them before or after.
    """
    z = np.asarray(depth, np.float64)
    if (u is None) != (v is None):
        raise ValueError("backproject: give both u and v, or neither")
    if u is None:
        if z.ndim != 2:
            raise ValueError(f"backproject: a whole depth map must be [H, W], got {z.shape}")
        u, v = pixel_grid(z.shape[1], z.shape[0])
    return pixel_rays(intrinsics, u, v) * z[..., None]


def depth_normals(depth, intrinsics) -> np.ndarray:
    """``[H, W, 3]`` unit surface normals (camera frame) of a z-depth map ``[H, W]`` from
    central differences of its points (:func:`backproject`), NaN where a neighbour is invalid
    and on the image border. Their sign follows the pixel grid (``du x dv``): a surface facing
    the camera gets a positive z."""
    p = backproject(depth, intrinsics)
    du, dv = np.full_like(p, np.nan), np.full_like(p, np.nan)
    du[:, 1:-1] = p[:, 2:] - p[:, :-2]
    dv[1:-1] = p[2:] - p[:-2]
    n = np.cross(du, dv)
    with np.errstate(invalid="ignore", divide="ignore"):
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


def corner_radius_sq(intrinsics, u, v, width: int, height: int) -> np.ndarray:
    """Squared distance of image points ``u, v`` (``[...]``, pixels) from the principal point
    over the farthest image corner's (pixel centres ``0 .. width - 1``): the radial coordinate the
    vignetting models use, 1 at that corner. ``intrinsics``: ``(fx, fy, cx, cy)`` ``[4]``."""
    cx, cy = float(intrinsics[2]), float(intrinsics[3])
    r2max = max((x - cx) ** 2 + (y - cy) ** 2 for x, y in ((0, 0), (width - 1, 0), (0, height - 1), (width - 1, height - 1)))
    return ((np.asarray(u, np.float64) - cx) ** 2 + (np.asarray(v, np.float64) - cy) ** 2) / r2max


def project(points, intrinsics, min_z: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Image points of camera points ``[..., 3]`` (metres), through ``intrinsics`` ``[4]`` or one
    camera per leading index of the points (``[..., 4]``, as :func:`pixel_rays`).

    Returns:
        uv ``[..., 2]`` float64 pixels (pixel centres at integers; :func:`nearest_pixel` rounds)
        and z ``[...]`` float64 metres. Points with ``z <= min_z`` (behind or on the camera) get
        a finite but meaningless ``uv``; mask them with ``z``.
    """
    p = np.asarray(points, np.float64)
    fx, fy, cx, cy = _split(intrinsics, p.ndim - 1)
    z = p[..., 2]
    zs = np.where(z > min_z, z, 1.0)
    return np.stack([p[..., 0] / zs * fx + cx, p[..., 1] / zs * fy + cy], -1), z


def nearest_pixel(uv) -> tuple[np.ndarray, np.ndarray]:
    """``(column, row)`` int64 ``[...]`` of the pixel whose centre is nearest to ``uv [..., 2]``.

    Not bounds-checked: compare with the image size.
    """
    px = np.rint(np.asarray(uv, np.float64)).astype(np.int64)
    return px[..., 0], px[..., 1]


def raster_intrinsics(intrinsics) -> np.ndarray:
    """The data's intrinsics ``[..., 4]`` (pixel centres at integers) as the rasterizer takes them
    (pixel centres at +0.5): ``(fx, fy, cx + 0.5, cy + 0.5)``, float64."""
    k = np.array(intrinsics, dtype=np.float64)
    k[..., 2:4] += 0.5
    return k
