"""Mass, centre of mass and inertia tensor of a link from its mesh and a density."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from artitwin_core._errors import InputError

WOOD_DENSITY_KG_M3 = 500.0


@dataclass(frozen=True)
class Inertial:
    """Rigid-body inertia of one link.

    Attributes:
        mass_kg: mass, kilograms (density x volume).
        volume_m3: the volume that gave the mass, cubic metres.
        com: ``[3]`` float64 centre of mass, metres, in the mesh's frame.
        inertia: ``[3, 3]`` float64 inertia tensor about ``com``, axes of the mesh's frame, kg m^2.
        source: which volume was used: ``"mesh"`` (watertight), ``"convex_hull"`` or ``"bounding_box"``.
    """

    mass_kg: float
    volume_m3: float
    com: np.ndarray
    inertia: np.ndarray
    source: str


def _outward(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy with outward normals (positive signed volume), so volumes of pieces add up."""
    m = mesh.copy()
    if m.volume < 0:
        m.invert()
    return m


def _props(mesh: trimesh.Trimesh, density: float, source: str) -> Inertial:
    m = _outward(mesh)
    m.density = float(density)
    return Inertial(
        mass_kg=float(m.mass), volume_m3=float(m.volume), com=np.asarray(m.center_mass, np.float64),
        inertia=np.asarray(m.moment_inertia, np.float64), source=source,
    )


def mesh_inertial(
    mesh: trimesh.Trimesh,
    density_kg_m3: float = WOOD_DENSITY_KG_M3,
    *,
    pieces: list[trimesh.Trimesh] | None = None,
    min_thickness_m: float = 0.01,
) -> Inertial:
    """Inertial properties of a solid of uniform density bounded by ``mesh`` (metres).

    Fused meshes are rarely closed (the back of a part is never seen), so the volume comes from the
    first of: the mesh itself if watertight; the union of its convex collision ``pieces`` if given
    (volumes add; CoACD pieces barely overlap, and they follow a hollow drawer far better than one
    hull); its convex hull (over-estimates concave parts such as a drawer box); its oriented
    bounding box with every side at least ``min_thickness_m`` (a part seen from one side only is a
    flat sheet with no volume).
    """
    if density_kg_m3 <= 0:
        raise InputError(f"mesh_inertial: density must be > 0 kg/m^3, got {density_kg_m3}.")
    if len(mesh.faces) == 0:
        raise InputError("mesh_inertial: the mesh has no faces; no volume to weigh.")
    min_volume = min_thickness_m**3
    if mesh.is_watertight and abs(mesh.volume) > min_volume:
        return _props(mesh, density_kg_m3, "mesh")
    if pieces:
        closed = [p for p in pieces if p.is_watertight and abs(p.volume) > 0]
        if closed and sum(abs(p.volume) for p in closed) > min_volume:
            return _props(trimesh.util.concatenate([_outward(p) for p in closed]), density_kg_m3, "convex_pieces")
    try:
        hull = mesh.convex_hull
        if hull.is_volume and hull.volume > min_volume * 10:
            return _props(hull, density_kg_m3, "convex_hull")
    except Exception:  # qhull on flat input
        pass
    obb = mesh.bounding_box_oriented
    extents = np.maximum(np.asarray(obb.primitive.extents, np.float64), min_thickness_m)
    box = trimesh.creation.box(extents=extents, transform=np.asarray(obb.primitive.transform))
    return _props(box, density_kg_m3, "bounding_box")
