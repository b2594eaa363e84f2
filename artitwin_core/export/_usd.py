"""USD writer: the URDF's model as one OpenUSD stage with a UsdPhysics articulation and the splats.

The stage (``<name>.usda``, z-up, metres, kilograms) holds the same links, joints and inertials as
``export_urdf`` (see ``_model``), laid out the way Isaac Sim's own assets are::

    /<name>                      Xform, default prim; its transform is ``sim_from_canonical``
      base                       RigidBodyAPI + ArticulationRootAPI (fixed to the world by root_joint)
        visual                   Mesh, vertex colours (displayColor)
        collision/piece_NN       Mesh, purpose guide, CollisionAPI + MeshCollisionAPI convexHull
        splats                   ParticleField3DGaussianSplat: the background and interior Gaussians
      <part>                     RigidBodyAPI + MassAPI, translated to the joint's pivot
        visual, collision/..., splats (the part's Gaussians)
      joints/root_joint          FixedJoint world -> base
      joints/<part>_joint        RevoluteJoint / PrismaticJoint / FixedJoint base -> part
    /physicsScene                PhysicsScene, gravity 9.81 m/s^2 down the stage's up axis

The axis change. Everything under the default prim is in the canonical frame (y up, gravity -y)
in its link frames; the default prim's one ``xformOp:transform`` is ``sim_from_canonical`` (by
default +90 degrees about x, canonical +y to the stage's +z), so the stage says ``upAxis = "Z"``
and no point, splat or spherical harmonic had to be rotated. With ``sim_from_canonical=None`` the
stage is the canonical frame and says ``upAxis = "Y"``.

Joints. UsdPhysics joints move along their frame's X axis, so each joint frame is rotated to put X
on the joint axis: ``localRot0`` / ``localRot1`` hold that rotation in the parent and child link
frames, ``localPos0`` is the pivot in the parent link, ``localPos1`` is zero (the child link sits at
the pivot). PhysX's convention holds: ``world_from_child = world_from_parent @ L0 @ J(q) @ inv(L1)``
with ``J(q)`` a rotation of ``q`` about X (revolute, limits in degrees) or a translation of ``q``
along X (prismatic, limits in metres). A passive ``DriveAPI`` (stiffness 0) carries the damping,
converted to USD's per-degree units for angular drives, and the effort as ``maxForce``.

Screw joints are the URDF's pair: ``<part>_slide`` (prismatic, base -> helper link) and
``<part>_joint`` (revolute, helper -> part) on one axis line. The coupling ``slide = pitch * q`` is
authored as ``PhysxMimicJointAPI:transX`` on the slide (``gearing = -pitch`` in metres per radian,
PhysX's ``slide + gearing * q = 0``), which Newton honours; PhysX documents that it does not yet
enforce mimic joints on linear DOFs, so in Isaac Sim drive the slide as well.

The splats of each link sit under it as ``UsdVol.ParticleField3DGaussianSplat`` (OpenUSD 25.11
and later), in the schema's own conventions: ``positions`` in the link frame (metres),
``orientations`` unit quaternions (USD's ``GfQuatf``: real part first in text, (w, x, y, z)),
``scales`` linear standard deviations (``exp(log_scale)``), ``opacities`` in [0, 1]
(``sigmoid(logit)``), and ``radiance:sphericalHarmonicsCoefficients`` the 3DGS coefficients as
trained (DC first, then degree 1..3 in the INRIA/gsplat basis order, colour = 0.5 + C0 * dc), K =
(degree + 1)^2 RGB triples per particle, particle-major. A link whose visual mesh and splats
would take more than ``payload_min_bytes`` keeps them in ``payloads/<link>.usdc``, a binary layer
loaded as a payload under ``<link>/looks``; physics (bodies, colliders, joints) stays in the text
stage.

Degenerate input: a visual mesh's non-finite vertices and zero-area faces are dropped (all of them
gone is an ``InputError`` naming the link); a collision piece with non-finite points or no volume is
dropped, and a link left without one collides as its visual mesh's oriented bounding box, at least
1 cm thick (``UsdResult.notes`` says so). Joint ranges and axes are checked by ``build_model``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdVol, Vt

from artitwin_core._errors import InputError
from artitwin_core.export._inertia import WOOD_DENSITY_KG_M3
from artitwin_core.export._model import (
    Z_UP_FROM_Y_UP,
    ExportPart,
    Link,
    Model,
    ModelJoint,
    _as_part,
    build_model,
    mean_rgba,
)
from artitwin_core.gaussians import LABEL_PART, GaussianParams
from artitwin_core.geometry import matrix_to_quat_wxyz

PAYLOAD_DIR = "payloads"
JOINTS_SCOPE = "joints"  # a sibling of the links: build_model keeps it out of the link names
ROOT_JOINT = "root_joint"
GRAVITY_M_S2 = 9.81
_MIN_THICKNESS_M = 0.01
_MIN_PIECE_VOLUME_M3 = 1e-9  # as _collision: below this engines reject a hull


@dataclass(frozen=True)
class UsdResult:
    """What ``export_usd`` wrote.

    Attributes:
        path: the stage, ``<out_dir>/<name>.usda``.
        payloads: ``{link: path}`` of the binary payload layers written (empty if none was needed).
        splat_counts: ``{link: number of Gaussians}`` placed under each link.
        notes: fallbacks taken (dropped faces or collision pieces, bounding-box colliders); a screw's
            coupling is stated on its slide joint prim instead.
    """

    path: Path
    payloads: dict[str, Path] = field(default_factory=dict)
    splat_counts: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def joint_frame_rotation(axis: np.ndarray) -> np.ndarray:
    """``[3, 3]`` a right-handed rotation whose first column is the unit ``axis [3]``."""
    x = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(x)))]  # the world axis least parallel to x
    y = np.cross(x, helper)
    y /= np.linalg.norm(y)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def up_axis_of(sim_from_canonical: np.ndarray | None) -> str:
    """``"Y"`` or ``"Z"``: where the canonical up (+y) lands in the stage; InputError otherwise."""
    if sim_from_canonical is None:
        return "Y"
    up = np.asarray(sim_from_canonical, np.float64)[:3, :3] @ np.array([0.0, 1.0, 0.0])
    for name, axis in (("Y", np.array([0.0, 1, 0])), ("Z", np.array([0.0, 0, 1]))):
        if np.allclose(up, axis, atol=1e-9):
            return name
    raise InputError(f"export_usd: sim_from_canonical sends the canonical up (+y) to {np.round(up, 6).tolist()}; "
                     "USD stages are y-up or z-up only, so it must map +y to +y or +z.")


def _gf_quatf(rot: np.ndarray) -> Gf.Quatf:
    w, x, y, z = matrix_to_quat_wxyz(rot)
    return Gf.Quatf(float(w), float(x), float(y), float(z))


def _gf_matrix(transform: np.ndarray) -> Gf.Matrix4d:
    # Gf matrices act on row vectors (p' = p M): the transpose of our column-vector matrices.
    return Gf.Matrix4d(np.asarray(transform, np.float64).T.tolist())


def _clean_visual(mesh: trimesh.Trimesh, link: str, notes: list[str]) -> trimesh.Trimesh:
    if len(mesh.faces) == 0:
        return mesh  # build_model says what an empty mesh means
    verts = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    ok = np.isfinite(verts).all(axis=1)[faces].all(axis=1)
    tri = np.where(np.isfinite(verts), verts, 0.0)[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    ok &= area > 1e-14
    if not ok.any():
        raise InputError(f"export_usd: link {link!r} has a degenerate visual mesh ({len(faces)} faces, all of them "
                         "zero-area or with non-finite vertices); refuse rather than write an empty Mesh.")
    if ok.all():
        return mesh
    notes.append(f"{link}: {int((~ok).sum())} of {len(faces)} visual faces were zero-area or non-finite and left out.")
    out = mesh.copy()
    out.update_faces(ok)
    out.remove_unreferenced_vertices()
    return out


def _clean_collision(pieces: list[trimesh.Trimesh], visual: trimesh.Trimesh, link: str,
                     notes: list[str]) -> list[trimesh.Trimesh]:
    kept = []
    for piece in pieces:
        v = np.asarray(piece.vertices, np.float64)
        if len(piece.faces) >= 4 and np.isfinite(v).all() and abs(piece.convex_hull.volume) > _MIN_PIECE_VOLUME_M3:
            kept.append(piece)
    if len(kept) < len(pieces):
        notes.append(f"{link}: {len(pieces) - len(kept)} collision piece(s) with no volume or non-finite points "
                     "were left out.")
    if kept:
        return kept
    obb = visual.bounding_box_oriented
    extents = np.maximum(np.asarray(obb.primitive.extents, np.float64), _MIN_THICKNESS_M)
    notes.append(f"{link}: no usable collision piece; it collides as its visual mesh's bounding box "
                 f"({np.round(extents, 3).tolist()} m).")
    return [trimesh.creation.box(extents=extents, transform=np.asarray(obb.primitive.transform))]


def _author_mesh(stage: Usd.Stage, path: str, mesh: trimesh.Trimesh) -> UsdGeom.Mesh:
    prim = UsdGeom.Mesh.Define(stage, path)
    verts = np.ascontiguousarray(mesh.vertices, np.float32)
    faces = np.asarray(mesh.faces, np.int32)
    prim.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(verts))
    prim.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    prim.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces.ravel())))
    prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    prim.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, verts.min(0))), Gf.Vec3f(*map(float, verts.max(0)))]))
    return prim


def _author_visual(stage: Usd.Stage, path: str, mesh: trimesh.Trimesh) -> None:
    prim = _author_mesh(stage, path, mesh)
    prim.CreateDoubleSidedAttr(True)  # fused surfaces are open: their backs are seen too
    colors = getattr(mesh.visual, "vertex_colors", None)
    pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray)
    if colors is not None and len(colors) == len(mesh.vertices):
        rgb = np.ascontiguousarray(np.asarray(colors, np.float32)[:, :3] / 255.0)
        pv.Set(Vt.Vec3fArray.FromNumpy(rgb))
        pv.SetInterpolation(UsdGeom.Tokens.vertex)
    else:
        pv.Set(Vt.Vec3fArray([Gf.Vec3f(*mean_rgba(mesh)[:3])]))
        pv.SetInterpolation(UsdGeom.Tokens.constant)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(x, np.float64)))


def _author_splats(stage: Usd.Stage, path: str, g: GaussianParams, origin: np.ndarray) -> None:
    """``g`` (canonical frame) as a ParticleField3DGaussianSplat in the frame of a link at ``origin [3]``."""
    prim = UsdVol.ParticleField3DGaussianSplat.Define(stage, path)
    p = prim.GetPrim()
    pos = np.ascontiguousarray(np.asarray(g.means, np.float64) - origin, np.float32)
    quat = np.asarray(g.quats_wxyz, np.float64)
    quat = quat / np.maximum(np.linalg.norm(quat, axis=1, keepdims=True), 1e-12)
    scales = np.exp(np.asarray(g.log_scales, np.float64)).astype(np.float32)
    sh = np.ascontiguousarray(np.asarray(g.sh, np.float32).reshape(-1, 3))
    UsdVol.ParticleFieldPositionAttributeAPI(p).CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(pos))
    # VtQuatfArray's memory layout is (x, y, z, w): imaginary part first, whatever its text shows.
    xyzw = np.ascontiguousarray(np.roll(quat, -1, axis=1), np.float32)
    UsdVol.ParticleFieldOrientationAttributeAPI(p).CreateOrientationsAttr(Vt.QuatfArray.FromNumpy(xyzw))
    UsdVol.ParticleFieldScaleAttributeAPI(p).CreateScalesAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(scales)))
    UsdVol.ParticleFieldOpacityAttributeAPI(p).CreateOpacitiesAttr(
        Vt.FloatArray.FromNumpy(_sigmoid(g.opacity_logits).astype(np.float32)))
    shapi = UsdVol.ParticleFieldSphericalHarmonicsAttributeAPI(p)
    shapi.CreateRadianceSphericalHarmonicsDegreeAttr(int(g.sh_degree))
    shapi.CreateRadianceSphericalHarmonicsCoefficientsAttr(Vt.Vec3fArray.FromNumpy(sh))
    reach = 3.0 * scales.max(axis=1, initial=0.0)[:, None]  # the kernel's 3-sigma support
    lo, hi = (pos - reach).min(0), (pos + reach).max(0)
    prim.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))


def _link_origins(model: Model) -> dict[str, np.ndarray]:
    """``{link: [4, 4] canonical_from_link}`` at q = 0, down the joint tree from the root link."""
    out = {model.links[0].name: np.eye(4)}
    pending = list(model.joints)
    while pending:
        ready = [j for j in pending if j.parent in out]
        if not ready:
            raise InputError(f"export_usd: joints {[j.name for j in pending]} do not hang from the base link.")
        for j in ready:
            out[j.child] = out[j.parent] @ j.origin
            pending.remove(j)
    return out


def _split_gaussians(g: GaussianParams | None, model: Model, part_links: list[str]) -> dict[str, GaussianParams]:
    """Background and interior to the base link, part k's Gaussians (label 2 + k) to ``part_links[k]``."""
    if g is None or g.num_gaussians == 0:
        return {}
    labels = np.asarray(g.labels)
    if labels.shape != (g.num_gaussians,):
        raise InputError(f"export_usd: Gaussian labels have shape {labels.shape}; expected ({g.num_gaussians},).")
    top = int(labels.max(initial=0)) - LABEL_PART
    if top >= len(part_links):
        raise InputError(f"export_usd: Gaussians are labelled for part {top} but only {len(part_links)} part(s) "
                         "were given; pass the joints the twin was optimised with.")
    groups = {model.links[0].name: labels < LABEL_PART}
    groups.update({name: labels == LABEL_PART + k for k, name in enumerate(part_links)})
    out = {}
    for name, keep in groups.items():
        if keep.any():
            out[name] = GaussianParams(np.asarray(g.means)[keep], np.asarray(g.quats_wxyz)[keep],
                                       np.asarray(g.log_scales)[keep], np.asarray(g.opacity_logits)[keep],
                                       np.asarray(g.sh)[keep], labels[keep])
    return out


