"""The physical effects a user can enable, declared once: which stage config models each, and how.

The diagnosis (``artitwin_core.diagnostics``) ranks every registered effect; this table says which
of them a stage can also model, so that ``PipelineConfig.with_effects``, ``enabled_effects``, the
rerun command ``artitwin diagnose`` prints, the ``--effect`` help and the docs' tables all read it
(``tests/foundation/test_config_truth.py`` checks the docs and the core's lists against it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, get_args

# Camera effects the 3DGS trainer learns with the Gaussians (artitwin_core.reconstruction's
# SENSOR_EFFECTS, which the test above keeps equal to this).
SensorEffect = Literal["exposure_white_balance", "vignetting", "depth_scale_offset"]


@dataclass(frozen=True)
class ModelledEffect:
    """One effect a stage models once it is enabled.

    Attributes:
        name: the effect's name, as the diagnosis reports it and ``--effect`` takes it.
        stage: the ``PipelineConfig`` field of the stage config that models it.
        field: the field of that config enabling it sets: a list the name is added to, a flag set
            True, or (with ``param``) the value the user gives.
        param: the diagnosis's fitted parameter the user passes as ``NAME=VALUE``; None: by name.
        also: further fields set with it.
    """

    name: str
    stage: str
    field: str
    param: str | None = None
    also: dict[str, Any] = field(default_factory=dict)


MODELLED_EFFECTS: tuple[ModelledEffect, ...] = (
    *(ModelledEffect(name, "reconstruct", "sensor_effects") for name in get_args(SensorEffect)),
    ModelledEffect("screw_joint", "fit_joints", "model_screw"),
    ModelledEffect("pose_drift", "pose_drift", "model"),
    ModelledEffect("pose_lag", "pose_lag", "model", also={"correct": True}),
    ModelledEffect("time_offset", "joint_states", "rgb_time_offset_s", param="seconds"),
)
MODELLED: dict[str, ModelledEffect] = {e.name: e for e in MODELLED_EFFECTS}
