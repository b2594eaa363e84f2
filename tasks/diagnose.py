"""Stages: predict what the sensors should have measured, and diagnose the twin against it.

``predict_views`` renders the canonical Gaussians at every frame of the static recording (RGB at
the RGB size, depth at the depth size). ``diagnose`` compares a prediction with the capture, and
each fitted joint with its part's 3D tracks, ranks the physical-effect plugins by the residual
they explain, and returns the ranking, the energies before and after, per-frame error curves and
an HTML report. Either half may be empty: an empty ``JointSet`` diagnoses the sensor alone.

``predict_dynamic`` and ``diagnose_dynamic`` do the same for the dynamic recording with the
articulated twin (stage IV): each frame rendered with the parts at the fitted joint states q(t),
at the registered camera poses, hand pixels left out (the twin has no hand). Its frames run from
closed to open, so its per-frame curves say at which joint states the twin fails.
"""

from __future__ import annotations

import io
import math
from dataclasses import replace

import numpy as np
from PIL import Image

from artitwin_core import InputError, progress
from artitwin_core.articulation import TwinRenderer
from artitwin_core.capture import Capture, downscale_rgb
from artitwin_core.diagnostics import DiagnoseConfig as CoreDiagnoseConfig
from artitwin_core.diagnostics import (
    Diagnosis,
    ResidualData,
    discover_effects,
    make_residual_data,
    per_frame_errors,
    registered_effects,
    render_html,
    track_model_from_joint,
)
from artitwin_core.diagnostics import diagnose as run_diagnosis
from artitwin_core.diagnostics._report import residual_maps
from artitwin_core.gaussians import GaussianParams
from artitwin_core.joints import Joint, poses_on_rgb_clock, to_rgb_clock
from artitwin_core.masks import MaskSequence, downscale_masks
from artitwin_core.reconstruction import ModelRenderer
from schemas import (
    CameraPoses,
    CaptureArtifact,
    GaussianCheckpoint,
    JointSet,
    MaskSequenceArtifact,
    PoseLagResult,
    Registration,
    ReportImage,
    TrajectoriesArtifact,
)
from schemas._diagnose import (
    DYNAMIC_SCOPE,
    STATIC_SCOPE,
    DiagnoseConfig,
    DiagnosisReport,
    EffectFinding,
    PredictViewsConfig,
    ViewPrediction,
)
from tasks._consistency import (
    defer_joint_effects,
    self_consistency,
    self_consistency_metrics,
    with_own_vignetting,
)
from tasks._convert import config_map, core_kwargs, json_safe, to_core, to_core_config
from tasks._stage import stage
from tasks.reconstruct import sensor_model

config_map(
    PredictViewsConfig,
    {ModelRenderer: "backend", downscale_rgb: "max_side"},
    stage_only={
        "min_alpha": "the stage leaves pixels rendered fainter than this out of the prediction",
        "max_frames": "which frames the stage predicts (prediction_frames)",
        "run_frames": "which frames the stage predicts (prediction_frames)",
    },
)
config_map(
    DiagnoseConfig,
    {
        CoreDiagnoseConfig: "min_explained min_gain_over_floor structure_ratio max_rounds heldout_every "
        "min_gain_over_null min_world_fixed",
        make_residual_data: {
            "depth_sigma_a_m": "depth_sigma[0]", "depth_sigma_b_per_m": "depth_sigma[1]",
            "min_confidence": "min_confidence", "track_noise_m": "track_noise_m",
        },
    },
    stage_only={
        "effects": "which registered effects the stage tests (the effect registry, not a config)",
        "effect_modules": "user effect plugins the stage loads (discover_effects)",
        "min_tracks_count": "the stage leaves joints with fewer tracks undiagnosed",
        "self_consistency": "whether the stage also tests the static recording against itself",
        "min_depth_error_m": "the self-consistency test's gate on the depth error, applied by the stage",
        "min_vignetting_falloff": "the vignetting self-consistency test's gate, applied by the stage",
        "max_lag_interpolation_s": "the self-consistency test's depth gate after a lag correction, applied by the stage",
        "self_consistency_min_depth_pixels": "the stage skips the self-consistency test on coarser depth maps",
    },
)