def _looks_bytes(visual: trimesh.Trimesh | None, g: GaussianParams | None) -> int:
    n = 0 if visual is None else len(visual.vertices) * 24 + len(visual.faces) * 16
    return n + (0 if g is None else g.num_gaussians * (44 + 12 * g.sh.shape[1]))


def _author_link_body(stage: Usd.Stage, path: str, link: Link, origin: np.ndarray, pieces: list[trimesh.Trimesh],
                      is_root: bool) -> None:
    xf = UsdGeom.Xform.Define(stage, path)
    xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*map(float, origin[:3, 3])))
    w, x, y, z = matrix_to_quat_wxyz(origin[:3, :3])
    xf.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Quatd(float(w), float(x), float(y), float(z)))
    prim = xf.GetPrim()
    UsdPhysics.RigidBodyAPI.Apply(prim)
    if is_root:
        UsdPhysics.ArticulationRootAPI.Apply(prim)
    if link.inertial is not None:
        mass = UsdPhysics.MassAPI.Apply(prim)
        mass.CreateMassAttr(float(link.inertial.mass_kg))
        mass.CreateCenterOfMassAttr(Gf.Vec3f(*map(float, link.inertial.com)))
        evals, evecs = np.linalg.eigh(0.5 * (link.inertial.inertia + link.inertial.inertia.T))
        if np.linalg.det(evecs) < 0:
            evecs[:, 2] *= -1  # a proper rotation for principalAxes
        mass.CreateDiagonalInertiaAttr(Gf.Vec3f(*map(float, np.maximum(evals, 0.0))))
        mass.CreatePrincipalAxesAttr(_gf_quatf(evecs))
    if pieces:
        UsdGeom.Scope.Define(stage, f"{path}/collision")
    for i, piece in enumerate(pieces):
        mesh = _author_mesh(stage, f"{path}/collision/piece_{i:02d}", piece)
        mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)  # colliders are not drawn in a render
        UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
        UsdPhysics.MeshCollisionAPI.Apply(mesh.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.convexHull)


