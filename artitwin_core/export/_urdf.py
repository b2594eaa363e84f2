"""URDF writer: one fixed base link, one child link per part, OBJ meshes by relative path."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import trimesh

from artitwin_core.export._inertia import WOOD_DENSITY_KG_M3
from artitwin_core.export._model import Z_UP_FROM_Y_UP, Model, build_model, mean_rgba, write_meshes


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.atleast_1d(values))


def matrix_to_rpy(rot: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll, pitch, yaw (radians) of ``rot [3, 3]`` = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = np.arcsin(-np.clip(rot[2, 0], -1.0, 1.0))
    if abs(rot[2, 0]) < 1 - 1e-9:
        roll = np.arctan2(rot[2, 1], rot[2, 2])
        yaw = np.arctan2(rot[1, 0], rot[0, 0])
    else:  # gimbal lock: fold yaw into roll
        roll = np.arctan2(-rot[1, 2], rot[1, 1])
        yaw = 0.0
    return np.array([roll, pitch, yaw])


def _origin(parent: ET.Element, transform: np.ndarray) -> None:
    ET.SubElement(parent, "origin", xyz=_fmt(transform[:3, 3]), rpy=_fmt(matrix_to_rpy(transform[:3, :3])))


def model_to_urdf(model: Model, effort: float, velocity: float) -> ET.Element:
    robot = ET.Element("robot", name=model.name)
    for note in model.notes:
        robot.append(ET.Comment(" " + note.replace("--", "-") + " "))
    # MuJoCo's URDF importer strips directories from mesh paths unless told not to, and merges
    # bodies without a joint (a fixed part) into their parent, which would lose the part's body.
    ET.SubElement(ET.SubElement(robot, "mujoco"), "compiler", strippath="false", discardvisual="true",
                  fusestatic="false")
    for link in model.links:
        el = ET.SubElement(robot, "link", name=link.name)
        if link.inertial is not None:
            inn = ET.SubElement(el, "inertial")
            ET.SubElement(inn, "origin", xyz=_fmt(link.inertial.com), rpy="0 0 0")
            ET.SubElement(inn, "mass", value=f"{link.inertial.mass_kg:.9g}")
            i = link.inertial.inertia
            ET.SubElement(inn, "inertia", ixx=f"{i[0, 0]:.9g}", ixy=f"{i[0, 1]:.9g}", ixz=f"{i[0, 2]:.9g}",
                          iyy=f"{i[1, 1]:.9g}", iyz=f"{i[1, 2]:.9g}", izz=f"{i[2, 2]:.9g}")
        if link.visual_file is not None:
            vis = ET.SubElement(el, "visual", name=f"{link.name}_visual")
            ET.SubElement(vis, "origin", xyz="0 0 0", rpy="0 0 0")
            ET.SubElement(ET.SubElement(vis, "geometry"), "mesh", filename=link.visual_file)
            mat = ET.SubElement(vis, "material", name=f"{link.name}_color")
            ET.SubElement(mat, "color", rgba=_fmt(mean_rgba(link.visual)))
        for k, rel in enumerate(link.collision_files):
            col = ET.SubElement(el, "collision", name=f"{link.name}_collision_{k:02d}")
            ET.SubElement(col, "origin", xyz="0 0 0", rpy="0 0 0")
            ET.SubElement(ET.SubElement(col, "geometry"), "mesh", filename=rel)
    for j in model.joints:
        el = ET.SubElement(robot, "joint", name=j.name, type=j.kind)
        _origin(el, j.origin)
        ET.SubElement(el, "parent", link=j.parent)
        ET.SubElement(el, "child", link=j.child)
        if j.kind != "fixed":
            ET.SubElement(el, "axis", xyz=_fmt(j.axis))
            ET.SubElement(el, "limit", lower=f"{j.lower:.9g}", upper=f"{j.upper:.9g}",
                          effort=f"{effort:.9g}", velocity=f"{velocity:.9g}")
        if j.mimic is not None:
            ET.SubElement(el, "mimic", joint=j.mimic[0], multiplier=f"{j.mimic[1]:.9g}", offset="0")
    ET.indent(robot)
    return robot


def export_urdf(
    out_dir: str | Path,
    base_mesh: trimesh.Trimesh,
    parts: list,
    *,
    name: str = "artitwin",
    base_collision: list[trimesh.Trimesh] | None = None,
    density_kg_m3: float = WOOD_DENSITY_KG_M3,
    effort: float = 50.0,
    velocity: float = 1.0,
    sim_from_canonical: np.ndarray | None = Z_UP_FROM_Y_UP,
) -> Path:
    """Write ``<out_dir>/<name>.urdf`` and its meshes under ``<out_dir>/meshes``; return the URDF path.

    Args:
        out_dir: output folder (created).
        base_mesh: the static scene without the parts, canonical frame, metres (``fuse_base_mesh``).
        parts: ``ExportPart`` or ``(name, Joint, mesh, collision_parts | None)`` per part; meshes in
            the canonical frame at ``q = 0``. Names are sanitised (``"../door 1"`` -> ``door_1``).
        base_collision: convex pieces of the base (canonical frame); ``None`` decomposes ``base_mesh``.
        density_kg_m3: uniform density for the parts' inertials (500: wood).
        effort, velocity: joint limits the estimate cannot give (N or N m; m/s or rad/s).
        sim_from_canonical: ``[4, 4]`` fixed transform of a root ``world`` link above ``base``
            (default: y-up canonical to z-up); ``None`` makes ``base`` the root.

    The joint limits are ``joint.q_range``; see ``_model`` for frames and screw joints.
    """
    out = Path(out_dir)
    model = build_model(base_mesh, parts, name=name, base_collision=base_collision,
                        density_kg_m3=density_kg_m3, sim_from_canonical=sim_from_canonical)
    write_meshes(model, out)
    path = out / f"{model.name}.urdf"
    tree = ET.ElementTree(model_to_urdf(model, effort, velocity))
    tree.write(path, encoding="utf-8", xml_declaration=True)
    return path
