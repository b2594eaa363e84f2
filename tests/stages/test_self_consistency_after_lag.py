"""After a pose-lag correction, the static recording's self-consistency test leaves out the frames
whose corrected time the recorded trajectory does not reach: they keep its end pose, and their
pose error faked a depth error in a recording whose depth is exact."""

from __future__ import annotations

import dataclasses
from dataclasses import replace

import numpy as np
import pytest

from artitwin_core.capture import correct_pose_lag
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
from schemas import CaptureArtifact, PoseLagResult
from schemas._diagnose import DiagnoseConfig
from tasks import to_artifact
from tasks._consistency import held_by_lag, self_consistency

LAG_S = 0.067  # two frames of a 30 fps stream, here one frame interval (every second frame kept)


def _corrected(stride: int) -> CaptureArtifact:
    """The tiny door at twice its size, 16 static frames (every ``stride``-th of 30 fps), its
    poses ``LAG_S`` late and corrected with the true lag; the depth is exact."""
    tiny = BENCHMARK_SCENES["tiny"]
    spec = replace(tiny, seed=0, static_frames=16, static_stride=stride, rgb_size=(256, 192), depth_size=(128, 96),
                   effects=(("pose_lag", {"seconds": LAG_S, "recordings": "static"}),))
    cap = generate_scene(spec).static
    fixed = dataclasses.replace(cap, world_from_camera=correct_pose_lag(cap.world_from_camera, cap.timestamps, LAG_S))
    return to_artifact(CaptureArtifact, fixed)


@pytest.fixture(scope="module")
def corrected():
    return _corrected(2)


def _depth_finding(findings):
    return next(f for f in findings if f.name == "depth_scale_offset")


def test_frames_holding_the_end_pose_are_left_out(corrected):
    lag = PoseLagResult.model_construct(estimated=True, applied=True, lag_s=LAG_S,
                                        frame_interval_s=float(np.median(np.diff(corrected.timestamps))))
    held = held_by_lag(corrected.timestamps, lag)
    assert held.tolist() == [False] * 14 + [True] * 2
    assert not held_by_lag(corrected.timestamps, lag.model_copy(update={"applied": False})).any()
    # Measured (bench/bench_lag_interpolation.py): with them, +23 mm at 1.8 m, 3.2 standard
    # errors, past the gate; without them +0.4 +- 2.6 mm.
    with_them = _depth_finding(self_consistency(corrected, DiagnoseConfig())[0])
    assert with_them.enabled and with_them.params["error_m"] > 0.015, with_them.params
    without = _depth_finding(self_consistency(corrected, DiagnoseConfig(), lag)[0])
    assert not without.enabled and abs(without.params["error_m"]) < 0.005, without.params
    assert np.isfinite(without.params["error_se_m"])


def test_a_depth_error_from_poses_interpolated_far_apart_is_reported_not_enabled():
    """Frames 0.27 s apart: the spline between them leaves the corrected poses about a millimetre
    off, which fakes -15 mm at 1.8 m (bench_lag_interpolation); the test cannot tell it from a
    sensor's error, so it says so instead of asking for the depth to be modelled."""
    capture = _corrected(8)
    lag = PoseLagResult.model_construct(estimated=True, applied=True, lag_s=LAG_S,
                                        frame_interval_s=float(np.median(np.diff(capture.timestamps))))
    plain = _depth_finding(self_consistency(capture, DiagnoseConfig())[0])
    assert plain.enabled and plain.params["error_m"] < -0.01, plain.params  # the fake, enabled without the lag
    findings, lines = self_consistency(capture, DiagnoseConfig(), lag)
    found = _depth_finding(findings)
    assert found.significant and not found.enabled, found.params
    assert any("Not enabled: its poses were corrected for a lag" in line and "0.27 s apart" in line for line in lines)
    # Frames close enough together are judged as before.
    close = _depth_finding(self_consistency(capture, DiagnoseConfig(max_lag_interpolation_s=0.5), lag)[0])
    assert close.enabled
