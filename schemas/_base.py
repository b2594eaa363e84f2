"""The artifact base class: typed pydantic models whose arrays live in zarr.

An :class:`Artifact` declares its fields with pydantic. Array fields are annotated with
``Array(dtype, dims)``: the dtype is checked exactly (no silent casts) and the symbolic dims are
checked for consistency across fields (every ``"T"`` in one artifact is the same length).
Writing to a zarr group puts each array in a zarr array (chunked one frame per chunk when its first
dim is ``"T"``), nested artifacts in sub-groups, and every other field as JSON in the group's
attributes, so a round trip is exact.
"""

from __future__ import annotations

import types
import typing
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import zarr
from pydantic import BaseModel, ConfigDict, model_validator
from pydantic_core import core_schema

FRAME_DIM = "T"
_ROW_CHUNK = 1 << 16  # rows per chunk for long non-frame arrays (Gaussians, tracks)


class SchemaError(ValueError):
    """An artifact read from storage does not match the schema the code expects."""


@dataclass(frozen=True)
class ArraySpec:
    """Type of an array field: exact numpy ``dtype`` and ``dims`` (names, or ints for fixed sizes)."""

    dtype: str
    dims: tuple[str | int, ...]

    def validate(self, value: Any) -> np.ndarray:
        if not isinstance(value, np.ndarray):
            raise ValueError(f"expected a numpy array of {self.dtype}{list(self.dims)}, got {type(value).__name__}")
        if value.dtype != np.dtype(self.dtype):
            raise ValueError(f"expected dtype {self.dtype}, got {value.dtype}")
        if value.ndim != len(self.dims):
            raise ValueError(f"expected {len(self.dims)} dims {list(self.dims)}, got shape {value.shape}")
        for size, dim in zip(value.shape, self.dims, strict=True):
            if isinstance(dim, int) and size != dim:
                raise ValueError(f"expected shape {list(self.dims)}, got {value.shape}")
        return value

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> core_schema.CoreSchema:
        return core_schema.no_info_plain_validator_function(
            self.validate,
            serialization=core_schema.plain_serializer_function_ser_schema(
                lambda a: {"dtype": str(a.dtype), "shape": list(a.shape)}
            ),
        )

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict:
        return {"type": "array", "description": f"{self.dtype} array of shape {list(self.dims)}"}


def Array(dtype: str, dims: tuple[str | int, ...] | str) -> Any:  # noqa: N802 (reads as a type)
    """Annotation for a numpy array field, e.g. ``Array("float32", "T H W")``."""
    if isinstance(dims, str):
        dims = tuple(int(d) if d.isdigit() else d for d in dims.split())
    return typing.Annotated[np.ndarray, ArraySpec(dtype, tuple(dims))]


_REGISTRY: dict[str, type[Artifact]] = {}


def artifact_class(kind: str) -> type[Artifact]:
    """The artifact class registered under ``kind`` (raises SchemaError if unknown)."""
    try:
        return _REGISTRY[kind]
    except KeyError:
        raise SchemaError(f"unknown artifact kind {kind!r}; known: {sorted(_REGISTRY)}") from None


def all_artifact_classes() -> list[type[Artifact]]:
    return [cls for _, cls in sorted(_REGISTRY.items())]


