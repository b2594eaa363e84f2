"""Generalization: seeded random scenes from the whole synthetic family, run end to end.

Each scene is ``random_scene_spec(seed)`` (furniture, texture, size, opening range, hand model and
arm side, hinge gap, front thickness, shelves, handle, camera paths, noise, session offset, and
sometimes a dynamic-only pose lag, a dynamic-only exposure drift or a partial overlap), written to
disk (nerfstudio for even seeds, r3d for odd ones, so both readers run) and reconstructed by
``flows.scene.run_scene_inline`` with the ``quick`` preset in its own store, each in its own
process (a crash, even a segfault, is contained and recorded).

A run that raises, writes no ``summary.json``, marks a stage failed there, or outlives
``--timeout`` is a crash (its error text is kept). Otherwise ``summary.json["joints"]`` is
compared with the ground truth: estimated joints are matched to true parts by the Hungarian
method on a motion distance (the RMS over frames and over the true part's surface points of the
distance between where the estimated and the true motion put them, divided by the RMS of the
true motion's displacement; a match needs a ratio below ``MATCH_RATIO``). An estimated joint
matching no true part is spurious; a true part matching none is missed. Per matched part: type
right, axis error (deg), pivot-line distance (mm, rotational parts: the true pivot's distance to
the estimated axis line), state RMSE (deg or mm, over the frames with an estimate). Exported
parts are read from ``export/twin.urdf``: a part link (``part_k``) whose joint k matched no true
part is a spurious exported part, whatever its joint type (a ``fixed`` link counts). If the
summary lists candidate parts with their fates (``summary["parts"]``), the fates are tallied.

Targets (issue 24): 0 crashes, 0 spurious exported parts, type right on >= 29 of 30 parts, axis
median <= 0.5 deg and 90th percentile <= 2 deg, pivot median <= 5 mm, state median <= 1 deg or
5 mm. Type accuracy counts every true part (a crashed or missed part is not right).

Columns beside the errors: ``reg_mm`` is the ``register`` stage's error at the true pivots (the
largest, mm), which a joint's pivot inherits; ``est`` lists every estimated joint's type;
``cpu_s`` the worker's CPU seconds (generation included), ``run_s`` the pipeline run's wall seconds.

Run: ``python bench/bench_generalization.py [--scenes 30] [--start-seed 0] [--jobs 1] [--keep DIR]
[--reuse] [--timeout 3600]``; prints a table per scene and the totals, writes
``bench/results/generalization.json``. ``--named [NAME ...]`` runs the scenes of
``BENCHMARK_SCENES`` (all of them without names) through the same harness and evaluation instead,
and writes ``bench/results/generalization_named.json``. ``--reuse`` evaluates the runs kept under ``--keep`` again
(after a change to this evaluation) without rerunning the pipeline.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
import traceback
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, write_results  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MATCH_RATIO = 0.5
TARGETS = {
    "crash_rate": 0.0,
    "spurious_exported": 0,
    "type_right_frac": 29 / 30,
    "axis_median_deg": 0.5,
    "axis_p90_deg": 2.0,
    "pivot_median_mm": 5.0,
    "state_median_deg": 1.0,
    "state_median_mm": 5.0,
}


def scene_format(seed: int | str) -> str:
    """Nerfstudio for even seeds and named scenes, r3d for odd seeds."""
    return "r3d" if isinstance(seed, int) and seed % 2 else "nerfstudio"


def scene_id(text: str) -> int | str:
    """A seed (a random scene) or the name of a scene of ``BENCHMARK_SCENES``."""
    return int(text) if text.lstrip("-").isdigit() else text


def scene_spec(ident: int | str):
    from artitwin_core.synth import BENCHMARK_SCENES, random_scene_spec

    return BENCHMARK_SCENES[ident] if isinstance(ident, str) else random_scene_spec(ident)


def scene_dir_name(ident: int | str) -> str:
    return f"scene_{ident}" if isinstance(ident, str) else f"seed_{ident:04d}"


def describe(spec) -> str:
    """A short line for the table: what was drawn."""
    parts = [spec.furniture]
    if "door" in spec.furniture:
        parts.append(f"{np.degrees(spec.door_open_rad):.0f}deg")
    if "drawer" in spec.furniture:
        parts.append(f"{100 * spec.drawer_open_m:.0f}cm")
    parts.append("lowtex" if spec.texture == "low-texture" else "tex")
    hand = "nohand" if spec.hand_model == "none" or spec.hand_occlusion == 0 else f"{spec.hand_model}/{spec.arm_from}"
    parts.append(hand)
    parts.append(f"{spec.handle} gap{1e3 * spec.hinge_gap_m:.0f} t{1e3 * spec.front_thickness_m:.0f}"
                 + (f" sh{spec.shelves}" if spec.shelves else "") + ("" if spec.interior_items else " empty"))
    parts.append(f"{spec.static_path}>{spec.dynamic_path}")
    parts.append(f"n{spec.noise_level:.1f} off{spec.session_offset_m:.1f}")
    from artitwin_core.synth import EFFECTS

    # A named scene may give an effect no parameters: its defaults apply.
    effects = {name: {**EFFECTS[name].defaults, **params} for name, params in spec.effects}
    if "pose_lag" in effects:
        parts.append(f"lag{effects['pose_lag']['seconds'] * 30 / spec.dynamic_stride:.1f}f")
    if "exposure" in effects:
        parts.append(f"exp{effects['exposure']['stops_std']:.2f}")
    if spec.static_shift_m:
        parts.append(f"shift{spec.static_shift_m:.2f}")
    return " ".join(parts)


# --- comparison with the ground truth (in the worker) ---------------------------------------------


def true_part_points(scene, k: int, max_points: int = 2000) -> np.ndarray:
    """``[N, 3]`` surface points of true part k in its closed pose (canonical frame): the clean
    render of the dynamic frame where the part shows most, back-projected and moved back."""
    from artitwin_core.synth import render_state

    truth = scene.truth
    t = int(np.argmax((truth.part_masks == k + 1).sum(axis=(1, 2))))
    w, h = scene.spec.rgb_size
    intr = scene.dynamic.rgb_intrinsics[t]
    q = [j.q[t] for j in truth.joints]
    pose = truth.dynamic_world_from_camera[t]
    _, depth, mask = render_state(scene, pose, intr, w, h, q)
    v, u = np.nonzero((mask == k + 1) & np.isfinite(depth))
    z = depth[v, u].astype(np.float64)
    fx, fy, cx, cy = intr
    cam = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], -1)
    world = cam @ pose[:3, :3].T + pose[:3, 3]
    inv = np.linalg.inv(truth.part_world_from_closed[k, t])
    closed = world @ inv[:3, :3].T + inv[:3, 3]
    if closed.shape[0] > max_points:
        closed = closed[np.random.default_rng(k).choice(closed.shape[0], max_points, replace=False)]
    return closed


def motion_cost(est: dict, true_motion: np.ndarray, points: np.ndarray) -> float:
    """RMS distance between the points moved by the estimated and by the true motion, over the
    frames where the estimate has a state, divided by the RMS of the true displacement."""
    from artitwin_core.joints import joint_transforms

    q = np.array([np.nan if v is None else v for v in est["q"]], dtype=np.float64)
    ok = np.isfinite(q)
    if not ok.any() or points.shape[0] == 0 or len(q) != true_motion.shape[0]:
        return float("inf")
    if est["type"] == "fixed":
        m_est = np.tile(np.eye(4), (int(ok.sum()), 1, 1))
    else:
        m_est = joint_transforms(est["type"], np.asarray(est["axis"], float), np.asarray(est["pivot"], float),
                                 q[ok], float(est.get("pitch") or 0.0))
    m_true = true_motion[ok]
    p_est = np.einsum("tij,nj->tni", m_est[:, :3, :3], points) + m_est[:, None, :3, 3]
    p_true = np.einsum("tij,nj->tni", m_true[:, :3, :3], points) + m_true[:, None, :3, 3]
    err = np.sqrt(np.mean(np.sum((p_est - p_true) ** 2, -1)))
    disp = np.einsum("tij,nj->tni", true_motion[:, :3, :3], points) + true_motion[:, None, :3, 3] - points
    scale = np.sqrt(np.mean(np.sum(disp**2, -1)))
    return float(err / max(scale, 1e-6))


def part_errors(est: dict, truth_joint) -> dict:
    """Type, axis (deg), pivot-line distance (mm, rotational), state RMSE (deg or mm)."""
    from artitwin_core.joints import Joint, joint_errors

    q = np.array([np.nan if v is None else v for v in est["q"]], dtype=np.float64)
    if q.shape != truth_joint.q.shape:  # not one state per dynamic frame: compare the line only
        q = np.full(truth_joint.q.shape, np.nan)
    j = Joint(joint_type=est["type"], axis=np.asarray(est["axis"], float), pivot=np.asarray(est["pivot"], float),
              q=q, q_range=np.asarray(est["range"], float), residual=np.zeros_like(q),
              confidence=np.ones_like(q), pitch=float(est.get("pitch") or 0.0))
    e = joint_errors(j, truth_joint)
    rotational = truth_joint.joint_type in ("revolute", "screw")
    same_kind = (est["type"] in ("revolute", "screw")) == rotational and est["type"] != "fixed"
    out = {"type_true": truth_joint.joint_type, "type_est": est["type"], "type_ok": bool(e.type_correct),
           "axis_deg": float(e.axis_angle_deg), "unit": "deg" if rotational else "mm",
           "pivot_mm": 1e3 * float(e.pivot_to_line_m) if rotational and same_kind else float("nan"),
           "state_rmse": float("nan")}
    if same_kind:
        sign = 1.0 if float(np.dot(j.axis, truth_joint.axis)) >= 0 else -1.0
        diff = sign * q - truth_joint.q
        scale = np.degrees(1.0) if rotational else 1e3
        if np.isfinite(diff).any():
            out["state_rmse"] = float(np.sqrt(np.nanmean(diff**2)) * scale)
    return out


def exported_part_links(urdf: Path) -> list[tuple[int, str]]:
    """``[(k, joint type)]`` of the URDF's part links ``part_k`` (a screw's ``_slide`` link is not
    another part)."""
    root = ET.parse(urdf).getroot()
    kinds = {j.find("child").get("link"): j.get("type") for j in root.iter("joint") if j.find("child") is not None}
    out = []
    for link in root.iter("link"):
        m = re.fullmatch(r"part_(\d+)", link.get("name", ""))
        if m:
            out.append((int(m.group(1)), kinds.get(link.get("name"), "?")))
    return out


def failure_of(summary: dict) -> str | None:
    """The failure a summary reports, if it reports one (failed runs may write a summary)."""
    for key in ("failed", "failure", "error"):
        if summary.get(key):
            return json.dumps(summary[key])[:300] if not isinstance(summary[key], str) else summary[key][:300]
    for name, stage in summary.get("stages", {}).items():
        if stage.get("status") in ("failed", "error"):
            return f"{name}: {stage.get('error', stage.get('notes', ''))}"[:300]
    return None


def evaluate(scene, summary: dict, run_dir: Path) -> dict:
    """Match the summary's joints to the true parts and measure each matched part."""
    from scipy.optimize import linear_sum_assignment

    truth = scene.truth
    est = summary.get("joints", [])
    n_true, n_est = len(truth.joints), len(est)
    points = [true_part_points(scene, k) for k in range(n_true)]
    cost = np.full((n_est, n_true), np.inf)
    for i, e in enumerate(est):
        for k in range(n_true):
            cost[i, k] = motion_cost(e, truth.part_world_from_closed[k], points[k])
    matches = {}
    if n_est and n_true:
        rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
        matches = {int(i): int(k) for i, k in zip(rows, cols, strict=True) if cost[i, k] < MATCH_RATIO}
    parts = []
    for k, tj in enumerate(truth.joints):
        i = next((i for i, kk in matches.items() if kk == k), None)
        row = {"part": k, "type_true": tj.joint_type, "matched": i is not None,
               "match_cost": float(cost[:, k].min()) if n_est else float("inf")}
        if i is not None:
            row.update(part_errors(est[i], tj), joint=i)
        parts.append(row)
    urdf = run_dir / "export" / "twin.urdf"
    links = exported_part_links(urdf) if urdf.is_file() else []
    spurious_links = [(k, kind) for k, kind in links if k not in matches]
    fates: dict[str, int] = {}
    for p in summary.get("parts", []) or []:
        fate = str(p.get("fate", "?")) if isinstance(p, dict) else "?"
        fates[fate] = fates.get(fate, 0) + 1
    return {
        "parts": parts,
        "estimated_joints": n_est,
        "spurious_joints": n_est - len(matches),
        "exported_part_links": len(links),
        "spurious_exported": len(spurious_links),
        "spurious_exported_kinds": [kind for _, kind in spurious_links],
        "urdf_found": urdf.is_file(),
        "fates": fates,
    }


