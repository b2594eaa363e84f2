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
        scopes: where this row models it: ``static`` / ``dynamic`` (the recordings) or ``joint``
            (each joint, ``joint_0`` ...). An effect with a model per recording has one row per
            recording (the camera's exposure is learned in stage I for the static recording and in
            stage IV for the dynamic one); the first row's scope is where a bare name goes.
        joint_field: for a ``joint`` row, the list field that takes the joint of a scoped entry
            (``joint_0:screw_joint`` adds ``joint_0``); a bare name sets ``field`` (every joint).
    """

    name: str
    stage: str
    field: str
    param: str | None = None
    also: dict[str, Any] = field(default_factory=dict)
    scopes: tuple[str, ...] = ("static",)
    joint_field: str | None = None


MODELLED_EFFECTS: tuple[ModelledEffect, ...] = (
    *(ModelledEffect(name, "reconstruct", "sensor_effects") for name in get_args(SensorEffect)),
    # The dynamic recording's own camera, fitted in stage IV against the twin (predict_dynamic applies it).
    ModelledEffect("exposure_white_balance", "articulate", "sensor_effects", scopes=("dynamic",)),
    ModelledEffect("vignetting", "articulate", "sensor_effects", scopes=("dynamic",)),
    ModelledEffect("screw_joint", "fit_joints", "model_screw", scopes=("joint",), joint_field="screw_joints"),
    ModelledEffect("pose_drift", "pose_drift", "model", scopes=("static", "dynamic")),
    ModelledEffect("pose_lag", "pose_lag", "model", also={"correct": True}, scopes=("static", "dynamic")),
    ModelledEffect("time_offset", "joint_states", "rgb_time_offset_s", param="seconds", scopes=("dynamic",)),
)
# Each effect's first row: its default scope's stage, and its parameter.
MODELLED: dict[str, ModelledEffect] = {}
for _e in MODELLED_EFFECTS:
    MODELLED.setdefault(_e.name, _e)
# Where each effect can be modelled, in the order of its rows (the first: where a bare name goes).
EFFECT_SCOPES: dict[str, tuple[str, ...]] = {}
for _e in MODELLED_EFFECTS:
    EFFECT_SCOPES[_e.name] = tuple(dict.fromkeys(EFFECT_SCOPES.get(_e.name, ()) + _e.scopes))
DEFAULT_SCOPES: dict[str, str] = {name: scopes[0] for name, scopes in EFFECT_SCOPES.items()}
# Effects with a model per recording: ``enabled_effects`` names them with their scope.
PER_RECORDING_EFFECTS: tuple[str, ...] = tuple(
    name for name in MODELLED if sum(e.name == name for e in MODELLED_EFFECTS) > 1
)


def modelled_in(name: str, scope_kind: str) -> ModelledEffect | None:
    """The row that models ``name`` in ``scope_kind`` (``static``, ``dynamic``, ``joint``); None if none does."""
    return next((e for e in MODELLED_EFFECTS if e.name == name and scope_kind in e.scopes), None)
