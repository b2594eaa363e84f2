"""Numba kernels of the CPU rasterizer: tile binning, forward compositing, and its backward.

Data layout (built by ``_raster_cpu``): the M visible Gaussians are renumbered in front-to-back
depth order, so binning them in index order leaves every tile's list depth-sorted (a counting
sort, no per-tile sort) and consecutive list entries touch neighbouring memory.

- ``params [M, 10]``: ``mean_x, mean_y, conic_a, conic_b, conic_c, r, g, b, opacity, depth``.
- ``boxes [M, 4]`` int32: half-open pixel ranges ``x0, x1, y0, y1`` whose centres lie inside the
  opacity-aware footprint; pixels outside have alpha < 1/255, so loops only visit the box.
- ``offsets [n_tiles + 1]``, ``ids [n_isect]``: tile ``t`` composites ``ids[offsets[t]:offsets[t+1]]``.
- ``consts``: ``[alpha_max, alpha_min, t_min]`` in the working dtype (keeps float32 math in
  float32; numba would otherwise promote to float64 through Python float literals).

The backward pass follows gsplat: the forward stores each pixel's final transmittance and the
index of its last contributor; the backward walks each tile's list back to front, recovering
``T_i = T_{i+1} / (1 - alpha_i)`` and (as one scalar per pixel) the pixel gradient dotted with
everything behind, and writes one gradient row per (tile, Gaussian) intersection, which a
serial pass then sums per Gaussian (no atomics).
Tiles are independent, so both passes run ``prange`` over tiles.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, types
from numba.extending import overload

TILE = 16
# No nnan/ninf: the kernels compare against thresholds and must keep IEEE semantics there.
_FM = {"nsz", "arcp", "contract", "afn", "reassoc"}


def _like(x, ref):
    """``x`` converted to the type of the scalar ``ref`` (usable inside the kernels)."""
    return type(ref)(x)


@overload(_like, inline="always")
def _like_overload(x, ref):
    conv = np.float32 if ref == types.float32 else np.float64

    def impl(x, ref):
        return conv(x)

    return impl


@njit(cache=True)
def bin_gaussians(boxes: np.ndarray, tiles_x: int, tiles_y: int) -> tuple[np.ndarray, np.ndarray]:
    """Tile lists of the Gaussians (already in depth order) overlapping each 16x16 tile.

    Returns ``offsets [n_tiles + 1]`` int64 and ``ids [n_isect]`` int32.
    """
    n_tiles = tiles_x * tiles_y
    counts = np.zeros(n_tiles + 1, np.int64)
    m = boxes.shape[0]
    for g in range(m):
        tx0 = boxes[g, 0] // TILE
        tx1 = (boxes[g, 1] - 1) // TILE + 1
        ty0 = boxes[g, 2] // TILE
        ty1 = (boxes[g, 3] - 1) // TILE + 1
        for ty in range(ty0, ty1):
            for tx in range(tx0, tx1):
                counts[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    offsets = counts
    fill = offsets[:-1].copy()
    ids = np.empty(offsets[n_tiles], np.int32)
    for g in range(m):
        tx0 = boxes[g, 0] // TILE
        tx1 = (boxes[g, 1] - 1) // TILE + 1
        ty0 = boxes[g, 2] // TILE
        ty1 = (boxes[g, 3] - 1) // TILE + 1
        for ty in range(ty0, ty1):
            for tx in range(tx0, tx1):
                t = ty * tiles_x + tx
                ids[fill[t]] = g
                fill[t] += 1
    return offsets, ids


@njit(inline="always", fastmath=_FM)
def _row_span(mx, dy, ca, cb, cc, r2, xs, xe, half):
    """Half-open pixel range ``[xa, xb)`` within ``[xs, xe)`` of one row's ellipse chord.

    Pixels with ``a dx^2 + 2 b dx dy + c dy^2 > r2`` (``dx = mean_x - centre_x``) have alpha below
    1/255, so only the chord of the cut-off ellipse is visited: for a round footprint that is
    pi/4 of its bounding box, for a thin diagonal one far less.
    """
    disc = cb * cb * dy * dy - ca * (cc * dy * dy - r2)
    if disc < 0:
        return xs, xs
    sq = math.sqrt(disc)
    # Pixel centres u = px + 0.5 with mean_x - dx_hi <= u <= mean_x - dx_lo.
    u_lo = mx - (sq - cb * dy) / ca - half
    u_hi = mx + (sq + cb * dy) / ca - half
    xa = xs
    if u_lo > xs:
        xa = min(int(math.ceil(u_lo)), xe)
    xb = xe
    if u_hi < xe - 1:
        xb = max(int(math.floor(u_hi)) + 1, xa)
    return xa, xb


@njit(inline="always", fastmath=_FM)
def _row_gauss_start(mx, dy, ca, cb, cc, xa, half):
    """``exp(power)`` at pixel ``xa`` of a row, and the factor to the next pixel (float64).

    Along a row ``power(dx) = -(a dx^2 + c dy^2)/2 - b dx dy`` is quadratic, so stepping one pixel
    right (``dx -> dx - 1``) multiplies ``exp(power)`` by ``exp(a dx - a/2 + b dy)``, a factor
    that itself shrinks by ``exp(-a)`` per pixel: two exps per row and one per Gaussian instead
    of one per pixel (libm ``exp`` was ~1/4 of the kernels' time). Done in float64, so after at
    most 16 steps the relative error (~1e-15) is far below float32 rounding.
    """
    dx = float(mx) - (float(xa) + float(half))
    a = float(ca)
    b = float(cb)
    c = float(cc)
    ddy = float(dy)
    power = -0.5 * (a * dx * dx + c * ddy * ddy) - b * dx * ddy
    return math.exp(power), math.exp(a * dx - 0.5 * a + b * ddy)


@njit(parallel=True, cache=True, fastmath=_FM)
def rasterize_forward(
    params: np.ndarray,
    boxes: np.ndarray,
    cutoff2: np.ndarray,
    offsets: np.ndarray,
    ids: np.ndarray,
    width: int,
    height: int,
    background: np.ndarray,
    consts: np.ndarray,
    out_rgbd: np.ndarray,
    out_tfinal: np.ndarray,
    out_last: np.ndarray,
) -> None:
    """Front-to-back compositing per tile.

    Writes ``out_rgbd [H, W, 4]`` (rgb including ``T_final * background``, then the
    accumulated depth ``sum w_i z_i``), ``out_tfinal [H, W]`` and ``out_last [H, W]`` (index into
    ``ids`` of the pixel's last contributor, -1 if none).
    """
    alpha_max = consts[0]
    alpha_min = consts[1]
    t_min = consts[2]
    one = consts[3]
    half = consts[4]
    tiles_x = (width + TILE - 1) // TILE
    n_tiles = offsets.shape[0] - 1
    for t in prange(n_tiles):
        ty = t // tiles_x
        tx = t - ty * tiles_x
        ox = tx * TILE
        oy = ty * TILE
        tw = min(TILE, width - ox)
        th = min(TILE, height - oy)
        trans = np.ones(TILE * TILE, params.dtype)
        acc = np.zeros((TILE * TILE, 4), params.dtype)
        last = np.full(TILE * TILE, -1, np.int32)
        done = np.zeros(TILE * TILE, np.bool_)
        n_pix = tw * th
        n_done = 0
        for k in range(offsets[t], offsets[t + 1]):
            g = ids[k]
            xs = max(boxes[g, 0], ox)
            xe = min(boxes[g, 1], ox + tw)
            ys = max(boxes[g, 2], oy)
            ye = min(boxes[g, 3], oy + th)
            mx = params[g, 0]
            my = params[g, 1]
            ca = params[g, 2]
            cb = params[g, 3]
            cc = params[g, 4]
            cr = params[g, 5]
            cg = params[g, 6]
            cbl = params[g, 7]
            op = params[g, 8]
            z = params[g, 9]
            r2 = cutoff2[g]
            exp_a = math.exp(-float(ca))
            for py in range(ys, ye):
                dy = my - (py + half)
                xa, xb = _row_span(mx, dy, ca, cb, cc, r2, xs, xe, half)
                if xa >= xb:
                    continue
                gauss, step = _row_gauss_start(mx, dy, ca, cb, cc, xa, half)
                row = (py - oy) * TILE - ox
                for px in range(xa, xb):
                    p = row + px
                    if not done[p]:
                        # Back to the working dtype: float32 alpha keeps the compositing math
                        # (and the backward's division) in single precision, ~8 % faster.
                        alpha = min(alpha_max, op * _like(gauss, one))
                        if alpha >= alpha_min:
                            t_next = trans[p] * (one - alpha)
                            if t_next <= t_min:
                                done[p] = True
                                n_done += 1
                            else:
                                w = alpha * trans[p]
                                acc[p, 0] += w * cr
                                acc[p, 1] += w * cg
                                acc[p, 2] += w * cbl
                                acc[p, 3] += w * z
                                trans[p] = t_next
                                last[p] = k
                    gauss *= step
                    step *= exp_a
            if n_done == n_pix:
                break
        for py in range(th):
            for px in range(tw):
                p = py * TILE + px
                tf = trans[p]
                out_rgbd[oy + py, ox + px, 0] = acc[p, 0] + tf * background[0]
                out_rgbd[oy + py, ox + px, 1] = acc[p, 1] + tf * background[1]
                out_rgbd[oy + py, ox + px, 2] = acc[p, 2] + tf * background[2]
                out_rgbd[oy + py, ox + px, 3] = acc[p, 3]
                out_tfinal[oy + py, ox + px] = tf
                out_last[oy + py, ox + px] = last[p]


@njit(parallel=True, cache=True, fastmath=_FM)
def rasterize_backward(
    params: np.ndarray,
    boxes: np.ndarray,
    cutoff2: np.ndarray,
    offsets: np.ndarray,
    ids: np.ndarray,
    width: int,
    height: int,
    background: np.ndarray,
    consts: np.ndarray,
    tfinal: np.ndarray,
    last_idx: np.ndarray,
    grad_rgbd: np.ndarray,
    grad_alpha: np.ndarray,
    out_isect_grads: np.ndarray,
) -> None:
    """Gradients of a loss w.r.t. every (tile, Gaussian) intersection.

    ``grad_rgbd [H, W, 4]`` and ``grad_alpha [H, W]`` are dL/d(rgb, depth) and dL/d(alpha).
    Writes ``out_isect_grads [n_isect, 10]``: dL/d``params`` columns for entry ``ids[k]``.
    """
    alpha_max = consts[0]
    alpha_min = consts[1]
    one = consts[3]
    half = consts[4]
    zero = one - one
    tiles_x = (width + TILE - 1) // TILE
    n_tiles = offsets.shape[0] - 1
    for t in prange(n_tiles):
        ty = t // tiles_x
        tx = t - ty * tiles_x
        ox = tx * TILE
        oy = ty * TILE
        tw = min(TILE, width - ox)
        th = min(TILE, height - oy)
        start = offsets[t]
        out_isect_grads[start : offsets[t + 1], :] = zero
        trans = np.ones(TILE * TILE, params.dtype)
        last = np.full(TILE * TILE, -1, np.int64)
        g_r = np.zeros(TILE * TILE, params.dtype)
        g_g = np.zeros(TILE * TILE, params.dtype)
        g_b = np.zeros(TILE * TILE, params.dtype)
        g_d = np.zeros(TILE * TILE, params.dtype)
        # behind_g: sum over the Gaussians behind of w_j (c_j . g + z_j g_d), i.e. the pixel
        # gradient dotted with what lies behind; const_g: T_final (background . g - g_alpha).
        # With them dL/dalpha_i = T_i (c_i . g + z_i g_d) - (behind_g + const_g) / (1 - alpha_i).
        behind_g = np.zeros(TILE * TILE, params.dtype)
        const_g = np.zeros(TILE * TILE, params.dtype)
        max_last = -1
        for py in range(th):
            for px in range(tw):
                p = py * TILE + px
                tfp = tfinal[oy + py, ox + px]
                trans[p] = tfp
                last[p] = last_idx[oy + py, ox + px]
                max_last = max(max_last, last[p])
                g_r[p] = grad_rgbd[oy + py, ox + px, 0]
                g_g[p] = grad_rgbd[oy + py, ox + px, 1]
                g_b[p] = grad_rgbd[oy + py, ox + px, 2]
                g_d[p] = grad_rgbd[oy + py, ox + px, 3]
                bg_dot = background[0] * g_r[p] + background[1] * g_g[p] + background[2] * g_b[p]
                const_g[p] = tfp * (bg_dot - grad_alpha[oy + py, ox + px])
        for k in range(max_last, start - 1, -1):
            g = ids[k]
            xs = max(boxes[g, 0], ox)
            xe = min(boxes[g, 1], ox + tw)
            ys = max(boxes[g, 2], oy)
            ye = min(boxes[g, 3], oy + th)
            mx = params[g, 0]
            my = params[g, 1]
            ca = params[g, 2]
            cb = params[g, 3]
            cc = params[g, 4]
            cr = params[g, 5]
            cg = params[g, 6]
            cbl = params[g, 7]
            op = params[g, 8]
            z = params[g, 9]
            v_mx = zero
            v_my = zero
            v_a = zero
            v_b = zero
            v_c = zero
            v_r = zero
            v_g = zero
            v_bl = zero
            v_o = zero
            v_z = zero
            r2 = cutoff2[g]
            exp_a = math.exp(-float(ca))
            for py in range(ys, ye):
                dy = my - (py + half)
                xa, xb = _row_span(mx, dy, ca, cb, cc, r2, xs, xe, half)
                if xa >= xb:
                    continue
                gauss, step = _row_gauss_start(mx, dy, ca, cb, cc, xa, half)
                row = (py - oy) * TILE - ox
                # Row moments of dL/dpower: sum v_pow, sum v_pow dx, sum v_pow dx^2 (dy is fixed
                # along the row, so the conic and mean gradients follow from these three).
                m0 = zero
                m1 = zero
                m2 = zero
                dx = mx - (xa + half)
                for px in range(xa, xb):
                    p = row + px
                    if k <= last[p]:
                        gauss_w = _like(gauss, one)
                        alpha_raw = op * gauss_w
                        alpha = min(alpha_max, alpha_raw)
                        if alpha >= alpha_min:
                            ra = one / (one - alpha)
                            t_before = trans[p] * ra
                            trans[p] = t_before
                            w = alpha * t_before
                            gr = g_r[p]
                            gg = g_g[p]
                            gb = g_b[p]
                            gd = g_d[p]
                            v_r += w * gr
                            v_g += w * gg
                            v_bl += w * gb
                            v_z += w * gd
                            cgd = cr * gr + cg * gg + cbl * gb + z * gd
                            v_alpha = t_before * cgd - (behind_g[p] + const_g[p]) * ra
                            behind_g[p] += w * cgd
                            if alpha_raw < alpha_max:
                                v_o += gauss_w * v_alpha
                                v_pow = alpha * v_alpha
                                m0 += v_pow
                                m1 += v_pow * dx
                                m2 += v_pow * dx * dx
                    gauss *= step
                    step *= exp_a
                    dx -= one
                # power = -(a dx^2 + c dy^2)/2 - b dx dy, d power/d mean_x = -(a dx + b dy), ...
                v_a -= half * m2
                v_b -= dy * m1
                v_c -= half * dy * dy * m0
                v_mx -= ca * m1 + cb * dy * m0
                v_my -= cb * m1 + cc * dy * m0
            out_isect_grads[k, 0] = v_mx
            out_isect_grads[k, 1] = v_my
            out_isect_grads[k, 2] = v_a
            out_isect_grads[k, 3] = v_b
            out_isect_grads[k, 4] = v_c
            out_isect_grads[k, 5] = v_r
            out_isect_grads[k, 6] = v_g
            out_isect_grads[k, 7] = v_bl
            out_isect_grads[k, 8] = v_o
            out_isect_grads[k, 9] = v_z


@njit(cache=True)
def sum_isect_grads(ids: np.ndarray, isect_grads: np.ndarray, m: int) -> np.ndarray:
    """``[m, 10]`` per-Gaussian sums of the per-intersection gradient rows (float64 sums)."""
    out = np.zeros((m, isect_grads.shape[1]), np.float64)
    for k in range(ids.shape[0]):
        g = ids[k]
        for j in range(isect_grads.shape[1]):
            out[g, j] += isect_grads[k, j]
    return out
