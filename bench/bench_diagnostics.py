"""Diagnosis of injected effects: detection rate, parameter error and residual before/after, per effect.

For each effect the synthetic generator can inject and the catalog models, tiny scenes (128x96
RGB, 12 static frames, 12 dynamic) are generated over several seeds with only that effect; the
prediction is the ground-truth render without it and the nominal joint (``synthetic_residual_data``).
The diagnosis is not told which effect was injected. Columns: ``first`` = fraction of seeds where
the expected plugin is ranked first and enabled; ``param_err`` = mean absolute error of the
headline parameter (unit in ``param``); ``before``/``after`` = mean target energy before and
after the enabled effects (units of the target: linear RGB^2, m^2, log-ratio^2, m^2);
``cut`` = mean 1 - after/before; ``ranked_first`` = the plugin ranked first most often.
Held out (``diagnose``'s check: every 4th frame held out, frames 2, 6, 10 of 12, images and tracks):
the expected plugin is refitted on the other frames and scored on the held-out ones; ``ho_error``
names the error (rgb_mae_linear, depth_mae_m, depth_nll_nats per pixel, track_rms_m) and
``ho_before``/``ho_after`` are its mean without and with the effect. A per-frame parameter
(exposure gain) is re-estimated on each held-out frame with white balance fixed from training.
The timing effects (``time_offset``, ``rolling_shutter``, and the ``clean door (dense)`` row) run on
``(dense)`` scenes: consecutive 30 fps static frames (stride 1, 0.37 s) with 2x2 anti-aliased RGB,
since the image velocity comes from the recorded poses of neighbouring frames.
The ``clean`` rows count false positives: seeds where any effect was enabled on a scene with
nothing injected; their ``ho_*`` columns are the held-out errors (unchanged: nothing enabled).
The ``twin error`` rows replace the predicted depth by a perturbed twin's (``perturb_twin_depth``:
every surface 2 cm out along its normal plus a 3 cm cosine over the floor plan, fixed in the
world, as an unconverged twin's error is). ``twin error`` alone counts the seeds where a depth
effect the twin-geometry null guards (pose_drift, depth_scale_offset) was enabled anyway (its
``before``/``after`` are the held-out null check's whitened energies of pose_drift: with the
static per-surface correction, then with the drift on top); ``pose_drift + twin error`` must still
find the drift.

The prediction is also rendered densely (``synthetic_residual_data(dense_prediction=True)``: 3x
point samples for the point-sampled scenes, the 2x2 sub-pixels for the anti-aliased ``(dense)``
ones), which the lens and timing effects resample instead of the 1x render;
``--no-dense-prediction`` leaves it out (the 1x resampling of before).

Run: ``python bench/bench_diagnostics.py [--seeds 5] [--first-seed 100] [--effects lens_distortion
"rolling_shutter (dense)" clean ...] [--no-dense-prediction]``; ``--effects`` keeps the rows whose
label starts with one of the words (``clean``, ``twin`` for those rows). Writes
``bench/results/diagnostics.json`` (a partial run: ``diagnostics_partial.json``).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _common import print_table, write_results

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from artitwin_core.diagnostics import diagnose  # noqa: E402
from artitwin_core.diagnostics._synthetic import perturb_twin_depth, synthetic_residual_data  # noqa: E402
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene  # noqa: E402
from artitwin_core.synth._generate import _Recorder  # noqa: E402


def _gains(sc):
    rec = _Recorder(sc.spec, "static")
    return np.stack([rec.gain(t) for t in sc.static.timestamps])


def _q_max(sc):
    return float(np.max(np.abs(sc.truth.joints[0].q)))


# Consecutive 30 fps static frames and 2x2 anti-aliased RGB: the timing effects need the camera's
# velocity (poses 0.27 s apart cannot follow hand shake) and a render that resamples cleanly.
DENSE = {"static_stride": 1, "rgb_supersample": 2}

# (injected effect, params, furniture, expected plugin, parameter name, error(scene, fitted params)[, spec])
CASES = [
    ("exposure", {}, "door", "exposure_white_balance", "gain_rel",
     lambda sc, p: float(np.mean(np.abs(np.asarray(p["gain"]) / _gains(sc) - 1)))),
    ("white_balance", {}, "door", "exposure_white_balance", "rb_ratio",
     lambda sc, p: float(np.mean(np.abs(np.asarray(p["gain"])[:, [0, 2]] / np.asarray(p["gain"])[:, 1:2]
                                        - _gains(sc)[:, [0, 2]] / _gains(sc)[:, 1:2])))),
    ("vignetting", {}, "door", "vignetting", "falloff", lambda sc, p: abs(p["corner_falloff"] - 0.35)),
    ("depth_bias", {}, "door", "depth_scale_offset", "scale", lambda sc, p: abs(p["scale"] - 1.03)),
    ("depth_noise", {"a_m": 0.002, "b_per_m": 0.008}, "door", "depth_noise", "b_rel",
     lambda sc, p: abs(p["b_per_m"] / 0.008 - 1)),
    ("screw_joint", {}, "door", "screw_joint", "pitch_m_per_rad",
     lambda sc, p: abs(p["pitch_m_per_rad"] - sc.truth.joints[0].pitch)),
    ("axis_sag", {}, "door", "axis_tilt", "tilt_rel",
     lambda sc, p: abs(p["tilt_rad_per_rad"] / (0.04 / _q_max(sc)) - 1)),
    ("drawer_tilt", {}, "drawer", "drawer_tilt", "tilt_rel",
     lambda sc, p: abs(p["tilt_rad_per_m"] / (0.04 / _q_max(sc)) - 1)),
    ("lens_distortion", {"record": False}, "door", "lens_distortion", "k1", lambda sc, p: abs(p["k1"] + 0.08)),
    ("pose_drift", {}, "door", "pose_drift", "drift_m_per_s", lambda sc, p: abs(p["drift_trans_m_per_s"] - 0.02)),
    ("time_offset", {}, "door", "time_offset", "seconds", lambda sc, p: abs(p["seconds"] - 0.05), DENSE),
    ("rolling_shutter", {}, "door", "rolling_shutter", "readout_s", lambda sc, p: abs(p["readout_s"] - 0.03), DENSE),
    ("rolling_shutter", {"readout_s": 0.05}, "door", "rolling_shutter", "readout_s",
     lambda sc, p: abs(p["readout_s"] - 0.05), DENSE),
]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--effects", nargs="*", default=None, help="row labels (prefixes) to run; default all")
    ap.add_argument("--no-dense-prediction", action="store_true", help="resample the 1x prediction (as before)")
    args = ap.parse_args()
    dense_pred = not args.no_dense_prediction

    def wanted(label: str) -> bool:
        return args.effects is None or any(label.startswith(e) for e in args.effects)

    base = replace(BENCHMARK_SCENES["tiny"], hand_occlusion=0.0)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rows = []
    t0 = time.perf_counter()
    for name, params, furniture, expected, pname, err, *spec in CASES:
        first, perr, before, after, tops, ho_before, ho_after, ho_err = [], [], [], [], [], [], [], ""
        over = spec[0] if spec else {}
        label = name + "".join(f" {k}={v}" for k, v in params.items() if k != "record") + (" (dense)" if over else "")
        if not wanted(label):
            continue
        for seed in seeds:
            sc = generate_scene(replace(base, furniture=furniture, effects=((name, params),), seed=seed, **over))
            dg = diagnose(synthetic_residual_data(sc, seed=seed, dense_prediction=dense_pred))
            ok = bool(dg.ranking and dg.ranking[0].name == expected and dg.enabled and dg.enabled[0].name == expected)
            first.append(ok)
            tops.append(dg.ranking[0].name if dg.ranking else "(none)")
            check = next((c for c in (dg.heldout.checks if dg.heldout else []) if c.name == expected), None)
            if check is not None:
                ho_err = check.error
                ho_before.append(check.error_before)
                ho_after.append(check.error_after)
            sig = next((s for s in dg.ranking if s.name == expected), None)
            if sig is not None:
                perr.append(err(sc, sig.params))
                before.append(sig.energy_before)
                after.append(dg.energy_after[sig.target])
        rows.append({"effect": label, "expected": expected, "ranked_first": max(set(tops), key=tops.count),
                     "first": float(np.mean(first)), "param": pname,
                     "param_err": float(np.mean(perr)), "before": float(np.mean(before)),
                     "after": float(np.mean(after)), "cut": float(np.mean(1 - np.array(after) / np.array(before))),
                     "ho_error": ho_err, "ho_before": float(np.mean(ho_before)) if ho_before else float("nan"),
                     "ho_after": float(np.mean(ho_after)) if ho_after else float("nan")})
        print(f"  {name}: {time.perf_counter() - t0:.0f} s", flush=True)
    for furniture, over in (("door", {}), ("drawer", {}), ("door", DENSE)):
        if not wanted(f"clean {furniture}" + (" (dense)" if over else "")):
            continue
        fp, ho_before, ho_after = [], [], []
        for seed in seeds:
            sc = generate_scene(replace(base, furniture=furniture, seed=seed, **over))
            dg = diagnose(synthetic_residual_data(sc, seed=seed, dense_prediction=dense_pred))
            fp.append([s.name for s in dg.enabled])
            ho_before.append(dg.heldout.errors_before["track_rms_m"])
            ho_after.append(dg.heldout.errors_after["track_rms_m"])
        rows.append({"effect": f"clean {furniture}" + (" (dense)" if over else ""), "expected": "(none)",
                     "ranked_first": "(none enabled)" if not any(fp) else "false positive",
                     "first": float(np.mean([not f for f in fp])), "param": "false positives",
                     "param_err": float(sum(bool(f) for f in fp)), "before": float("nan"), "after": float("nan"),
                     "cut": float("nan"), "ho_error": "track_rms_m", "ho_before": float(np.mean(ho_before)),
                     "ho_after": float(np.mean(ho_after))})
    twin = {"amplitude_m": 0.03, "wavelength_m": 2.0, "offset_m": 0.02}
    for label, effects in (("twin error", ()), ("pose_drift + twin error", (("pose_drift", {}),))):
        if not wanted(label):
            continue
        hits, null_e, eff_e, ho_before, ho_after = [], [], [], [], []
        for seed in seeds:
            sc = generate_scene(replace(base, furniture="door", effects=effects, seed=seed))
            data = synthetic_residual_data(sc, seed=seed, dense_prediction=dense_pred)
            dg = diagnose(perturb_twin_depth(data, **twin))
            on = [s.name for s in dg.enabled]
            hits.append(bool(on and on[0] == "pose_drift") if effects else
                        not ({"pose_drift", "depth_scale_offset"} & set(on)))
            check = next((c for c in dg.null_checks if c.name == "pose_drift"), None)
            if check is not None:
                null_e.append(check.energy_null)
                eff_e.append(check.energy_effect)
            ho_before.append(dg.heldout.errors_before["depth_mae_m"])
            ho_after.append(dg.heldout.errors_after["depth_mae_m"])
        rows.append({"effect": label, "expected": "pose_drift" if effects else "(no depth effect)",
                     "ranked_first": "pose_drift" if effects and all(hits) else "-",
                     "first": float(np.mean(hits)), "param": "null: gain over null",
                     "param_err": float(np.mean(1 - np.array(eff_e) / np.array(null_e))) if null_e else float("nan"),
                     "before": float(np.mean(null_e)) if null_e else float("nan"),
                     "after": float(np.mean(eff_e)) if eff_e else float("nan"),
                     "cut": float(np.mean(1 - np.array(eff_e) / np.array(null_e))) if null_e else float("nan"),
                     "ho_error": "depth_mae_m", "ho_before": float(np.mean(ho_before)),
                     "ho_after": float(np.mean(ho_after))})
        print(f"  {label}: {time.perf_counter() - t0:.0f} s", flush=True)
    print_table(rows)
    meta = {"seeds": list(seeds), "seconds": time.perf_counter() - t0, "dense_prediction": dense_pred}
    write_results("diagnostics" if args.effects is None else "diagnostics_partial", rows, meta)


if __name__ == "__main__":
    main()
