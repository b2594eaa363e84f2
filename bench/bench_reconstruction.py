"""Canonical reconstruction per benchmark scene: held-out PSNR/SSIM, depth error, pose corrections, time.

    python bench/bench_reconstruction.py                    # the synthetic benchmark scenes
    python bench/bench_reconstruction.py door low-noise     # some of them
    python bench/bench_reconstruction.py path/to/capture    # any recording folder or file
    python bench/bench_reconstruction.py --steps 800 --repeat 3 door

Targets (issue 4): held-out PSNR >= 28 dB and depth MAE <= 1 cm in under 5 minutes on CPU for a
256x192 capture of ~40 frames. Depth MAE is reported against the sensor depth and, for synthetic
scenes, against the ground-truth depth; pose errors against the true poses for synthetic scenes.
Writes bench/results/reconstruction.json.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from artitwin_core.capture import read_capture  # noqa: E402
from artitwin_core.reconstruction import (  # noqa: E402
    ReconstructionConfig,
    TrainConfig,
    pose_difference,
    reconstruct,
)
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, render_state  # noqa: E402
from bench._common import print_table, write_results  # noqa: E402

DEFAULT_SCENES = ["door", "drawer", "low-texture-door", "high-noise"]


def run_one(name: str, steps: int, seed: int) -> dict:
    gt_depth, truth = None, None
    if name in BENCHMARK_SCENES:
        scene = generate_scene(BENCHMARK_SCENES[name])
        capture, truth = scene.static, scene.truth.static_world_from_camera
        w, h = capture.rgb_size
        q = [0.0] * len(scene.truth.joints)
        gt_depth = np.stack([
            render_state(scene, truth[t], capture.rgb_intrinsics[t], w, h, q)[1] for t in range(capture.num_frames)
        ])  # fmt: skip
    else:
        capture = read_capture(Path(name))
    config = ReconstructionConfig(train=TrainConfig.with_schedule(steps, seed=seed))
    t0 = time.perf_counter()

    def progress(state) -> None:
        if state.step % 100 == 0:
            recent = float(np.mean(state.losses[-100:]))
            print(f"  step {state.step}: {state.num_gaussians} Gaussians, loss {recent:.4f}, "
                  f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)  # fmt: skip

    rec = reconstruct(capture, config, gt_depth=gt_depth, callback=progress)
    total = time.perf_counter() - t0
    ev = rec.evaluation.summary()
    row = {
        "scene": name,
        "frames": capture.num_frames,
        "size": f"{capture.rgb_size[0]}x{capture.rgb_size[1]}",
        "gaussians": rec.params.num_gaussians,
        "init_gaussians": rec.initial_gaussians,
        "steps": rec.steps,
        "psnr_db": ev["psnr_db"],
        "ssim": ev["ssim"],
        "depth_mae_sensor_m": ev["depth_mae_m"],
        "depth_mae_gt_m": ev.get("depth_mae_gt_m", float("nan")),
        "pose_status": rec.poses.status,
        "pose_corr_mean_m": float(rec.poses.correction_translation_m.mean()),
        "pose_corr_mean_deg": float(rec.poses.correction_rotation_deg.mean()),
        "seconds": total,
        "seconds_poses": rec.seconds["poses"],
        "seconds_train": rec.seconds["train"],
    }
    if truth is not None:
        dt0, dr0 = pose_difference(capture.world_from_camera, truth)
        dt1, dr1 = pose_difference(rec.poses.world_from_camera, truth)
        row.update(pose_err_capture_m=float(dt0.mean()), pose_err_refined_m=float(dt1.mean()),
                   pose_err_capture_deg=float(dr0.mean()), pose_err_refined_deg=float(dr1.mean()))  # fmt: skip
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="*", help="benchmark scene names or capture paths")
    ap.add_argument("--steps", type=int, default=TrainConfig().steps)
    ap.add_argument("--repeat", type=int, default=1, help="runs per scene; the median time is reported")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rows = []
    for name in args.scenes or DEFAULT_SCENES:
        runs = [run_one(name, args.steps, seed) for seed in range(args.repeat)]
        row = dict(runs[0])
        row["seconds"] = statistics.median(r["seconds"] for r in runs)
        row["seconds_all"] = [r["seconds"] for r in runs]
        rows.append(row)
        print(f"{name}: {row['psnr_db']:.2f} dB, {row['seconds']:.0f} s", flush=True)
    columns = ["scene", "frames", "gaussians", "psnr_db", "ssim", "depth_mae_sensor_m", "depth_mae_gt_m",
               "pose_status", "pose_corr_mean_m", "pose_corr_mean_deg", "seconds"]  # fmt: skip
    print_table(rows, columns)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    path = write_results("reconstruction", rows, {"steps": args.steps, "load_average_1min": load})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