def _author_joint(stage: Usd.Stage, root: str, j: ModelJoint, *, effort: float, damping: float) -> None:
    path = f"{root}/{JOINTS_SCOPE}/{j.name}"
    frame = joint_frame_rotation(j.axis)
    if j.kind == "revolute":
        joint = UsdPhysics.RevoluteJoint.Define(stage, path)
        joint.CreateLowerLimitAttr(float(np.degrees(j.lower)))
        joint.CreateUpperLimitAttr(float(np.degrees(j.upper)))
    elif j.kind == "prismatic":
        joint = UsdPhysics.PrismaticJoint.Define(stage, path)
        joint.CreateLowerLimitAttr(float(j.lower))
        joint.CreateUpperLimitAttr(float(j.upper))
    else:
        joint = UsdPhysics.FixedJoint.Define(stage, path)
        frame = np.eye(3)
    if j.kind in ("revolute", "prismatic"):
        joint.CreateAxisAttr(UsdPhysics.Tokens.x)
        kind = "angular" if j.kind == "revolute" else "linear"
        drive = UsdPhysics.DriveAPI.Apply(joint.GetPrim(), kind)
        drive.CreateTypeAttr(UsdPhysics.Tokens.force)
        drive.CreateStiffnessAttr(0.0)
        # Angular drive damping is per degree in USD: N m s / rad * (pi / 180) = N m s / deg.
        drive.CreateDampingAttr(float(damping * (np.pi / 180.0 if kind == "angular" else 1.0)))
        drive.CreateMaxForceAttr(float(effort))
    joint.CreateBody0Rel().SetTargets([Sdf.Path(f"{root}/{j.parent}")])
    joint.CreateBody1Rel().SetTargets([Sdf.Path(f"{root}/{j.child}")])
    joint.CreateLocalPos0Attr(Gf.Vec3f(*map(float, j.origin[:3, 3])))
    joint.CreateLocalRot0Attr(_gf_quatf(j.origin[:3, :3] @ frame))
    joint.CreateLocalPos1Attr(Gf.Vec3f(0.0, 0.0, 0.0))
    joint.CreateLocalRot1Attr(_gf_quatf(frame))
    if j.mimic is not None:
        lead, gearing = j.mimic  # this joint = gearing * lead (metres per radian)
        prim = joint.GetPrim()
        prim.AddAppliedSchema("PhysxMimicJointAPI:transX")  # PhysX schema, not in usd-core: authored by name
        prim.CreateRelationship("physxMimicJoint:transX:referenceJoint", custom=False).SetTargets(
            [Sdf.Path(f"{root}/{JOINTS_SCOPE}/{lead}")])
        prim.CreateAttribute("physxMimicJoint:transX:referenceJointAxis", Sdf.ValueTypeNames.Token,
                             custom=False).Set("rotX")
        prim.CreateAttribute("physxMimicJoint:transX:gearing", Sdf.ValueTypeNames.Float, custom=False).Set(-gearing)
        prim.CreateAttribute("physxMimicJoint:transX:offset", Sdf.ValueTypeNames.Float, custom=False).Set(0.0)
        prim.SetDocumentation(f"Screw: keep {j.name} = {gearing:.9g} m/rad * {lead} (the revolute).")


