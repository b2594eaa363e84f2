"""Rigid-body geometry and the camera: quaternions (wxyz), SE(3) matrices, axis conventions,
the pinhole model and its pixel convention.

Transforms are named target-from-source (``world_from_camera``), as COLMAP does, and stored as
4x4 float64 matrices. Quaternions are scalar-first ``[w, x, y, z]`` everywhere. Pixel centres
lie at integer image coordinates (see ``_camera``); the rasterizer's +0.5 is converted once,
by ``raster_intrinsics``.
"""

from artitwin_core.geometry._camera import (
    backproject,
    corner_radius_sq,
    depth_normals,
    nearest_pixel,
    pixel_grid,
    pixel_rays,
    project,
    raster_intrinsics,
)
from artitwin_core.geometry._quaternion import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from artitwin_core.geometry._se3 import (
    OPENGL_FROM_OPENCV,
    axis_angle_to_matrix,
    check_rigid,
    invert_se3,
    make_se3,
    transform_points,
)
from artitwin_core.geometry._trajectory import interpolate_poses, relative_motion
from artitwin_core.geometry._voxels import unique_rows

__all__ = [
    "OPENGL_FROM_OPENCV",
    "axis_angle_to_matrix",
    "backproject",
    "check_rigid",
    "corner_radius_sq",
    "depth_normals",
    "interpolate_poses",
    "relative_motion",
    "invert_se3",
    "make_se3",
    "matrix_to_quat_wxyz",
    "nearest_pixel",
    "pixel_grid",
    "pixel_rays",
    "project",
    "quat_wxyz_to_matrix",
    "raster_intrinsics",
    "transform_points",
    "unique_rows",
]
