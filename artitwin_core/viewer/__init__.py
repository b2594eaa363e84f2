"""The interactive twin viewer's data and math: what is drawn, and where each part is at a slider state.

``TwinData`` gathers the Gaussian twin (part-labelled), its joints, the capture's cameras, residuals
and collision meshes; ``read_twin_files`` makes one from plain files. ``splat_arrays`` turns 3DGS
parameters into renderer inputs, ``part_poses`` gives ``world_from_part`` per joint state, and
``pose_splats`` is the reference for moving part Gaussians; ``depth_residual_points`` makes the
residual heat map from the diagnostics' predicted depth. The browser app lives in ``artitwin``.
"""

# The viewer's quaternion helpers are geometry's (re-exported: the CLI and tests import them here).
from artitwin_core.geometry import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from artitwin_core.viewer._files import (
    list_export_files,
    model_files,
    read_collision_meshes,
    read_joints_json,
    read_residual,
    read_twin_files,
)
from artitwin_core.viewer._residual import depth_residual_points, residual_by_label, residual_on_gaussians
from artitwin_core.viewer._splats import heat_colors, part_poses, pose_splats, slider_range, splat_arrays
from artitwin_core.viewer._synthetic import synthetic_twin
from artitwin_core.viewer._twin import CameraRig, MeshPiece, TwinData

__all__ = [
    "CameraRig",
    "MeshPiece",
    "TwinData",
    "depth_residual_points",
    "residual_by_label",
    "residual_on_gaussians",
    "heat_colors",
    "list_export_files",
    "model_files",
    "matrix_to_quat_wxyz",
    "part_poses",
    "pose_splats",
    "quat_wxyz_to_matrix",
    "read_collision_meshes",
    "read_joints_json",
    "read_residual",
    "read_twin_files",
    "slider_range",
    "splat_arrays",
    "synthetic_twin",
]
