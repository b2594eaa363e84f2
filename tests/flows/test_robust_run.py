"""A scene run never dies on a part: spurious candidates are dropped and reported, and a failed
stage still leaves a summary with the static recording's diagnosis (inline executor, tiny scene)."""

from __future__ import annotations

import functools
import json
import re
from dataclasses import replace

import numpy as np
import pytest

from artitwin_core.masks import MaskSequence
from flows._pipeline import SceneFailed
from flows.scene import run_scene_inline
from infra.store import ArtifactStore
from schemas import PipelineConfig


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    # Shared by the tests below so the second reuses the first's static stages (they do not
    # depend on the part masks the first one patches).
    return str(tmp_path_factory.mktemp("robust") / "store")


def _light() -> PipelineConfig:
    """The quick preset with a third of its 3DGS and stage IV steps: these tests judge what
    becomes of each part and stage, not the twin's pixels (training took 38 of a quick run's 105 s)."""
    quick = PipelineConfig.preset("quick")
    return quick.model_copy(update={
        "reconstruct": quick.reconstruct.model_copy(update={"steps": 100}),
        "articulate": quick.articulate.model_copy(update={"phase1_steps": 40, "phase2_steps": 20}),
    })


def _registration_again() -> PipelineConfig:
    """``_light`` with another registration config: the register stage runs (and fails) again in
    the shared store, whose static stages stay cached."""
    light = _light()
    return light.model_copy(update={"registration": light.registration.model_copy(update={"yaw_step_deg": 3.0})})


def _free_window(free: np.ndarray, size: int) -> tuple[int, int]:
    """Top-left corner of a ``size`` x ``size`` window inside ``free [H, W]``."""
    h, w = free.shape
    for y in range(h - size):
        for x in range(w - size):
            if free[y : y + size, x : x + size].all():
                return y, x
    raise AssertionError("no free window")


@pytest.mark.slow
def test_untrackable_and_depthless_candidates_are_dropped_not_exported(tiny_scene, store, tmp_path, monkeypatch):
    import tasks.register as register

    real = register.segment_parts

    @functools.wraps(real)
    def with_spurious_parts(dynamic, *args, **kwargs):
        seg = real(dynamic, *args, **kwargs)
        part = seg.masks.part.copy()
        free = ((part == 0) & ~seg.masks.hand).all(0)
        y, x = _free_window(free, 24)
        part[:, y + 1, x + 1] = 2  # a one-pixel speck in every frame: too little depth to build it
        part[-1, y + 4 : y + 24, x + 4 : x + 24] = 3  # a patch seen in the last frame only: nothing to track
        masks = MaskSequence(part=part, hand=seg.masks.hand, score=seg.masks.score)
        return replace(seg, masks=masks, candidates=np.array([*seg.candidates, 5, 6], np.int32))

    monkeypatch.setattr(register, "segment_parts", with_spurious_parts)
    out = tmp_path / "out"
    summary = run_scene_inline(tiny_scene, _light(), store, out=out)
    assert summary["status"] == "ok"
    fates = {p["candidate"]: p for p in json.loads((out / "summary.json").read_text())["parts"]}
    assert fates[0]["fate"] == "kept" and fates[0]["joint"] == "joint_0"
    assert fates[5]["fate"] == "dropped" and "too few depth points" in fates[5]["reason"], fates[5]
    assert fates[6]["fate"] == "dropped" and fates[6]["part"] is None, fates[6]
    assert "no kept part touches it" in fates[6]["reason"], fates[6]
    assert "could be tracked" in fates[6]["reason"] or "no joint could be fitted" in fates[6]["reason"], fates[6]
    assert [j["name"] for j in summary["joints"]] == ["joint_0"] and summary["joints"][0]["type"] == "revolute"
    # The export has the one real part and nothing of the spurious ones.
    urdf = (out / "export" / "twin.urdf").read_text()
    assert re.findall(r'<link name="([^"]+)"', urdf) == ["world", "base", "part_0"]
    assert re.findall(r'<joint name="([^"]+)"', urdf) == ["world_to_base", "part_0_joint"]
    assert summary["stages"]["final_masks"]["status"] == "computed"
    # The kept part carries the part finder's depth-fitted joint beside its tracks' (joint_states' second opinion).
    final = ArtifactStore(store).get(summary["stages"]["final_masks"]["key"])
    assert [(j.name, j.joint_type) for j in final.depth_joints] == [("joint_0", "revolute")]
    notes = " ".join(summary["stages"]["settle_parts"]["notes"])
    assert "candidate part 5: dropped" in notes and "candidate part 6: dropped" in notes


