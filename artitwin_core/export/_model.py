"""The articulated model both writers share: links with meshes in their own frames, joints, inertials.

Link frames. The base link's frame is the canonical frame (the static recording's world frame,
gravity along -y). Each part's link frame sits at its joint's ``pivot`` with the canonical axes
(no rotation), so a joint origin is a pure translation (``parent_from_child`` at ``q = 0``), the
joint axis in the joint frame is the canonical axis, and a part vertex ``x`` (canonical, closed)
becomes ``x - pivot``. A fixed root link ``world`` above the base applies ``sim_from_canonical``
(by default y-up to z-up) so that simulators' gravity (-z) points down.

Screw joints (no URDF or MJCF screw type) become a prismatic joint ``<part>_slide`` into a massless
helper link ``<part>_slider``, then the revolute ``<part>_joint``: both along the same axis line, so
they commute and together reproduce the screw exactly when ``slide = pitch * q``. URDF states that
coupling as ``<mimic>`` (honoured by yourdfpy; PyBullet and MuJoCo's URDF importer leave it to the
user); the MJCF writer enforces it with a joint equality constraint.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from artitwin_core._errors import InputError
from artitwin_core.export._collision import convex_decomposition
from artitwin_core.export._inertia import WOOD_DENSITY_KG_M3, Inertial, mesh_inertial
from artitwin_core.export._names import sanitize_name, unique_names
from artitwin_core.joints import Joint

# Canonical frame (ARKit: y up) to simulator frame (z up): +90 degrees about x sends +y to +z.
Z_UP_FROM_Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
MESH_DIR = "meshes"
_HELPER_MASS_KG = 1e-3  # the screw's helper link: engines reject zero mass on a moving body


@dataclass(frozen=True)
class ExportPart:
    """One articulated part to export.

    Attributes:
        name: any text; sanitised into link, joint and file names.
        joint: the part's ``Joint`` (canonical frame).
        mesh: the part's surface at ``q = 0``, canonical frame, metres (``fuse_part_mesh``).
        collision: convex pieces in the same frame, or ``None`` to decompose ``mesh`` here.
    """

    name: str
    joint: Joint
    mesh: trimesh.Trimesh
    collision: list[trimesh.Trimesh] | None = None


@dataclass
class Link:
    name: str
    visual: trimesh.Trimesh | None  # link frame
    collision: list[trimesh.Trimesh]  # link frame
    inertial: Inertial | None  # link frame; None = static link without mass
    visual_file: str | None = None  # relative to the model file
    collision_files: list[str] = field(default_factory=list)


@dataclass
class ModelJoint:
    name: str
    kind: str  # "revolute" | "prismatic" | "fixed"
    parent: str
    child: str
    origin: np.ndarray  # [4, 4] parent_from_child at q = 0
    axis: np.ndarray  # [3] unit, in the joint (child) frame
    lower: float
    upper: float
    mimic: tuple[str, float] | None = None  # (joint, multiplier): this = multiplier * that


@dataclass
class Model:
    name: str
    links: list[Link]
    joints: list[ModelJoint]
    notes: list[str]


def _as_part(p) -> ExportPart:
    if isinstance(p, ExportPart):
        return p
    if isinstance(p, (tuple, list)) and len(p) in (3, 4):
        return ExportPart(*p)
    raise InputError("export: each part is an ExportPart or a (name, Joint, mesh[, collision_parts]) tuple.")


def _shifted(mesh: trimesh.Trimesh, offset: np.ndarray) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_translation(-np.asarray(offset, np.float64))
    return out


def _shift_inertial(inertial: Inertial, offset: np.ndarray) -> Inertial:
    return Inertial(inertial.mass_kg, inertial.volume_m3, inertial.com - offset, inertial.inertia, inertial.source)


def build_model(
    base_mesh: trimesh.Trimesh,
    parts: list,
    *,
    name: str = "artitwin",
    base_collision: list[trimesh.Trimesh] | None = None,
    density_kg_m3: float = WOOD_DENSITY_KG_M3,
    sim_from_canonical: np.ndarray | None = Z_UP_FROM_Y_UP,
) -> Model:
    """Links and joints for ``export_urdf`` / ``export_mjcf`` (see the module docstring)."""
    parts = [_as_part(p) for p in parts]
    if len(base_mesh.faces) == 0:
        raise InputError("export: the base mesh has no faces; fuse the static recording first.")
    # "joints" is the USD stage's scope beside the links (export_usd).
    part_names = unique_names([p.name for p in parts], reserved=("world", "base", "joints"))
    notes: list[str] = []
    links = [Link("world", None, [], None)] if sim_from_canonical is not None else []
    base_col = base_collision if base_collision is not None else convex_decomposition(base_mesh, max_parts=32)
    # The base is fixed: it needs no mass (a fused room has no meaningful volume anyway).
    links.append(Link("base", base_mesh, list(base_col), None))
    joints: list[ModelJoint] = []
    if sim_from_canonical is not None:
        joints.append(ModelJoint("world_to_base", "fixed", "world", "base", np.asarray(sim_from_canonical, np.float64),
                                 np.array([1.0, 0, 0]), 0.0, 0.0))
    for part, pname in zip(parts, part_names, strict=True):
        j = part.joint
        if len(part.mesh.faces) == 0:
            raise InputError(f"export: part {part.name!r} has an empty mesh; nothing was fused for it.")
        axis = np.asarray(j.axis, np.float64)
        norm = np.linalg.norm(axis)
        if not np.isfinite(norm) or norm < 1e-9:
            raise InputError(f"export: part {part.name!r} has a zero or non-finite joint axis {j.axis}.")
        axis = axis / norm
        pivot = np.asarray(j.pivot, np.float64)
        lo, hi = (float(v) for v in np.asarray(j.q_range, np.float64))
        if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
            raise InputError(f"export: part {part.name!r} has an invalid q_range {j.q_range}; need q_min <= q_max.")
        collision = part.collision if part.collision is not None else convex_decomposition(part.mesh)
        inertial = mesh_inertial(part.mesh, density_kg_m3, pieces=collision)
        links.append(Link(pname, _shifted(part.mesh, pivot), [_shifted(c, pivot) for c in collision],
                          _shift_inertial(inertial, pivot)))
        origin = np.eye(4)
        origin[:3, 3] = pivot
        if j.joint_type in ("revolute", "prismatic"):
            joints.append(ModelJoint(f"{pname}_joint", j.joint_type, "base", pname, origin, axis, lo, hi))
        elif j.joint_type == "fixed":
            joints.append(ModelJoint(f"{pname}_joint", "fixed", "base", pname, origin, axis, 0.0, 0.0))
        elif j.joint_type == "screw":
            helper = f"{pname}_slider"
            taken = {n.lower() for n in part_names} | {link.name.lower() for link in links}
            while helper.lower() in taken:  # a part may already be called "<name>_slider"
                helper += "_x"
            eye = np.eye(3) * 1e-6
            links.insert(-1, Link(helper, None, [], Inertial(_HELPER_MASS_KG, 0.0, np.zeros(3), eye, "helper")))
            s_lo, s_hi = sorted((j.pitch * lo, j.pitch * hi))
            joints.append(ModelJoint(f"{pname}_slide", "prismatic", "base", helper, origin, axis, s_lo, s_hi,
                                     mimic=(f"{pname}_joint", float(j.pitch))))
            joints.append(ModelJoint(f"{pname}_joint", "revolute", helper, pname, np.eye(4), axis, lo, hi))
            notes.append(f"{pname}: screw joint exported as {pname}_slide (prismatic) + {pname}_joint (revolute); "
                         f"keep {pname}_slide = {j.pitch:.6g} * {pname}_joint.")
        else:
            raise InputError(f"export: part {part.name!r} has unknown joint type {j.joint_type!r}.")
    return Model(sanitize_name(name, "artitwin"), links, joints, notes)


def write_meshes(model: Model, out_dir: Path) -> None:
    """Write each link's meshes as OBJ under ``out_dir/meshes`` and record their relative paths."""
    mesh_dir = out_dir / MESH_DIR
    mesh_dir.mkdir(parents=True, exist_ok=True)
    for link in model.links:
        if link.visual is not None:
            link.visual_file = f"{MESH_DIR}/{link.name}_visual.obj"
            link.visual.export(out_dir / link.visual_file, file_type="obj", include_color=False,
                               include_normals=False, include_texture=False)
        link.collision_files = []
        for i, piece in enumerate(link.collision):
            rel = f"{MESH_DIR}/{link.name}_collision_{i:02d}.obj"
            piece.export(out_dir / rel, file_type="obj", include_normals=False, include_texture=False)
            link.collision_files.append(rel)


def mean_rgba(mesh: trimesh.Trimesh | None) -> tuple[float, float, float, float]:
    """A flat colour for engines that ignore vertex colours (the mean of the fused colours)."""
    colors = getattr(getattr(mesh, "visual", None), "vertex_colors", None) if mesh is not None else None
    if colors is None or len(colors) == 0:
        return (0.7, 0.7, 0.7, 1.0)
    c = np.asarray(colors, np.float64)[:, :3].mean(0) / 255.0
    return (float(c[0]), float(c[1]), float(c[2]), 1.0)