def registration_error(summary: dict, truth, store: Path) -> dict:
    """The ``register`` stage's transform (from ``store``, the run's own) against the truth:
    rotation (deg) and the largest displacement (mm) it gives a true part's pivot; empty if the
    stage's output is not there."""
    from infra.store import ArtifactStore
    from schemas import Registration

    stage = summary.get("stages", {}).get("register")
    if not stage or not stage.get("key"):
        return {}
    try:
        reg = ArtifactStore(str(store)).get(stage["key"], Registration)
    except Exception:  # noqa: BLE001 - a diagnostic column, never a reason to lose the scene's row
        return {}
    err = reg.canonical_from_session @ np.linalg.inv(truth.canonical_from_dynamic_session)
    angle = np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1.0, 1.0)))
    moved = [np.linalg.norm(err[:3, :3] @ j.pivot + err[:3, 3] - j.pivot) for j in truth.joints]
    return {"reg_rot_deg": float(angle), "reg_mm": 1e3 * float(max(moved, default=np.nan)),
            "reg_inliers": float(reg.inlier_fraction)}


def run_one(seed: int | str, workdir: Path, reuse: bool = False) -> dict:
    """Generate, write, run and evaluate one scene (in a worker process); with ``reuse``, evaluate
    the run already in ``workdir`` again (the scene is regenerated in memory, not rerun)."""
    os.environ.setdefault("ARTITWIN_HOME", str(workdir / "home"))
    from artitwin_core.synth import generate_scene, write_scene
    from flows.scene import run_scene_inline
    from schemas import PipelineConfig

    run_dir = workdir / "run"
    previous = workdir / "result.json"
    reuse = reuse and (run_dir / "summary.json").is_file() and previous.is_file()
    result: dict = {"seed": seed, "format": scene_format(seed)}
    t0 = time.perf_counter()
    spec = scene_spec(seed)
    scene = generate_scene(spec)
    if not reuse:
        write_scene(scene, workdir / "scene", fmt=scene_format(seed))
    result.update(draw=describe(spec), overlap=scene.truth.overlap_fraction, gen_s=time.perf_counter() - t0,
                  true_types=",".join(j.joint_type for j in scene.truth.joints))
    if reuse:
        old = json.loads(previous.read_text())
        result.update({k: old[k] for k in ("run_s", "cpu_s", "error", "traceback") if k in old})
    else:
        t0 = time.perf_counter()
        try:
            run_scene_inline(workdir / "scene", PipelineConfig.preset("quick"), str(workdir / "store"), out=run_dir)
        except BaseException as exc:  # noqa: BLE001 - the benchmark records any failure of the run
            result["error"] = f"{type(exc).__name__}: {exc}"[:600]
            result["traceback"] = traceback.format_exc()[-3000:]
        result["run_s"] = time.perf_counter() - t0
        own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        # Every thread of the worker and of any process it ran, generation included.
        result["cpu_s"] = own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else None
    if summary is not None:
        stages = summary.get("stages", {})
        if stages:
            slow = max(stages.items(), key=lambda kv: kv[1].get("seconds", 0.0))
            result["slowest_stage"] = f"{slow[0]} {slow[1].get('seconds', 0.0):.0f}s"
        failure = failure_of(summary)
        if failure and "error" not in result:
            result["error"] = failure
        result["est_types"] = ",".join(j["type"] for j in summary.get("joints", []))
        result.update(registration_error(summary, scene.truth, workdir / "store"))
    if "error" in result or summary is None:
        result["status"] = "crash"
        result.setdefault("error", "no summary.json written")
        if summary is not None:  # a failed run that still reports: tally what it says
            result.update(evaluate(scene, summary, run_dir))
        return result
    result["status"] = "ok"
    result.update(evaluate(scene, summary, run_dir))
    return result