def test_a_failed_stage_leaves_a_summary_and_the_static_diagnosis(tiny_scene, store, tmp_path, monkeypatch):
    faults = tmp_path / "faults"
    faults.mkdir()
    (faults / "register.json").write_text(json.dumps({"stage": "register", "action": "fail"}))
    monkeypatch.setenv("ARTITWIN_FAULTS", str(faults))
    out = tmp_path / "out"
    with pytest.raises(SceneFailed, match="stage register failed: RuntimeError: injected failure") as err:
        run_scene_inline(tiny_scene, _registration_again(), store, out=out)
    summary = json.loads((out / "summary.json").read_text())
    assert summary == err.value.summary | {"exports": summary["exports"]}
    assert summary["status"] == "failed" and summary["failed_stages"] == ["register"]
    stages = summary["stages"]
    assert stages["register"]["status"] == "failed" and "injected failure" in stages["register"]["error"]
    # Nothing downstream of the registration ran (no parts were invented), and it says why.
    for name in ("part_masks", "track", "settle_parts", "joint_states", "articulate", "export"):
        assert stages[name] == {"stage": name, "label": stages[name]["label"], "status": "skipped",
                                "error": "not run: register failed", "seconds": 0.0}, stages[name]
    assert summary["joints"] == [] and summary["parts"] == []
    # What completed is there, and the static recording is diagnosed all the same.
    assert stages["reconstruct"]["status"] in ("computed", "cached")
    assert stages["diagnose_static"]["status"] == "computed" and stages["diagnose_static"]["notes"]
    assert "diagnosis.html" in summary["exports"]


@pytest.mark.slow
def test_a_scene_where_nothing_moved_ends_with_a_static_twin(tiny_scene, store, tmp_path):
    """The static recording given twice (one AR session: the registration is the identity)."""
    import shutil

    still = tmp_path / "still"
    still.mkdir()
    for name in ("static.r3d", "dynamic.r3d"):
        shutil.copy(tiny_scene / "static.r3d", still / name)
    out = tmp_path / "out"
    summary = run_scene_inline(still, _light(), store, out=out)
    assert summary["status"] == "ok" and summary["joints"] == [] and summary["parts"] == []
    assert any("No moving part found" in n for n in summary["stages"]["settle_parts"]["notes"])
    reg = np.asarray(summary["stages"]["register"]["canonical_from_session"])
    assert np.abs(reg - np.eye(4)).max() < 0.02, reg
    urdf = (out / "export" / "twin.urdf").read_text()
    assert re.findall(r'<link name="([^"]+)"', urdf) == ["world", "base"]
    assert re.findall(r'<joint name="([^"]+)"', urdf) == ["world_to_base"]
    assert summary["stages"]["diagnose"]["notes"] and "diagnosis.html" in summary["exports"]


def test_the_command_line_exits_non_zero_on_a_failed_stage(tiny_scene, store, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from artitwin.cli import app

    faults = tmp_path / "faults"
    faults.mkdir()
    (faults / "f.json").write_text(json.dumps({"stage": "register", "action": "fail"}))
    monkeypatch.setenv("ARTITWIN_FAULTS", str(faults))
    config = tmp_path / "config.json"
    config.write_text(_registration_again().model_dump_json())
    result = CliRunner().invoke(app, ["run", str(tiny_scene), "--config", str(config), "--no-prefect", "--store", store,
                                      "--out", str(tmp_path / "out")])
    assert result.exit_code == 1, result.output
    assert "register failed" in result.output and (tmp_path / "out" / "summary.json").is_file()
