"""Benchmark of ``artitwin_core.gaussians.rasterize``: forward + backward time per backend.

Scene: a room-like cloud seen from ~1.5 m (means uniform in a 2 x 1.5 x 1 m box 1-2 m in front of
the camera, scales log-normal around 1.5 cm, opacities 0.5-0.9, SH degree 3), 256x192 pinhole.
Threads are pinned to 2 (torch and numba) to match the target machine. The loss is a fixed random
linear function of rgb, depth and alpha so the backward pass sees dense pixel gradients.

The machine is shared, so wall-clock medians swing with other people's load (the JSON records
the load average). Each CPU row is therefore also timed single-threaded with ``time.thread_time``
(CPU time of this thread only, so time spent descheduled does not count): a load-robust measure
of the work, roughly twice the 2-thread wall time on an idle machine.

On an oversubscribed machine, OpenMP's default spin-waiting makes the 2-thread wall time several
times worse; run with ``OMP_WAIT_POLICY=PASSIVE`` (recorded in the JSON) to see the difference.

Run: ``python bench/bench_rasterizer.py [--repeats 15] [--n 20000]``; prints a table and writes
``bench/results/rasterizer.json``.
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "2")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from artitwin_core.gaussians import rasterize  # noqa: E402


def room_scene(n: int, seed: int = 0) -> list[torch.Tensor]:
    """``[means, quats, log_scales, opacity_logits, sh]`` of a room-like cloud (camera at origin)."""
    g = torch.Generator().manual_seed(seed)
    lo = torch.tensor([-1.0, -0.75, 1.0])
    hi = torch.tensor([1.0, 0.75, 2.0])
    means = lo + (hi - lo) * torch.rand(n, 3, generator=g)
    quats = torch.randn(n, 4, generator=g)
    log_scales = np.log(0.015) + 0.4 * torch.randn(n, 3, generator=g)
    opac = 0.5 + 0.4 * torch.rand(n, generator=g)
    logits = torch.log(opac / (1 - opac))
    sh = 0.1 * torch.randn(n, 16, 3, generator=g)
    sh[:, 0] = torch.randn(n, 3, generator=g)
    return [t.float().requires_grad_() for t in (means, quats, log_scales, logits, sh)]


def camera(width: int, height: int) -> tuple[torch.Tensor, tuple[float, float, float, float]]:
    f = 0.86 * width  # ~60 degrees horizontal field of view
    return torch.eye(4, dtype=torch.float64), (f, f, 0.5 * width, 0.5 * height)


def _run(params, cam_from_world, intr, width, height, backend, weights, repeats, clock):
    w_rgb, w_depth, w_alpha = weights
    fwd, bwd = [], []
    for _ in range(repeats + 1):  # the first run compiles / warms caches and is dropped
        t0 = clock()
        out = rasterize(*params, cam_from_world, intr, width, height, backend=backend)
        t1 = clock()
        loss = (out.rgb * w_rgb).sum() + (out.depth * w_depth).sum() + (out.alpha * w_alpha).sum()
        loss.backward()
        t2 = clock()
        for p in params:
            p.grad = None
        fwd.append(t1 - t0)
        bwd.append(t2 - t1)
    return np.array(fwd[1:]) * 1e3, np.array(bwd[1:]) * 1e3, out


def time_backend(backend: str, n: int, width: int, height: int, repeats: int) -> dict:
    params = room_scene(n)
    cam_from_world, intr = camera(width, height)
    g = torch.Generator().manual_seed(1)
    w_rgb = torch.randn(height, width, 3, generator=g)
    w_depth = torch.randn(height, width, generator=g)
    w_alpha = torch.randn(height, width, generator=g)
    weights = (w_rgb, w_depth, w_alpha)
    fwd_ms, bwd_ms, out = _run(
        params, cam_from_world, intr, width, height, backend, weights, repeats, time.perf_counter
    )
    tot = fwd_ms + bwd_ms
    cpu1 = None
    if backend == "cpu":  # single-threaded CPU time: robust to other processes' load
        numba.set_num_threads(1)
        torch.set_num_threads(1)
        f1, b1, _ = _run(
            params, cam_from_world, intr, width, height, backend, weights, repeats, time.thread_time
        )
        numba.set_num_threads(2)
        torch.set_num_threads(2)
        cpu1 = float(np.median(f1 + b1))
    return {
        "backend": backend,
        "n": n,
        "width": width,
        "height": height,
        "repeats": repeats,
        "visible": int((out.radii > 0).sum()),
        "forward_ms_median": float(np.median(fwd_ms)),
        "backward_ms_median": float(np.median(bwd_ms)),
        "total_ms_median": float(np.median(tot)),
        "total_ms_p90": float(np.percentile(tot, 90)),
        "single_thread_cpu_ms_median": cpu1,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--n", type=int, default=20000)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "rasterizer.json")
    ap.add_argument("--skip-large", action="store_true", help="leave out the 512x384 row")
    args = ap.parse_args()
    torch.set_num_threads(2)
    load_start = os.getloadavg()[0]
    rows = [
        time_backend("reference", 300, 64, 48, max(3, args.repeats // 3)),
        time_backend("cpu", 300, 64, 48, args.repeats),
        time_backend("cpu", args.n, 256, 192, args.repeats),
    ]
    if not args.skip_large:
        rows.append(time_backend("cpu", args.n, 512, 384, max(3, args.repeats // 3)))
    if torch.cuda.is_available():
        try:
            rows.append(time_backend("cuda", args.n, 256, 192, args.repeats))
        except RuntimeError as exc:  # gsplat missing
            print(f"cuda backend skipped: {exc}")
    hdr = (
        f"{'backend':<10} {'N':>6} {'resolution':>10} {'visible':>7} {'fwd ms':>8} {'bwd ms':>8} "
        f"{'total med':>10} {'total p90':>10} {'1-thr CPU ms':>12}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(
            f"{r['backend']:<10} {r['n']:>6} {str(r['width']) + 'x' + str(r['height']):>10} {r['visible']:>7} "
            f"{r['forward_ms_median']:>8.1f} {r['backward_ms_median']:>8.1f} {r['total_ms_median']:>10.1f} "
            f"{r['total_ms_p90']:>10.1f} "
            + (
                f"{r['single_thread_cpu_ms_median']:>12.1f}"
                if r["single_thread_cpu_ms_median"]
                else f"{'-':>12}"
            )
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "machine": platform.processor() or platform.machine(),
        "torch_threads": torch.get_num_threads(),
        "numba_threads": int(os.environ["NUMBA_NUM_THREADS"]),
        "load_average_1min_at_end": os.getloadavg()[0],
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "(default)"),
        "numba_threading_layer": numba.threading_layer(),
        "load_average_1min_at_start": load_start,
        "target": "20k Gaussians, 256x192, forward+backward median < 300 ms on 2 threads",
    }
    args.out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    print(
        f"load average {meta['load_average_1min_at_start']:.1f} -> {meta['load_average_1min_at_end']:.1f}, "
        f"OMP_WAIT_POLICY={meta['omp_wait_policy']}, numba layer {meta['numba_threading_layer']}"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