class Artifact(BaseModel):
    """Base of every stored artifact. Subclasses set ``kind`` and ``schema_version``.

    Bump ``schema_version`` whenever a field's meaning, units or layout changes: the store key of
    every artifact includes it, so old cached results are not reused under the new meaning.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", arbitrary_types_allowed=True)

    kind: ClassVar[str] = ""
    schema_version: ClassVar[int] = 1

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.kind:
            if cls.kind in _REGISTRY and _REGISTRY[cls.kind].__qualname__ != cls.__qualname__:
                raise TypeError(f"artifact kind {cls.kind!r} registered twice")
            _REGISTRY[cls.kind] = cls

    # --- validation -------------------------------------------------------------------------
    @model_validator(mode="after")
    def _check_dims(self) -> Artifact:
        sizes: dict[str, tuple[int, str]] = {}
        for name, spec in self.array_specs().items():
            value = getattr(self, name)
            if value is None:
                continue
            for size, dim in zip(value.shape, spec.dims, strict=True):
                if isinstance(dim, int):
                    continue
                if dim in sizes and sizes[dim][0] != size:
                    other_size, other = sizes[dim]
                    raise ValueError(
                        f"{type(self).__name__}: dim {dim!r} is {size} in field {name!r} but "
                        f"{other_size} in field {other!r}"
                    )
                sizes.setdefault(dim, (size, name))
        return self

    # --- field introspection ----------------------------------------------------------------
    @classmethod
    def array_specs(cls) -> dict[str, ArraySpec]:
        out = {}
        for name, info in cls.model_fields.items():
            spec = next((m for m in info.metadata if isinstance(m, ArraySpec)), None)
            if spec is None:
                spec = _optional_array_spec(info.annotation)
            if spec is not None:
                out[name] = spec
        return out

    @classmethod
    def nested_fields(cls) -> dict[str, tuple[type[Artifact], bool]]:
        """Fields holding nested artifacts: name -> (class, is_list)."""
        if not cls.__pydantic_complete__:
            # A field typed with a class defined further down its module is a forward reference
            # until pydantic rebuilds the model, which it does on the first validation only: a
            # fresh process reading before writing would take the nested list for a plain field,
            # find it missing from the stored fields, and read it as its default (empty).
            cls.model_rebuild()
        out = {}
        for name, info in cls.model_fields.items():
            ann = info.annotation
            origin = typing.get_origin(ann)
            if isinstance(ann, type) and issubclass(ann, Artifact):
                out[name] = (ann, False)
            elif origin is list:
                (arg,) = typing.get_args(ann)
                if isinstance(arg, type) and issubclass(arg, Artifact):
                    out[name] = (arg, True)
        return out

    # --- zarr I/O ---------------------------------------------------------------------------
    def to_zarr(self, group: zarr.Group) -> None:
        """Write this artifact into an empty zarr group."""
        arrays = self.array_specs()
        nested = self.nested_fields()
        plain = [n for n in type(self).model_fields if n not in arrays and n not in nested]
        none_arrays = []
        for name, spec in arrays.items():
            value = getattr(self, name)
            if value is None:
                none_arrays.append(name)
                continue
            _write_array(group, name, value, spec)
        for name, (_, is_list) in nested.items():
            value = getattr(self, name)
            sub = group.create_group(name)
            if is_list:
                sub.attrs["length"] = len(value)
                for i, item in enumerate(value):
                    item.to_zarr(sub.create_group(str(i)))
            else:
                value.to_zarr(sub)
        group.attrs.update(
            {
                "artitwin_kind": self.kind,
                "artitwin_schema_version": self.schema_version,
                "fields": self.model_dump(mode="json", include=set(plain)),
                "none_arrays": none_arrays,
            }
        )

    @classmethod
    def from_zarr(cls, group: zarr.Group) -> Artifact:
        """Read an artifact written by :meth:`to_zarr`; dispatches on the stored kind."""
        attrs = group.attrs.asdict()
        kind = attrs.get("artitwin_kind")
        if kind is None:
            raise SchemaError("zarr group has no 'artitwin_kind' attribute: not an ArtiTwin artifact")
        target = artifact_class(kind)
        if cls is not Artifact and not issubclass(target, cls):
            raise SchemaError(f"stored artifact is a {kind!r}, expected {cls.kind!r}")
        version = attrs.get("artitwin_schema_version")
        if version != target.schema_version:
            raise SchemaError(
                f"stored {kind!r} has schema version {version}, this code reads version "
                f"{target.schema_version}; recompute it (the store key changes with the version)"
            )
        values: dict[str, Any] = dict(attrs["fields"])
        for name in target.array_specs():
            values[name] = None if name in attrs["none_arrays"] else group[name][...]
        for name, (sub_cls, is_list) in target.nested_fields().items():
            sub = group[name]
            if is_list:
                values[name] = [sub_cls.from_zarr(sub[str(i)]) for i in range(sub.attrs["length"])]
            else:
                values[name] = sub_cls.from_zarr(sub)
        return target.model_validate(values)

    # --- helpers ----------------------------------------------------------------------------
    def equals(self, other: Artifact) -> bool:
        """Exact equality, arrays compared bitwise (NaN equals NaN)."""
        if type(self) is not type(other):
            return False
        for name in type(self).model_fields:
            a, b = getattr(self, name), getattr(other, name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or a.dtype != b.dtype or a.shape != b.shape:
                    return False
                if a.tobytes() != b.tobytes():
                    return False
            elif isinstance(a, list) and a and isinstance(a[0], Artifact):
                if len(a) != len(b) or not all(x.equals(y) for x, y in zip(a, b, strict=True)):
                    return False
            elif isinstance(a, Artifact):
                if not a.equals(b):
                    return False
            elif a != b:
                return False
        return True


def _optional_array_spec(annotation: Any) -> ArraySpec | None:
    """The ArraySpec inside ``Array(...) | None``, if that is what ``annotation`` is."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        for arg in typing.get_args(annotation):
            if typing.get_origin(arg) is typing.Annotated:
                spec = next((m for m in arg.__metadata__ if isinstance(m, ArraySpec)), None)
                if spec is not None:
                    return spec
    return None


def _write_array(group: zarr.Group, name: str, value: np.ndarray, spec: ArraySpec) -> None:
    if value.ndim == 0 or 0 in value.shape:
        chunks = tuple(max(s, 1) for s in value.shape) or None
    elif spec.dims[0] == FRAME_DIM:
        chunks = (1, *value.shape[1:])
    else:
        chunks = (min(value.shape[0], _ROW_CHUNK), *value.shape[1:])
    arr = group.create_array(name, shape=value.shape, dtype=value.dtype, chunks=chunks, fill_value=None)
    if value.size:
        arr[...] = value


class StageConfig(BaseModel):
    """Base of every stage config: frozen, unknown fields rejected (typos are errors, not no-ops)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