# --- the driver -----------------------------------------------------------------------------------


def _launch(seed: int | str, root: Path, timeout: float, threads: int, reuse: bool = False) -> dict:
    workdir = root / scene_dir_name(seed)
    workdir.mkdir(parents=True, exist_ok=True)
    out = workdir / "result.json"
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads),
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(seed), "--workdir", str(workdir)]
    cmd += ["--reuse"] if reuse else []
    t0 = time.perf_counter()
    with open(workdir / "worker.log", "w") as log:
        try:
            proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, timeout=timeout, cwd=ROOT)
            code = proc.returncode
        except subprocess.TimeoutExpired:
            code = None
    if out.is_file() and out.stat().st_mtime >= time.time() - (time.perf_counter() - t0) - 1:
        result = json.loads(out.read_text())
    else:
        tail = (workdir / "worker.log").read_text()[-600:]
        why = f"timeout after {timeout:.0f} s" if code is None else f"worker exited with {code}"
        result = {"seed": seed, "format": scene_format(seed), "status": "crash", "error": f"{why}: {tail}"}
    result["wall_s"] = time.perf_counter() - t0
    print(f"{'seed ' if isinstance(seed, int) else ''}{seed}: {result['status']} in {result['wall_s']:.0f} s"
          + (f" ({result.get('error', '')[:160]})" if result["status"] != "ok" else ""), flush=True)
    return result


