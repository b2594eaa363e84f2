"""Joint metrics: line distances and axis errors against constructions with known answers."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from artitwin_core.joints import Joint, axis_angle_error_deg, joint_errors, line_distance

unit3 = st.tuples(*[st.floats(-1, 1)] * 3).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1)
vec3 = st.tuples(*[st.floats(-3, 3)] * 3).map(np.array)


def _rotation(v: np.ndarray, angle: float) -> np.ndarray:
    v = v / np.linalg.norm(v)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _joint(kind, axis, pivot, q, pitch=0.0):
    q = np.asarray(q, float)
    return Joint(
        kind,
        np.asarray(axis, float),
        np.asarray(pivot, float),
        q,
        np.array([q.min(), q.max()]),
        np.zeros_like(q),
        np.ones_like(q),
        pitch,
    )


@settings(max_examples=60, deadline=None)
@given(pa=vec3, da=unit3, pb=vec3, db=unit3)
def test_line_distance_symmetric_and_sign_free(pa, da, pb, db):
    d = line_distance(pa, da, pb, db)
    # Exact symmetry up to float rounding of the same products (1e-12 m at coordinates of ~3 m).
    assert abs(d - line_distance(pb, db, pa, da)) < 1e-12 * (1 + d) + 1e-12
    assert abs(d - line_distance(pa, -da, pb, db)) < 1e-12 * (1 + d) + 1e-12
    # Moving the anchor points along their lines changes nothing.
    assert abs(d - line_distance(pa + 0.7 * da, da, pb - 1.3 * db, db)) < 1e-9
    assert d >= 0


@settings(max_examples=60, deadline=None)
@given(
    axis=unit3,
    angle=st.floats(0.01, np.pi - 0.01),
    dist=st.floats(0.0, 2.0),
    rot_axis=unit3,
    rot_angle=st.floats(-np.pi, np.pi),
    shift=vec3,
    s1=st.floats(-2, 2),
    s2=st.floats(-2, 2),
)
def test_skew_lines_at_known_distance(axis, angle, dist, rot_axis, rot_angle, shift, s1, s2):
    # Line a: the x axis; line b: through (0, 0, dist) along (cos, sin, 0); closest points at x=0.
    rot = _rotation(rot_axis, rot_angle)
    da = rot @ [1.0, 0, 0]
    db = rot @ [np.cos(angle), np.sin(angle), 0.0]
    pa = shift + s1 * da
    pb = shift + rot @ [0, 0, dist] + s2 * db
    # 1e-9 m: the formula divides by |a x b| >= sin(0.01); inputs are O(5) m.
    assert abs(line_distance(pa, da, pb, db) - dist) < 1e-9


@settings(max_examples=60, deadline=None)
@given(
    dist=st.floats(0.0, 2.0),
    rot_axis=unit3,
    rot_angle=st.floats(-np.pi, np.pi),
    shift=vec3,
    s=st.floats(-5, 5),
    flip=st.booleans(),
)
def test_parallel_lines_at_known_distance_not_zero(dist, rot_axis, rot_angle, shift, s, flip):
    rot = _rotation(rot_axis, rot_angle)
    d = rot @ [0, 0, 1.0]
    pa = shift
    pb = shift + rot @ [dist, 0, 0] + s * d
    db = -d if flip else d
    assert abs(line_distance(pa, d, pb, db) - dist) < 1e-9


@settings(max_examples=60, deadline=None)
@given(a=unit3, b=unit3)
def test_axis_error_ignores_sign_and_is_symmetric(a, b):
    e = axis_angle_error_deg(a, b)
    assert 0.0 <= e <= 90.0 + 1e-12
    assert abs(e - axis_angle_error_deg(-a, b)) < 1e-9
    assert abs(e - axis_angle_error_deg(b, a)) < 1e-9
    cos = abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b)
    assert abs(e - np.degrees(np.arccos(min(cos, 1.0)))) < 1e-5  # arccos is the looser one near 0


@settings(max_examples=30, deadline=None)
@given(axis=unit3, tilt=st.floats(0.0, 80.0), q_max=st.floats(0.1, 1.5))
def test_joint_errors_known_values_and_sign_flip(axis, tilt, q_max):
    axis = axis / np.linalg.norm(axis)
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    perp = np.cross(axis, helper)
    perp /= np.linalg.norm(perp)
    q = np.linspace(0, q_max, 9)
    truth = _joint("revolute", axis, [0.1, 0.2, 0.3], q)
    # The same joint written with the opposite axis and negated q: zero error everywhere.
    same = _joint("revolute", -axis, np.array([0.1, 0.2, 0.3]) + 2.0 * axis, -q)
    e = joint_errors(same, truth)
    assert e.type_correct and e.axis_angle_deg < 1e-6 and e.pivot_error_m < 1e-9
    assert e.state_error_deg < 1e-9 and e.range_error_deg < 1e-9
    # Tilted axis through a pivot shifted 0.05 m along the common normal; states off by 0.01 rad.
    tilted = np.cos(np.radians(tilt)) * axis + np.sin(np.radians(tilt)) * perp
    est = _joint("revolute", tilted, np.array([0.1, 0.2, 0.3]) + 0.05 * np.cross(axis, perp), q + 0.01)
    e = joint_errors(est, truth)
    assert abs(e.axis_angle_deg - tilt) < 1e-6
    if tilt > 1e-3:
        assert abs(e.pivot_error_m - 0.05) < 1e-9
    assert abs(e.state_error_deg - np.degrees(0.01)) < 1e-9
    assert abs(e.range_error_deg - np.degrees(0.01)) < 1e-9


def test_prismatic_errors_have_no_pivot_and_metre_states():
    q = np.linspace(0, 0.3, 5)
    truth = _joint("prismatic", [1, 0, 0], [0, 0, 0], q)
    est = _joint("prismatic", [-1, 0, 0], [5, 5, 5], -(q + 0.002))
    e = joint_errors(est, truth)
    assert e.type_correct
    assert np.isnan(e.pivot_error_m) and np.isnan(e.state_error_deg)
    assert abs(e.state_error_m - 0.002) < 1e-12 and abs(e.range_error_m - 0.002) < 1e-12
    wrong = joint_errors(_joint("revolute", [1, 0, 0], [0, 0, 0], q), truth)
    assert not wrong.type_correct and np.isnan(wrong.state_error_m) and np.isnan(wrong.state_error_deg)
