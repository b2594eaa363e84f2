"""Splat arrays, part poses and the reference part motion against ground truth and each other."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from artitwin_core.gaussians import LABEL_PART, GaussianParams
from artitwin_core.joints import Joint
from artitwin_core.viewer import (
    heat_colors,
    matrix_to_quat_wxyz,
    part_poses,
    pose_splats,
    quat_wxyz_to_matrix,
    slider_range,
    splat_arrays,
)

unit = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


@settings(max_examples=60, deadline=None)
@given(axis=unit, angle=st.floats(-np.pi, np.pi))
def test_quaternion_round_trip(axis, angle):
    # Rodrigues gives the matrix; the quaternion of it must give it back (near 180 degrees included).
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    q = matrix_to_quat_wxyz(rot)
    assert abs(np.linalg.norm(q) - 1) < 1e-12
    assert q[0] >= 0
    np.testing.assert_allclose(quat_wxyz_to_matrix(q[None])[0], rot, atol=1e-12)  # float64 round-off


def test_part_poses_match_the_true_part_motion(door_scene):
    # The synthetic door is an ideal joint: its true per-frame part motion is the joint at q[t].
    truth = door_scene.truth
    q = np.stack([j.q for j in truth.joints])  # [K, T]
    for t in range(q.shape[1]):
        np.testing.assert_allclose(part_poses(truth.joints, q[:, t]), truth.part_world_from_closed[:, t], atol=1e-9)


def _random_params(rng, n: int, num_parts: int) -> GaussianParams:
    return GaussianParams(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=rng.uniform(-5, -2, (n, 3)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(size=(n, 4, 3)).astype(np.float32),
        labels=rng.integers(0, LABEL_PART + num_parts, n).astype(np.int32),
    )


def test_splat_arrays_covariances_and_colours():
    rng = np.random.default_rng(0)
    p = _random_params(rng, 200, 1)
    centers, covs, rgbs, opac = splat_arrays(p)
    # Eigenvalues of R S^2 R^T are the squared scales (float32 storage: 1e-5 relative).
    eig = np.sort(np.linalg.eigvalsh(covs.astype(np.float64)), 1)
    np.testing.assert_allclose(eig, np.sort(np.exp(2.0 * p.log_scales.astype(np.float64)), 1), rtol=1e-4)
    np.testing.assert_allclose(rgbs, np.clip(0.5 + 0.28209479177387814 * p.sh[:, 0], 0, 1), atol=1e-6)
    np.testing.assert_allclose(opac[:, 0], 1 / (1 + np.exp(-p.opacity_logits)), atol=1e-6)
    np.testing.assert_array_equal(centers, p.means)


@pytest.mark.parametrize("joint_type", ["revolute", "prismatic", "screw"])
def test_pose_splats_equals_moving_the_gaussians_themselves(joint_type):
    # Reference check of the part motion: rotating each part Gaussian's own quaternion and centre
    # and recomputing its covariance must give what pose_splats does with R C R^T.
    rng = np.random.default_rng(1)
    p = _random_params(rng, 300, 2)
    axis = np.array([0.3, 1.0, -0.2]) / np.linalg.norm([0.3, 1.0, -0.2])
    joints = [Joint(joint_type, axis, np.array([0.4, 0.2, -0.1]), np.zeros(1), np.array([0, 1.0]), np.zeros(1),
                    np.ones(1), pitch=0.05),
              Joint("revolute", np.array([0, 0, 1.0]), np.zeros(3), np.zeros(1), np.array([0, 1.0]), np.zeros(1), np.ones(1))]
    poses = part_poses(joints, [0.7, -0.4])
    centers, covs, _, _ = splat_arrays(p)
    moved_c, moved_cov = pose_splats(centers, covs, p.labels, poses)

    means, quats = p.means.astype(np.float64).copy(), p.quats_wxyz.astype(np.float64).copy()
    for k, pose in enumerate(poses):
        sel = p.labels == LABEL_PART + k
        means[sel] = means[sel] @ pose[:3, :3].T + pose[:3, 3]
        quats[sel] = _quat_mul(matrix_to_quat_wxyz(pose[:3, :3])[None], quats[sel])
    moved = GaussianParams(means.astype(np.float32), quats.astype(np.float32), p.log_scales, p.opacity_logits, p.sh,
                           p.labels)
    want_c, want_cov, _, _ = splat_arrays(moved)
    np.testing.assert_allclose(moved_c, want_c, atol=2e-6)  # float32 metres near 1 m
    np.testing.assert_allclose(moved_cov, want_cov, atol=1e-7)  # variances ~1e-4..1e-2 m^2, float32
    static = p.labels < LABEL_PART
    np.testing.assert_array_equal(moved_c[static], centers[static])


def test_slider_range_includes_closed_state_and_widens_degenerate_ones():
    j = Joint("revolute", np.array([0, 1.0, 0]), np.zeros(3), np.zeros(1), np.array([0.2, 1.1]), np.zeros(1), np.ones(1))
    assert slider_range(j) == (0.0, 1.1)
    flat = Joint("prismatic", np.array([0, 0, 1.0]), np.zeros(3), np.zeros(1), np.array([np.nan, np.nan]),
                 np.zeros(1), np.ones(1))
    assert slider_range(flat) == (0.0, 0.3)


def test_heat_colors_order_and_missing_values():
    v = np.array([0.0, 1.0, 2.0, 3.0, 4.0, np.nan])
    c = heat_colors(v, lo=0.0, hi=4.0)
    lum = c[:5] @ np.array([0.2126, 0.7152, 0.0722])
    assert np.all(np.diff(lum) > 0)  # brighter = larger residual
    np.testing.assert_allclose(c[5], [0.6, 0.6, 0.6], atol=1e-6)


def test_depth_residual_points_lie_on_the_measured_surface():
    from artitwin_core._errors import InputError
    from artitwin_core.viewer import depth_residual_points

    # A wall 2 m in front of a camera turned 30 degrees about y and moved: every point must be on it.
    a = np.deg2rad(30)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    pose[:3, 3] = [0.5, 1.0, -0.2]
    depth = np.full((1, 48, 64), 2.0, np.float32)
    pred = depth + 0.05
    pred[0, :, :32] = np.nan  # no prediction there: left out
    pts, vals = depth_residual_points(depth, pred, np.array([[50.0, 50.0, 32.0, 24.0]]), pose[None], stride=2)
    assert pts.shape == (24 * 16, 3)
    in_cam = (pts.astype(np.float64) - pose[:3, 3]) @ pose[:3, :3]
    np.testing.assert_allclose(in_cam[:, 2], 2.0, atol=1e-6)  # float32 points near 2 m
    # Only the right half (u >= 32; column 32 is the principal point, x = 0) had a prediction.
    assert np.all(in_cam[:, 0] > -1e-6) and np.isclose(in_cam[:, 0].min(), 0.0, atol=1e-6)
    np.testing.assert_allclose(vals, 0.05, atol=1e-6)
    with pytest.raises(InputError, match="predicted depth"):
        depth_residual_points(depth, pred[:, :10], np.zeros((1, 4)), pose[None])


def test_residual_accumulates_onto_the_nearest_gaussians_and_per_label():
    from artitwin_core.viewer import residual_by_label, residual_on_gaussians

    means = np.array([[0.0, 0, 0], [1.0, 0, 0], [5.0, 0, 0]])
    rng = np.random.default_rng(0)
    pts = np.concatenate([0.01 * rng.standard_normal((50, 3)), [1, 0, 0] + 0.01 * rng.standard_normal((30, 3)),
                          [[3.0, 0, 0]]])  # the last point is far from every Gaussian
    vals = np.concatenate([np.full(50, 0.002), np.full(30, 0.05), [9.0]])
    per = residual_on_gaussians(means, pts, vals, max_distance_m=0.1)
    np.testing.assert_allclose(per[:2], [0.002, 0.05], rtol=1e-6)
    assert np.isnan(per[2])  # never observed
    by = residual_by_label(per, np.array([0, 2, 2]), {0: "background", 1: "interior", 2: "part_0"})
    assert by["background"] == pytest.approx(0.002) and by["part_0"] == pytest.approx(0.05)
    assert np.isnan(by["interior"])