def _percentile(values: list[float], q: float) -> float:
    v = np.array([x for x in values if np.isfinite(x)], dtype=float)
    return float(np.percentile(v, q)) if v.size else float("nan")


def totals(results: list[dict]) -> dict:
    """Crash rate, spurious and missed parts, type accuracy, error medians and 90th percentiles."""
    n = len(results)
    crashes = [r for r in results if r["status"] != "ok"]
    parts = [p for r in results for p in r.get("parts", [])]
    n_true = sum(len(r.get("true_types", "").split(",")) if r.get("true_types") else 0 for r in results)
    completed = [r for r in results if r["status"] == "ok"]
    matched = [p for p in parts if p.get("matched")]
    rot = [p for p in matched if p.get("unit") == "deg"]
    pri = [p for p in matched if p.get("unit") == "mm"]
    out = {
        "scenes": n,
        "crashes": len(crashes),
        "crash_rate": len(crashes) / max(n, 1),
        "true_parts": n_true,
        "spurious_exported": sum(r.get("spurious_exported", 0) for r in completed),
        "scenes_with_spurious_exported": sum(r.get("spurious_exported", 0) > 0 for r in completed),
        "spurious_joints": sum(r.get("spurious_joints", 0) for r in completed),
        "missed_parts": sum(not p.get("matched") for r in completed for p in r.get("parts", [])),
        "type_right": sum(bool(p.get("type_ok")) for r in completed for p in r.get("parts", [])),
        "axis_median_deg": _percentile([p["axis_deg"] for p in matched], 50),
        "axis_p90_deg": _percentile([p["axis_deg"] for p in matched], 90),
        "pivot_median_mm": _percentile([p["pivot_mm"] for p in rot], 50),
        "pivot_p90_mm": _percentile([p["pivot_mm"] for p in rot], 90),
        "state_median_deg": _percentile([p["state_rmse"] for p in rot], 50),
        "state_p90_deg": _percentile([p["state_rmse"] for p in rot], 90),
        "state_median_mm": _percentile([p["state_rmse"] for p in pri], 50),
        "state_p90_mm": _percentile([p["state_rmse"] for p in pri], 90),
        "median_run_s": _percentile([r.get("run_s", np.nan) for r in results], 50),
        "median_scene_cpu_s": _percentile([r.get("cpu_s", np.nan) for r in results], 50),
    }
    out["type_right_frac"] = out["type_right"] / max(n_true, 1)
    fates: dict[str, int] = {}
    for r in results:
        for fate, count in r.get("fates", {}).items():
            fates[fate] = fates.get(fate, 0) + count
    out["fates"] = fates
    return out


