"""The Prefect layer: retries for transient errors only, the scene flow end to end, UI artifacts.

All Prefect runs live in this one module so the embedded server starts once (~10 s).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from prefect import flow

from flows import raw_input
from flows.scene import reconstruct_scene, stage_task
from schemas import PipelineConfig
from tests.flows._toy import CALLS, FAILURES, ToyConfig


@pytest.fixture
def folder(tmp_path):
    d = tmp_path / "rec"
    d.mkdir()
    (d / "a.bin").write_bytes(b"x" * 10)
    CALLS.clear()
    FAILURES.clear()
    return d


def _one_stage_flow(store: str, folder: Path):
    fast_retry = stage_task.with_options(retry_delay_seconds=0, retry_jitter_factor=None)
    raw = raw_input(folder, [p for p in folder.iterdir()])

    @flow
    def toy_flow():
        return fast_retry(store, "toy_measure", ToyConfig(), {"recording": raw}, "x")

    return toy_flow


def test_transient_error_is_retried_to_success(tmp_path, folder):
    FAILURES["toy_measure"] = 2
    run = _one_stage_flow(str(tmp_path / "store"), folder)()
    assert run.status == "computed"
    assert CALLS["toy_measure"] == 3  # two transient failures, then success


def test_bad_input_fails_fast_without_retries(tmp_path, folder):
    missing = tmp_path / "nope"
    missing.mkdir()
    (missing / "a.bin").write_bytes(b"1")
    toy = _one_stage_flow(str(tmp_path / "store"), missing)
    (missing / "a.bin").unlink()
    missing.rmdir()  # gone by the time the stage reads it
    with pytest.raises(Exception, match="does not exist"):
        toy()
    assert CALLS["toy_measure"] == 1


@pytest.mark.slow
def test_scene_flow_writes_summary_and_reruns_from_cache(tmp_path, tiny_scene):
    store = str(tmp_path / "store")
    out = tmp_path / "out"
    config = PipelineConfig.preset("quick")
    first = reconstruct_scene(str(tiny_scene), config=config, store=store, out=str(out))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stages"].keys() == first["stages"].keys()
    assert set(summary["stages"]) == {
        "ingest/static", "ingest/dynamic", "capture_check/static", "capture_check/dynamic", "pose_lag/static",
        "pose_lag/dynamic", "correct_pose_lag/static", "correct_pose_lag/dynamic", "refine_poses",
        "reconstruct", "reconstruct_report", "register", "part_masks", "part_masks_report", "frame_poses",
        "correct_frame_poses", "track", "fit_joints", "settle_parts", "final_masks",
        "joint_states", "articulate", "articulate_report", "predict_views", "diagnose", "predict_dynamic", "diagnose_dynamic",
        "export",
    }
    assert all(s["status"] == "computed" for s in summary["stages"].values())
    assert summary["status"] == "ok" and [(p["candidate"], p["fate"], p["joint"]) for p in summary["parts"]] == [
        (0, "kept", "joint_0")
    ]
    # The tiny scene's recorded poses are exact: its frame pose corrections are fitted, not applied.
    frame_poses = summary["stages"]["frame_poses"]
    assert frame_poses["metrics"]["applied"] == 0 and frame_poses["metrics"]["fast_chi2_per_dof"] < 10
    assert "poses stay as recorded" in frame_poses["notes"][0]
    # ... and they are in time with the images: no lag is corrected (measured: -0.004 and +0.002 frame).
    for label in ("static", "dynamic"):
        lag = summary["stages"][f"pose_lag/{label}"]["metrics"]
        assert lag["estimated"] == 1 and lag["applied"] == 0 and abs(lag["lag_frames"]) < 0.1, lag
    check = summary["stages"]["capture_check/static"]["metrics"]
    assert check["frames_count"] > 0 and 0 < check["valid_depth_frac"] <= 1
    assert [j["type"] for j in summary["joints"]] == ["revolute"]  # the tiny scene's one door
    # The tiny door's hinge: axis +-y through (0.4, 0.45, 0) in the canonical frame.
    axis = np.asarray(summary["joints"][0]["axis"])
    assert abs(abs(axis[1]) - 1.0) < 1 - np.cos(np.radians(5.0)), axis
    pivot = np.asarray(summary["joints"][0]["pivot"])
    assert np.hypot(pivot[0] - 0.4, pivot[2]) < 0.03, pivot
    # The export bundle lands under out/export and its URDF carries that joint.
    urdf = Path(summary["exports"]["export/twin.urdf"])
    assert urdf.parent == out / "export" and urdf.is_file()
    assert 'type="revolute"' in urdf.read_text()
    assert Path(summary["exports"]["export/twin.xml"]).is_file()
    # The twin's parts are labelled, so the export has a splat file per part besides the base.
    assert summary["stages"]["articulate_report"]["metrics"]["part_0_gaussians_count"] > 0
    assert any(p.startswith("export/splats/") and "part" in p for p in summary["exports"]), list(summary["exports"])
    # The diagnosis compares the twin with the static recording and says what it found.
    assert summary["stages"]["diagnose"]["notes"], summary["stages"]["diagnose"]
    assert "<svg" in Path(summary["exports"]["diagnosis.html"]).read_text()
    # The change report: one part found, the masks drawn over the frames in part_masks_report.html.
    masks_report = summary["stages"]["part_masks_report"]["metrics"]
    assert masks_report["parts_count"] == 1 and masks_report["hand_labelled_part_frac"] < 0.1, masks_report
    assert Path(summary["exports"]["part_masks_report.html"]).read_text().count("<img") >= 3
    _check_dynamic_prediction(store, summary, tiny_scene)
    second = reconstruct_scene(str(tiny_scene), config=config, store=store, out=str(out))
    assert all(s["status"] == "cached" for s in second["stages"].values())
    assert {k: s["key"] for k, s in second["stages"].items()} == {k: s["key"] for k, s in first["stages"].items()}


def _check_dynamic_prediction(store_url: str, summary: dict, scene_dir: Path) -> None:
    """The articulated twin predicts the dynamic recording: where the fitted joint state is right
    and the door well open, the door is drawn where it opened to (its true pixels get the measured
    depth, which a closed door would miss); the hand is left out; the dynamic recording gets its
    own diagnosis."""
    from artitwin_core.articulation import render_twin
    from artitwin_core.gaussians import GaussianParams
    from artitwin_core.joints import Joint
    from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
    from infra.store import ArtifactStore
    from schemas import (
        CaptureArtifact,
        DiagnosisReport,
        GaussianCheckpoint,
        JointSet,
        MaskSequenceArtifact,
        Registration,
    )
    from schemas._diagnose import ViewPrediction
    from tasks import to_core

    st = ArtifactStore(store_url)
    get = lambda name, kind: st.get(summary["stages"][name]["key"], kind)  # noqa: E731
    pred, dyn = get("predict_dynamic", ViewPrediction), get("ingest/dynamic", CaptureArtifact)
    assert pred.rgb.shape == dyn.rgb.shape and pred.depth.shape == dyn.depth.shape
    assert not (pred.coverage & get("part_masks", MaskSequenceArtifact).hand).any()  # the twin has no hand
    truth = generate_scene(BENCHMARK_SCENES["tiny"]).truth
    q_true, q_fit = truth.joints[0].q, get("joint_states", JointSet).joints[0].q
    # joint_states measured the fully open door from depth (the tracks alone stop near 61 of 69 deg).
    assert abs(np.degrees(q_fit[-1] - q_true[-1])) < 2.0, np.degrees([q_fit[-1], q_true[-1]])
    t = int(np.flatnonzero((q_true > 0.4) & (np.abs(q_fit - q_true) < 0.05))[0])
    part = truth.part_masks[t][::2, ::2] == 1  # RGB -> depth grid (2:1 in the tiny scene)
    twin = to_core(GaussianParams, get("articulate", GaussianCheckpoint))
    joint = to_core(Joint, get("joint_states", JointSet).joints[0])
    pose = get("register", Registration).canonical_from_session @ dyn.world_from_camera[t]
    _, closed, _ = render_twin(twin, [joint], [0.0], pose, dyn.depth_intrinsics[t], dyn.depth.shape[2], dyn.depth.shape[1])
    ok = part & np.isfinite(pred.depth[t]) & (dyn.depth[t] > 0) & (closed > 0)
    assert ok.sum() > 50, ok.sum()
    err_twin = np.median(np.abs(pred.depth[t] - dyn.depth[t])[ok])
    err_closed = np.median(np.abs(closed - dyn.depth[t])[ok])
    assert err_twin < 0.05 and err_twin < 0.5 * err_closed, (t, err_twin, err_closed)
    report = get("diagnose_dynamic", DiagnosisReport)
    assert report.findings and {f.scope for f in report.findings} == {"dynamic recording"}
    assert "diagnosis_dynamic.html" in summary["exports"]
