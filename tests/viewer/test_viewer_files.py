"""Reading a twin from plain files and from a run's summary.json + store."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from artitwin_core._errors import InputError
from artitwin_core.gaussians import LABEL_PART
from artitwin_core.reconstruction import write_ply
from artitwin_core.viewer import TwinData, read_twin_files


def _joints_json(twin) -> list[dict]:
    # The summary's joint entries (flows._pipeline.build_summary), written by hand here.
    return [{"name": n, "type": j.joint_type, "axis": j.axis.tolist(), "pivot": j.pivot.tolist(),
             "range": j.q_range.tolist(), "q": j.q.tolist(), "pitch": j.pitch}
            for j, n in zip(twin.joints, twin.joint_names, strict=True)]


def test_ply_joints_labels_residual_and_export_folder(tmp_path, door_twin):
    g = door_twin.gaussians
    write_ply(tmp_path / "twin.ply", g)
    np.save(tmp_path / "labels.npy", g.labels)
    np.save(tmp_path / "residual.npy", np.linspace(0, 1, g.num_gaussians))
    (tmp_path / "joints.json").write_text(json.dumps({"joints": _joints_json(door_twin)}))
    # An export folder: the base's pieces in the canonical frame, the part's in its link frame (x - pivot).
    part_box = trimesh.creation.box(extents=(0.8, 0.9, 0.05))
    part_box.apply_translation([0.0, 0.45, 0.04])
    pivot = door_twin.joints[0].pivot
    link = sanitized = door_twin.joint_names[0]
    (tmp_path / "export" / "meshes").mkdir(parents=True)
    part_box.copy().apply_translation(-pivot).export(tmp_path / "export" / "meshes" / f"{sanitized}_collision_00.obj")
    trimesh.creation.box(extents=(2, 0.1, 2)).export(tmp_path / "export" / "meshes" / "base_collision_00.obj")
    (tmp_path / "export" / "meshes" / "ghost_collision_00.obj").write_text("v 0 0 0\n")  # unknown link: skipped

    twin = read_twin_files(tmp_path / "twin.ply", tmp_path / "joints.json", labels=tmp_path / "labels.npy",
                           residual=tmp_path / "residual.npy", export_dir=tmp_path / "export")
    np.testing.assert_array_equal(twin.gaussians.labels, g.labels)
    np.testing.assert_allclose(twin.gaussians.means, g.means)
    assert twin.joint_names == (link,)
    np.testing.assert_allclose(twin.joints[0].axis, door_twin.joints[0].axis, atol=1e-12)
    np.testing.assert_allclose(twin.joints[0].q_range, door_twin.joints[0].q_range)
    assert twin.residual.shape == (g.num_gaussians,)
    pieces = {p.name: p for p in twin.collision}
    assert set(pieces) == {f"{link}_collision_00", "base_collision_00"}
    assert pieces[f"{link}_collision_00"].part == 0 and pieces["base_collision_00"].part == -1
    # Back in the canonical frame: the link-frame shift is undone (float32 storage).
    np.testing.assert_allclose(np.sort(pieces[f"{link}_collision_00"].vertices, 0), np.sort(part_box.vertices, 0),
                               atol=1e-6)


def test_bad_inputs_name_the_file(tmp_path, door_twin):
    g = door_twin.gaussians
    write_ply(tmp_path / "twin.ply", g)
    np.save(tmp_path / "labels.npy", np.zeros(3, np.int32))
    with pytest.raises(InputError, match="labels.npy"):
        read_twin_files(tmp_path / "twin.ply", labels=tmp_path / "labels.npy")
    (tmp_path / "j.json").write_text(json.dumps([{"type": "hinge", "axis": [0, 1, 0], "pivot": [0, 0, 0]}]))
    with pytest.raises(InputError, match="j.json.*hinge"):
        read_twin_files(tmp_path / "twin.ply", tmp_path / "j.json")
    # Labels naming a part with no joint are refused, not silently drawn rigid.
    with pytest.raises(InputError, match="part 0"):
        TwinData(g)
    assert int(g.labels.max()) == LABEL_PART



def _write_run(tmp_path, door_scene, door_twin, extra: dict | None = None):
    """A run as `artitwin run` leaves it: summary.json naming store keys, and export/meshes."""
    from infra.store import ArtifactStore
    from schemas import CameraPoses, CaptureArtifact, GaussianCheckpoint, JointParams, JointSet
    from tasks._convert import to_artifact

    truth = door_scene.truth
    cap = to_artifact(CaptureArtifact, door_scene.static)
    artifacts = {
        "ingest/static": ("static", cap),
        "refine_poses": ("static", CameraPoses(world_from_camera=truth.static_world_from_camera,
                                               frame_ids=cap.frame_ids, frame="canonical")),
        "reconstruct": ("static", to_artifact(GaussianCheckpoint, door_twin.gaussians)),
        "fit_joints": ("dynamic", JointSet(joints=[to_artifact(JointParams, j, name="joint_0") for j in truth.joints])),
        **(extra or {}),
    }
    store = ArtifactStore(tmp_path / "store")
    stages = {}
    for i, (name, (label, art)) in enumerate(artifacts.items()):
        key = f"{i:x}" * 64
        store.put(key, art)
        stages[name] = {"stage": name.split("/")[0], "label": label, "key": key, "kind": art.kind}
    run = tmp_path / "run"
    (run / "export" / "meshes").mkdir(parents=True)
    (run / "summary.json").write_text(json.dumps({"scene": str(tmp_path / "tiny"), "store": str(tmp_path / "store"),
                                                  "stages": stages}))
    return run


def test_a_run_folder_gives_twin_joints_cameras_and_collision(tmp_path, door_scene, door_twin):
    from artitwin._viewer import load_twin

    truth = door_scene.truth
    run = _write_run(tmp_path, door_scene, door_twin)
    pivot = truth.joints[0].pivot
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(run / "export" / "meshes" / "part_0_collision_00.obj")
    (run / "export" / "payloads").mkdir()
    for name in ("twin.urdf", "twin.xml", "twin.usda", "payloads/base.usdc", "sim_check.json"):
        (run / "export" / name).write_text("")

    twin = load_twin(run)
    np.testing.assert_array_equal(twin.gaussians.means, door_twin.gaussians.means)
    assert twin.joint_names == ("joint_0",) and twin.joints[0].joint_type == "revolute"
    np.testing.assert_allclose(twin.joints[0].pivot, pivot)
    np.testing.assert_array_equal(twin.cameras.world_from_camera, truth.static_world_from_camera)
    # The export stage's link part_0 is joint 0's part; its piece is shifted back to the pivot.
    (piece,) = twin.collision
    assert piece.part == 0
    np.testing.assert_allclose(piece.vertices.mean(0), pivot, atol=1e-6)
    assert twin.residual_values is None  # no diagnostics in this run
    # The simulator files the user opens elsewhere, stages first and the USD payload last.
    assert [Path(p).relative_to(run / "export").as_posix() for p in twin.exports] == [
        "twin.urdf", "twin.usda", "twin.xml", "payloads/base.usdc"]


def test_a_run_folder_with_diagnostics_gives_the_depth_residual(tmp_path, door_scene, door_twin):
    from artitwin._viewer import load_twin

    diagnose = pytest.importorskip("schemas._diagnose", reason="the diagnostics stage's schemas are not installed")
    static = door_scene.static
    # The diagnostics' predicted depth: 2 cm too far inside a window of every frame, exact elsewhere.
    pred_depth = np.array(static.depth, np.float32)
    h, w = pred_depth.shape[1:]
    pred_depth[:, h // 4 : h // 2, w // 4 : w // 2] += 0.02
    pred = diagnose.ViewPrediction(rgb=np.asarray(static.rgb), depth=pred_depth,
                                   frame_ids=np.asarray(static.frame_ids, np.int64))
    twin = load_twin(_write_run(tmp_path, door_scene, door_twin, {"predict_views": ("static", pred)}))
    vals = twin.residual_values
    assert vals.shape[0] > 1000
    np.testing.assert_allclose(np.sort(np.unique(np.round(vals, 4))), [0.0, 0.02], atol=1e-6)
    assert 0.05 < np.mean(vals > 0.01) < 0.1  # the window is 1/16 of the pixels
    # ... accumulated onto the Gaussians: the ones the window's pixels land on carry its 2 cm.
    per = twin.residual
    assert per.shape == (twin.gaussians.num_gaussians,) and np.isfinite(per).mean() > 0.05
    seen = per[np.isfinite(per)]
    assert seen.min() >= 0.0 and seen.max() <= 0.02 + 1e-6
    assert 0.01 < np.mean(seen > 0.01) < 0.4
