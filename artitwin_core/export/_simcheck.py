"""The export checked for real: load the files in each simulator, drive the joints, compare poses.

Each simulator loads the exported model (yourdfpy, PyBullet and MuJoCo read the URDF; MuJoCo also
reads the MJCF), sets every part's joint to each state of its estimated ``q(t)`` (and both
limits) and reads the part link's world pose. The twin says where that link should be: the
joint's motion at ``q`` (``joint_transforms``) applied to the closed-state link frame (at the
pivot, canonical axes; see ``_model``). The error is the largest distance between the two poses
applied to the part's own points (its mesh vertices), so a rotation error counts at the part's far
edge, not only at the pivot. States are set directly (no dynamics): this checks the files' frames,
axes, signs and couplings, not a controller.

A simulator whose Python package is missing is skipped with a note; a model that fails to load is
reported as failed with the simulator's message, never raised.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.export._model import Z_UP_FROM_Y_UP
from artitwin_core.geometry import invert_se3, quat_wxyz_to_matrix
from artitwin_core.joints import Joint, joint_transforms

SimStatus = Literal["ok", "mismatch", "failed", "skipped"]
SIMULATORS = ("yourdfpy", "pybullet", "mujoco_urdf", "mujoco_mjcf")
_PACKAGE = {"yourdfpy": "yourdfpy", "pybullet": "pybullet", "mujoco_urdf": "mujoco", "mujoco_mjcf": "mujoco"}

# pose(link, {joint name: state}) -> [4, 4] link pose in the simulator's world
PoseFn = Callable[[str, dict[str, float]], np.ndarray]


@dataclass(frozen=True)
class SimPart:
    """One exported part as the check sees it.

    Attributes:
        link: the part's link (MuJoCo body) name in the files; its joint is ``<link>_joint`` and a
            screw's slide is ``<link>_slide`` (as ``export_urdf`` / ``export_mjcf`` name them).
        joint: the twin's joint (canonical frame) with the states ``q [T]`` to drive it through.
        points: ``[N, 3]`` metres, points of the part in its link frame (mesh vertices minus the
            pivot); ``None`` = the link origin alone.
    """

    link: str
    joint: Joint
    points: np.ndarray | None = None


@dataclass(frozen=True)
class SimResult:
    """What one simulator did with the model.

    Attributes:
        simulator: one of ``SIMULATORS``.
        status: ``"ok"`` (loaded, every error within tolerance), ``"mismatch"`` (loaded, some error
            above it), ``"failed"`` (did not load or run) or ``"skipped"`` (package or file missing).
        max_error_m: largest point error over all parts and states, metres (NaN unless it ran).
        part_errors_m: per part link name, its largest error, metres.
        states: joint states set, summed over parts.
        note: why it was skipped or failed; empty otherwise.
    """

    simulator: str
    status: SimStatus
    max_error_m: float = float("nan")
    part_errors_m: dict[str, float] = field(default_factory=dict)
    states: int = 0
    note: str = ""

    def to_json(self) -> dict:
        """JSON-ready summary, errors in millimetres (``None`` when it did not run)."""
        return {
            "simulator": self.simulator,
            "status": self.status,
            "max_error_mm": float(self.max_error_m * 1e3) if np.isfinite(self.max_error_m) else None,
            "part_max_error_mm": {k: float(v * 1e3) for k, v in self.part_errors_m.items()},
            "states": self.states,
            "note": self.note,
        }


def _states(joint: Joint) -> np.ndarray:
    """The estimated ``q(t)`` plus both limits (finite values only); one state for a fixed joint."""
    if joint.joint_type == "fixed":
        return np.zeros(1)
    q = np.concatenate([np.asarray(joint.q, np.float64).ravel(), np.asarray(joint.q_range, np.float64).ravel()])
    return q[np.isfinite(q)]


def _part_errors(pose: PoseFn, parts: list[SimPart], canon_from_sim: np.ndarray) -> tuple[dict[str, float], int]:
    errors: dict[str, float] = {}
    count = 0
    for sp in parts:
        j = sp.joint
        pivot = np.asarray(j.pivot, np.float64)
        pts = np.zeros((1, 3)) if sp.points is None or len(sp.points) == 0 else np.asarray(sp.points, np.float64)
        qs = _states(j)
        motions = joint_transforms(j.joint_type, j.axis, pivot, qs, j.pitch)
        worst = 0.0
        for q, motion in zip(qs, motions, strict=True):
            states = {} if j.joint_type == "fixed" else {f"{sp.link}_joint": float(q)}
            if j.joint_type == "screw":
                states[f"{sp.link}_slide"] = float(j.pitch * q)
            sim = canon_from_sim @ pose(sp.link, states)
            got = pts @ sim[:3, :3].T + sim[:3, 3]
            want = (pts + pivot) @ motion[:3, :3].T + motion[:3, 3]  # motion(q) @ translate(pivot)
            worst = max(worst, float(np.linalg.norm(got - want, axis=1).max()))
            count += 1
        errors[sp.link] = worst
    return errors, count


@contextmanager
def _yourdfpy(urdf: Path) -> Iterator[PoseFn]:
    import yourdfpy

    robot = yourdfpy.URDF.load(str(urdf), load_meshes=True, build_collision_scene_graph=True)
    actuated = set(robot.actuated_joint_names)

    def pose(link: str, states: dict[str, float]) -> np.ndarray:
        # A screw's slide is a <mimic> of its hinge: yourdfpy derives it, so only set actuated joints.
        robot.update_cfg({n: v for n, v in states.items() if n in actuated})
        return np.asarray(robot.get_transform(frame_to=link, frame_from=robot.base_link), np.float64)

    yield pose


@contextmanager
def _pybullet(urdf: Path) -> Iterator[PoseFn]:
    import pybullet

    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf), useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE,
                                 physicsClientId=client)
        joints, links = {}, {}
        for i in range(pybullet.getNumJoints(body, physicsClientId=client)):
            info = pybullet.getJointInfo(body, i, physicsClientId=client)
            joints[info[1].decode()] = i
            links[info[12].decode()] = i  # a link's index is that of the joint above it

        def pose(link: str, states: dict[str, float]) -> np.ndarray:
            for name, value in states.items():  # PyBullet ignores <mimic>: screws set their slide too
                pybullet.resetJointState(body, joints[name], value, physicsClientId=client)
            st = pybullet.getLinkState(body, links[link], computeForwardKinematics=True, physicsClientId=client)
            x, y, z, w = st[5]  # the URDF link frame (4, 5), not the inertial frame (0, 1)
            out = np.eye(4)
            out[:3, :3] = quat_wxyz_to_matrix(np.array([w, x, y, z]))
            out[:3, 3] = st[4]
            return out

        yield pose
    finally:
        pybullet.disconnect(client)


@contextmanager
def _mujoco(path: Path) -> Iterator[PoseFn]:
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)

    def pose(link: str, states: dict[str, float]) -> np.ndarray:
        data.qpos[:] = model.qpos0
        for name, value in states.items():  # qpos set directly: the MJCF's screw equality is not solved here
            data.qpos[model.jnt_qposadr[model.joint(name).id]] = value
        mujoco.mj_kinematics(model, data)
        b = model.body(link).id
        out = np.eye(4)
        out[:3, :3] = data.xmat[b].reshape(3, 3)
        out[:3, 3] = data.xpos[b]
        return out

    yield pose


_OPEN = {"yourdfpy": _yourdfpy, "pybullet": _pybullet, "mujoco_urdf": _mujoco, "mujoco_mjcf": _mujoco}


def check_in_simulators(
    urdf_path: str | Path | None,
    mjcf_path: str | Path | None,
    parts: list[SimPart],
    *,
    sim_from_canonical: np.ndarray | None = Z_UP_FROM_Y_UP,
    simulators: tuple[str, ...] = SIMULATORS,
    tolerance_m: float = 5e-3,
) -> list[SimResult]:
    """Load the exported model in each simulator and compare its part poses with the twin's.

    Args:
        urdf_path, mjcf_path: the files ``export_urdf`` / ``export_mjcf`` wrote (meshes beside
            them); ``None`` skips the simulators that read that format.
        parts: one ``SimPart`` per exported part (link name, the twin's joint, link-frame points).
        sim_from_canonical: ``[4, 4]`` the transform the export put above the base (its
            ``sim_from_canonical``; ``None`` if the base is the root).
        simulators: a subset of ``SIMULATORS``.
        tolerance_m: errors above this (metres; the issue's 5 mm) make the status ``"mismatch"``.

    Returns:
        One ``SimResult`` per requested simulator, in order.
    """
    unknown = [s for s in simulators if s not in SIMULATORS]
    if unknown:
        raise InputError(f"check_in_simulators: unknown simulator(s) {unknown}; choose from {SIMULATORS}.")
    canon_from_sim = np.eye(4) if sim_from_canonical is None else invert_se3(np.asarray(sim_from_canonical, np.float64))
    results = []
    for sim in simulators:
        path = mjcf_path if sim == "mujoco_mjcf" else urdf_path
        if path is None:
            fmt = "MJCF" if sim == "mujoco_mjcf" else "URDF"
            results.append(SimResult(sim, "skipped", note=f"no {fmt} was exported"))
            continue
        if importlib.util.find_spec(_PACKAGE[sim]) is None:
            results.append(SimResult(sim, "skipped", note=f"package {_PACKAGE[sim]!r} is not installed "
                                     f"(pip install {_PACKAGE[sim]}, or the project's 'test' extra)"))
            continue
        try:
            with _OPEN[sim](Path(path)) as pose:
                errors, count = _part_errors(pose, parts, canon_from_sim)
        except Exception as exc:  # any loader or lookup error is the finding, reported rather than raised
            results.append(SimResult(sim, "failed", note=f"{type(exc).__name__}: {exc}"[:500]))
            continue
        worst = max(errors.values(), default=0.0)
        status = "ok" if worst <= tolerance_m else "mismatch"
        results.append(SimResult(sim, status, worst, errors, count))
    return results
