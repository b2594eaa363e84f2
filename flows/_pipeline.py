"""The scene pipeline as a graph of stages, independent of how stages are executed.

``scene_pipeline`` names which stage consumes which output; the executor decides whether they
run inline or as Prefect tasks. New stages are added here, in order.
"""

from __future__ import annotations

import base64
import io
import json
import math
import os
import shutil
import subprocess
import time
from dataclasses import asdict
from html import escape
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from artitwin_core import ArtiTwinError
from artitwin_core.capture import find_scene_recordings, recording_files
from flows._runner import Executor, StageFailure, StageRun, raw_input
from infra.store import ArtifactStore
from schemas import (
    DepthCalibrationResult,
    DiagnosisReport,
    ExportBundle,
    FramePoseCorrections,
    JointSet,
    PipelineConfig,
    PoseDriftResult,
    PoseLagResult,
    Registration,
    StageReport,
    TrajectoriesArtifact,
)

SUMMARY_VERSION = 2


def gpu_available() -> bool:
    """True when the 3DGS stages would train on CUDA (a CUDA device and gsplat: ``backend="auto"``)."""
    from artitwin_core.gaussians import resolve_backend

    return resolve_backend("auto").is_cuda


def hardware_preset(name: str) -> PipelineConfig:
    """``PipelineConfig.preset(name)`` for this machine: the GPU budget when :func:`gpu_available`."""
    return PipelineConfig.preset(name, gpu=gpu_available())


class SceneFailed(ArtiTwinError):
    """A scene run in which a stage failed; ``summary`` is what was written (``status: failed``,
    the failed stage and its error, everything that completed, the static diagnosis if it ran)."""

    def __init__(self, summary: dict[str, Any]):
        failed = summary.get("failed_stages") or ["?"]
        super().__init__(f"stage {failed[0]} failed: {summary.get('error', '')}")
        self.summary = summary


class PipelineHandles(dict):
    """Stage handles by ``stage/label``, and the handle of the static capture every static stage
    reads (after any correction), so a failed run can still diagnose the static recording."""

    static_capture: Any = None


