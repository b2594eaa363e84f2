"""The effect plugin contract, the registry, and discovery of effects written outside the package.

An effect is a physical cause of residual the twin does not model yet (an exposure change, a
depth bias, a screw joint...). It has a name, the residual it targets, a cheap ``fit`` on the
residuals (closed form or a small least-squares problem: never a refit of the twin) and an
``apply`` that adds its parameters to the forward model (or corrects the measurement). Its
signature, how much of its target it explains, is measured by applying it: ``1 - energy(after) /
energy(before)``, the same yardstick for every effect, built in or not.

User effects are found through the ``artitwin.effects`` entry-point group and the
``ARTITWIN_EFFECTS`` environment variable (``module:attr[,module:attr...]``, where ``attr`` is an
``Effect`` subclass, an instance, or a list of either).

An effect whose parameters are per frame (an exposure gain) also overrides ``transfer``: the
held-out check fits on training frames and needs that part re-estimated on frames it never saw.
"""

from __future__ import annotations

import importlib
import os
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from importlib import metadata

import numpy as np

from artitwin_core._errors import InputError
from artitwin_core.diagnostics._residuals import TARGETS, ResidualData, target_energy

ENTRY_POINT_GROUP = "artitwin.effects"
ENV_VAR = "ARTITWIN_EFFECTS"


@dataclass(frozen=True)
class Evidence:
    """The plot that shows an effect: ``y`` against ``x``, with the effect's prediction ``model``.

    Attributes:
        title: one line, e.g. "measured/predicted intensity vs image radius".
        x_label, y_label: axis names with units.
        x: ``[K]`` abscissae.
        y: ``[K]`` or ``[C, K]`` measured values (one row per series).
        model: same shape as ``y``: what the fitted effect predicts (NaN where it has no say).
        series: names of the rows of ``y`` (empty for one series).
    """

    title: str
    x_label: str
    y_label: str
    x: list
    y: list
    model: list
    series: tuple[str, ...] = ()


@dataclass(frozen=True)
class Signature:
    """What one effect would do to the residual, without being enabled.

    Attributes:
        name: the effect's name.
        target: the residual it targets (one of ``TARGETS``).
        explained_fraction: ``1 - energy_after / energy_before`` on the target (can be < 0).
        energy_before, energy_after: ``target_energy`` before and after applying it.
        params: fitted parameter values (JSON-friendly: floats and lists).
        evidence: the plot that shows it.
    """

    name: str
    target: str
    explained_fraction: float
    energy_before: float
    energy_after: float
    params: dict = field(default_factory=dict)
    evidence: Evidence | None = None


class Effect(ABC):
    """Base class of every effect plugin.

    Subclasses set ``name``, ``target`` (one of ``TARGETS``: photometric, depth, depth-noise,
    joint-tracks) and ``description``, and implement ``applies``, ``fit`` and ``apply``.
    ``signature`` (fit, apply, measure) is shared and rarely needs overriding.
    """

    name: str = ""
    target: str = ""
    description: str = ""
    # ``ResidualData`` fields whose change cannot change this effect's signature (it never reads
    # them). When the effect enabled in one round of the diagnosis changed only such fields, the
    # next round keeps this effect's signature instead of fitting it again. Empty (the default, and
    # right for any plugin that does not say): every change refits.
    unaffected_by: frozenset[str] = frozenset()

    @abstractmethod
    def applies(self, data: ResidualData) -> bool:
        """True when ``data`` holds what this effect needs (e.g. RGB, tracks of a revolute joint)."""

    @abstractmethod
    def fit(self, data: ResidualData) -> tuple[dict, Evidence | None]:
        """Estimate the effect's parameters from the residuals in ``data``; also the evidence plot."""

    @abstractmethod
    def apply(self, data: ResidualData, params: dict) -> ResidualData:
        """A copy of ``data`` with the effect added to the prediction (or removed from the measurement)."""

    def apply_to_target(self, data: ResidualData, params: dict) -> ResidualData:
        """``apply`` as far as the effect's ``target`` residual sees it (``signature`` measures
        only that): an effect whose ``apply`` also changes other parts of the data at a cost (a
        pose drift moves the RGB prediction too) may skip them here. The default is ``apply``."""
        return self.apply(data, params)

    def transfer(self, params: dict, train: ResidualData, heldout: ResidualData) -> dict:
        """Parameters for frames the fit never saw (the held-out check, ``evaluate_heldout``).

        ``params`` were fitted on ``train``; ``heldout`` is the same data with only the held-out
        frames valid. A global effect (the default) keeps ``params``. An effect with per-frame
        parameters re-estimates those on the held-out frames with its global part fixed, and
        returns parameters ``apply`` can use on every frame.
        """
        return params

    def null_columns(self, geometry) -> np.ndarray | None:
        """For a depth effect the twin's own world-fixed geometry error can mimic (a pose drift, a
        depth bias): ``[n, k]`` its linearised change of the point-to-plane residual per parameter
        at the pixels of ``geometry`` (``_patch.PatchGeometry``). The diagnosis then enables
        it only when it beats that null (``surface_null_check``). None (default): no such check."""
        return None

    def signature(self, data: ResidualData) -> Signature:
        """Fit, apply, and measure how much of the targeted residual the effect explains."""
        params, evidence = self.fit(data)
        before = target_energy(data, self.target)
        after = target_energy(self.apply_to_target(data, params), self.target)
        # NaN when the target cannot be measured on this data (too few depth pixels, no tracks...).
        frac = (1.0 - after / before if before > 0 else 0.0) if np.isfinite(before) else float("nan")
        return Signature(self.name, self.target, float(frac), before, after, params, evidence)


