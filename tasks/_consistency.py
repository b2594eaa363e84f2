"""The recordings against themselves, without the twin: the diagnosis's self-consistency tests.

A twin trained on a recording absorbs some of its effects (a depth error, a drift, a vignetting),
and its residual then hardly shows them. The recording's own frames do: at the right poses,
depth and camera they agree with each other. ``diagnose`` and ``diagnose_dynamic`` add these
findings to the twin-based ones, and the metrics ``artitwin compare`` leads with when a rerun
models them.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from artitwin_core import InputError
from artitwin_core.capture import (
    Capture,
    DriftSignificance,
    beyond_recorded,
    estimate_depth_calibration,
    estimate_vignetting,
)
from artitwin_core.capture import DepthCalibrationConfig as CoreCalibrationConfig
from schemas import CaptureArtifact, PoseDriftConfig, PoseLagResult
from schemas._configs import effect_scope
from schemas._diagnose import (
    DYNAMIC_SCOPE,
    SELF_CONSISTENCY_METRICS,
    STATIC_SCOPE,
    DiagnoseConfig,
    DiagnosisReport,
    EffectFinding,
    ViewPrediction,
)
from tasks._convert import core_kwargs, json_safe, to_core

# The self-consistency fits stop once a re-association moves them by less than this: a hundredth
# of the smallest gate they face (min_depth_error_m, the drift's few millimetres).
_SELF_TOL_M = 1e-4


def held_by_lag(timestamps: np.ndarray, pose_lag: PoseLagResult | None,
                track_timestamps: np.ndarray | None = None) -> np.ndarray:
    """``[T]`` the frames whose pose a lag correction could not read off the recorded trajectory
    (``track_timestamps``, the pose stream's, default the frames' own: their time plus the lag
    falls outside it): they keep its end pose, up to a lag's motion off."""
    if pose_lag is None or not pose_lag.applied:
        return np.zeros(np.shape(timestamps), bool)
    return beyond_recorded(timestamps, pose_lag.lag_s, track_timestamps)


def lag_pose_spacing(pose_lag: PoseLagResult | None) -> float:
    """How far apart (s) the recorded poses were that a lag correction read the frames' poses
    between: the pose stream's spacing, or the frames' when the capture had no stream (or the
    result predates the field); 0 when no lag was applied."""
    if pose_lag is None or not pose_lag.applied:
        return 0.0
    return pose_lag.pose_interval_s if math.isfinite(pose_lag.pose_interval_s) else pose_lag.frame_interval_s


