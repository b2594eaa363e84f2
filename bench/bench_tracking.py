"""Benchmark of ``artitwin_core.tracking.track_part_points`` on the synthetic benchmark scenes.

Masks are the generator's ground-truth part and hand masks (not a segmenter's), and the
registration is the true ``canonical_from_dynamic_session``: this measures the tracker alone.
Per scene and part: tracks, valid fraction, 3D error (median / p90) of every valid sample
against the true position of its surface point (the noise-free render's point under the
query pixel, moved by the part's true motion), 2D error in pixels, samples on the hand, the
fraction of the part's opening covered by frames with tracks, and seconds (median of repeats).
Then ``estimate_joint`` on those tracks, with the reference frame at the first closed frame
(true q = 0) that has tracks: axis error (deg), pivot-to-axis distance (mm), mean state error,
range error and the chosen type.

Run: ``python bench/bench_tracking.py [--scenes tiny door ...] [--repeats 3]``; prints a table
and writes ``bench/results/tracking.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, write_results  # noqa: E402

from artitwin_core.joints import estimate_joint, joint_errors  # noqa: E402
from artitwin_core.masks import MaskSequence  # noqa: E402
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, render_state  # noqa: E402
from artitwin_core.tracking import (  # noqa: E402
    TrackingConfig,
    lift_pixels,
    track_errors_m,
    track_part_points,
    true_track_positions,
)


def true_positions(scene, traj, part: int) -> np.ndarray:
    """``[T, N, 3]`` true canonical positions of the tracked surface points."""
    d, tr = scene.dynamic, scene.truth
    q = traj.query_frame
    pose = tr.dynamic_world_from_camera[q]
    w, h = d.rgb_size
    _, depth, _ = render_state(scene, pose, d.rgb_intrinsics[q], w, h, [j.q[q] for j in tr.joints])
    # The render is pinhole; with a distorted recording the query pixel is undistorted first.
    xq, _ = lift_pixels(traj.pixels[q], depth, None, d.rgb_intrinsics[q], d.rgb_intrinsics[q], pose, d.distortion)
    return true_track_positions(traj, tr.part_world_from_closed[part], xq)


def pixel_errors(scene, traj, truth: np.ndarray) -> np.ndarray:
    """``[T, N]`` pixels between each valid track and its true point projected with the true pose."""
    d, tr = scene.dynamic, scene.truth
    out = np.full(traj.valid.shape, np.nan)
    dist = np.zeros(5) if d.distortion is None else d.distortion
    for t in range(traj.valid.shape[0]):
        v = traj.valid[t] & np.all(np.isfinite(truth[t]), axis=1)
        if not v.any():
            continue
        cam_from_world = np.linalg.inv(tr.dynamic_world_from_camera[t])
        fx, fy, cx, cy = d.rgb_intrinsics[t]
        k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        rvec, _ = cv2.Rodrigues(cam_from_world[:3, :3])
        uv, _ = cv2.projectPoints(truth[t, v], rvec, cam_from_world[:3, 3], k, dist)
        out[t, v] = np.linalg.norm(uv.reshape(-1, 2) - traj.pixels[t, v], axis=1)
    return out


def on_hand(scene, traj) -> float:
    t, n = np.nonzero(traj.valid)
    if t.size == 0:
        return float("nan")
    px = np.rint(traj.pixels[t, n]).astype(int)
    return float(scene.truth.hand_masks[t, px[:, 1], px[:, 0]].mean())


def bench_scene(name: str, repeats: int, config: TrackingConfig) -> list[dict]:
    scene = generate_scene(BENCHMARK_SCENES[name])
    d, tr = scene.dynamic, scene.truth
    masks = MaskSequence(part=tr.part_masks, hand=tr.hand_masks, score=np.ones(d.num_frames, np.float32))
    rows = []
    for k, joint_true in enumerate(tr.joints):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            traj = track_part_points(d, masks, tr.canonical_from_dynamic_session, part_label=k + 1, config=config)
            times.append(time.perf_counter() - t0)
        row = {"scene": name, "part": k, "joint_true": joint_true.joint_type, "frames": d.num_frames,
               "rgb": f"{d.rgb_size[0]}x{d.rgb_size[1]}", "tracks": int(traj.valid.shape[1]),
               "query_frame": traj.query_frame, "seconds": float(np.median(times))}
        n_valid = traj.valid.sum(1)
        row["valid_frac"] = float(traj.valid.mean()) if traj.valid.size else 0.0
        moving = np.abs(joint_true.q) > 0
        covered = n_valid >= 3
        q_abs = np.abs(joint_true.q)
        row["q_coverage"] = float(q_abs[covered].max() / q_abs.max()) if covered.any() and q_abs.max() > 0 else 0.0
        row["moving_frames_tracked"] = float(covered[moving].mean()) if moving.any() else float("nan")
        if traj.valid.any():
            truth = true_positions(scene, traj, k)
            err = track_errors_m(traj, truth)
            px = pixel_errors(scene, traj, truth)
            row.update(err3d_med_mm=1e3 * float(np.nanmedian(err)), err3d_p90_mm=1e3 * float(np.nanpercentile(err, 90)),
                       err2d_med_px=float(np.nanmedian(px)), err2d_p90_px=float(np.nanpercentile(px, 90)),
                       on_hand=on_hand(scene, traj))
        closed = np.nonzero((q_abs == 0) & covered)[0]
        ref = int(closed[0]) if closed.size else traj.query_frame
        row["ref_frame"] = ref
        try:
            fit = estimate_joint(traj, reference_frame=ref)
        except Exception as exc:  # noqa: BLE001 - a benchmark row records the failure
            row["joint_est"] = f"failed: {exc}"[:60]
            rows.append(row)
            continue
        e = joint_errors(fit.joint, joint_true)
        row.update(joint_est=fit.joint.joint_type, axis_deg=e.axis_angle_deg, pivot_mm=1e3 * e.pivot_to_line_m,
                   state_err=e.state_error_deg if np.isfinite(e.state_error_deg) else 1e3 * e.state_error_m,
                   range_err=e.range_error_deg if np.isfinite(e.range_error_deg) else 1e3 * e.range_error_m,
                   state_unit="deg" if np.isfinite(e.state_error_deg) else "mm")
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=list(BENCHMARK_SCENES))
    parser.add_argument("--repeats", type=int, default=1, help="timing repeats (median reported)")
    args = parser.parse_args()
    cv2.setNumThreads(2)
    config = TrackingConfig()
    rows = []
    for name in args.scenes:
        rows.extend(bench_scene(name, args.repeats, config))
        print_table(rows[-len(BENCHMARK_SCENES[name].furniture.split("+")):], ["scene", "part", "tracks", "valid_frac",
                    "err3d_med_mm", "err3d_p90_mm", "seconds"])
    print("\nMasks: ground-truth part and hand masks; registration: the true canonical_from_session.")
    print_table(rows, ["scene", "part", "tracks", "valid_frac", "q_coverage", "err3d_med_mm", "err3d_p90_mm",
                       "err2d_med_px", "err2d_p90_px", "on_hand", "seconds", "joint_true", "joint_est", "axis_deg",
                       "pivot_mm", "state_err", "state_unit", "range_err"])
    path = write_results("tracking", rows, {"masks": "ground truth (synthetic generator)",
                                            "registration": "ground truth canonical_from_dynamic_session",
                                            "repeats": args.repeats, "config": repr(config)})
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