def scene_pipeline(scene: str | Path, config: PipelineConfig, ex: Executor) -> PipelineHandles:
    """Submit every stage of one scene; returns handles by ``stage/label``."""
    recordings = find_scene_recordings(Path(scene))
    h = PipelineHandles()
    caps = {}
    for label, path in (("static", recordings.static), ("dynamic", recordings.dynamic)):
        raw = raw_input(path, recording_files(path))
        caps[label] = h[f"ingest/{label}"] = ex.submit("ingest", config.ingest, {"recording": raw}, label)
        h[f"capture_check/{label}"] = ex.submit("capture_check", config.capture_check, {"capture": caps[label]}, label)
    # Poses that lag the images are corrected first, before anything is built on them: the static
    # recording's drift, depth calibration, refined poses and 3DGS, the dynamic recording's
    # registration and part masks (a lagging pose makes the background look moved: phantom parts).
    # Each lag is estimated from its own recording, so it needs nothing downstream. With the
    # correction off the lag is only reported, and every other stage keeps its key.
    lags = {}
    for label in ("static", "dynamic"):
        lags[label] = h[f"pose_lag/{label}"] = ex.submit("pose_lag", config.pose_lag, {"capture": caps[label]}, label)
        if config.pose_lag.correct:
            caps[label] = h[f"correct_pose_lag/{label}"] = ex.submit(
                "correct_pose_lag", config.pose_lag, {"capture": caps[label], "lag": lags[label]}, label
            )
    # With the poses' drift modelled (pose_drift), the static recording's is fitted from its own
    # frames and corrected before anything else is built on it (the depth calibration included,
    # which drifting poses would bias); the dynamic recording's needs the canonical model and its
    # part masks, so it is corrected after part_masks (below).
    if config.pose_drift.model:
        static_drift = h["static_drift"] = ex.submit("static_drift", config.pose_drift, {"capture": caps["static"]}, "static")
        caps["static"] = h["correct_pose_drift/static"] = ex.submit(
            "correct_pose_drift", config.pose_drift, {"capture": caps["static"], "drift": static_drift}, "static"
        )
    # With the sensor's depth error modelled (the effect depth_scale_offset), it is found from the
    # static recording and every stage reads both recordings' depth corrected by it, the 3DGS too:
    # the Gaussians are then metric, as the joints fitted to the corrected depth are. The 3DGS is
    # not asked to learn the error again: its own estimate is loose (±1.5 % on the tiny scene) and
    # would pull the Gaussians off the corrected depth.
    recon_config = config.reconstruct
    if "depth_scale_offset" in config.reconstruct.sensor_effects:
        recon_config = recon_config.model_copy(
            update={"sensor_effects": [e for e in recon_config.sensor_effects if e != "depth_scale_offset"]}
        )
        calibration = h["depth_calibration"] = ex.submit(
            "depth_calibration", config.calibrate_depth, {"capture": caps["static"]}, "static"
        )
        for label in ("static", "dynamic"):
            caps[label] = h[f"calibrate_depth/{label}"] = ex.submit(
                "calibrate_depth", config.calibrate_depth, {"capture": caps[label], "calibration": calibration}, label
            )
    static, dynamic = caps["static"], caps["dynamic"]
    h.static_capture = static
    # I. canonical reconstruction of the static recording
    poses = h["refine_poses"] = ex.submit("refine_poses", config.refine_poses, {"capture": static}, "static")
    gaussians = h["reconstruct"] = ex.submit("reconstruct", recon_config, {"capture": static, "poses": poses}, "static")
    h["reconstruct_report"] = ex.submit(
        "reconstruct_report", recon_config, {"capture": static, "poses": poses, "gaussians": gaussians}, "static"
    )
    # II. registration and part masks of the dynamic recording
    reg = h["register"] = ex.submit("register", config.registration, {"static": static, "dynamic": dynamic}, "dynamic")
    masks = h["part_masks"] = ex.submit(
        "part_masks",
        config.part_masks,
        {"static": static, "static_poses": poses, "dynamic": dynamic, "registration": reg},
        "dynamic",
    )
    h["part_masks_report"] = ex.submit(
        "part_masks_report", config.part_masks, {"dynamic": dynamic, "masks": masks, "registration": reg}, "dynamic"
    )
    if config.pose_drift.model:
        session_drift = h["session_drift"] = ex.submit(
            "session_drift",
            config.pose_drift,
            {"static": static, "dynamic": dynamic, "registration": reg, "masks": masks},
            "dynamic",
        )
        dynamic = h["correct_pose_drift/dynamic"] = ex.submit(
            "correct_pose_drift", config.pose_drift, {"capture": dynamic, "drift": session_drift}, "dynamic"
        )
    # Each frame's pose error, measured on the static background once the parts and the hand are
    # masked: recorded poses jitter by millimetres and the tracks would carry it into the joint.
    frame_poses = h["frame_poses"] = ex.submit(
        "frame_poses", config.frame_poses, {"dynamic": dynamic, "masks": masks}, "dynamic"
    )
    dynamic = h["correct_frame_poses"] = ex.submit(
        "correct_frame_poses", config.frame_poses, {"capture": dynamic, "corrections": frame_poses}, "dynamic"
    )
    # III. tracks and joints
    tracks = h["track"] = ex.submit("track", config.track, {"dynamic": dynamic, "masks": masks, "registration": reg}, "dynamic")
    fitted = h["fit_joints"] = ex.submit("fit_joints", config.fit_joints, {"trajectories": tracks, "masks": masks}, "dynamic")
    # Every candidate part is kept, merged into the part whose motion explains it, or dropped; the
    # stages below see the settled parts only (joint k, mask label k + 1), so they agree on them.
    fitted = h["settle_parts"] = ex.submit(
        "settle_parts",
        config.settle_parts,
        {"joints": fitted, "trajectories": tracks, "masks": masks, "dynamic": dynamic, "registration": reg},
        "dynamic",
    )
    masks = h["final_masks"] = ex.submit("final_masks", config.settle_parts, {"masks": masks, "parts": fitted}, "dynamic")
    joints = h["joint_states"] = ex.submit(
        "joint_states",
        config.joint_states,
        {"joints": fitted, "dynamic": dynamic, "masks": masks, "registration": reg},
        "dynamic",
    )
    # IV. the twin: Gaussians split into background / interior / parts and trained with the parts moved
    twin = h["articulate"] = ex.submit(
        "articulate",
        config.articulate,
        {
            "canonical": gaussians, "static": static, "static_poses": poses, "dynamic": dynamic,
            "registration": reg, "masks": masks, "joints": joints,
        },
        "scene",
    )
    h["articulate_report"] = ex.submit(
        "articulate_report",
        config.articulate,
        {"canonical": gaussians, "twin": twin, "dynamic": dynamic, "registration": reg, "masks": masks, "joints": joints},
        "scene",
    )
    # Model against measurement: the twin's predictions beside what the sensors measured
    dyn_prediction = h["predict_dynamic"] = ex.submit(
        "predict_dynamic",
        config.predict_views,
        {"twin": twin, "dynamic": dynamic, "registration": reg, "masks": masks, "joints": joints},
        "dynamic",
    )
    h["diagnose_dynamic"] = ex.submit(
        "diagnose_dynamic", config.diagnose,
        {"dynamic": dynamic, "prediction": dyn_prediction, "pose_lag": lags["dynamic"]}, "dynamic",
    )
    prediction = h["predict_views"] = ex.submit(
        "predict_views", config.predict_views, {"capture": static, "poses": poses, "checkpoint": gaussians}, "static"
    )
    h["diagnose"] = ex.submit(
        "diagnose",
        config.diagnose,
        {"capture": static, "prediction": prediction, "joints": joints, "trajectories": tracks, "pose_lag": lags["static"]},
        "scene",
    )
    # V. simulator files of the twin
    h["export"] = ex.submit(
        "export",
        config.export,
        {
            "static": static, "static_poses": poses, "dynamic": dynamic, "registration": reg, "masks": masks,
            "joints": joints, "gaussians": twin,
        },
        "scene",
    )
    return h