def self_consistency(
    capture: CaptureArtifact, config: DiagnoseConfig, pose_lag: PoseLagResult | None = None
) -> tuple[list[EffectFinding], list[str]]:
    """The static recording against itself, without the twin: findings for ``pose_drift`` and
    ``depth_scale_offset`` and the conclusion's lines.

    The twin-based tests cannot always tell a drift or a depth error from the twin's own geometry
    (a short training leaves both in its residual). The recording's frames can: at the right poses
    and depth their depth maps and keypoints agree. ``estimate_depth_calibration`` fits a linear
    drift with the depth error; the drift is enabled when it passes the gate ``static_drift``
    applies (``PoseDriftConfig``'s defaults: size, standard errors, both halves alike). The depth
    error is then refitted at the drift-corrected poses and enabled when its size at the median
    depth is at least ``min_depth_error_m`` and 3 standard errors, with a standard error of at
    most 1 cm (the depth_calibration stage's own limit). A finding is significant when it is
    enabled (the gate is its significance test). A recording whose effects are already modelled
    (the corrected capture) finds neither. Depth maps of fewer than
    ``config.self_consistency_min_depth_pixels`` pixels are not tested (a note says so).

    With ``pose_lag`` applied, the frames at the recording's end whose corrected time the
    recorded trajectory does not reach are left out: they keep its end pose, and at phone frame
    rates their few centimetres of pose error faked a depth error past the gate
    (``bench/bench_lag_interpolation.py``). With frames more than
    ``config.max_lag_interpolation_s`` apart and no pose stream between them (the poses of
    the frames not read, ``Capture.pose_track``), the corrected poses are interpolated far
    between recorded ones, which fakes a depth error too: the depth finding is then reported
    (significant) but not enabled, and the line says why.
    """
    _, dh, dw = capture.depth.shape
    if dh * dw < config.self_consistency_min_depth_pixels:
        return [], [
            f"{STATIC_SCOPE}: its self-consistency (pose drift, depth error) was not tested: its depth maps are {dw}x{dh}, "
            f"fewer than {config.self_consistency_min_depth_pixels} pixels, on which the test cannot be trusted."
        ]
    cap = to_core(Capture, capture)
    held = held_by_lag(cap.timestamps, pose_lag, cap.pose_track()[0])
    if held.any():
        cap = cap.select_frames(np.nonzero(~held)[0])
    gate = core_kwargs(DriftSignificance.why_not, PoseDriftConfig())
    try:
        joint = estimate_depth_calibration(cap, config=CoreCalibrationConfig(pose_drift=True, step_tolerance_m=_SELF_TOL_M),
                                           halves_gate=(gate["min_displacement_m"], gate["min_z"]))
    except InputError as e:
        return [], [f"{STATIC_SCOPE}: its frames' self-consistency could not be tested ({e})"]
    sig = joint.drift_significance
    why = sig.why_not(**gate)
    poses = joint.drift.apply(cap.world_from_camera, cap.timestamps) if not why else cap.world_from_camera
    depth_only = CoreCalibrationConfig(step_tolerance_m=_SELF_TOL_M)
    plain_recorded = estimate_depth_calibration(cap, config=depth_only)
    depth = estimate_depth_calibration(cap, world_from_camera=poses, config=depth_only) if not why else plain_recorded
    z_ref = depth.reference_depth_m
    error = (depth.scale - 1.0) * z_ref + depth.offset_m
    depth_seen = (
        abs(error) >= config.min_depth_error_m and abs(error) >= 3.0 * depth.error_se_m and depth.error_se_m <= 0.01
    )
    # Poses a lag correction read between recorded poses far apart carry the interpolation's error,
    # which fakes a depth error of this size (bench_lag_interpolation: -15 mm at 1.8 m, frames
    # 0.27 s apart and no pose stream between them).
    spacing = lag_pose_spacing(pose_lag)
    interpolated = bool(spacing > config.max_lag_interpolation_s)
    depth_on = depth_seen and not interpolated

    def explained(before: float, after: float) -> float:
        return float(1.0 - (after / before) ** 2) if before > 0 else 0.0

    findings = [
        EffectFinding(
            name="pose_drift", scope=STATIC_SCOPE, target="self-consistency",
            explained_frac=explained(plain_recorded.residual_m, joint.residual_m),
            energy_before=plain_recorded.residual_m**2, energy_after=joint.residual_m**2,
            significant=not why, enabled=not why,
            params=json_safe({
                "displacement_m": sig.displacement_m.tolist(), "displacement_se_m": sig.displacement_se_m.tolist(),
                "z_score": sig.z_score, "rate_m_per_s": sig.rate_m_per_s.tolist(),
                "half_disagreement": sig.half_disagreement,
                "rot_rate_rad_per_s": joint.drift.rot_rate_rad_per_s.tolist(),
                "trans_rate_m_per_s": joint.drift.trans_rate_m_per_s.tolist(),
            }),
        ),
        EffectFinding(
            name="depth_scale_offset", scope=STATIC_SCOPE, target="self-consistency",
            explained_frac=explained(depth.initial_residual_m, depth.residual_m),
            energy_before=depth.initial_residual_m**2, energy_after=depth.residual_m**2,
            significant=bool(depth_seen), enabled=bool(depth_on),
            params=json_safe({
                "scale": depth.scale, "offset_m": depth.offset_m, "error_m": error, "error_se_m": depth.error_se_m,
                "reference_depth_m": z_ref,
            }),
        ),
    ]
    lines = []
    if not why:
        lines.append(
            f"{STATIC_SCOPE}: its own frames agree only under a linear pose drift: {1e3 * sig.size_m:.0f} mm by the "
            f"last frame at {z_ref:.1f} m ahead of the first camera ({sig.z_score:.0f} standard errors, both halves of "
            "the recording alike). Model it: --effect pose_drift."
        )
    if depth_seen:
        seen = (
            f"{STATIC_SCOPE}: its own frames agree only with its depth corrected: measured = {depth.scale:.4f} z "
            f"{1e3 * depth.offset_m:+.1f} mm, {1e3 * error:+.1f} mm at {z_ref:.1f} m (standard error "
            f"{1e3 * depth.error_se_m:.1f} mm)."
        )
        lines.append(
            f"{seen} Model it: --effect depth_scale_offset." if depth_on else
            f"{seen} Not enabled: its poses were corrected for a lag by reading them between recorded poses "
            f"{spacing:.2f} s apart (the recording holds no pose stream between its frames), and that interpolation "
            "fakes a depth error of this size. A recording whose frames are kept closer together (a higher ingest "
            "max_frames), or an export that keeps the poses of the frames it drops, can tell; --effect "
            "depth_scale_offset models it anyway."
        )
    return findings, lines


