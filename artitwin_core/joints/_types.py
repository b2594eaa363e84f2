"""The in-memory form of estimated (or ground-truth) joints."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

JointType = Literal["revolute", "prismatic", "screw", "fixed"]
JOINT_TYPES: tuple[JointType, ...] = get_args(JointType)


@dataclass(frozen=True)
class Joint:
    """One articulation joint in the canonical frame (= the static recording's world frame).

    Revolute: the part rotates by ``q`` radians about ``axis`` through ``pivot`` (right-hand rule).
    Prismatic: the part translates by ``q`` metres along ``axis``; ``pivot`` is a point on the part's
    axis line at ``q = 0`` (used for drawing and export only).
    Screw: rotation ``q`` about the axis line plus translation ``pitch * q`` along it.
    Fixed: nothing moved; ``q`` is all zeros.

    Attributes:
        joint_type: one of ``JOINT_TYPES``.
        axis: ``[3]`` float64 unit direction in the canonical frame.
        pivot: ``[3]`` float64 metres, a point on the axis line in the canonical frame.
        q: ``[T]`` float64 state per dynamic frame, radians (revolute, screw) or metres
            (prismatic); ``q = 0`` is the canonical (closed, static-recording) state.
        q_range: ``[2]`` float64 ``(q_min, q_max)`` observed range of motion.
        residual: ``[T]`` float64 metres, per-frame RMS distance of the part's tracked points to
            their joint-predicted positions (NaN where the frame had no valid tracks).
        confidence: ``[T]`` float64 in [0, 1], per-frame confidence of ``q``.
        pitch: metres per radian of axial translation (screw joints only, else 0).
        axis_se_rad: standard error of the axis direction (radians), or None where the fit did
            not estimate it. Revolute joints get it from their frame-level fit, with each frame
            one sample (an error shared by a frame's tracks, such as the recording's pose
            error there, counts once), or from the face-plane line fit where that replaced the
            line (``refine_joint_states``); prismatic ones from the frames' displacements across
            the slide, or from that fused with the part's face normal. Errors every frame
            shares (the registration, a sensor defect, a depth error pattern that repeats from
            frame to frame) are not in it: from tracks alone it is a lower bound
            (docs/accuracy.md has the measured coverage).
        pivot_se_m: standard error of the axis line's position across the axis (metres, its
            worse direction), or None (prismatic and fixed joints); as ``axis_se_rad``.
    """

    joint_type: JointType
    axis: np.ndarray
    pivot: np.ndarray
    q: np.ndarray
    q_range: np.ndarray
    residual: np.ndarray
    confidence: np.ndarray
    pitch: float = 0.0
    axis_se_rad: float | None = None
    pivot_se_m: float | None = None
