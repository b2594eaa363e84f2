"""The yaw sweep alone finds yaw and translation of gravity-aligned clouds (no ICP)."""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core.geometry import axis_angle_to_matrix
from artitwin_core.registration._global import gravity_basis, yaw_candidates
from tests.registration.conftest import room


def test_gravity_basis_is_right_handed():
    for g in ([0, -1, 0], [0, 0, -1], [1, 2, 3]):
        b = gravity_basis(g)
        assert np.allclose(b @ b.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(b), 1.0)
        assert np.allclose(b[1], -np.asarray(g) / np.linalg.norm(g))


@pytest.mark.parametrize("yaw_deg", [170.0, -60.0, 5.0])
def test_sweep_finds_yaw_and_translation(yaw_deg):
    rng = np.random.default_rng(0)
    pts, nrm = room(rng)
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