def _verdicts(t: dict) -> list[tuple[str, str, str, bool]]:
    """``(measure, value, target, met)`` lines for the totals."""
    def ok(value, limit, at_least=False):
        return bool(np.isfinite(value) and (value >= limit if at_least else value <= limit))

    return [
        ("crash rate", f"{t['crashes']}/{t['scenes']}", "0", t["crashes"] == 0),
        ("spurious exported parts", f"{t['spurious_exported']} in {t['scenes_with_spurious_exported']} scenes", "0",
         t["spurious_exported"] == 0),
        ("missed parts (completed runs)", str(t["missed_parts"]), "0", t["missed_parts"] == 0),
        ("type right", f"{t['type_right']}/{t['true_parts']}", ">= 29/30", ok(t["type_right_frac"], TARGETS["type_right_frac"], True)),
        ("axis median", f"{t['axis_median_deg']:.3g} deg", "<= 0.5 deg", ok(t["axis_median_deg"], TARGETS["axis_median_deg"])),
        ("axis p90", f"{t['axis_p90_deg']:.3g} deg", "<= 2 deg", ok(t["axis_p90_deg"], TARGETS["axis_p90_deg"])),
        ("pivot median", f"{t['pivot_median_mm']:.3g} mm (p90 {t['pivot_p90_mm']:.3g})", "<= 5 mm",
         ok(t["pivot_median_mm"], TARGETS["pivot_median_mm"])),
        ("state median (revolute)", f"{t['state_median_deg']:.3g} deg (p90 {t['state_p90_deg']:.3g})", "<= 1 deg",
         ok(t["state_median_deg"], TARGETS["state_median_deg"])),
        ("state median (prismatic)", f"{t['state_median_mm']:.3g} mm (p90 {t['state_p90_mm']:.3g})", "<= 5 mm",
         ok(t["state_median_mm"], TARGETS["state_median_mm"])),
    ]


