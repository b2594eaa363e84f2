"""What correcting a pose lag costs when the frames are far apart (issue 28): the corrected poses
are read off the recorded trajectory between frames, and that interpolation error is a fake depth
error to the static recording's self-consistency test.

The tiny door scene at twice its size (256 x 192 RGB, 128 x 96 depth), 16 static frames, the
static poses recorded ``--lag`` seconds late. For each frame spacing (``--strides``: every n-th
frame of a 30 fps stream), the poses corrected with the true lag (``correct_pose_lag``: cubic
splines through the recorded poses, ``interpolate_poses``) are compared with the true poses: the displacement of the point
at the scene's median depth ahead of each camera (mm; median and worst frame, the worst usually
the last, which keeps its end pose). Then the depth error the self-consistency test finds
(``estimate_depth_calibration``, as ``diagnose`` runs it) at the corrected poses and at the true
poses, in mm at the reference depth with its standard error (the injected depth is exact, so any
error found is the poses'), and at the corrected poses without the frames that hold the end pose.

    .venv/bin/python bench/bench_lag_interpolation.py
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from _common import print_table, write_results

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from artitwin_core.capture import (  # noqa: E402
    DepthCalibrationConfig,
    beyond_recorded,
    correct_pose_lag,
    estimate_depth_calibration,
)
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene  # noqa: E402


def _displacement_mm(a: np.ndarray, b: np.ndarray, depth_m: float) -> np.ndarray:
    """``[T]`` distance (mm) between where poses ``a`` and ``b [T, 4, 4]`` put the point
    ``depth_m`` ahead of the camera."""
    p = np.array([0.0, 0.0, depth_m])
    return 1e3 * np.linalg.norm((a[:, :3, :3] - b[:, :3, :3]) @ p + a[:, :3, 3] - b[:, :3, 3], axis=1)


def _depth_error(capture, poses) -> tuple[float, float]:
    cal = estimate_depth_calibration(capture, world_from_camera=poses, config=DepthCalibrationConfig(step_tolerance_m=1e-4))
    return 1e3 * ((cal.scale - 1.0) * cal.reference_depth_m + cal.offset_m), 1e3 * cal.error_se_m


def row(stride: int, lag_s: float, seed: int, size: int) -> dict:
    tiny = BENCHMARK_SCENES["tiny"]
    spec = replace(tiny, seed=seed, static_frames=16, static_stride=stride,
                   rgb_size=tuple(size * v for v in tiny.rgb_size), depth_size=tuple(size * v for v in tiny.depth_size),
                   effects=(("pose_lag", {"seconds": lag_s, "recordings": "static"}),))
    scene = generate_scene(spec)
    cap, truth = scene.static, np.asarray(scene.truth.static_world_from_camera, np.float64)
    z = float(np.nanmedian(cap.depth))
    recorded = _displacement_mm(np.asarray(cap.world_from_camera, np.float64), truth, z)
    # the frames whose corrected time the recorded stream does not reach keep its end pose
    kept = np.nonzero(~beyond_recorded(cap.timestamps, lag_s))[0]
    err_t, se_t = _depth_error(dataclasses.replace(cap, world_from_camera=truth), truth)
    out = {
        "stride": stride, "frame_interval_s": float(np.median(np.diff(cap.timestamps))), "lag_s": lag_s,
        "recorded_pose_error_mm_median": float(np.median(recorded)), "held_frames": int(cap.num_frames - len(kept)),
        "depth_error_true_poses_mm": err_t, "depth_error_true_poses_se_mm": se_t,
    }
    # read off the frames' own poses (splines through them), and off the 30 fps pose stream
    for name, track in (("frames", None), ("stream", cap.pose_track())):
        corrected = correct_pose_lag(cap.world_from_camera, cap.timestamps, lag_s, track)
        off = _displacement_mm(corrected, truth, z)
        err_c, se_c = _depth_error(cap, corrected)
        err_k, se_k = _depth_error(cap.select_frames(kept), corrected[kept])
        out.update({
            f"{name}_pose_error_mm_median": float(np.median(off)), f"{name}_pose_error_mm_max": float(np.max(off)),
            f"{name}_depth_error_mm": err_c, f"{name}_depth_error_se_mm": se_c,
            f"{name}_depth_error_without_held_mm": err_k, f"{name}_depth_error_without_held_se_mm": se_k,
        })
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strides", type=int, nargs="+", default=[8, 4, 2], help="every n-th frame of a 30 fps stream")
    ap.add_argument("--lag", type=float, default=0.067, help="the static poses' lag, seconds")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=2, help="the tiny scene's RGB and depth sizes times this")
    args = ap.parse_args()
    rows = [row(s, args.lag, args.seed, args.size) for s in args.strides]
    print_table(rows)
    write_results("lag_interpolation", rows, {"seed": args.seed, "scene": f"tiny x{args.size}, 16 static frames"})


if __name__ == "__main__":
    main()