def vignetting_consistency(
    capture: CaptureArtifact, scope: str, config: DiagnoseConfig, modelled: list[float] | None = None
) -> tuple[list[EffectFinding], list[str]]:
    """The recording's vignetting from its own frames, without the twin (``estimate_vignetting``):
    a finding for ``vignetting`` in ``scope`` and the conclusion's lines.

    A twin trained on vignetted frames takes the darker corners into its view-dependent colour, so
    its residual against those frames hardly shows them, while the other recording's residual
    shows their inverse, where the twin now predicts corners too dark: the twin-based test blames
    the wrong recording. The recording's frames, compared with each other at their poses, say
    which camera it is. ``modelled``: the twin's model of this camera's vignetting (``(a, b)``,
    the prediction's); the test then measures what that model left. Enabled (and significant)
    when the corner fall-off left is at least ``config.min_vignetting_falloff`` and 3 standard
    errors."""
    try:
        est = estimate_vignetting(to_core(Capture, capture), modelled=None if modelled is None else (modelled[0], modelled[1]))
    except InputError as e:
        return [], [f"{scope}: its vignetting could not be tested against its own frames ({e})"]
    on = bool(abs(est.falloff) >= config.min_vignetting_falloff and abs(est.falloff) >= 3.0 * est.falloff_se)
    finding = EffectFinding(
        name="vignetting", scope=scope, target="self-consistency",
        explained_frac=float(1.0 - (est.residual / est.initial_residual) ** 2) if est.initial_residual > 0 else 0.0,
        energy_before=est.initial_residual**2, energy_after=est.residual**2, significant=on, enabled=on,
        params=json_safe({
            "corner_falloff": est.falloff, "corner_falloff_se": est.falloff_se, "gain_r2": est.gain[0],
            "gain_r4": est.gain[1], "points": est.points, "modelled": modelled,
        }),
    )
    lines = []
    if on:
        left = " beyond what the twin's model of this camera holds" if modelled is not None else ""
        lines.append(
            f"{scope}: its own frames agree only under vignetting{left}: the corners {100 * est.falloff:.0f} % "
            f"{'darker' if est.falloff > 0 else 'brighter'} than the centre (standard error {100 * est.falloff_se:.1f} %). "
            f"Model it: --effect {effect_scope(scope)}:vignetting."
        )
    return [finding], lines


def overrule_twin_vignetting(report: DiagnosisReport, scope: str, own: list[EffectFinding]) -> tuple[DiagnosisReport, list[str]]:
    """``report`` with its twin-based ``vignetting`` finding in ``scope`` no longer enabled when
    the recording's own frames (``own``, :func:`vignetting_consistency`) found none: the radial
    pattern in the twin's residual is then the twin's, carried over from the other recording's
    vignetting, and modelling this camera's would put a vignette where there is none. With the
    conclusion's line that says so."""
    mine = next((f for f in own if f.name == "vignetting"), None)
    entry = f"{scope}/vignetting"
    if mine is None or mine.enabled or entry not in report.enabled:
        return report, []
    line = (
        f"{scope}: its residual against the twin has a radial pattern, but its own frames show no vignetting (corner "
        f"fall-off {100 * mine.params['corner_falloff']:.1f} %, standard error {100 * mine.params['corner_falloff_se']:.1f} %): "
        "the twin carries it, from the other recording's camera; vignetting is not enabled here."
    )
    own_target = mine.target
    return _disabled(report, lambda f: f.scope == scope and f.name == "vignetting" and f.target != own_target), [line]


