"""The registration's error, shared by every frame, added to a joint's standard errors."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artitwin_core.joints._model import skew
from artitwin_core.joints._types import Joint


def _worst_across(cov3: np.ndarray, axis: np.ndarray) -> float:
    """Largest variance of ``cov3 [3, 3]`` in the plane perpendicular to unit ``axis``."""
    p = np.eye(3) - np.outer(axis, axis)
    return float(max(np.linalg.eigvalsh(p @ cov3 @ p)[-1], 0.0))


def with_registration_error(joint: Joint, covariance: np.ndarray | None) -> Joint:
    """``joint`` with the registration's error added (in quadrature) to its standard errors.

    A joint is fitted to points put into the canonical frame by one registration, so the
    registration's error moves the whole line: a rotation ``w`` turns the axis by ``w x a``, and
    at the pivot ``p`` the line moves by ``w x p + v``. The frames cannot show that error (they
    all share it), so the fit's own standard errors leave it out. ``covariance`` is the
    registration's ``[6, 6]`` over ``(w, v)`` (``RegistrationResult.covariance``); each joint
    standard error becomes ``sqrt(fit**2 + registration**2)``, the registration's part being the
    worse direction across the axis. Standard errors the fit did not estimate stay None, and so
    does everything when ``covariance`` is None.
    """
    if covariance is None or (joint.axis_se_rad is None and joint.pivot_se_m is None):
        return joint
    c = np.asarray(covariance, dtype=np.float64)
    if c.shape != (6, 6) or not np.all(np.isfinite(c)):
        return joint
    a = np.asarray(joint.axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    m = -skew(a)  # w x a = -[a]_x w
    axis_se = joint.axis_se_rad
    if axis_se is not None:
        axis_se = float(np.sqrt(axis_se**2 + _worst_across(m @ c[:3, :3] @ m.T, a)))
    pivot_se = joint.pivot_se_m
    if pivot_se is not None:
        jac = np.hstack([-skew(np.asarray(joint.pivot, dtype=np.float64)), np.eye(3)])
        pivot_se = float(np.sqrt(pivot_se**2 + _worst_across(jac @ c @ jac.T, a)))
    return replace(joint, axis_se_rad=axis_se, pivot_se_m=pivot_se)
