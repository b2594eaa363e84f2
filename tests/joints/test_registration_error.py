"""A joint's standard errors take in the registration's error, which every frame shares."""

import numpy as np

from artitwin_core.geometry import axis_angle_to_matrix
from artitwin_core.joints import Joint, with_registration_error


def _door(axis_se=0.001, pivot_se=0.002) -> Joint:
    t = 5
    return Joint(
        joint_type="revolute", axis=np.array([0.0, 0.0, 1.0]), pivot=np.array([1.0, 0.0, 0.0]),
        q=np.linspace(0, 1, t), q_range=np.array([0.0, 1.0]), residual=np.zeros(t), confidence=np.ones(t),
        axis_se_rad=axis_se, pivot_se_m=pivot_se,
    )


def test_registration_error_adds_in_quadrature():
    sw, sv = 0.002, 0.003  # radians, metres
    cov = np.diag([sw**2] * 3 + [sv**2] * 3)
    joint = with_registration_error(_door(), cov)
    # Axis z: w turns it by (w_y, -w_x, 0). Pivot (1, 0, 0): w x p + v = (v_x, w_z + v_y, v_z - w_y),
    # across z the worse direction is y with variance sw^2 + sv^2.
    assert np.isclose(joint.axis_se_rad, np.hypot(0.001, sw))
    assert np.isclose(joint.pivot_se_m, np.sqrt(0.002**2 + sw**2 + sv**2))


def test_the_convention_matches_a_registration_that_moves_the_line():
    """Sampled registration errors (the small motion x -> R x + v) applied to the joint's line:
    the spread of the moved pivot across the axis matches the propagated standard error."""
    rng = np.random.default_rng(0)
    cov = np.diag([0.004**2, 0.001**2, 0.002**2, 0.002**2, 0.001**2, 0.003**2])
    base = _door(axis_se=0.0, pivot_se=0.0)
    joint = with_registration_error(base, cov)
    offsets, tilts = [], []
    for x in rng.multivariate_normal(np.zeros(6), cov, size=4000):
        rot = axis_angle_to_matrix(x[:3], np.linalg.norm(x[:3]))
        pivot = rot @ base.pivot + x[3:]
        axis = rot @ base.axis
        d = pivot - base.pivot
        offsets.append(d - (d @ base.axis) * base.axis)
        tilts.append(axis - (axis @ base.axis) * base.axis)
    worst = lambda v: float(np.sqrt(np.linalg.eigvalsh(np.cov(np.array(v).T))[-1]))  # noqa: E731
    assert abs(worst(offsets) / joint.pivot_se_m - 1.0) < 0.05
    assert abs(worst(tilts) / joint.axis_se_rad - 1.0) < 0.05


def test_without_a_covariance_or_fit_errors_nothing_changes():
    assert with_registration_error(_door(), None).pivot_se_m == 0.002
    bare = _door(axis_se=None, pivot_se=None)
    assert with_registration_error(bare, np.eye(6) * 1e-6).axis_se_rad is None