def collect_runs(ex: Executor, handles: dict[str, Any]) -> tuple[dict[str, StageRun], dict[str, StageFailure]]:
    """Wait for every submitted stage: what completed, and what failed or was skipped."""
    runs, failures = {}, {}
    for name, handle in handles.items():
        result = ex.result(handle)
        (failures if isinstance(result, StageFailure) else runs)[name] = result
    return runs, failures


def finish_scene(
    scene: str | Path, config: PipelineConfig, ex: Any, handles: Any, store: ArtifactStore, started: float,
    out: str | Path | None, exports: bool = True,
) -> dict[str, Any]:
    """Wait for the stages, diagnose the static recording if the run failed before its diagnosis,
    write ``summary.json`` (and with ``exports`` the export files and reports) under ``out``, and
    return the summary; raises ``SceneFailed`` (holding the summary) when a stage failed."""
    runs, failures = collect_runs(ex, handles)
    diagnose_failed_run(config, ex, handles, runs, failures)
    summary = build_summary(scene, store, runs, started, config, failures)
    if out is not None:
        if exports:
            summary["exports"] = write_exports(store, runs, out)
        write_summary(summary, out)
    if summary["status"] == "failed":
        raise SceneFailed(summary)
    return summary


def diagnose_failed_run(
    config: PipelineConfig, ex: Executor, handles: PipelineHandles, runs: dict[str, StageRun], failures: dict[str, StageFailure]
) -> None:
    """When a stage failed and the scene's diagnosis did not run (it needs the joints), diagnose the
    static recording alone (``diagnose_static``) if its prediction exists; adds to ``runs`` or
    ``failures`` in place."""
    if not failures or "diagnose" in runs or "predict_views" not in runs or handles.static_capture is None:
        return
    inputs = {"capture": handles.static_capture, "prediction": handles["predict_views"]}
    if "pose_lag/static" in runs:  # its lag is reported too when it was measured
        inputs["pose_lag"] = handles["pose_lag/static"]
    handle = ex.submit("diagnose_static", config.diagnose, inputs, "static")
    result = ex.result(handle)
    (failures if isinstance(result, StageFailure) else runs)["diagnose_static"] = result


