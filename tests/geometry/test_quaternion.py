"""Quaternion conversions (wxyz): round trips over random rotations, numpy and torch forms agree,
and the documented zero-quaternion behaviour."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from artitwin_core.gaussians._project import quat_to_rotmat_columns
from artitwin_core.geometry import axis_angle_to_matrix, matrix_to_quat_wxyz, quat_wxyz_to_matrix

quats = arrays(np.float64, (8, 4), elements=st.floats(-10, 10, allow_nan=False)).filter(
    lambda q: bool(np.all(np.linalg.norm(q, axis=1) > 1e-3))
)


@settings(max_examples=200, deadline=None)
@given(q=quats)
def test_matrix_is_a_rotation_and_round_trips(q):
    rot = quat_wxyz_to_matrix(q)
    np.testing.assert_allclose(
        rot @ np.swapaxes(rot, -1, -2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)
    back = matrix_to_quat_wxyz(rot)
    unit = q / np.linalg.norm(q, axis=1, keepdims=True)
    unit = np.where(unit[:, :1] < 0, -unit, unit)
    # The sign is fixed by w >= 0; at w == 0 both signs are the same rotation.
    same = np.minimum(np.abs(back - unit).max(1), np.abs(back + unit).max(1))
    assert same.max() < 1e-9
    assert np.all(back[:, 0] >= 0)
    np.testing.assert_allclose(quat_wxyz_to_matrix(back), rot, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(
    axis=arrays(np.float64, 3, elements=st.floats(-1, 1)).filter(lambda a: np.linalg.norm(a) > 1e-3),
    angle=st.floats(-np.pi, np.pi),
)
def test_half_turns_and_axis_angles_round_trip(axis, angle):
    rot = axis_angle_to_matrix(axis, angle)
    np.testing.assert_allclose(quat_wxyz_to_matrix(matrix_to_quat_wxyz(rot)), rot, atol=1e-12)
    for flip in (np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])):
        np.testing.assert_allclose(
            quat_wxyz_to_matrix(matrix_to_quat_wxyz(flip @ rot)), flip @ rot, atol=1e-12
        )


def test_numpy_torch_and_rasterizer_columns_agree():
    q = np.random.default_rng(1).normal(size=(50, 4))
    ref = quat_wxyz_to_matrix(q)
    tq = torch.tensor(q, dtype=torch.float64, requires_grad=True)
    rot_t = quat_wxyz_to_matrix(tq)
    assert rot_t.dtype == torch.float64 and rot_t.shape == (50, 3, 3)
    np.testing.assert_allclose(rot_t.detach().numpy(), ref, atol=1e-15)
    cols = torch.stack(quat_to_rotmat_columns(tq), -1).reshape(-1, 3, 3)
    np.testing.assert_allclose(cols.detach().numpy(), ref, atol=1e-15)
    rot_t.sum().backward()
    assert torch.isfinite(tq.grad).all()


def test_zero_quaternion_is_the_identity_in_every_form():
    np.testing.assert_array_equal(quat_wxyz_to_matrix(np.zeros(4)), np.eye(3))
    np.testing.assert_array_equal(
        quat_wxyz_to_matrix(torch.zeros(2, 4)).numpy(), np.broadcast_to(np.eye(3), (2, 3, 3))
    )
    cols = torch.stack(quat_to_rotmat_columns(torch.zeros(1, 4)), -1).reshape(3, 3)
    np.testing.assert_array_equal(cols.numpy(), np.eye(3))


def test_batch_shapes_are_kept():
    rot = quat_wxyz_to_matrix(np.ones((2, 3, 4)))
    assert rot.shape == (2, 3, 3, 3)
    assert matrix_to_quat_wxyz(rot).shape == (2, 3, 4)
    assert matrix_to_quat_wxyz(np.eye(3)).shape == (4,)
