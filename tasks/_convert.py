"""Conversion between core dataclasses and schemas, by field name.

Artifacts mirror the core dataclasses field for field, so one generic converter serves every pair;
a field present on only one side must be given explicitly (``extra``) or has a default.

Stage configs are the settings a user writes; the core dataclasses (and a few core functions'
keyword parameters) are where those settings act. Each stage config declares once, with
:func:`config_map`, which core home every one of its fields sets (by name, or renamed) and why a
field sets none; :func:`to_core_config` builds a core config from it, and
``tests/foundation/test_config_truth.py`` checks that every field has a home with the same default.
A stage field with no declared home is an error at import, not a setting silently ignored.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from schemas import Artifact, StageConfig

A = TypeVar("A", bound=Artifact)
T = TypeVar("T")


def to_artifact(cls: type[A], obj: Any, **extra: Any) -> A:
    """Build artifact ``cls`` from the same-named fields of dataclass ``obj`` (plus ``extra``)."""
    values = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.name in cls.model_fields}
    values.update(extra)
    return cls(**values)


def to_core(cls: type[T], artifact: Artifact, **extra: Any) -> T:
    """Build core dataclass ``cls`` from the same-named fields of ``artifact`` (plus ``extra``)."""
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    values = {n: getattr(artifact, n) for n in names if n in type(artifact).model_fields}
    values.update(extra)
    return cls(**values)


# --- stage configs -> core configs -----------------------------------------------------------------

Home = Any  # a core dataclass (its fields), or a core function (its keyword parameters)


@dataclasses.dataclass(frozen=True)
class ConfigMap:
    """Where one stage config's fields act.

    Attributes:
        stage: the stage config class.
        homes: per core home (a dataclass, or a function taking the settings as keyword
            parameters), ``{stage field: core field}``; a dotted core field (``"partition.depth_tol_m"``)
            sets a field of a nested core dataclass.
        stage_only: ``{stage field: why}`` for the fields that set no core field (a switch of the
            stage, a gate the stage applies to a core result, a path).
        differs: ``{stage field: why}`` for the fields whose default is not their home's (the
            test of config truth accepts only these).
    """

    stage: type[StageConfig]
    homes: Mapping[Home, Mapping[str, str]]
    stage_only: Mapping[str, str]
    differs: Mapping[str, str]

    def home_names(self, home: Home) -> dict[str, str]:
        try:
            # A decorated core function (functools.wraps) is the function it wraps.
            return dict(self.homes[inspect.unwrap(home) if callable(home) and not isinstance(home, type) else home])
        except KeyError:
            raise TypeError(
                f"{self.stage.__name__} declares no fields for {_name(home)}; its homes are "
                f"{[_name(h) for h in self.homes]} (tasks: config_map)"
            ) from None


CONFIG_MAPS: dict[type[StageConfig], ConfigMap] = {}


def config_map(
    stage: type[StageConfig],
    homes: Mapping[Home, str | Mapping[str, str]],
    *,
    stage_only: Mapping[str, str] | None = None,
    differs: Mapping[str, str] | None = None,
) -> ConfigMap:
    """Declare (and register) where ``stage``'s fields act: ``homes`` maps each core home to its
    fields, a space-separated string of names both sides share or ``{stage field: core field}``.

    Raises TypeError, naming the field, when a stage field has no home and no ``stage_only``
    reason, when a named field does not exist on either side, or when a field is both."""
    normal = {h: _names(f) for h, f in homes.items()}
    stage_only = dict(stage_only or {})
    differs = dict(differs or {})
    own = set(stage.model_fields)
    placed: set[str] = set()
    for home, names in normal.items():
        targets = _home_fields(home)
        for s, c in names.items():
            if s not in own:
                raise TypeError(f"{stage.__name__} has no field {s!r} (config_map, home {_name(home)})")
            if c.split(".")[0].split("[")[0] not in targets:
                raise TypeError(f"{_name(home)} has no field {c!r} for {stage.__name__}.{s}")
            placed.add(s)
    for s in (*stage_only, *differs):
        if s not in own:
            raise TypeError(f"{stage.__name__} has no field {s!r} (config_map stage_only/differs)")
    both = placed & set(stage_only)
    homeless = own - placed - set(stage_only)
    if both:
        raise TypeError(f"{stage.__name__}: field(s) {sorted(both)} are given a home and called stage-only")
    if homeless:
        raise TypeError(
            f"{stage.__name__}: field(s) {sorted(homeless)} set no core field; give each its home in "
            "config_map (tasks/<stage>.py), or say in stage_only why it sets none"
        )
    m = ConfigMap(stage, normal, stage_only, differs)
    CONFIG_MAPS[stage] = m
    return m


def config_map_of(stage: type[StageConfig]) -> ConfigMap:
    try:
        return CONFIG_MAPS[stage]
    except KeyError:
        raise TypeError(f"{stage.__name__} has no config_map: declare where its fields act (tasks._convert)") from None


def core_values(home: Home, config: StageConfig) -> dict[str, Any]:
    """The values ``config`` gives ``home``'s fields, by core name (nested stage configs converted,
    lists made tuples; dotted names merged into a copy of the nested dataclass's default)."""
    values: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    items: dict[str, dict[int, Any]] = {}
    for s, c in config_map_of(type(config)).home_names(home).items():
        value = core_value(getattr(config, s))
        head, _, rest = c.partition(".")
        if rest:
            nested.setdefault(head, {})[rest] = value
        elif c.endswith("]"):
            head, _, index = c[:-1].partition("[")
            items.setdefault(head, {})[int(index)] = value
        else:
            values[c] = value
    for head, subs in nested.items():
        values[head] = dataclasses.replace(values.get(head, home_default(home, head)), **subs)
    for head, by_index in items.items():
        seq = list(home_default(home, head))
        for i, v in by_index.items():
            seq[i] = v
        values[head] = tuple(seq)
    return values


