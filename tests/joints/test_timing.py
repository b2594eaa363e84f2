"""States read from depth maps recorded after the RGB, moved back to the RGB exposures' times."""

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.joints import Joint, to_rgb_clock


def _door(lag_s: float, fps: float = 15.0, frames: int = 30, noise_rad: float = 0.0, seed: int = 0):
    """A door opening 1.2 rad with an eased profile; its states as a sensor whose depth and pose
    are ``lag_s`` later than the RGB measures them, and the truth at the RGB times."""
    ts = np.arange(frames) / fps
    def q_of(t):
        s = np.clip((t - 0.3) / 1.2, 0.0, 1.0)
        return 1.2 * s * s * (3 - 2 * s)
    measured = q_of(ts + lag_s) + np.random.default_rng(seed).normal(0.0, noise_rad, frames)
    joint = Joint(
        "revolute", np.array([0.0, 1.0, 0.0]), np.zeros(3), measured, np.array([measured.min(), measured.max()]),
        np.zeros(frames), np.ones(frames),
    )
    return joint, ts, q_of(ts)


def test_states_move_to_the_rgb_clock():
    joint, ts, truth = _door(0.033)
    before = np.degrees(np.sqrt(np.mean((joint.q - truth) ** 2)))
    moved = to_rgb_clock(joint, ts, 0.033)
    after = np.degrees(np.sqrt(np.mean((moved.q - truth) ** 2)))
    # Measured 1.60 deg -> 0.07 deg (the linear interpolation's error at the eased ends).
    assert before > 1.0
    assert after < 0.1
    assert np.isclose(moved.q_range[1], moved.q.max()) and moved.axis is joint.axis
    # The wrong sign doubles the lag instead.
    wrong = to_rgb_clock(joint, ts, -0.033)
    assert np.degrees(np.sqrt(np.mean((wrong.q - truth) ** 2))) > 1.5 * before


def test_unmeasured_frames_stay_unmeasured_and_no_lag_is_no_change():
    joint, ts, _ = _door(0.05)
    q = joint.q.copy()
    q[[0, 12]] = np.nan
    gappy = Joint(joint.joint_type, joint.axis, joint.pivot, q, joint.q_range, joint.residual, joint.confidence)
    moved = to_rgb_clock(gappy, ts, 0.05)
    assert np.isnan(moved.q[[0, 12]]).all() and np.isfinite(np.delete(moved.q, [0, 12])).all()
    assert to_rgb_clock(joint, ts, 0.0) is joint


def test_bad_timing_input_is_named():
    joint, ts, _ = _door(0.0)
    with pytest.raises(InputError, match="timestamps"):
        to_rgb_clock(joint, ts[:-1], 0.03)
    with pytest.raises(InputError, match="increasing"):
        to_rgb_clock(joint, ts[::-1], 0.03)
    with pytest.raises(InputError, match="time offset"):
        to_rgb_clock(joint, ts, 5.0)


def test_poses_move_to_the_rgb_clock():
    from artitwin_core.geometry import axis_angle_to_matrix
    from artitwin_core.joints import poses_on_rgb_clock

    ts = np.arange(20) / 15.0

    def pose_at(t):
        p = np.eye(4)
        p[:3, :3] = axis_angle_to_matrix(np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1]), 0.4 * t)
        p[:3, 3] = [0.3 * t, 0.1, -0.2 * t]
        return p

    lag = 0.033
    recorded = np.stack([pose_at(t + lag) for t in ts])  # taken with the depth, lag later
    moved = poses_on_rgb_clock(recorded, ts, lag)
    truth = np.stack([pose_at(t) for t in ts])
    # A constant turn and a straight path are interpolated exactly, but the first frame (before
    # the first recorded pose) holds it.
    np.testing.assert_allclose(moved[1:], truth[1:], atol=1e-9)
    np.testing.assert_allclose(moved[0], recorded[0])
    with pytest.raises(InputError, match="expected"):
        poses_on_rgb_clock(recorded[:-1], ts, lag)