# 4: the prediction says which vignetting it applied.
@stage(name="predict_views", version=4, config=PredictViewsConfig, output=ViewPrediction)
def predict_views(
    capture: CaptureArtifact, poses: CameraPoses, checkpoint: GaussianCheckpoint, config: PredictViewsConfig
) -> ViewPrediction:
    """Render the Gaussians at the capture's recorded poses: RGB at RGB size, depth at depth size,
    through the sensor model learned with them (exposure, vignetting, depth error) when there is one.

    The cameras are at ``poses``, the poses the Gaussians were trained with (the refined ones): the
    prediction is the twin's, camera poses included, so a pose error the refinement left shows up
    in the residual (pose drift) and one it removed does not.
    """
    if poses.world_from_camera.shape[0] != capture.rgb.shape[0] or not np.array_equal(poses.frame_ids, capture.frame_ids):
        raise InputError(
            f"predict_views: {poses.world_from_camera.shape[0]} poses for a capture of {capture.rgb.shape[0]} frames "
            "(or other frame ids); give the poses refined from this capture."
        )
    params = to_core(GaussianParams, checkpoint)
    sensor = sensor_model(checkpoint)  # the camera effects the twin models, learned with it
    frames = prediction_frames(capture.rgb.shape[0], config)
    cap = _predicted_grid(to_core(Capture, capture), frames, config)
    w, h = cap.rgb_size
    _, dh, dw = capture.depth.shape
    rgb, depth, cover = [], [], []
    renderer = ModelRenderer(params, backend=config.backend)  # the model goes to the device once
    for i in _counted("rendering the static frames", len(frames)):
        t, pose = frames[i], poses.world_from_camera[frames[i]]
        colour, _, alpha = renderer.render(pose, cap.rgb_intrinsics[i], w, h)
        _, z, alpha_d = renderer.render(pose, capture.depth_intrinsics[t], dw, dh)
        if sensor is not None:
            colour, z = sensor.apply_rgb(colour, t, cap.rgb_intrinsics[i]), sensor.apply_depth(z)
        rgb.append(np.round(np.clip(colour, 0, 1) * 255).astype(np.uint8))
        depth.append(np.where(alpha_d >= config.min_alpha, z, np.nan).astype(np.float32))
        cover.append(alpha >= config.min_alpha)
    return ViewPrediction(rgb=np.stack(rgb), depth=np.stack(depth), coverage=np.stack(cover),
                          frame_ids=capture.frame_ids[frames].copy(),
                          world_from_camera=np.asarray(poses.world_from_camera, np.float64)[frames],
                          vignetting=_vignetting_of(sensor))