def _author_root_joint(stage: Usd.Stage, root: str, base: str, world_from_base: np.ndarray) -> None:
    joint = UsdPhysics.FixedJoint.Define(stage, f"{root}/{JOINTS_SCOPE}/{ROOT_JOINT}")
    joint.CreateBody1Rel().SetTargets([Sdf.Path(f"{root}/{base}")])  # body0 unset: the world
    joint.CreateLocalPos0Attr(Gf.Vec3f(*map(float, world_from_base[:3, 3])))
    joint.CreateLocalRot0Attr(_gf_quatf(world_from_base[:3, :3]))
    joint.CreateLocalPos1Attr(Gf.Vec3f(0.0, 0.0, 0.0))
    joint.CreateLocalRot1Attr(Gf.Quatf(1.0, 0.0, 0.0, 0.0))


def export_usd(
    out_dir: str | Path,
    base_mesh: trimesh.Trimesh,
    parts: list,
    *,
    name: str = "artitwin",
    base_collision: list[trimesh.Trimesh] | None = None,
    gaussians: GaussianParams | None = None,
    density_kg_m3: float = WOOD_DENSITY_KG_M3,
    effort: float = 50.0,
    damping: float = 0.5,
    sim_from_canonical: np.ndarray | None = Z_UP_FROM_Y_UP,
    payload_min_bytes: int | None = 1 << 18,
) -> UsdResult:
    """Write ``<out_dir>/<name>.usda`` (and ``payloads/*.usdc`` for heavy links); see the module docstring.

    Args:
        out_dir: output folder (created).
        base_mesh, parts, base_collision, density_kg_m3: as ``export_urdf`` (canonical frame, metres,
            meshes at ``q = 0``); link and joint names are the URDF's.
        gaussians: the articulated twin's Gaussians (canonical frame, closed state); labels 0 and 1
            go under the base, ``2 + k`` under part k's link. ``None`` writes no splats.
        effort: each joint drive's ``maxForce``, N m (revolute) or N (prismatic).
        damping: each joint drive's damping, N m s/rad or N s/m (written per degree for revolute).
        sim_from_canonical: ``[4, 4]`` the default prim's transform; must send canonical +y to +y or
            +z (the stage's ``upAxis``). ``None``: the stage is the canonical frame, y-up.
        payload_min_bytes: a link whose visual mesh and splats take more than this (estimated bytes)
            gets them in a binary payload layer; ``None`` keeps everything in the ``.usda``.

    Returns:
        A ``UsdResult``: the stage path, payload paths, splats per link and the fallbacks taken.
    """
    up_axis = up_axis_of(sim_from_canonical)
    world_from_canonical = np.eye(4) if sim_from_canonical is None else np.asarray(sim_from_canonical, np.float64)
    notes: list[str] = []
    # Cleaned before the model is built, so the inertials come from the same surfaces.
    base_mesh = _clean_visual(base_mesh, "base", notes)
    if base_collision is not None:
        base_collision = _clean_collision(base_collision, base_mesh, "base", notes)
    clean = []
    for part in (_as_part(p) for p in parts):
        mesh = _clean_visual(part.mesh, str(part.name), notes)
        pieces = None if part.collision is None else _clean_collision(part.collision, mesh, str(part.name), notes)
        clean.append(ExportPart(part.name, part.joint, mesh, pieces))
    model = build_model(base_mesh, clean, name=name, base_collision=base_collision,
                        density_kg_m3=density_kg_m3, sim_from_canonical=None)
    part_links = [lk.name for lk in model.links[1:] if lk.visual is not None]
    if len(part_links) != len(parts):  # every part link has a mesh; helpers have none
        raise InputError(f"export_usd: {len(parts)} parts but {len(part_links)} part links were built.")
    splats = _split_gaussians(gaussians, model, part_links)
    origins = _link_origins(model)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{model.name}.usda"
    if path.exists():
        path.unlink()  # CreateNew refuses an existing file
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up_axis == "Z" else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    root = f"/{model.name}"
    top = UsdGeom.Xform.Define(stage, root)
    top.AddTransformOp().Set(_gf_matrix(world_from_canonical))
    stage.SetDefaultPrim(top.GetPrim())
    stage.GetRootLayer().documentation = (
        f"ArtiTwin articulated twin '{model.name}'. Metres, kilograms, up axis {up_axis}. Under {root} everything "
        f"is in ArtiTwin's canonical frame (y up); {root}'s transform maps it into the stage. Link frames sit at "
        "their joint pivots with canonical axes; joints move along their frame's X axis. Splats are "
        "UsdVol ParticleField3DGaussianSplat prims in their link's frame.")
    result_payloads: dict[str, Path] = {}
    base_name = model.links[0].name
    for link in model.links:
        lpath = f"{root}/{link.name}"
        visual = link.visual
        _author_link_body(stage, lpath, link, origins[link.name], link.collision, is_root=link.name == base_name)
        g = splats.get(link.name)
        if visual is None and g is None:
            continue
        offset = origins[link.name][:3, 3]  # link axes are the canonical axes: splats only shift
        if payload_min_bytes is not None and _looks_bytes(visual, g) > payload_min_bytes:
            rel = f"{PAYLOAD_DIR}/{link.name}.usdc"
            (out / PAYLOAD_DIR).mkdir(exist_ok=True)
            target = out / rel
            if target.exists():
                target.unlink()
            sub = Usd.Stage.CreateNew(str(target))
            UsdGeom.SetStageUpAxis(sub, UsdGeom.GetStageUpAxis(stage))
            UsdGeom.SetStageMetersPerUnit(sub, 1.0)
            looks = UsdGeom.Xform.Define(sub, "/looks")
            sub.SetDefaultPrim(looks.GetPrim())
            if visual is not None:
                _author_visual(sub, "/looks/visual", visual)
            if g is not None:
                _author_splats(sub, "/looks/splats", g, offset)
            sub.GetRootLayer().Save()
            holder = UsdGeom.Xform.Define(stage, f"{lpath}/looks")
            holder.GetPrim().GetPayloads().AddPayload(f"./{rel}")
            result_payloads[link.name] = target
        else:
            if visual is not None:
                _author_visual(stage, f"{lpath}/visual", visual)
            if g is not None:
                _author_splats(stage, f"{lpath}/splats", g, offset)
    UsdGeom.Scope.Define(stage, f"{root}/{JOINTS_SCOPE}")
    _author_root_joint(stage, root, base_name, world_from_canonical @ origins[base_name])
    for j in model.joints:
        _author_joint(stage, root, j, effort=effort, damping=damping)
    scene = UsdPhysics.Scene.Define(stage, "/physicsScene")
    scene.CreateGravityDirectionAttr(Gf.Vec3f(0.0, 0.0, -1.0) if up_axis == "Z" else Gf.Vec3f(0.0, -1.0, 0.0))
    scene.CreateGravityMagnitudeAttr(GRAVITY_M_S2)
    stage.GetRootLayer().Save()
    return UsdResult(path, result_payloads, {k: v.num_gaussians for k, v in splats.items()}, notes)
