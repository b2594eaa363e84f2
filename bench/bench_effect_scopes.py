"""Close the loop where the effect lives (issue 28): each modelable effect injected into the static
recording only, the dynamic recording only, or both; and each effect enabled on a clean scene.

Injected rows (``--cases``, ``--where``): a tiny door scene (seed ``--seed``) with the effect in
the recordings named; the pipeline runs to its diagnoses (quick preset), the rerun enables the
``--effect`` flags the diagnosis prints (``rerun_effects``, as ``artitwin diagnose`` does), and
the two runs are compared as ``artitwin compare`` does. Columns:

- ``named``: in every scope the effect was injected in, the diagnosis ranks it first there
  (enabled); ``elsewhere``: scopes where it was enabled but not injected;
- ``flags``: the rerun's ``--effect`` values;
- ``cut``: the smallest cut, over the scopes it was injected in, of the diagnosis's held-out
  error on the targeted residual (``rgb_mae_linear`` for the camera, ``depth_mae_m`` for depth and
  poses, ``track_rms_m`` for joints; the error the issue quotes), twin A against twin B (target:
  >= 50 %); ``compare_lead_cut``: the cut ``artitwin compare`` leads with (per-frame ``rgb_rms``
  or ``depth_rms_m`` on the frames stage I / IV held out); ``regressions``: other scopes' curves
  that rose beyond their noise (target: none).

Clean rows (``--clean``): the clean scene, each effect enabled in each scope it has a model in,
against the plain run: the change of held-out PSNR (the static twin's, ``reconstruct_report``;
the dynamic recording's, from the diagnosis's held-out ``rgb_rms`` of linear RGB) (target:
< 0.3 dB) and other scopes' regressions.

Every run of one scene shares a store, so a rerun recomputes the stages its effect changes only.

    .venv/bin/python bench/bench_effect_scopes.py --cases exposure --where dynamic static both
    .venv/bin/python bench/bench_effect_scopes.py --cases --clean
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from _common import print_table, write_results

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from artitwin_core.diagnostics._runs import curve_shift, target_shift  # noqa: E402
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene  # noqa: E402
from flows._pipeline import build_summary, write_summary  # noqa: E402
from flows._runner import InlineExecutor  # noqa: E402
from flows._runs import (  # noqa: E402
    comparison_targets,
    diagnosis_of,
    rank_findings,
    read_summary,
    rerun_effects,
    run_record,
)
from flows.nightly import select_pipeline  # noqa: E402
from infra.store import ArtifactStore  # noqa: E402
from schemas import PipelineConfig  # noqa: E402
from schemas._diagnose import SELF_CONSISTENCY_METRICS  # noqa: E402

STAGES = ["ingest", "pose_lag", "correct_pose_lag", "depth_calibration", "calibrate_depth", "static_drift",
          "refine_poses", "reconstruct", "reconstruct_report", "register", "part_masks", "session_drift",
          "correct_pose_drift", "frame_poses", "correct_frame_poses", "track", "fit_joints", "settle_parts",
          "final_masks", "joint_states", "articulate", "articulate_report", "predict_dynamic", "diagnose_dynamic",
          "predict_views", "diagnose"]
# injected synthetic effect -> (its parameters, the catalog effect that models it)
CASES = {
    "exposure": ({"stops_std": 0.35}, "exposure_white_balance"),
    "vignetting": ({"strength": 0.35}, "vignetting"),
    "depth_bias": ({"scale": 1.03, "offset_m": 0.01}, "depth_scale_offset"),
    "pose_lag": ({"seconds": 0.067}, "pose_lag"),
    "pose_drift": ({"trans_m_per_s": 0.02, "yaw_rad_per_s": 0.01}, "pose_drift"),
    "time_offset": ({"seconds": 0.05}, "time_offset"),
    "screw_joint": ({"rise_m_per_rad": 0.01}, "screw_joint"),
}
# Injected effects the pipeline corrects without a rerun, and the parameter its estimate is judged against.
AUTO_CORRECTED = {"pose_lag": "seconds"}
SCOPE = {"static": ["static recording"], "dynamic": ["dynamic recording"], "both": ["static recording", "dynamic recording"]}
# (effect, --effect scope) pairs enabled on the clean scene; time_offset takes a value the user
# gives (nothing to regularise), so it has no clean row.
CLEAN = [("exposure_white_balance", "static"), ("exposure_white_balance", "dynamic"), ("vignetting", "static"),
         ("vignetting", "dynamic"), ("depth_scale_offset", "static"), ("pose_drift", "static"), ("pose_lag", "static"),
         ("screw_joint", "joint_0")]


# The tiny scene's depth (64 x 48) is coarser than any phone's: there the static recording's
# self-consistency finds a depth error of ~1 % in clean frames. Doubled, it is 256 x 192 RGB
# and 128 x 96 depth.
SIZE = 2


# Cases whose effect the tiny scene's recordings cannot show, and the recordings they need:
# - a linear pose drift is enabled only when each half of the recording sees it alike
#   (DriftSignificance.why_not), which needs 2 x 8 + 2 frames (the calibration's largest frame
#   gap): a longer static sweep than the others' 16 frames;
# (A time offset is read from the camera's velocity, which poses more than 0.1 s apart cannot
# tell; the tiny scene's frames are 0.27 s and 0.17 s apart, and its rows ran on every second
# frame of the 30 fps streams until the velocity was read off the recordings' pose streams.)
CASE_SPEC = {"pose_drift": {"static_frames": 24}}


def _scene(root: Path, seed: int, effects: tuple, size: int, **spec_changes) -> Path:
    tiny = BENCHMARK_SCENES["tiny"]
    spec = replace(tiny, **{"static_frames": 16, **spec_changes}, seed=seed, effects=effects,
                   rgb_size=tuple(size * v for v in tiny.rgb_size), depth_size=tuple(size * v for v in tiny.depth_size))
    write_scene(generate_scene(spec), root / "scene")
    return root / "scene"


def _run(scene: Path, config: PipelineConfig, store: ArtifactStore, out: Path) -> tuple[float, int]:
    """Run ``STAGES`` and write the run folder; ``(seconds, stages recomputed)``."""
    t0 = time.perf_counter()
    ex = InlineExecutor(store)
    runs = {n: ex.result(h) for n, h in select_pipeline(scene, config, ex, STAGES).items()}
    write_summary(build_summary(scene, store, runs, 0.0, config), out)
    return time.perf_counter() - t0, sum(r.status == "computed" for r in runs.values())


def _compare(a: Path, b: Path) -> tuple[list[dict], list[str]]:
    """The targeted curves on held-out frames (before, after, cut) and the other scopes' curves
    that rose beyond their noise, as ``artitwin compare`` judges them."""
    ra, rb = run_record(a), run_record(b)
    targets, others = comparison_targets(ra, rb)
    out = []
    for label, curve, entry in targets:
        shift = target_shift(ra, rb, curve)
        if shift is not None:
            ma, mb, n, _ = shift
            out.append({"curve": label, "entry": entry, "before": ma, "after": mb, "cut": 1 - mb / ma if ma else math.nan, "frames": n})
    rose = []
    for label, curve in others:
        shift = curve_shift(ra, rb, curve)
        if shift is not None and shift[3] and shift[1] > shift[0]:
            rose.append(f"{label} {100 * (shift[1] / shift[0] - 1):+.0f}%")
    return out, rose


def _heldout_psnr(run: Path) -> dict[str, float]:
    """Held-out PSNR (dB) of the static twin (``reconstruct_report``) and, from the diagnosis's
    held-out ``rgb_rms`` of linear RGB, of the dynamic recording."""
    rec = run_record(run)
    out = {"static": rec.metrics.get("reconstruct_report/heldout_psnr_db", math.nan)}
    name = "diagnose/dynamic recording/rgb_rms"
    if name in rec.per_frame and rec.heldout.get(name):
        vals = [rec.per_frame[name][i] for i in rec.heldout[name] if math.isfinite(rec.per_frame[name][i])]
        out["dynamic"] = -20 * math.log10(math.sqrt(sum(v * v for v in vals) / len(vals))) if vals else math.nan
    return out


# The diagnosis's held-out error of each target (its held-out frames, refitted without them).
HELDOUT_ERROR = {"photometric": "rgb_mae_linear", "depth": "depth_mae_m", "self-consistency": "depth_mae_m",
                 "joint-tracks": "track_rms_m"}


def _named_first(ranked: list, scope: str, effect: str) -> bool:
    """The diagnosis names ``effect`` first in ``scope``: it is enabled there, and no other effect
    enabled there on the same residual ranks above it (other residuals, e.g. the depth noise
    beside an exposure drift, are other findings)."""
    on = [f for f in ranked if f.scope == scope and f.enabled]
    mine = next((f for f in on if f.name == effect), None)
    return mine is not None and next(f for f in on if f.target == mine.target) is mine


def _heldout_cuts(a: Path, b: Path, scopes: list[str], effect_target: str, effect: str) -> dict[str, float]:
    """Per scope, the cut of the diagnosis's held-out error on the effect's target (A's twin
    against B's: ``heldout_<error>_before`` of each run); for a target of the recording's
    agreement with itself, the cut of that disagreement (``SELF_CONSISTENCY_METRICS``: no twin is
    fitted to it, so there is nothing to hold out)."""
    ra, rb = run_record(a), run_record(b)
    err = HELDOUT_ERROR[effect_target]
    out = {}
    for s in scopes:
        stage = "diagnose_dynamic" if s == "dynamic recording" else "diagnose"
        key = f"{stage}/{s}/heldout_{err}_before"
        if effect_target == "self-consistency" and effect in SELF_CONSISTENCY_METRICS:
            key = f"{stage}/{s}/{SELF_CONSISTENCY_METRICS[effect]}"
        if key in ra.metrics and key in rb.metrics and ra.metrics[key] > 0:
            out[s] = 1.0 - rb.metrics[key] / ra.metrics[key]
    return out


def injected_row(case: str, where: str, seed: int, root: Path, size: int = SIZE) -> dict:
    params, effect = CASES[case]
    if case == "screw_joint":
        where, injected = "joint", (("screw_joint", params),)
    else:
        injected = ((case, {**params, "recordings": where}),)
    if case == "exposure":  # a phone's auto exposure moves the white balance with it
        injected += (("white_balance", {"gain_std": 0.06, "recordings": where}),)
    scene = _scene(root, seed, injected, size, **CASE_SPEC.get(case, {}))
    store = ArtifactStore(str(root / "store"))
    base = PipelineConfig.preset("quick")
    t_a, _ = _run(scene, base, store, root / "a")
    where_a, summary = read_summary(root / "a")
    report = diagnosis_of(summary, where_a)
    scopes = ["joint_0"] if where == "joint" else SCOPE[where]
    ranked = rank_findings(list(report.findings)) if report is not None else []
    named = all(_named_first(ranked, s, effect) for s in scopes)
    elsewhere = sorted({f.scope for f in ranked if f.name == effect and f.enabled and f.scope not in scopes})
    flags = rerun_effects(report, base.enabled_effects())[0] if report is not None else []
    first = {s: next((f"{f.name} ({'enabled' if f.enabled else 'not enabled'}, {100 * f.explained_frac:.0f}%)"
                      for f in ranked if f.scope == s), "-") for s in scopes}
    row = {"case": case, "where": where, "seed": seed, "effect": effect, "named": named, "first": first,
           "elsewhere": elsewhere, "enabled": list(report.enabled) if report is not None else [], "flags": flags,
           "first_run_s": t_a}
    # An effect the pipeline corrects by itself when its evidence passes a gate (pose_lag): found
    # and corrected in the first run, in its own scopes, with no rerun to ask for. Judged by how
    # close the correction came to what was injected (issue 24: a quarter of a frame).
    auto = {f.scope: f.params for f in ranked if f.name == effect and f.scope in scopes and f.significant
            and f.params.get("applied")}
    if case in AUTO_CORRECTED and set(auto) == set(scopes):
        truth = params[AUTO_CORRECTED[case]]
        err = {sc: abs(p["seconds"] - truth) * abs(p["frames"] / p["seconds"]) for sc, p in auto.items() if p["seconds"]}
        other = [f for f in flags if f.split(":")[-1].split("=")[0] != effect]
        return row | {"named": not elsewhere, "corrected_in_first_run": {sc: p["seconds"] for sc, p in auto.items()},
                      "error_frames": err, "other_flags": other, "cut": math.nan, "regressions": [], "targets": [],
                      "passed": bool(not elsewhere and err and max(err.values()) <= 0.25)}
    if not flags:
        return row | {"cut": math.nan, "regressions": [], "targets": [], "passed": False}
    t_b, recomputed = _run(scene, base.with_effects(flags), store, root / "b")
    targets, rose = _compare(root / "a", root / "b")
    ours = [t for t in targets if t["entry"].split(":")[-1].split("=")[0] == effect]
    cut_rms = min((t["cut"] for t in ours), default=math.nan)
    found = next((f for f in ranked if f.name == effect and f.scope in scopes), None)
    cuts = _heldout_cuts(root / "a", root / "b", scopes, found.target if found is not None else "photometric", effect)
    cut = min(cuts.values(), default=math.nan)
    return row | {"cut": cut, "cut_by_scope": cuts, "compare_lead_cut": cut_rms, "regressions": rose, "targets": targets,
                  "rerun_s": t_b, "rerun_stages_computed": recomputed,
                  "passed": bool(named and not elsewhere and cut >= 0.5 and not rose)}


def clean_rows(seed: int, root: Path, pairs: list[tuple[str, str]], size: int = SIZE) -> list[dict]:
    scene = _scene(root, seed, (), size)
    store = ArtifactStore(str(root / "store"))
    base = PipelineConfig.preset("quick")
    _run(scene, base, store, root / "plain")
    plain = _heldout_psnr(root / "plain")
    rows = []
    for name, scope in pairs:
        out = root / f"{scope}-{name}"
        t, recomputed = _run(scene, base.with_effects([f"{scope}:{name}"]), store, out)
        psnr = _heldout_psnr(out)
        _, rose = _compare(root / "plain", out)
        d = {k: psnr.get(k, math.nan) - plain.get(k, math.nan) for k in ("static", "dynamic")}
        rows.append({"case": "clean", "seed": seed, "effect": f"{scope}:{name}",
                     "static_psnr_change_db": d["static"], "dynamic_psnr_change_db": d["dynamic"],
                     "regressions": rose, "rerun_s": t, "rerun_stages_computed": recomputed,
                     "passed": bool(all(not math.isfinite(v) or abs(v) < 0.3 for v in d.values()) and not rose)})
        print_table(rows[-1:])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES), help="effects injected (none: only --clean)")
    ap.add_argument("--where", nargs="+", default=list(SCOPE), choices=list(SCOPE), help="recordings injected into")
    ap.add_argument("--clean", action="store_true", help="also enable each effect on the clean scene")
    ap.add_argument("--clean-effects", nargs="*", default=None, help="with --clean: SCOPE:NAME pairs (default: all)")
    ap.add_argument("--seed", type=int, default=0, help="scene seed")
    ap.add_argument("--size", type=int, default=SIZE, help="the tiny scene's RGB and depth sizes times this")
    ap.add_argument("--name", default="effect_scopes", help="results file bench/results/NAME.json")
    ap.add_argument("--keep", type=Path, default=None, help="keep the scenes, stores and runs under this folder")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = args.keep or tmp
        for case in args.cases:
            for where in (["joint"] if case == "screw_joint" else args.where):
                rows.append(injected_row(case, where, args.seed, Path(tmp) / f"{case}-{where}", args.size))
                print_table([{k: v for k, v in rows[-1].items() if k != "targets"}])
        if args.clean:
            pairs = CLEAN if args.clean_effects is None else [(e.partition(":")[2], e.partition(":")[0]) for e in args.clean_effects]
            rows += clean_rows(args.seed, Path(tmp) / "clean", pairs, args.size)
    print_table([{k: v for k, v in r.items() if k != "targets"} for r in rows])
    write_results(args.name, rows, {"seed": args.seed, "preset": "quick", "scene": f"tiny x{args.size}, 16 static frames (changed for some cases: {CASE_SPEC})"})


if __name__ == "__main__":
    main()
