"""write_scene through the capture writers, read back with the capture readers, and the ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from artitwin_core import InputError
from artitwin_core.capture import find_scene_recordings, read_capture
from artitwin_core.synth import load_ground_truth, load_scene_spec, write_scene


def _compare(read, cap, depth_atol):
    assert read.rgb.shape == cap.rgb.shape
    # JPEG quality 95 at 128x96 on these textures: measured mean |diff| 2.4 grey levels.
    assert np.abs(read.rgb.astype(float) - cap.rgb).mean() < 4.0
    np.testing.assert_array_equal(np.isnan(read.depth), np.isnan(cap.depth))
    ok = np.isfinite(cap.depth)
    np.testing.assert_allclose(read.depth[ok], cap.depth[ok], atol=depth_atol)
    np.testing.assert_allclose(read.world_from_camera, cap.world_from_camera, atol=1e-9)
    np.testing.assert_allclose(read.rgb_intrinsics, cap.rgb_intrinsics, atol=1e-9)
    np.testing.assert_allclose(read.depth_intrinsics, cap.depth_intrinsics, atol=1e-9)
    np.testing.assert_allclose(read.timestamps, cap.timestamps, atol=1e-9)
    np.testing.assert_array_equal(read.frame_ids, cap.frame_ids)


@pytest.mark.parametrize("fmt", ["r3d", "nerfstudio"])
def test_written_scene_reads_back_as_the_generated_captures(tiny, tmp_path, fmt):
    out = write_scene(tiny, tmp_path / "scene", fmt=fmt)
    names = json.loads((out / "scene.json").read_text())
    rec = find_scene_recordings(out)
    assert rec.static.name == names["static"] and rec.dynamic.name == names["dynamic"]
    for role in ("static", "dynamic"):
        cap = getattr(tiny, role)
        read = read_capture(getattr(rec, role))
        # r3d stores float32 depth as is; nerfstudio uint16 millimetres (0.5 mm rounding).
        _compare(read, cap, depth_atol=0.0 if fmt == "r3d" else 5.01e-4)
        if fmt == "r3d":
            np.testing.assert_array_equal(read.confidence, cap.confidence)


def test_ground_truth_round_trips(tiny, tmp_path):
    out = write_scene(tiny, tmp_path / "scene")
    truth = load_ground_truth(out)
    ref = tiny.truth
    for name in ("part_masks", "hand_masks", "static_world_from_camera", "dynamic_world_from_camera",
                 "canonical_from_dynamic_session", "part_world_from_closed"):
        np.testing.assert_array_equal(getattr(truth, name), getattr(ref, name))
    assert truth.effects == ref.effects
    assert len(truth.joints) == len(ref.joints)
    for a, b in zip(truth.joints, ref.joints, strict=True):
        assert a.joint_type == b.joint_type and a.pitch == b.pitch
        for name in ("axis", "pivot", "q", "q_range", "residual", "confidence"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert load_scene_spec(out) == tiny.spec


def test_effects_and_spec_survive_the_json(make_scene, tmp_path):
    scene = make_scene(static_frames=3, dynamic_frames=4, effects=(("screw_joint", {"rise_m_per_rad": 0.02}),))
    out = write_scene(scene, tmp_path / "s")
    assert load_scene_spec(out) == scene.spec
    truth = load_ground_truth(out)
    assert truth.effects == {"screw_joint": {"rise_m_per_rad": 0.02}}
    assert truth.joints[0].joint_type == "screw" and truth.joints[0].pitch == scene.truth.joints[0].pitch


def test_recorded_distortion_needs_a_format_that_stores_it(make_scene, tmp_path):
    scene = make_scene(static_frames=3, dynamic_frames=4, effects=(("lens_distortion", {"record": True}),))
    with pytest.raises(InputError, match="nerfstudio"):
        write_scene(scene, tmp_path / "r3d", fmt="r3d")
    out = write_scene(scene, tmp_path / "ns", fmt="nerfstudio")
    read = read_capture(out / "static")
    np.testing.assert_allclose(read.distortion[:4], scene.static.distortion, atol=1e-12)


def test_missing_ground_truth_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="ground_truth"):
        load_ground_truth(tmp_path)
    with pytest.raises(InputError, match="fmt"):
        write_scene(None, tmp_path, fmt="mp4")


def test_cli_synth_random_writes_the_seeded_draw(monkeypatch, tmp_path):
    """``artitwin synth random --seed N`` renders ``random_scene_spec(N)``; ``--list`` names it."""
    from typer.testing import CliRunner

    import artitwin_core.synth as synth
    from artitwin.cli import app

    seen = []
    monkeypatch.setattr(synth, "random_scene_spec", lambda seed: f"spec-{seed}")
    monkeypatch.setattr(synth, "generate_scene", lambda spec: seen.append(spec) or spec)
    monkeypatch.setattr(synth, "write_scene", lambda scene, out, fmt: seen.append((out, fmt)))
    result = CliRunner().invoke(app, ["synth", "random", "--seed", "5", "--out", str(tmp_path / "r"),
                                      "--format", "nerfstudio"])
    assert result.exit_code == 0, result.output
    assert seen == ["spec-5", (tmp_path / "r", "nerfstudio")]
    listed = CliRunner().invoke(app, ["synth", "--list"])
    assert "random:" in listed.output
