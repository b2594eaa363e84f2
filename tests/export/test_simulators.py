"""The exported URDF / MJCF load in yourdfpy, PyBullet and MuJoCo and move exactly as the joints say.

Hand-made boxes keep these fast; the joints have tilted axes and off-origin pivots so that a wrong
frame, sign or axis convention shows up as centimetres of error. Each simulator is driven through a
q(t) sequence and the poses of every mesh vertex are compared with ``joint_transforms``.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from artitwin_core.export import Z_UP_FROM_Y_UP, export_mjcf, export_urdf, mesh_inertial
from artitwin_core.geometry import invert_se3, quat_wxyz_to_matrix
from artitwin_core.joints import Joint, joint_transforms

yourdfpy = pytest.importorskip("yourdfpy", reason="yourdfpy not installed (pip install yourdfpy)")
pybullet = pytest.importorskip("pybullet", reason="pybullet not installed (pip install pybullet)")
mujoco = pytest.importorskip("mujoco", reason="mujoco not installed (pip install mujoco)")

DENSITY = 500.0
# The issue's target for the simulated part pose against the twin's, metres.
ISSUE_TOL_M = 5e-3
# What the exported frames actually achieve: PyBullet and MuJoCo compute forward kinematics in
# float64 from 9-digit XML numbers; measured max vertex error 2e-9 m (yourdfpy, MuJoCo) and
# 3e-8 m (PyBullet). 1e-6 m leaves room and still catches any frame bug.
EXACT_TOL_M = 1e-6


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(extents=hi - lo)
    b.apply_translation((lo + hi) / 2)
    return b


def _joint(kind, axis, pivot, q_range, pitch=0.0) -> Joint:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    z = np.zeros(3)
    return Joint(kind, axis, np.asarray(pivot, float), z, np.asarray(q_range, float), z, z, pitch=pitch)


# name -> (joint, mesh in the canonical frame at q = 0)
PARTS = {
    "door": (_joint("revolute", [0.05, 1.0, -0.08], [0.4, 0.45, 0.01], [-0.1, 1.3]), _box([-0.4, 0, 0], [0.4, 0.9, 0.02])),
    "drawer": (_joint("prismatic", [0.1, -0.05, 1.0], [0.0, 0.3, 0.02], [0.0, 0.28]),
               _box([-0.3, 0.2, -0.4], [0.3, 0.4, 0.02])),
    "knob": (_joint("screw", [0.0, 0.2, 1.0], [0.2, 0.7, 0.05], [0.0, 3.0], pitch=0.004),
             _box([0.17, 0.67, 0.02], [0.23, 0.73, 0.08])),
}
BASE = _box([-0.45, 0, -0.5], [0.45, 0.95, 0])


def _q_path(lo: float, hi: float, n: int = 13) -> np.ndarray:
    """q(t) out to the upper limit and back, limits included."""
    return lo + (hi - lo) * (0.5 - 0.5 * np.cos(np.linspace(0, 2 * np.pi, n)))


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("export")
    parts = [(name, j, m, [m]) for name, (j, m) in PARTS.items()]
    urdf = export_urdf(out, BASE, parts, base_collision=[BASE], density_kg_m3=DENSITY)
    mjcf = export_mjcf(out, BASE, parts, base_collision=[BASE], density_kg_m3=DENSITY)
    return urdf, mjcf


def _check_poses(name: str, link_pose_at) -> float:
    """Max vertex error (metres) of ``link_pose_at(q) -> canonical_from_link [4, 4]`` along q(t)."""
    joint, mesh = PARTS[name]
    verts = np.asarray(mesh.vertices)
    local = verts - joint.pivot  # the link frame sits at the pivot, canonical axes
    qs = _q_path(*joint.q_range)
    truth = joint_transforms(joint.joint_type, joint.axis, joint.pivot, qs, joint.pitch)
    worst = 0.0
    for q, motion in zip(qs, truth, strict=True):
        pose = link_pose_at(q)
        sim = local @ pose[:3, :3].T + pose[:3, 3]
        want = verts @ motion[:3, :3].T + motion[:3, 3]
        worst = max(worst, float(np.linalg.norm(sim - want, axis=1).max()))
    return worst


CANON_FROM_SIM = invert_se3(Z_UP_FROM_Y_UP)


def test_yourdfpy_poses_limits_inertials(exported):
    urdf_path, _ = exported
    robot = yourdfpy.URDF.load(str(urdf_path), load_meshes=True, build_collision_scene_graph=True)
    # The screw's slide mimics its hinge, so only the three hinges/slides are actuated.
    assert sorted(robot.actuated_joint_names) == ["door_joint", "drawer_joint", "knob_joint"]
    for name, (joint, mesh) in PARTS.items():
        jn = f"{name}_joint"

        def pose_at(q, jn=jn, name=name):
            robot.update_cfg({jn: q})
            return CANON_FROM_SIM @ robot.get_transform(frame_to=name, frame_from="world")

        err = _check_poses(name, pose_at)
        print(f"yourdfpy {name}: max vertex error {err:.2e} m")
        assert err < ISSUE_TOL_M, f"{name}: {err * 1e3:.3f} mm"  # the issue's 5 mm target
        assert err < EXACT_TOL_M, f"{name}: {err:.2e} m"  # see EXACT_TOL_M
        lim = robot.joint_map[jn].limit
        np.testing.assert_allclose([lim.lower, lim.upper], joint.q_range, atol=1e-9)  # 9 printed digits
        inertial = robot.link_map[name].inertial
        assert inertial.mass == pytest.approx(DENSITY * mesh.volume, rel=1e-6)  # closed box: exact
        assert np.all(np.linalg.eigvalsh(inertial.inertia) > 0)
        # About the COM, canonical axes = link axes: the solid box's tensor (9 printed digits).
        np.testing.assert_allclose(inertial.inertia, DENSITY * mesh.moment_inertia, rtol=1e-7, atol=1e-10)
        np.testing.assert_allclose(inertial.origin[:3, 3], mesh.center_mass - joint.pivot, atol=1e-8)
        # The visual and collision files hold the mesh in the link frame (origin at the pivot).
        link = robot.link_map[name]
        for geometry in (link.visuals[0].geometry, link.collisions[0].geometry):
            stored = trimesh.load(urdf_path.parent / geometry.mesh.filename, force="mesh")
            np.testing.assert_allclose(stored.bounds, mesh.bounds - joint.pivot, atol=1e-6)  # OBJ prints 8 digits


def test_pybullet_poses_limits_inertials(exported):
    urdf_path, _ = exported
    c = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf_path), useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE,
                                 physicsClientId=c)
        index = {}
        for i in range(pybullet.getNumJoints(body, physicsClientId=c)):
            info = pybullet.getJointInfo(body, i, physicsClientId=c)
            index[info[1].decode()] = (i, info)
            index[info[12].decode()] = (i, info)  # child link name -> same index
        for name, (joint, mesh) in PARTS.items():
            ji, info = index[f"{name}_joint"]
            np.testing.assert_allclose([info[8], info[9]], joint.q_range, atol=1e-9)  # 9 printed digits

            def pose_at(q, ji=ji, joint=joint, name=name):
                pybullet.resetJointState(body, ji, q, physicsClientId=c)
                if joint.joint_type == "screw":  # PyBullet ignores <mimic>: drive the slide too
                    pybullet.resetJointState(body, index[f"{name}_slide"][0], joint.pitch * q, physicsClientId=c)
                st = pybullet.getLinkState(body, ji, computeForwardKinematics=True, physicsClientId=c)
                x, y, z, w = st[5]  # URDF link frame (index 4/5), not the COM frame (0/1)
                pose = np.eye(4)
                pose[:3, :3] = quat_wxyz_to_matrix(np.array([w, x, y, z]))
                pose[:3, 3] = st[4]
                return CANON_FROM_SIM @ pose

            err = _check_poses(name, pose_at)
            print(f"pybullet {name}: max vertex error {err:.2e} m")
            assert err < ISSUE_TOL_M, f"{name}: {err * 1e3:.3f} mm"  # the issue's 5 mm target
            assert err < EXACT_TOL_M, f"{name}: {err:.2e} m"  # see EXACT_TOL_M
            dyn = pybullet.getDynamicsInfo(body, ji, physicsClientId=c)
            assert dyn[0] == pytest.approx(DENSITY * mesh.volume, rel=1e-6)  # mass = density x volume
            assert min(dyn[2]) > 0  # principal moments: positive-definite inertia
            # The inertial frame is the COM: PyBullet reports it in the link frame.
            np.testing.assert_allclose(dyn[3], mesh.center_mass - joint.pivot, atol=1e-7)
    finally:
        pybullet.disconnect(c)


def _mujoco_pose(model, data, body: str) -> np.ndarray:
    b = model.body(body).id
    pose = np.eye(4)
    pose[:3, :3] = data.xmat[b].reshape(3, 3)
    pose[:3, 3] = data.xpos[b]
    return CANON_FROM_SIM @ pose


@pytest.mark.parametrize("which", ["mjcf", "urdf"])
def test_mujoco_poses_limits_inertials(exported, which):
    path = exported[1] if which == "mjcf" else exported[0]
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    for name, (joint, mesh) in PARTS.items():
        jid = model.joint(f"{name}_joint").id
        np.testing.assert_allclose(model.jnt_range[jid], joint.q_range, atol=1e-9)  # 9 printed digits
        assert bool(model.jnt_limited[jid])

        def pose_at(q, jid=jid, joint=joint, name=name):
            data.qpos[:] = 0
            data.qpos[model.jnt_qposadr[jid]] = q
            if joint.joint_type == "screw":
                data.qpos[model.jnt_qposadr[model.joint(f"{name}_slide").id]] = joint.pitch * q
            mujoco.mj_kinematics(model, data)
            return _mujoco_pose(model, data, name)

        err = _check_poses(name, pose_at)
        print(f"mujoco-{which} {name}: max vertex error {err:.2e} m")
        assert err < ISSUE_TOL_M, f"{which} {name}: {err * 1e3:.3f} mm"  # the issue's 5 mm target
        assert err < EXACT_TOL_M, f"{which} {name}: {err:.2e} m"  # see EXACT_TOL_M
        if which == "mjcf":  # MuJoCo re-centres mesh vertices; the geom frame must undo that
            pose_at(0.7 * joint.q_range[1])
            motion = joint_transforms(joint.joint_type, joint.axis, joint.pivot, [0.7 * joint.q_range[1]], joint.pitch)[0]
            want = np.asarray(mesh.vertices) @ motion[:3, :3].T + motion[:3, 3]
            for geom in (f"{name}_visual", f"{name}_collision_00"):
                g = model.geom(geom).id
                m = model.geom_dataid[g]
                v = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
                sim = CANON_FROM_SIM @ np.vstack([
                    (v @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]).T, np.ones(len(v))])
                gap = cKDTree(want).query(sim[:3].T)[0].max()
                assert gap < EXACT_TOL_M, (geom, gap)  # float32 mesh vertices: measured 1.4e-8 m
        b = model.body(name).id
        assert model.body_mass[b] == pytest.approx(DENSITY * mesh.volume, rel=1e-6)  # density x volume
        assert np.all(model.body_inertia[b] > 0)  # principal moments: positive-definite


def test_mujoco_screw_equality_holds_while_simulating(exported):
    """The MJCF's equality keeps slide = pitch * hinge while the knob moves under a torque.

    Gravity is off here: MuJoCo's equality is a soft constraint, and with gravity along the knob's
    tilted axis it lags by ~0.4 mm (measured; reported, not hidden). This checks the coupling itself.
    """
    model = mujoco.MjModel.from_xml_path(str(exported[1]))
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
    data = mujoco.MjData(model)
    joint, _ = PARTS["knob"]
    hinge, slide = model.joint("knob_joint"), model.joint("knob_slide")
    dof = model.jnt_dofadr[hinge.id]
    for _ in range(300):
        data.qfrc_applied[dof] = 0.05  # N m about the knob's axis
        mujoco.mj_step(model, data)
    q = data.qpos[model.jnt_qposadr[hinge.id]]
    s = data.qpos[model.jnt_qposadr[slide.id]]
    print(f"mujoco screw: q {q:.4f} rad, |slide - pitch q| {abs(s - joint.pitch * q):.2e} m")
    assert q > 0.05  # it did turn (radians)
    assert s > 0.5 * joint.pitch * q  # and the slide followed (metres)
    # Soft constraint lagging the motion: measured |s - pitch q| = 1.4e-4 m after 300 steps (the slide
    # never moving would give pitch * q = 3e-4 m); 0.2 mm = 4% of the 5 mm target.
    assert abs(s - joint.pitch * q) < 2e-4


def test_inertial_of_open_meshes_falls_back_and_stays_physical():
    """A fused surface is open: the mass then comes from the convex pieces, else the hull, else a box."""
    closed = _box([0, 0, 0], [0.8, 0.9, 0.02])
    open_mesh = closed.copy()
    open_mesh.update_faces(np.arange(len(open_mesh.faces)) >= 2)  # drop one side: no longer watertight
    assert not open_mesh.is_watertight
    hull = mesh_inertial(open_mesh, DENSITY)
    assert hull.source == "convex_hull"
    assert hull.mass_kg == pytest.approx(DENSITY * closed.volume, rel=1e-6)  # hull of a box = the box
    pieces = mesh_inertial(open_mesh, DENSITY, pieces=[_box([0, 0, 0], [0.4, 0.9, 0.02]), _box([0.4, 0, 0], [0.8, 0.9, 0.02])])
    assert pieces.source == "convex_pieces"
    assert pieces.mass_kg == pytest.approx(DENSITY * closed.volume, rel=1e-6)
    np.testing.assert_allclose(pieces.inertia, closed.moment_inertia * DENSITY, rtol=1e-6, atol=1e-12)
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])
    sheet = mesh_inertial(flat, DENSITY, min_thickness_m=0.01)
    assert sheet.source == "bounding_box"
    assert sheet.mass_kg == pytest.approx(DENSITY * 1.0 * 1.0 * 0.01, rel=1e-6)  # 1 x 1 m, 1 cm floor
    for inertial in (hull, pieces, sheet):
        assert np.all(np.linalg.eigvalsh(inertial.inertia) > 0)