_REGISTRY: dict[str, Effect] = {}


def _check(effect: Effect) -> Effect:
    if not isinstance(effect, Effect):
        raise InputError(f"{effect!r} is not an artitwin_core.diagnostics.Effect; subclass Effect.")
    if not effect.name or not isinstance(effect.name, str):
        raise InputError(f"effect {type(effect).__name__} has no name; set the class attribute `name`.")
    if effect.target not in TARGETS:
        raise InputError(f"effect {effect.name!r} targets {effect.target!r}; use one of {TARGETS}.")
    return effect


def register_effect(effect: Effect | type[Effect], *, replace: bool = False) -> Effect:
    """Add an effect (instance or class, instantiated without arguments) to the registry."""
    if isinstance(effect, type):
        if not issubclass(effect, Effect):
            raise InputError(f"{effect.__name__} is not an artitwin_core.diagnostics.Effect; subclass Effect.")
        try:
            effect = effect()
        except TypeError as exc:
            raise InputError(f"effect class {effect.__name__} cannot be built without arguments ({exc}); "
                             "give its parameters defaults or register an instance.") from exc
    inst = _check(effect)
    if inst.name in _REGISTRY and not replace and type(_REGISTRY[inst.name]) is not type(inst):
        raise InputError(
            f"an effect named {inst.name!r} is already registered ({type(_REGISTRY[inst.name]).__name__}); "
            "pick another name or pass replace=True."
        )
    _REGISTRY[inst.name] = inst
    return inst


def registered_effects() -> dict[str, Effect]:
    """Every registered effect by name (built-ins plus whatever ``discover_effects`` loaded)."""
    return dict(_REGISTRY)


def _load_target(spec: str, source: str) -> list[Effect]:
    module_name, _, attr = spec.strip().partition(":")
    if not module_name or not attr:
        raise InputError(f"{source}: {spec!r} is not 'module:attr'; e.g. ARTITWIN_EFFECTS=my_effects:GlueCreep.")
    try:
        obj = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise InputError(f"{source}: cannot load {spec!r} ({exc}); is the module on PYTHONPATH?") from exc
    items = obj if isinstance(obj, list | tuple) else [obj]
    try:
        return [register_effect(item, replace=True) for item in items]
    except InputError as exc:
        raise InputError(f"{source}: {spec!r}: {exc}") from exc


def discover_effects(extra: tuple[str, ...] = ()) -> list[str]:
    """Load user effects: the ``artitwin.effects`` entry points, ``ARTITWIN_EFFECTS`` and ``extra``.

    Each source names ``module:attr``; ``attr`` is an ``Effect`` subclass, an instance or a list.
    Returns the names loaded. A source that fails to load raises ``InputError`` naming it.
    """
    names: list[str] = []
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        names += [e.name for e in _load_target(ep.value, f"entry point {ep.name!r} in {ENTRY_POINT_GROUP}")]
    for spec in [s for s in os.environ.get(ENV_VAR, "").split(",") if s.strip()]:
        names += [e.name for e in _load_target(spec, f"environment variable {ENV_VAR}")]
    for spec in extra:
        names += [e.name for e in _load_target(spec, "config effect_modules")]
    return names
