"""Capture reader throughput: write one synthetic recording per format, time reading it back.

    python bench/bench_capture.py [--frames 30] [--repeats 3]

Record3D-sized frames (RGB 720x960, depth 192x256). Reports the median over repeats of the full
read (ms per frame), the read with ReadOptions(rgb_max_width=360), and the size on disk.
Prints a table and writes bench/results/capture.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._common import print_table, write_results  # noqa: E402


def synthetic(frames: int):
    import numpy as np

    from artitwin_core.capture import Capture, depth_intrinsics_from_rgb
    from artitwin_core.geometry import axis_angle_to_matrix, make_se3

    rng = np.random.default_rng(0)
    w, h, dw, dh = 720, 960, 192, 256
    yy, xx = np.mgrid[0:h, 0:w] / h
    rgb = np.empty((frames, h, w, 3), np.uint8)
    for t in range(frames):
        for c in range(3):
            a, b, p = rng.uniform(-1, 1, 3)
            rgb[t, :, :, c] = np.clip(128 + 90 * np.sin(9 * (a * xx + b * yy) + 6 * p), 0, 255)
    rgb = np.clip(rgb + rng.integers(0, 12, rgb.shape, dtype=np.uint8), 0, 255).astype(np.uint8)
    depth = rng.uniform(0.5, 4.0, (frames, dh, dw)).astype(np.float32)
    k = np.tile([[680.0, 680.0, 361.2, 478.9]], (frames, 1))
    poses = np.stack([make_se3(axis_angle_to_matrix(rng.normal(size=3), rng.uniform(0, 3)), rng.normal(size=3))
                      for _ in range(frames)])
    return Capture(rgb=rgb, depth=depth, confidence=rng.integers(0, 3, depth.shape, dtype=np.uint8),
                   rgb_intrinsics=k, depth_intrinsics=depth_intrinsics_from_rgb(k, (w, h), (dw, dh)),
                   world_from_camera=poses, timestamps=np.arange(frames) / 60, frame_ids=np.arange(frames))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    from artitwin_core.capture import (
        ReadOptions,
        read_capture,
        recording_files,
        write_nerfstudio,
        write_r3d,
        write_record3d_exr,
        write_stray,
    )

    cap = synthetic(args.frames)
    tmp = Path(tempfile.mkdtemp(prefix="artitwin-bench-capture-"))
    paths = {
        "record3d-r3d": write_r3d(cap, tmp / "a.r3d"),
        "record3d-exr": write_record3d_exr(cap, tmp / "exr"),
        "nerfstudio": write_nerfstudio(cap, tmp / "ns").parent,
        "stray": write_stray(cap, tmp / "stray"),
    }
    rows = []
    for fmt, path in paths.items():
        timings = {}
        for label, opts in (("full", None), ("rgb360", ReadOptions(rgb_max_width=360))):
            runs = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                read_capture(path, opts)
                runs.append(time.perf_counter() - t0)
            timings[label] = statistics.median(runs)
        size = sum(f.stat().st_size for f in recording_files(path))
        rows.append({"format": fmt, "frames": args.frames, "ms_per_frame": 1000 * timings["full"] / args.frames,
                     "ms_per_frame_rgb360": 1000 * timings["rgb360"] / args.frames,
                     "MB_on_disk": size / 1e6})
    print_table(rows)
    out = write_results("capture", rows, {"rgb": "720x960", "depth": "192x256", "repeats": args.repeats})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
