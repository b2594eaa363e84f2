"""Benchmark of the simulator export on the synthetic benchmark scenes.

Per scene and part: TSDF fusion of the part from the dynamic recording (true joint and true
registration: this measures fusion and export alone), faces, Chamfer against the part's rendered
true surface moved back to q = 0 (accuracy fused -> true, completeness true -> fused, their mean;
mm), CoACD and k-means convex decomposition (pieces, seconds), the inertial (kg, which volume),
then the URDF and MJCF written and loaded in yourdfpy, PyBullet and MuJoCo with the part driven
through the true q(t): the max mesh-vertex error against ``joint_transforms`` (m); then the USD
stage written (seconds, bytes of twin.usda plus payloads) and checked by ``check_usd`` (pxr
read-back, and Newton where installed; same error, m). Seconds are the median of ``--repeats`` runs.

Run: ``python bench/bench_export.py [--scenes door drawer ...] [--voxels 0.01 0.005] [--repeats 3]``;
prints a table and writes ``bench/results/export.json``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, write_results  # noqa: E402

from artitwin_core.export import (  # noqa: E402
    Z_UP_FROM_Y_UP,
    SimPart,
    check_usd,
    convex_decomposition,
    export_mjcf,
    export_urdf,
    export_usd,
    fuse_base_mesh,
    fuse_part_mesh,
    mesh_inertial,
)
from artitwin_core.export._fuse import _backproject  # noqa: E402
from artitwin_core.geometry import invert_se3  # noqa: E402
from artitwin_core.joints import joint_transforms  # noqa: E402
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, render_state  # noqa: E402


def _median_time(repeats: int, fn, *args, **kwargs):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times))


def _motions(joint):
    return joint_transforms(joint.joint_type, joint.axis, joint.pivot, joint.q, joint.pitch)


def _true_surface(scene, k):
    d, truth = scene.dynamic, scene.truth
    motions = _motions(truth.joints[k])
    out = []
    for t in range(d.num_frames):
        pose = truth.dynamic_world_from_camera[t]
        _, depth, labels = render_state(scene, pose, d.depth_intrinsics[t], *d.depth_size,
                                        [j.q[t] for j in truth.joints])
        pts = _backproject(np.nan_to_num(depth), d.depth_intrinsics[t])[labels == k + 1]
        c = invert_se3(motions[t]) @ pose
        out.append(pts @ c[:3, :3].T + c[:3, 3])
    return np.concatenate(out)


def _sim_errors(urdf, mjcf, name, joint, mesh) -> dict[str, float]:
    import mujoco
    import pybullet
    import yourdfpy

    verts = np.asarray(mesh.vertices)
    local = verts - joint.pivot
    canon_from_sim = invert_se3(Z_UP_FROM_Y_UP)
    motions = _motions(joint)

    def worst(pose_at):
        err = 0.0
        for q, m in zip(joint.q, motions, strict=True):
            p = canon_from_sim @ pose_at(q)
            err = max(err, float(np.linalg.norm(local @ p[:3, :3].T + p[:3, 3] - (verts @ m[:3, :3].T + m[:3, 3]),
                                                axis=1).max()))
        return err

    robot = yourdfpy.URDF.load(str(urdf))

    def ur(q):
        robot.update_cfg({f"{name}_joint": q})
        return robot.get_transform(frame_to=name, frame_from="world")

    model = mujoco.MjModel.from_xml_path(str(mjcf))
    data = mujoco.MjData(model)

    def mj(q):
        data.qpos[model.jnt_qposadr[model.joint(f"{name}_joint").id]] = q
        mujoco.mj_kinematics(model, data)
        b = model.body(name).id
        p = np.eye(4)
        p[:3, :3], p[:3, 3] = data.xmat[b].reshape(3, 3), data.xpos[b]
        return p

    c = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf), useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE,
                                 physicsClientId=c)
        names = [pybullet.getJointInfo(body, i, physicsClientId=c)[1].decode()
                 for i in range(pybullet.getNumJoints(body, physicsClientId=c))]
        ji = names.index(f"{name}_joint")

        def pb(q):
            pybullet.resetJointState(body, ji, q, physicsClientId=c)
            st = pybullet.getLinkState(body, ji, computeForwardKinematics=True, physicsClientId=c)
            p = np.eye(4)
            p[:3, :3] = np.array(pybullet.getMatrixFromQuaternion(st[5])).reshape(3, 3)
            p[:3, 3] = st[4]
            return p

        pb_err = worst(pb)
    finally:
        pybullet.disconnect(c)
    return {"err_yourdfpy_m": worst(ur), "err_pybullet_m": pb_err, "err_mujoco_m": worst(mj)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["door", "drawer"])
    parser.add_argument("--voxels", nargs="+", type=float, default=[0.01, 0.005])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows = []
    for scene_name in args.scenes:
        scene = generate_scene(BENCHMARK_SCENES[scene_name])
        truth = scene.truth
        w, h, d = scene.spec.size_m
        crop = np.array([[-w / 2 - 0.1, -0.02, -d - 0.1], [w / 2 + 0.1, h + 0.1, 0.2]])
        for k, joint in enumerate(truth.joints):
            true_pts = _true_surface(scene, k)
            for voxel in args.voxels:
                mesh, t_fuse = _median_time(
                    args.repeats, fuse_part_mesh, scene.dynamic, truth.part_masks == k + 1,
                    world_from_capture=truth.canonical_from_dynamic_session,
                    world_from_closed=_motions(joint), voxel_m=voxel)
                samples = np.asarray(mesh.sample(20000, seed=0))
                acc = float(cKDTree(true_pts).query(samples)[0].mean() * 1e3)
                comp = float(cKDTree(samples).query(true_pts)[0].mean() * 1e3)
                row = {"scene": scene_name, "part": k, "type": joint.joint_type, "voxel_mm": voxel * 1e3,
                       "faces": len(mesh.faces), "fuse_s": t_fuse, "acc_mm": acc, "comp_mm": comp,
                       "chamfer_mm": (acc + comp) / 2}
                if voxel == args.voxels[0]:
                    pieces, t_coacd = _median_time(1, convex_decomposition, mesh, method="coacd")
                    km, t_km = _median_time(1, convex_decomposition, mesh, method="kmeans")
                    inertial = mesh_inertial(mesh, pieces=pieces)
                    base, t_base = _median_time(1, fuse_base_mesh, scene.static, [mesh], crop_box=crop, voxel_m=0.02)
                    base_col = convex_decomposition(base, method="kmeans", max_parts=8)
                    with tempfile.TemporaryDirectory() as tmp:
                        parts = [("part", joint, mesh, pieces)]
                        t0 = time.perf_counter()
                        urdf = export_urdf(tmp, base, parts, base_collision=base_col)
                        mjcf = export_mjcf(tmp, base, parts, base_collision=base_col)
                        t_export = time.perf_counter() - t0
                        errs = _sim_errors(urdf, mjcf, "part", joint, mesh)
                        t0 = time.perf_counter()
                        usd = export_usd(tmp, base, parts, base_collision=base_col)
                        errs["usd_s"] = time.perf_counter() - t0
                        errs["usd_bytes"] = usd.path.stat().st_size + sum(p.stat().st_size for p in usd.payloads.values())
                        sim_part = SimPart("part", joint, np.asarray(mesh.vertices) - joint.pivot)
                        for r in check_usd(usd.path, [sim_part]):
                            errs[f"err_{r.simulator}_m"] = r.max_error_m if r.status in ("ok", "mismatch") else None
                    row.update({"coacd_pieces": len(pieces), "coacd_s": t_coacd, "kmeans_pieces": len(km),
                                "kmeans_s": t_km, "mass_kg": inertial.mass_kg, "mass_from": inertial.source,
                                "base_faces": len(base.faces), "base_fuse_s": t_base, "export_s": t_export, **errs})
                rows.append(row)
                print(row, flush=True)
    print_table(rows, ["scene", "part", "type", "voxel_mm", "faces", "fuse_s", "acc_mm", "comp_mm", "chamfer_mm",
                       "coacd_pieces", "coacd_s", "kmeans_s", "mass_kg", "mass_from", "err_pybullet_m",
                       "err_mujoco_m", "err_yourdfpy_m", "usd_s", "usd_bytes", "err_usd_m", "err_newton_usd_m"])
    path = write_results("export", rows, {"repeats": args.repeats})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
