"""The whole pipeline on one command: per-stage seconds, CPU seconds, peak memory and joint accuracy.

    python bench/bench_end_to_end.py                         # (a) door and drawer, (b) phone capture
    python bench/bench_end_to_end.py --scenes a-door         # one of them
    python bench/bench_end_to_end.py --threads 1             # one thread: CPU seconds = one core's wall
    python bench/bench_end_to_end.py --preset quick --scenes a-door

Scenes (issue 25):

- ``a-door``, ``a-drawer``: 40 static + 60 dynamic frames, RGB 512x384, depth 256x192 (the
  generator's default 30 fps clock, strides 3 and 2), seeds 1 and 2 as the benchmark door/drawer.
- ``b-phone``: shaped like a real phone capture: 1920x1440 RGB JPEG, 256x192 depth with ARKit
  confidence in a Record3D ``.r3d``, 60 fps, 20 s static + 15 s dynamic (1200 + 900 frames), with
  phone-like pose jitter (1 mm / 1 mrad per frame). See :func:`phone_scene` for how it is made
  within the generator's limits (its 30 fps clock and the memory of a 2100-frame render).

Scenes are generated once into ``--cache`` (default ``$ARTITWIN_BENCH_CACHE`` or
``~/.cache/artitwin/bench``), keyed by their spec; ``generation.json`` beside each says what it cost.
Every run uses a fresh artifact store, so nothing is cached between runs. Stages run inline (no
Prefect: its scheduling is not what is measured; ``bench_flow.py`` measures that). Per stage:
wall seconds, CPU seconds of this process (all its threads), and the peak resident memory while it
ran (sampled every 0.1 s). The machine's load average is recorded at the start and the end: wall
times on a shared machine are inflated by the other load, CPU seconds much less so. With
``--threads 1`` every library runs one thread, so the CPU seconds are what one idle core would take
(an upper bound of the wall time on two idle cores).

Accuracy: each true joint is matched to the fitted joint closest in axis, and compared by
``artitwin_core.joints.joint_errors`` on the dynamic frames the pipeline kept; issue 6's targets are
axis <= 0.5 deg, pivot <= 5 mm (rotational), state <= 1 deg or 5 mm, type right.

``--skip-stages export`` leaves stages out (reported as skipped), e.g. on a machine whose Python
lacks the export's packages (the GPU check, bench/gpu_check.sh). Writes
``bench/results/end_to_end.json`` (``--name`` to change it).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path

# Threads must be fixed before numpy, torch and numba are imported.
if __name__ == "__main__":
    _threads = next((sys.argv[i + 1] for i, a in enumerate(sys.argv[:-1]) if a == "--threads"), None)
    if _threads is not None:
        for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
            os.environ[var] = _threads

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench._common import print_table, write_results  # noqa: E402

TARGETS = {"axis_deg": 0.5, "pivot_mm": 5.0, "state_deg": 1.0, "state_mm": 5.0}
STAGE_GROUPS = {
    "stage I": ("refine_poses", "reconstruct", "reconstruct_report"),
    "stage IV": ("articulate", "articulate_report"),
    "diagnosis": ("predict_views", "diagnose", "predict_dynamic", "diagnose_dynamic", "diagnose_static"),
}


def cache_root(arg: str | None) -> Path:
    return Path(arg or os.environ.get("ARTITWIN_BENCH_CACHE") or Path.home() / ".cache" / "artitwin" / "bench")


def a_spec(furniture: str, seed: int):
    from artitwin_core.synth import SceneSpec

    return SceneSpec(furniture=furniture, static_frames=40, dynamic_frames=60,
                     rgb_size=(512, 384), depth_size=(256, 192), seed=seed)


# The phone-shaped scene: rendered at PHONE_RENDER, written at PHONE_RGB.
PHONE_RGB = (1920, 1440)
PHONE_RENDER = (640, 480)
PHONE_FPS = 60.0
PHONE_SECONDS = (20.0, 15.0)
PHONE_JITTER = {"trans_std_m": 0.001, "rot_std_rad": 0.001}


def phone_specs(seed: int = 21):
    """The two generator calls of ``b-phone``: (static recording, dynamic recording).

    The generator keeps every frame of a recording in memory with its int64 label map, and its
    clock runs at 30 fps. 1200 + 900 frames at 1920x1440 would need ~40 GB in one call, so the
    static and the dynamic recording are rendered by two calls (the scene's geometry and each
    recording's camera path depend on the seed and that recording's own length only, so the two
    calls describe one scene; :func:`phone_scene` checks that the joints agree), at 640x480, and
    each RGB frame is upsampled 3x (bicubic) when written. The 30 fps frames are relabelled at
    60 fps: a 40 s sweep rendered on the 30 fps clock is written as the 20 s sweep a 60 fps phone
    records (the camera path spans the recording, so its speed is that of a 20 s sweep).
    """
    from dataclasses import replace

    from artitwin_core.synth import SceneSpec

    n_static, n_dynamic = (round(s * PHONE_FPS) for s in PHONE_SECONDS)
    base = SceneSpec(furniture="door", rgb_size=PHONE_RENDER, depth_size=(256, 192), static_stride=1,
                     dynamic_stride=1, effects=(("pose_jitter", dict(PHONE_JITTER)),), seed=seed)
    return replace(base, static_frames=n_static, dynamic_frames=2), replace(base, static_frames=2, dynamic_frames=n_dynamic)


SCENES = {
    "a-door": lambda: ("synthetic", a_spec("door", 1)),
    "a-drawer": lambda: ("synthetic", a_spec("drawer", 2)),
    "b-phone": lambda: ("phone", phone_specs()),
}


def _spec_key(specs) -> str:
    import hashlib

    return hashlib.sha256(repr(specs).encode()).hexdigest()[:12]


class _PeakRss:
    """Peak resident memory of this process, sampled in a thread (``psutil``); ``reset`` per stage."""

    def __init__(self, every_s: float = 0.1) -> None:
        import psutil

        self.proc = psutil.Process()
        self.peak = self.proc.memory_info().rss
        self.stage_peak = self.peak
        self._stop = threading.Event()
        self._every = every_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self._every):
            self.sample()

    def sample(self) -> None:
        rss = self.proc.memory_info().rss
        self.peak = max(self.peak, rss)
        self.stage_peak = max(self.stage_peak, rss)

    def reset_stage(self) -> None:
        self.sample()
        self.stage_peak = self.proc.memory_info().rss

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def _cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _write_timed(t0: tuple[float, float], path: Path, **extra) -> None:
    wall, cpu = time.time() - t0[0], _cpu_seconds() - t0[1]
    import resource

    info = {"wall_s": wall, "cpu_s": cpu, "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
            "load_avg": os.getloadavg(), **extra}
    path.write_text(json.dumps(info, indent=2, default=str))


def ensure_scene(name: str, cache: Path) -> Path:
    """The scene folder of ``name`` in ``cache``, generated (once) if missing."""
    from artitwin_core.synth import generate_scene, write_scene

    kind, specs = SCENES[name]()
    folder = cache / f"{name}-{_spec_key(specs)}"
    if (folder / "scene.json").is_file():
        return folder
    print(f"generating {name} into {folder} (once) ...", flush=True)
    t0 = (time.time(), _cpu_seconds())
    tmp = folder.with_name(folder.name + ".tmp")
    if kind == "synthetic":
        write_scene(generate_scene(specs), tmp)
    else:
        phone_scene(specs, tmp)
    _write_timed(t0, tmp / "generation.json", spec=repr(specs))
    tmp.rename(folder)
    return folder


def phone_scene(specs, out: Path) -> None:
    """Write ``b-phone`` (see :func:`phone_specs`): two generator calls, RGB upsampled to
    ``PHONE_RGB``, timestamps at ``PHONE_FPS``, one ground truth (static poses from the first call,
    everything about the dynamic recording and the joints from the second)."""
    import dataclasses
    import gc

    from artitwin_core.capture import write_r3d
    from artitwin_core.capture._common import scale_intrinsics
    from artitwin_core.synth import generate_scene
    from artitwin_core.synth._io import write_ground_truth

    out.mkdir(parents=True, exist_ok=True)
    truths = []
    for role, spec in zip(("static", "dynamic"), specs, strict=True):
        scene = generate_scene(spec)
        cap = getattr(scene, role)
        sx, sy = PHONE_RGB[0] / cap.rgb_size[0], PHONE_RGB[1] / cap.rgb_size[1]
        cap = dataclasses.replace(
            cap, rgb=_Upsampled(cap.rgb, PHONE_RGB), rgb_intrinsics=scale_intrinsics(cap.rgb_intrinsics, sx, sy),
            timestamps=np.asarray(cap.frame_ids, np.float64) / PHONE_FPS,
        )
        write_r3d(cap, out / f"{role}.r3d")
        truths.append(scene.truth)
        del scene, cap
        gc.collect()
    static_truth, truth = truths
    for a, b in zip(static_truth.joints, truth.joints, strict=True):
        if not (np.allclose(a.axis, b.axis) and np.allclose(a.pivot, b.pivot)):
            raise RuntimeError("the two generator calls built different scenes; phone_specs no longer holds")
    truth = dataclasses.replace(truth, static_world_from_camera=static_truth.static_world_from_camera)
    write_ground_truth(truth, specs[1], out / "ground_truth")
    (out / "scene.json").write_text(json.dumps({"static": "static.r3d", "dynamic": "dynamic.r3d"}, indent=2))


class _Upsampled:
    """``[T, H, W, 3]`` uint8 frames upsampled (bicubic) to ``size`` one at a time when indexed,
    so a writer streams 1920x1440 frames without holding them all (8.3 MB each)."""

    dtype = np.dtype(np.uint8)
    ndim = 4

    def __init__(self, rgb: np.ndarray, size: tuple[int, int]) -> None:
        self.rgb, self.size = rgb, size
        self.shape = (rgb.shape[0], size[1], size[0], 3)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, t: int) -> np.ndarray:
        import cv2

        return cv2.resize(self.rgb[int(t)], self.size, interpolation=cv2.INTER_CUBIC)


class TimedExecutor:
    """An ``InlineExecutor`` that records each stage's wall seconds, CPU seconds and peak memory,
    and reports the stages in ``skip`` as skipped without running them. In a ``ParallelExecutor``
    (``--workers``) it runs inside the worker threads; CPU seconds are then the process's over the
    stage's span (other stages running beside it included), so only the inline run attributes them."""

    def __init__(self, store, skip: set[str], rss: _PeakRss, parallel: bool) -> None:
        from flows._runner import InlineExecutor

        self.inner = InlineExecutor(store)
        self.skip = skip
        self.rss = rss
        self.parallel = parallel
        self.rows: list[dict] = []
        self.t0 = time.perf_counter()

    def submit(self, stage_name, config, inputs, label):
        from flows._runner import StageFailure

        if stage_name in self.skip:
            return StageFailure(stage_name, label, "skipped", "not run: --skip-stages")
        if not self.parallel:
            self.rss.reset_stage()
        w0, c0 = time.perf_counter(), _cpu_seconds()
        out = self.inner.submit(stage_name, config, inputs, label)
        wall, cpu = time.perf_counter() - w0, _cpu_seconds() - c0
        self.rss.sample()
        status = getattr(out, "status", "?")
        peak = self.rss.stage_peak if not self.parallel else self.rss.peak
        print(f"  {stage_name}[{label}] {status} {wall:.1f} s (cpu {cpu:.1f} s, peak {peak / 2**30:.2f} GB)", flush=True)
        deps = sorted({f"{v.stage}[{v.label}]" for v in inputs.values() if hasattr(v, "stage") and hasattr(v, "key")})
        self.rows.append({"stage": stage_name, "label": label, "status": status, "start_s": w0 - self.t0,
                          "wall_s": wall, "cpu_s": cpu, "peak_rss_gb": peak / 2**30, "after": deps})
        return out

    def result(self, handle):
        return self.inner.result(handle)


