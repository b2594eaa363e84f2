"""Joints: types, estimation from 3D trajectories, state refinement from depth, metrics against ground truth."""

from artitwin_core.joints._config import JointFitConfig, StateRefineConfig
from artitwin_core.joints._depth_fit import fit_line_from_planes
from artitwin_core.joints._estimate import estimate_joint
from artitwin_core.joints._metrics import (
    JointErrors,
    axis_angle_error_deg,
    joint_errors,
    line_distance,
    point_line_distance,
)
from artitwin_core.joints._model import joint_motion, joint_transforms
from artitwin_core.joints._result import HypothesisScore, JointFit
from artitwin_core.joints._rigid import ransac_rigid
from artitwin_core.joints._simulate import random_part_joint, simulate_trajectories
from artitwin_core.joints._states import refine_joint_states
from artitwin_core.joints._timing import poses_on_rgb_clock, to_rgb_clock
from artitwin_core.joints._types import JOINT_TYPES, Joint, JointType
from artitwin_core.joints._uncertainty import with_registration_error

__all__ = [
    "joint_motion",
    "ransac_rigid",
    "fit_line_from_planes",
    "JOINT_TYPES",
    "JointType",
    "HypothesisScore",
    "Joint",
    "JointErrors",
    "JointFit",
    "JointFitConfig",
    "StateRefineConfig",
    "axis_angle_error_deg",
    "estimate_joint",
    "joint_errors",
    "joint_transforms",
    "line_distance",
    "point_line_distance",
    "poses_on_rgb_clock",
    "random_part_joint",
    "refine_joint_states",
    "simulate_trajectories",
    "to_rgb_clock",
    "with_registration_error",
]