def to_core_config(cls: type[T], config: StageConfig, **extra: Any) -> T:
    """Core config ``cls`` built from the fields of ``config`` that its :func:`config_map` sends to
    ``cls``, by name (plus ``extra``, which wins). The other fields of ``cls`` keep their defaults."""
    values = core_values(cls, config)
    values.update(extra)
    return cls(**values)


def core_kwargs(fn: Callable[..., Any], config: StageConfig) -> dict[str, Any]:
    """The keyword arguments ``config`` gives the core function ``fn`` (see :func:`config_map`)."""
    return core_values(fn, config)


def core_value(value: Any) -> Any:
    """A stage config value as the core takes it: a nested stage config becomes its (single) core
    home, a list a tuple."""
    if isinstance(value, StageConfig):
        m = config_map_of(type(value))
        (home,) = m.homes  # a nested section mirrors exactly one core dataclass
        return to_core_config(home, value)
    if isinstance(value, list):
        return tuple(core_value(v) for v in value)
    return value


def home_default(home: Home, name: str) -> Any:
    """The default of field (or keyword parameter) ``name`` of ``home``; dotted names go into
    nested dataclasses. ``inspect.Parameter.empty`` when it has none."""
    head, _, rest = name.partition(".")
    index = None
    if head.endswith("]"):
        head, _, i = head[:-1].partition("[")
        index = int(i)
    if dataclasses.is_dataclass(home):
        f = {f.name: f for f in dataclasses.fields(home)}[head]
        if f.default is not dataclasses.MISSING:
            value = f.default
        elif f.default_factory is not dataclasses.MISSING:
            value = f.default_factory()
        else:
            value = inspect.Parameter.empty
    else:
        value = inspect.signature(home).parameters[head].default
    if index is not None and value is not inspect.Parameter.empty:
        value = value[index]
    for part in rest.split(".") if rest else ():
        value = getattr(value, part)
    return value


def _home_fields(home: Home) -> set[str]:
    if dataclasses.is_dataclass(home):
        return {f.name for f in dataclasses.fields(home)}
    params = inspect.signature(home).parameters.values()
    return {p.name for p in params if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)}


def _names(fields: str | Mapping[str, str]) -> dict[str, str]:
    if isinstance(fields, str):
        return {n: n for n in fields.split()}
    return dict(fields)


def _name(home: Home) -> str:
    return getattr(home, "__qualname__", repr(home))


def json_safe(value):
    """Fitted parameters as JSON the store can round-trip (NaN and inf become None)."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value if isinstance(value, str) or value is None else str(value)