def schedule_estimate(rows: list[dict], workers: int = 2) -> float:
    """Wall seconds of the stages run ``workers`` at a time in submission order, each as soon as the
    stages it reads have ended (as ``ParallelExecutor`` runs them), taking each stage's CPU seconds
    from an inline one-thread run as its duration: an estimate of the wall time on ``workers``
    idle cores that needs no idle machine (each stage's own threads would only shorten it)."""
    end: dict[str, float] = {}
    free = [0.0] * workers
    for r in rows:
        ready = max((end.get(d, 0.0) for d in r.get("after", [])), default=0.0)
        k = min(range(workers), key=lambda i: max(free[i], ready))
        start = max(free[k], ready)
        free[k] = start + r["cpu_s"]
        end[f"{r['stage']}[{r['label']}]"] = free[k]
    return max(end.values(), default=0.0)


def joint_accuracy(summary: dict, store, scene_dir: Path) -> list[dict]:
    """Per true joint: the matched fitted joint's errors on the dynamic frames the run kept."""
    from artitwin_core.joints import Joint, joint_errors
    from artitwin_core.synth import load_ground_truth, load_scene_spec
    from schemas import CaptureArtifact

    truth = load_ground_truth(scene_dir)
    spec = load_scene_spec(scene_dir)
    ingest = summary["stages"].get("ingest/dynamic")
    if ingest is None or "key" not in ingest:
        return []
    frame_ids = np.asarray(store.get(ingest["key"], CaptureArtifact).frame_ids, np.int64)
    positions = frame_ids // spec.dynamic_stride
    fitted = [
        Joint(joint_type=j["type"], axis=np.asarray(j["axis"]), pivot=np.asarray(j["pivot"]),
              q=np.asarray([np.nan if v is None else v for v in j["q"]], np.float64), q_range=np.asarray(j["range"]),
              residual=np.zeros(len(j["q"])), confidence=np.ones(len(j["q"])), pitch=float(j["pitch"] or 0.0))
        for j in summary["joints"]
    ]
    rows = []
    for k, jt in enumerate(truth.joints):
        jt = Joint(joint_type=jt.joint_type, axis=jt.axis, pivot=jt.pivot, q=np.asarray(jt.q)[positions],
                   q_range=jt.q_range, residual=np.zeros(len(positions)), confidence=np.ones(len(positions)),
                   pitch=jt.pitch)
        if not fitted:
            rows.append({"part": k, "type_ok": False, "meets": False, "note": "no joint fitted"})
            continue
        best = min(fitted, key=lambda j: abs(float(np.dot(j.axis, jt.axis))) * -1.0)
        e = joint_errors(best, jt)
        rotational = jt.joint_type in ("revolute", "screw")
        row = {"part": k, "true_type": jt.joint_type, "type_ok": bool(e.type_correct),
               "axis_deg": e.axis_angle_deg, "pivot_mm": 1e3 * e.pivot_error_m if rotational else float("nan"),
               "state": e.state_error_deg if rotational else 1e3 * e.state_error_m,
               "state_unit": "deg" if rotational else "mm"}
        row["meets"] = bool(
            row["type_ok"] and row["axis_deg"] <= TARGETS["axis_deg"]
            and (not rotational or row["pivot_mm"] <= TARGETS["pivot_mm"])
            and row["state"] <= (TARGETS["state_deg"] if rotational else TARGETS["state_mm"])
        )
        rows.append(row)
    return rows


