"""Joint kinematics and the estimator's analytic Jacobian (reference: finite differences)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize._numdiff import approx_derivative

from artitwin_core.joints import joint_transforms
from artitwin_core.joints._fit import _Fit, _theta_problem

unit3 = st.tuples(*[st.floats(-1, 1)] * 3).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1)
vec3 = st.tuples(*[st.floats(-3, 3)] * 3).map(np.array)


@settings(max_examples=40, deadline=None)
@given(
    kind=st.sampled_from(["revolute", "prismatic", "screw"]),
    axis=unit3,
    pivot=vec3,
    q1=st.floats(-2, 2),
    q2=st.floats(-2, 2),
    pitch=st.floats(-0.2, 0.2),
    s=st.floats(-2, 2),
)
def test_motion_is_a_one_parameter_subgroup(kind, axis, pivot, q1, q2, pitch, s):
    m = joint_transforms(kind, axis, pivot, np.array([q1, q2, q1 + q2, 0.0]), pitch)
    # Rounding of products of O(3) numbers: 1e-12.
    assert np.abs(m[2] - m[0] @ m[1]).max() < 1e-12
    assert np.abs(m[3] - np.eye(4)).max() < 1e-15
    a = axis / np.linalg.norm(axis)
    on_axis = pivot + s * a
    moved = m[0, :3, :3] @ on_axis + m[0, :3, 3]
    expected = {"revolute": on_axis, "prismatic": on_axis + q1 * a, "screw": on_axis + pitch * q1 * a}[kind]
    assert np.abs(moved - expected).max() < 1e-12


def test_analytic_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    t_count, n = 7, 40
    y = rng.normal(size=(t_count, n, 3))
    pts = rng.normal(size=(n, 3))
    w = rng.uniform(0.2, 1.0, size=(t_count, n))
    for kind in ("prismatic", "revolute", "screw"):
        axis = rng.normal(size=3)
        fit = _Fit(
            kind,
            axis / np.linalg.norm(axis),
            rng.normal(size=3),
            0.07,
            rng.uniform(-2, 2, t_count),
            pts,
            w,
            np.ones(n, bool),
            np.ones(t_count),
        )
        fun, jac, x0, _ = _theta_problem(fit, y, np.arange(t_count))
        x = x0 + rng.normal(scale=0.1, size=x0.shape)
        ja = jac(x)
        jn = approx_derivative(fun, x, method="3-point")
        # Central differences are good to ~1e-9 here (measured 6e-10 max with entries up to 16).
        assert np.abs(ja - jn).max() < 1e-7 * max(1.0, np.abs(jn).max()), kind


def test_compressed_residuals_equal_point_residuals():
    rng = np.random.default_rng(2)
    t_count, n = 5, 30
    y = rng.normal(size=(t_count, n, 3))
    pts = rng.normal(size=(n, 3))
    w = rng.uniform(0.0, 1.0, size=(t_count, n)) * (rng.random((t_count, n)) > 0.2)
    for kind in ("prismatic", "revolute", "screw"):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        fit = _Fit(
            kind,
            axis,
            rng.normal(size=3),
            0.05,
            rng.uniform(-1, 1, t_count),
            pts,
            w,
            np.ones(n, bool),
            np.ones(t_count),
        )
        fun, _, x0, unpack = _theta_problem(fit, y, np.arange(t_count))
        ax, piv, pitch, q = unpack(x0)
        m = joint_transforms(kind, ax, piv, q, pitch)
        pred = np.einsum("tij,nj->tni", m[:, :3, :3], pts) + m[:, None, :3, 3]
        direct = np.sum(w * np.sum((pred - y) ** 2, -1))
        compressed = np.sum(fun(x0) ** 2)
        if kind == "prismatic":
            # The prismatic residuals omit the rotational part, which no parameter changes.
            wc = w.sum(1)
            xb = (w @ pts) / wc[:, None]
            yb = np.einsum("tn,tni->ti", w, y) / wc[:, None]
            rot_part = np.sum(w * np.sum(((pts[None] - xb[:, None]) - (y - yb[:, None])) ** 2, -1))
            compressed += rot_part
        # Exact algebra; the Gram-matrix square root loses ~sqrt(eps) relative: 1e-7.
        assert abs(direct - compressed) < 1e-7 * direct, kind
