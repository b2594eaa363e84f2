"""Non-ideal joints on synthetic trajectories (ground-truth motion + noise, fixed seeds): a drawer
that tilts as it slides is still a prismatic joint, a door is still a hinge.

A drawer dipping by ``tilt * q / q_max`` about a horizontal edge that rides with it is, over a
small angle, a rotation about an axis ``travel / tilt`` away (6 m for 0.04 rad over 0.25 m); the
revolute hypothesis then wins the BIC by far (the prismatic model has no tilt), so the type must
come from the geometry: a hinge sits at its part, a slide's tilt is small.
"""

import numpy as np
import pytest

from artitwin_core.joints import (
    Joint,
    JointFitConfig,
    axis_angle_error_deg,
    estimate_joint,
    joint_errors,
    joint_transforms,
    simulate_trajectories,
)
from artitwin_core.joints._slide import _tilt_rate
from artitwin_core.tracking import Trajectories

T, N = 20, 200
SLIDE = np.array([0.0, 0.0, 1.0])  # out of the carcass, towards the camera
UP = np.array([0.0, 1.0, 0.0])


def _front(rng: np.random.Generator, n: int = N) -> np.ndarray:
    """Tracks on a 0.5 x 0.2 m drawer front (its face at z = 0, 2 m in front of the camera)."""
    return np.stack([rng.uniform(-0.25, 0.25, n), rng.uniform(0.1, 0.3, n), rng.normal(0.0, 0.002, n)], 1)


def _tilting_drawer(tilt_rad: float, tilt_pivot: np.ndarray, seed: int, travel_m: float = 0.25):
    """Nominal prismatic joint along ``SLIDE``, plus a dip of ``tilt_rad * q / q_max`` about the
    horizontal axis across the slide through ``tilt_pivot`` (closed state; it rides with the
    drawer), as the synthetic scenes' ``drawer_tilt`` effect. 1 mm noise, 10% outlier tracks."""
    rng = np.random.default_rng(seed)
    pts = _front(rng)
    q = travel_m * np.sin(np.linspace(0.0, np.pi / 2, T)) ** 2
    truth = Joint("prismatic", SLIDE, pts.mean(0), q, np.array([0.0, travel_m]), np.zeros(T), np.ones(T))
    traj, _ = simulate_trajectories(truth, pts, rng, noise_m=0.001, outlier_fraction=0.1)
    side = np.cross(UP, SLIDE)
    p = traj.points_in_world.copy()
    for t in range(T):
        m = joint_transforms(
            "revolute", side, tilt_pivot + q[t] * SLIDE, np.array([tilt_rad * q[t] / travel_m])
        )[0]
        p[t] = p[t] @ m[:3, :3].T + m[:3, 3]
    return truth, pts, Trajectories(p, traj.pixels, traj.valid, traj.query_frame)


@pytest.mark.parametrize("seed", [0, 1])
def test_drawer_tilting_about_its_front_is_prismatic(seed):
    # Tilt axis through the tracked front: its points move along the nominal slide.
    truth, pts, traj = _tilting_drawer(0.04, np.array([0.0, 0.2, 0.0]), seed)
    fit = estimate_joint(traj)
    # The rotation about an axis ~6 m away explains the tilt: it wins the BIC by hundreds ...
    assert fit.score("revolute").bic + 100.0 < fit.score("prismatic").bic
    # ... but a hinge 20 part radii from its part that turns it by 2 degrees is a tilted slide.
    assert fit.joint.joint_type == "prismatic", [(h.joint_type, h.bic) for h in fit.hypotheses]
    e = joint_errors(fit.joint, truth)
    assert e.axis_angle_deg < 3.0  # measured 0.02 / 0.004 deg (seeds 0 / 1)
    assert e.state_error_m < 0.005


