"""Model against measurement: the predicted views, the diagnose stage's config and its report.

``ViewPrediction`` is what the twin says the static recording's sensors should have measured (RGB,
depth, coverage), frame for frame. ``DiagnosisReport`` ranks the physical effects by the residual
they explain, with fitted parameters, energies before and after, per-frame error curves and the
self-contained HTML report a user opens.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from schemas._artifacts import ReportImage
from schemas._base import Array, Artifact, StageConfig
from schemas._vocab import BackendName


class PredictViewsConfig(StageConfig):
    """Rendering the canonical Gaussians into every frame of the static recording."""

    backend: BackendName = Field(default="auto", description="Rasterizer backend: auto, cpu or cuda (or reference, the plain torch one).")
    min_alpha: float = Field(
        default=0.5, ge=0, le=1, description="Pixels whose rendered opacity is below this are not compared."
    )
    max_side: int | None = Field(
        default=None, ge=16,
        description="Render the RGB prediction at most this many pixels on the long side (the diagnosis compares it "
        "with the capture downscaled alike); None = the capture's RGB size. Depth stays at the depth size.",
    )
    max_frames: int | None = Field(
        default=None, ge=3,
        description="Predict at most this many frames, in runs of run_frames consecutive frames spread evenly over "
        "the recording (the timing effects read the camera's velocity from neighbouring frames); None = every frame.",
    )
    run_frames: int = Field(default=5, ge=1, description="Length of the runs of consecutive frames max_frames keeps.")


class DiagnoseConfig(StageConfig):
    """Thresholds and plugins of the diagnosis (``artitwin_core.diagnostics.diagnose``)."""

    effects: list[str] = Field(
        default_factory=list,
        description="Names of the effects to test (empty = every registered effect, user plugins included).",
    )
    effect_modules: list[str] = Field(
        default_factory=list,
        description="Extra user effects to load, 'module:attr' each (as the ARTITWIN_EFFECTS variable).",
    )
    min_explained: float = Field(
        default=0.2, ge=0, le=1, description="An effect must explain at least this fraction of its target residual."
    )
    min_gain_over_floor: float = Field(
        default=0.5, ge=0, description="... and lower its target's energy by at least this many noise floors."
    )
    structure_ratio: float = Field(
        default=2.0, gt=0, description="A residual left above this many noise floors is reported as unexplained structure."
    )
    max_rounds: int = Field(default=4, ge=1, description="At most this many effects are enabled, greedily.")
    min_gain_over_null: float = Field(
        default=0.3, ge=0, le=1,
        description="Share of what the twin-geometry null (a static per-surface correction) leaves that pose drift "
        "or a depth bias must remove on held-out frames to be enabled.",
    )
    min_world_fixed: float = Field(
        default=0.5, ge=0, le=1,
        description="Share of the remaining depth structure a static per-surface correction must explain for the "
        "report to call it the twin's own geometry (no effect needed; train the twin longer).",
    )
    depth_sigma_a_m: float = Field(
        default=0.001, gt=0, description="Depth noise the twin assumes, sigma(z) = a + b z^2: a, metres."
    )
    depth_sigma_b_per_m: float = Field(
        default=0.002, ge=0, description="Depth noise the twin assumes, sigma(z) = a + b z^2: b, 1/metres."
    )
    min_confidence: int = Field(
        default=1, ge=0, le=2, description="Depth pixels with ARKit confidence below this are not compared."
    )
    track_noise_m: float = Field(
        default=0.002, gt=0, description="Per-coordinate noise of one 3D track observation, metres (the track floor)."
    )
    min_tracks_count: int = Field(
        default=10, ge=1, description="A joint with fewer valid tracks than this is not diagnosed."
    )
    heldout_every: int = Field(
        default=4, ge=0,
        description="Hold out every n-th frame (images and tracks), refit the enabled effects on the others and "
        "score them on the held-out frames (per-frame parameters such as exposure re-estimated there); 0 = no check.",
    )
    self_consistency: bool = Field(
        default=True,
        description="Also test the recordings against themselves, without the twin: whether the static recording's "
        "frames' depth and keypoints agree only under a linear pose drift (gated as PoseDriftConfig's defaults gate it) "
        "or a depth scale and offset (artitwin_core.capture.estimate_depth_calibration), and whether each recording's "
        "frames agree in colour only under vignetting (artitwin_core.capture.estimate_vignetting).",
    )
    self_consistency_min_depth_pixels: int = Field(
        default=8000, ge=0,
        description="The self-consistency test runs only on depth maps of at least this many pixels: on coarser ones "
        "its standard errors are too small to gate on (64x48 maps: a depth error flagged in 4 of 20 clean recordings, "
        "at up to 6.5 standard errors; 128x96: none of 20). Phone depth maps are 256x192 or larger.",
    )
    max_lag_interpolation_s: float = Field(
        default=0.1, ge=0,
        description="After a pose-lag correction, the self-consistency test reports a depth error but does not enable "
        "depth_scale_offset when the recorded poses it read the frames' poses between (the pose stream's, else the "
        "frames' own) are more than this many seconds apart: poses interpolated that far between recorded ones fake a "
        "depth error (bench/bench_lag_interpolation.py: -15 mm at 1.8 m, frames 0.27 s apart and no stream).",
    )
    min_vignetting_falloff: float = Field(
        default=0.05, ge=0, le=1,
        description="The self-consistency test of each recording enables vignetting when the corner fall-off its own "
        "frames show, past the twin's model of the camera, is at least this share of the light and 3 standard errors.",
    )
    min_depth_error_m: float = Field(
        default=0.005, ge=0,
        description="The self-consistency test enables depth_scale_offset when the depth error at the recording's median "
        "depth is at least this (metres), at least 3 standard errors, and its standard error at most 1 cm.",
    )


class ViewPrediction(Artifact):
    """The twin's prediction of one recording, frame for frame (e.g. the canonical 3DGS rendered at its poses)."""

    kind = "view_prediction"
    schema_version = 1

    rgb: Array("uint8", "T H W 3") = Field(
        description="Predicted sRGB, [T, H, W, 3] uint8, at the capture's RGB size or downscaled to PredictViewsConfig.max_side."
    )
    depth: Array("float32", "T h w") = Field(
        description="Predicted z-depth at the capture's depth size, metres, [T, h, w]; NaN (or 0) where none."
    )
    coverage: Array("bool", "T H W") | None = Field(
        default=None, description="Pixels the prediction covers (e.g. render opacity > 0.5), [T, H, W]; None = all."
    )
    frame_ids: Array("int64", "T") = Field(
        description="Frame numbers of the capture these predictions are for, [T] (all of its frames, or the ones "
        "PredictViewsConfig.max_frames kept)."
    )
    world_from_camera: Array("float64", "T 4 4") | None = Field(
        default=None,
        description="The camera poses the prediction was rendered at (the twin's, e.g. refined), [T, 4, 4]; None = the capture's.",
    )
    vignetting: list[float] | None = Field(
        default=None,
        description="The radial gain 1 + a r^2 + b r^4 the prediction applied, (a, b): the twin's model of the camera's "
        "vignetting (r over the farthest image corner's distance from the principal point); None = none modelled.",
    )


