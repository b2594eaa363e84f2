"""Time the synthetic scene generator on every benchmark scene and summarise what it rendered.

Run: ``python bench/bench_synth.py [--repeats 3] [--scenes door drawer ...]``. Prints a table and
writes ``bench/results/bench_synth.json``. Timings are wall-clock on CPU; take the median of the
repeats (shared machines are noisy).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from artitwin_core.synth import BENCHMARK_SCENES, generate_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenes", nargs="*", default=list(BENCHMARK_SCENES))
    args = parser.parse_args()
    rows = []
    for name in args.scenes:
        spec = BENCHMARK_SCENES[name]
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            scene = generate_scene(spec)
            times.append(time.perf_counter() - t0)
        frames = scene.static.num_frames + scene.dynamic.num_frames
        truth = scene.truth
        rows.append({
            "scene": name,
            "frames": frames,
            "rgb_size": list(spec.rgb_size),
            "seconds_median": statistics.median(times),
            "seconds_all": times,
            "ms_per_frame": 1000 * statistics.median(times) / frames,
            "depth_invalid_fraction": float(np.isnan(np.concatenate(
                [scene.static.depth.ravel(), scene.dynamic.depth.ravel()])).mean()),
            "part_pixel_fraction": float((truth.part_masks > 0).mean()),
            "hand_pixel_fraction": float(truth.hand_masks.mean()),
            "joints": [j.joint_type for j in truth.joints],
            "effects": sorted(truth.effects),
        })
        r = rows[-1]
        print(f"{name:24s} {frames:4d} frames {r['seconds_median']:7.2f} s  {r['ms_per_frame']:6.1f} ms/frame  "
              f"depth NaN {r['depth_invalid_fraction']:.3f}  part {r['part_pixel_fraction']:.3f}  "
              f"hand {r['hand_pixel_fraction']:.3f}  {r['joints']}", flush=True)
    out = Path(__file__).parent / "results" / "bench_synth.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    out.write_text(json.dumps({"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                               "load_average_at_end": load, "repeats": args.repeats, "rows": rows}, indent=2))
    print(f"wrote {out} (load average at end: {load})")


if __name__ == "__main__":
    main()
