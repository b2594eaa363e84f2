"""The USD stage checked: validated, parsed as a physics engine parses it, its joints read back and driven.

``check_usd`` runs two checks, reported like the URDF/MJCF simulators (``SimResult``):

- ``usd``: OpenUSD itself. The stage is opened with ``pxr``, run through every registered
  ``UsdValidation`` validator (USD's own validation; ``UsdUtils.ComplianceChecker`` is gone from
  recent releases), checked for its ``metersPerUnit`` / ``upAxis``, and parsed by
  ``UsdPhysics``' own parser (the one physics engines share) for one fixed-base
  articulation that holds every joint. Every joint is then read back (type, bodies, local frames,
  axis, limits) and the part links are placed by forward kinematics through those joints,
  ``world_from_child = world_from_parent @ L0 @ J(q) @ inv(L1)`` (PhysX's convention, see
  ``_usd``), from the world through ``root_joint``. Validation errors, a wrong articulation or
  limits other than ``q_range`` make the status ``"failed"`` with the reasons in the note.
- ``newton_usd``: the Newton physics engine (``pip install newton newton-usd-schemas``, optional)
  loads the stage with its own USD importer, and its forward kinematics place the links; its
  joint limits (converted from degrees by Newton) must be ``q_range``, and a screw's slide must
  come out coupled to its revolute (Newton reads ``PhysxMimicJointAPI``).

Both drive each part through its estimated ``q(t)`` and both limits, exactly as
``check_in_simulators`` does, and measure the error on the part's own points.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.export._model import Z_UP_FROM_Y_UP
from artitwin_core.export._simcheck import PoseFn, SimPart, SimResult, _part_errors
from artitwin_core.export._usd import ROOT_JOINT
from artitwin_core.geometry import invert_se3, quat_wxyz_to_matrix

USD_SIMULATORS = ("usd", "newton_usd")
_PACKAGE = {"usd": "pxr", "newton_usd": "newton"}


@dataclass(frozen=True)
class UsdJoint:
    """One joint as the stage states it (units converted to the twin's).

    Attributes:
        name: the joint prim's name (``<part>_joint``, ``<part>_slide``, ``root_joint``).
        kind: ``"revolute"``, ``"prismatic"`` or ``"fixed"``.
        parent: body0's prim name, or ``None`` for the world.
        child: body1's prim name.
        parent_from_joint: ``[4, 4]`` the joint frame in body0 (localPos0, localRot0).
        child_from_joint: ``[4, 4]`` the joint frame in body1 (localPos1, localRot1).
        axis: ``"X"``, ``"Y"`` or ``"Z"``: the joint frame axis it moves along.
        lower, upper: limits, radians (revolute; the stage says degrees) or metres.
    """

    name: str
    kind: str
    parent: str | None
    child: str
    parent_from_joint: np.ndarray
    child_from_joint: np.ndarray
    axis: str
    lower: float
    upper: float


def _frame(pos, rot) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = quat_wxyz_to_matrix(np.array([rot.GetReal(), *rot.GetImaginary()], np.float64))
    out[:3, 3] = np.asarray(pos, np.float64)
    return out


def read_usd_joints(stage) -> list[UsdJoint]:
    """Every UsdPhysics joint of an open ``Usd.Stage``, in stage order."""
    from pxr import Usd, UsdPhysics

    out = []
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):
        if not prim.IsA(UsdPhysics.Joint):
            continue
        j = UsdPhysics.Joint(prim)
        b0, b1 = j.GetBody0Rel().GetTargets(), j.GetBody1Rel().GetTargets()
        if not b1:
            raise InputError(f"{prim.GetPath()}: joint has no body1.")
        lower, upper, axis = 0.0, 0.0, "X"
        if prim.IsA(UsdPhysics.RevoluteJoint):
            kind, typed = "revolute", UsdPhysics.RevoluteJoint(prim)
            lower, upper = np.radians(typed.GetLowerLimitAttr().Get()), np.radians(typed.GetUpperLimitAttr().Get())
            axis = str(typed.GetAxisAttr().Get())
        elif prim.IsA(UsdPhysics.PrismaticJoint):
            kind, typed = "prismatic", UsdPhysics.PrismaticJoint(prim)
            lower, upper = typed.GetLowerLimitAttr().Get(), typed.GetUpperLimitAttr().Get()
            axis = str(typed.GetAxisAttr().Get())
        elif prim.IsA(UsdPhysics.FixedJoint):
            kind = "fixed"
        else:
            raise InputError(f"{prim.GetPath()}: joint type {prim.GetTypeName()} is not one ArtiTwin writes.")
        out.append(UsdJoint(
            prim.GetName(), kind, b0[0].name if b0 else None, b1[0].name,
            _frame(j.GetLocalPos0Attr().Get(), j.GetLocalRot0Attr().Get()),
            _frame(j.GetLocalPos1Attr().Get(), j.GetLocalRot1Attr().Get()),
            axis, float(lower), float(upper)))
    return out


def _joint_motion(joint: UsdJoint, q: float) -> np.ndarray:
    """``J(q) [4, 4]``: the child's joint frame in the parent's joint frame."""
    out = np.eye(4)
    if joint.kind == "fixed":
        return out
    k = "XYZ".index(joint.axis)
    if joint.kind == "prismatic":
        out[k, 3] = q
        return out
    c, s = np.cos(q), np.sin(q)
    i, j = [(1, 2), (2, 0), (0, 1)][k]
    out[i, i], out[i, j], out[j, i], out[j, j] = c, -s, s, c
    return out


def usd_link_poses(joints: list[UsdJoint], states: dict[str, float],
                   roots: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """``{link: [4, 4] world_from_link}`` by forward kinematics through ``joints`` from the world,
    or from ``roots`` (``{link: world_from_link}``, e.g. the authored poses) for links no joint moves."""
    children = {j.child for j in joints}
    poses = {name: pose for name, pose in (roots or {}).items() if name not in children}
    pending = list(joints)
    while pending:
        ready = [j for j in pending if j.parent is None or j.parent in poses]
        if not ready:
            raise InputError(f"USD joints {[j.name for j in pending]} do not connect to the world.")
        for j in ready:
            parent = np.eye(4) if j.parent is None else poses[j.parent]
            poses[j.child] = parent @ j.parent_from_joint @ _joint_motion(j, states.get(j.name, 0.0)) @ invert_se3(
                j.child_from_joint)
            pending.remove(j)
    return poses


def authored_poses(stage) -> dict[str, np.ndarray]:
    """``{name: [4, 4] world_from_prim}`` of the default prim's children, as their xforms place them."""
    from pxr import UsdGeom

    cache = UsdGeom.XformCache()
    root = stage.GetDefaultPrim()
    if not root:
        return {}
    # Gf matrices act on row vectors: transpose to our column-vector convention.
    return {c.GetName(): np.asarray(cache.GetLocalToWorldTransform(c), np.float64).T
            for c in root.GetChildren() if c.IsA(UsdGeom.Xformable)}


def parse_physics(stage) -> dict:
    """``{UsdPhysics.ObjectType: (paths, descriptions)}``: the stage as UsdPhysics' shared parser reads it."""
    from pxr import UsdPhysics

    # Renamed after OpenUSD 26.3 (the oldest release this project takes); the old name still works, deprecated.
    load = getattr(UsdPhysics, "UsdPhysicsLoadStageFromPrimRange", None) or UsdPhysics.LoadUsdPhysicsFromRange
    return load(stage, ["/"])


def validate_usd(stage) -> list[str]:
    """Problems with an open stage: validator errors, missing units, an articulation that is not one
    fixed-base tree with every joint in it, links whose authored pose disagrees with their joints."""
    from pxr import UsdGeom, UsdPhysics, UsdValidation

    problems = []
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    for err in UsdValidation.ValidationContext(validators).Validate(stage):
        if err.GetType() == UsdValidation.ValidationErrorType.Error:
            problems.append(f"{err.GetIdentifier()}: {err.GetMessage()}")
    if not stage.HasAuthoredMetadata("metersPerUnit") or UsdGeom.GetStageMetersPerUnit(stage) != 1.0:
        problems.append("the stage does not state metersPerUnit = 1")
    if not stage.HasAuthoredMetadata("upAxis"):
        problems.append("the stage does not state its upAxis")
    parsed = parse_physics(stage)
    arts = parsed.get(UsdPhysics.ObjectType.Articulation, ([], []))[1]
    joint_paths = {str(p) for kind, (paths, _) in parsed.items() if "Joint" in str(kind) for p in paths}
    if len(arts) != 1:
        problems.append(f"UsdPhysics parses {len(arts)} articulations; expected 1")
    else:
        art = arts[0]
        if not any(p.isEmpty for p in art.articulatedBodies):
            problems.append("the articulation is not fixed to the world (no joint to the world)")
        missing = joint_paths - {str(p) for p in art.articulatedJoints}
        if missing:
            problems.append(f"joints outside the articulation: {sorted(missing)}")
    authored = authored_poses(stage)
    rest = usd_link_poses(read_usd_joints(stage), {}, authored)
    for name, pose in rest.items():
        if name not in authored:
            problems.append(f"joint body {name!r} is not a child of the default prim")
            continue
        err = np.abs(authored[name] - pose).max()
        if err > 1e-5:  # float32 joint frames against double xforms: ~1e-7 in practice
            problems.append(f"{name}: authored pose is {err:.2g} off its joints' pose at q = 0")
    return problems


def _check_limits(lookup, parts: list[SimPart], problems: list[str], atol: float = 1e-5) -> None:
    """``lookup(joint name) -> (lower, upper)`` in SI units or None; compare with each part's q_range."""
    for sp in parts:
        j = sp.joint
        if j.joint_type == "fixed":
            continue
        got = lookup(f"{sp.link}_joint")
        want = np.asarray(j.q_range, np.float64)
        if got is None:
            problems.append(f"{sp.link}_joint: not found")
        elif not np.allclose(got, want, atol=atol):
            problems.append(f"{sp.link}_joint: limits {np.round(got, 6).tolist()} but q_range {want.tolist()}")


@contextmanager
def _usd(path: Path, parts: list[SimPart], problems: list[str]) -> Iterator[PoseFn]:
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise InputError(f"{path}: OpenUSD could not open the stage.")
    problems.extend(validate_usd(stage))
    joints = read_usd_joints(stage)
    by_name = {j.name: j for j in joints}
    _check_limits(lambda n: (by_name[n].lower, by_name[n].upper) if n in by_name else None, parts, problems)
    if not any(j.name == ROOT_JOINT and j.parent is None for j in joints):
        problems.append(f"no {ROOT_JOINT} from the world to the base")

    authored = authored_poses(stage)

    def pose(link: str, states: dict[str, float]) -> np.ndarray:
        return usd_link_poses(joints, states, authored)[link]

    yield pose


@contextmanager
def _newton(path: Path, parts: list[SimPart], problems: list[str]) -> Iterator[PoseFn]:
    import warp as wp

    wp.config.log_level = 40  # errors only, set before newton initialises warp: no banner, no per-kernel lines
    import newton
    builder = newton.ModelBuilder()
    # Keep the stage's own up axis and world: the poses are compared in the stage's frame.
    builder.add_usd(str(path), apply_up_axis_from_stage=True)
    model = builder.finalize(device="cpu")
    joint_index = {label.rsplit("/", 1)[-1]: i for i, label in enumerate(model.joint_label)}
    body_index = {label.rsplit("/", 1)[-1]: i for i, label in enumerate(model.body_label)}
    q_start = model.joint_q_start.numpy()
    lower, upper = model.joint_limit_lower.numpy(), model.joint_limit_upper.numpy()
    qd_start = model.joint_qd_start.numpy()

    def limits(name: str):
        i = joint_index.get(name)
        return None if i is None else (float(lower[qd_start[i]]), float(upper[qd_start[i]]))

    _check_limits(limits, parts, problems)
    reference, coeffs = model.joint_mimic_joint.numpy(), model.joint_mimic_coeffs.numpy()  # q = c0 + c1 * q[ref]
    mimics = {(i, int(r)): float(coeffs[i][1]) for i, r in enumerate(reference) if r >= 0}
    for sp in parts:  # a screw's slide must follow its revolute: slide = pitch * q
        if sp.joint.joint_type == "screw":
            key = (joint_index.get(f"{sp.link}_slide", -1), joint_index.get(f"{sp.link}_joint", -1))
            if key not in mimics or abs(mimics[key] - sp.joint.pitch) > 1e-6:
                problems.append(f"{sp.link}_slide: Newton has no mimic coupling slide = {sp.joint.pitch:.6g} * q")
    state = model.state()

    def pose(link: str, states: dict[str, float]) -> np.ndarray:
        q = model.joint_q.numpy()
        q[:] = 0.0
        for name, value in states.items():
            q[q_start[joint_index[name]]] = value
        newton.eval_fk(model, wp.array(q, dtype=wp.float32, device="cpu"), model.joint_qd, state)
        px, py, pz, qx, qy, qz, qw = (float(v) for v in state.body_q.numpy()[body_index[link]])
        out = np.eye(4)
        out[:3, :3] = quat_wxyz_to_matrix(np.array([qw, qx, qy, qz]))
        out[:3, 3] = (px, py, pz)
        return out

    yield pose


_OPEN = {"usd": _usd, "newton_usd": _newton}


def check_usd(
    usd_path: str | Path | None,
    parts: list[SimPart],
    *,
    sim_from_canonical: np.ndarray | None = Z_UP_FROM_Y_UP,
    simulators: tuple[str, ...] = USD_SIMULATORS,
    tolerance_m: float = 5e-3,
) -> list[SimResult]:
    """Validate the stage ``export_usd`` wrote and compare its part poses with the twin's (see module).

    Args:
        usd_path: the ``.usda``; ``None`` skips every check with a note.
        parts: one ``SimPart`` per part (link name, the twin's joint with its ``q(t)``, link-frame points).
        sim_from_canonical: ``[4, 4]`` what ``export_usd`` was given (the default prim's transform).
        simulators: a subset of ``USD_SIMULATORS``.
        tolerance_m: pose errors above this make the status ``"mismatch"``.

    Returns:
        One ``SimResult`` per requested check, in order; problems found on the way make it ``"failed"``.
    """
    unknown = [s for s in simulators if s not in USD_SIMULATORS]
    if unknown:
        raise InputError(f"check_usd: unknown check(s) {unknown}; choose from {USD_SIMULATORS}.")
    canon_from_sim = np.eye(4) if sim_from_canonical is None else invert_se3(np.asarray(sim_from_canonical, np.float64))
    results = []
    for sim in simulators:
        if usd_path is None:
            results.append(SimResult(sim, "skipped", note="no USD stage was exported"))
            continue
        if importlib.util.find_spec(_PACKAGE[sim]) is None:
            hint = "pip install newton newton-usd-schemas" if sim == "newton_usd" else "pip install usd-core"
            results.append(SimResult(sim, "skipped", note=f"package {_PACKAGE[sim]!r} is not installed ({hint})"))
            continue
        problems: list[str] = []
        try:
            with _OPEN[sim](Path(usd_path), parts, problems) as pose:
                errors, count = _part_errors(pose, parts, canon_from_sim)
        except Exception as exc:  # a loader's error is the finding, reported rather than raised
            results.append(SimResult(sim, "failed", note=f"{type(exc).__name__}: {exc}"[:500]))
            continue
        worst = max(errors.values(), default=0.0)
        status = "failed" if problems else ("ok" if worst <= tolerance_m else "mismatch")
        results.append(SimResult(sim, status, worst, errors, count, note="; ".join(problems)[:2000]))
    return results