def code_version() -> str:
    """Package version plus the git commit when run from a checkout (informational only)."""
    try:
        version = metadata.version("artitwin")
    except metadata.PackageNotFoundError:  # run from a checkout that is not installed
        version = "0+unknown"
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout.strip()
        return f"{version}+g{sha}" if sha else version
    except (OSError, subprocess.SubprocessError):
        return version


def build_summary(
    scene: str | Path,
    store: ArtifactStore,
    runs: dict[str, StageRun],
    started: float,
    config: PipelineConfig | None = None,
    failures: dict[str, StageFailure] | None = None,
) -> dict[str, Any]:
    """The machine-readable summary of a scene run (documented in docs/summary.md); with
    ``failures``, the failed and skipped stages beside what completed, and ``status: failed``."""
    stages = {}
    for name, run in runs.items():
        entry: dict[str, Any] = asdict(run)
        if run.kind == StageReport.kind:
            report = store.get(run.key, StageReport)
            entry["metrics"] = {k: _finite(v) for k, v in report.metrics.items()}
            entry["notes"] = list(report.notes)
        elif run.kind == Registration.kind:
            reg = store.get(run.key, Registration)
            entry["metrics"] = {"residual_m": reg.residual_m, "inlier_frac": reg.inlier_fraction}
            entry["canonical_from_session"] = reg.canonical_from_session.tolist()
        elif run.kind == DepthCalibrationResult.kind:
            cal = store.get(run.key, DepthCalibrationResult)
            entry["metrics"] = {
                "depth_scale": cal.scale, "depth_offset_m": cal.offset_m, "residual_m": cal.residual_m,
                "depth_error_se_m": _finite(cal.error_se_m), "applied": float(cal.applied),
            }
            entry["notes"] = [cal.note] if cal.note else []
        elif run.kind == PoseDriftResult.kind:
            drift = store.get(run.key, PoseDriftResult)
            entry["metrics"] = {
                "drift_displacement_m": float(np.linalg.norm(drift.displacement_m)), "drift_z_score": _finite(drift.z_score),
                "drift_rate_m_per_s": float(np.linalg.norm(drift.rate_m_per_s)), "residual_m": drift.residual_m,
                "applied": float(drift.applied),
            }
            entry["notes"] = [drift.note] if drift.note else []
        elif run.kind == PoseLagResult.kind:
            lag = store.get(run.key, PoseLagResult)
            entry["metrics"] = {
                "lag_s": lag.lag_s, "lag_frames": lag.lag_frames, "lag_se_s": _finite(lag.lag_se_s),
                "lag_z_score": _finite(lag.z_score), "agreement_z": _finite(lag.agreement_z),
                "residual_before_m": _finite(lag.residual_zero_m), "residual_after_m": _finite(lag.residual_lag_m),
                "frame_interval_s": _finite(lag.frame_interval_s), "estimated": float(lag.estimated),
                "significant": float(lag.significant), "applied": float(lag.applied), "forced": float(lag.forced),
            }
            entry["notes"] = [lag.note] if lag.note else []
        elif run.kind == FramePoseCorrections.kind:
            fp = store.get(run.key, FramePoseCorrections)
            finite = np.isfinite(fp.translation_se_m)
            entry["metrics"] = {
                "chi2_per_dof": _finite(fp.chi2_per_dof), "fast_chi2_per_dof": _finite(fp.fast_chi2_per_dof),
                "whiteness": _finite(fp.whiteness), "depth_agreement": _finite(fp.depth_agreement),
                "pairs_used_count": float(fp.pairs_used),
                "correction_rms_m": float(np.sqrt(np.mean(fp.translation_m[finite] ** 2))) if finite.any() else 0.0,
                "correction_rms_deg": float(np.degrees(np.sqrt(np.mean(fp.rotation_rad[finite] ** 2)))) if finite.any() else 0.0,
                "applied": float(fp.applied), "applied_all": float(fp.applied_part == "all"),
            }
            entry["notes"] = [fp.note] if fp.note else []
        elif run.kind == DiagnosisReport.kind:
            report = store.get(run.key, DiagnosisReport)
            entry["metrics"] = {k: _finite(v) for k, v in report.metrics.items()}
            entry["notes"] = list(report.conclusion)
            entry["effects_enabled"] = list(report.enabled)
        elif run.kind == JointSet.kind:
            js = store.get(run.key, JointSet)
            entry["metrics"] = {"joints_count": float(len(js.joints))}
            if js.fates:
                entry["metrics"] |= {f"{x}_count": float(sum(f.fate == x for f in js.fates)) for x in ("kept", "merged", "dropped")}
            entry["notes"] = list(js.notes) + [fate_line(f) for f in js.fates if f.stage == run.stage and f.fate != "kept"]
            if run.stage == "settle_parts" and not js.joints:
                entry["notes"].append("No moving part found: the twin is the static scene (its diagnosis still runs). "
                                      "Check that a part moved in view of the dynamic recording.")
        elif run.kind == TrajectoriesArtifact.kind:
            traj = store.get(run.key, TrajectoriesArtifact)
            entry["metrics"] = {"tracks_count": float(traj.valid.shape[1])}
            entry["notes"] = list(traj.notes)
        elif run.kind == ExportBundle.kind:
            bundle = store.get(run.key, ExportBundle)
            entry["metrics"] = {k: _finite(v) for k, v in bundle.metrics.items()}
            entry["notes"] = list(bundle.notes)
            entry["files"] = bundle.paths
        stages[name] = entry
    for name, failure in (failures or {}).items():
        stages[name] = {k: v for k, v in asdict(failure).items() if v != "" or k == "error"}
    failed = [name for name, f in (failures or {}).items() if f.status == "failed"]
    # The last joint set submitted is the final one (joint_states refines the settled parts' states).
    joint_runs = [run for run in runs.values() if run.kind == JointSet.kind]
    final_set = store.get(joint_runs[-1].key, JointSet) if joint_runs else None
    parts = [
        {"candidate": f.candidate, "fate": f.fate, "part": f.part, "joint": None if f.part is None else f"joint_{f.part}",
         "into_candidate": f.into, "stage": f.stage, "reason": f.reason}
        for f in (final_set.fates if final_set is not None else [])
    ]
    joints = [
        {
            "name": j.name,
            "type": j.joint_type,
            "axis": j.axis.tolist(),
            "pivot": j.pivot.tolist(),
            "range": j.q_range.tolist(),
            "q": [_finite(float(v)) for v in j.q],
            "pitch": j.pitch,
            "axis_se_rad": j.axis_se_rad,
            "pivot_se_m": j.pivot_se_m,
        }
        for j in (final_set.joints if final_set is not None else [])
    ]
    return {
        "summary_version": SUMMARY_VERSION,
        "status": "failed" if failed else "ok",
        **({"failed_stages": failed, "error": failures[failed[0]].error} if failed else {}),
        "scene": str(Path(scene).resolve()),
        "store": store.url,
        "code_version": code_version(),
        "started_at": started,
        "wall_seconds": time.time() - started,
        "stages": stages,
        "parts": parts,
        "joints": joints,
        "exports": {},
        "effects": config.enabled_effects() if config is not None else [],
        "config": config.model_dump(mode="json") if config is not None else None,
    }


