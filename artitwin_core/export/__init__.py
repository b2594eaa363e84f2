"""Simulator export: fused meshes per link, convex collision pieces, inertials, URDF and MJCF.

``fuse_part_mesh`` / ``fuse_base_mesh`` turn the recordings into closed-state meshes,
``convex_decomposition`` makes collision pieces, ``mesh_inertial`` weighs a link, and
``export_urdf`` / ``export_mjcf`` write a base link plus one jointed child link per part, and
``export_part_plys`` splits the Gaussian twin into one standard 3DGS ``.ply`` per label, and
``check_in_simulators`` loads the files in yourdfpy, PyBullet and MuJoCo and compares the part poses
along the estimated ``q(t)`` with the twin's. ``export_usd`` writes the same model as an OpenUSD
stage (UsdPhysics articulation, the splats as ``UsdVol.ParticleField3DGaussianSplat``) and
``check_usd`` validates it, reads its joints back and drives them (in pxr and, if installed, Newton).
"""

from artitwin_core.export._collision import convex_decomposition
from artitwin_core.export._fuse import clean_mesh, fuse_base_mesh, fuse_part_mesh
from artitwin_core.export._inertia import WOOD_DENSITY_KG_M3, Inertial, mesh_inertial
from artitwin_core.export._mjcf import export_mjcf
from artitwin_core.export._model import Z_UP_FROM_Y_UP, ExportPart
from artitwin_core.export._names import sanitize_name
from artitwin_core.export._ply import export_part_plys
from artitwin_core.export._simcheck import SIMULATORS, SimPart, SimResult, check_in_simulators
from artitwin_core.export._urdf import export_urdf
from artitwin_core.export._usd import UsdResult, export_usd
from artitwin_core.export._usdcheck import (
    USD_SIMULATORS,
    UsdJoint,
    check_usd,
    parse_physics,
    read_usd_joints,
    validate_usd,
)

__all__ = [
    "parse_physics",
    "SIMULATORS",
    "USD_SIMULATORS",
    "WOOD_DENSITY_KG_M3",
    "Z_UP_FROM_Y_UP",
    "ExportPart",
    "Inertial",
    "SimPart",
    "SimResult",
    "UsdJoint",
    "UsdResult",
    "check_in_simulators",
    "check_usd",
    "clean_mesh",
    "convex_decomposition",
    "export_mjcf",
    "export_part_plys",
    "export_urdf",
    "export_usd",
    "fuse_base_mesh",
    "fuse_part_mesh",
    "mesh_inertial",
    "read_usd_joints",
    "sanitize_name",
    "validate_usd",
]