class EffectFinding(Artifact):
    """One effect's signature on the residual: how much of it it explains and with what parameters."""

    kind = "effect_finding"
    schema_version = 1

    name: str = Field(description="The effect's registered name, e.g. 'vignetting'.")
    scope: str = Field(description="What was diagnosed: 'static recording' or a joint name such as 'joint_0'.")
    target: str = Field(description="The residual it targets: photometric, depth, depth-noise or joint-tracks.")
    explained_frac: float = Field(description="1 - energy_after / energy_before on its target (may be < 0).")
    energy_before: float = Field(description="Target energy before the effect (units of the target, see docs/effects.md).")
    energy_after: float = Field(description="Target energy with the fitted effect applied, same units.")
    significant: bool = Field(default=False, description="True when it passed the significance test against the noise floor.")
    enabled: bool = Field(default=False, description="True when the diagnosis selected it (greedy, in rank order).")
    params: dict[str, Any] = Field(
        default_factory=dict, description="Fitted parameter values by name (units in the name: _m, _rad, _per_m...)."
    )


# The diagnosis's scopes of the two recordings (a joint's scope is its name, ``joint_0``).
STATIC_SCOPE = "static recording"
DYNAMIC_SCOPE = "dynamic recording"

# The diagnosis's metrics of a recording's disagreement with itself (under its scope, "static
# recording/" or "dynamic recording/", each with a standard error "..._se"), by the effect whose
# model removes it: a twin trained on biased depth, drifting poses or vignetted frames absorbs
# those, so ``artitwin compare`` leads with these.
SELF_CONSISTENCY_METRICS = {
    "depth_scale_offset": "self_consistency_depth_error_m",
    "pose_drift": "self_consistency_drift_m",
    "vignetting": "self_consistency_vignetting_falloff",
}


class DiagnosisReport(Artifact):
    """Where the twin fails against the measurement and which physical effects it is missing."""

    kind = "diagnosis_report"
    schema_version = 2

    findings: list[EffectFinding] = Field(
        description="Every applicable effect per scope, ranked: significant first, then by explained fraction."
    )
    enabled: list[str] = Field(
        default_factory=list, description="Selected effects in order, 'scope/name' each (e.g. 'joint_0/screw_joint')."
    )
    metrics: dict[str, float] = Field(
        default_factory=dict,
        description="'<scope>/<target>_energy_before|after|floor' energies; held-out frames: "
        "'<scope>/heldout_<error>_before|after' (rgb_mae_linear, depth_mae_m, depth_nll_nats, track_rms_m), "
        "'<scope>/heldout_<target>_energy_before|after', per enabled effect '<scope>/<effect>/heldout_...'; "
        "and counts (*_count).",
    )
    per_frame: dict[str, list[float]] = Field(
        default_factory=dict,
        description="Per-frame error curves '<scope>/<curve>_before|after' (rgb_rms linear, depth_rms_m, track_rms_m).",
    )
    frames: dict[str, list[int]] = Field(
        default_factory=dict,
        description="Per recording scope ('static recording', 'dynamic recording'): the position in that recording of "
        "each entry of its per-frame curves (predict_views may predict some frames only: PredictViewsConfig.max_frames).",
    )
    recording_frames: dict[str, int] = Field(
        default_factory=dict, description="Per recording scope: how many frames the recording has."
    )
    conclusion: list[str] = Field(default_factory=list, description="The verdict in plain language, one line per finding.")
    no_effect_needed: bool = Field(
        default=False, description="True when every residual is at its noise floor and no effect is enabled."
    )
    images: list[ReportImage] = Field(default_factory=list, description="Residual maps of the worst frames, before and after.")
    html: str = Field(default="", description="The self-contained HTML report (inline SVG plots and PNG images).")
