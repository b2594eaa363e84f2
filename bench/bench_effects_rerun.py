"""Add an effect and rerun (issue 8): for each camera effect a stage can model, inject it into a
small synthetic scene, run the pipeline up to the diagnosis, rerun with the effect modelled
(``PipelineConfig.with_effects``), and compare the two twins.

Columns: the injected effect; whether the first run's diagnosis ranks the matching catalog effect
first among the effects on its target; the twin's own residual energy on that target (no
diagnosis correction) before and after; held-out PSNR and depth error of the canonical 3DGS on
frames it never trained on; how many stages the rerun took from the store.

    .venv/bin/python bench/bench_effects_rerun.py [--effects exposure vignetting depth_bias] [--steps 300]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from _common import print_table, write_results

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene  # noqa: E402
from flows._runner import InlineExecutor  # noqa: E402
from flows.nightly import select_pipeline  # noqa: E402
from infra.store import ArtifactStore  # noqa: E402
from schemas import DiagnosisReport, PipelineConfig, StageReport  # noqa: E402

STATIC = "static recording"
STAGES = ["ingest", "pose_lag", "correct_pose_lag", "depth_calibration", "calibrate_depth", "refine_poses", "reconstruct", "reconstruct_report",
          "register", "part_masks", "frame_poses", "correct_frame_poses", "track", "fit_joints", "settle_parts", "final_masks", "joint_states", "predict_views", "diagnose"]
# injected synthetic effect(s) -> (catalog effect that models it, its target)
CASES = {
    "exposure": ((("exposure", {}), ("white_balance", {})), "exposure_white_balance", "photometric"),
    "vignetting": ((("vignetting", {"strength": 0.35}),), "vignetting", "photometric"),
    "depth_bias": ((("depth_bias", {"scale": 1.03, "offset_m": 0.01}),), "depth_scale_offset", "depth"),
}


def _run(scene: Path, config: PipelineConfig, store: ArtifactStore) -> dict:
    ex = InlineExecutor(store)
    return {n: ex.result(h) for n, h in select_pipeline(scene, config, ex, STAGES).items()}


def bench_case(name: str, steps: int, root: Path) -> dict:
    injected, effect, target = CASES[name]
    spec = replace(BENCHMARK_SCENES["tiny"], static_frames=24, effects=injected)
    write_scene(generate_scene(spec), root / name / "scene")
    store = ArtifactStore(str(root / name / "store"))
    base = PipelineConfig.preset("quick")
    base = base.model_copy(update={"reconstruct": base.reconstruct.model_copy(update={"steps": steps, "holdout_every": 4})})
    t0 = time.perf_counter()
    a = _run(root / name / "scene", base, store)
    t1 = time.perf_counter()
    b = _run(root / name / "scene", base.with_effects([effect]), store)
    t2 = time.perf_counter()
    da, db = store.get(a["diagnose"].key, DiagnosisReport), store.get(b["diagnose"].key, DiagnosisReport)
    ra, rb = (store.get(r["reconstruct_report"].key, StageReport).metrics for r in (a, b))
    on_target = [f for f in da.findings if f.scope == STATIC and f.target == target]
    key = f"{STATIC}/{target}_energy_before"
    return {
        "injected": name,
        "effect": effect,
        "ranked_first": bool(on_target and on_target[0].name == effect),
        "energy_before": da.metrics[key],
        "energy_after": db.metrics[key],
        "cut": 1.0 - db.metrics[key] / da.metrics[key],
        "heldout_psnr_before_db": ra["heldout_psnr_db"],
        "heldout_psnr_after_db": rb["heldout_psnr_db"],
        "heldout_depth_mae_before_m": ra["heldout_depth_mae_m"],
        "heldout_depth_mae_after_m": rb["heldout_depth_mae_m"],
        "rerun_cached_stages": sum(r.status == "cached" for r in b.values()),
        "rerun_stages": len(b),
        "first_run_s": t1 - t0,
        "rerun_s": t2 - t1,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--steps", type=int, default=300, help="3DGS steps of both runs")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.effects:
            rows.append(bench_case(name, args.steps, Path(tmp)))
            print_table(rows[-1:])
    print_table(rows)
    write_results("effects_rerun", rows, {"steps": args.steps})


if __name__ == "__main__":
    main()
