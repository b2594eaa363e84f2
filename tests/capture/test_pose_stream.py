"""A recording's pose stream: the poses of the frames not read (a Record3D export with frames
removed, a strided or keyframed read) are kept, written and read back, and a pose lag is
corrected off them rather than off chords between frames far apart.

The tiny scene keeps every 8th frame of a 30 fps stream (0.27 s apart); its generator records a
pose for every frame of the stream, as a phone does.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from artitwin_core.capture import (
    ReadOptions,
    correct_pose_lag,
    estimate_pose_lag,
    lag_corrected,
    read_capture,
    write_nerfstudio,
    write_r3d,
    write_record3d_exr,
    write_stray,
)
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene
from schemas import PoseLagResult
from tasks._consistency import lag_pose_spacing

LAG_S = 0.067  # two frames of the 30 fps stream
TINY = BENCHMARK_SCENES["tiny"]


@pytest.fixture(scope="module")
def late():
    """The tiny scene (RGB and depth at twice their size) with its static poses ``LAG_S`` late."""
    spec = replace(TINY, seed=0, rgb_size=tuple(2 * v for v in TINY.rgb_size),
                   depth_size=tuple(2 * v for v in TINY.depth_size),
                   effects=(("pose_lag", {"seconds": LAG_S, "recordings": "static"}),))
    return generate_scene(spec)


def _no_stream(cap):
    return replace(cap, stream_world_from_camera=None, stream_timestamps=None, stream_frame_ids=None)


def _off_mm(a: np.ndarray, b: np.ndarray, depth_m: float = 1.5) -> np.ndarray:
    """``[T]`` mm between where poses ``a`` and ``b`` put the point ``depth_m`` ahead of the camera."""
    p = np.array([0.0, 0.0, depth_m])
    return 1e3 * np.linalg.norm((a[:, :3, :3] - b[:, :3, :3]) @ p + a[:, :3, 3] - b[:, :3, 3], axis=1)


def test_the_generator_records_a_pose_for_every_frame_of_the_stream(late):
    cap = late.static
    assert cap.frame_ids.tolist() == list(range(0, 8 * cap.num_frames, 8))
    np.testing.assert_array_equal(cap.stream_frame_ids, np.arange(cap.frame_ids[-1] + 1))
    np.testing.assert_allclose(cap.stream_timestamps, cap.stream_frame_ids / 30.0)
    np.testing.assert_array_equal(cap.stream_world_from_camera[cap.frame_ids], cap.world_from_camera)
    # between the frames the poses move on: not the frames' poses repeated
    assert np.abs(cap.stream_world_from_camera[4, :3, 3] - cap.world_from_camera[0, :3, 3]).max() > 1e-3


@pytest.mark.parametrize("fmt", ["r3d", "exr"])
def test_record3d_files_keep_the_stream_and_a_strided_read_still_has_it(late, tmp_path, fmt):
    cap = late.static
    path = write_r3d(cap, tmp_path / "s.r3d") if fmt == "r3d" else write_record3d_exr(cap, tmp_path / "s")
    back = read_capture(path, ReadOptions(stride=3))
    assert back.frame_ids.tolist() == cap.frame_ids[::3].tolist()
    np.testing.assert_array_equal(back.stream_frame_ids, cap.stream_frame_ids)
    np.testing.assert_allclose(back.stream_world_from_camera, cap.stream_world_from_camera, atol=1e-6)
    np.testing.assert_allclose(back.stream_timestamps, cap.stream_timestamps, atol=1e-9)
    np.testing.assert_array_equal(back.stream_world_from_camera[back.frame_ids], back.world_from_camera)


def test_an_exporters_repeated_poses_are_not_read_as_recorded(late, tmp_path):
    """Without a stream the writer fills the removed frames' rows with the nearest frame's pose
    (as ArtiTwin's writer always did): read back, those repeats are not a stream."""
    path = write_r3d(_no_stream(late.static), tmp_path / "plain.r3d")
    assert read_capture(path).stream_world_from_camera is None  # every frame read: nothing to add
    strided = read_capture(path, ReadOptions(stride=2))
    np.testing.assert_array_equal(strided.stream_frame_ids, late.static.frame_ids)  # the frames' poses only


@pytest.mark.parametrize("writer", [write_stray, write_nerfstudio])
def test_a_strided_read_of_other_formats_keeps_every_listed_pose(late, tmp_path, writer):
    cap = late.static
    back = read_capture(writer(cap, tmp_path / "rec"), ReadOptions(stride=4))
    assert back.num_frames == 3
    np.testing.assert_array_equal(back.stream_frame_ids, cap.frame_ids)
    np.testing.assert_allclose(back.stream_world_from_camera, cap.world_from_camera, atol=1e-6)
    assert read_capture(writer(cap, tmp_path / "all")).stream_world_from_camera is None


def test_a_lag_is_corrected_off_the_stream_not_off_chords(late):
    """Measured (seed 0): the frames' chords leave the corrected poses 1.2 mm off at the median
    (8 mm at the last frame, which holds the end pose); the stream's poses put every frame but
    the last exactly where it was. The lag is estimated as 67.3 ms off the stream, 64.6 ms off
    the frames (true 67)."""
    cap, truth = late.static, np.asarray(late.truth.static_world_from_camera)
    chords = _off_mm(correct_pose_lag(cap.world_from_camera, cap.timestamps, LAG_S), truth)[:-1]
    streamed = _off_mm(correct_pose_lag(cap.world_from_camera, cap.timestamps, LAG_S, cap.pose_track()), truth)[:-1]
    assert np.median(chords) > 0.5 and np.median(streamed) < 0.01 and streamed.max() < 0.01
    fixed = lag_corrected(cap, LAG_S)
    np.testing.assert_allclose(fixed.world_from_camera[:-1], truth[:-1], atol=1e-6)
    np.testing.assert_array_equal(fixed.stream_world_from_camera[fixed.frame_ids], fixed.world_from_camera)

    lag, lag_frames = estimate_pose_lag(cap), estimate_pose_lag(_no_stream(cap))
    assert lag.pose_interval_s == pytest.approx(1 / 30) and lag_frames.pose_interval_s == pytest.approx(8 / 30)
    assert abs(lag.lag_s - LAG_S) < 0.002 and abs(lag.lag_s - LAG_S) < abs(lag_frames.lag_s - LAG_S)


def test_the_diagnosis_gates_on_the_spacing_of_the_poses_read_between():
    def result(pose_interval_s: float) -> PoseLagResult:
        return PoseLagResult(
            estimated=True, lag_s=0.067, lag_frames=0.25, lag_se_s=0.002, frame_interval_s=0.267,
            pose_interval_s=pose_interval_s, z_score=30.0, agreement_z=7.0, disagreement_zero=0.2,
            disagreement_lag=0.1, residual_zero_m=0.01, residual_lag_m=0.005, lags_frames=np.zeros(0),
            disagreement=np.zeros(0), searched_frames=1.0, frames_used=10, pairs=20, method="m",
            significant=True, applied=True,
        )

    assert lag_pose_spacing(result(1 / 30)) == pytest.approx(1 / 30)
    assert lag_pose_spacing(result(float("nan"))) == pytest.approx(0.267)  # stored before the field: the frames'
    assert lag_pose_spacing(result(1 / 30).model_copy(update={"applied": False})) == 0.0
