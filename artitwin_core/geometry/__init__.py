"""Rigid-body geometry: quaternions (wxyz), SE(3) matrices, axis conventions.

Transforms are named target-from-source (``world_from_camera``), as COLMAP does, and stored as
4x4 float64 matrices. Quaternions are scalar-first ``[w, x, y, z]`` everywhere.
"""

from artitwin_core.geometry._se3 import (
    OPENGL_FROM_OPENCV,
    axis_angle_to_matrix,
    check_rigid,
    invert_se3,
    make_se3,
    matrix_to_quat_wxyz,
    quat_wxyz_to_matrix,
    transform_points,
)
from artitwin_core.geometry._trajectory import interpolate_poses

__all__ = [
    "OPENGL_FROM_OPENCV",
    "axis_angle_to_matrix",
    "check_rigid",
    "interpolate_poses",
    "invert_se3",
    "make_se3",
    "matrix_to_quat_wxyz",
    "quat_wxyz_to_matrix",
    "transform_points",
]
