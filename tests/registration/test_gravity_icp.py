"""The gravity-keeping ICP, the free-space evidence and the pose hypotheses, on small exact inputs."""

from __future__ import annotations

import numpy as np
import pytest

from artitwin_core.geometry import axis_angle_to_matrix, make_se3
from artitwin_core.registration._evidence import DepthViews, evidence, seen_through
from artitwin_core.registration._global import camera_anchor, pose_hypotheses
from artitwin_core.registration._gravity_icp import PlaneTarget, gravity_icp, tilt_of
from tests.registration.conftest import room

UP = np.array([0.0, 1.0, 0.0])


def _moved(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    return points @ transform[:3, :3].T + transform[:3, 3]


@pytest.mark.parametrize("yaw_deg", [3.0, -5.0])
def test_recovers_yaw_and_translation_without_tilting(yaw_deg):
    rng = np.random.default_rng(1)
    pts, nrm = room(rng, spacing=0.1)
    truth = make_se3(axis_angle_to_matrix(UP, np.radians(yaw_deg)), np.array([0.05, 0.02, -0.04]))
    source = _moved(pts, np.linalg.inv(truth))
    # Started 2 degrees tilted: the 4-DOF ICP cannot remove a tilt, but must not add one either.
    start = make_se3(axis_angle_to_matrix(np.array([1.0, 0.0, 0.0]), np.radians(2.0)), np.zeros(3))
    r = gravity_icp(source, PlaneTarget.of(pts, nrm), start, UP, max_distance_m=0.3, kernel_m=0.2, iterations=50)
    assert abs(np.degrees(tilt_of(r.transform, UP)) - 2.0) < 1e-9
    level = gravity_icp(source, PlaneTarget.of(pts, nrm), np.eye(4), UP, max_distance_m=0.3, kernel_m=0.2, iterations=50)
    assert tilt_of(level.transform, UP) < 1e-12
    assert np.allclose(level.transform, truth, atol=1e-6)  # exact data: converges to the truth


def test_tilt_is_estimated_and_clamped():
    rng = np.random.default_rng(2)
    pts, nrm = room(rng, spacing=0.1)
    target = PlaneTarget.of(pts, nrm)
    tilted = make_se3(axis_angle_to_matrix(np.array([1.0, 0.0, 0.5]), np.radians(0.4)), np.array([0.01, 0.0, 0.02]))
    source = _moved(pts, np.linalg.inv(tilted))
    free = gravity_icp(source, target, np.eye(4), UP, max_distance_m=0.3, kernel_m=0.2, iterations=50,
                       max_tilt_rad=np.radians(1.0))
    assert np.allclose(free.transform, tilted, atol=1e-6)
    bounded = gravity_icp(source, target, np.eye(4), UP, max_distance_m=0.3, kernel_m=0.2, iterations=50,
                          max_tilt_rad=np.radians(0.25))
    assert np.degrees(tilt_of(bounded.transform, UP)) == pytest.approx(0.25, abs=1e-6)


def _one_view(depth_m: float) -> DepthViews:
    """A 20x20 camera at the origin looking down +z at a wall ``depth_m`` away."""
    near = np.full((1, 20, 20), depth_m, np.float32)
    return DepthViews(camera_from_world=np.eye(4)[None], intrinsics=np.array([[10.0, 10.0, 9.5, 9.5]]), near_depth=near)


def test_evidence_tells_surface_free_space_and_unseen_apart():
    views = _one_view(2.0)
    wall = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 5), np.linspace(-0.5, 0.5, 5), [2.0]), -1).reshape(-1, 3)
    target = PlaneTarget.of(wall, np.tile([0.0, 0.0, -1.0], (len(wall), 1)))
    points = np.array([
        [0.0, 0.0, 2.005],  # on the wall: for
        [0.0, 0.0, 1.0],  # in front of it, where the camera saw through: against
        [0.0, 0.0, 3.0],  # behind it: unseen
        [5.0, 0.0, 2.0],  # outside the view: unseen
    ])
    ev = evidence(points, target, views, inlier_m=0.02, margin_m=0.05)
    assert (ev.agree, ev.conflict, ev.total) == (1, 1, 4)
    assert ev.agree_mask.tolist() == [True, False, False, False]
    assert ev.overlap == 0.5 and ev.inlier_ratio == 0.5 and ev.support == 0.0
    # The other way round: a surface 1 m away that a 2 m ray passed through.
    assert seen_through(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.01], [0.0, 0.0, 2.5]]), views, 0, 0.05) == 1


def test_pose_hypotheses():
    gravity = (0.0, -1.0, 0.0)
    static_cam = make_se3(axis_angle_to_matrix(UP, 0.3) @ axis_angle_to_matrix(np.array([1.0, 0, 0]), -0.4),
                          np.array([1.0, 1.4, 2.0]))
    offset = make_se3(axis_angle_to_matrix(UP, 1.1), np.array([0.5, 0.1, -2.0]))
    dynamic_cam = np.linalg.inv(offset) @ static_cam
    # The same camera in another session frame: the anchor undoes the session offset exactly.
    assert np.allclose(camera_anchor(static_cam, dynamic_cam, gravity), offset, atol=1e-9)
    names = [name for name, _ in pose_hypotheses(static_cam[None], dynamic_cam[None], gravity)]
    assert names[0] == "identity" and len(names) == 3
