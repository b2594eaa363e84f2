"""Read finished runs back (their summary.json and the store it points to) for `artitwin
diagnose` and `artitwin compare`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from artitwin_core import InputError
from artitwin_core.diagnostics._runs import RunComparison, RunRecord, compare_runs, comparison_html
from artitwin_core.reconstruction import split_frames
from infra.store import ArtifactStore
from schemas import DiagnosisReport, JointSet
from schemas._diagnose import DYNAMIC_SCOPE, SELF_CONSISTENCY_METRICS, STATIC_SCOPE


def read_summary(path: str | Path) -> tuple[Path, dict[str, Any]]:
    """``(run folder, summary)`` of a run folder or its summary.json; ``InputError`` naming the path."""
    path = Path(path)
    file = path / "summary.json" if path.is_dir() else path
    if not file.is_file():
        raise InputError(f"{file}: no summary.json here; give a run folder written by `artitwin run --out DIR`.")
    try:
        summary = json.loads(file.read_text())
        summary["stages"]  # noqa: B018 (the one field every summary has)
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{file}: not an ArtiTwin run summary ({e}); rerun the scene to rewrite it.") from None
    return file.parent, summary


# The static recording and joints (or, in a run that failed before them, the static recording
# alone); the dynamic recording.
DIAGNOSIS_STAGES = ("diagnose", "diagnose_static", "diagnose_dynamic")


def _canonical(entry: str) -> str:
    """An ``--effect`` entry without its value, with its scope where the effect has a model per
    recording (a bare one gets the default scope): what two entries are compared by."""
    from schemas._configs import DEFAULT_SCOPES, PER_RECORDING_EFFECTS, split_effect

    scope, name, _ = split_effect(entry)
    if name in PER_RECORDING_EFFECTS:
        return f"{scope or DEFAULT_SCOPES[name]}:{name}"
    return name


def rerun_effects(report: DiagnosisReport, modelled: list[str]) -> tuple[list[str], list[str]]:
    """The ``--effect`` values that model what the diagnosis ``report`` enabled, each in the scope
    it was found in (``dynamic:exposure_white_balance``, ``joint_0:screw_joint``), beside those the
    run already ``modelled`` (``PipelineConfig.enabled_effects``); and the enabled effects no stage
    models there, with their scope. An effect that takes a value gets the one the diagnosis fitted
    (``time_offset=0.033``)."""
    from schemas._configs import EFFECT_SCOPES, EFFECT_STAGES, effect_scope, scope_kind
    from schemas._effects import MODELLED

    have = {_canonical(m) for m in modelled}
    flags, cannot = [], []
    for entry in dict.fromkeys(report.enabled):
        scope, _, name = entry.rpartition("/")
        try:
            short = effect_scope(scope) if scope else None
        except ValueError:
            short = None
        kind = scope_kind(short) if short else None
        if name not in EFFECT_STAGES:
            cannot.append(name if not scope else f"{name} ({scope})")
            continue
        if short is None or kind not in EFFECT_SCOPES[name]:
            where = " or ".join(EFFECT_SCOPES[name])
            cannot.append(f"{name} ({scope}: modelled only in the {where} scope)")
            continue
        flag = f"{short}:{name}"
        if _canonical(flag) in have:
            continue
        param = MODELLED[name].param
        if param:
            # the value fitted where it was enabled: the same effect fitted in another scope (a
            # time offset of the static recording, ~0) is not the one to model here
            fitted = [f.params[param] for f in report.findings
                      if f.name == name and param in f.params and (not scope or f.scope == scope)]
            if not fitted:
                continue
            flag = f"{flag}={float(fitted[0]):.4g}"
        flags.append(flag)
    return sorted(dict.fromkeys(flags)), sorted(dict.fromkeys(cannot))


# What to do about a diagnosed effect no stage models (docs/effects.md, "Which of them a rerun can model").
NOT_MODELLED = {
    "depth_noise": "not modelled: the twin's depth loss is already weighted by the sensor's confidence; a noisier "
    "sensor than assumed calls for capturing closer or with a better depth sensor",
    "axis_tilt": "not modelled yet: a rigid hinge is what the URDF/USD exports can express; the fitted tilt is reported",
    "drawer_tilt": "not modelled yet: a rigid slide is what the URDF/USD exports can express; the fitted tilt is reported",
    "lens_distortion": "not learnable from the images at phone resolution; recalibrate the camera and re-export the "
    "recording with its distortion coefficients (a lens the capture records is honoured)",
    "rolling_shutter": "not modelled: record again moving the camera more slowly (the shift grows with image speed)",
}


def not_modelled_advice(entry: str) -> str:
    """``entry`` (as ``rerun_effects`` lists it) with what to do about it, outside the product if need be."""
    name = entry.split(" (")[0]
    return f"{entry}: {NOT_MODELLED[name]}" if name in NOT_MODELLED else entry


def rank_findings(findings: list) -> list:
    """Every scope's findings in one ranking: enabled first, then significant, then by the share
    of their target's residual they explain (a scope's own order breaks ties)."""
    order = {id(f): i for i, f in enumerate(findings)}
    return sorted(findings, key=lambda f: (not f.enabled, not f.significant, -f.explained_frac, order[id(f)]))


def scope_bare_effects(names: list[str], report: DiagnosisReport | None) -> list[str]:
    """``--effect`` entries with each bare per-recording name (``exposure_white_balance``) put in
    the scope(s) the diagnosis ``report`` found it in (enabled there); a name the diagnosis did
    not enable anywhere, or with no diagnosis at all, keeps its default scope (the static recording)."""
    from schemas._configs import EFFECT_SCOPES, PER_RECORDING_EFFECTS, effect_scope, scope_kind, split_effect

    out = []
    for entry in names:
        scope, name, _ = split_effect(entry)
        found = []
        if scope is None and report is not None and (name in PER_RECORDING_EFFECTS or "joint" in EFFECT_SCOPES.get(name, ())):
            for e in report.enabled:
                where, _, n = e.rpartition("/")
                if n != name:
                    continue
                try:
                    short = effect_scope(where)
                except ValueError:  # a scope no --effect can name
                    continue
                if scope_kind(short) in EFFECT_SCOPES[name]:
                    found.append(f"{short}:{entry}")
        out += found or [entry]
    return out


def fit_joint_names(summary: dict[str, Any]) -> dict[str, str]:
    """``{settled joint name: fit_joints' name}`` of a run: the diagnosis names the settled joints
    (``joint_k``, the k-th part kept), ``fit_joints`` its candidates (``joint_<label - 1>``); they
    differ once a candidate before it was merged or dropped. Empty when the run settled no parts."""
    entry = summary["stages"].get("settle_parts")
    if entry is None or entry.get("status") in ("failed", "skipped"):
        return {}
    try:
        settled = ArtifactStore(summary["store"]).get(entry["key"], JointSet)
    except (KeyError, FileNotFoundError, OSError):
        return {}
    labels = settled.mask_labels or list(range(1, len(settled.joints) + 1))
    return {j.name: f"joint_{int(label) - 1}" for j, label in zip(settled.joints, labels, strict=False)}


def joint_effects_as_fitted(names: list[str], mapping: dict[str, str]) -> tuple[list[str], list[str]]:
    """``--effect`` entries with each joint scope (the diagnosis's settled name) turned into the
    name ``fit_joints`` fits that part under (``fit_joint_names``), and a note per entry changed."""
    from schemas._configs import scope_kind, split_effect

    out, notes = [], []
    for entry in names:
        scope, name, _ = split_effect(entry)
        fitted = mapping.get(scope, scope) if scope is not None and scope_kind(scope) == "joint" else scope
        if fitted != scope:
            out.append(f"{fitted}:{entry.split(':', 1)[1]}")
            notes.append(f"{entry}: the diagnosis's {scope} is the part fit_joints fits as {fitted}")
        else:
            out.append(entry)
    return out, notes


def diagnosis_of(summary: dict[str, Any], where: Path) -> DiagnosisReport | None:
    """The run's diagnosis from its store: the ``diagnose`` report, with the dynamic recording's
    (``diagnose_dynamic``) findings, metrics, curves and conclusion merged in when the run has
    it; in a failed run, the static recording's (``diagnose_static``). None when the run has none."""
    reports = []
    for stage in DIAGNOSIS_STAGES:
        entry = summary["stages"].get(stage)
        if entry is None or entry.get("status") in ("failed", "skipped"):
            continue
        try:
            reports.append(ArtifactStore(summary["store"]).get(entry["key"], DiagnosisReport))
        except (KeyError, FileNotFoundError, OSError) as e:
            raise InputError(
                f"{where}: the {stage} report {entry.get('key', '?')[:16]} is not in the store {summary.get('store')!r} ({e}); "
                "pass the run's --store or rerun the scene."
            ) from None
    if not reports:
        return None
    first = reports[0]
    return first.model_copy(update={
        "findings": [f for r in reports for f in r.findings],
        "enabled": [e for r in reports for e in r.enabled],
        "metrics": {k: v for r in reports for k, v in r.metrics.items() if k not in ("enabled_count", "significant_count")}
        | {"enabled_count": float(sum(len(r.enabled) for r in reports)),
           "significant_count": float(sum(f.significant for r in reports for f in r.findings))},
        "per_frame": {k: v for r in reports for k, v in r.per_frame.items()},
        "frames": {k: v for r in reports for k, v in r.frames.items()},
        "recording_frames": {k: v for r in reports for k, v in r.recording_frames.items()},
        "conclusion": [c for r in reports for c in r.conclusion],
        "no_effect_needed": all(r.no_effect_needed for r in reports),
        "images": [i for r in reports for i in r.images],
    })  # fmt: skip


def run_record(path: str | Path) -> RunRecord:
    """A run reduced to what ``compare_runs`` needs: metrics, per-frame curves, held-out frames."""
    where, summary = read_summary(path)
    metrics: dict[str, float] = {}
    for stage, entry in summary["stages"].items():
        for k, v in (entry.get("metrics") or {}).items():
            if v is not None:
                metrics[f"{stage}/{k}"] = float(v)
    per_frame: dict[str, list[float]] = {}
    heldout: dict[str, list[int]] = {}
    report = diagnosis_of(summary, where)
    config = summary.get("config") or {}
    holdout_every = (config.get("reconstruct") or {}).get("holdout_every")
    dynamic_holdout_every = (config.get("articulate") or {}).get("holdout_every")
    if report is not None:
        for k, v in report.per_frame.items():
            if not k.endswith("_before"):  # "_after" is the diagnosis's what-if, not the twin
                continue
            name = f"diagnose/{k[: -len('_before')]}"
            per_frame[name] = [float("nan") if x is None else float(x) for x in v]
            for scope, every in ((STATIC_SCOPE, holdout_every), (DYNAMIC_SCOPE, dynamic_holdout_every)):
                if k.startswith(scope + "/") and every is not None:
                    heldout[name] = _held_out_entries(report, scope, len(v), int(every))
    return RunRecord(
        name=str(where), effects=list(summary.get("effects", [])), metrics=metrics, per_frame=per_frame, heldout=heldout
    )


def _held_out_entries(report: DiagnosisReport, scope: str, n: int, every: int) -> list[int]:
    """Which of the ``n`` entries of a per-frame curve of ``scope`` are frames its stage (I for the
    static recording, IV for the dynamic one) held out of training: ``split_frames`` over the whole
    recording, mapped through the positions the diagnosis predicted (a subset with
    ``PredictViewsConfig.max_frames``). A report without positions has predicted every frame."""
    positions = report.frames.get(scope)
    if positions is None or len(positions) != n:
        return split_frames(n, every)[1]
    held = set(split_frames(int(report.recording_frames.get(scope, max(positions) + 1)), every)[1])
    return [i for i, p in enumerate(positions) if p in held]


# The per-frame curve of the residual each modelable effect targets (the diagnosis's curves).
EFFECT_CURVES = {
    "exposure_white_balance": ("photometric", "rgb_rms"),
    "vignetting": ("photometric", "rgb_rms"),
    "time_offset": ("photometric", "rgb_rms"),
    "depth_scale_offset": ("depth", "depth_rms_m"),
    "pose_drift": ("depth", "depth_rms_m"),
    "pose_lag": ("depth", "depth_rms_m"),
    "screw_joint": ("joint tracks", "track_rms_m"),
}


def _scopes_of(entry: str, curve_scopes: list[str]) -> list[str]:
    """The diagnosis scopes an ``--effect`` entry models: its own, or for an effect whose one
    switch serves both recordings (or every joint), all of them that have curves."""
    from schemas._configs import DEFAULT_SCOPES, EFFECT_SCOPES, PER_RECORDING_EFFECTS, split_effect

    scope, name, _ = split_effect(entry)
    kinds = EFFECT_SCOPES.get(name, ())
    if name in PER_RECORDING_EFFECTS:
        kinds = (scope or DEFAULT_SCOPES[name],)
    full = {"static": STATIC_SCOPE, "dynamic": DYNAMIC_SCOPE}
    out = [full[k] for k in kinds if k in full]
    if "joint" in kinds:
        out += [s for s in curve_scopes if s not in (STATIC_SCOPE, DYNAMIC_SCOPE)]
    return out


def comparison_targets(ra: RunRecord, rb: RunRecord) -> tuple[list[tuple[str, str, str]], list[tuple[str, str]]]:
    """``(targets, others)`` for ``compare_runs``: the curve, in its scope, of each effect ``rb``
    models and ``ra`` does not; and every other scope's curves."""
    curves = sorted(set(ra.per_frame) & set(rb.per_frame))
    curve_scopes = sorted({c.split("/")[1] for c in curves if c.count("/") >= 2})
    have = {_canonical(e) for e in ra.effects}
    targets = []
    for entry in rb.effects:
        effect = entry.split(":")[-1].split("=")[0]
        if _canonical(entry) in have or effect not in EFFECT_CURVES:
            continue
        target, leaf = EFFECT_CURVES[effect]
        for scope in _scopes_of(entry, curve_scopes):
            # A depth error, drift or vignetting the twin absorbed: the recording's disagreement
            # with itself, where the diagnosis of both runs measured it.
            stage = "diagnose_dynamic" if scope == DYNAMIC_SCOPE else "diagnose"
            own = f"{stage}/{scope}/{SELF_CONSISTENCY_METRICS[effect]}" if effect in SELF_CONSISTENCY_METRICS else None
            if own in ra.metrics and own in rb.metrics:
                targets.append((f"{scope}, agreement with itself ({SELF_CONSISTENCY_METRICS[effect]})", own, entry))
            else:
                targets.append((f"{scope}, {target} ({leaf})", f"diagnose/{scope}/{leaf}", entry))
    others = [(f"{c.split('/')[1]}, {c.split('/')[-1]}", c) for c in curves if c.count("/") >= 2]
    return targets, others


def compare_run_folders(a: str | Path, b: str | Path, html_out: str | Path | None = None) -> RunComparison:
    """Compare run ``b`` with run ``a``; write the HTML report to ``html_out`` when given. The
    comparison leads with the residuals the effects ``b`` adds target, in their scope, on held-out
    frames, and flags any other scope's curve that rose beyond its noise."""
    ra, rb = run_record(a), run_record(b)
    cmp = compare_runs(ra, rb, *comparison_targets(ra, rb))
    if html_out is not None:
        out = Path(html_out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(comparison_html(cmp), encoding="utf-8")
    return cmp
