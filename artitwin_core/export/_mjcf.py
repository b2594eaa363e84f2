"""MJCF writer: the same model as the URDF, as MuJoCo bodies with hinge/slide joints and mesh assets."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import trimesh

from artitwin_core.export._inertia import WOOD_DENSITY_KG_M3
from artitwin_core.export._model import Z_UP_FROM_Y_UP, Model, build_model, mean_rgba, write_meshes
from artitwin_core.geometry import matrix_to_quat_wxyz

_MJ_JOINT = {"revolute": "hinge", "prismatic": "slide"}


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.atleast_1d(values))


def model_to_mjcf(model: Model, damping: float) -> ET.Element:
    root = ET.Element("mujoco", model=model.name)
    for note in model.notes:
        root.append(ET.Comment(" " + note.replace("--", "-") + " "))
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(root, "option", gravity="0 0 -9.81")
    default = ET.SubElement(root, "default")
    vis = ET.SubElement(default, "default", {"class": "visual"})
    ET.SubElement(vis, "geom", type="mesh", contype="0", conaffinity="0", group="2", mass="0")
    col = ET.SubElement(default, "default", {"class": "collision"})
    ET.SubElement(col, "geom", type="mesh", group="3", mass="0")
    asset = ET.SubElement(root, "asset")
    for link in model.links:
        if link.visual_file is not None:
            # Fused surfaces are open; "shell" inertia keeps MuJoCo from rejecting their volume.
            ET.SubElement(asset, "mesh", name=f"{link.name}_visual", file=link.visual_file, inertia="shell")
        for k, rel in enumerate(link.collision_files):
            ET.SubElement(asset, "mesh", name=f"{link.name}_collision_{k:02d}", file=rel)
    world = ET.SubElement(root, "worldbody")
    children: dict[str, list] = {}
    for j in model.joints:
        children.setdefault(j.parent, []).append(j)
    links = {link.name: link for link in model.links}
    child_names = {j.child for j in model.joints}
    roots = [link.name for link in model.links if link.name not in child_names]

    def add_link(parent_el: ET.Element, name: str) -> None:
        link = links[name]
        if link.inertial is not None:
            i = link.inertial.inertia
            ET.SubElement(parent_el, "inertial", pos=_fmt(link.inertial.com), mass=f"{link.inertial.mass_kg:.9g}",
                          fullinertia=_fmt([i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]))
        if link.visual_file is not None:
            ET.SubElement(parent_el, "geom", {"class": "visual", "name": f"{name}_visual",
                                              "mesh": f"{name}_visual", "rgba": _fmt(mean_rgba(link.visual))})
        for k in range(len(link.collision_files)):
            ET.SubElement(parent_el, "geom", {"class": "collision", "name": f"{name}_collision_{k:02d}",
                                              "mesh": f"{name}_collision_{k:02d}"})
        for j in children.get(name, []):
            body = ET.SubElement(parent_el, "body", name=j.child, pos=_fmt(j.origin[:3, 3]),
                                 quat=_fmt(matrix_to_quat_wxyz(j.origin[:3, :3])))
            if j.kind in _MJ_JOINT:
                ET.SubElement(body, "joint", name=j.name, type=_MJ_JOINT[j.kind], axis=_fmt(j.axis),
                              range=_fmt([j.lower, j.upper]), limited="true", damping=f"{damping:.9g}")
            add_link(body, j.child)

    for name in roots:
        if name == "world":  # the URDF's fixed root is MuJoCo's worldbody
            add_link(world, name)
        else:
            add_link(ET.SubElement(world, "body", name=name), name)
    equality = [j for j in model.joints if j.mimic is not None]
    if equality:
        eq = ET.SubElement(root, "equality")
        for j in equality:
            # solref 0.004 s (2 x the default time step, MuJoCo's floor) is stiffer than the default
            # 0.02 s; the coupling is still soft: under gravity along the axis it lags by ~0.1-0.4 mm.
            ET.SubElement(eq, "joint", joint1=j.name, joint2=j.mimic[0], polycoef=_fmt([0, j.mimic[1], 0, 0, 0]),
                          solref="0.004 1")
    ET.indent(root)
    return root


def export_mjcf(
    out_dir: str | Path,
    base_mesh: trimesh.Trimesh,
    parts: list,
    *,
    name: str = "artitwin",
    base_collision: list[trimesh.Trimesh] | None = None,
    density_kg_m3: float = WOOD_DENSITY_KG_M3,
    damping: float = 0.5,
    sim_from_canonical: np.ndarray | None = Z_UP_FROM_Y_UP,
) -> Path:
    """Write ``<out_dir>/<name>.xml`` (MuJoCo MJCF) and its meshes under ``<out_dir>/meshes``.

    Same arguments and link frames as ``export_urdf``; joints are ``hinge``/``slide`` with
    ``range = joint.q_range`` and ``damping`` (N m s/rad or N s/m); a screw's slide follows its hinge
    through a joint equality constraint. Returns the MJCF path.
    """
    out = Path(out_dir)
    model = build_model(base_mesh, parts, name=name, base_collision=base_collision,
                        density_kg_m3=density_kg_m3, sim_from_canonical=sim_from_canonical)
    write_meshes(model, out)
    path = out / f"{model.name}.xml"
    ET.ElementTree(model_to_mjcf(model, damping)).write(path, encoding="utf-8", xml_declaration=True)
    return path
