"""bench/bench_generalization.py's comparison with the ground truth, on a summary made from the truth.

The benchmark's own numbers are only as good as this: the true joints must score zero error, a
joint that moves nothing (or moves another way) must match no part, and an exported link that
matches no part must count as spurious.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(BENCH))
    try:
        spec = importlib.util.spec_from_file_location("bench_generalization", BENCH / "bench_generalization.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(BENCH))


def _as_summary_joint(j, name: str) -> dict:
    return {"name": name, "type": j.joint_type, "axis": j.axis.tolist(), "pivot": j.pivot.tolist(),
            "range": j.q_range.tolist(), "q": j.q.tolist(), "pitch": j.pitch}


def _urdf(path: Path, parts: list[tuple[str, str]]) -> None:
    links = "".join(f'<link name="{name}"/>' for name, _ in parts)
    joints = "".join(f'<joint name="{name}_joint" type="{kind}"><parent link="base"/><child link="{name}"/></joint>'
                     for name, kind in parts)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'<robot name="twin"><link name="world"/><link name="base"/>{links}{joints}</robot>')


def test_the_truth_scores_zero_and_extra_parts_are_spurious(bench, make_scene, tmp_path):
    scene = make_scene(furniture="door+drawer", static_frames=2, dynamic_frames=8, hand_occlusion=0.0)
    door, drawer = scene.truth.joints
    still = {"name": "joint_2", "type": "fixed", "axis": [0.0, 1.0, 0.0], "pivot": [0.0, 0.0, 0.0],
             "range": [0.0, 0.0], "q": [0.0] * len(door.q), "pitch": 0.0}
    # Listed out of order, with a joint that moves nothing: matching must not depend on the order.
    summary = {"joints": [_as_summary_joint(drawer, "joint_0"), _as_summary_joint(door, "joint_1"), still],
               "parts": [{"fate": "kept"}, {"fate": "kept"}, {"fate": "merged", "into": 0}]}
    _urdf(tmp_path / "export" / "twin.urdf", [("part_0", "prismatic"), ("part_1", "revolute"), ("part_2", "fixed")])
    result = bench.evaluate(scene, summary, tmp_path)
    parts = result["parts"]
    assert [p["joint"] for p in parts] == [1, 0]
    for p in parts:
        assert p["type_ok"] and p["match_cost"] < 1e-9
        assert p["axis_deg"] < 1e-6 and p["state_rmse"] < 1e-9
    assert parts[0]["pivot_mm"] < 1e-6 and np.isnan(parts[1]["pivot_mm"])
    assert result["spurious_joints"] == 1
    assert result["spurious_exported"] == 1 and result["spurious_exported_kinds"] == ["fixed"]
    assert result["fates"] == {"kept": 2, "merged": 1}


def test_a_wrong_joint_is_measured_or_left_unmatched(bench, make_scene, tmp_path):
    scene = make_scene(static_frames=2, dynamic_frames=8, hand_occlusion=0.0)
    (door,) = scene.truth.joints
    off = _as_summary_joint(door, "joint_0")
    off["pivot"] = (door.pivot + [0.01, 0.0, 0.0]).tolist()  # 1 cm off: still the door, measured
    result = bench.evaluate(scene, {"joints": [off]}, tmp_path)
    assert result["parts"][0]["matched"]
    assert result["parts"][0]["pivot_mm"] == pytest.approx(10.0, abs=1e-6)
    swapped = _as_summary_joint(door, "joint_0")
    swapped["axis"] = [0.0, 0.0, 1.0]  # a slide instead of a swing: moves the door elsewhere
    swapped["type"] = "prismatic"
    result = bench.evaluate(scene, {"joints": [swapped]}, tmp_path)
    assert not result["parts"][0]["matched"] and result["spurious_joints"] == 1
    assert not result["urdf_found"] and result["spurious_exported"] == 0


def test_a_summary_that_reports_a_failure_is_a_crash(bench):
    assert bench.failure_of({"stages": {"register": {"status": "computed"}}}) is None
    assert "fit_joints" in bench.failure_of({"stages": {"fit_joints": {"status": "failed", "error": "0 valid tracks"}}})
    assert "boom" in bench.failure_of({"failed": {"stage": "articulate", "error": "boom"}})
    json.dumps(bench.TARGETS)  # the results file carries them


def test_every_named_scene_is_described_with_its_effects_defaults(bench):
    """`--named high-noise` and `sensor-effects` crashed in the harness: they give the exposure
    effect no parameters, and the description read them without the defaults."""
    from artitwin_core.synth import BENCHMARK_SCENES

    described = {name: bench.describe(spec) for name, spec in BENCHMARK_SCENES.items()}
    assert described["high-noise"].endswith("exp0.35") and described["sensor-effects"].endswith("exp0.35")
    assert "exp" not in described["tiny"]