@pytest.mark.parametrize("tilt", [0.04, 0.1, 0.2])
def test_drawer_tilting_about_its_back_bottom_edge_slides_along_its_front(tilt):
    """As the synthetic scenes' drawer: the tilt axis is the box's back-bottom edge, 0.4 m behind
    and 0.1 m below the tracked front, which therefore drops by ``tilt * 0.4`` m while sliding
    0.25 m: the tracks themselves move ``atan(0.4 tilt / 0.25)`` off the rail (3.7 deg at 0.04
    rad), a bias no rigid-motion fit can remove (the tilt axis is not observed). The frames'
    turn shows the slide tilts, and the rail is then the closed front's normal."""
    truth, pts, traj = _tilting_drawer(tilt, np.array([0.0, 0.1, -0.4]), seed=2)
    fit = estimate_joint(traj)
    assert fit.joint.joint_type == "prismatic", [(h.joint_type, h.bic) for h in fit.hypotheses]
    # Measured 0.12-0.16 deg at every tilt (seeds 2-4): the front's plane fit, whose standard
    # error is 0.15-0.17 deg.
    assert axis_angle_error_deg(fit.joint.axis, truth.axis) < 0.3
    # Without the tilt test the fit keeps the tracks' direction: the bias stands.
    tracks = estimate_joint(traj, JointFitConfig(tilt_min_rad=np.inf)).joint
    bias = np.degrees(np.arctan(0.4 * tilt / 0.25))
    assert abs(axis_angle_error_deg(tracks.axis, truth.axis) - bias) < 1.0


def test_a_small_turn_is_no_tilt():
    # The frames' rotations are noise around none: the slide is no tilting one.
    truth, pts, traj = _tilting_drawer(0.0, np.array([0.0, 0.1, -0.4]), seed=2)
    fit = estimate_joint(traj)
    assert _tilt_rate(fit.rigid_motions[1:], fit.joint.q[1:], JointFitConfig()) is None
    truth, pts, traj = _tilting_drawer(0.04, np.array([0.0, 0.1, -0.4]), seed=2)
    fit = estimate_joint(traj)
    rate = _tilt_rate(fit.rigid_motions[1:], fit.joint.q[1:], JointFitConfig())
    # 0.04 rad over 0.25 m about the horizontal axis across the slide (x): 0.16 rad per metre.
    assert rate is not None and abs(abs(rate[0]) - 0.16) < 0.02 and np.hypot(rate[1], rate[2]) < 0.02


def _door(q_max: float, seed: int, patch: bool = False):
    """A 0.8 m wide door hinged on its left edge (vertical axis); ``patch`` keeps only tracks on a
    0.15 m square near the free edge (the rest occluded)."""
    rng = np.random.default_rng(seed)
    lo, hi = ([0.6, 0.9, 0.0], [0.75, 1.05, 0.0]) if patch else ([0.0, 0.0, 0.0], [0.8, 2.0, 0.0])
    pts = rng.uniform(lo, hi, (N, 3)) + rng.normal(0.0, 0.002, (N, 3)) * [0, 0, 1]
    pts = pts + [-0.4, -1.0, 2.0]
    q = q_max * np.sin(np.linspace(0.0, np.pi / 2, T)) ** 2
    truth = Joint(
        "revolute", UP, np.array([-0.4, 0.0, 2.0]), q, np.array([0.0, q_max]), np.zeros(T), np.ones(T)
    )
    traj, _ = simulate_trajectories(truth, pts, rng, noise_m=0.001, outlier_fraction=0.1)
    return truth, traj


@pytest.mark.parametrize(("q_max", "patch"), [(1.2, False), (1.2, True), (0.15, False)])
def test_doors_stay_revolute(q_max, patch):
    # A full door (axis one part radius from its centroid), a door seen only through a patch 4.5
    # patch radii from the hinge (the turn of 1.2 rad is no tilt), a door opened by 9 degrees.
    truth, traj = _door(q_max, seed=3, patch=patch)
    fit = estimate_joint(traj)
    e = joint_errors(fit.joint, truth)
    assert e.type_correct, [(h.joint_type, h.bic) for h in fit.hypotheses]
    assert e.axis_angle_deg < 1.0  # measured 0.008 / 0.04 / 0.06 deg
    assert e.pivot_to_line_m < 0.02  # measured 0.1 / 0.3 / 1.2 mm


def test_ransac_without_any_inlier_returns_a_motion():
    """Three tracks that are not rigid at all (a frame where the tracker lost the drawer, seen on
    non-ideal-joints): no sample has an inlier, RANSAC must still end (it raised OverflowError)."""
    from artitwin_core.joints import ransac_rigid

    src = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
    dst = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.02, 0.3]])
    res = ransac_rigid(
        src,
        dst,
        np.random.default_rng(0),
        iterations=50,
        threshold_m=1e-3,
        min_threshold_m=1e-4,
        inlier_sigmas=4.0,
    )
    assert res is not None and res.inliers.sum() < 3