def _disabled(report: DiagnosisReport, which: Callable[[EffectFinding], bool]) -> DiagnosisReport:
    """``report`` with the findings ``which`` picks no longer enabled (still reported), their
    entries out of ``enabled`` and ``enabled_count`` recounted."""
    off = {f"{f.scope}/{f.name}" for f in report.findings if which(f)}
    findings = [f.model_copy(update={"enabled": False}) if which(f) else f for f in report.findings]
    enabled = [e for e in report.enabled if e not in off]
    metrics = {**report.metrics, "enabled_count": float(len(enabled))}
    return report.model_copy(update={"findings": findings, "enabled": enabled, "metrics": metrics})


def defer_joint_effects(report: DiagnosisReport, findings: list[EffectFinding]) -> tuple[DiagnosisReport, list[str]]:
    """``report`` with its joint effects (the joint-tracks target) no longer enabled while the
    static recording's own frames show a depth error (``findings``: ``self_consistency``'s, the
    ``depth_scale_offset`` one enabled), and a line per joint saying why.

    The joints' tracks are lifted from the sensor's depth. With the depth off by a scale and an
    offset, a point on a moving part is misplaced along its camera ray by an amount that changes as
    the part turns toward or away from the camera: a rise or a tilt the joint does not have (a
    depth error in both recordings asked for a screw joint no door had). The depth is modelled
    first; the rerun's diagnosis judges the joints on corrected tracks."""
    depth = next((f for f in findings if f.name == "depth_scale_offset" and f.enabled), None)
    if depth is None:
        return report, []
    def joint_effect(f: EffectFinding) -> bool:
        return f.enabled and f.target == "joint-tracks" and f.scope not in (STATIC_SCOPE, DYNAMIC_SCOPE)

    held = [f for f in report.findings if joint_effect(f)]
    if not held:
        return report, []
    error_mm = 1e3 * float(depth.params["error_m"])
    lines = [
        f"{f.scope}: {f.name} is not enabled yet: the joint's tracks were lifted from depth that the static recording's "
        f"own frames say is {error_mm:+.0f} mm off at {float(depth.params['reference_depth_m']):.1f} m, which bends "
        "tracks as a joint effect would. Model the depth first (--effect depth_scale_offset); the rerun's diagnosis "
        "judges the joint on corrected tracks."
        for f in held
    ]
    return _disabled(report, joint_effect), lines


def with_own_vignetting(
    report: DiagnosisReport, scope: str, capture: CaptureArtifact, prediction: ViewPrediction, config: DiagnoseConfig
) -> tuple[DiagnosisReport, list[EffectFinding], list[str]]:
    """The recording's own vignetting test (``config.self_consistency``, vignetting among the
    effects tested), past the twin's model of its camera; ``report`` with its twin-based
    vignetting overruled where the frames show none; the findings and lines to add."""
    if not config.self_consistency or (config.effects and "vignetting" not in config.effects):
        return report, [], []
    findings, lines = vignetting_consistency(capture, scope, config, prediction.vignetting)
    report, overruled = overrule_twin_vignetting(report, scope, findings)
    return report, findings, lines + overruled


def self_consistency_metrics(findings: list[EffectFinding]) -> dict[str, float]:
    """A recording's disagreement with itself, as metrics ``artitwin compare`` can lead with (under
    the finding's scope): the depth error at the reference depth (``self_consistency_depth_error_m``),
    the linear drift's displacement by the last frame (``self_consistency_drift_m``) and the corner
    fall-off of the vignetting the twin's camera model left (``self_consistency_vignetting_falloff``),
    each with its standard error (``..._se``). These are what ``depth_scale_offset``,
    ``pose_drift`` and ``vignetting`` target: a twin trained on biased depth, drifting poses or
    vignetted frames absorbs them, so its residual against the sensors hardly shows them, while the
    recording's frames, corrected, agree with each other. Found whether or not the effect was
    enabled."""
    out = {}
    for f in findings:
        p = f.params
        if f.name == "depth_scale_offset" and "error_m" in p:
            value, se = abs(float(p["error_m"])), float(p["error_se_m"])
        elif f.name == "vignetting" and f.target == "self-consistency":
            value, se = abs(float(p["corner_falloff"])), float(p["corner_falloff_se"])
        elif f.name == "pose_drift" and "displacement_m" in p:
            value = float(np.linalg.norm(p["displacement_m"]))
            se = value / float(p["z_score"]) if p.get("z_score") else float("nan")
        else:
            continue
        name = f"{f.scope}/{SELF_CONSISTENCY_METRICS[f.name]}"
        out[name], out[name + "_se"] = value, se
    return out