def stage_report_html(report: StageReport) -> str:
    """A stage report with images as one self-contained HTML page (images inlined as PNG)."""
    rows = "".join(f"<tr><td>{escape(k)}</td><td>{v:.6g}</td></tr>" for k, v in sorted(report.metrics.items()))
    notes = "".join(f"<li>{escape(n)}</li>" for n in report.notes)
    figures = []
    for image in report.images:
        buf = io.BytesIO()
        Image.fromarray(np.asarray(image.pixels, dtype=np.uint8)).save(buf, format="PNG")
        data = base64.b64encode(buf.getvalue()).decode("ascii")
        figures.append(
            f'<figure><img src="data:image/png;base64,{data}" alt="{escape(image.caption)}">'
            f"<figcaption>{escape(image.caption)}</figcaption></figure>"
        )
    return (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{escape(report.stage)}</title>"
        "<style>body{font-family:sans-serif;margin:1.5em}figure{display:inline-block;margin:.4em}"
        "img{image-rendering:pixelated;width:384px}td{padding:0 1em 0 0}</style></head><body>"
        f"<h1>{escape(report.stage)}</h1>" + (f"<ul>{notes}</ul>" if notes else "")
        + f"<table>{rows}</table>" + "".join(figures) + "</body></html>"
    )


def write_exports(store: ArtifactStore, runs: dict[str, StageRun], out_dir: str | Path) -> dict[str, str]:
    """Write the export bundle's files under ``out_dir/export``, the diagnosis reports as
    ``out_dir/diagnosis.html`` (static recording and joints) and ``out_dir/diagnosis_dynamic.html``
    (the articulated twin against the dynamic recording), and every stage report with images as
    ``out_dir/<stage>.html`` (the part masks over the frames: ``part_masks_report.html``); return
    ``{path relative to out_dir: written path}``.

    Files are written to a staging folder that replaces ``export/`` in one rename, so an
    interrupted run leaves the previous export whole.
    """
    written: dict[str, str] = {}
    for run in runs.values():
        if run.kind == StageReport.kind:
            report = store.get(run.key, StageReport)
            if report.images:
                written[f"{run.stage}.html"] = str(_write_atomic(Path(out_dir) / f"{run.stage}.html", stage_report_html(report)))
        if run.kind == DiagnosisReport.kind:
            html = store.get(run.key, DiagnosisReport).html
            if html:
                # A failed run's static diagnosis stands in for the scene's: it is the diagnosis.
                name = "diagnosis.html" if run.stage in ("diagnose", "diagnose_static") else f"diagnosis{run.stage[len('diagnose'):]}.html"
                written[name] = str(_write_atomic(Path(out_dir) / name, html))
    runs_export = [r for r in runs.values() if r.kind == ExportBundle.kind]
    if not runs_export:
        return written
    bundle = store.get(runs_export[0].key, ExportBundle)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    final = out / "export"
    staging = out / f".export.{os.getpid()}.tmp"
    old = out / f".export.{os.getpid()}.old"
    for leftover in (staging, old):
        if leftover.exists():
            shutil.rmtree(leftover)
    bundle.write_files(staging)
    if final.exists():
        os.replace(final, old)
    os.replace(staging, final)
    if old.exists():
        shutil.rmtree(old)
    return written | {f"export/{p}": str(final / p) for p in bundle.paths}


def _write_atomic(target: Path, text: str) -> Path:
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, target)
    return target


def fate_line(fate: Any) -> str:
    """One candidate part's fate in words (summary notes, the CLI)."""
    if fate.stage == "fit_joints":  # settle_parts decides its fate from here
        return f"candidate part {fate.candidate}: no joint of its own: {fate.reason}"
    where = {"kept": f"kept as part {fate.part}", "dropped": "dropped"}.get(
        fate.fate, f"merged into candidate {fate.into}" + ("" if fate.part is None else f" (part {fate.part})")
    )
    return f"candidate part {fate.candidate}: {where}" + (f": {fate.reason}" if fate.reason else "")


def write_summary(summary: dict[str, Any], out_dir: str | Path) -> Path:
    """Write ``out_dir/summary.json`` atomically (a reader never sees half a file)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / f".summary.json.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(summary, indent=2, allow_nan=False))
    os.replace(tmp, out / "summary.json")
    return out / "summary.json"


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None