# 4: the dynamic recording's camera, when stage IV modelled it, is applied.
# 5: the prediction says which vignetting it applied.
@stage(name="predict_dynamic", version=7, config=PredictViewsConfig, output=ViewPrediction)
def predict_dynamic(
    twin: GaussianCheckpoint,
    dynamic: CaptureArtifact,
    registration: Registration,
    masks: MaskSequenceArtifact,
    joints: JointSet,
    config: PredictViewsConfig,
) -> ViewPrediction:
    """Render the articulated twin at every dynamic frame: parts moved to the fitted q(t), cameras
    at the dynamic poses mapped into the canonical frame by the registration.

    Coverage leaves out the pipeline's hand pixels, and the depth prediction is NaN under them,
    so the hand (which the twin does not model) is not counted as the twin's error. The poses
    recorded are the canonical ones the depth was rendered at.

    Where the joint set's states are on the RGB clock (the effect time_offset: depth maps and
    poses recorded ``joints.rgb_time_offset_s`` after the RGB), each frame's RGB is rendered at
    its exposure (the pose interpolated back, ``poses_on_rgb_clock``, and the states as they
    are) and its depth where the depth map was taken (the recorded pose, the states moved back
    with ``to_rgb_clock``).

    When stage IV modelled the dynamic recording's own camera (``ArticulateConfig.sensor_effects``,
    stored with the twin), each frame's RGB goes through it: the per-frame gains where fitted,
    interpolated in time on the frames stage IV held out.
    """
    t_frames = dynamic.rgb.shape[0]
    if masks.hand.shape[0] != t_frames or any(len(j.q) != t_frames for j in joints.joints):
        raise InputError(
            f"predict_dynamic: the masks ({masks.hand.shape[0]} frames) and joint states "
            f"({[len(j.q) for j in joints.joints]} frames) must cover the dynamic recording's {t_frames} frames; "
            "give the part_masks and fit_joints results of this recording."
        )
    params = to_core(GaussianParams, twin)
    js = [to_core(Joint, j) for j in joints.joints]
    core = to_core(Capture, dynamic)
    poses = registration.canonical_from_session @ np.asarray(dynamic.world_from_camera, np.float64)
    rgb_poses, js_depth = poses, js
    lag = joints.rgb_time_offset_s
    if lag != 0.0 and joints.timestamps is not None:
        rgb_poses = poses_on_rgb_clock(poses, joints.timestamps, lag, core.stream_track())
        js_depth = [_on_depth_clock(joints, k, j) for k, j in enumerate(js)]
    frames = prediction_frames(t_frames, config)
    cap = _predicted_grid(core, frames, config)
    _, hr, wr, _ = dynamic.rgb.shape
    w, h = cap.rgb_size
    _, dh, dw = dynamic.depth.shape
    rgb, depth, cover = [], [], []
    hands = None  # the hand at a lower prediction resolution: a pixel is the hand's if any pixel it covers is
    if (w, h) != (wr, hr):
        sel = np.asarray(masks.hand, bool)[frames]
        no_part = np.broadcast_to(np.zeros((1, 1, 1), np.uint8), sel.shape)
        hands = downscale_masks(MaskSequence(no_part, sel, np.ones(len(frames), np.float32)), (w, h)).hand
    camera = sensor_model(twin)  # the dynamic recording's camera, when stage IV modelled it
    twin = TwinRenderer(params, js, backend=config.backend)  # the twin goes to the device once
    twin_depth = twin if js_depth is js else TwinRenderer(params, js_depth, backend=config.backend)
    for i in _counted("rendering the dynamic frames", len(frames)):
        t = frames[i]
        q = [float(j.q[t]) for j in js]
        q_d = [float(j.q[t]) for j in js_depth]
        colour, _, alpha = twin.render(q, rgb_poses[t], cap.rgb_intrinsics[i], w, h)
        if camera is not None:
            colour = camera.apply_rgb(np.clip(colour, 0, 1), t, cap.rgb_intrinsics[i])
        _, z, alpha_d = twin_depth.render(q_d, poses[t], dynamic.depth_intrinsics[t], dw, dh)
        hand_full = np.asarray(masks.hand[t], bool)
        hand = hand_full if hands is None else hands[i]  # at the prediction's RGB size
        # The hand mask on the depth grid: a depth pixel is the hand's if any RGB pixel it spans is.
        yy = np.minimum((np.arange(dh)[:, None] * hr) // dh, hr - 1)
        xx = np.minimum((np.arange(dw)[None, :] * wr) // dw, wr - 1)
        hand_d = np.zeros((dh, dw), bool)
        for oy in range(max(1, hr // dh)):
            for ox in range(max(1, wr // dw)):
                hand_d |= hand_full[np.minimum(yy + oy, hr - 1), np.minimum(xx + ox, wr - 1)]
        rgb.append(np.round(np.clip(colour, 0, 1) * 255).astype(np.uint8))
        depth.append(np.where((alpha_d >= config.min_alpha) & ~hand_d, z, np.nan).astype(np.float32))
        cover.append((alpha >= config.min_alpha) & ~hand)
    return ViewPrediction(rgb=np.stack(rgb), depth=np.stack(depth), coverage=np.stack(cover),
                          frame_ids=np.asarray(dynamic.frame_ids, np.int64)[frames].copy(), world_from_camera=poses[frames],
                          vignetting=_vignetting_of(camera))


def _vignetting_of(camera) -> list[float] | None:
    """The ``(a, b)`` of the vignetting a sensor model applies, None when it models none."""
    v = None if camera is None else camera.vignetting
    return None if v is None else [float(v[0]), float(v[1])]


def prediction_frames(n: int, config: PredictViewsConfig) -> list[int]:
    """Positions of the ``n`` frames predicted: every one, or ``config.max_frames`` of them in runs
    of ``config.run_frames`` consecutive frames spread evenly (first and last runs at the ends)."""
    if config.max_frames is None or n <= config.max_frames:
        return list(range(n))
    run = max(1, min(config.run_frames, config.max_frames))
    runs = max(1, config.max_frames // run)
    starts = np.round(np.linspace(0, n - run, runs)).astype(int)
    return sorted({int(s) + k for s in starts for k in range(run)})


def _predicted_grid(capture: Capture, frames: list[int], config: PredictViewsConfig) -> Capture:
    """The capture's ``frames`` at the RGB size the prediction is rendered at (``config.max_side``)."""
    return downscale_rgb(capture.select_frames(frames), config.max_side)


def _on_depth_clock(joints: JointSet, k: int, joint: Joint) -> Joint:
    """Joint ``k`` of ``joints`` (states on the RGB clock, ``rgb_time_offset_s`` not 0) with its
    states on the depth maps' clock: as ``joint_states`` measured them when the set keeps them
    (``depth_clock_q``), else moved back (``to_rgb_clock`` with the opposite lag)."""
    if joints.depth_clock_q is not None and k < joints.depth_clock_q.shape[0]:
        q = np.asarray(joints.depth_clock_q[k], np.float64)
        return replace(joint, q=q, q_range=np.array([float(np.nanmin(q)), float(np.nanmax(q))]))
    return to_rgb_clock(joint, joints.timestamps, -joints.rgb_time_offset_s)


def _counted(name: str, n: int):
    """``range(n)``, reported as progress (``artitwin_core.progress``)."""
    with progress(name, total=n) as report:
        for t in range(n):
            yield t
            report.advance()


def _sensor_data(capture: CaptureArtifact, prediction: ViewPrediction, config: DiagnoseConfig) -> ResidualData:
    capture = _as_predicted(capture, prediction)
    if prediction.rgb.shape != capture.rgb.shape:
        raise InputError(
            f"diagnose: the prediction's RGB is {prediction.rgb.shape}, the capture's {capture.rgb.shape}; "
            "predict every frame of the same capture (predict_views)."
        )
    if prediction.depth.shape != capture.depth.shape:
        raise InputError(
            f"diagnose: the prediction's depth is {prediction.depth.shape}, the capture's {capture.depth.shape}; "
            "render the depth with the capture's depth intrinsics and size."
        )
    if not np.array_equal(prediction.frame_ids, capture.frame_ids):
        raise InputError("diagnose: the prediction's frame_ids differ from the capture's; predict this capture's frames.")
    return make_residual_data(
        rgb_pred=prediction.rgb, rgb_meas=capture.rgb, rgb_intrinsics=capture.rgb_intrinsics,
        rgb_mask=prediction.coverage, depth_pred=prediction.depth, depth_meas=capture.depth,
        depth_confidence=capture.confidence, timestamps=capture.timestamps,
        depth_intrinsics=capture.depth_intrinsics,
        world_from_camera=capture.world_from_camera if prediction.world_from_camera is None else prediction.world_from_camera,
        pose_track=capture.stream_track(), **core_kwargs(make_residual_data, config),
    )


def _as_predicted(capture: CaptureArtifact, prediction: ViewPrediction) -> Capture:
    """The capture's frames that ``prediction`` predicts, at its RGB size (``predict_views`` may
    predict some of the frames, at a lower resolution: ``PredictViewsConfig.max_frames``, ``max_side``)."""
    cap = to_core(Capture, capture)
    pos = predicted_positions(cap.frame_ids, prediction.frame_ids)
    if not np.array_equal(pos, np.arange(cap.num_frames)):
        cap = cap.select_frames(pos)
    h, w = prediction.rgb.shape[1:3]
    if (w, h) != cap.rgb_size:
        small = downscale_rgb(cap, max(w, h))
        if small.rgb_size == (w, h):
            cap = small
    return cap


def predicted_positions(capture_ids: np.ndarray, prediction_ids: np.ndarray) -> np.ndarray:
    """Where in the recording (frame positions) the prediction's frames are, in its order."""
    capture_ids, ids = np.asarray(capture_ids, np.int64), np.asarray(prediction_ids, np.int64)
    if np.array_equal(ids, capture_ids):
        return np.arange(len(ids))
    pos = np.searchsorted(capture_ids, ids)
    n = len(capture_ids)
    if n == 0 or np.any(pos >= n) or not np.array_equal(capture_ids[np.minimum(pos, n - 1)], ids):
        raise InputError("diagnose: the prediction names frames the capture does not have; predict this capture's frames.")
    return pos


def _with_positions(report: DiagnosisReport, scope: str, capture: CaptureArtifact, prediction: ViewPrediction) -> DiagnosisReport:
    """``report`` recording where in the recording of ``scope`` its per-frame curves' frames are:
    a comparison of runs needs it to find the frames a stage held out of training."""
    pos = predicted_positions(capture.frame_ids, prediction.frame_ids)
    return report.model_copy(update={
        "frames": {**report.frames, scope: [int(p) for p in pos]},
        "recording_frames": {**report.recording_frames, scope: int(len(capture.frame_ids))},
    })


def _track_data(joints: JointSet, trajectories: TrajectoriesArtifact, config: DiagnoseConfig) -> list[tuple[str, ResidualData]]:
    """One residual set per joint: its part's tracks against the joint's motion."""
    if not joints.joints:
        return []
    n_frames = trajectories.points_in_world.shape[0]
    part_ids = trajectories.part_ids if trajectories.part_ids is not None else np.zeros(trajectories.valid.shape[1], np.int32)
    # The tracks are the candidate parts'; a settled set says which part each candidate became.
    part_of_track = part_ids if joints.label_map is None else joints.label_map[part_ids + 1].astype(np.int64) - 1
    out = []
    for k, jp in enumerate(joints.joints):
        if jp.q.shape[0] != n_frames:
            raise InputError(
                f"diagnose: joint {jp.name!r} has {jp.q.shape[0]} states but the trajectories have {n_frames} frames; "
                "fit the joints on these trajectories."
            )
        keep = part_of_track == k
        if np.count_nonzero(trajectories.valid[:, keep].any(0)) < config.min_tracks_count or jp.joint_type == "fixed":
            continue
        joint = to_core(Joint, jp)
        if joints.rgb_time_offset_s != 0.0 and joints.timestamps is not None:
            # The tracks were lifted with the depth maps and poses, recorded rgb_time_offset_s
            # after the RGB whose clock the states are on: compare on the tracks' clock.
            joint = _on_depth_clock(joints, k, joint)
        obs, valid = trajectories.points_in_world[:, keep], trajectories.valid[:, keep]
        model = track_model_from_joint(joint, obs, valid)
        out.append((jp.name, make_residual_data(tracks=model, tracks_obs=obs, tracks_valid=valid,
                                                **core_kwargs(make_residual_data, config))))
    return out


def _core_config(config: DiagnoseConfig) -> CoreDiagnoseConfig:
    return to_core_config(CoreDiagnoseConfig, config)


def _effects(config: DiagnoseConfig) -> dict:
    discover_effects(tuple(config.effect_modules))
    pool = registered_effects()
    unknown = sorted(set(config.effects) - set(pool))
    if unknown:
        raise InputError(
            f"DiagnoseConfig.effects names unknown effects {unknown}; registered: {sorted(pool)}. "
            "Load user effects with effect_modules or the ARTITWIN_EFFECTS variable."
        )
    return {n: e for n, e in pool.items() if not config.effects or n in config.effects}


def diagnose_sections(
    capture: CaptureArtifact | None,
    prediction: ViewPrediction | None,
    joints: JointSet | None,
    trajectories: TrajectoriesArtifact | None,
    config: DiagnoseConfig,
) -> list[tuple[str, Diagnosis, ResidualData]]:
    """The diagnoses behind the report: the static recording (when given) and each joint's tracks."""
    effects, core_cfg = _effects(config), _core_config(config)
    data: list[tuple[str, ResidualData]] = []
    if capture is not None and prediction is not None:
        data.append((STATIC_SCOPE, _sensor_data(capture, prediction, config)))
    if joints is not None and trajectories is not None:
        data += _track_data(joints, trajectories, config)
    return [(scope, run_diagnosis(d, effects, core_cfg), d) for scope, d in data]


def report_from_sections(sections: list[tuple[str, Diagnosis, ResidualData]], title: str = "ArtiTwin diagnosis") -> DiagnosisReport:
    """Findings, energies, curves, images and HTML of the diagnoses, as one artifact."""
    findings, enabled, metrics, per_frame, conclusion, images = [], [], {}, {}, [], []
    for scope, dg, data in sections:
        on = [s.name for s in dg.enabled]
        enabled += [f"{scope}/{n}" for n in on]
        for s in dg.ranking:
            findings.append(EffectFinding(
                name=s.name, scope=scope, target=s.target, explained_frac=float(s.explained_fraction),
                energy_before=float(s.energy_before), energy_after=float(s.energy_after),
                significant=s.name in dg.significant, enabled=s.name in on, params=json_safe(s.params),
            ))
        for t in dg.energy_before:
            metrics[f"{scope}/{t}_energy_before"] = float(dg.energy_before[t])
            metrics[f"{scope}/{t}_energy_after"] = float(dg.energy_after[t])
            metrics[f"{scope}/{t}_energy_floor"] = float(dg.floors[t])
        after = dg.residual_after if dg.residual_after is not None else data
        for when, d in (("before", data), ("after", after)):
            for name, curve in per_frame_errors(d).items():
                per_frame[f"{scope}/{name}_{when}"] = [float(v) for v in curve]
        if dg.heldout is not None:
            # Held-out frames: the enabled effects refitted on the other frames (per-frame parts re-estimated).
            h = dg.heldout
            metrics[f"{scope}/heldout_image_frames_count"] = float(len(h.image_frames))
            metrics[f"{scope}/heldout_track_frames_count"] = float(len(h.track_frames))
            for name, v in h.errors_before.items():
                metrics[f"{scope}/heldout_{name}_before"] = float(v)
                metrics[f"{scope}/heldout_{name}_after"] = float(h.errors_after[name])
            for t, v in h.energy_before.items():
                metrics[f"{scope}/heldout_{t}_energy_before"] = float(v)
                metrics[f"{scope}/heldout_{t}_energy_after"] = float(h.energy_after[t])
            for c in (c for c in h.checks if not c.failed):  # a failed refit is in the conclusion
                metrics[f"{scope}/{c.name}/heldout_{c.target}_energy_before"] = float(c.energy_before)
                metrics[f"{scope}/{c.name}/heldout_{c.target}_energy_after"] = float(c.energy_after)
                metrics[f"{scope}/{c.name}/heldout_{c.error}_before"] = float(c.error_before)
                metrics[f"{scope}/{c.name}/heldout_{c.error}_after"] = float(c.error_after)
        conclusion += [f"{scope}: {line}" for line in dg.conclusion]
        for caption, png in residual_maps(data, after, n_frames=1):
            pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
            images.append(ReportImage(pixels=pixels, caption=f"{scope}: {caption}"))
    metrics["enabled_count"] = float(len(enabled))
    metrics["significant_count"] = float(sum(f.significant for f in findings))
    return DiagnosisReport(
        findings=findings, enabled=enabled, metrics=metrics, per_frame=per_frame, conclusion=conclusion,
        no_effect_needed=bool(sections) and all(dg.no_effect_needed for _, dg, _ in sections),
        images=images, html=render_html(sections, title),
    )


def pose_lag_finding(lag: PoseLagResult, scope: str) -> tuple[list[EffectFinding], list[str]]:
    """The recording's pose lag (stage ``pose_lag``) as a finding, and the conclusion's line: how
    late its poses are and whether they were corrected. The finding is significant when the lag
    passed the stage's gate, and enabled (a rerun with ``--effect pose_lag`` is suggested) when it
    is significant but the poses were not corrected (``pose_lag.correct`` off)."""
    if not lag.estimated:
        return [], [f"{scope}: {lag.note}"] if lag.note else []
    frames = f"{lag.lag_frames:+.2f} frames, standard error {lag.lag_se_s / lag.frame_interval_s:.2f}"
    if lag.applied:
        line = (
            f"{scope}: its poses were {1e3 * abs(lag.lag_s):.0f} ms {'late' if lag.lag_s >= 0 else 'early'} against its "
            f"images ({frames}) and were corrected before anything was built on them"
            + (" (forced by the effect pose_lag)." if lag.forced else ".")
        )
    elif lag.significant:
        line = (
            f"{scope}: its poses are {1e3 * abs(lag.lag_s):.0f} ms {'late' if lag.lag_s >= 0 else 'early'} against its "
            f"images ({frames}, {lag.z_score:.0f} standard errors) and were not corrected. Model it: --effect pose_lag."
        )
    else:
        line = f"{scope}: {lag.note}"

    def energy(residual: float) -> float:
        return residual**2 if math.isfinite(residual) else 0.0

    before, after = energy(lag.residual_zero_m), energy(lag.residual_lag_m)
    finding = EffectFinding(
        name="pose_lag", scope=scope, target="self-consistency",
        explained_frac=float(1.0 - after / before) if before > 0 else 0.0,
        energy_before=before, energy_after=after, significant=lag.significant,
        enabled=lag.significant and not lag.applied,
        params=json_safe({
            "seconds": lag.lag_s, "frames": lag.lag_frames, "se_s": lag.lag_se_s, "z_score": lag.z_score,
            "agreement_z": lag.agreement_z, "applied": lag.applied, "forced": lag.forced,
        }),
    )
    return [finding], [line]


def _lag_findings(pose_lag: PoseLagResult | None, scope: str, config: DiagnoseConfig) -> tuple[list[EffectFinding], list[str]]:
    if pose_lag is None or (config.effects and "pose_lag" not in config.effects):
        return [], []
    return pose_lag_finding(pose_lag, scope)


def _with_findings(report: DiagnosisReport, scope: str, findings: list[EffectFinding], lines: list[str]) -> DiagnosisReport:
    """``report`` with findings the twin's residuals did not produce (the recording against
    itself, its pose lag) and their conclusion lines added."""
    enabled = list(report.enabled)
    enabled += [f"{scope}/{f.name}" for f in findings if f.enabled and f"{scope}/{f.name}" not in enabled]
    metrics = dict(report.metrics)
    metrics["enabled_count"] = float(len(enabled))
    metrics["significant_count"] = float(metrics.get("significant_count", 0.0) + sum(f.significant for f in findings))
    return report.model_copy(update={
        "findings": list(report.findings) + findings, "enabled": enabled, "metrics": metrics,
        "conclusion": list(report.conclusion) + lines,
        "no_effect_needed": report.no_effect_needed and not any(f.enabled for f in findings),
    })


# 10: the self-consistency metrics (self_consistency_metrics).
# 11: the recording's own vignetting test; joint effects wait for a depth error to be modelled;
# the self-consistency test leaves out the frames a lag correction could not reach.
# 12: after a lag correction between frames far apart, the depth error is reported, not enabled.
@stage(name="diagnose", version=16, config=DiagnoseConfig, output=DiagnosisReport)
def diagnose_twin(
    capture: CaptureArtifact,
    prediction: ViewPrediction,
    joints: JointSet,
    trajectories: TrajectoriesArtifact,
    config: DiagnoseConfig,
    pose_lag: PoseLagResult | None = None,
) -> DiagnosisReport:
    """Diagnose the twin: the static recording against its predicted views, each joint against
    its tracks, and (``config.self_consistency``) the static recording against itself; with the
    static recording's ``pose_lag``, how late its poses were and whether they were corrected."""
    report = report_from_sections(diagnose_sections(capture, prediction, joints, trajectories, config))
    findings, lines = [], []
    if config.self_consistency:
        findings, lines = self_consistency(capture, config, pose_lag)
        if config.effects:  # restricted to named effects
            findings = [f for f in findings if f.name in config.effects]
            lines = [line for line in lines if any(f"--effect {f.name}" in line for f in findings)]
    report, vig_findings, vig_lines = with_own_vignetting(report, STATIC_SCOPE, capture, prediction, config)
    report, deferred = defer_joint_effects(report, findings)
    lag_findings, lag_lines = _lag_findings(pose_lag, STATIC_SCOPE, config)
    report = _with_positions(report, STATIC_SCOPE, capture, prediction)
    findings += vig_findings
    report = report.model_copy(update={"metrics": {**report.metrics, **self_consistency_metrics(findings)}})
    return _with_findings(report, STATIC_SCOPE, findings + lag_findings, lines + vig_lines + lag_lines + deferred)


# 4: the self-consistency metrics, as diagnose.
# 5: the recording's own vignetting test, as diagnose.
# 6: as diagnose 12.
@stage(name="diagnose_static", version=8, config=DiagnoseConfig, output=DiagnosisReport)
def diagnose_static(
    capture: CaptureArtifact, prediction: ViewPrediction, config: DiagnoseConfig, pose_lag: PoseLagResult | None = None
) -> DiagnosisReport:
    """``diagnose`` with no joints: the static recording against its predicted views (and itself,
    and its pose lag). A scene run whose joints could not be fitted (a stage failed) still gets
    this, because a failing scene is when a user most needs to know why."""
    empty = TrajectoriesArtifact(
        points_in_world=np.zeros((0, 0, 3)), pixels=np.zeros((0, 0, 2), np.float32), valid=np.zeros((0, 0), bool)
    )
    return diagnose_twin.fn(capture, prediction, JointSet(joints=[]), empty, config, pose_lag)


# 5: the recording's own vignetting test.
@stage(name="diagnose_dynamic", version=8, config=DiagnoseConfig, output=DiagnosisReport)
def diagnose_dynamic(
    dynamic: CaptureArtifact, prediction: ViewPrediction, config: DiagnoseConfig, pose_lag: PoseLagResult | None = None
) -> DiagnosisReport:
    """Diagnose the articulated twin against the dynamic recording (``predict_dynamic``); with
    the dynamic recording's ``pose_lag``, how late its poses were and whether they were corrected."""
    data = _sensor_data(dynamic, prediction, config)
    section = (DYNAMIC_SCOPE, run_diagnosis(data, _effects(config), _core_config(config)), data)
    report = report_from_sections([section], title="ArtiTwin diagnosis: the dynamic recording")
    report, vig_findings, vig_lines = with_own_vignetting(report, DYNAMIC_SCOPE, dynamic, prediction, config)
    report = _with_positions(report, DYNAMIC_SCOPE, dynamic, prediction)
    report = report.model_copy(update={"metrics": {**report.metrics, **self_consistency_metrics(vig_findings)}})
    lag_findings, lag_lines = _lag_findings(pose_lag, DYNAMIC_SCOPE, config)
    return _with_findings(report, DYNAMIC_SCOPE, vig_findings + lag_findings, vig_lines + lag_lines)
