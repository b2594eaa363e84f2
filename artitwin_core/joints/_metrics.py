"""Joint errors against ground truth, defined as articulated-object papers define them.

Ditto, PARIS, "Neural Implicit Representation for Building Digital Twins of Unknown Articulated
Objects" (Weng et al.) and Articulate-Anything report: the axis angle error in degrees with the
axis sign ignored (a hinge along ``a`` is the hinge along ``-a``), the axis position error as the
shortest distance between the two axis lines (revolute only; for parallel lines the distance from
a point of one to the other line, not 0), and the state error as the absolute difference of joint
states (degrees for revolute, metres for prismatic). Here the state error is averaged over the
frames of a trajectory, with one global sign taken from the axes (if the estimate's axis points
the other way, its ``q`` is negated before comparing). Papers that report the axis position in
units of 0.1 m (PARIS) differ from ``pivot_error_m`` by a factor of 10 only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artitwin_core.joints._types import Joint

_ROTATIONAL = ("revolute", "screw")


@dataclass(frozen=True)
class JointErrors:
    """Errors of one estimated joint against the truth. NaN where a metric does not apply.

    Attributes:
        type_correct: the estimated ``joint_type`` equals the true one.
        axis_angle_deg: angle between the axes ignoring sign, in [0, 90] degrees (NaN if either
            joint is fixed).
        pivot_error_m: distance between the two axis lines, metres (rotational truth and estimate
            only; NaN for prismatic or fixed).
        pivot_to_line_m: distance from the true pivot (a point near the part) to the estimated
            axis line, metres; unlike the line-line distance it does not shrink when nearly
            parallel lines cross far from the part. Same applicability as ``pivot_error_m``.
        state_error_deg: mean over frames of ``|q_est - s q_true|`` in degrees (``s`` the global
            axis sign); rotational truth and estimate only, else NaN.
        state_error_m: the same in metres, prismatic truth and estimate only, else NaN.
        range_error_deg: max of the errors of ``q_min`` and ``q_max`` (sign-aligned), degrees.
        range_error_m: the same in metres for prismatic joints.
        pitch_error_m_per_rad: ``|pitch_est - pitch_true|`` for screw truth and estimate, else NaN.
    """

    type_correct: bool
    axis_angle_deg: float
    pivot_error_m: float
    pivot_to_line_m: float
    state_error_deg: float
    state_error_m: float
    range_error_deg: float
    range_error_m: float
    pitch_error_m_per_rad: float


def axis_angle_error_deg(axis_a: np.ndarray, axis_b: np.ndarray) -> float:
    """Angle between two axis directions ``[3]`` ignoring sign: ``min(angle, 180 - angle)`` degrees."""
    a = np.asarray(axis_a, dtype=np.float64)
    b = np.asarray(axis_b, dtype=np.float64)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    # atan2 of |cross| and |dot| is accurate near 0 and 90 degrees, unlike arccos.
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), abs(a @ b))))


def point_line_distance(point: np.ndarray, line_point: np.ndarray, line_dir: np.ndarray) -> float:
    """Distance (metres) from ``point [3]`` to the line through ``line_point [3]`` along ``line_dir [3]``."""
    d = np.asarray(line_dir, dtype=np.float64)
    d = d / np.linalg.norm(d)
    return float(np.linalg.norm(np.cross(np.asarray(point, float) - np.asarray(line_point, float), d)))


def line_distance(point_a: np.ndarray, dir_a: np.ndarray, point_b: np.ndarray, dir_b: np.ndarray) -> float:
    """Shortest distance (metres) between two infinite 3D lines, each a point ``[3]`` and direction ``[3]``.

    For (near-)parallel lines (``|a x b| < 1e-9``) this is the distance from ``point_b`` to line a,
    which is then the same for every point of b.
    """
    a = np.asarray(dir_a, dtype=np.float64)
    b = np.asarray(dir_b, dtype=np.float64)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    delta = np.asarray(point_b, dtype=np.float64) - np.asarray(point_a, dtype=np.float64)
    n = np.cross(a, b)
    nn = np.linalg.norm(n)
    if nn < 1e-9:
        return float(np.linalg.norm(np.cross(delta, a)))
    return float(abs(delta @ n) / nn)


def joint_errors(estimated: Joint, truth: Joint) -> JointErrors:
    """Compare ``estimated`` with ``truth`` (same frames: ``q [T]`` both, NaN frames skipped)."""
    nan = float("nan")
    type_ok = estimated.joint_type == truth.joint_type
    moving = estimated.joint_type != "fixed" and truth.joint_type != "fixed"
    axis_deg = axis_angle_error_deg(estimated.axis, truth.axis) if moving else nan
    rot_both = estimated.joint_type in _ROTATIONAL and truth.joint_type in _ROTATIONAL
    pris_both = estimated.joint_type == "prismatic" and truth.joint_type == "prismatic"
    pivot = line_distance(estimated.pivot, estimated.axis, truth.pivot, truth.axis) if rot_both else nan
    pivot_pt = point_line_distance(truth.pivot, estimated.pivot, estimated.axis) if rot_both else nan
    state_deg = state_m = range_deg = range_m = nan
    if rot_both or pris_both:
        sign = 1.0 if float(np.dot(estimated.axis, truth.axis)) >= 0 else -1.0
        qe = sign * np.asarray(estimated.q, dtype=np.float64)
        qt = np.asarray(truth.q, dtype=np.float64)
        if qe.shape != qt.shape:
            raise ValueError(f"estimated q has shape {qe.shape}, truth {qt.shape}: compare the same frames")
        ok = np.isfinite(qe) & np.isfinite(qt)
        state = float(np.mean(np.abs(qe[ok] - qt[ok]))) if ok.any() else nan
        lo_e, hi_e = sorted(sign * np.asarray(estimated.q_range, dtype=np.float64))
        lo_t, hi_t = np.asarray(truth.q_range, dtype=np.float64)
        rng_err = float(max(abs(lo_e - lo_t), abs(hi_e - hi_t)))
        if rot_both:
            state_deg, range_deg = float(np.degrees(state)), float(np.degrees(rng_err))
        else:
            state_m, range_m = state, rng_err
    pitch = (
        abs(estimated.pitch - truth.pitch)
        if estimated.joint_type == "screw" and truth.joint_type == "screw"
        else nan
    )
    return JointErrors(
        type_correct=type_ok,
        axis_angle_deg=axis_deg,
        pivot_error_m=pivot,
        pivot_to_line_m=pivot_pt,
        state_error_deg=state_deg,
        state_error_m=state_m,
        range_error_deg=range_deg,
        range_error_m=range_m,
        pitch_error_m_per_rad=float(pitch),
    )
