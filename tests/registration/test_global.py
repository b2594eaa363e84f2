"""The yaw sweep alone finds yaw and translation of gravity-aligned clouds (no ICP)."""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core.geometry import axis_angle_to_matrix
from artitwin_core.registration._global import gravity_basis, yaw_candidates


def _box_surface(rng, lo, size, spacing=0.04):
    """Points and outward normals on the six faces of an axis-aligned box."""
    lo, size = np.asarray(lo, float), np.asarray(size, float)
    pts, nrm = [], []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        n = max(int(size[u] * size[v] / spacing**2), 4)
        for side in (0.0, 1.0):
            p = np.empty((n, 3))
            p[:, u] = lo[u] + rng.random(n) * size[u]
            p[:, v] = lo[v] + rng.random(n) * size[v]
            p[:, axis] = lo[axis] + side * size[axis]
            normal = np.zeros(3)
            normal[axis] = 1.0 if side else -1.0
            pts.append(p)
            nrm.append(np.tile(normal, (n, 1)))
    return np.concatenate(pts), np.concatenate(nrm)


def _room(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points and normals of an L-shaped room corner with two boxes: no symmetry to confuse yaw."""
    boxes = [
        ((0, -0.02, 0), (4.0, 0.02, 3.0)),  # floor
        ((0, 0, -0.02), (4.0, 2.5, 0.02)),  # back wall
        ((-0.02, 0, 0), (0.02, 2.5, 3.0)),  # left wall
        ((1.0, 0.0, 0.02), (0.8, 0.9, 0.45)),
        ((2.6, 0.0, 1.2), (0.4, 0.4, 0.4)),
    ]
    parts = [_box_surface(rng, lo, size) for lo, size in boxes]
    return np.concatenate([p for p, _ in parts]), np.concatenate([n for _, n in parts])


def test_gravity_basis_is_right_handed():
    for g in ([0, -1, 0], [0, 0, -1], [1, 2, 3]):
        b = gravity_basis(g)
        assert np.allclose(b @ b.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(b), 1.0)
        assert np.allclose(b[1], -np.asarray(g) / np.linalg.norm(g))


@pytest.mark.parametrize("yaw_deg", [170.0, -60.0, 5.0])
def test_sweep_finds_yaw_and_translation(yaw_deg):
    rng = np.random.default_rng(0)
    pts, nrm = _room(rng)
    rot = axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), np.radians(yaw_deg))
    trans = np.array([2.0, 0.3, -3.0])
    # Session points x_s = R^T (x_c - t): the sweep must find canonical_from_session = (R, t).
    d_pts = (pts - trans) @ rot
    d_nrm = nrm @ rot
    cands = yaw_candidates(pts, nrm, d_pts, d_nrm, (0.0, -1.0, 0.0), yaw_step_deg=2.0, cell_m=0.05)
    best = cands[0].canonical_from_session
    d = rot.T @ best[:3, :3]
    err_deg = np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1)))
    assert err_deg < 2.0  # half the yaw step plus cell quantisation; measured <= 1 deg
    assert np.linalg.norm(best[:3, 3] - trans) < 0.12  # ~2 cells; ICP refines from here