def run_scene(name: str, scene_dir: Path, preset: str, skip: set[str], workdir: Path, workers: int) -> dict:
    from flows import hardware_preset
    from flows._pipeline import SceneFailed, finish_scene, scene_pipeline
    from flows._runner import ParallelExecutor
    from infra.store import ArtifactStore

    store = ArtifactStore(str(workdir / f"store-{name}"))
    config = hardware_preset(preset)
    rss = _PeakRss()
    timed = TimedExecutor(store, skip, rss, parallel=workers > 1)
    ex = timed
    if workers > 1:
        ex = ParallelExecutor(store, workers)
        ex.inline = timed
    load0 = os.getloadavg()
    w0, c0 = time.time(), _cpu_seconds()
    print(f"{name}: {scene_dir} (preset {preset})", flush=True)
    try:
        summary = finish_scene(scene_dir, config, ex, scene_pipeline(scene_dir, config, ex), store, w0,
                               workdir / f"out-{name}", exports=False)
        status = "ok"
    except SceneFailed as e:
        summary, status = e.summary, "failed: " + "; ".join(
            f"{k}: {v.get('error', '')}" for k, v in e.summary["stages"].items() if v.get("status") == "failed")
    finally:
        if workers > 1:
            ex.shutdown()
    wall, cpu = time.time() - w0, _cpu_seconds() - c0
    rss.stop()
    load1 = os.getloadavg()
    groups = {g: sum(r["wall_s"] for r in timed.rows if r["stage"] in stages) for g, stages in STAGE_GROUPS.items()}
    groups_cpu = {g: sum(r["cpu_s"] for r in timed.rows if r["stage"] in stages) for g, stages in STAGE_GROUPS.items()}
    accuracy = joint_accuracy(summary, store, scene_dir)
    return {
        "scene": name, "status": status, "wall_s": wall, "cpu_s": cpu, "peak_rss_gb": rss.peak / 2**30,
        "load_avg_start": load0, "load_avg_end": load1, "workers": workers, "stages": timed.rows,
        "groups_wall_s": groups, "groups_cpu_s": groups_cpu,
        "diagnosis_share_wall": groups["diagnosis"] / wall, "diagnosis_share_cpu": groups_cpu["diagnosis"] / cpu,
        "estimated_wall_2_idle_cores_s": schedule_estimate(timed.rows) if workers == 1 else None,
        "accuracy": accuracy, "accuracy_met": bool(accuracy) and all(r["meets"] for r in accuracy),
        "heldout_psnr_db": {
            "stage I": summary["stages"].get("reconstruct_report", {}).get("metrics", {}).get("heldout_psnr_db"),
            "stage IV": summary["stages"].get("articulate_report", {}).get("metrics", {}).get("psnr_holdout_db"),
        },
        "frames": {k: summary["stages"].get(f"capture_check/{k}", {}).get("metrics", {}).get("frames_count")
                   for k in ("static", "dynamic")},
        "working_rgb": [summary["stages"].get("capture_check/static", {}).get("metrics", {}).get(f"rgb_{d}_px")
                        for d in ("width", "height")],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="*", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--preset", default="default", help="PipelineConfig preset (default: the one for real captures)")
    ap.add_argument("--cache", default=None, help="where generated scenes are kept (see the module docstring)")
    ap.add_argument("--scene-dir", default=None, help="run this scene folder instead (with --scenes NAME naming it)")
    ap.add_argument("--threads", type=int, default=None, help="threads of every library (set before import)")
    ap.add_argument("--workers", type=int, default=1,
                    help="stages run at once (ParallelExecutor, as Prefect's task runner overlaps them); 1: inline")
    ap.add_argument("--skip-stages", nargs="*", default=[], help="stages not run (reported as skipped)")
    ap.add_argument("--workdir", default=None, help="stores and outputs (default: a temporary folder)")
    ap.add_argument("--name", default="end_to_end", help="results file bench/results/NAME.json")
    ap.add_argument("--generate-only", action="store_true", help="generate the scenes into the cache and stop")
    args = ap.parse_args()

    import tempfile

    if args.threads is not None:
        import torch

        torch.set_num_threads(args.threads)
    cache = cache_root(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    dirs = {}
    for name in args.scenes:
        dirs[name] = Path(args.scene_dir) if args.scene_dir else ensure_scene(name, cache)
    if args.generate_only:
        for name, d in dirs.items():
            print(name, d, (d / "generation.json").read_text() if (d / "generation.json").exists() else "")
        return
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="artitwin-e2e-"))
    results = [run_scene(name, d, args.preset, set(args.skip_stages), workdir, args.workers) for name, d in dirs.items()]

    for res in results:
        est = res["estimated_wall_2_idle_cores_s"]
        if est is not None:
            print(f"\n{res['scene']}: estimated wall on 2 idle cores (CPU seconds scheduled 2 stages at a time): {est:.0f} s")
        print(f"\n{res['scene']}: {res['status']}, wall {res['wall_s']:.0f} s, cpu {res['cpu_s']:.0f} s, "
              f"peak RSS {res['peak_rss_gb']:.2f} GB, load {res['load_avg_start'][0]:.1f} -> {res['load_avg_end'][0]:.1f}, "
              f"frames {res['frames']}, working RGB {res['working_rgb']}")
        print_table(res["stages"], ["stage", "label", "status", "start_s", "wall_s", "cpu_s", "peak_rss_gb"])
        print("groups (wall s):", {k: round(v, 1) for k, v in res["groups_wall_s"].items()},
              f"diagnosis share {100 * res['diagnosis_share_wall']:.0f} % wall, {100 * res['diagnosis_share_cpu']:.0f} % cpu")
        if res["accuracy"]:
            print_table(res["accuracy"])
    rows = [{"scene": r["scene"], "status": r["status"], "wall_s": r["wall_s"], "cpu_s": r["cpu_s"],
             "peak_rss_gb": r["peak_rss_gb"], "diag_share_wall": r["diagnosis_share_wall"],
             "diag_share_cpu": r["diagnosis_share_cpu"], "est_2core_s": r["estimated_wall_2_idle_cores_s"],
             "psnr_I_db": r["heldout_psnr_db"]["stage I"], "psnr_IV_db": r["heldout_psnr_db"]["stage IV"],
             "accuracy_met": r["accuracy_met"],
             "load_start": r["load_avg_start"][0]} for r in results]
    print()
    print_table(rows)
    import torch

    meta = {"preset": args.preset, "threads": args.threads, "workers": args.workers, "torch_threads": torch.get_num_threads(),
            "cuda": torch.cuda.is_available(), "scenes": results}
    print(f"results: {write_results(args.name, rows, meta)}")


if __name__ == "__main__":
    main()