def _table_row(r: dict) -> dict:
    parts = r.get("parts", [])
    m = [p for p in parts if p.get("matched")]

    def worst(key):
        v = [p.get(key, np.nan) for p in m]
        v = [x for x in v if np.isfinite(x)]
        return max(v) if v else float("nan")

    return {
        "seed": r["seed"], "fmt": r.get("format", ""), "status": r["status"],
        "run_s": r.get("run_s", float("nan")), "cpu_s": r.get("cpu_s", float("nan")), "draw": r.get("draw", ""),
        "overlap": r.get("overlap", float("nan")),
        "types": r.get("true_types", "") + ">" + ",".join(p.get("type_est", "-") for p in parts),
        "est": r.get("est_types", ""),
        "reg_mm": r.get("reg_mm", float("nan")),
        "axis_deg": worst("axis_deg"), "pivot_mm": worst("pivot_mm"),
        "state": worst("state_rmse"),
        "spur_exp": r.get("spurious_exported", ""), "missed": sum(not p.get("matched") for p in parts),
        "slowest": r.get("slowest_stage", ""),
        "error": r.get("error", "")[:100],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=30, help="random scenes to run (default 30)")
    parser.add_argument("--start-seed", type=int, default=0, help="seed of the first scene")
    parser.add_argument("--seeds", type=int, nargs="+", default=None, metavar="SEED",
                        help="run exactly these seeds instead of --scenes from --start-seed")
    parser.add_argument("--jobs", type=int, default=1, help="scenes run in parallel processes")
    parser.add_argument("--keep", type=Path, default=None, help="keep each scene, store and run under this folder")
    parser.add_argument("--timeout", type=float, default=3600.0, help="seconds before a scene's run is a crash")
    parser.add_argument("--reuse", action="store_true",
                        help="with --keep: evaluate the runs already kept there again instead of rerunning them")
    parser.add_argument("--named", nargs="*", default=None, metavar="NAME",
                        help="run these scenes of BENCHMARK_SCENES instead of random ones (no names: all of them)")
    parser.add_argument("--worker", type=scene_id, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--workdir", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker is not None:
        result = run_one(args.worker, args.workdir, args.reuse)
        (args.workdir / "result.json").write_text(json.dumps(result, indent=1, default=float))
        return
    if args.scenes < 1 or args.jobs < 1:
        parser.error("--scenes and --jobs must be at least 1")
    if args.reuse and args.keep is None:
        parser.error("--reuse evaluates the runs kept under --keep DIR; name the folder")
    root = args.keep if args.keep is not None else Path(tempfile.mkdtemp(prefix="artitwin-generalization-"))
    root.mkdir(parents=True, exist_ok=True)
    threads = max(1, (os.cpu_count() or 1) // args.jobs)
    if args.named is not None:
        from artitwin_core.synth import BENCHMARK_SCENES

        unknown = [n for n in args.named if n not in BENCHMARK_SCENES]
        if unknown:
            parser.error(f"unknown scene(s) {unknown}; BENCHMARK_SCENES holds {sorted(BENCHMARK_SCENES)}")
        seeds = list(args.named or BENCHMARK_SCENES)
    elif args.seeds is not None:
        seeds = list(dict.fromkeys(args.seeds))
    else:
        seeds = list(range(args.start_seed, args.start_seed + args.scenes))
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(lambda s: _launch(s, root, args.timeout, threads, args.reuse), seeds))
    wall = time.perf_counter() - t0
    if args.keep is None:
        import shutil

        shutil.rmtree(root, ignore_errors=True)
    which = (f"{len(seeds)} benchmark scenes" if args.named is not None
             else f"{len(seeds)} random scenes (seeds {', '.join(map(str, seeds))})" if args.seeds is not None
             else f"{len(seeds)} random scenes (seeds {seeds[0]}-{seeds[-1]})")
    print(f"\nGeneralization: {which}, quick preset, "
          f"{args.jobs} job(s), {wall:.0f} s")
    print_table([_table_row(r) for r in results])
    t = totals(results)
    print("\nTotals against issue 24's targets")
    print_table([{"measure": m, "value": v, "target": tgt, "met": "yes" if ok else "NO"}
                 for m, v, tgt, ok in _verdicts(t)])
    if t["fates"]:
        print("candidate part fates: " + ", ".join(f"{k} {v}" for k, v in sorted(t["fates"].items())))
    crashes = [r for r in results if r["status"] != "ok"]
    for r in crashes:
        print(f"\ncrash, {r['seed']} ({r.get('draw', '')}):\n  {r.get('error', '')}")
    name = ("generalization_named" if args.named is not None
            else "generalization_seeds" if args.seeds is not None else "generalization")
    path = write_results(name, results, {"totals": t, "targets": TARGETS, "match_ratio": MATCH_RATIO,
                                                     "jobs": args.jobs, "wall_s": wall, "seeds": seeds,
                                                     "preset": "quick"})
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
