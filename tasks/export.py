"""Stage: the articulated twin as simulator files (URDF, MJCF, USD, meshes, per-part splats), checked.

Each part's mesh is TSDF-fused from the dynamic recording with its motion undone (part k is mask
label k + 1 and joint k), the base from the static recording minus the parts; CoACD makes the
collision pieces, the mesh volume the inertials. The files are written to a scratch folder, loaded
in every simulator that is installed, driven through the estimated ``q(t)`` and read back into the
bundle byte for byte, with the check's results as ``sim_check.json``. The USD stage (``twin.usda``,
payloads under ``payloads/``) carries the splats under their links and is validated, read back and
driven the same way (``check_usd``).
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from artitwin_core import InputError
from artitwin_core.capture import Capture
from artitwin_core.export import (
    Z_UP_FROM_Y_UP,
    ExportPart,
    SimPart,
    check_in_simulators,
    check_usd,
    convex_decomposition,
    export_mjcf,
    export_part_plys,
    export_urdf,
    export_usd,
    fuse_base_mesh,
    fuse_part_mesh,
    mesh_inertial,
)
from artitwin_core.gaussians import LABEL_PART, GaussianParams
from artitwin_core.joints import Joint, joint_transforms
from schemas import (
    CameraPoses,
    CaptureArtifact,
    GaussianCheckpoint,
    JointSet,
    MaskSequenceArtifact,
    Registration,
)
from schemas._export import ExportBundle, ExportConfig, ExportFile
from tasks._convert import config_map, to_core
from tasks._stage import stage

# The export calls many core functions, one setting each (or two: the parts' and the base's), so
# it passes its fields by hand; the map says where each acts and the test of config truth checks
# the defaults.
config_map(
    ExportConfig,
    {
        fuse_part_mesh: {"part_voxel_m": "voxel_m", "depth_max_m": "depth_max_m", "mask_erode_px": "erode_px",
                         "part_max_faces": "max_faces"},
        fuse_base_mesh: {"base_part_margin_m": "margin_m", "base_voxel_m": "voxel_m", "base_max_faces": "max_faces"},
        convex_decomposition: {"collision_method": "method", "max_collision_pieces": "max_parts",
                               "coacd_threshold": "threshold", "seed": "seed"},
        mesh_inertial: "density_kg_m3",
        export_urdf: "effort velocity",
        export_mjcf: "damping",
        export_usd: {"usd_payload_min_bytes": "payload_min_bytes"},
    },
    stage_only={
        "name": "the model's name, given to every writer",
        "base_crop_margin_m": "the stage crops the base to the parts' box grown by this (fuse_base_mesh's crop_box)",
        "base_collision_method": "convex_decomposition's method, for the base",
        "base_max_collision_pieces": "convex_decomposition's max_parts, for the base",
        "formats": "which writers the stage calls",
        "splats_in_link_frames": "whether the stage shifts the part splats into their link frames",
        "check_simulators": "whether the stage runs the simulator check",
        "sim_tolerance_mm": "the simulator check's tolerance, applied by the stage",
    },
)

SIM_CHECK_FILE = "sim_check.json"
SPLAT_DIR = "splats"


def part_name(k: int) -> str:
    """Link, file and ``.ply`` name of part k (mask label k + 1, joint k, Gaussian label 2 + k)."""
    return f"part_{k}"


def _check_inputs(dynamic: CaptureArtifact, masks: MaskSequenceArtifact, joints: list[Joint], names: list[str]) -> None:
    t_count = dynamic.rgb.shape[0]
    if masks.part.shape[0] != t_count:
        raise InputError(
            f"export: the part masks have {masks.part.shape[0]} frames but the dynamic recording has {t_count}; "
            "recompute the masks from this recording."
        )
    if masks.part.shape[1:] != dynamic.rgb.shape[1:3]:
        raise InputError(
            f"export: part masks are {masks.part.shape[1:]} pixels, the dynamic RGB frames {dynamic.rgb.shape[1:3]}; "
            "masks must be at RGB resolution."
        )
    for joint, name in zip(joints, names, strict=True):
        if joint.joint_type != "fixed" and len(joint.q) != t_count:
            raise InputError(
                f"export: joint {name!r} has {len(joint.q)} states q(t) for a dynamic recording of {t_count} frames; "
                "fit the joints on this recording's tracks."
            )


def _crop_box(meshes: list[trimesh.Trimesh], joints: list[Joint], margin_m: float | None) -> np.ndarray | None:
    """``[2, 3]`` metres: the parts' bounds, closed and at both range ends, grown by ``margin_m``."""
    if margin_m is None:
        return None
    pts = []
    for mesh, j in zip(meshes, joints, strict=True):
        v = np.asarray(mesh.vertices, np.float64)
        for m in joint_transforms(j.joint_type, j.axis, j.pivot, np.r_[0.0, np.asarray(j.q_range, np.float64)], j.pitch):
            pts.append(v @ m[:3, :3].T + m[:3, 3])
    pts = np.concatenate(pts)
    return np.stack([pts.min(0) - margin_m, pts.max(0) + margin_m])


def _read_tree(root: Path) -> list[ExportFile]:
    return [ExportFile.from_bytes(p.relative_to(root).as_posix(), p.read_bytes())
            for p in sorted(root.rglob("*")) if p.is_file()]


@stage(name="export", version=2, config=ExportConfig, output=ExportBundle)
def export_twin(
    static: CaptureArtifact,
    static_poses: CameraPoses,
    dynamic: CaptureArtifact,
    registration: Registration,
    masks: MaskSequenceArtifact,
    joints: JointSet,
    gaussians: GaussianCheckpoint,
    config: ExportConfig,
) -> ExportBundle:
    """URDF + MJCF + USD + OBJ meshes + per-part 3DGS ``.ply`` + ``sim_check.json`` of the twin.

    ``static_poses`` are the static recording's refined poses (canonical frame); ``registration``
    puts the dynamic recording into that frame; joint k moves the pixels of mask label k + 1 and
    the Gaussians of label 2 + k. Joint limits are each joint's estimated ``q_range``.
    """
    core_joints = [to_core(Joint, j) for j in joints.joints]
    names = [part_name(k) for k in range(len(core_joints))]
    _check_inputs(dynamic, masks, core_joints, names)
    if static_poses.world_from_camera.shape[0] != static.world_from_camera.shape[0]:
        raise InputError(
            f"export: {static_poses.world_from_camera.shape[0]} static poses for a static recording of "
            f"{static.world_from_camera.shape[0]} frames; refine the poses of this recording."
        )
    static_cap = to_core(Capture, static, world_from_camera=static_poses.world_from_camera)
    dynamic_cap = to_core(Capture, dynamic)
    notes: list[str] = []
    metrics: dict[str, float] = {"parts_count": float(len(core_joints))}

    meshes, collisions = [], []
    for k, (joint, name) in enumerate(zip(core_joints, names, strict=True)):
        motions = joint_transforms(joint.joint_type, joint.axis, joint.pivot, joint.q, joint.pitch)
        mesh = fuse_part_mesh(
            dynamic_cap, (masks.part == k + 1) & ~masks.hand,
            world_from_capture=registration.canonical_from_session, world_from_closed=motions,
            voxel_m=config.part_voxel_m, depth_max_m=config.depth_max_m, erode_px=config.mask_erode_px,
            max_faces=config.part_max_faces,
        )
        if len(mesh.faces) == 0:
            raise InputError(
                f"export: part {k} ({name}) has no depth inside mask label {k + 1} in any dynamic frame; "
                "check the part masks (and the registration) of the dynamic recording."
            )
        pieces = convex_decomposition(mesh, method=config.collision_method, max_parts=config.max_collision_pieces,
                                      threshold=config.coacd_threshold, seed=config.seed)
        inertial = mesh_inertial(mesh, config.density_kg_m3, pieces=pieces)
        metrics[f"{name}_faces_count"] = float(len(mesh.faces))
        metrics[f"{name}_collision_pieces_count"] = float(len(pieces))
        metrics[f"{name}_mass_kg"] = inertial.mass_kg
        if joint.joint_type == "screw":
            notes.append(f"{name}: screw joint exported as {name}_slide (prismatic) + {name}_joint (revolute); "
                         f"PyBullet and MuJoCo's URDF importer do not enforce {name}_slide = {joint.pitch:.4g} * {name}_joint.")
        meshes.append(mesh)
        collisions.append(pieces)

    base = fuse_base_mesh(
        static_cap, meshes, margin_m=config.base_part_margin_m,
        crop_box=_crop_box(meshes, core_joints, config.base_crop_margin_m) if meshes else None,
        voxel_m=config.base_voxel_m, max_faces=config.base_max_faces, depth_max_m=config.depth_max_m,
    )
    if len(base.faces) == 0:
        raise InputError("export: nothing of the static recording was fused into the base (no valid depth in the "
                         "crop box); check the static recording's depth, or set base_crop_margin_m to None.")
    base_pieces = convex_decomposition(base, method=config.base_collision_method,
                                       max_parts=config.base_max_collision_pieces,
                                       threshold=config.coacd_threshold, seed=config.seed)
    metrics["base_faces_count"] = float(len(base.faces))
    metrics["base_collision_pieces_count"] = float(len(base_pieces))
    parts = [ExportPart(n, j, m, c) for n, j, m, c in zip(names, core_joints, meshes, collisions, strict=True)]

    with tempfile.TemporaryDirectory(prefix="artitwin-export-") as tmp:
        out = Path(tmp)
        common = dict(name=config.name, base_collision=base_pieces, density_kg_m3=config.density_kg_m3,
                      sim_from_canonical=Z_UP_FROM_Y_UP)
        urdf = (export_urdf(out, base, parts, effort=config.effort, velocity=config.velocity, **common)
                if "urdf" in config.formats else None)
        mjcf = export_mjcf(out, base, parts, damping=config.damping, **common) if "mjcf" in config.formats else None
        usd = None
        if "usd" in config.formats:
            start = time.perf_counter()
            written = export_usd(out, base, parts, gaussians=to_core(GaussianParams, gaussians), effort=config.effort,
                                 damping=config.damping, payload_min_bytes=config.usd_payload_min_bytes, **common)
            usd = written.path
            metrics["usd_write_s"] = time.perf_counter() - start
            notes += [f"usd: {n}" for n in written.notes]
        if "splats" in config.formats:
            params = to_core(GaussianParams, gaussians)
            if not np.any(params.labels >= LABEL_PART):
                notes.append("The Gaussian checkpoint has no part labels yet: its splats are exported as the base "
                             "only (run the articulated optimisation to split them by part).")
            pivots = [np.asarray(j.pivot, np.float64) for j in core_joints] if config.splats_in_link_frames else None
            plys = export_part_plys(params, out / SPLAT_DIR, part_names=names, pivots=pivots)
            metrics["splat_files_count"] = float(len(plys))
        if config.check_simulators and (urdf is not None or mjcf is not None or usd is not None):
            sim_parts = [SimPart(n, j, np.asarray(m.vertices, np.float64) - np.asarray(j.pivot, np.float64))
                         for n, j, m in zip(names, core_joints, meshes, strict=True)]
            results = check_in_simulators(urdf, mjcf, sim_parts, sim_from_canonical=Z_UP_FROM_Y_UP,
                                          tolerance_m=config.sim_tolerance_mm * 1e-3)
            start = time.perf_counter()
            results += check_usd(usd, sim_parts, sim_from_canonical=Z_UP_FROM_Y_UP,
                                 tolerance_m=config.sim_tolerance_mm * 1e-3)
            metrics["usd_check_s"] = time.perf_counter() - start
            for r in results:
                if np.isfinite(r.max_error_m):
                    metrics[f"sim_{r.simulator}_max_error_mm"] = r.max_error_m * 1e3
                if r.status == "mismatch":
                    notes.append(f"{r.simulator}: the simulated part pose is {r.max_error_m * 1e3:.2f} mm from the "
                                 f"twin's (tolerance {config.sim_tolerance_mm:g} mm).")
                elif r.status in ("failed", "skipped"):
                    notes.append(f"{r.simulator} {r.status}: {r.note}")
            report = {
                "tolerance_mm": config.sim_tolerance_mm,
                "frame": "errors compare link poses applied to each part's mesh vertices, canonical frame",
                "parts": [{"link": sp.link, "joint_type": sp.joint.joint_type,
                           "q_range": [float(v) for v in sp.joint.q_range]} for sp in sim_parts],
                "simulators": [r.to_json() for r in results],
            }
            (out / SIM_CHECK_FILE).write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
        return ExportBundle(files=_read_tree(out), metrics=metrics, notes=notes)
